"""Time integrators: velocity Verlet with a stable-step estimate, and adaptive dynamic
relaxation (ADR) for quasi-static loading.

Stable step. Each model gives a Gershgorin bound ``R_i`` on the row sums of
``|d force / d y|`` at the reference state (:meth:`Model.stiffness_bound`). The largest
eigenvalue of ``M^-1 K`` is then at most ``max_i sum_models R_i / rho_i`` (force
densities; ``R_i / m_i`` for per-particle forces), and velocity Verlet is stable for
``dt < 2 / sqrt(lambda_max)``. For PMB this is exactly the Silling-Askari (2005) bound
``dt < sqrt(2 rho / sum_j V_j c / |xi|)``. :func:`linearised_critical_dt` gives the sharp
value by power iteration on the linearised force, for checking the bound.

ADR: Kilic & Madenci (2010), "An adaptive dynamic relaxation method for quasi-static
simulations using the peridynamic theory", Theor. Appl. Fract. Mech. 53, 194: fictitious
diagonal density ``Lambda_i = dt^2 R_i / 4`` (dt = 1) and the damping from Rayleigh's
quotient of the local diagonal stiffness.
"""
from __future__ import annotations

import numpy as np

__all__ = ["stable_time_step", "linearised_critical_dt", "VelocityVerlet",
           "AdaptiveDynamicRelaxation", "BlowUp"]


class BlowUp(RuntimeError):
    """A run became unstable; the message says where, when and what to do."""


def _inertia(system, model):
    return system.density if model.force_kind == "density" else system.mass


def stiffness_over_inertia(system, models) -> np.ndarray | None:
    """sum_models R_i / inertia_i (N,) in 1/s^2, or None if a model gives no bound."""
    lam = np.zeros(system.n)
    for m in models:
        r = m.stiffness_bound()
        if r is None:
            return None
        lam += r / _inertia(system, m)
    return lam


def stable_time_step(system, models, part=None) -> float | None:
    """Gershgorin/Silling-Askari stable step estimate (s) for velocity Verlet, or None.
    Field rows (rotations, ``upscale.engine.fields``) count with their own inertia. With
    ``part`` (a run over MPI ranks, :mod:`upscale.engine.parallel`) the largest bound is
    taken over every rank's owned particles (a halo row is incomplete)."""
    lam = stiffness_over_inertia(system, models)
    if part is not None:
        mine = float(lam[part.owned].max()) if lam is not None else None
        lmax = part.comm.allreduce_max(-1.0 if mine is None else mine)
        if lam is None or lmax < 0:
            return None
        return float("inf") if lmax <= 0 else 2.0 / np.sqrt(lmax)
    if lam is None:
        return None
    if any(hasattr(m, "fields") for m in models):
        from upscale.engine.fields import collect_fields, field_stiffness_over_inertia

        lam_f = field_stiffness_over_inertia(system, models, collect_fields(models, system.n))
        if lam_f is not None:
            lam = np.maximum(lam, lam_f)
    lmax = float(lam.max())
    return float("inf") if lmax <= 0 else 2.0 / np.sqrt(lmax)


def linearised_critical_dt(sim, iters: int = 60, seed: int = 0) -> float:
    """Sharp critical step 2/sqrt(lambda_max(M^-1 K)) at the current state, by power
    iteration on finite differences of the total particle force (constrained dofs held)."""
    st = sim.state
    y0 = st.y.copy()
    intact0 = st.intact.copy()
    mass = sim.system.mass[:, None]
    free = ~sim.constrained
    rng = np.random.default_rng(seed)
    v = rng.normal(size=y0.shape) * free
    v /= np.linalg.norm(v)
    h = 1e-7 * sim.system.spacing
    F0 = sim.internal_forces(failure=False)
    lam = 0.0
    try:
        for _ in range(iters):
            st.y[...] = y0 + h * v
            F1 = sim.internal_forces(failure=False)
            w = -(F1 - F0) / h / mass * free
            lam = float(np.vdot(v, w))
            nrm = np.linalg.norm(w)
            if nrm == 0:
                break
            v = w / nrm
    finally:
        st.y[...] = y0
        st.intact[...] = intact0
    return float("inf") if lam <= 0 else 2.0 / np.sqrt(lam)


class StableEstimate:
    """The stable-step estimate of an integrator (:func:`stable_time_step`), as the
    attribute ``estimate``. With a given step and ``force=True`` nothing needs it before a
    run, so :meth:`_check_step` only records the simulation and the estimate is computed
    when first read (a blow-up's diagnosis, ``describe``): on a coarse tube it is a Lanczos
    eigenvalue solve, 0.15 s, as long as a tenth of a picosecond of its dynamics."""

    _estimate: float | None = None
    _estimate_of = None

    @property
    def estimate(self) -> float | None:
        if self._estimate_of is not None:
            system, models = self._estimate_of
            self._estimate_of = None
            self._estimate = stable_time_step(system, models)
        return self._estimate

    @estimate.setter
    def estimate(self, value) -> None:
        self._estimate, self._estimate_of = value, None

    def _check_step(self, sim, dt, what: str = "time step") -> None:
        """The estimate for ``sim``, deferred when the step ``dt`` is given and forced;
        else a step above it is refused."""
        part = getattr(sim, "part", None)
        if dt is not None and self.force and part is None:
            self._estimate_of = (sim.system, sim.models)
            return
        self.estimate = stable_time_step(sim.system, sim.models, part)  # collective
        if dt is not None and not self.force and self.estimate is not None and dt > self.estimate:
            tu = sim.system.time_unit
            raise ValueError(f"{what} {dt:.6g} {tu} exceeds the stable estimate "
                             f"{self.estimate:.6g} {tu} (Silling-Askari/Gershgorin bound); use "
                             f"a {what} <= {self.estimate:.6g} or pass force=True (--force-dt)")


class VelocityVerlet(StableEstimate):
    """Velocity Verlet (kick-drift-kick), LAMMPS ``fix nve`` order.

    Parameters
    ----------
    dt : float, optional
        Time step (s). Default ``safety`` x the stable estimate.
    safety : float
        Fraction of the estimate used when ``dt`` is not given.
    force : bool
        Allow a ``dt`` above the stable estimate (otherwise refused with a ValueError
        that gives the estimate).
    thermostat : Langevin or NoseHooverChain, optional
        :mod:`upscale.engine.thermostats`, on a region (NVE without).
    """

    name = "velocity-verlet"

    def __init__(self, dt: float | None = None, *, safety: float = 0.8, force: bool = False,
                 thermostat=None):
        self.thermostat = thermostat
        if dt is not None and not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"time step must be positive, got {dt!r}")
        if not (0 < safety <= 1):
            raise ValueError(f"safety factor must be in (0, 1], got {safety!r}")
        self.dt = dt
        self.safety = float(safety)
        self.force = bool(force)
        self.estimate = None

    def prepare(self, sim) -> None:
        """Check (or choose) the step against the stable estimate (:class:`StableEstimate`)."""
        self._check_step(sim, self.dt)
        if self.dt is None:
            if self.estimate is None:
                raise ValueError("no stable time step estimate for these models: give dt explicitly")
            self.dt = self.safety * self.estimate
        if self.thermostat is not None:
            self.thermostat.prepare(sim)

    def checkpoint_arrays(self) -> dict:
        """The thermostat's variables (and random state), for an exact restart."""
        th = self.thermostat
        return {} if th is None else {f"thermostat_{k}": v for k, v in th.checkpoint_arrays().items()}

    def restore_arrays(self, d: dict) -> None:
        if self.thermostat is not None:
            self.thermostat.restore_arrays({k[len("thermostat_"):]: v for k, v in d.items()
                                            if k.startswith("thermostat_")})

    def step(self, sim) -> int:
        """Advance ``sim.state`` by one step; returns the number of bonds broken."""
        from upscale.engine.kernels import drift, kick

        st, dt = sim.state, self.dt
        inv_m = sim.inv_mass_n
        fields = getattr(sim, "field_specs", None)
        if self.thermostat is not None:
            self.thermostat.begin(sim, dt)
        kick(st.v, sim.F, inv_m, 0.5 * dt)
        if fields:
            _kick_fields(sim, 0.5 * dt)
        sim.apply_velocity(st.t + 0.5 * dt)
        drift(st.y, st.v, dt)
        if fields:
            for k in fields:
                r = fields[k].span  # the rows that carry the field
                st.fields[k][r] += dt * st.field_v[k][r]
        st.t += dt
        st.step += 1
        sim.apply_displacement(st.t, dt)
        broken = sim.update_forces()
        kick(st.v, sim.F, inv_m, 0.5 * dt)
        if fields:
            _kick_fields(sim, 0.5 * dt)
        sim.apply_velocity(st.t)
        if self.thermostat is not None:
            self.thermostat.end(sim, dt)
        return broken


def _kick_fields(sim, h: float) -> None:
    """Field rates += h G / inertia (generalised degrees of freedom)."""
    st = sim.state
    for k, inv in sim.field_inv_inertia.items():
        r = sim.field_specs[k].span  # the rows that carry the field
        st.field_v[k][r] += h * sim.G[k][r] * inv[r, None]


class AdaptiveDynamicRelaxation:
    """Adaptive dynamic relaxation to static equilibrium (Kilic & Madenci 2010).

    ``sim.relax(adr)`` iterates until the out-of-balance force on the free degrees of
    freedom, relative to the largest of the reaction and applied forces, is below ``tol``.
    ``run(sim, checkpoint=Checkpoint(path, every))`` writes the iterate, its fictitious
    velocity and last force every ``every`` iterations; ``resume=True`` continues from
    there bit for bit.
    """

    name = "adr"

    def __init__(self, tol: float = 1e-6, max_steps: int = 100_000, dt: float = 1.0):
        self.tol = float(tol)
        self.max_steps = int(max_steps)
        self.dt = float(dt)

    def run(self, sim, progress: bool = False, checkpoint=None, resume: bool = False) -> dict:
        if getattr(sim, "field_specs", None):
            raise ValueError(f"adaptive dynamic relaxation moves translations only; fields "
                             f"{sorted(sim.field_specs)} need upscale.engine.fields.solve_static "
                             f"(linear models) or velocity Verlet")
        st = sim.state
        R = np.zeros(sim.system.n)
        for m in sim.models:
            r = m.stiffness_bound()
            if r is None:
                raise ValueError(f"model {m.name!r} gives no stiffness bound; ADR needs one")
            R += r * (sim.system.volume if m.force_kind == "density" else 1.0)
        dt = self.dt
        lam = 0.25 * dt * dt * R  # fictitious mass per particle (force / length units)
        lam = np.where(lam > 0, lam, 1.0)[:, None]
        free = ~sim.constrained
        sim.apply_displacement(st.t, None)
        sim.update_forces()
        F = sim.F * free
        v_half = 0.5 * dt * F / lam
        F_prev = F.copy()
        res = np.inf
        it = start = 0
        if resume and checkpoint is not None and checkpoint.path.is_file():
            from upscale.engine.checkpoint import load_checkpoint

            s2, meta, eng = load_checkpoint(checkpoint.path, sim.system.x0,
                                            nb=st.intact.shape[0], engine=True)
            if meta.get("solver") != "adr":
                raise ValueError(f"checkpoint {checkpoint.path} is not of an ADR run "
                                 f"({meta.get('solver')!r}); valid: the run it interrupted")
            st.y[...], st.intact[...] = s2.y, s2.intact
            v_half, F_prev = eng["v_half"], eng["F_prev"]
            start = it = int(eng["iteration"])
            checkpoint.last_step = it
        for it in range(start + 1, self.max_steps + 1):
            st.y += dt * v_half
            sim.apply_displacement(st.t, None)
            sim.update_forces()
            F = sim.F * free
            # local diagonal stiffness and Rayleigh damping coefficient
            with np.errstate(divide="ignore", invalid="ignore"):
                K1 = np.where(np.abs(v_half) > 0, -(F - F_prev) / (lam * dt * v_half), 0.0)
            u = st.y - st.x0
            num = float(np.sum(u * K1 * u))
            den = float(np.sum(u * u))
            c = 2.0 * np.sqrt(num / den) if den > 0 and num > 0 else 0.0
            c = min(c, 1.9 / dt)
            v_half = ((2.0 - c * dt) * v_half + 2.0 * dt * F / lam) / (2.0 + c * dt)
            F_prev = F
            scale = max(float(np.linalg.norm(sim.reactions)), float(np.linalg.norm(sim.F_ext)), 1e-300)
            res = float(np.linalg.norm(F)) / scale
            if res < self.tol:
                break
            if checkpoint is not None and it % checkpoint.every == 0:
                checkpoint.write(st, {"solver": "adr"},
                                 engine={"v_half": v_half, "F_prev": F_prev,
                                         "iteration": np.int64(it)})
        st.v[...] = 0.0
        return {"iterations": it, "residual": res, "converged": bool(res < self.tol)}
