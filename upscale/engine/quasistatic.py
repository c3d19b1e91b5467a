"""Quasi-static fracture under displacement control: load step, equilibrate, break,
re-equilibrate at the same load until no bond breaks.

For a model with a failure criterion (``model.needs.failure``) and the hooks
``failure_index(state) -> (nb,)`` (>= 1: the bond breaks) and ``break_bonds(state)``:

1. equilibrium at the prescribed displacement lambda u_dir of the driven degrees of
   freedom by modified Newton on the model's residual and sparse tangent
   (:class:`Equilibrium`: CG preconditioned by a reused sparse Cholesky factor, corrected
   by a local factor of the current tangent where bonds broke since);
2. break every bond whose index is >= 1 and solve again at the same lambda, until none
   breaks (each such equilibrium is a point of the load-displacement curve);
3. the next load: lambda + d_lambda, but no further than the load at which the largest
   index reaches 1 if the index scales as lambda^order (``order = 2`` for an energy
   criterion of a linear elastic body: the first failure of every loading branch is then
   hit exactly, to the small geometric nonlinearity, which the solve at the predicted load
   corrects and the next prediction absorbs); the first load is a probe of
   d_lambda / 100.

The load P is the reaction of the driven dofs along ``u_dir`` (N), the critical load the
peak of the curve. The run stops when P falls below ``stop_fraction`` of the peak, when
lambda exceeds ``u_max``, or after ``max_equilibria`` solves.
"""
from __future__ import annotations

import dataclasses
import inspect
import time

import numpy as np

import scipy.sparse as sp
import scipy.sparse.linalg as spla

from upscale.engine.solvers import Factor, check_method, direct_solve, pcg, rigid_body_modes, say_once

__all__ = ["FractureCurve", "quasi_static_fracture", "Equilibrium"]


class Equilibrium:
    """Static equilibrium on the free dofs by modified Newton with a preconditioned
    conjugate-gradient inner solve (for symmetric positive definite tangents).

    Newton iterations y <- y + K^-1 R on the free dofs until |R_free| <= tol max(|R_0|,
    |F_int|). The inner solve is CG on the current tangent, applied matrix-free by
    differences of the residual (``matvec="matrix-free"``: bonds may break between solves
    without reassembly) or assembled (``"assembled"``, reassembled when the bonds change),
    preconditioned by a factorisation of an earlier tangent (:class:`upscale.engine.solvers.
    Factor`, ``preconditioner="cholmod"`` by default: a supernodal Cholesky whose symbolic
    analysis is kept while the tangent's pattern is the same), refactored when CG needs more
    than ``refactor_after`` iterations: after a few bonds break the old factor is still an
    excellent preconditioner (the change is of low rank). ``preconditioner="amg"`` (pyamg
    smoothed aggregation with the rigid-body modes) or ``"jacobi"`` never factorise (large
    elastic solves); ``"splu"`` is SuperLU. When CG does not converge in ``cg_maxiter``
    iterations the step is solved directly with a fresh factorisation of the current
    tangent (said once per process).

    The matrix-free product is by default a forward difference from the residual of the
    current Newton iterate, K v = (F(y) - F(y + h v)) / h with a perturbation of 1e-8 dx
    per dof (``difference="forward"``: one residual per CG iteration; the truncation error
    is of the order of the strain change, 1e-8, the rounding error eps |F| / (K h v) about
    1e-10, both far below ``cg_tol``; the outer Newton loop converges on the exact
    residual either way). ``difference="central"`` takes two residuals with 1e-6 dx.

    Refactorisation (``refactor="amortised"``, default): breaking bonds makes the old factor
    a worse preconditioner, so CG needs more iterations with every round. The factor is
    renewed before a solve once the CG iterations spent since the last factorisation
    beyond ``n_fresh`` per Newton step (the count of the first Newton step after that
    factorisation) would have paid for a new one, i.e. excess x t_iteration >=
    t_assembly + t_factor, both times those of the latest factorisation (the ski-rental
    rule: at most twice the cost of the best refactorisation schedule).
    ``refactor="never"`` keeps only the in-solve rule (more than ``refactor_after`` CG
    iterations in one Newton step).

    Local correction (``local_hops``, default 1; None: off). Breaking bonds changes the
    tangent only near them, but in many directions at once (each failing particle changes
    the gain of its whole family): the old factor's error is spatially local, not of low
    rank, so deflating a few directions does not help, while CG's iterations grow with
    every round. Each equilibrium therefore assembles the current tangent's rows on the
    region T of the particles whose gain changed since the factorisation, their families
    and ``local_hops`` more family hops (``model.tangent(state, particles=...)``, exact on
    those rows), factorises J_TT, and preconditions CG by the symmetric multiplicative
    Schwarz step z1 = L r, z2 = z1 + G (r - J z1), z = z2 + L (r - J z2) (G the factor's
    solve, L the local one: one factor solve, two local ones and one product per
    iteration). A region larger than ``local_max_dofs`` dofs renews the factor instead.

    Inner tolerance (``forcing="adaptive"``, default): the Newton step k solves
    K du = R_k only to the relative residual eta_k (inexact Newton, Eisenstat and Walker
    1996, choice 2), eta_0 = ``eta_max``, eta_k = 0.9 (|R_k| / |R_k-1|)^2 clipped to
    [``cg_tol``, ``eta_max``], and never tighter than 0.5 tol r0 / |R_k| (no oversolving
    of the last step); a linear solve to ``cg_tol`` is wasted where the nonlinearity
    limits the step anyway (after bonds break the first Newton step reduces |R| by about
    1e-3 whatever the inner tolerance). The stopping test |R| <= tol r0 is the same, so the
    equilibrium is the same to that tolerance. ``forcing="fixed"``: eta_k = ``cg_tol``.

    Parameters
    ----------
    model : Model
        With ``residual`` and ``tangent``.
    fixed : (N, 3) bool
        Constrained dofs (the z dofs of a 2D body are added).
    """

    PRECONDITIONERS = ("cholmod", "splu", "amg", "jacobi")

    def __init__(self, model, fixed, *, tol=1e-9, max_iter=30, cg_tol=1e-6,
                 refactor_after=40, preconditioner="cholmod", matvec="matrix-free",
                 difference="forward", refactor="amortised", forcing="adaptive", eta_max=1e-3,
                 cg_maxiter=2000, local_hops=1, local_max_dofs=6000):
        check_method(preconditioner, self.PRECONDITIONERS, "preconditioner")
        if difference not in ("forward", "central"):
            raise ValueError(f"difference={difference!r}; valid: 'forward', 'central'")
        if refactor not in ("amortised", "never"):
            raise ValueError(f"refactor={refactor!r}; valid: 'amortised', 'never'")
        if forcing not in ("adaptive", "fixed"):
            raise ValueError(f"forcing={forcing!r}; valid: 'adaptive', 'fixed'")
        if local_hops is not None and not (isinstance(local_hops, (int, np.integer)) and local_hops >= 0):
            raise ValueError(f"local_hops={local_hops!r}; valid: None (no local correction) or an int >= 0")
        if not 0 < eta_max < 1:
            raise ValueError(f"eta_max={eta_max!r}; valid: 0 < eta_max < 1")
        if matvec not in ("matrix-free", "assembled"):
            raise ValueError(f"matvec={matvec!r}; valid: 'matrix-free', 'assembled'")
        self.difference, self.refactor, self.forcing, self.eta_max = difference, refactor, forcing, eta_max
        self._F_base = None
        self._excess = 0
        self._fresh = None
        self._budget = None
        self._factor_cost = 0.0
        n = model.system.n
        mask = np.asarray(fixed, dtype=bool).copy()
        mask[:, model.system.dim:] = True
        self.model, self.mask = model, mask
        self.free = np.flatnonzero(~mask.ravel())
        self.tol, self.max_iter, self.cg_tol, self.cg_maxiter = tol, max_iter, cg_tol, int(cg_maxiter)
        self.refactor_after, self.kind = refactor_after, preconditioner
        self.matvec = matvec
        self._pc = None
        if preconditioner != "jacobi":
            near = None
            if preconditioner == "amg":
                near = rigid_body_modes(model.system.x0, self.free, model.system.dim)
            self._pc = Factor(preconditioner, near_null=near)
        self.local_hops, self.local_max_dofs = local_hops, int(local_max_dofs)
        if local_hops is not None and (preconditioner not in ("cholmod", "splu")
                                       or "particles" not in inspect.signature(model.tangent).parameters):
            self.local_hops = None          # needs a factor and a tangent of a subset of particles
        self._local = None
        self._pos = np.full(3 * n, -1, np.int64)
        self._pos[self.free] = np.arange(self.free.size)
        self._ready = False
        self._K = None
        self._K_intact = None
        self._sub = None
        self.stats = {"matvecs": 0, "assemblies": 0, "factorisations": 0, "cg_iterations": 0, "outer_iterations": 0,
                      "direct_fallbacks": 0, "local_blocks": 0, "local_s": 0.0, "assembly_s": 0.0, "factor_s": 0.0, "cg_s": 0.0, "residual_s": 0.0}
        self.n = n

    def _assemble(self, state):
        """The tangent on the free dofs; the free rows and columns of a pattern seen before
        are taken by a stored index map (the model's tangent keeps its pattern; the map is
        rebuilt only when the pattern's content differs)."""
        t = time.perf_counter()
        K = self.model.tangent(state).tocsr()
        sub = self._sub
        if sub is None or not (sub[0].shape == K.indptr.shape and sub[1].shape == K.indices.shape
                               and np.array_equal(sub[0], K.indptr) and np.array_equal(sub[1], K.indices)):
            probe = sp.csr_matrix((np.arange(K.nnz, dtype=float), K.indices, K.indptr), shape=K.shape)
            Kp = probe[self.free][:, self.free].tocsr()
            Kp.sort_indices()
            self._sub = sub = (K.indptr.copy(), K.indices.copy(), Kp.data.astype(np.int64), Kp.indices, Kp.indptr)
        _, _, take, ind, ptr = sub
        self._K = sp.csr_matrix((K.data[take], ind, ptr), shape=(self.free.size, self.free.size))
        self._K_intact = state.intact.copy()
        self.stats["assemblies"] += 1
        self.stats["assembly_s"] += time.perf_counter() - t
        return time.perf_counter() - t

    def _jv(self, state, v):
        """Tangent times v on the free dofs by differences of the residual: forward,
        K v = (F(y) - F(y + h v)) / h from the residual ``_F_base`` of the current iterate,
        or central, K v = (F(y - h v) - F(y + h v)) / 2h (exact for a quadratic energy)."""
        y = state.y.reshape(-1)
        base = y[self.free].copy()
        nv = float(np.linalg.norm(v))
        if nv == 0:
            return np.zeros_like(v)
        forward = self.difference == "forward" and self._F_base is not None
        h = (1e-8 if forward else 1e-6) * self.model.system.spacing * np.sqrt(v.size) / nv
        try:
            y[self.free] = base + h * v
            fp = self.model.residual(state)[self.free]
            if not forward:
                y[self.free] = base - h * v
                fm = self.model.residual(state)[self.free]
        finally:
            y[self.free] = base
        self.stats["matvecs"] += 1
        if forward:
            return (self._F_base - fp) / h
        return (fm - fp) / (2 * h)

    def _factor(self, state):
        """Assemble and factorise the current tangent; the factor's cost (s) is kept for
        the refactorisation rule."""
        t_asm = self._assemble(state)
        t = time.perf_counter()
        if self._pc is not None:
            # a small shift keeps the factor regular when broken bonds leave a particle loose
            # (a zero row: the operator is singular there but its residual is zero too)
            A = self._K.copy()          # in place on the diagonal: the pattern (explicit zeros of
            d = A.diagonal()            # broken bonds too) stays, and with it the symbolic analysis
            mean = float(np.mean(np.abs(d)))
            A.setdiag(d + 1e-8 * mean + np.where(d == 0, mean, 0.0))
            try:
                self._pc.factor(A)
            except ArithmeticError:     # Cholesky of a tangent that is not positive definite
                say_once("cholmod-indefinite", "the tangent is not positive definite (Cholesky failed); "
                         "preconditioning with SuperLU from here on")
                self._pc = Factor("splu")
                self._pc.factor(A)
            self.stats["factorisations"] += 1
        dt = time.perf_counter() - t
        self.stats["factor_s"] += dt
        self._factor_cost = t_asm + dt
        self._budget = None
        self._excess, self._fresh = 0, None
        self._local = None
        self._F_intact = state.intact.copy()
        self._ready = True

    def _local_block(self, state):
        """The local correction (class docstring): T = the particles whose gain changed
        since the factor's tangent (owners of the bonds broken since), their families and
        ``local_hops`` more family hops; the current tangent's rows on T, exact because the
        contributions of every particle within one hop of T are assembled, give J[T, :]
        and J_TT, and a sparse Cholesky factor of J_TT the local solve."""
        self._local = None
        changed = self._F_intact != state.intact
        if self.local_hops is None or not changed.any():
            return
        t = time.perf_counter()
        fam, dim = self.model.family, self.model.system.dim
        mark = np.zeros(self.n, bool)
        mark[fam.owner[changed]] = True
        for _ in range(1 + self.local_hops):
            mark[fam.neighbors[mark[fam.owner]]] = True
        members = mark.copy()
        members[fam.neighbors[mark[fam.owner]]] = True
        K = self.model.tangent(state, particles=np.flatnonzero(members)).tocsr()
        rows = (3 * np.flatnonzero(mark)[:, None] + np.arange(dim)).ravel()
        rows = rows[self._pos[rows] >= 0]
        Tf = self._pos[rows]
        JT = K[rows][:, self.free].tocsr()            # J[T, :] on the free dofs
        JTT = JT[:, Tf].tocsr()
        d = JTT.diagonal()
        mean = float(np.mean(np.abs(d)))
        JTT.setdiag(d + 1e-8 * mean + np.where(d == 0, mean, 0.0))   # voids: zero rows
        loc = Factor("cholmod")
        try:
            loc.factor(JTT)
        except ArithmeticError:
            loc = Factor("splu").factor(JTT)
        self._local = (Tf, JT.T.tocsr(), loc)
        self.stats["local_blocks"] += 1
        self.stats["local_s"] += time.perf_counter() - t

    def _precondition(self, A, r):
        """The factor's solve, or with a local block the symmetric multiplicative Schwarz
        step: z1 = L r, z2 = z1 + G (r - J z1), z = z2 + L (r - J z2) (L the local, G the
        factor's solve)."""
        if self._local is None:
            return self._pc.solve(r)
        Tf, JcolT, loc = self._local
        z1 = loc.solve(r[Tf])
        z = self._pc.solve(r - JcolT @ z1)
        z[Tf] += z1
        z[Tf] += loc.solve((r - A @ z)[Tf])
        return z

    def solve(self, state, u_prescribed):
        """Mutates ``state.y``: sets the constrained dofs to x0 + ``u_prescribed`` (N, 3)
        there, relaxes the free dofs. Returns the reaction (N, 3) (N) on constrained dofs
        (force the constraints exert on the body) and the outer iteration count."""
        m, st = self.model, self.stats
        x0 = m.system.x0
        state.y[self.mask] = x0[self.mask] + u_prescribed[self.mask]
        free = self.free
        if not self._ready or (self.refactor == "amortised" and self._budget is not None
                               and self._excess >= self._budget and self._pc is not None):
            self._factor(state)
        elif self.matvec == "assembled" and not np.array_equal(self._K_intact, state.intact):
            self._assemble(state)
        if self._pc is not None and self._pc.method in ("cholmod", "splu"):
            self._local_block(state)
            if self._local is not None and self._local[0].size > self.local_max_dofs:
                self._factor(state)
        if self.matvec == "assembled":
            A = self._K
        else:
            A = spla.LinearOperator((free.size, free.size), matvec=lambda v: self._jv(state, v))
        if self._pc is None:
            dinv = 1.0 / self._K.diagonal()
            M = spla.LinearOperator(A.shape, matvec=lambda v: dinv * v)
        elif self.local_hops is None:
            M = self._pc.operator(free.size)
        else:
            M = spla.LinearOperator(A.shape, matvec=lambda v: self._precondition(A, v), dtype=np.float64)

        def direct(b):
            st["direct_fallbacks"] += 1
            if self._pc is not None and self._pc.method in ("cholmod", "splu"):
                self._factor(state)
                return self._pc.solve(b)
            self._assemble(state)
            return direct_solve(self._K, b, "cholmod")

        it = 0
        r0 = r_prev = None
        self.history = []
        while True:
            t = time.perf_counter()
            F = m.residual(state)
            st["residual_s"] += time.perf_counter() - t
            R = F[free]
            self._F_base = R
            r = float(np.linalg.norm(R))
            if r0 is None:
                r0 = max(r, float(np.linalg.norm(F)), 1e-300)
            self.history.append((it, r / r0))
            if r <= self.tol * r0 or it >= self.max_iter:
                break
            t = time.perf_counter()
            eta = self.cg_tol
            if self.forcing == "adaptive":
                eta = self.eta_max if r_prev is None else 0.9 * (r / r_prev) ** 2
                eta = min(max(eta, self.cg_tol), self.eta_max)
                eta = min(max(eta, 0.5 * self.tol * r0 / r), 0.5)
            r_prev = r
            du, count, _ = pcg(A, R, M, rtol=eta, maxiter=self.cg_maxiter, direct=direct,
                               what="the equilibrium's preconditioned CG")
            dt = time.perf_counter() - t
            st["cg_s"] += dt
            st["cg_iterations"] += count
            if self._fresh is None:
                self._fresh = count
            self._excess += max(0, count - self._fresh)
            if self._budget is None and count > 0 and self._factor_cost > 0:
                # the latest factorisation's cost in CG iterations
                self._budget = self._factor_cost / (dt / count)
            if self._pc is not None and count > self.refactor_after:
                self._factor(state)
                if self.matvec == "assembled":
                    A = self._K
            state.y.reshape(-1)[free] += du
            it += 1
            st["outer_iterations"] += 1
        self._F_base = None
        if it >= self.max_iter and r > self.tol * r0:
            raise RuntimeError(f"no equilibrium after {it} iterations (|R| = {r:.3e} N of {r0:.3e} N)")
        return np.where(self.mask, -F.reshape(-1, 3), 0.0), it     # F: the residual at the final state


@dataclasses.dataclass
class FractureCurve:
    """Load-displacement record of :func:`quasi_static_fracture`.

    Attributes
    ----------
    displacement : (k,) float
        lambda of every equilibrium (m).
    load : (k,) float
        Reaction along the loading direction (N).
    broken : (k,) int
        Directed bonds broken before that equilibrium (0 for a new load step).
    newton_iterations : (k,) int
    index_max : (k,) float
        Largest failure index after the equilibrium.
    first_broken : (m,) int64
        Directed bonds in the order they broke (``first_broken_round`` gives the
        equilibrium index at which each broke).
    wall_s : float
    time_split_s : dict
        Where the time went: ``newton`` (assembly + factorisation + residuals),
        ``failure`` (index evaluation, breaking, Upsilon recomputation).
    """

    displacement: np.ndarray
    load: np.ndarray
    broken: np.ndarray
    newton_iterations: np.ndarray
    index_max: np.ndarray
    first_broken: np.ndarray
    first_broken_round: np.ndarray
    wall_s: float
    time_split_s: dict
    stop_reason: str

    @property
    def peak(self) -> tuple[float, float]:
        """(P_c, displacement at P_c): the peak of the curve (N, m)."""
        k = int(np.argmax(self.load))
        return float(self.load[k]), float(self.displacement[k])

    def as_dict(self) -> dict:
        return {"displacement_m": self.displacement.tolist(), "load_N": self.load.tolist(),
                "broken": self.broken.tolist(), "newton_iterations": self.newton_iterations.tolist(),
                "index_max": self.index_max.tolist(), "P_c_N": self.peak[0],
                "displacement_at_P_c_m": self.peak[1], "wall_s": self.wall_s,
                "time_split_s": self.time_split_s, "stop_reason": self.stop_reason}


def quasi_static_fracture(model, state, *, fixed, u_dir, u_max: float, d_lambda: float,
                          order: float = 2.0, stop_fraction: float = 0.2,
                          max_equilibria: int = 2000, max_rounds: int = 1000,
                          overshoot: float = 1e-6, progress: bool = False,
                          tol: float = 1e-9) -> FractureCurve:
    """Displacement-controlled quasi-static fracture (module docstring); mutates ``state``.

    Parameters
    ----------
    model : Model
        Prepared, with ``residual``, ``tangent``, ``failure_index`` and ``break_bonds``.
    state : State
        Start state (reference); ``y`` and ``intact`` are updated.
    fixed : (N, 3) bool
        Constrained dofs (driven and held).
    u_dir : (N, 3) float
        Displacement of the constrained dofs per unit lambda (zero on held dofs).
    u_max : float
        Largest lambda (m).
    d_lambda : float
        Largest load increment (m).
    order : float
        Exponent of the failure index in lambda used to step to the next failure
        (0 disables the prediction).
    stop_fraction : float
        Stop once the load has fallen below this fraction of the peak.
    """
    if not (u_max > 0 and d_lambda > 0):
        raise ValueError(f"u_max={u_max!r}, d_lambda={d_lambda!r}; valid: both > 0")
    fixed = np.asarray(fixed, dtype=bool)
    u_dir = np.asarray(u_dir, dtype=float)
    norm = np.linalg.norm(u_dir[fixed])
    if norm == 0:
        raise ValueError("u_dir is zero on every constrained dof: nothing drives the body")
    t0 = time.perf_counter()
    tsplit = {"newton": 0.0, "failure": 0.0}
    lam = 0.0
    rec = {k: [] for k in ("d", "P", "b", "it", "phi")}
    order_b, round_b = [], []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=max_equilibria, desc="equilibria", unit="solve")

    eq = Equilibrium(model, fixed, tol=tol)

    def equilibrate(dl, broken):
        ts = time.perf_counter()
        reaction, its = eq.solve(state, lam * u_dir)
        tsplit["newton"] += time.perf_counter() - ts
        P = float(np.sum(reaction * u_dir)) / float(np.max(np.abs(u_dir)))
        ts = time.perf_counter()
        phi = model.failure_index(state)
        tsplit["failure"] += time.perf_counter() - ts
        rec["d"].append(lam)
        rec["P"].append(P)
        rec["b"].append(broken)
        rec["it"].append(its)
        rec["phi"].append(float(phi.max()) if phi.size else 0.0)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(P=f"{P:.4g}", lam=f"{lam:.4g}")
        return P, phi

    stop = "u_max"
    phi_max = 0.0
    while lam < u_max and len(rec["d"]) < max_equilibria:
        dl = d_lambda
        if order > 0 and lam == 0:
            dl = 1e-2 * d_lambda      # a probe load: the prediction needs one equilibrium
        if order > 0 and phi_max > 0 and lam > 0:
            dl = min(dl, lam * (phi_max ** (-1.0 / order) * (1 + overshoot) - 1.0))
            dl = max(dl, 1e-6 * d_lambda)
        if lam > 0:   # linear predictor: scale the last displacement field to the new load
            free = ~eq.mask
            u = state.y - model.system.x0
            state.y[free] = model.system.x0[free] + u[free] * ((lam + dl) / lam)
        lam += dl
        P, phi = equilibrate(dl, 0)
        rounds = 0
        while rounds < max_rounds and len(rec["d"]) < max_equilibria:
            ts = time.perf_counter()
            before = state.intact.copy()
            k = model.break_bonds(state)
            tsplit["failure"] += time.perf_counter() - ts
            if k == 0:
                break
            newly = np.flatnonzero(before & ~state.intact)
            order_b.append(newly)
            round_b.append(np.full(newly.size, len(rec["d"])))
            P, phi = equilibrate(0.0, k)
            rounds += 1
            if P < stop_fraction * max(rec["P"]):
                break
        phi_max = float(phi.max()) if phi.size else 0.0
        pk = max(rec["P"])
        if pk > 0 and rec["P"][-1] < stop_fraction * pk:
            stop = "load dropped"
            break
    else:
        if len(rec["d"]) >= max_equilibria:
            stop = "max_equilibria"
    if bar is not None:
        bar.close()
    fb = np.concatenate(order_b) if order_b else np.zeros(0, np.int64)
    fr = np.concatenate(round_b) if round_b else np.zeros(0, np.int64)
    tsplit["solver"] = dict(eq.stats)
    return FractureCurve(np.array(rec["d"]), np.array(rec["P"]), np.array(rec["b"], int),
                         np.array(rec["it"], int), np.array(rec["phi"]), fb, fr,
                         time.perf_counter() - t0, tsplit, stop)
