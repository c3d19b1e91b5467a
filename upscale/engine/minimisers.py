"""Minimisers: static equilibrium of a :class:`~upscale.engine.simulation.Simulation`, peers
of the integrators, on the same model interface (forces; energy where a method needs it).

Every minimiser works on the free degrees of freedom of ``sim.state.y``: the kinematic
conditions are applied at ``sim.state.t`` first and their dofs stay where they put them.
The total potential is

    Pi(y) = sum_models E_m(y) - sum_i F_ext,i . (y_i - x0_i)                      (1)

(J, or eV in atomistic scenes), whose negative gradient on the free dofs is the engine's
force ``sim.forces()`` (internal + external). Bonds do not break during a minimisation
(failure is a property of the load path; the quasi-static driver breaks bonds between
minimisations).

Convergence: ``fmax = max_i |F_i|`` over free particles (N, or eV/Å) at or below ``ftol``
(with bounds, a force component that pushes a dof against its active bound counts as 0).
A run that does not converge within ``max_iter`` raises :class:`NotConverged` (one line:
method, iterations, fmax against ftol), with the state left at the last finite iterate and
the :class:`MinimiseResult` on the exception. ``raise_on_fail=False`` returns the result
instead.

Methods
-------
:class:`FIRE`
    Fast inertial relaxation engine: E. Bitzek, P. Koskinen, F. Gaehler, M. Moseler,
    P. Gumbsch, Phys. Rev. Lett. 97, 170201 (2006). MD with the particles' masses and the
    velocity mixed toward the force, ``v <- (1 - alpha) v + alpha |v| F/|F|``; after
    ``n_min`` downhill steps (``P = F . v > 0``) the step grows by ``f_inc`` (up to
    ``dt_max``) and ``alpha`` shrinks by ``f_alpha``; uphill, ``v = 0``, the step shrinks
    by ``f_dec`` and ``alpha = alpha0``. Semi-implicit Euler, a displacement per step at
    most ``max_step``.
:class:`QuickMin`
    Damped dynamics with the velocity projected on the force (LAMMPS ``min_style
    quickmin``): ``v <- (v . F) F / |F|^2`` when ``v . F > 0``, else ``v = 0``.
:class:`LBFGS`
    Limited-memory BFGS with bounds (R. H. Byrd, P. Lu, J. Nocedal, C. Zhu, SIAM J. Sci.
    Comput. 16, 1190 (1995), through :func:`scipy.optimize.minimize` ``L-BFGS-B``) on
    eq. (1); needs the models' energies. ``bounds=(lo, hi)``: (N, 3) arrays (or scalars,
    ``+-inf`` for none) on the positions ``y``. A model's massless internal fields are
    minimised together with the positions: a model that declares ``internal_fields``
    (``{name: (lo, hi)}``, arrays ``state.extra[name]`` with bounds) gives
    ``internal_gradient(state) -> {name: dE/dfield}`` and stops relaxing them itself while
    ``hold_internal(True)`` (as the integrators and the other minimisers need it to);
    ``fmax`` then includes the largest field gradient component off its bound. Its line search compares energies, so
    it cannot resolve forces below about ``sqrt(machine eps) |Pi| / length`` (e.g.
    ~1e-6 eps/sigma for a 13-atom LJ cluster): a tighter ``ftol`` ends in
    :class:`NotConverged` with scipy's reason; FIRE, driven by forces only, goes further.

The same methods on flat arrays, for a model that is its own configuration space:
:mod:`upscale.engine.array_minimisers`.

Restart: FIRE and QuickMin write ``checkpoint`` (a :class:`~upscale.engine.checkpoint.Checkpoint`)
every ``checkpoint.every`` iterations with their own variables (step, mixing, counters),
and ``resume=True`` continues from it bit for bit. L-BFGS-B keeps its curvature pairs
inside scipy; it checkpoints its iterates, but a resumed L-BFGS-B starts a new history
(the same minimum, not the same iterates).
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from upscale.engine.array_minimisers import one_blas_thread

__all__ = ["MinimiseResult", "NotConverged", "FIRE", "QuickMin", "LBFGS", "total_energy"]


class NotConverged(RuntimeError):
    """A minimiser did not reach ``ftol`` in its budget; ``.result`` holds its record."""

    def __init__(self, message: str, result: "MinimiseResult"):
        super().__init__(message)
        self.result = result


@dataclasses.dataclass
class MinimiseResult:
    """Record of a minimisation.

    Attributes
    ----------
    method : str
    converged : bool
    iterations : int
    fmax : float
        Largest free particle force at the end (force units of the scene).
    energy : float or None
        Total potential eq. (1) at the end (None if the models have no energy).
    n_force : int
        Force evaluations.
    wall_s : float
    message : str
    history : list of (iteration, fmax)
    """

    method: str
    converged: bool
    iterations: int
    fmax: float
    energy: float | None
    n_force: int
    wall_s: float
    message: str = ""
    history: list = dataclasses.field(default_factory=list)

    def as_dict(self) -> dict:
        return {k: v for k, v in dataclasses.asdict(self).items() if k != "history"}


def total_energy(sim) -> float:
    """Eq. (1): the models' energies minus the work of the external loads at ``sim.state``."""
    st = sim.state
    return sim.energy() - float(np.sum(sim.external_forces() * (st.y - st.x0)))


def _free_forces(sim) -> np.ndarray:
    F = sim.forces()
    F[sim.constrained] = 0.0
    return F


def _fmax(F) -> float:
    return float(np.sqrt(np.max(np.einsum("nc,nc->n", F, F)))) if F.size else 0.0


def _check_common(ftol, max_iter):
    if not (np.isfinite(ftol) and ftol > 0):
        raise ValueError(f"ftol must be positive, got {ftol!r}")
    if int(max_iter) < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter!r}")


class _Dynamic:
    """Shared driver of the damped-dynamics minimisers (FIRE, QuickMin)."""

    name = "dynamic"

    def __init__(self, ftol, max_iter, dt, max_step):
        _check_common(ftol, max_iter)
        if dt is not None and not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be positive, got {dt!r}")
        self.ftol, self.max_iter, self.dt0, self.max_step = float(ftol), int(max_iter), dt, max_step

    def _vars(self) -> dict:  # the method's own variables (checkpointed)
        return {}

    def _set_vars(self, d: dict) -> None:
        pass

    def _update_velocity(self, v, F, m) -> None:
        raise NotImplementedError

    def minimise(self, sim, *, raise_on_fail: bool = True, checkpoint=None,
                 resume: bool = False, progress: bool = False) -> MinimiseResult:
        """Relax ``sim.state`` (mutated) to ``fmax <= ftol``; returns a :class:`MinimiseResult`."""
        from upscale.engine.checkpoint import load_checkpoint

        t0 = time.perf_counter()
        st = sim.state
        sim.apply_displacement(st.t, None)
        m = sim.system.mass[:, None]
        free = ~sim.constrained
        dt = self.dt0
        if dt is None:
            from upscale.engine.integrators import stable_time_step

            est = stable_time_step(sim.system, sim.models)
            if est is None:
                raise ValueError(f"{self.name}: no stable time step estimate for these models; "
                                 "give dt")
            dt = 0.5 * est
        self.dt = dt
        self._reset()
        max_step = self.max_step if self.max_step is not None else 0.2 * sim.system.spacing
        it = 0
        v = np.zeros_like(st.y)
        if resume and checkpoint is not None and checkpoint.path.is_file():
            s2, meta, eng = load_checkpoint(checkpoint.path, sim.system.x0,
                                            nb=st.intact.shape[0], engine=True)
            if meta.get("minimiser") != self.name:
                raise ValueError(f"checkpoint {checkpoint.path} is of {meta.get('minimiser')!r}, "
                                 f"not {self.name!r}; valid: the run it interrupted")
            st.y[...] = s2.y
            v[...] = s2.v
            it = int(eng["iteration"])
            self._set_vars({k[4:]: val for k, val in eng.items() if k.startswith("var_")})
            checkpoint.last_step = it
        fields = _Fields(sim, m)
        try:
            it, fm, nf, msg, hist = self._iterate(sim, fields, m, free, v, it, max_step, checkpoint)
        finally:
            fields.release()
        res = MinimiseResult(self.name, fm <= self.ftol, it, fm, _energy_or_none(sim), nf,
                             time.perf_counter() - t0, msg, hist)
        return _finish(res, self.ftol, self.max_iter, raise_on_fail)


    def _iterate(self, sim, fields, m, free, v, it, max_step, checkpoint):
        """The damped-dynamics loop over the rows and the models' internal fields
        (:class:`_Fields`): (iterations, fmax, force calls, message, history)."""
        st = sim.state
        F, Ff = _free_forces(sim), fields.forces()
        nf = 1
        fm = max(_fmax(F), fields.fmax(Ff))
        hist = [(it, fm)]
        y_good, f_good = st.y.copy(), fields.values()
        vf = np.zeros_like(Ff)
        msg = ""
        while fm > self.ftol and it < self.max_iter:
            if vf.size:  # one velocity vector over rows and fields: FIRE's power and mixing
                vv = np.concatenate([v.ravel(), vf])
                self._update_velocity(vv, np.concatenate([F.ravel(), Ff]),
                                      np.concatenate([np.broadcast_to(m, v.shape).ravel(),
                                                      fields.mass]))
                v[...] = vv[:v.size].reshape(v.shape)
                vf[...] = vv[v.size:]
            else:
                self._update_velocity(v, F, m)
            v *= free
            dy, dfl = self.dt * v, self.dt * vf
            big = float(np.sqrt(np.max(np.einsum("nc,nc->n", dy, dy)))) if dy.size else 0.0
            big = max(big, fields.largest_step(dfl))
            if big > max_step:
                dy *= max_step / big
                dfl *= max_step / big
            st.y += dy
            fields.move(dfl, vf)
            F, Ff = _free_forces(sim), fields.forces()
            nf += 1
            it += 1
            fm = max(_fmax(F), fields.fmax(Ff))
            if not np.isfinite(fm):
                st.y[...] = y_good
                fields.put(f_good)
                F = _free_forces(sim)
                fm = max(_fmax(F), fields.fmax(fields.forces()))
                msg = f"non-finite force at iteration {it}; state put back to iteration {it - 1}"
                break
            y_good[...] = st.y
            f_good[...] = fields.values()
            if it % 50 == 0:
                hist.append((it, fm))
            if checkpoint is not None and it % checkpoint.every == 0:
                eng = {"iteration": np.int64(it)}
                eng.update({f"var_{k}": np.asarray(val) for k, val in self._vars().items()})
                s_ = st.copy()
                s_.v = v.copy()
                checkpoint.write(s_, {"minimiser": self.name}, engine=eng)
        hist.append((it, fm))
        return it, fm, nf, msg, hist


class _Fields:
    """The models' massless internal fields (``internal_fields``: ``{name: (lo, hi)}``,
    arrays ``state.extra[name]``) as further unknowns of a damped-dynamics minimiser, as
    :class:`LBFGS` minimises them: held (``hold_internal(True)``) while it runs, forces
    -``internal_gradient``, moved within their bounds (a field at a bound with its force
    pointing out stops there), each field component with the rows' mean mass (the
    minimiser's fictitious dynamics; a field's inertia only scales its steps)."""

    def __init__(self, sim, m):
        self.st = sim.state
        self.items = [(md, name, lh) for md in sim.models
                      for name, lh in (getattr(md, "internal_fields", None) or {}).items()]
        sizes = [self.st.extra[name].size for _, name, _ in self.items]
        self.lo = np.concatenate([np.full(k, float(lh[0])) for k, (_, _, lh) in
                                  zip(sizes, self.items)]) if sizes else np.zeros(0)
        self.hi = np.concatenate([np.full(k, float(lh[1])) for k, (_, _, lh) in
                                  zip(sizes, self.items)]) if sizes else np.zeros(0)
        self.mass = np.full(sum(sizes), float(np.mean(m)) if sizes else 0.0)
        for md, _, _ in self.items:
            md.hold_internal(True)

    def release(self) -> None:
        for md, _, _ in self.items:
            md.hold_internal(False)

    def values(self) -> np.ndarray:
        return np.concatenate([self.st.extra[n].ravel() for _, n, _ in self.items]) \
            if self.items else np.zeros(0)

    def put(self, x) -> None:
        o = 0
        for _, name, _ in self.items:
            a = self.st.extra[name]
            a.reshape(-1)[...] = x[o:o + a.size]
            o += a.size

    def forces(self) -> np.ndarray:
        if not self.items:
            return np.zeros(0)
        g = np.concatenate([md.internal_gradient(self.st)[name].reshape(-1)
                            for md, name, _ in self.items])
        x = self.values()
        f = -g
        f[((x <= self.lo) & (f < 0)) | ((x >= self.hi) & (f > 0))] = 0.0
        return f

    def fmax(self, f) -> float:
        return float(np.abs(f).max()) if f.size else 0.0

    def largest_step(self, d) -> float:
        return float(np.abs(d).max()) if d.size else 0.0

    def move(self, d, vf) -> None:
        if not self.items:
            return
        x = self.values() + d
        out = (x < self.lo) | (x > self.hi)
        vf[out] = 0.0
        self.put(np.clip(x, self.lo, self.hi))


def _energy_or_none(sim):
    try:
        return total_energy(sim)
    except NotImplementedError:
        return None


def _finish(res: MinimiseResult, ftol, max_iter, raise_on_fail) -> MinimiseResult:
    if not res.converged:
        why = res.message or f"fmax {res.fmax:.4g} > ftol {ftol:.4g} after {res.iterations} " \
                             f"iterations (max_iter {max_iter})"
        res.message = why
        if raise_on_fail:
            raise NotConverged(f"{res.method} did not converge: {why}; the state is the last "
                               "iterate", res)
    return res


class FIRE(_Dynamic):
    """FIRE minimiser (module docstring; Bitzek et al. 2006, their Table I defaults).

    Parameters
    ----------
    ftol : float
        Force tolerance (force units of the scene).
    max_iter : int
    dt : float, optional
        Initial step (time units); default half the engine's stable-step estimate.
    dt_max : float, optional
        Largest step; default ``10 dt``.
    n_min, f_inc, f_dec, alpha0, f_alpha : FIRE's constants (5, 1.1, 0.5, 0.1, 0.99).
    max_step : float, optional
        Largest displacement of a particle in one iteration (default 0.2 spacing).
    """

    name = "fire"

    def __init__(self, ftol: float = 1e-6, max_iter: int = 10_000, *, dt: float | None = None,
                 dt_max: float | None = None, n_min: int = 5, f_inc: float = 1.1,
                 f_dec: float = 0.5, alpha0: float = 0.1, f_alpha: float = 0.99,
                 max_step: float | None = None):
        super().__init__(ftol, max_iter, dt, max_step)
        self.dt_max_arg, self.n_min, self.f_inc, self.f_dec = dt_max, int(n_min), f_inc, f_dec
        self.alpha0, self.f_alpha = alpha0, f_alpha

    def _reset(self):
        self.dt_max = self.dt_max_arg if self.dt_max_arg is not None else 10.0 * self.dt
        self.alpha = self.alpha0
        self.n_pos = 0

    def _vars(self):
        return {"dt": np.float64(self.dt), "alpha": np.float64(self.alpha),
                "n_pos": np.int64(self.n_pos), "dt_max": np.float64(self.dt_max)}

    def _set_vars(self, d):
        self.dt, self.alpha = float(d["dt"]), float(d["alpha"])
        self.n_pos, self.dt_max = int(d["n_pos"]), float(d["dt_max"])

    def _update_velocity(self, v, F, m):
        P = float(np.sum(F * v))
        if P > 0:
            vn = np.sqrt(np.sum(v * v))
            fn = np.sqrt(np.sum(F * F))
            if fn > 0:
                v *= 1.0 - self.alpha
                v += self.alpha * vn / fn * F
            if self.n_pos > self.n_min:
                self.dt = min(self.dt * self.f_inc, self.dt_max)
                self.alpha *= self.f_alpha
            self.n_pos += 1
        else:
            v[...] = 0.0
            self.dt *= self.f_dec
            self.alpha = self.alpha0
            self.n_pos = 0
        v += self.dt * F / m


class QuickMin(_Dynamic):
    """Quick-min: damped dynamics with the velocity projected on the force (module docstring).

    Parameters as :class:`FIRE` (``dt`` fixed during the run).
    """

    name = "quickmin"

    def __init__(self, ftol: float = 1e-6, max_iter: int = 10_000, *, dt: float | None = None,
                 max_step: float | None = None):
        super().__init__(ftol, max_iter, dt, max_step)

    def _reset(self):
        pass

    def _update_velocity(self, v, F, m):
        v += self.dt * F / m
        vf = float(np.sum(v * F))
        ff = float(np.sum(F * F))
        if vf <= 0 or ff == 0:
            v[...] = 0.0
        else:
            v[...] = (vf / ff) * F


class LBFGS:
    """L-BFGS-B on eq. (1) (module docstring).

    Parameters
    ----------
    ftol : float
        Force tolerance: converged when the largest free particle force is <= ftol.
    max_iter : int
        L-BFGS iterations.
    memory : int
        Correction pairs kept (scipy's ``maxcor``).
    bounds : (lo, hi), optional
        Bounds on ``y``: scalars or (N, 3) arrays; ``None`` / ``+-inf`` for none.
    maxls : int
        Line-search steps per iteration (scipy's ``maxls``). Near the resolution limit of
        the energy (module docstring) every line search fails and costs that many
        evaluations, twice before scipy gives up (it restarts once): the array-level
        :func:`lbfgs_b` keeps scipy's 20.
    energy_rtol : float
        Also stop when an iteration lowers the energy by a relative amount of at most this,
        (E_k - E_k+1) / max(|E_k|, |E_k+1|, 1) <= ``energy_rtol`` (scipy's ``ftol``; 0, the
        default: off). Where the energy has a step (a pair held at a step cut-off) the force
        test cannot be met and, without this test, the minimisation ends only after failed
        line searches; a caller with its own restarts (the coarse tube's damped dynamics)
        stops here instead, as :func:`lbfgs_b`'s callers do with 1e-15.
    """

    name = "lbfgs"

    def __init__(self, ftol: float = 1e-6, max_iter: int = 10_000, *, memory: int = 10,
                 bounds=None, maxls: int = 40, energy_rtol: float = 0.0):
        _check_common(ftol, max_iter)
        if int(maxls) < 1:
            raise ValueError(f"maxls must be >= 1, got {maxls!r}")
        if not 0.0 <= float(energy_rtol) < 1.0:
            raise ValueError(f"energy_rtol={energy_rtol!r}; valid: 0 <= energy_rtol < 1")
        self.ftol, self.max_iter, self.memory, self.bounds = float(ftol), int(max_iter), int(memory), bounds
        self.maxls = int(maxls)
        self.energy_rtol = float(energy_rtol)

    def minimise(self, sim, *, raise_on_fail: bool = True, checkpoint=None,
                 resume: bool = False, progress: bool = False) -> MinimiseResult:
        """Relax ``sim.state`` (mutated); returns a :class:`MinimiseResult`."""
        from scipy.optimize import Bounds, minimize

        from upscale.engine.checkpoint import load_checkpoint

        t0 = time.perf_counter()
        st = sim.state
        sim.apply_displacement(st.t, None)
        if resume and checkpoint is not None and checkpoint.path.is_file():
            s2, meta, _ = load_checkpoint(checkpoint.path, sim.system.x0, engine=True)
            st.y[...] = s2.y
        free = (~sim.constrained).ravel()
        idx = np.flatnonzero(free)
        n = sim.system.n
        bnds = None
        if self.bounds is not None:
            lo, hi = self.bounds
            lo = np.broadcast_to(np.asarray(-np.inf if lo is None else lo, float), (n, 3)).ravel()[idx]
            hi = np.broadcast_to(np.asarray(np.inf if hi is None else hi, float), (n, 3)).ravel()[idx]
            if np.any(lo > hi):
                k = int(np.flatnonzero(lo > hi)[0])
                raise ValueError(f"bounds: lower {lo[k]!r} above upper {hi[k]!r} at free dof {k}")
            y0 = st.y.ravel()[idx]
            if np.any((y0 < lo) | (y0 > hi)):
                k = int(np.flatnonzero((y0 < lo) | (y0 > hi))[0])
                raise ValueError(f"bounds: the start position {y0[k]!r} of free dof {k} is outside "
                                 f"[{lo[k]!r}, {hi[k]!r}]")
            bnds = (lo, hi)
        yflat = st.y.reshape(-1)
        count = {"f": 0, "it": 0}
        y_good = st.y.copy()
        hist = []
        # massless internal fields minimised together with the positions (module docstring)
        fields = [(m, name, lh) for m in sim.models
                  for name, lh in (getattr(m, "internal_fields", None) or {}).items()]
        ny = idx.size
        fsl, off = [], ny
        for m, name, (flo, fhi) in fields:
            a = st.extra[name]
            fsl.append(slice(off, off + a.size))
            off += a.size
        if fields:
            flo_all = np.concatenate([np.full(st.extra[nm].size, float(lh[0])) for _, nm, lh in fields])
            fhi_all = np.concatenate([np.full(st.extra[nm].size, float(lh[1])) for _, nm, lh in fields])
            ylo = np.full(ny, -np.inf) if bnds is None else bnds[0]
            yhi = np.full(ny, np.inf) if bnds is None else bnds[1]
            bnds = (np.concatenate([ylo, flo_all]), np.concatenate([yhi, fhi_all]))
            for m, name, _ in fields:
                m.hold_internal(True)

        free_y = slice(None) if ny == yflat.size else idx  # every dof free: no gather

        def put(x):
            yflat[free_y] = x[:ny]
            for (m, name, _), sl in zip(fields, fsl):
                st.extra[name].reshape(-1)[...] = x[sl]

        # eq. (1) with the loads once: they depend on time alone, which stays (a minimisation
        # called total_energy and forces at every evaluation, each summing them anew)
        ext = sim.external_forces()
        loaded = bool(np.any(ext))

        def fun(x):
            put(x)
            count["f"] += 1
            e = sim.energy()
            F = sim.internal_forces()
            if loaded:
                e -= float(np.sum(ext * (st.y - st.x0)))
                F += ext
            g = np.empty(x.size)  # a new array: scipy keeps the last gradient
            np.negative(F.reshape(-1)[free_y], out=g[:ny])
            for (m, name, _), sl in zip(fields, fsl):
                g[sl] = m.internal_gradient(st)[name].reshape(-1)
            if not (math.isfinite(e) and np.isfinite(g).all()):
                return np.inf, np.zeros_like(x)
            return e, g

        def cb(x):
            count["it"] += 1
            put(x)
            y_good[...] = st.y
            if count["it"] % 50 == 0:
                hist.append((count["it"], _fmax(_free_forces(sim))))
            if checkpoint is not None and count["it"] % checkpoint.every == 0:
                checkpoint.write(st, {"minimiser": self.name},
                                 engine={"iteration": np.int64(count["it"])})

        x0 = yflat[idx].copy()
        if fields:
            x0 = np.concatenate([x0] + [np.clip(st.extra[nm].reshape(-1), lh[0], lh[1])
                                        for _, nm, lh in fields])
        try:
            # scipy's projected-gradient test is per component; ours is per particle.
            # BLAS on one thread, as in lbfgs_b (one_blas_thread: the vectors are short)
            with one_blas_thread():
                # bounds as arrays (scipy's Bounds): a list of (lo, hi) pairs cost scipy
                # an element-by-element conversion per call
                r = minimize(fun, x0, jac=True, method="L-BFGS-B",
                             bounds=None if bnds is None else Bounds(*bnds),
                             callback=cb, options={"maxiter": self.max_iter,
                                                   "maxcor": self.memory,
                                                   "gtol": self.ftol / np.sqrt(3.0),
                                                   "ftol": self.energy_rtol,
                                                   "maxfun": 20 * self.max_iter,
                                                   "maxls": self.maxls})
            put(r.x)
            g_fields = 0.0
            if fields:  # the largest field gradient component off its active bound
                gf = np.concatenate([m.internal_gradient(st)[name].reshape(-1)
                                     for m, name, _ in fields])
                xf = r.x[ny:]
                gf[((xf <= flo_all) & (gf > 0)) | ((xf >= fhi_all) & (gf < 0))] = 0.0
                g_fields = float(np.abs(gf).max()) if gf.size else 0.0
        finally:
            for m, name, _ in fields:
                m.hold_internal(False)

        def projected():  # a force pushing a dof against its active bound holds it there
            F = _free_forces(sim)
            if self.bounds is not None:
                f = F.reshape(-1)
                yv = yflat[idx]
                fv = f[idx]
                fv[((yv <= lo) & (fv < 0)) | ((yv >= hi) & (fv > 0))] = 0.0
                f[idx] = fv
            return F

        F = projected()
        fm = max(_fmax(F), g_fields)
        msg = ""
        if not np.isfinite(fm):
            st.y[...] = y_good
            fm = _fmax(projected())
            msg = "non-finite force at the last iterate; state put back to the last good one"
        elif fm > self.ftol:
            msg = f"fmax {fm:.4g} > ftol {self.ftol:.4g} after {count['it']} iterations ({r.message})"
        hist.append((count["it"], fm))
        res = MinimiseResult(self.name, bool(fm <= self.ftol and not msg), count["it"], fm,
                             _energy_or_none(sim), count["f"] + 1, time.perf_counter() - t0, msg,
                             hist)
        return _finish(res, self.ftol, self.max_iter, raise_on_fail)
