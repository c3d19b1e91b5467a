"""The ASE plumbing shared by the project's potentials, written once.

A potential subclasses :class:`PotentialCalculator`, sets :attr:`~PotentialCalculator.cutoff`
(the largest interaction distance, Angstrom) and implements :meth:`compute`, which returns
``(energy, energies_n, forces_nc, virial_cc)`` from its kernel on a ready neighbour list.
The base class does the rest: ASE's change detection, a copy of the atoms (the caller's are
never touched), the neighbour list with its skin and rebuild rule, the overlap check, fresh
result arrays, and stress only when the cell has full rank.

Conventions. The virial is LAMMPS's: ``W = -sum_bonds r_ij (x) dE/dr_ij`` summed over the
terms of the energy, so ``W = sum_i x_i (x) f_i`` for a finite cluster and the pressure
tensor is ``W / V``. ASE's stress is ``sigma = -W / V`` (``dE/d(strain) / V``), reported in
Voigt order xx, yy, zz, yz, xz, xy.
"""
from __future__ import annotations

import numpy as np
from ase.calculators.calculator import Calculator, PropertyNotImplementedError, all_changes

from potentials.neighbours import NeighbourList, min_bond_distance

__all__ = ["PotentialCalculator", "OverlappingAtomsError", "full_rank_volume"]


class OverlappingAtomsError(ValueError):
    """Two atoms are closer than the calculator's ``min_distance``."""


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

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._nl: NeighbourList | None = None

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

    def calculate(self, atoms=None, properties=("energy",), system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)  # self.atoms is now a copy
        atoms = self.atoms
        volume = full_rank_volume(atoms.cell)
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
        self.results = {
            "energy": energy,
            "free_energy": energy,
            "energies": np.array(energies, dtype=float),
            "forces": np.array(forces, dtype=float),
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
        d, i, j = min_bond_distance(positions, np.asarray(cell, float), nl.first_n, nl.j_b,
                                    nl.shift_bc)
        if d < dmin:
            i, j = sorted((int(i), int(j)))
            raise OverlappingAtomsError(
                f"atoms {i} and {j} overlap: distance {d:.4g} Angstrom < min_distance "
                f"{dmin:g} Angstrom")

    def get_virial(self, atoms=None) -> np.ndarray:
        """The 3x3 virial (eV), defined for any cell."""
        self.get_property("energy", atoms)
        return self.results["virial"].copy()
