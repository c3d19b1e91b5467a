"""The coarse tube of any structure (:class:`upscale.models.dcbr.model.DCBRModel`) as a
:class:`~upscale.experiments.protocols.Specimen` of the quasi-static periodic ramp.

The model is built from the atoms (registered lattice, defects found, atomistic regions
around them); the rows of the engine's state are its particles, or with regions its
non-slave particles then the free atoms. The protocol is the LAMMPS runners' and
:class:`~upscale.experiments.scenes.tube_atomistic.AtomisticTube`'s:

* zero-stress relaxation: the period L0 at which dE/dL_z = 0 (secant,
  :func:`upscale.engine.array_minimisers.zero_cell_force`), the rows scaled along the axis about
  the tube's centre at each trial period;
* at strain eps the period is L0 (1 + eps), the rows mapped affinely along the axis, the
  energy minimised at fixed period, the failure rules applied (the coarse link rule, then
  the lattice-stability rule: :meth:`DCBRModel.break_bonds`) and the minimisation repeated
  until nothing breaks;
* stress sigma = (dE/dL_z) / (2 pi R t), t = 3.4 Å, R the mean radius of the rows after
  the zero-stress relaxation.

Each minimisation is the engine's L-BFGS-B over the rows and the sublattice shifts (the
model's internal field), ``ftol`` the protocol's; where it stalls (a pair of the atomistic
region at the step cutoff, whose energy jumps), QuickMin from there, up to three cycles, as
the LAMMPS runner falls back from CG to damped dynamics
(:class:`~upscale.engine.fallback.LBFGSDamped`).
"""
from __future__ import annotations

import math

import numpy as np

from upscale.constants import EV_PER_A3_IN_GPA, WALL_THICKNESS_A
from upscale.engine.fallback import LBFGSDamped
from upscale.engine.array_minimisers import zero_cell_force
from upscale.engine.simulation import Simulation
from upscale.experiments.protocols import Specimen

__all__ = ["CoarseTube"]

#: the damped-dynamics step, fs (the engine's time unit here: DCBRModel's masses are
#: amu / unit)
_DAMPED_DT = 1.0
#: largest force left by a minimisation that is accepted (eV/Å): a pair at the step cutoff
#: of the atomistic region has no equilibrium (its force jumps), as in the old tube
_HELD = 1e-4


class CoarseTube(Specimen):
    """``atoms`` coarse-grained at ``coarsening`` under a periodic quasi-static
    ``protocol`` (module docstring).

    Parameters
    ----------
    atoms : ase.Atoms
        one carbon tube periodic along z, with any defects.
    protocol : QuasiStatic
        the ramp (``periodic`` True; its ``ftol``, ``step``).
    coarsening : float
        particle spacing over the lattice constant (K >= 1).
    potential : str
        LAMMPS ``.tersoff`` file of the lattice and the atoms (step cutoff).
    """

    def __init__(self, atoms, protocol, coarsening: float, potential: str = "BNC.tersoff"):
        from upscale.models.dcbr.model import DCBRModel

        if not protocol.periodic:
            raise ValueError("the coarse tube runs the periodic quasi-static ramp; got a "
                             "finite (gripped) one: use model='atomistic' or 'lammps'")
        self.protocol = protocol
        self.ftol = float(protocol.ftol)
        self.model = DCBRModel(atoms, coarsening, potential=potential)
        if self.model.Lz is None:
            raise ValueError("a periodic protocol needs a structure periodic along z "
                             "(atoms.pbc[2] and a cell length); got an open one")
        self.sim = Simulation(self.model.system(), None, [self.model])
        self.axis = np.asarray(self.model.tube.axis, float)
        self.centre = np.asarray(self.model.tube.centre, float)
        self.minimisations = self.unconverged = 0
        self._relax_zero_stress()
        self.L0 = self.model.Lz
        self.x_rest = self.sim.state.y.copy()
        r = self.x_rest - self.centre
        radial = r - np.outer(r @ self.axis, self.axis)
        self.radius = float(np.linalg.norm(radial, axis=1).mean())
        self.area = 2 * math.pi * self.radius * WALL_THICKNESS_A

    # ------------------------------------------------------------------ relaxations
    def _scale(self, y_from, L_from: float, L_to: float) -> None:
        """Rows ``y_from`` at period ``L_from`` mapped affinely along the axis to ``L_to``
        (about the centre) into the state."""
        s = (y_from - self.centre) @ self.axis
        self.sim.state.y[...] = y_from + np.outer(s * (L_to / L_from - 1.0), self.axis)

    def _minimise(self) -> None:
        """L-BFGS-B (stopping also where an iteration no longer lowers the energy, relative
        1e-15: a pair held at the step cutoff); while a force above ``_HELD`` is left,
        QuickMin and L-BFGS-B again, at most three cycles
        (:class:`~upscale.engine.fallback.LBFGSDamped`, the LAMMPS runner's)."""
        m = LBFGSDamped(self.ftol, accept=max(_HELD, self.ftol), dt=_DAMPED_DT, maxls=20,
                        energy_rtol=1e-15)
        r = self.sim.minimise(m)
        self.minimisations += m.runs
        self.unconverged += not r.converged

    def _relax_zero_stress(self) -> None:
        y0, L_start = self.sim.state.y.copy(), float(self.model.Lz)

        def relax(L):
            self.model.set_cell(L)
            self._scale(y0, L_start, L)
            self._minimise()
            return None, self.model.cell_force(self.sim.state)

        _, L, _ = zero_cell_force(relax, L_start, tol=1e-4 * self.model.n / 100)
        relax(L)

    # ------------------------------------------------------------------ the Specimen
    def apply(self, value: float) -> None:
        L = self.L0 * (1.0 + value)
        self._scale(self.sim.state.y.copy(), self.model.Lz, L)
        self.model.set_cell(L)
        k = int(round(abs(value) / self.protocol.step))
        self.sim.state.y += self.protocol.perturbation(k, np.ones(self.model.n, bool))

    def relax(self) -> int:
        """Minimise, apply the failure rules, again until nothing breaks; the links
        broken."""
        broken = 0
        for _ in range(4 * self.model.tube.N + 10):
            self._minimise()
            nb = self.model.break_bonds(self.sim.state)
            broken += nb
            if nb == 0:
                break
        return broken

    def record(self) -> dict:
        st = self.sim.state
        s = self.model.cell_force(st) / self.area * EV_PER_A3_IN_GPA
        return {"response": float(s), "energy_eV": float(self.model.energy(st)),
                "Lz_A": float(self.model.Lz),
                "broken_links": int((~st.extra["dcbr.intact"]).sum())}

    def damage(self) -> np.ndarray:
        """(n,) per row: particles by their links, free atoms by their bonds."""
        return np.asarray(self.model.particle_damage(self.sim.state), float)
