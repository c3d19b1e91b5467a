"""Static solve of a linear model with prescribed displacements: ``K_ff u_f = f_f - K_fc u_c``.

For models whose internal force is linear in the displacement (Ti-PD, correspondence with
the linear law): one symmetric solve instead of Newton iterations or dynamic relaxation.
Either on the assembled stiffness (``model.tangent``, a direct factorisation or conjugate
gradients preconditioned by Jacobi or algebraic multigrid, :mod:`upscale.engine.solvers`) or
matrix-free (conjugate gradients whose product is ``-F_int`` of the model's
own force kernel; for models whose assembled stiffness is too dense, e.g. correspondence
with its 2 delta coupling in 3D).

Units: forces in N per particle, displacements in m.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from upscale.engine import solvers
from upscale.engine.newton import dirichlet

__all__ = ["solve_linear", "LinearSolveError"]


class LinearSolveError(RuntimeError):
    """The linear static solve failed (singular system or CG did not converge)."""


def solve_linear(model, state, *, fixed, u_prescribed=None, f_ext=None,
                 method: str = "direct", tol: float = 1e-11, maxiter: int = 20000,
                 progress: bool = False) -> dict:
    """Equilibrium of a linear model; mutates ``state.y``.

    Parameters
    ----------
    model : Model
        Prepared; ``F_int`` linear in ``u`` and zero at ``u = 0``.
    state : State
        ``state.y`` is set to the solution.
    fixed : bool (N,) or (N, 3)
        Prescribed dofs (2D: z is always fixed).
    u_prescribed : (N, 3), optional
        Displacement of the prescribed dofs (m).
    f_ext : (N, 3), optional
        External force per particle (N).
    method : {"direct", "cholmod", "cg", "amg", "matrix-free"}
        SuperLU on the assembled stiffness, a sparse Cholesky of it (symmetric positive
        definite), Jacobi-preconditioned CG on it, CG preconditioned by smoothed-aggregation
        multigrid with the rigid-body modes (pyamg; a direct solve if it does not converge,
        said once), or CG on the force kernel (Jacobi from the assembled diagonal is not
        available: unpreconditioned).
    tol : float
        CG relative residual tolerance.

    Returns
    -------
    dict with ``method``, ``iterations`` (CG), ``residual`` (|R_free| / |f_free|),
    ``wall_time_s``.

    Raises
    ------
    ValueError
        unknown method, bad shapes; :class:`LinearSolveError` singular or unconverged.
    """
    valid = ("direct", "cholmod", "cg", "amg", "matrix-free")
    if method not in valid:
        raise ValueError(f"unknown method {method!r}; valid: {', '.join(repr(v) for v in valid)}")
    t0 = time.perf_counter()
    sysm = model.system
    n = sysm.n
    mask, ubar, fbar, free = dirichlet(sysm, fixed, u_prescribed, f_ext)
    uc = np.where(mask, ubar, 0.0)
    state.y[...] = sysm.x0 + uc
    rhs = fbar.ravel()[free] + model.residual(state)[free]    # f - K_fc u_c
    info = {"method": method, "iterations": None}

    def embed(v):
        u = np.zeros(3 * n)
        u[free] = v
        return u.reshape(n, 3)

    if method == "matrix-free":
        y0 = state.y.copy()

        def matvec(v):
            state.y[...] = sysm.x0 + embed(v)
            return -model.residual(state)[free]

        A = spla.LinearOperator((free.size, free.size), matvec=matvec, dtype=np.float64)
        M = None
    else:
        K = model.tangent(state).tocsr()
        A = K[free][:, free]
        dg = A.diagonal()
        M = sp.diags(1.0 / np.where(dg > 0, dg, 1.0)) if method == "cg" else None
        if method == "amg":
            near = solvers.rigid_body_modes(sysm.x0, free, sysm.dim)
            M = solvers.Factor("amg", near_null=near).factor(A).operator(free.size)
    if method in ("direct", "cholmod"):
        try:
            v = solvers.direct_solve(A, rhs, "splu" if method == "direct" else "cholmod")
        except (RuntimeError, ArithmeticError) as exc:
            raise LinearSolveError(f"singular stiffness on the free dofs ({exc}); the "
                                   "prescribed dofs must remove every rigid-body mode") from exc
    else:
        count = [0]
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(desc="CG iterations", unit="it")

        def cb(_):
            count[0] += 1
            if bar is not None:
                bar.update(1)

        direct = None
        if method == "amg":
            def direct(b):
                return solvers.direct_solve(A, b, "cholmod")
        v, its, ok = solvers.pcg(A, rhs, M, rtol=tol, maxiter=maxiter, direct=direct, callback=cb,
                                 what="multigrid-preconditioned CG")
        if bar is not None:
            bar.close()
        info["iterations"] = count[0]
        if not ok:
            raise LinearSolveError(f"conjugate gradients did not converge in {maxiter} "
                                   f"iterations (tol {tol:g}); the stiffness may be indefinite "
                                   "or very ill-conditioned on the free dofs")
    if not np.all(np.isfinite(v)):
        raise LinearSolveError("non-finite solution: the stiffness is singular on the free dofs")
    state.y[...] = sysm.x0 + uc + embed(v)
    R = fbar.ravel() + model.residual(state)
    info["residual"] = float(np.linalg.norm(R[free]) / max(np.linalg.norm(rhs), 1e-300))
    info["wall_time_s"] = time.perf_counter() - t0
    return info
