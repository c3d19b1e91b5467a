"""The atomistic tube on the engine as a :class:`~upscale.experiments.protocols.Specimen`.

Every atom is a particle of :class:`upscale.models.tersoff.TersoffModel` (the project's
Tersoff, exact against LAMMPS ``pair_style tersoff``); relaxations are the engine's
L-BFGS-B with QuickMin as the fallback where L-BFGS-B stalls, as the LAMMPS runner falls
back from CG to damped dynamics (the step cutoff makes the energy jump when a bond crosses it,
which stops line searches).

Periodic tube (tension, compression): the zero-stress relaxation finds the cell length L0
at which dE/dL_z = 0 (secant, :func:`upscale.engine.array_minimisers.zero_cell_force`); at load
eps the cell is L0 (1 + eps), atoms are mapped affinely along z and relaxed at fixed cell.
Stress sigma = (dE/dL_z) / (2 pi R t), dE/dL_z = -W_zz / L_z (virial W), R the mean wall
radius after the zero-stress relaxation, t = 3.4 Å.

Finite tube (torsion): a periodic structure is first relaxed at zero stress as above, then
cut open at the cell boundary and relaxed again with every atom free (the LAMMPS runner's
set-up); the atoms within ``grip`` Å of each end are held
rigidly (engine ``Displacement`` conditions, so every minimiser keeps them); at twist phi the top grip is turned by phi about the
tube axis against the bottom one, the free atoms first turned by the affine fraction of the
increment. Torque T = sum over the top grip of (x F_y - y F_x) about the axis, eV (the
reaction the rest of the tube exerts on it, with the sign of the twist).
"""
from __future__ import annotations

import math

import numpy as np

from upscale.constants import CARBON_MASS_AMU, EV_PER_A3_IN_GPA, WALL_THICKNESS_A
from upscale.engine.fallback import LBFGSDamped
from upscale.engine.array_minimisers import zero_cell_force
from upscale.engine.simulation import Simulation
from upscale.engine.system import ParticleSystem
from upscale.experiments.protocols import Specimen
from upscale.experiments.pull import PullSpecimen
from upscale.models.tersoff import TersoffModel

__all__ = ["AtomisticTube", "AtomisticPull", "bond_pairs", "bond_damage"]

#: bonds at the start are pairs closer than this, Å; broken beyond BREAK_A (the references')
BOND_A, BREAK_A = 2.0, 2.1
#: the damped-dynamics step of the minimisations: 1 fs in the engine's time unit
#: sqrt(amu A^2 / eV) = 10.18 fs, the LAMMPS runner's
_DAMPED_DT = 1.0 / 10.1805
#: largest force a minimisation may leave, eV/Å (the LAMMPS runner's fmax tolerance)
_ACCEPT = 1e-4


class AtomisticTube(Specimen):
    """The atoms of ``atoms`` under ``protocol`` on the engine (module docstring).

    Parameters
    ----------
    atoms : ase.Atoms
        one carbon tube along z; periodic along z for a periodic protocol.
    protocol : QuasiStatic
        the loading protocol (its ``periodic``, ``grip``, ``ftol``).
    potential : str
        LAMMPS ``.tersoff`` file (default the references' ``BNC.tersoff``, step cutoff).
    """

    def __init__(self, atoms, protocol, potential: str = "BNC.tersoff"):
        self.protocol = protocol
        x = atoms.get_positions()
        self.axis = _axis_xy(x)
        self.periodic = bool(protocol.periodic)
        if self.periodic:
            if not atoms.pbc[2] or atoms.cell[2, 2] <= 0:
                raise ValueError("a periodic protocol needs a structure periodic along z "
                                 "(atoms.pbc[2] and a cell length); got an open one")
            self.L = float(atoms.cell[2, 2])
            model = TersoffModel(potential, period_z=self.L)
        else:
            model = TersoffModel(potential)
        self.ftol = float(protocol.ftol)
        self.value = 0.0
        self.minimisations = 0
        self.unconverged = 0
        if not self.periodic and atoms.pbc[2] and atoms.cell[2, 2] > 0:
            x = self._relaxed_and_cut(atoms, potential)
        self.model = model
        self.system = ParticleSystem(x, 1.0, CARBON_MASS_AMU, spacing=1.42, units="atomic")
        self.sim = Simulation(self.system, None, model)
        self._relax_zero_stress()
        self.x_rest = self.sim.state.y.copy()
        self.L0 = self.L if self.periodic else None
        # R: the periodic tube's after its zero-stress relaxation where the tube was cut from
        # one (the LAMMPS runners' stress area), else this tube's
        self.radius = getattr(self, "radius_periodic", None) or \
            float(np.mean(np.hypot(*(self.x_rest[:, :2] - self.axis).T)))
        self.area = 2 * math.pi * self.radius * WALL_THICKNESS_A
        self.bonds = bond_pairs(self.x_rest, self.L0)
        if not self.periodic:
            z = self.x_rest[:, 2]
            g = float(protocol.grip)
            if z.max() - z.min() <= 2 * g:
                raise ValueError(f"grip={g} Å at each end of a {z.max() - z.min():.1f} Å tube;"
                                 " valid: grips shorter than half the tube")
            self.bottom = z <= z.min() + g          # within grip Å, ends included
            self.top = z >= z.max() - g
            self.axis = _axis_xy(self.x_rest)
            self.z_lo, self.z_hi = z.min() + g, z.max() - g
            self._hold_grips()

    def _hold_grips(self) -> None:
        """Both grips held where they are now: displacement conditions whose values
        (``self._u_grip``, updated in place by a twist) the minimisers keep."""
        from upscale.engine.conditions import Displacement, Region

        y, x0 = self.sim.state.y, self.system.x0
        self._u_grip = {}
        conds = []
        for name, mask in (("bottom", self.bottom), ("top", self.top)):
            u = y[mask] - x0[mask]
            self._u_grip[name] = u
            conds.append(Displacement(Region(name, mask), u))
        self.sim = Simulation(self.system, None, self.model, conditions=conds,
                              state=self.sim.state)

    def _relaxed_and_cut(self, atoms, potential) -> np.ndarray:
        """Positions of the periodic tube relaxed at zero stress (a periodic specimen of
        the same atoms; the cell scaled about its centre), cut open at z = 0 of the input's
        frame (z wrapped into [0, L0)): the LAMMPS runner's cut, where the relaxed box
        [L/2 - L0/2, L/2 + L0/2] is wrapped the same way."""
        from upscale.experiments.protocols import QuasiStatic

        periodic = AtomisticTube(atoms, QuasiStatic(ftol=self.ftol), potential)
        self.minimisations += periodic.minimisations
        self.radius_periodic = periodic.radius
        y, L0 = periodic.x_rest.copy(), periodic.L0
        y[:, 2] = np.mod(y[:, 2], L0)
        y[y[:, 2] >= L0, 2] -= L0
        return y

    # ------------------------------------------------------------------ relaxations
    def _minimise(self) -> None:
        """L-BFGS-B; where it stalls (a bond held at the step cutoff), QuickMin from there
        and L-BFGS-B again, at most three cycles: the LAMMPS runner's minimisation
        (:class:`~upscale.engine.fallback.LBFGSDamped`)."""
        m = LBFGSDamped(self.ftol, accept=max(_ACCEPT, self.ftol), dt=_DAMPED_DT)
        r = self.sim.minimise(m)
        self.minimisations += m.runs
        self.unconverged += not r.converged

    def _relax_zero_stress(self) -> None:
        if not self.periodic:
            self._minimise()
            return
        x_start = self.sim.state.y.copy()
        L_start = self.L
        c = 0.5 * L_start

        def relax(L):  # scaled about the cell's centre, as LAMMPS's fix box/relax does
            self.model.set_period(L)
            self.sim.state.y[...] = x_start
            self.sim.state.y[:, 2] = c + (x_start[:, 2] - c) * (L / L_start)
            self._minimise()
            return None, self.cell_force()

        _, self.L, _ = zero_cell_force(relax, self.L, tol=1e-4 * len(x_start) / 100)
        relax(self.L)

    def cell_force(self) -> float:
        """dE/dL_z, eV/Å (periodic tube)."""
        return float(-self.model.virial(self.sim.state)[2, 2] / self.model.period_z)

    # ------------------------------------------------------------------ the Specimen
    def apply(self, value: float) -> None:
        if self.periodic:
            Lz = self.L0 * (1.0 + value)
            self.sim.state.y[:, 2] *= Lz / self.model.period_z
            self.model.set_period(Lz)
            free = np.ones(len(self.x_rest), bool)
        else:
            self._twist(math.radians(value - self.value))
            free = ~(self.bottom | self.top)
        k = int(round(abs(value) / self.protocol.step))
        self.sim.state.y += self.protocol.perturbation(k, free)
        self.value = float(value)

    def _twist(self, dphi: float) -> None:
        y = self.sim.state.y
        f = np.clip((self.x_rest[:, 2] - self.z_lo) / (self.z_hi - self.z_lo), 0.0, 1.0)
        f[self.bottom], f[self.top] = 0.0, 1.0
        c, s = np.cos(f * dphi), np.sin(f * dphi)
        dx, dy = y[:, 0] - self.axis[0], y[:, 1] - self.axis[1]
        y[:, 0] = self.axis[0] + c * dx - s * dy
        y[:, 1] = self.axis[1] + s * dx + c * dy
        x0 = self.system.x0
        self._u_grip["top"][...] = y[self.top] - x0[self.top]

    def relax(self) -> int:
        self._minimise()
        return 0  # bonds break through the potential itself

    def record(self) -> dict:
        st = self.sim.state
        if self.periodic:
            s = self.cell_force() / self.area * EV_PER_A3_IN_GPA
            return {"response": float(s), "energy_eV": self.model.energy(st),
                    "Lz_A": float(self.model.period_z),
                    "broken_bonds": int(self.broken().sum())}
        F = self.sim.forces()
        y = st.y[self.top]
        T = np.sum((y[:, 0] - self.axis[0]) * F[self.top, 1]
                   - (y[:, 1] - self.axis[1]) * F[self.top, 0])
        return {"response": float(-T), "energy_eV": self.model.energy(st),
                "broken_bonds": int(self.broken().sum())}

    def broken(self) -> np.ndarray:
        """(M,) bool: the bonds of the start longer than BREAK_A now."""
        return bond_lengths(self.sim.state.y, self.bonds, self.model.period_z) > BREAK_A

    def damage(self) -> np.ndarray:
        return bond_damage(self.sim.state.y, self.bonds, self.model.period_z)


def _axis_xy(x) -> np.ndarray:
    return np.asarray(x, dtype=float)[:, :2].mean(axis=0)


def bond_pairs(x, period_z=None) -> np.ndarray:
    """(M, 2): pairs i < j closer than BOND_A Å (minimum image along z with a period)."""
    from scipy.spatial import cKDTree

    x = np.asarray(x, dtype=float)
    if period_z:
        box = np.array([np.inf, np.inf, period_z])
        xs = x.copy()
        xs[:, 2] %= period_z
        tree = cKDTree(np.column_stack([xs[:, :2] - xs[:, :2].min(0), xs[:, 2]]),
                       boxsize=np.where(np.isinf(box), 1e12, box))
    else:
        tree = cKDTree(x)
    return tree.query_pairs(BOND_A, output_type="ndarray").astype(np.int64)


def bond_lengths(y, bonds, period_z=None) -> np.ndarray:
    d = y[bonds[:, 1]] - y[bonds[:, 0]]
    if period_z:
        d[:, 2] -= period_z * np.round(d[:, 2] / period_z)
    return np.linalg.norm(d, axis=1)


def bond_damage(y, bonds, period_z=None) -> np.ndarray:
    """(N,) mu = 1 - bonds left / bonds at the start (seed 004 eq. 5.16; a bond is broken
    beyond BREAK_A Å)."""
    n = len(y)
    ok = (bond_lengths(y, bonds, period_z) <= BREAK_A).astype(float)
    total = np.bincount(bonds.ravel(), minlength=n).astype(float)
    left = np.bincount(bonds[:, 0], ok, n) + np.bincount(bonds[:, 1], ok, n)
    return np.where(total > 0, 1.0 - left / np.maximum(total, 1.0), 0.0)


class AtomisticPull(PullSpecimen):
    """The atoms of ``atoms`` in a dynamic pull (:class:`~upscale.experiments.protocols.
    Dynamic`) on the engine: the LAMMPS runner's dynamic protocol
    (:mod:`upscale.experiments.lammps.dynamic`) step for step.

    Set-up as :class:`AtomisticTube`'s finite tube: the periodic tube relaxed at zero stress,
    cut open at the cell boundary and relaxed with every atom free. The grips hold the atoms
    within ``grip`` Å of the open tube's end atoms and move rigidly apart at ``speed`` Å/ps
    each; the free atoms start with Gaussian thermal velocities whose x, y temperature is
    exactly T (zero momentum) plus the linear axial ramp between the grip speeds, under a
    Nose-Hoover chain of 3 on their x and y velocities (LAMMPS's ``fix nvt`` with ``compute
    temp/partial 1 1 0``), velocity Verlet at ``dt`` fs. Every 10 steps the grips' reactions
    are read (tension = mean of the bottom grip's +z and the top one's -z reaction); a
    sample is their mean over its block, stress = tension / (2 pi R t), strain = grip
    separation change / initial grip-plane distance at the block's middle time. Units of the
    pull: eV, Å, fs (masses in eV fs^2 / Å^2).
    """

    def __init__(self, atoms, protocol, potential: str = "BNC.tersoff"):
        from upscale.constants import ACC_EV_A_AMU_IN_A_FS2, K_B_EV
        from upscale.engine.conditions import Grip, Region
        from upscale.engine.integrators import VelocityVerlet
        from upscale.engine.thermostats import NoseHooverChain
        from upscale.experiments.protocols import QuasiStatic

        if protocol.load != "tension":
            raise ValueError(f"load={protocol.load!r} in a dynamic pull of the atomistic tube; "
                             "valid: tension")
        opened = AtomisticTube(atoms, QuasiStatic(load="tension", periodic=False,
                                                  grip=protocol.grip), potential)
        self.protocol, self.radius, self.area = protocol, opened.radius, opened.area
        self.axis, self.minimisations = opened.axis, opened.minimisations
        x = opened.x_rest
        self.x_rest, self.bonds = x, bond_pairs(x)
        bottom, top = self.bottom, self.top = opened.bottom, opened.top
        self.z_lo, self.gauge = float(opened.z_lo), float(opened.z_hi - opened.z_lo)
        v = protocol.speed * 1e-3  # Å/fs
        system = ParticleSystem(x, 1.0, CARBON_MASS_AMU / ACC_EV_A_AMU_IN_A_FS2, spacing=1.42,
                                units="atomic")
        self.grips = (Grip(Region("grip bottom", bottom), velocity=(0.0, 0.0, -v), record_every=0),
                      Grip(Region("grip top", top), velocity=(0.0, 0.0, v), record_every=0))
        free = ~(bottom | top)
        T = protocol.temperature
        thermo = NoseHooverChain(T, 1e3 * protocol.tau, region=free, chain=3,
                                 components=(0, 1), k_B=K_B_EV) if T > 0 else None
        self.simulation = Simulation(system, None, opened.model, conditions=list(self.grips),
                                     integrator=VelocityVerlet(protocol.dt, force=True,
                                                               thermostat=thermo))
        self.simulation.state.v[...] = self._start_velocities(system.mass, free, bottom, top, v)
        self.max_steps = int(math.ceil(protocol.maximum * self.gauge / (2 * v * protocol.dt))) \
            + 2 * protocol.sample_every
        self.acc, self.reads = 0.0, 0

    def _start_velocities(self, mass, free, bottom, top, v) -> np.ndarray:
        from upscale.constants import K_B_EV

        T, x = self.protocol.temperature, self.x_rest
        vel = np.zeros_like(x)
        if T > 0:
            rng = np.random.default_rng(self.protocol.seed)
            vel[free] = rng.normal(size=(int(free.sum()), 3)) * np.sqrt(K_B_EV * T / mass[free])[:, None]
            vel[free] -= (mass[free, None] * vel[free]).sum(axis=0) / mass[free].sum()
            txy = (mass[free, None] * vel[free, :2] ** 2).sum() / (2 * free.sum() * K_B_EV)
            vel[free] *= math.sqrt(T / txy)
        vel[free, 2] += np.clip(-v + 2 * v * (x[free, 2] - self.z_lo) / self.gauge, -v, v)
        vel[bottom, 2], vel[top, 2] = -v, v
        return vel

    # ------------------------------------------------------------------ PullSpecimen
    def read(self, sim) -> None:
        if int(sim.state.step) % 10:
            return
        # the unzeroed forces on the grips' rows (kept in a checkpoint, so a resumed run
        # reads what the uninterrupted one read): tension = mean of the bottom grip's +z and
        # the top one's -z reaction
        R = sim.reactions
        self.acc += 0.5 * (R[self.bottom, 2].sum() - R[self.top, 2].sum())
        self.reads += 1

    def sample(self, sim) -> dict:
        p = self.protocol
        tmid = (int(sim.state.step) - 0.5 * p.sample_every) * p.dt
        s = self.acc / max(self.reads, 1) / self.area * EV_PER_A3_IN_GPA
        self.acc, self.reads = 0.0, 0
        return {"load": 2 * p.speed * 1e-3 * tmid / self.gauge, "response": float(s),
                "time_ps": tmid * 1e-3, "broken_bonds": int(self.broken().sum())}

    def load(self, sim) -> float:
        return 2 * self.protocol.speed * 1e-3 * int(sim.state.step) * self.protocol.dt / self.gauge

    def bookkeeping(self) -> dict:
        return {"acc": self.acc, "reads": self.reads}

    def restore(self, book: dict) -> None:
        self.acc, self.reads = float(book["acc"]), int(book["reads"])

    def broken(self) -> np.ndarray:
        return bond_lengths(self.simulation.state.y, self.bonds) > BREAK_A

    def damage(self) -> np.ndarray:
        return bond_damage(self.simulation.state.y, self.bonds)
