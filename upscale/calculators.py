"""ASE calculators of the coarse models.

:class:`DCBRCalculator` wraps :class:`upscale.models.dcbr.DCBRTube`: the ``Atoms`` are the
coarse particles (one per lattice patch, mass = its share of atoms x 12.011 amu), periodic
along z with the cell length as the tube length. At every new configuration the sublattice
shifts (internal, massless degrees of freedom) are relaxed at fixed particle positions,
so the energy is the DCBR energy and the forces are its exact negative gradient (envelope
theorem). Units: eV, Å. The cell is rank-deficient in x, y (a tube in vacuum), so no
stress is offered; the axial force is ``calc.axial_force`` (eV/Å, dE/dLz).

    model = DCBRTube(10, 10, 100.0, coarsening=2)
    atoms = dcbr_atoms(model)
    atoms.calc = DCBRCalculator(model)
    atoms.get_potential_energy(), atoms.get_forces()
"""
from __future__ import annotations

import numpy as np
from ase import Atoms
from ase.calculators.calculator import Calculator, all_changes
from scipy.optimize import minimize

from upscale.constants import CARBON_MASS_AMU

__all__ = ["DCBRCalculator", "dcbr_atoms"]

CARBON_MASS = CARBON_MASS_AMU  # amu


def dcbr_atoms(model, vacuum: float = 10.0) -> Atoms:
    """The coarse particles of ``model`` as ASE Atoms (axis at the box centre, pbc along z)."""
    side = 2 * (model.lattice.R0 + vacuum)
    atoms = Atoms("C" * model.N, positions=model.x0 + [side / 2, side / 2, 0.0],
                  cell=[side, side, model.L], pbc=(False, False, True))
    atoms.set_masses(model.natoms_n * CARBON_MASS)
    atoms.info["axis_xy"] = (side / 2, side / 2)
    atoms.info["atoms_per_particle"] = float(model.natoms_n[0])
    return atoms


class DCBRCalculator(Calculator):
    """ASE calculator of the DCBR tube (see module docstring).

    Parameters
    ----------
    model : upscale.models.dcbr.DCBRTube
    gtol : float
        Convergence of the shift relaxation, max |dE/d shift| in eV/Å.
    """

    implemented_properties = ["energy", "free_energy", "forces", "energies"]
    default_parameters: dict = {}

    def __init__(self, model, gtol: float = 1e-8, **kwargs):
        super().__init__(**kwargs)
        self.model = model
        self.gtol = gtol
        self.delta = np.zeros((model.N, 3))
        self.axial_force = None

    def calculate(self, atoms=None, properties=("energy",), system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        m = self.model
        if len(self.atoms) != m.N:
            raise ValueError(f"the atoms have {len(self.atoms)} particles, the DCBR model {m.N}")
        cx, cy = self.atoms.info.get("axis_xy", (0.0, 0.0))
        y = self.atoms.get_positions() - [cx, cy, 0.0]
        Lz = float(self.atoms.cell[2, 2])
        N = m.N

        def fun(dv):
            E, gy, gd, gL = m.energy_and_gradient(y, dv.reshape(N, 3), Lz)
            return E, gd.ravel()

        if m.relax_shift:
            res = minimize(fun, self.delta.ravel(), jac=True, method="L-BFGS-B",
                           options={"gtol": self.gtol, "ftol": 1e-16, "maxiter": 2000})
            self.delta = res.x.reshape(N, 3)
        E, gy, gd, gL = m.energy_and_gradient(y, self.delta, Lz)
        self.axial_force = float(gL)
        self.results["energy"] = float(E)
        self.results["free_energy"] = float(E)
        self.results["forces"] = -gy.copy()
        self.results["energies"] = m.natoms_n * (m._e_n - m.e0)
