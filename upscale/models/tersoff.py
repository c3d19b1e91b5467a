"""The atomistic Tersoff tube as an engine model: every particle is an atom.

Energy and forces are those of LAMMPS ``pair_style tersoff`` (J. Tersoff, Phys. Rev. B 37,
6991 (1988); 39, 5566 (1989)), computed by :func:`potentials.tersoff_kernels.tersoff` on an
open-boundary Verlet list (:class:`potentials.neighbours.NeighbourList`, rebuilt when an
atom has moved more than half the ``skin``), so the model is the project's Tersoff
calculator (:class:`potentials.tersoff.Tersoff`) on the engine's arrays:

    E = sum_i E_i,   E_i = 1/2 sum_{j != i} f_C(r_ij) [f_R(r_ij) + b_ij f_A(r_ij)]

Units: eV, Å, amu; the time unit is the one in which ``m v^2`` is an energy
(sqrt(amu Å^2 / eV) = 10.18 fs; :data:`upscale.constants.ACC_EV_A_AMU_IN_A_FS2` converts);
``force_kind = "particle"`` (eV/Å per atom); the body's masses are ``density * volume``
(amu: volume 1, density the atomic mass).

``step_cutoff=True`` (default, as the strength references) replaces the switching function
f_C by a step at R + D (2.1 Å for C-C in ``BNC.tersoff``); LAMMPS is handed the same
potential as a file with D = 1e-5 Å (:func:`potentials.tersoff.write_step_cutoff_file`):
the two agree exactly while no distance lies within 2e-5 Å of the cutoff.

Bonds break through the potential itself (the pair leaves the cutoff), so the model has no
failure rule of its own (``needs.failure = False``); the damage of an atom is measured on
its positions (:func:`atom_damage`, mu = 1 - bonds left / bonds at the start, the
references' rule: bonds < 2.0 Å at the start, broken beyond 2.1 Å).
"""
from __future__ import annotations

import numba
import numpy as np

from potentials import tersoff_kernels as tk
from potentials.neighbours import NeighbourList, neighbour_list
from potentials.tersoff import read_tersoff_file
from upscale.models import register
from upscale.models.base import Model, Needs, check_positive

__all__ = ["TersoffModel", "atom_damage", "initial_bonds"]

_OPEN = (False, False, False)
_NOCELL = np.zeros((3, 3))


class TersoffModel(Model):
    """Tersoff potential on the particles of one body (module docstring).

    Parameters
    ----------
    potential : str
        A LAMMPS ``.tersoff`` file name or path (default ``"BNC.tersoff"``, the Lindsay &
        Broido C-C parameters of the references).
    elements : sequence of str
        Elements read from the file; every particle is ``elements[types[i]]``.
    types : (N,) int, optional
        Element index of each particle (default all 0).
    step_cutoff : bool
        f_C a step at R + D (default True, the strength references' potential).
    skin : float
        Neighbour-list skin, Å (default 1.0).
    nthreads : int, optional
        numba threads of the kernel (default: numba's current setting).
    period_z : float, optional
        Periodic along z with this period, Å (a periodic tube; default open boundaries).
    """

    name = "tersoff"
    needs = Needs(pairs=False, energy=True)
    force_kind = "particle"

    def __init__(self, potential: str = "BNC.tersoff", elements=("C",), *, types=None,
                 step_cutoff: bool = True, skin: float = 1.0, nthreads: int | None = None,
                 period_z: float | None = None):
        check_positive(skin=skin, period_z=period_z)
        self.period_z = None if period_z is None else float(period_z)
        if self.period_z is None:
            self._cell, self._pbc = _NOCELL, _OPEN
        else:
            self._cell, self._pbc = np.diag([1.0, 1.0, self.period_z]), (False, False, True)
        self.parameters = read_tersoff_file(potential, list(elements)).with_step_cutoff(
            bool(step_cutoff))
        self.potential = str(potential)
        self.step_cutoff = bool(step_cutoff)
        self.cutoff = self.parameters.cutoff
        self.skin = float(skin)
        self.nthreads = nthreads
        self._P = self.parameters.table
        self._e2p = np.ascontiguousarray(self.parameters.e2p, dtype=np.int64)
        self._types_in = None if types is None else np.asarray(types, dtype=np.int64)
        self._last = None

    def prepare(self, system, family=None, **kw) -> None:
        super().prepare(system, family, **kw)
        n = system.n
        t = np.zeros(n, np.int64) if self._types_in is None else self._types_in
        if t.shape != (n,):
            raise ValueError(f"types has shape {t.shape}; valid: ({n},), one per particle")
        nel = len(self.parameters.elements)
        if t.size and (t.min() < 0 or t.max() >= nel):
            raise ValueError(f"types must lie in 0..{nel - 1} (elements "
                             f"{self.parameters.elements}), got {int(t.min())}..{int(t.max())}")
        self.types = np.ascontiguousarray(t)
        self.nl = NeighbourList(self.cutoff, self.skin)
        self._last = None

    def set_period(self, period_z: float) -> None:
        """Set the period along z, Å (mutates the model; a periodic model only): the cell of
        a quasi-static strain step. The neighbour list sees the new cell and rebuilds."""
        if self.period_z is None:
            raise ValueError("set_period on an open-boundary Tersoff model; valid: a model "
                             "made with period_z")
        check_positive(period_z=period_z)
        self.period_z = float(period_z)
        self._cell = np.diag([1.0, 1.0, self.period_z])
        self._last = None

    def virial(self, state) -> np.ndarray:
        """(3, 3) eV: W = sum over bonds of r_ij (x) f_ij (LAMMPS's virial, the kinetic part
        left out). With a period along z, dE/dL_z = -W_zz / L_z under an affine stretch."""
        return self.evaluate(state.y)[3].copy()

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, y):
        """``(energy, e_n, f_nc, W_cc)`` of positions ``y`` (N, 3) Å: eV, eV per atom, eV/Å,
        virial (eV). The last result is kept while ``y`` is unchanged."""
        y = np.ascontiguousarray(y, dtype=np.float64)
        last = self._last
        if last is not None and last[0].shape == y.shape and np.array_equal(last[0], y):
            return last[1]
        self.nl.update(y, self._cell, self._pbc)
        nt = self.nthreads or numba.get_num_threads()
        out = tk.tersoff(y, self._cell, self.nl.first_n, self.nl.j_b, self.nl.shift_bc,
                         self.types, self._e2p, self._P, float(self.cutoff), int(nt))
        self._last = (y.copy(), out)
        return out

    def add_force(self, state, out) -> None:
        out += self.evaluate(state.y)[2]

    def energy(self, state) -> float:
        return float(self.evaluate(state.y)[0])

    def site_energies(self, state) -> np.ndarray:
        """(N,) eV: the Tersoff energy of each atom."""
        return self.evaluate(state.y)[1].copy()

    def energy_density(self, state):
        return self.evaluate(state.y)[1] / self.system.volume

    def stiffness_bound(self):
        """None: give the integrator a ``dt`` (1 fs, as the references)."""
        return None

    def describe(self) -> dict:
        return {"model": self.name, "potential": self.potential,
                "elements": list(self.parameters.elements), "step_cutoff": self.step_cutoff,
                "cutoff_A": self.cutoff, "period_z_A": self.period_z}


def initial_bonds(x, bond_cutoff: float = 2.0) -> np.ndarray:
    """(M, 2) int: the pairs i < j closer than ``bond_cutoff`` Å in positions ``x``."""
    first, j, _ = neighbour_list(np.ascontiguousarray(x, dtype=float), _NOCELL, _OPEN,
                                 float(bond_cutoff), half=True)
    i = np.repeat(np.arange(len(first) - 1), np.diff(first))
    return np.column_stack([i, j]).astype(np.int64)


def atom_damage(x, bonds, break_cutoff: float = 2.1) -> np.ndarray:
    """(N,) damage mu = 1 - (bonds left) / (bonds at the start) of each atom (seed 004 eq.
    5.16; a bond of ``bonds`` is broken when longer than ``break_cutoff`` Å); atoms without
    bonds get 0."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    if len(bonds) == 0:
        return np.zeros(n)
    d = np.linalg.norm(x[bonds[:, 0]] - x[bonds[:, 1]], axis=1)
    ok = (d <= break_cutoff).astype(float)
    total = np.bincount(bonds.ravel(), minlength=n).astype(float)
    left = np.bincount(bonds[:, 0], ok, n) + np.bincount(bonds[:, 1], ok, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = np.where(total > 0, 1.0 - left / np.maximum(total, 1), 0.0)
    return mu


register("tersoff", TersoffModel)
