"""Lennard-Jones with a smooth (shifted-force) cutoff, for the van der Waals attraction
between the tubes of a bundle; ASE calculator and numba kernel.

    phi(r)    = 4 eps [(sigma/r)^12 - (sigma/r)^6]
    phi_SF(r) = phi(r) - phi(rc) - (r - rc) phi'(rc)     for r < rc, 0 beyond

Energy and force go to zero continuously at ``rc``; this is exactly LAMMPS
``pair_style lj/smooth/linear rc``. Pairs of atoms with the same molecule id (``mol``, or
``atoms.arrays['mol-id']``) are skipped when ``exclude_same_mol`` is set, so a bundle of
tubes, each carrying its own covalent potential, gets LJ only between different tubes
(LAMMPS: ``neigh_modify exclude molecule/intra all``).

Carbon parameter sets (``params=``):

- ``"airebo"`` (default): eps = 2.84 meV, sigma = 3.40 A, the C-C Lennard-Jones term of
  AIREBO, S. J. Stuart, A. B. Tutein, J. A. Harrison, J. Chem. Phys. 112, 6472 (2000)
  (also in LAMMPS's ``CH.airebo``); default ``rc = 3 sigma`` as there.
- ``"girifalco2000"``: from C6 = 15.2 eV A^6, C12 = 24.1e3 eV A^12 of L. A. Girifalco,
  M. Hodak, R. S. Lee, Phys. Rev. B 62, 13104 (2000) (graphitic potential for nanotubes
  and ropes): eps = C6^2/(4 C12), sigma = (C12/C6)^(1/6).

Array suffixes as in :mod:`potentials.neighbours` (``_n`` atom, ``_b`` bond, ``_c``
Cartesian).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from potentials.brenner_kernels import threads_for
from potentials.calculator import PotentialCalculator

__all__ = ["LennardJones", "LJ_CARBON", "lj_energy_forces"]

_G_C6, _G_C12 = 15.2, 24.1e3
LJ_CARBON = {
    "airebo": {"epsilon": 0.00284, "sigma": 3.40,
               "citation": "S. J. Stuart, A. B. Tutein, J. A. Harrison, J. Chem. Phys. 112, "
                           "6472 (2000), AIREBO C-C Lennard-Jones parameters"},
    "girifalco2000": {"epsilon": _G_C6 ** 2 / (4 * _G_C12),
                      "sigma": (_G_C12 / _G_C6) ** (1.0 / 6.0),
                      "citation": "L. A. Girifalco, M. Hodak, R. S. Lee, Phys. Rev. B 62, "
                                  "13104 (2000): C6 = 15.2 eV A^6, C12 = 24.1e3 eV A^12"},
}


@njit(parallel=True, cache=True)
def lj_energy_forces(x_nc, cell, first_n, j_b, shift_bc, eps, sigma, rc, mol_n, use_mol):
    """Shifted-force LJ on a full CSR neighbour list.

    Parameters
    ----------
    x_nc : (N, 3) positions, Angstrom; cell : (3, 3); first_n, j_b, shift_bc : full list
    eps (eV), sigma (Angstrom), rc (Angstrom) : LJ parameters and cutoff
    mol_n : (N,) int molecule ids; pairs with equal ids are skipped when ``use_mol``

    Returns
    -------
    energy (eV), energies_n (N,) (eV), forces_nc (N, 3) (eV/A), virial_cc (3, 3) (eV,
    ``W = -sum_pairs r (x) dE/dr``)
    """
    n = first_n.shape[0] - 1
    s6 = sigma ** 6
    irc = 1.0 / rc
    irc6 = s6 * irc ** 6
    phic = 4.0 * eps * (irc6 * irc6 - irc6)
    dphic = 4.0 * eps * (-12.0 * irc6 * irc6 + 6.0 * irc6) * irc
    rc2 = rc * rc
    e_n = np.zeros(n)
    F_nc = np.zeros((n, 3))
    W_ncc = np.zeros((n, 3, 3))
    for i in prange(n):
        ei = 0.0
        for b in range(first_n[i], first_n[i + 1]):
            j = j_b[b]
            if use_mol and mol_n[i] == mol_n[j]:
                continue
            d0 = (x_nc[j, 0] - x_nc[i, 0] + shift_bc[b, 0] * cell[0, 0]
                  + shift_bc[b, 1] * cell[1, 0] + shift_bc[b, 2] * cell[2, 0])
            d1 = (x_nc[j, 1] - x_nc[i, 1] + shift_bc[b, 0] * cell[0, 1]
                  + shift_bc[b, 1] * cell[1, 1] + shift_bc[b, 2] * cell[2, 1])
            d2 = (x_nc[j, 2] - x_nc[i, 2] + shift_bc[b, 0] * cell[0, 2]
                  + shift_bc[b, 1] * cell[1, 2] + shift_bc[b, 2] * cell[2, 2])
            rr = d0 * d0 + d1 * d1 + d2 * d2
            if rr >= rc2:
                continue
            r = math.sqrt(rr)
            ir = 1.0 / r
            sr6 = s6 / (rr * rr * rr)
            phi = 4.0 * eps * (sr6 * sr6 - sr6) - phic - (r - rc) * dphic
            dphi = 4.0 * eps * (-12.0 * sr6 * sr6 + 6.0 * sr6) * ir - dphic
            ei += 0.5 * phi
            # F_i = sum_j phi'(r) (r_ij / r); each directed bond carries half the virial
            g = dphi * ir
            F_nc[i, 0] += g * d0
            F_nc[i, 1] += g * d1
            F_nc[i, 2] += g * d2
            dv = (d0, d1, d2)
            for a in range(3):
                for c in range(3):
                    W_ncc[i, a, c] -= 0.5 * g * dv[a] * dv[c]
        e_n[i] = ei
    energy = 0.0
    W = np.zeros((3, 3))
    for i in range(n):
        energy += e_n[i]
        for a in range(3):
            for c in range(3):
                W[a, c] += W_ncc[i, a, c]
    return energy, e_n, F_nc, W


class LennardJones(PotentialCalculator):
    """Shifted-force Lennard-Jones for carbon van der Waals (ASE calculator).

    Parameters
    ----------
    params : {"airebo", "girifalco2000"}
        Carbon parameter set (see module docstring); ``epsilon``/``sigma`` override it.
    epsilon : float, eV; sigma : float, Angstrom
    rc : float, Angstrom
        Cutoff; default 3 sigma.
    mol : (N,) int array or None
        Molecule (tube) id per atom; if None, ``atoms.arrays['mol-id']`` is used when
        present.
    exclude_same_mol : bool
        Skip pairs within one molecule (default True; no effect without molecule ids).
    skin, min_distance : see :class:`potentials.calculator.PotentialCalculator`
    """

    default_parameters = {**PotentialCalculator.default_parameters,
                          "params": "airebo", "epsilon": None, "sigma": None, "rc": None,
                          "mol": None, "exclude_same_mol": True, "min_distance": 0.5}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._setup()

    def set(self, **kwargs):
        changed = super().set(**kwargs)
        if changed and hasattr(self, "_eps"):
            self._setup()
            self.reset()
        return changed

    def _setup(self):
        p = self.parameters
        if p["params"] not in LJ_CARBON:
            raise ValueError(f"unknown LJ carbon parameter set {p['params']!r}; choose one "
                             f"of {sorted(LJ_CARBON)}")
        base = LJ_CARBON[p["params"]]
        self._eps = float(base["epsilon"] if p["epsilon"] is None else p["epsilon"])
        self._sigma = float(base["sigma"] if p["sigma"] is None else p["sigma"])
        rc = 3.0 * self._sigma if p["rc"] is None else float(p["rc"])
        if not (self._eps > 0 and self._sigma > 0 and rc > 0):
            raise ValueError(f"need epsilon, sigma, rc > 0, got {self._eps}, {self._sigma}, "
                             f"{rc}")
        self.cutoff = rc

    def _mol(self, atoms):
        m = self.parameters["mol"]
        if m is None:
            m = atoms.arrays.get("mol-id")
        if m is None:
            return np.zeros(len(atoms), np.int64), False
        m = np.asarray(m).astype(np.int64).ravel()
        if len(m) != len(atoms):
            raise ValueError(f"mol has {len(m)} entries for {len(atoms)} atoms")
        return m, bool(self.parameters["exclude_same_mol"])

    def check_atoms(self, atoms) -> None:
        self._mol(atoms)

    def compute(self, atoms, nl):
        mol, use = self._mol(atoms)
        x = np.ascontiguousarray(atoms.positions, dtype=float)
        cell = np.ascontiguousarray(atoms.cell.array, dtype=float)
        with threads_for(len(atoms), per_thread=500):
            return lj_energy_forces(x, cell, nl.first_n, nl.j_b, nl.shift_bc, self._eps,
                                    self._sigma, float(self.cutoff), mol, use)
