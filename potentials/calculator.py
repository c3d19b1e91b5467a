"""The ASE plumbing shared by the project's potentials, written once.

A potential subclasses :class:`PotentialCalculator`, sets :attr:`~PotentialCalculator.cutoff`
(the largest interaction distance, Angstrom) and implements :meth:`compute`, which returns
``(energy, energies_n, forces_nc, virial_cc)`` from its kernel on a ready neighbour list.
The base class does the rest: ASE's change detection, a copy of the atoms (the caller's are
never touched), the neighbour list with its skin and rebuild rule, the overlap check, fresh
result arrays, and stress only when the cell has full rank.

Cost outside the kernel. Three things would otherwise be a few per cent of a Tersoff call on
a large system, and are done with the same outcome at a fraction of the cost:

- change detection (:meth:`PotentialCalculator.check_state`) is ASE's ``compare_atoms``
  with its tolerance (``|a - b| <= 1e-15`` elementwise, as ``np.allclose(rtol=0)``), but each
  array is compared in one compiled pass that stops at the first difference, instead of
  ``np.allclose``'s temporaries;
- the overlap check needs no pass over the list while the list is not rebuilt: with
  ``d_0`` the shortest listed distance at the last build and ``u`` the largest displacement
  since (:attr:`NeighbourList.displacement <potentials.neighbours.NeighbourList>`), every
  listed pair is at least ``d_0 - 2 u`` long now, so only when that bound is not above
  ``min_distance`` is the exact minimum computed (the error raised is the same);
- results a subclass returns as new arrays (``compute_returns_new_arrays``) are kept
  without another copy (ASE copies them again on the way out).

Conventions. The virial is LAMMPS's: ``W = -sum_bonds r_ij (x) dE/dr_ij`` summed over the
terms of the energy, so ``W = sum_i x_i (x) f_i`` for a finite cluster and the pressure
tensor is ``W / V``. ASE's stress is ``sigma = -W / V`` (``dE/d(strain) / V``), reported in
Voigt order xx, yy, zz, yz, xz, xy.
"""
from __future__ import annotations

import numpy as np
from ase.calculators.calculator import (Calculator, PropertyNotImplementedError, all_changes,
                                        equal)
from numba import njit

from potentials.neighbours import NeighbourList, min_bond_distance

__all__ = ["PotentialCalculator", "OverlappingAtomsError", "full_rank_volume",
           "compare_atoms"]

# the overlap check skips the exact pass only when its lower bound clears min_distance by
# this much (Angstrom): far above the rounding of positions of any size
_OVERLAP_BOUND_MARGIN = 1e-9


class OverlappingAtomsError(ValueError):
    """Two atoms are closer than the calculator's ``min_distance``."""


@njit(cache=True)
def _flat_close(a, b, atol):
    """Whether every |a[k] - b[k]| <= atol (equal infinities count as close, NaN never),
    stopping at the first element that is not; the test of ``np.allclose(a, b, rtol=0)``."""
    for k in range(a.shape[0]):
        x = float(a[k])
        y = float(b[k])
        if x == y:
            continue
        if not abs(x - y) <= atol:
            return False
    return True


def _arrays_close(a, b, atol: float) -> bool:
    """ASE's ``equal(a, b, atol=atol)`` for arrays; float64/int64 C-contiguous arrays of one
    shape in one compiled pass, anything else through ASE."""
    if (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape
            and a.dtype == b.dtype and a.dtype in (np.float64, np.int64)
            and a.flags.c_contiguous and b.flags.c_contiguous):
        return bool(_flat_close(a.reshape(-1), b.reshape(-1), float(atol)))
    return bool(equal(a, b, atol=atol))


def compare_atoms(atoms1, atoms2, tol: float = 1e-15) -> list:
    """The changes from ``atoms1`` to ``atoms2``, as ``ase.calculators.calculator.
    compare_atoms`` finds them (same properties, same tolerance), with the arrays compared
    by :func:`_arrays_close`. ``atoms1`` None means everything changed."""
    if atoms1 is None:
        return all_changes[:]
    changes = []
    for prop in ("cell", "pbc"):
        if not equal(getattr(atoms1, prop), getattr(atoms2, prop), atol=tol):
            changes.append(prop)
    check = set(all_changes) - {"cell", "pbc"}
    arrays1, arrays2 = atoms1.arrays, atoms2.arrays
    changes += sorted(check & (set(arrays1) ^ set(arrays2)))
    for prop in sorted(check & set(arrays1) & set(arrays2)):
        if not _arrays_close(arrays1[prop], arrays2[prop], tol):
            changes.append(prop)
    return changes


def full_rank_volume(cell, rtol: float = 1e-12) -> float:
    """|det(cell)| if the cell has full rank, else 0.0 (Angstrom^3)."""
    cell = np.asarray(cell, dtype=float).reshape(3, 3)
    vol = abs(float(np.linalg.det(cell)))
    scale = float(np.prod(np.linalg.norm(cell, axis=1)))
    return vol if scale > 0 and vol > rtol * scale else 0.0


class PotentialCalculator(Calculator):
    """Base class of the project's ASE calculators (energy, energies, forces, stress).

    Parameters (``default_parameters``, settable as keyword arguments)
    ------------------------------------------------------------------
    skin : float
        Neighbour-list skin, Angstrom. The list holds pairs within ``cutoff + skin`` and is
        rebuilt when an atom moved more than ``skin / 2`` or the cell/pbc/number changed.
    min_distance : float
        Two atoms closer than this (Angstrom) raise :class:`OverlappingAtomsError`.

    Subclasses set :attr:`cutoff` and :attr:`half_list` and implement :meth:`compute`.
    Besides ASE's properties, ``results['virial']`` holds the 3x3 virial (eV), also for
    cells without full rank (e.g. ``ase.build.nanotube`` without vacuum), where ASE's
    ``stress`` raises ``PropertyNotImplementedError``.
    """

    implemented_properties = ["energy", "free_energy", "energies", "forces", "stress"]
    default_parameters = {"skin": 0.3, "min_distance": 0.5}
    #: largest interaction distance, Angstrom (set by the subclass)
    cutoff: float = 0.0
    #: whether the kernel wants each pair once (True) or a full list (False)
    half_list: bool = False
    #: whether :meth:`compute` returns energies and forces as float64 arrays that nothing
    #: else holds (then they are stored without a copy)
    compute_returns_new_arrays: bool = False

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._nl: NeighbourList | None = None
        # (list, its build count, shortest listed distance at that build)
        self._overlap_ref = None
        self._volume_of = (None, 0.0)  # (cell bytes, full_rank_volume of that cell)

    # -- what a subclass provides --------------------------------------------------------
    def compute(self, atoms, nl: NeighbourList):
        """Evaluate the potential.

        Parameters
        ----------
        atoms : ase.Atoms
            The calculator's own copy (may be read, must not be kept).
        nl : NeighbourList
            Up to date for ``atoms`` with ``cutoff + skin``.

        Returns
        -------
        energy : float, eV
        energies_n : (N,) float, eV, summing to ``energy``
        forces_nc : (N, 3) float, eV/Angstrom
        virial_cc : (3, 3) float, eV (LAMMPS convention, see module docstring)
        """
        raise NotImplementedError(f"{type(self).__name__} must implement compute()")

    def check_atoms(self, atoms) -> None:
        """Hook for subclasses: validate species etc. before the neighbour list is used."""

    # -- the plumbing -------------------------------------------------------------------
    @property
    def neighbour_list(self) -> NeighbourList:
        """The current neighbour list (built on the first calculation)."""
        p = self.parameters
        if (self._nl is None or self._nl.skin != float(p.skin)
                or self._nl.cutoff != float(self.cutoff) or self._nl.half != self.half_list):
            self._nl = NeighbourList(self.cutoff, skin=float(p.skin), half=self.half_list)
        return self._nl

    def reset(self):
        super().reset()
        self._nl = None
        self._overlap_ref = None

    def check_state(self, atoms, tol=1e-15):
        """Changes since the last calculation: :func:`compare_atoms` (ASE's rule, cheaper)."""
        if not getattr(self, "use_cache", True):
            return all_changes
        return compare_atoms(self.atoms, atoms, tol=tol)

    def calculate(self, atoms=None, properties=("energy",), system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)  # self.atoms is now a copy
        atoms = self.atoms
        key = np.ascontiguousarray(atoms.cell.array, dtype=float).tobytes()
        if key != self._volume_of[0]:
            self._volume_of = (key, full_rank_volume(atoms.cell))
        volume = self._volume_of[1]
        if "stress" in properties and volume == 0.0:
            raise PropertyNotImplementedError(
                "stress needs a cell of full rank; this cell (lengths "
                f"{atoms.cell.lengths().round(6).tolist()} Angstrom) "
                "has zero volume (use results['virial'], or give the cell vacuum)")
        self.check_atoms(atoms)
        positions = np.ascontiguousarray(atoms.positions, dtype=float)
        nl = self.neighbour_list
        nl.update(positions, atoms.cell.array, atoms.pbc)
        self._check_overlap(positions, atoms.cell.array, nl)
        energy, energies, forces, virial = self.compute(atoms, nl)
        energy = float(energy)
        virial = np.array(virial, dtype=float).reshape(3, 3)
        keep = np.asarray if self.compute_returns_new_arrays else np.array
        self.results = {
            "energy": energy,
            "free_energy": energy,
            "energies": keep(energies, dtype=float),
            "forces": keep(forces, dtype=float),
            "virial": virial,
        }
        if volume > 0.0:
            s = -virial / volume
            self.results["stress"] = np.array(
                [s[0, 0], s[1, 1], s[2, 2], 0.5 * (s[1, 2] + s[2, 1]),
                 0.5 * (s[0, 2] + s[2, 0]), 0.5 * (s[0, 1] + s[1, 0])])

    def _check_overlap(self, positions, cell, nl: NeighbourList) -> None:
        dmin = float(self.parameters.min_distance)
        if dmin <= 0 or nl.n_bonds == 0:
            return
        ref = self._overlap_ref
        if ref is not None and ref[0] is nl and ref[1] == nl.nbuilds:
            # every listed pair is at least d_0 - 2 u long (see the module docstring)
            if ref[2] - 2.0 * nl.displacement > dmin + _OVERLAP_BOUND_MARGIN:
                return
        d, i, j = min_bond_distance(positions, np.asarray(cell, float), nl.first_n, nl.j_b,
                                    nl.shift_bc)
        if nl.displacement == 0.0:  # the positions of the build: d is d_0
            self._overlap_ref = (nl, nl.nbuilds, float(d))
        if d < dmin:
            i, j = sorted((int(i), int(j)))
            raise OverlappingAtomsError(
                f"atoms {i} and {j} overlap: distance {d:.4g} Angstrom < min_distance "
                f"{dmin:g} Angstrom")

    def get_virial(self, atoms=None) -> np.ndarray:
        """The 3x3 virial (eV), defined for any cell."""
        self.get_property("energy", atoms)
        return self.results["virial"].copy()
