"""The :class:`Simulation`: a system, a pair family, models, conditions and an integrator.

It owns the loops the models do not: force assembly, conditions, time stepping,
blow-up detection, output, checkpoints and the progress bar. It does only what the models'
``needs`` and the outputs ask for: no bond checks unless a model has a failure criterion,
no strain energy unless an output asks, no triplets unless a model needs them.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from upscale.engine.checkpoint import Checkpoint, load_checkpoint
from upscale.engine.conditions import (BodyForce, Displacement, Force, Grip, Velocity,
                                       constrained_dofs)
from upscale.engine.families import FamilyRecipe, damage
from upscale.engine.integrators import BlowUp, VelocityVerlet
from upscale.engine.parallel.comm import Refused, world
from upscale.engine.state import State

__all__ = ["Simulation"]


class Simulation:
    """Tie a body, its family, models, conditions and an integrator together.

    Parameters
    ----------
    system : ParticleSystem
    family : Family, FamilyRecipe or None
        Pair family shared by the models (None if no model needs pairs). A
        :class:`~upscale.engine.families.FamilyRecipe` is built here (on several MPI
        ranks: each rank builds the rows of its part only), with its initial bond state
        when ``state`` is None.
    models : Model or sequence of Model
        Each is ``prepare``-d here. Their force contributions add up.
    conditions : sequence of Condition
    integrator : VelocityVerlet, optional
        Default ``VelocityVerlet()`` (0.8 of the stable estimate).
    state : State, optional
        Initial state (default: the reference state at rest).
    damage_weights : {"count", "volume"}
        How :meth:`damage` weighs bonds (seed 004 counts them; LAMMPS weighs by volume).

    Several MPI ranks (started by ``mpiexec``/``srun``): the simulation keeps this rank's
    part of the body (:func:`upscale.engine.parallel.localize`, ``self.part``) and the
    models are prepared on it alone. ``state``, ``damage()``, ``F`` are then per local
    particle (owned + halo, in global order); :meth:`gather` gives the whole body's
    array, :meth:`energy`, :meth:`kinetic_energy`, :meth:`broken_bonds` and the blow-up
    guard sum over the ranks (collective: every rank calls them).
    """

    def __init__(self, system, family=None, models=(), conditions=(), integrator=None,
                 state: State | None = None, *, damage_weights: str = "count"):
        if hasattr(models, "step_force"):  # one model (the engine knows models by contract)
            models = [models]
        self.system = system
        self.family = family
        self.models = list(models)
        if not self.models:
            raise ValueError("a simulation needs at least one model")
        self.conditions = list(conditions)
        self.integrator = integrator if integrator is not None else VelocityVerlet()
        self.damage_weights = damage_weights
        self.part = None  # the split over MPI ranks (upscale.engine.parallel), None on one
        comm = world()
        if comm.size == 1 and isinstance(family, FamilyRecipe):  # built here, whole
            recipe, family = family, family.build()
            if state is None:
                state = State.reference(system.x0, family.nb)
                state.intact[...] = recipe.initial_intact(family.offsets, family.neighbors)
            self.family = family
        if comm.size > 1:  # this rank's part of the body; the models never see the rest
            from upscale.engine.parallel.partition import localize

            system, family, conditions, state, self.part = localize(
                comm, system, family, self.models, conditions, state, self.integrator)
            self.system, self.family, self.conditions = system, family, list(conditions)
        needs = [m.needs for m in self.models]
        if any(n.pairs for n in needs) and family is None:
            raise ValueError("a model needs the pair family: pass family=build_family(system, horizon)")
        triplets = quadruplets = None
        if any(n.triplets for n in needs) or any(n.quadruplets for n in needs):
            from upscale.engine import multibody

            if any(n.triplets for n in needs):
                triplets = multibody.build_triplets(system.x0, family)
            if any(n.quadruplets for n in needs):
                quadruplets = multibody.build_quadruplets(system.x0, family)
        self.triplets, self.quadruplets = triplets, quadruplets
        for m in self.models:
            m.prepare(system, family, triplets=triplets, quadruplets=quadruplets)
        self.failure = any(n.failure for n in needs)
        nb = family.nb if family is not None else 0
        self.state = state if state is not None else State.reference(system.x0, nb)
        for m in self.models:
            m.init_state(self.state)
        self._init_fields()
        self.constrained = constrained_dofs(system.n, self.conditions)
        if self.part is not None:  # halo rows follow their owners, never the integrator
            self.constrained[self.part.halo] = True
        self.inv_mass = (1.0 / system.mass)[:, None]
        self.inv_mass_n = np.ascontiguousarray(1.0 / system.mass)
        self._mass_n = np.ascontiguousarray(system.mass)
        self._any_constrained = bool(self.constrained.any())
        self._vol = system.volume[:, None]
        self._disp = [c for c in self.conditions if isinstance(c, Displacement)]
        self._vel = [c for c in self.conditions if isinstance(c, Velocity)]
        self._loads = [c for c in self.conditions if isinstance(c, (Force, BodyForce))]
        self._grips = [c for c in self.conditions if isinstance(c, Grip)]
        self._density_models = [m for m in self.models if m.force_kind == "density"]
        self._particle_models = [m for m in self.models if m.force_kind != "density"]
        self._b = np.zeros((system.n, 3))
        self.F = np.zeros((system.n, 3))
        self.F_ext = np.zeros((system.n, 3))
        self.reactions = np.zeros((system.n, 3))  # forces on the prescribed dofs
        self._prepared = False
        self.broken_total = 0
        self._ke_hist: list[float] = []  # kinetic energies of the last steps (blow-up guard)
        self._restored: dict | None = None  # driver arrays of a checkpoint being resumed

    def _init_fields(self) -> None:
        """Generalised degrees of freedom (``upscale.engine.fields``): the models' field
        declarations, zero arrays in the state, the prescribed components, force buffers."""
        from upscale.engine import fields

        self.field_specs = fields.collect_fields(self.models, self.system.n)
        fields.init_fields(self.state, self.field_specs)
        self.field_constrained = fields.field_constrained(self.system.n, self.field_specs,
                                                          self.conditions)
        self.G = {k: np.zeros((self.system.n, s.ncomp)) for k, s in self.field_specs.items()}
        self.field_inv_inertia = {k: 1.0 / (s.inertia * self.system.volume)
                                  for k, s in self.field_specs.items()}

    def update_field_forces(self) -> None:
        """Recompute ``self.G`` (generalised forces per particle on the fields; zero on the
        prescribed components)."""
        from upscale.engine.fields import add_field_forces

        for k in self.G:
            self.G[k][...] = 0.0
        add_field_forces(self, self.state, self.G)
        for k, mask in self.field_constrained.items():
            self.G[k][mask] = 0.0

    # ------------------------------------------------------------------ forces
    def internal_forces(self, failure: bool = False) -> np.ndarray:
        """Sum of the models' forces per particle (N, 3) on the current state (a new
        array); with ``failure`` the models' criteria update ``state.intact``."""
        st = self.state
        if self.part is not None:
            self.part.exchange_positions(st.y)
        fail = failure and self.failure
        if self._density_models:
            b = np.zeros_like(st.y)
            for m in self._density_models:
                self.broken_total += m.step_force(st, b, failure=fail)
            F = b * self._vol
        else:  # particle models only (e.g. a minimiser's evaluations of the coarse tube)
            F = np.zeros_like(st.y)
        for m in self._particle_models:
            self.broken_total += m.step_force(st, F, failure=fail)
        return F

    def update_forces(self) -> int:
        """Recompute ``self.F`` (internal + external, constrained dofs zeroed in the
        acceleration sense) on the current state, with bond failure. Returns bonds broken."""
        st = self.state
        if self.part is not None:
            self.part.exchange_positions(st.y)
        before = self.broken_total
        b = self._b
        b[...] = 0.0
        for m in self._density_models:
            self.broken_total += m.step_force(st, b, failure=self.failure)
        F = self.F
        np.multiply(b, self._vol, out=F)
        for m in self._particle_models:
            self.broken_total += m.step_force(st, F, failure=self.failure)
        if self._loads:
            self.F_ext[...] = 0.0
            for c in self._loads:
                c.add(self.F_ext, self.system, st.t)
            F += self.F_ext
        for g in self._grips:  # before the prescribed dofs are zeroed
            g.record(F, st.t)
        if self._any_constrained:
            np.multiply(F, self.constrained, out=self.reactions)
            F[self.constrained] = 0.0
        if self.field_specs:
            self.update_field_forces()
        return self.broken_total - before

    def forces(self) -> np.ndarray:
        """Internal + external particle forces (N, 3) on the current state, no failure."""
        return self.internal_forces(failure=False) + self.external_forces()

    def external_forces(self) -> np.ndarray:
        """The load conditions' particle forces (N, 3) at the current time (a new array)."""
        ext = np.zeros_like(self.state.y)
        for c in self._loads:
            c.add(ext, self.system, self.state.t)
        return ext

    # ------------------------------------------------------------------ conditions
    def apply_displacement(self, t: float, dt: float | None) -> None:
        for c in self._disp:
            c.apply(self.state, t, dt)

    def apply_velocity(self, t: float) -> None:
        for c in self._vel:
            c.apply_velocity(self.state, t)

    # ------------------------------------------------------------------ diagnostics
    def kinetic_energy(self) -> float:
        """Translational plus field (e.g. rotation) kinetic energy (J), with the coupling
        part of a non-diagonal mass (:mod:`upscale.engine.mass`)."""
        from upscale.engine.kernels import health

        ke = float(health(self.state.y, self.state.v, self._mass_n)[0])
        if self.part is not None:  # halo velocities are zero: the owned rows' sum
            return float(self.part.sum(ke))
        if getattr(self, "field_specs", None):
            from upscale.engine.fields import field_kinetic_energy

            ke += field_kinetic_energy(self)
        extra = getattr(self.integrator, "extra_kinetic_energy", None)  # non-diagonal mass
        return ke + extra(self) if extra is not None else ke

    def energy(self) -> float:
        """Total stored (strain) energy of all models (J)."""
        if self.part is not None:  # sum_i W_i V_i over the owned particles of every rank
            own = self.part.owned
            mine = sum(float(np.dot(m.energy_density(self.state)[own], self.system.volume[own]))
                       for m in self.models)
            return float(self.part.sum(mine))
        return float(sum(m.energy(self.state) for m in self.models))

    def broken_bonds(self) -> int:
        """Broken directed bonds of the whole body (on several ranks: summed over them)."""
        if self.part is not None:
            return self.part.broken_bonds(self.state.intact)
        return int(self.state.intact.size - np.count_nonzero(self.state.intact))

    def gather(self, a) -> np.ndarray:
        """A per-particle array of this simulation's particles as the whole body's (N, ...):
        itself on one rank, every rank's owned rows on several (collective)."""
        return np.asarray(a) if self.part is None else self.part.gather(a)

    def damage(self) -> np.ndarray:
        """Damage index mu (N,): of the pair family's bonds, or, for models that keep their
        own links (``model.particle_damage(state) -> (N,)``, e.g. the coarse tube), the largest of
        theirs; 0 with neither."""
        mu = np.zeros(self.system.n)
        if self.family is not None:
            mu = damage(self.family, self.state.intact, weights=self.damage_weights,
                        volume=self.system.volume)
        for m in self.models:
            own = getattr(m, "particle_damage", None)
            if callable(own):
                mu = np.maximum(mu, own(self.state))
        return mu

    def describe(self) -> dict:
        s = self.system
        d = {"particles": s.n if self.part is None else self.part.local.n_global, "dim": s.dim, "spacing_m": s.spacing, "thickness_m": s.thickness,
             "plane": s.plane if s.dim == 2 else None,
             "models": [m.describe() for m in self.models],
             "conditions": [c.describe() for c in self.conditions]}
        if self.family is not None:
            d.update(bonds=self.family.nb if self.part is None else self.part.local.nb_global,
                     horizon_m=self.family.horizon, partial_volume=self.family.partial_volume)
        if self.part is not None:
            d["mpi"] = self.part.describe()
        integ = self.integrator
        d["integrator"] = {"name": integ.name, "dt_s": getattr(integ, "dt", None),
                           "stable_estimate_s": getattr(integ, "estimate", None)}
        return d

    # ------------------------------------------------------------------ running
    def prepare(self) -> None:
        """Check the step, apply the conditions and compute the initial forces (on a
        resumed state: take the forces the checkpoint saved, see :meth:`resume`)."""
        if self._prepared:
            return
        self.integrator.prepare(self)
        if self._restored is not None:
            eng, self._restored = self._restored, None
            dt = eng.get("dt")
            if dt is not None and getattr(self.integrator, "dt", None) != float(dt):
                raise ValueError(f"the checkpoint was written with time step {float(dt)!r}, "
                                 f"this run has {self.integrator.dt!r}; valid: the same step "
                                 "(a resumed run continues the one it interrupted)")
            for k in ("F", "F_ext", "reactions"):
                getattr(self, k)[...] = eng[k]
            for k in getattr(self, "G", {}):
                if f"field_force__{k}" in eng:
                    self.G[k][...] = eng[f"field_force__{k}"]
            self.broken_total = int(eng["broken_total"])
            self._ke_hist = [float(x) for x in eng["ke_hist"]]
            restore = getattr(self.integrator, "restore_arrays", None)
            ia = {k[len("integrator__"):]: v for k, v in eng.items() if k.startswith("integrator__")}
            if restore is not None:
                restore(ia)
            self._prepared = True
            return
        if self.state.step == 0:
            self.apply_velocity(self.state.t)
            self.apply_displacement(self.state.t, None)
        self.update_forces()
        self._prepared = True

    def checkpoint_arrays(self) -> dict:
        """What a resumed run needs beyond the state to continue bit for bit: the forces of
        the last step (the next half-kick uses them; recomputed after the resume they would
        miss the bonds that broke in that evaluation), the external forces and reactions,
        the generalised forces on the fields, the broken-bond counter, the blow-up guard's
        history, the time step and the integrator's own arrays (e.g. a thermostat's
        variables and random state)."""
        eng = {"F": self.F, "F_ext": self.F_ext, "reactions": self.reactions,
               "broken_total": np.int64(self.broken_total),
               "ke_hist": np.asarray(self._ke_hist, dtype=np.float64)}
        eng.update({f"field_force__{k}": g for k, g in getattr(self, "G", {}).items()})
        dt = getattr(self.integrator, "dt", None)
        if dt is not None:
            eng["dt"] = np.float64(dt)
        arrays = getattr(self.integrator, "checkpoint_arrays", None)
        if arrays is not None:
            eng.update({f"integrator__{k}": v for k, v in arrays().items()})
        if self.part is not None:  # what merges the rank files into one (parallel.convert)
            loc = self.part.local
            eng.update(mpi_gid=loc.gid, mpi_owned=loc.owned, mpi_bond_gid=loc.bond_gid,
                       mpi_bond_owned=self.part.owned_bonds, mpi_n=np.int64(loc.n_global),
                       mpi_nb=np.int64(loc.nb_global))
        return eng

    def resume(self, path) -> bool:
        """Load the checkpoint at ``path`` if it exists (returns True if it did).

        The run then continues exactly as the one that wrote it would have: the state, the
        forces of its last step and the integrator's arrays come from the checkpoint, and
        no force is recomputed (a recomputation would apply the failure criterion again and
        lose the forces of the bonds that broke in the last evaluation). A checkpoint
        without these arrays resumes from forces recomputed without failure."""
        p = Path(path)
        whole = True
        if self.part is not None:
            p = self._rank_file(p)
            if p is None:
                return False
            whole = p == Path(path)
        elif not p.is_file():
            from upscale.engine.parallel.partition import refuse_other_ranks

            refuse_other_ranks(p, 1)
            return False
        if self.part is not None and whole:  # a whole-body checkpoint: this rank's part
            st, _, eng = load_checkpoint(p, engine=True)
            st, eng = self.part.localize_checkpoint(st, eng, self.system.x0)
        else:
            st, _, eng = load_checkpoint(p, self.system.x0, nb=self.state.intact.shape[0],
                                         engine=True)
        self.state = st
        if self.field_specs:
            from upscale.engine.fields import init_fields

            init_fields(st, self.field_specs)
        self._prepared = False
        if "F" in eng:
            self._restored = eng
        else:
            self._restored = None
            self.integrator.prepare(self)
            self.update_forces_without_failure()
            self._prepared = True
        return True

    def update_forces_without_failure(self) -> None:
        """Like :meth:`update_forces` but the models' failure criteria are not applied."""
        failure, self.failure = self.failure, False
        try:
            self.update_forces()
        finally:
            self.failure = failure

    def _global_index(self, i: int) -> int:
        return int(i) if self.part is None else int(self.part.local.gid[i])

    def _local_trouble(self, health, spacing: float, dt: float) -> str | None:
        """A non-finite state or a particle crossing a spacing in one step, on this rank."""
        st = self.state
        ke, imax, vmax2, finite = health
        if not (finite and np.isfinite(ke)):
            bad = np.flatnonzero(~(np.isfinite(st.y).all(axis=1) & np.isfinite(st.v).all(axis=1)))
            where = f" (particle {self._global_index(bad[0])} first)" if bad.size else ""
            return f"non-finite positions, velocities or kinetic energy{where}"
        vmax = float(np.sqrt(vmax2))
        if vmax * dt > spacing:
            return (f"particle {self._global_index(imax)} moves {vmax * dt / spacing:.3g} "
                    f"spacings in one step (|v| = {vmax:.4g})")
        return None

    def _check_health(self, ke_hist: list, spacing: float, dt: float) -> str | None:
        """The blow-up guard after a step: None, or why the run blew up. On several ranks
        the kinetic energy and the verdict are summed over them (one Allreduce per step),
        so every rank stops at the same step with the diagnosis of the first rank that
        saw it."""
        from upscale.engine.kernels import health as _health

        hl = _health(self.state.y, self.state.v, self._mass_n)
        why = self._local_trouble(hl, spacing, dt)
        ke = hl[0]
        if self.part is not None:
            tot = self.part.sum(np.array([ke, 0.0 if why is None else 1.0]))
            ke = float(tot[0])
            if tot[1] > 0:
                whys = self.part.comm.allgather(why)
                r = next(k for k, w in enumerate(whys) if w is not None)
                return f"{whys[r]} on rank {r} of {self.part.size}"
        ke_hist.append(ke)
        if len(ke_hist) > 40:
            del ke_hist[:-40]
        if why is None and len(ke_hist) >= 20 and all(
                b > 1.5 * a > 0 for a, b in zip(ke_hist[-20:-1], ke_hist[-19:])):
            why = (f"kinetic energy grew by more than 1.5x per step for 20 steps "
                   f"(now {ke:.4g} {self.system.energy_unit})")
        return why

    def run(self, steps: int, *, output=None, checkpoint: Checkpoint | None = None,
            progress: bool = False, callback=None, meta: dict | None = None) -> dict:
        """Advance ``steps`` steps (from the current state).

        ``output`` writes every ``output.every`` steps (and at the start and end);
        ``checkpoint`` every ``checkpoint.every`` steps, only from healthy states. A
        blow-up (non-finite state, a particle crossing a spacing in one step, or runaway
        kinetic energy) raises :class:`BlowUp` naming the step, the time step against the
        estimate and the last good checkpoint left on disk. ``callback(sim)`` runs after
        every step; returning True stops the run.
        """
        from tqdm.auto import tqdm

        if int(steps) < 0:
            raise ValueError(f"steps must be >= 0, got {steps!r}")
        if self.part is not None and checkpoint is not None:
            self._rank_checkpoint(checkpoint)
        self.prepare()
        dt = self.integrator.dt
        st = self.state
        spacing = self.system.spacing
        if output is not None:
            output.start(self)
            if st.step == 0 or not output.rows:
                output.write(self)
        if checkpoint is not None and checkpoint.last_step is None:
            # a good state to fall back on
            checkpoint.write(st, {**(meta or {}), "dt_s": dt}, engine=self.checkpoint_arrays())
        ke_hist = self._ke_hist
        t0 = time.perf_counter()
        target = st.step + int(steps)
        quiet = not progress or (self.part is not None and self.part.rank != 0)
        bar = tqdm(total=int(steps), disable=quiet, unit="step", mininterval=0.5,
                   desc=f"{'+'.join(m.name for m in self.models)}")
        broken0 = self.broken_bonds()
        try:
            while st.step < target:
                self.integrator.step(self)
                bar.update(1)
                why = self._check_health(ke_hist, spacing, dt)
                if why is not None:
                    est = getattr(self.integrator, "estimate", None)
                    ck = (f"last good checkpoint: {checkpoint.path} (step {checkpoint.last_step})"
                          if checkpoint is not None and checkpoint.last_step is not None
                          else "no checkpoint was written")
                    tu = self.system.time_unit
                    est_s = f"{est:.4g} {tu}" if est else "unknown"
                    raise BlowUp(f"run blew up at step {st.step} (t = {st.t:.6g} {tu}): {why}; "
                                 f"time step {dt:.4g} {tu} vs stable estimate {est_s}"
                                 f"{' (forced past it)' if est and dt > est else ''}; {ck}")
                if checkpoint is not None and st.step % checkpoint.every == 0:
                    growing = len(ke_hist) >= 5 and all(
                        b > 1.5 * a > 0 for a, b in zip(ke_hist[-5:-1], ke_hist[-4:]))
                    if not growing:
                        checkpoint.write(st, {**(meta or {}), "dt_s": dt},
                                         engine=self.checkpoint_arrays())
                if output is not None and st.step % output.every == 0:
                    output.write(self)
                if callback is not None and callback(self):
                    break
        finally:
            bar.close()
        wall = time.perf_counter() - t0
        if output is not None and (not output.rows or output.rows[-1]["step"] != st.step):
            output.write(self)
        if checkpoint is not None and checkpoint.last_step != st.step:
            checkpoint.write(st, {**(meta or {}), "dt_s": dt}, engine=self.checkpoint_arrays())
        broken = self.broken_bonds()
        return {"steps": int(st.step), "time_s": float(st.t), "dt_s": dt, "wall_s": wall,
                "broken_bonds": broken, "broken_this_run": broken - broken0}

    def minimise(self, minimiser=None, **kw):
        """Static equilibrium by a minimiser of :mod:`upscale.engine.minimisers` (default
        FIRE); returns its :class:`~upscale.engine.minimisers.MinimiseResult`."""
        from upscale.engine.minimisers import FIRE

        self._one_rank("minimisers")
        return (minimiser or FIRE()).minimise(self, **kw)

    def relax(self, adr=None, progress: bool = False, **kw) -> dict:
        """Quasi-static equilibrium by adaptive dynamic relaxation (see integrators);
        ``kw``: ``checkpoint``, ``resume``."""
        from upscale.engine.integrators import AdaptiveDynamicRelaxation

        if self.part is not None:  # the fused ADR adds its sums over the ranks
            from upscale.engine.adr import FusedAdaptiveDynamicRelaxation

            if adr is None:
                adr = FusedAdaptiveDynamicRelaxation()
            if not isinstance(adr, FusedAdaptiveDynamicRelaxation) or kw:
                raise Refused(f"{type(adr).__name__}{' with ' + ', '.join(kw) if kw else ''} "
                              f"runs on one rank in this version; this run has {self.part.size}"
                              " MPI ranks (valid there: FusedAdaptiveDynamicRelaxation, "
                              "without checkpoints)")
        adr = adr or AdaptiveDynamicRelaxation()
        return adr.run(self, progress=progress, **kw)

    def _one_rank(self, what: str) -> None:
        if self.part is not None:
            raise Refused(f"{what} run on one rank in this version; this run has "
                          f"{self.part.size} MPI ranks (valid there: velocity Verlet)")

    def _rank_checkpoint(self, checkpoint) -> None:
        """Point ``checkpoint`` at this rank's file (``name.rank<r>of<n>.npz``), once."""
        from upscale.engine.parallel.partition import rank_path

        if getattr(checkpoint, "rank_of", None) is None:
            checkpoint.global_path = checkpoint.path
            checkpoint.path = rank_path(checkpoint.path, self.part.rank, self.part.size)
            checkpoint.rank_of = (self.part.rank, self.part.size)
            checkpoint.keep_previous = True

    def _rank_file(self, path: Path):
        """This rank's checkpoint file for ``path`` on several ranks, ``path`` itself for a
        whole-body checkpoint (serial or merged), None when there is none (collective).
        Refuses a set written by another rank count or a partial set, with one line."""
        from upscale.engine.parallel.partition import rank_path, refuse_other_ranks

        mine = rank_path(path, self.part.rank, self.part.size)
        prev = mine.with_name(f"{mine.stem}.prev{mine.suffix}")
        steps = {_checkpoint_step(f): f for f in (prev, mine) if f.is_file()}
        every = self.part.comm.allgather(sorted(steps))
        have = [bool(s) for s in every]
        if not any(have):
            if path.is_file():
                return path
            refuse_other_ranks(path, self.part.size)
            return None
        if not all(have):
            missing = [r for r, h in enumerate(have) if not h]
            raise Refused(f"checkpoint {path} lacks the files of ranks {missing}; valid: "
                          "one file per rank, all written by the same run")
        common = set(every[0]).intersection(*every[1:])
        if not common:
            raise Refused(f"the ranks' checkpoints of {path} hold no common step "
                          f"({every}); valid: the files of one run")
        return steps[max(common)]


def _checkpoint_step(path) -> int:
    """The step a checkpoint file holds (reads one scalar of the npz)."""
    with np.load(path) as z:
        return int(z["step"])
