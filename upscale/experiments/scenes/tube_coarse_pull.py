"""Dynamic tension of any open tube on the coarse model :class:`~upscale.models.dcbr.model.
DCBRModel`: the LAMMPS references' dynamic protocol, from an ``ase.Atoms`` with any defects.

The port of the validated dynamic coarse tube (``dcbr_dynamic.dynamic_tension`` on
``DCBRDefectTube``, its pristine scene with atomistic bands across the grip planes) to the
new model, step for step (seed 004 sec. 5.3.1; the old module docstring gives the reasons):

1. the tube is opened (``pbc`` off along its axis: a finite tube of the same atoms) and
   built as ``DCBRModel(atoms, K, select=bands, shifts=...)``: atomistic bands of half-width
   ``r_atomistic`` across both grip planes, ``grip`` Å inside the end atoms along the
   registered axis, and the automatic regions at every defect the model finds;
2. the open tube is minimised once (shifts massless, the engine's L-BFGS on the rows and
   the shifts, the grips' two lateral components held: the grips hold them during the pull
   too); the planes then follow the band atoms within 3 Å of each, and the grips hold the
   particle rows and band atoms beyond them (LAMMPS picks its grip atoms after its set-up);
3. the pull: the grips move rigidly apart at ``speed`` Å/ps each along the axis
   (:class:`~upscale.engine.conditions.Grip`, their particles' sublattice shifts held with
   them, :class:`~upscale.engine.fields.FixedField`), the free rows start on the axial
   velocity ramp between the planes plus Gaussian velocities at ``temperature`` (no net
   momentum; the shifts' velocities from their reduced mass, a quarter of the row's), and
   run under velocity Verlet of ``dt`` fs inside a Nose-Hoover thermostat (damping
   ``tdamp`` fs) on the x, y velocities of the free rows and the free shifts, with the
   old scene's degrees of freedom ndf = 2 n_free_rows + 3 n_free_shifts;
4. sampling: after every step the grips' mean axial reaction, F = (-R_top + R_bottom) / 2
   (eV/Å, from the unzeroed forces of the prescribed rows), is accumulated; every
   ``sample`` steps the block's mean stress F / (2 pi R t) (GPa, t = 3.4 Å, R the mean atom
   radius after the set-up) belongs to the block's middle strain 2 v (step - sample/2) dt /
   gauge (gauge = initial distance between the planes); the coarse link rule
   (:meth:`DCBRModel.break_bonds`) is applied and the forces recomputed; the run stops by
   the protocol's stop rule (:class:`~upscale.experiments.protocols.StopRule`: failure at
   the first drop of 5 %, stop below 20 % of the peak after it) or at ``max_strain``;
5. region growth (``grow``, a fraction of the link rule, :func:`upscale.models.dcbr.switch.
   flagged_particles`): at a sample where a coarse link's bond exceeds ``grow`` x the
   cutoff, its particles are replaced by their atoms (:func:`upscale.models.dcbr.switch.
   switch`) and the run continues on a new simulation from the same step and time (grips,
   thermostat variable kept); the region travels in the state's extras
   (``dcbr.inside``), so a checkpoint written after a switch resumes on the grown model.

The time loop is :func:`upscale.experiments.pull.pull`: checkpoints with exact resume (the
model's links, shifts and region in ``state.extra``, the records in the pull's own extra).

Ghost forces: the coupling's interfaces (bands, defects' regions, the atomistic ends the
model keeps at an open tube's edges) carry the ghost-force dead load of the pristine twin
(:meth:`upscale.models.dcbr.ghost.GhostLoad.prepare_stretch`) at the grips' strain, lam_z =
lam_z0 (1 + strain), refreshed every sample (a dead load in between), the grips' rows
keeping the set-up stretch's load: the old scene's ``ghost="grips"`` with
``_hold_grip_ghost``. The scene writes it to the state's extras (``dcbr.ghost``,
``dcbr.ghost_hold``), which the model follows, so a checkpoint carries it. (The old scene's
default, ``ghost="local"``, took each side's stretch from its interface particles; the two
agree up to failure, when the gauge is uniform.)

Not the old scene's (stated, issue 51): the clamped coarse grips of the old vacancy scene
(``DCBRDefectTube.clamp_grips``, ``_balanced_grip_weights``): the grips here are always
atomistic bands (a defect tube keeps its defects' regions besides).

Units: eV, Å, fs, amu (masses amu / ``ACC_EV_A_AMU_IN_A_FS2``); stress GPa.
"""
from __future__ import annotations

import math
import time

import numpy as np

from upscale.constants import EV_PER_A3_IN_GPA, K_B_EV, WALL_THICKNESS_A
from upscale.experiments.pull import PullSpecimen, pull

__all__ = ["coarse_dynamic_tension", "open_tube", "setup_open_tube", "CoarsePull"]

FIELD = "dcbr.delta"
#: the extras the model's ghost-force load follows (:meth:`DCBRModel._sync_ghost`)
GHOST, GHOST_HOLD = "dcbr.ghost", "dcbr.ghost_hold"


def open_tube(atoms):
    """A copy of ``atoms`` without periodicity (a finite tube of the same atoms, the
    periodic images' bonds cut), positions wrapped into the cell along a periodic axis."""
    a = atoms.copy()
    if a.pbc.any():
        a.wrap()
    a.pbc = False
    return a


def _axial(model, x):
    """Axial coordinate (Å) of positions ``x`` (n, 3) along the model's registered axis."""
    t = model.tube
    return (np.asarray(x) - t.centre) @ t.axis


def _bands(atoms, grip, r_atomistic, chirality=None):
    """(select mask (K,), planes (zb, zt) on the registered axis, axis, centre)."""
    from upscale.models.dcbr.structure import register  # noqa: PLC0415

    reg = register(atoms, chirality).tubes[0]
    s = (atoms.positions - reg.centre) @ reg.axis
    zb, zt = float(s.min()) + grip, float(s.max()) - grip
    if not (grip > 0 and zb + r_atomistic < zt - r_atomistic):
        raise ValueError(f"grip={grip} Å, r_atomistic={r_atomistic} Å in a "
                         f"{s.max() - s.min():.1f} Å tube; valid: grip > 0 and the two bands "
                         "(grip + r_atomistic from each end) not overlapping")
    return (np.abs(s - zb) < r_atomistic) | (np.abs(s - zt) < r_atomistic), (zb, zt)


def zero_stress_lattice(cell, P_f):
    """(lam_t, lam_z, shift (3,)) of the unstressed uniform lattice of a particle's cell
    (gam = 0; all five minimise the energy per atom; Newton's method, gtol 1e-12 eV per
    atom, BFGS if it fails): the old scene's ``uniform_lattice(None)``."""
    from upscale.engine.array_minimisers import bfgs, newton  # noqa: PLC0415

    def fun(v):
        e, g = cell.energy(np.array([v[0], 0.0, v[1], v[2], v[3], v[4]]), P_f)
        return e, np.array([g[0], g[2], g[3], g[4], g[5]])

    x0 = np.array([1.0, 1.0, 0.0, 0.0, 0.0])
    r = newton(fun, x0, gtol=1e-12)
    if not r.converged:
        r = bfgs(fun, x0, gtol=1e-12, max_iter=500)
    return float(r.x[0]), float(r.x[1]), r.x[2:].copy()


def _uniform_rows(model, lam_t, lam_z):
    """The model's reference rows mapped uniformly (n, 3): radial lam_t, axial lam_z about
    the tube's centre."""
    t = model.tube
    rel = model.x0 - t.centre
    s = rel @ t.axis
    return t.centre + lam_t * (rel - np.outer(s, t.axis)) + np.outer(lam_z * s, t.axis)


def _grip_masks(model, y, zb, zt):
    """(bottom, top) (n,) bool: the rows beyond the planes (axial coordinate)."""
    s = _axial(model, y)
    return s < zb, s > zt


def setup_open_tube(atoms, coarsening: float = 2.0, *, grip: float = 50.0,
                    r_atomistic: float = 8.0, gtol: float = 1e-4, **model_kw) -> dict:
    """Steps 1-2 of the module docstring. Returns ``atoms`` (the open tube), ``select``
    (the bands), ``y`` (n, 3) and ``delta`` (N, 3) of the relaxed set-up, ``zb`` < ``zt``
    (the planes after it, axial Å), ``gauge`` = zt - zb, ``bottom``/``top`` (n,) masks,
    ``R`` (mean atom radius, Å), ``area`` (2 pi R t, Å^2), ``model_kw``, ``setup``
    (the minimiser's report)."""
    from upscale.engine.conditions import Fixed, Region  # noqa: PLC0415
    from upscale.engine.minimisers import LBFGS  # noqa: PLC0415
    from upscale.engine.simulation import Simulation  # noqa: PLC0415
    from upscale.engine.system import ParticleSystem  # noqa: PLC0415
    from upscale.models.dcbr.model import DCBRModel  # noqa: PLC0415

    a = open_tube(atoms)
    select, _ = _bands(a, grip, r_atomistic, model_kw.get("chirality"))
    kw = dict(model_kw, r_atomistic=r_atomistic)
    m = DCBRModel(a, coarsening, select=select, shifts="relaxed", failure=False,
                  stability=False, **{k: v for k, v in kw.items()
                                      if k not in ("shifts", "failure", "stability")})
    # step 1 of the old scene: the zero-stress uniform lattice (the planes ``grip`` inside
    # its end atoms), then the open tube minimised with the grips' x, y held
    lam_t, lam_z, shift = zero_stress_lattice(m.tube.cell, m.tube.P_f)
    y0 = _uniform_rows(m, lam_t, lam_z)
    s_at = lam_z * ((a.positions - m.tube.centre) @ m.tube.axis)
    zb, zt = float(s_at.min()) + grip, float(s_at.max()) - grip
    bottom, top = _grip_masks(m, y0, zb, zt)
    if not (bottom.any() and top.any()):
        raise ValueError(f"grip={grip} Å holds no particle or atom; valid: a longer grip")
    body = ParticleSystem(y0, 1.0, density=m.masses(), spacing=m.tube.bond, units="atomic")
    sim = Simulation(body, None, [m], [Fixed(Region("grips", bottom | top), components=(0, 1))])
    sim.state.extra[FIELD][...] = shift
    ghost = m.stretch_ghost
    if ghost:  # the ghost-force dead load at the set-up stretch (the old prepare_step(L0))
        sim.state.extra[GHOST] = np.array([lam_z, lam_z])
    s0 = _axial(m, y0)
    r = sim.minimise(LBFGS(ftol=gtol, max_iter=5000))
    y = sim.state.y.copy()
    d = np.array(sim.state.extra[FIELD], copy=True)
    nd = _nd(m)
    s1 = _axial(m, y)
    atom = np.arange(len(y)) >= nd
    near_b, near_t = atom & (np.abs(s0 - zb) < 3.0), atom & (np.abs(s0 - zt) < 3.0)
    zb += float(np.mean(s1[near_b] - s0[near_b]))
    zt += float(np.mean(s1[near_t] - s0[near_t]))
    bottom, top = _grip_masks(m, y, zb, zt)
    xa = m.atom_positions(sim.state)
    t = m.tube
    rel = xa - t.centre
    R = float(np.mean(np.linalg.norm(rel - np.outer(rel @ t.axis, t.axis), axis=1)))
    return {"atoms": a, "select": select, "y": y, "delta": d, "zb": zb, "zt": zt,
            "gauge": float(zt - zb), "bottom": bottom, "top": top, "R": R,
            "area": 2 * math.pi * R * WALL_THICKNESS_A, "model_kw": kw,
            "coarsening": float(coarsening), "lam_z0": lam_z, "ghost": ghost,
            "setup": {"converged": bool(getattr(r, "converged", True)),
                      "iterations": int(getattr(r, "iterations", -1))}}


def _nd(model) -> int:
    """Particle rows of the model's state."""
    c = model.coupling
    return model.tube.N if c is None else len(c.dof_idx)


class CoarsePull(PullSpecimen):
    """The open tube of :func:`coarse_dynamic_tension` as a :class:`~upscale.experiments.
    pull.PullSpecimen` (module docstring, steps 3-5)."""

    def __init__(self, st: dict, *, speed, dt, sample, temperature, tdamp, seed, grow,
                 max_strain):
        self.st = st
        self.vz = 1e-3 * float(speed)  # Å/fs
        self.dt, self.sample_every = float(dt), int(sample)
        self.T, self.tdamp, self.seed = float(temperature), float(tdamp), int(seed)
        self.grow = grow
        self.rec = {"strains": [], "stresses": [], "times": [], "blk": [], "broken": [],
                    "switches": [], "free_atoms": [], "first_damage": None}
        self.max_steps = int(np.ceil(max_strain * st["gauge"] / (2 * self.vz * self.dt))) \
            + 2 * self.sample_every
        self._pending = None
        self._first = m = self._model(None)
        self.build(m, self._start(m))

    # ------------------------------------------------------------------ set-up
    def _model(self, inside):
        from upscale.models.dcbr.model import DCBRModel  # noqa: PLC0415

        st = self.st
        kw = {k: v for k, v in st["model_kw"].items() if k not in ("shifts", "failure",
                                                                 "stability")}
        return DCBRModel(st["atoms"], st["coarsening"], select=st["select"],
                         shifts="inertial", failure=False, stability=False,
                         atomistic_particles=inside, **kw)

    def _start(self, m):
        """The initial State: the set-up rows, the shift field, the velocity ramp and the
        thermal velocities (module docstring, step 3)."""
        from upscale.engine.state import State  # noqa: PLC0415

        st = self.st
        y = st["y"].copy()
        nd = _nd(m)
        dof = np.arange(m.tube.N) if m.coupling is None else m.coupling.dof_idx
        state = State.reference(y, 0)
        m.init_state(state)
        state.extra[FIELD] = np.array(st["delta"], copy=True)
        bottom, top = st["bottom"], st["top"]
        grips = bottom | top
        ax = m.tube.axis
        s = _axial(m, y)
        zc, half = 0.5 * (st["zb"] + st["zt"]), 0.5 * st["gauge"]
        v = np.outer(np.clip((s - zc) / half, -1, 1) * self.vz, ax)
        v[bottom] = -self.vz * ax
        v[top] = self.vz * ax
        mass = m.masses()
        fd = np.zeros((m.n, 3))
        fd[:nd] = st["delta"][dof]
        fv = np.zeros((m.n, 3))
        if self.T > 0:
            rng = np.random.default_rng(self.seed)
            mv = ~grips
            sd = np.sqrt(K_B_EV * self.T / mass[mv])
            vt = rng.standard_normal((int(mv.sum()), 3)) * sd[:, None]
            vt -= np.sum(mass[mv, None] * vt, axis=0) / mass[mv].sum()
            v[mv] += vt
            sdd = np.sqrt(K_B_EV * self.T / (0.25 * mass[:nd]))
            fv[:nd] = rng.standard_normal((nd, 3)) * sdd[:, None]
            fv[:nd][grips[:nd]] = 0.0
        state.v[...] = v
        self._store_ghost(state, 0, grips)
        state.fields = {FIELD: fd}
        state.field_v = {FIELD: fv}
        return state

    def _store_ghost(self, state, step, grips) -> None:
        """The ghost-force load the model is to apply (its extras): at the grips' strain of
        ``step``, the grips' rows ``grips`` (n,) at the set-up stretch (module docstring)."""
        st = self.st
        if not st["ghost"]:
            return
        lam0 = st["lam_z0"]
        state.extra[GHOST] = np.array([lam0 * (1.0 + self._strain(step)), lam0])
        state.extra[GHOST_HOLD] = np.asarray(grips, bool).copy()

    def build(self, m, state, xi=0.0):
        """A simulation of model ``m`` from ``state`` (its reference rows the set-up's)."""
        from upscale.engine.conditions import Grip, Region  # noqa: PLC0415
        from upscale.engine.fields import FixedField  # noqa: PLC0415
        from upscale.engine.integrators import VelocityVerlet  # noqa: PLC0415
        from upscale.engine.simulation import Simulation  # noqa: PLC0415
        from upscale.engine.system import ParticleSystem  # noqa: PLC0415
        from upscale.engine.thermostats import NoseHoover  # noqa: PLC0415

        nd, ax = _nd(m), m.tube.axis
        x_ref = np.array(state.x0, copy=True)
        bottom, top = _grip_masks(m, x_ref, self.st["zb"], self.st["zt"])
        grips = bottom | top
        body = ParticleSystem(x_ref, 1.0, density=m.masses(), spacing=m.tube.bond,
                              units="atomic")
        held = np.zeros(m.n, bool)
        held[:nd] = grips[:nd]
        conds = [Grip(Region("grip bottom", bottom), velocity=-self.vz * ax, record_every=0),
                 Grip(Region("grip top", top), velocity=self.vz * ax, record_every=0)]
        if held.any():  # (grips of atoms only hold no shift)
            conds.append(FixedField(Region("grip shifts", held), FIELD, (0, 1, 2), hold=True))
        ndf = 2 * int((~grips).sum()) + 3 * int((~held[:nd]).sum())
        th = None
        if self.T > 0:
            th = NoseHoover(self.T, self.tdamp, components=(0, 1), fields=(FIELD,), ndf=ndf,
                            k_B=K_B_EV)
            th.xi = float(xi)
        sim = Simulation(body, None, [m], conds, VelocityVerlet(self.dt, force=True,
                                                                 thermostat=th),
                         state=state)
        self.model, self.simulation = m, sim
        self.bottom, self.top = bottom, top
        return sim

    # ------------------------------------------------------------------ PullSpecimen
    def read(self, sim) -> None:
        R = sim.reactions @ self.model.tube.axis
        self.rec["blk"].append(0.5 * (-R[self.top].sum() + R[self.bottom].sum()))

    def _strain(self, step) -> float:
        return 2 * self.vz * step * self.dt / self.st["gauge"]

    def sample(self, sim) -> dict:
        from upscale.models.dcbr.switch import flagged_particles  # noqa: PLC0415

        rec, s_ = self.rec, sim.state
        step = int(s_.step)
        stress = float(np.mean(rec["blk"])) / self.st["area"] * EV_PER_A3_IN_GPA
        rec["blk"] = []
        rec["strains"].append(self._strain(step - 0.5 * self.sample_every))
        rec["stresses"].append(stress)
        rec["times"].append(step * self.dt * 1e-3)
        nb = self.model.break_bonds(s_)
        rec["broken"].append(int(nb))
        self._store_ghost(s_, step, self.bottom | self.top)  # (refreshed every sample)
        sim.update_forces()
        rec["free_atoms"].append(0 if self.model.coupling is None else
                                 int(self.model.coupling.nf))
        if rec["first_damage"] is None:
            rec["first_damage"] = self._damage_at(s_, rec["strains"][-1])
        self._pending = None
        if self.grow is not None:
            flag = flagged_particles(self.model, s_, self.grow)
            c = self.model.coupling
            inside = np.zeros_like(flag) if c is None else c.inside
            if flag.any() and not (inside | flag).all():  # (never the whole tube)
                self._pending = flag
        return {"load": rec["strains"][-1], "response": stress}

    def load(self, sim) -> float:
        return self._strain(int(sim.state.step))

    def damage(self, state) -> np.ndarray:
        """(n,) damage per row against the pull's start: a particle's link damage
        (:meth:`DCBRModel.particle_damage`), a free atom's 1 - (bonds left) / (bonds < 2.0 Å
        at the set-up state, broken beyond 2.1 Å) (an input defect's stretched bonds, which
        the set-up relaxes, are not damage)."""
        from upscale.models.tersoff import atom_damage, initial_bonds  # noqa: PLC0415

        m = self.model
        nd = _nd(m)
        if getattr(self, "_bonds0", (None,))[0] is not m:
            self._bonds0 = (m, initial_bonds(state.x0[nd:]))
        return np.r_[m.particle_damage(state)[:nd], atom_damage(state.y[nd:], self._bonds0[1])]

    def where(self, state, hit, strain=None):
        """Where the rows ``hit`` (n,) bool are: their count and axial positions (Å, min,
        median, max, set-up frame), and the defect (not an edge) nearest their median
        along the axis (kind, axial position, axial distance; the crack of a tube that
        broke is a ring, whose centroid is on the axis)."""
        m = self.model
        z = _axial(m, state.y[hit])
        out = {"strain": None if strain is None else float(strain), "rows": int(hit.sum()),
               "z_A": [float(z.min()), float(np.median(z)), float(z.max())]}
        cand = [d for d in m.defects if d.kind != "edge"]
        if cand:
            lam0 = self.st["lam_z0"]
            t = m.tube
            zd = [lam0 * float((d.position - t.centre) @ t.axis) for d in cand]
            k = int(np.argmin(np.abs(np.array(zd) - np.median(z))))
            out.update(nearest_defect=cand[k].kind, defect_z_A=zd[k],
                       distance_A=float(abs(zd[k] - np.median(z))))
        return out

    def _damage_at(self, state, strain):
        """The first damage (None if none yet): :meth:`where` of the damaged rows."""
        hit = self.damage(state) > 0
        return self.where(state, hit, strain) if hit.any() else None

    def wants_switch(self) -> bool:
        return self._pending is not None

    def switch(self) -> None:
        """The flagged particles' atoms made free (:func:`upscale.models.dcbr.switch.switch`)
        and a new simulation from the same step, time and thermostat variable."""
        from upscale.models.dcbr.switch import switch  # noqa: PLC0415

        sim = self.simulation
        th = sim.integrator.thermostat
        for k in (GHOST, GHOST_HOLD):  # (the old rows' mask does not fit the new rows)
            sim.state.extra.pop(k, None)
        new, st2, log = switch(self.model, sim.state, self._pending)
        st2.x0 = self._reference_rows(new)
        b, t = _grip_masks(new, st2.x0, self.st["zb"], self.st["zt"])
        self._store_ghost(st2, int(st2.step), b | t)
        self.rec["switches"].append({"step": int(st2.step), **log.as_dict()})
        self._pending = None
        self.build(new, st2, 0.0 if th is None else th.xi)

    def _reference_rows(self, m):
        """The set-up state of model ``m``'s rows (the grips' displacements count from it):
        the particle rows from the set-up, a new atom where the first model's maps put it
        at the set-up (:meth:`DCBRModel.atom_positions`)."""
        from upscale.engine.state import State  # noqa: PLC0415

        first = self._first
        s0 = State.reference(self.st["y"].copy(), 0)
        first.init_state(s0)
        s0.extra[FIELD] = np.array(self.st["delta"], copy=True)
        xa = first.atom_positions(s0)
        yp = first.coupling.particle_positions(self.st["y"], first.Lz)
        c = m.coupling
        return np.vstack([yp[c.dof_idx], xa[c.free_idx]])

    def bookkeeping(self) -> dict:
        return self.rec

    def restore(self, book: dict) -> None:
        self.rec.update(book)

    def prepare_resume(self, path) -> None:
        """The checkpoint's region (``dcbr.inside``): a model grown to it, if it grew."""
        with np.load(path) as z:
            key = "extra__dcbr.inside"
            inside = np.array(z[key]) if key in z.files else None
        first = self._first
        if inside is None or first.coupling is None or \
                np.array_equal(inside, first.coupling.inside):
            return
        m = self._model(inside)
        from upscale.engine.state import State  # noqa: PLC0415

        state = State.reference(self._reference_rows(m), 0)
        self.build(m, state)


def coarse_dynamic_tension(atoms, coarsening: float = 2.0, *, grip: float = 50.0,
                           speed: float = 1.0, dt: float = 1.0, max_strain: float = 0.3,
                           sample: int = 100, temperature: float = 10.0, tdamp: float = 100.0,
                           seed: int = 12345, r_atomistic: float = 8.0, gtol: float = 1e-4,
                           grow: float | None = None, fit_max_strain: float = 0.02,
                           checkpoint=None, checkpoint_every: int = 500,
                           resume: bool = False, max_steps: int | None = None,
                           progress=None, output=None, setup: dict | None = None,
                           **model_kw) -> dict:
    """Dynamic tension of the open tube made of ``atoms`` (module docstring).

    Parameters
    ----------
    atoms : ase.Atoms
        One carbon tube with any defects (periodic or finite; opened here).
    coarsening : float
        K of :class:`~upscale.models.dcbr.model.DCBRModel`.
    grip, speed, dt, max_strain, sample, temperature, tdamp, seed :
        The dynamic protocol (Å, Å/ps per grip, fs, -, steps, K, fs, -), as the old scene's
        and the LAMMPS runner's.
    r_atomistic : float
        Half-width of the grip bands and radius of the defects' regions, Å.
    grow : float, optional
        Grow the region where a coarse link exceeds ``grow`` x its failure rule (e.g. 0.9).
    checkpoint : str or Path, optional
        A checkpoint every ``checkpoint_every`` steps; ``resume`` continues from it.
    max_steps : int, optional
        Stop after this many steps (a short run), else by the stop rule / ``max_strain``.
    setup : dict, optional
        The result of :func:`setup_open_tube` with the same arguments (reused).
    model_kw : the model's other keywords (hourglass, horizon_factor, chirality, ...).

    Returns
    -------
    dict
        ``curve`` (strain, stress_GPa, time_ps, links_broken, free_atoms), the curve metrics
        of :func:`upscale.analysis.stress.curve_metrics` (``strength_GPa``,
        ``youngs_modulus_TPa``, ``strain_at_peak``, ``failed``, ...), ``steps``,
        ``switches`` (one log per region growth), ``first_damage`` (the first sample with
        damage: strain, rows, their axial positions, the nearest defect and its axial
        distance), ``crack`` (the same of the rows with damage >= 0.5 at the end),
        ``gauge_length_A``, ``radius_relaxed_A``,
        ``area_A2``, ``grip_planes_A``, ``model`` (``DCBRModel.describe()`` at the end),
        ``positions`` (every atom at the end, (K, 3) Å), ``x0_rows`` (the rows' reference
        positions, (n, 3) Å), ``damage`` (per row, :meth:`CoarsePull.damage`),
        ``blowup_after_failure``, ``setup_s``, ``dynamics_s``.
    """
    from upscale.analysis.stress import curve_metrics  # noqa: PLC0415
    from upscale.engine.checkpoint import Checkpoint  # noqa: PLC0415
    from upscale.experiments.protocols import Dynamic  # noqa: PLC0415

    if not (grip > 0 and speed > 0 and dt > 0 and 0 < max_strain <= 1 and sample >= 1):
        raise ValueError(f"grip={grip}, speed={speed}, dt={dt}, max_strain={max_strain}, "
                         f"sample={sample}; valid: all > 0, max_strain <= 1, sample >= 1")
    if not (temperature >= 0 and tdamp > 0):
        raise ValueError(f"temperature={temperature!r} K, tdamp={tdamp!r} fs; valid: "
                         "temperature >= 0 (0: no thermostat), tdamp > 0")
    if grow is not None and not 0 < grow <= 1:
        raise ValueError(f"grow={grow!r}; valid: a fraction of the link rule in (0, 1]")
    t0 = time.perf_counter()
    st = setup if setup is not None else setup_open_tube(
        atoms, coarsening, grip=grip, r_atomistic=r_atomistic, gtol=gtol, **model_kw)
    t_setup = time.perf_counter() - t0
    spec = CoarsePull(st, speed=speed, dt=dt, sample=sample, temperature=temperature,
                      tdamp=tdamp, seed=seed, grow=grow, max_strain=max_strain)
    if max_steps is not None:
        spec.max_steps = int(max_steps)
    protocol = Dynamic(load="tension", speed=speed, grip=grip, dt=dt, sample_every=sample,
                       temperature=temperature, tau=tdamp * 1e-3, maximum=max_strain,
                       seed=seed)
    out = pull(spec, protocol, progress=progress, resume=resume, output=output,
               checkpoint=None if checkpoint is None else
               Checkpoint(checkpoint, int(checkpoint_every)),
               meta={"scene": "coarse dynamic tension"})
    rec, m, sim = spec.rec, spec.model, spec.simulation
    res = {"model": "dcbr", "protocol": "dynamic", "coarsening": float(coarsening),
           "steps": out["steps"], "gauge_length_A": st["gauge"], "radius_relaxed_A": st["R"],
           "area_A2": st["area"], "grip_planes_A": [st["zb"], st["zt"]], "dt_fs": dt,
           "speed_A_per_ps": speed, "temperature_K": temperature, "seed": seed,
           "curve": {"strain": rec["strains"], "stress_GPa": rec["stresses"],
                     "time_ps": rec["times"], "links_broken": rec["broken"],
                     "free_atoms": rec["free_atoms"]},
           "first_damage": rec["first_damage"],
           "switches": rec["switches"], "blowup_after_failure": out["blowup_after_failure"],
           "setup_s": t_setup, "dynamics_s": out["dynamics_s"], "describe": m.describe()}
    try:  # (a short run may hold too few samples for the metrics)
        res.update(curve_metrics(rec["strains"], rec["stresses"],
                                 fit_max_strain=fit_max_strain, plateau_fraction=0.0))
    except ValueError as e:
        res["metrics"] = f"none: {e}"
    res["positions"] = m.atom_positions(sim.state)
    res["x0_rows"] = np.array(sim.state.x0, copy=True)
    res["damage"] = spec.damage(sim.state)
    cracked = res["damage"] >= 0.5
    res["crack"] = spec.where(sim.state, cracked) if cracked.any() else None
    return res
