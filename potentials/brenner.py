"""Brenner 1990 (REBO-I) potential for carbon, as an ASE calculator.

Form (D. W. Brenner, Phys. Rev. B 42, 9458 (1990); seed 004, eqs. 5.10-5.12):

    E = sum_{i<j} [V_R(r_ij) - Bbar_ij V_A(r_ij)]
    V_R = f(r) D_e/(S-1) exp[-sqrt(2S) beta (r - r_e)]
    V_A = f(r) D_e S/(S-1) exp[-sqrt(2/S) beta (r - r_e)]
    f(r) = 1 (r < R1),  [1 + cos(pi (r-R1)/(R2-R1))]/2 (R1 <= r < R2),  0 (r >= R2)
    B_ij = [1 + sum_{k != i,j} G(theta_ijk) f(r_ik)]^(-delta)
    G(theta) = a0 [1 + c0^2/d0^2 - c0^2/(d0^2 + (1 + cos theta)^2)]
    Bbar_ij = [B_ij + B_ji + F(N_i, N_j, N_conj)] / 2

with both published carbon parameter sets (potential I, delta = 0.80469; potential II,
delta = 1/2) and the tabulated conjugation correction F of carbon, stored with their
citations in ``potentials/data/brenner1990.json`` (see that file for the definitions of
N_i, N_conj, the interpolation and the weight 1/2 of F). Hydrogen is not implemented.

Option ``step_cutoff=True`` replaces the switching region of f by a step at R2 = 2.0 A,
the common fix of the spurious stiffening of stretched bonds before they break.
"""
from __future__ import annotations

import functools
import json
from importlib import resources

import numpy as np

from potentials.brenner_kernels import (N_PARAMS, P_A0, P_BETA, P_C0, P_D, P_D0, P_DELTA,
                                        P_R1, P_R2, P_RE, P_S, brenner_energy_forces,
                                        reverse_bonds, threads_for)
from potentials.calculator import PotentialCalculator

__all__ = ["Brenner", "brenner_parameters", "brenner_data", "conjugation_table",
           "lammps_tersoff_line"]


@functools.cache
def brenner_data() -> dict:
    """The parsed ``brenner1990.json`` (parameter sets, conjugation tables, citations)."""
    text = resources.files("potentials").joinpath("data/brenner1990.json").read_text()
    return json.loads(text)


def brenner_parameters(name: str = "II") -> dict:
    """Parameters of set ``"I"`` or ``"II"`` (a fresh dict: D_e, S, beta, r_e, delta, a0,
    c0, d0, R1, R2, citation)."""
    sets = brenner_data()["sets"]
    key = str(name).upper()
    if key not in sets:
        raise ValueError(f"unknown Brenner parameter set {name!r}; choose one of "
                         f"{sorted(sets)} (Brenner, Phys. Rev. B 42, 9458 (1990), Table I)")
    return {k: v for k, v in sets[key].items() if k != "conjugation"}


def conjugation_table(name: str = "II"):
    """Arrays ``(F_v, F_dNi, F_dNj)`` of shape (4, 4, 2): the conjugation correction
    F(N_i, N_j, N_conj) of set ``name`` on the nodes N_i, N_j = 0..3, N_conj = 1, 2 and its
    tabulated derivatives; unlisted nodes are zero, symmetry F(a,b,c) = F(b,a,c) filled in.
    """
    tab = brenner_data()["sets"][str(name).upper()]["conjugation"]
    F_v = np.zeros((4, 4, 2))
    F_dx = np.zeros((4, 4, 2))
    F_dy = np.zeros((4, 4, 2))
    for node in tab["nodes"]:
        a, b, c = node["Ni"], node["Nj"], node["Nconj"] - 1
        F_v[a, b, c] = F_v[b, a, c] = node["F"]
    for node in tab["derivatives_dNi"]:
        a, b, c = node["Ni"], node["Nj"], node["Nconj"] - 1
        F_dx[a, b, c] = node["dF"]
        F_dy[b, a, c] = node["dF"]
    return F_v, F_dx, F_dy


def _param_vector(p: dict) -> np.ndarray:
    v = np.zeros(N_PARAMS)
    v[P_D], v[P_S], v[P_BETA], v[P_RE] = p["D_e"], p["S"], p["beta"], p["r_e"]
    v[P_DELTA], v[P_A0], v[P_C0], v[P_D0] = p["delta"], p["a0"], p["c0"], p["d0"]
    v[P_R1], v[P_R2] = p["R1"], p["R2"]
    return v


def lammps_tersoff_line(name: str = "II", step_cutoff: bool = False,
                        element: str = "C") -> str:
    """A LAMMPS ``pair_style tersoff`` entry that is exactly Brenner ``name`` without F.

    Only possible for delta = 1/2 (set II): LAMMPS's b_ij = (1 + beta^n zeta^n)^(-1/2n)
    with n = beta = 1 is (1 + zeta)^(-1/2). Mapping: m = 3 (unused, lambda3 = 0),
    gamma = a0, c = c0, d = d0, costheta0 = -1, lambda1 = sqrt(2S) beta,
    A = D_e/(S-1) exp(lambda1 r_e), lambda2 = sqrt(2/S) beta, B = D_e S/(S-1) exp(lambda2 r_e),
    R = (R1+R2)/2, D = (R2-R1)/2 (LAMMPS's 1/2 - 1/2 sin(pi/2 (r-R)/D) is Brenner's f);
    with ``step_cutoff`` R = R2 - 1e-5, D = 1e-5. LAMMPS's E = 1/2 sum_i sum_j f_C [f_R +
    b_ij f_A] is then Brenner's sum over pairs with (B_ij + B_ji)/2.
    """
    p = brenner_parameters(name)
    if abs(p["delta"] - 0.5) > 1e-15:
        raise ValueError(f"Brenner set {name} has delta = {p['delta']}: LAMMPS tersoff's "
                         "bond order (1 + zeta)^(-1/2n) cannot express it; only delta = 1/2 "
                         "(set II) maps exactly")
    S, beta, De, re = p["S"], p["beta"], p["D_e"], p["r_e"]
    l1 = np.sqrt(2.0 * S) * beta
    l2 = np.sqrt(2.0 / S) * beta
    A = De / (S - 1.0) * np.exp(l1 * re)
    B = De * S / (S - 1.0) * np.exp(l2 * re)
    if step_cutoff:
        R, D = p["R2"] - 1e-5, 1e-5
    else:
        R, D = 0.5 * (p["R1"] + p["R2"]), 0.5 * (p["R2"] - p["R1"])
    vals = [3.0, p["a0"], 0.0, p["c0"], p["d0"], -1.0, 1.0, 1.0, l2, B, R, D, l1, A]
    return f"{element} {element} {element} " + " ".join(repr(float(v)) for v in vals)


class Brenner(PotentialCalculator):
    """Brenner 1990 (REBO-I) carbon, ASE calculator (energy, energies, forces, stress).

    Parameters
    ----------
    parameters : {"I", "II"}
        Brenner's potential I (delta = 0.80469) or II (delta = 1/2), Table I of
        Phys. Rev. B 42, 9458 (1990). Default "II". Stored as ``parameter_set`` (ASE
        reserves the name ``parameters``); ``parameter_set=`` is accepted too.
    conjugation : bool
        Include the tabulated conjugation correction F_ij (default True). It vanishes in
        perfect graphene, nanotubes and diamond, not at vacancies or breaking bonds.
    step_cutoff : bool
        Replace the switching region R1 < r < R2 of f(r) by a step at R2 = 2.0 A (default
        False).
    skin, min_distance : float
        See :class:`potentials.calculator.PotentialCalculator`.

    All atoms must be carbon. ``results['virial']`` is available for any cell; ``stress``
    only for cells of full rank.
    """

    implemented_properties = ["energy", "free_energy", "energies", "forces", "stress"]
    default_parameters = {**PotentialCalculator.default_parameters,
                          "parameter_set": "II", "conjugation": True, "step_cutoff": False}

    def __init__(self, parameters: str | None = None, **kwargs):
        if parameters is not None:  # ASE's set() reads a `parameters` keyword as a file
            kwargs["parameter_set"] = parameters
        super().__init__(**kwargs)
        self._setup()

    def set(self, **kwargs):
        if "parameters" in kwargs and isinstance(kwargs["parameters"], str) \
                and kwargs["parameters"].upper() in ("I", "II"):
            kwargs["parameter_set"] = kwargs.pop("parameters")
        changed = super().set(**kwargs)
        if changed and hasattr(self, "_p"):
            self._setup()
            self.reset()
        return changed

    def _setup(self):
        pset = self.parameters["parameter_set"]
        self._p = brenner_parameters(pset)
        self._pvec = _param_vector(self._p)
        self._table = conjugation_table(pset)
        self.cutoff = float(self._p["R2"])

    def check_atoms(self, atoms) -> None:
        z = atoms.numbers
        if len(z) and np.any(z != 6):
            bad = sorted(set(atoms.get_chemical_symbols()) - {"C"})
            raise ValueError(f"Brenner 1990 is implemented for carbon only; the atoms "
                             f"contain {', '.join(bad)}")

    def compute(self, atoms, nl):
        with threads_for(len(atoms)):
            if getattr(self, "_rev_for", None) is not nl.j_b:
                self._rev = reverse_bonds(nl.first_n, nl.j_b, nl.shift_bc)
                self._rev_for = nl.j_b
            x = np.ascontiguousarray(atoms.positions, dtype=float)
            cell = np.ascontiguousarray(atoms.cell.array, dtype=float)
            F_v, F_dx, F_dy = self._table
            return brenner_energy_forces(
                x, cell, nl.first_n, nl.j_b, nl.shift_bc, self._rev, self._pvec, F_v, F_dx,
                F_dy, bool(self.parameters["step_cutoff"]),
                bool(self.parameters["conjugation"]))
