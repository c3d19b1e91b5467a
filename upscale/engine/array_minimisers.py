"""Array-level minimisers: the engine's methods on flat arrays.

The same methods on a flat vector (or a list of arrays) for a model that is its own
configuration space (e.g. a coarse tube whose unknowns are particles, free atoms and
sublattice shifts, with its cell length as a further unknown): the model supplies the
energy and gradient, these functions own the iterations. Each returns an
:class:`ArrayMinimum`.

:func:`lbfgs_b`
    ``scipy.optimize.minimize(method="L-BFGS-B")`` with scipy's own stopping rules
    (``gtol`` on the largest projected gradient component, ``ftol`` on the relative energy
    change); a trial point off the model's domain (non-finite unknowns, energy or gradient,
    or a ``FloatingPointError``) gets an infinite energy so that the line search steps back,
    and the lowest finite point seen is returned if scipy ends on such a point (after such
    a trial scipy can stop above ``gtol`` and still report success: a caller checks the
    gradient at the result).
:func:`bfgs`
    Unbounded BFGS (``scipy.optimize.minimize(method="BFGS")``) for a few unknowns (a
    lattice cell's parameters).
:func:`newton`
    Newton's method with a finite-difference Hessian of the gradient, for a few unknowns
    whose minimum must be found to round-off (where BFGS's line search stops short).
:func:`quick_min_blocks`
    Quick-min on a list of arrays (positions, shifts, ...), each with its masses and an
    optional symmetric bound: the velocity projected on the force over all blocks, a step
    of at most ``max_step`` per component (LAMMPS ``min_style quickmin`` with its
    ``dmax``), until ``|F|_2 < ftol``.
:func:`restarted`
    A minimisation restarted from its own result while a test fails (e.g. quick-min then
    L-BFGS again while a force is left, or a trial start across a discontinuity).
:func:`first_lower`
    The first of several trial starts whose minimum lies below a given energy.
:func:`zero_cell_force`
    A secant iteration on a cell length to zero cell force, the other unknowns minimised at
    every length.
"""
from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["ArrayMinimum", "lbfgs_b", "one_blas_thread", "bfgs", "newton", "quick_min_blocks",
           "restarted", "first_lower", "zero_cell_force"]


@dataclasses.dataclass
class ArrayMinimum:
    """Result of an array-level minimisation (module docstring).

    Attributes
    ----------
    x : ndarray or list of ndarray
        The minimiser's last iterate (a flat vector, or the blocks of
        :func:`quick_min_blocks`).
    energy : float or None
        The objective at ``x`` as the method last evaluated it (None: not evaluated).
    iterations : int
    n_force : int
        Gradient (force) evaluations.
    converged : bool
        The method's own stopping test was met (scipy's ``success``; quick-min: ``|F| <
        ftol``).
    message : str
    """

    x: object
    energy: float | None
    iterations: int
    n_force: int
    converged: bool
    message: str = ""


_BLAS_CONTROLLER = None


def one_blas_thread():
    """Context in which BLAS runs on one thread. scipy's L-BFGS-B makes many small BLAS
    calls per iteration (vectors of the unknowns, tens of correction pairs); with OpenBLAS's
    threads on a small, shared machine those cost several times more than on one thread
    (and the spinning threads slow the energy evaluations in between), while the vectors
    are far too short for threads to pay. Same algorithm and stopping rules."""
    global _BLAS_CONTROLLER
    from threadpoolctl import ThreadpoolController

    if _BLAS_CONTROLLER is None:
        _BLAS_CONTROLLER = ThreadpoolController()
    return _BLAS_CONTROLLER.limit(limits=1, user_api="blas")


def lbfgs_b(fun, x0, lo=None, hi=None, *, gtol: float, max_iter: int, memory: int = 10,
            ftol: float = 0.0, maxfun: int | None = None, maxls: int = 20,
            single_blas_thread: bool = True) -> ArrayMinimum:
    """L-BFGS-B (Byrd, Lu, Nocedal, Zhu 1995) of ``fun(x) -> (E, dE/dx)`` from ``x0`` (n,).

    ``lo``, ``hi``: bounds, scalars or (n,) arrays (None or +-inf: none). ``gtol``: scipy's
    test on the largest projected gradient component; ``ftol``: its relative energy change
    test (0: off); ``memory``: correction pairs (scipy's ``maxcor``); ``maxfun``: energy
    evaluations (default ``20 max_iter``); ``maxls``: line-search steps per iteration;
    ``single_blas_thread``: run in :func:`one_blas_thread`. A point off the domain is given
    an infinite energy (module docstring).
    """
    from scipy.optimize import Bounds, minimize

    x0 = np.asarray(x0, dtype=float)
    n = x0.size
    lo = np.array(np.broadcast_to(np.asarray(-np.inf if lo is None else lo, float), (n,)))
    hi = np.array(np.broadcast_to(np.asarray(np.inf if hi is None else hi, float), (n,)))
    if np.any(lo > hi):
        k = int(np.flatnonzero(lo > hi)[0])
        raise ValueError(f"lbfgs_b: lower bound {lo[k]!r} above upper bound {hi[k]!r} at {k}")
    best = [np.inf, None]

    def guarded(x):
        if not np.all(np.isfinite(x)):
            return np.inf, np.zeros_like(x)
        try:
            E, g = fun(x)
        except FloatingPointError:
            return np.inf, np.zeros_like(x)
        if not (np.isfinite(E) and np.all(np.isfinite(g))):
            return np.inf, np.zeros_like(x)
        if E < best[0]:
            best[0], best[1] = E, x.copy()
        return E, g

    options = {"maxiter": int(max_iter), "maxcor": int(memory), "gtol": gtol, "ftol": ftol,
               "maxfun": int(20 * max_iter if maxfun is None else maxfun)}
    if maxls != 20:
        options["maxls"] = int(maxls)
    import contextlib

    with one_blas_thread() if single_blas_thread else contextlib.nullcontext():
        res = minimize(guarded, x0, jac=True, method="L-BFGS-B", bounds=Bounds(lo, hi),
                       options=options)
    x, E = res.x, float(res.fun)
    if not np.all(np.isfinite(x)) and best[1] is not None:
        x, E = best[1], float(best[0])  # the last good point, not the trial off the domain
    return ArrayMinimum(x, E, int(res.nit), int(res.nfev), bool(res.success), str(res.message))


def bfgs(fun, x0, *, gtol: float, max_iter: int) -> ArrayMinimum:
    """Unbounded BFGS of ``fun(x) -> (E, dE/dx)`` (a few unknowns), scipy's ``gtol`` test on
    the gradient's largest component."""
    from scipy.optimize import minimize

    res = minimize(fun, np.asarray(x0, dtype=float), jac=True, method="BFGS",
                   options={"gtol": gtol, "maxiter": int(max_iter)})
    return ArrayMinimum(res.x, float(res.fun), int(res.nit), int(res.njev), bool(res.success),
                        str(res.message))


def newton(fun, x0, *, gtol: float, max_iter: int = 50, h: float = 1e-6) -> ArrayMinimum:
    """Newton's method for ``fun(x) -> (E, dE/dx)`` of a few unknowns, the Hessian by
    central differences of the gradient (step ``h``, symmetrised): x <- x - H^-1 g until the
    gradient's largest component is at most ``gtol`` (``success``), or the step has fallen
    to round-off (1e-15 |x|) or ``max_iter`` iterations have passed (then not). Quadratic
    convergence reaches a gradient at round-off in a few iterations where BFGS's line search
    stops short of it ("precision loss"); so the result depends only on ``x0`` and ``fun``.
    A Hessian that is not positive definite (Cholesky fails), or a non-finite step, ends
    it unsuccessful at the last iterate: the caller decides (e.g. falls back to
    :func:`bfgs`)."""
    x = np.array(x0, dtype=float, copy=True)
    E, g = fun(x)
    nf, n = 1, len(x)
    it = 0
    while np.abs(g).max() > gtol and it < int(max_iter):
        H = np.empty((n, n))
        for k in range(n):
            xp, xm = x.copy(), x.copy()
            xp[k] += h
            xm[k] -= h
            H[:, k] = (fun(xp)[1] - fun(xm)[1]) / (2.0 * h)
        nf += 2 * n
        try:
            c = np.linalg.cholesky(0.5 * (H + H.T))
        except np.linalg.LinAlgError:
            return ArrayMinimum(x, float(E), it, nf, False, "Hessian not positive definite")
        dx = -np.linalg.solve(c.T, np.linalg.solve(c, g))
        if not np.all(np.isfinite(dx)):
            return ArrayMinimum(x, float(E), it, nf, False, "non-finite Newton step")
        x = x + dx
        E, g = fun(x)
        nf += 1
        it += 1
        if np.abs(dx).max() <= 1e-15 * max(1.0, np.abs(x).max()):
            break
    ok = bool(np.abs(g).max() <= gtol)
    return ArrayMinimum(x, float(E), it, nf, ok, "converged" if ok else
                        f"gradient {np.abs(g).max():.3g} > gtol {gtol:g} after {it} iterations")


def quick_min_blocks(forces, x, mass, *, dt: float, steps: int, max_step: float, ftol: float,
                     bounds=None, acc: float = 1.0) -> ArrayMinimum:
    """Quick-min on the blocks ``x`` (list of arrays, copied; module docstring).

    ``forces(x) -> list of force arrays`` (held components zero); ``mass``: per block an
    array broadcasting against it; ``acc``: force / mass to length / time^2 (e.g. eV/Å/amu
    to Å/fs^2); ``bounds``: per block None or b (the block is clipped to [-b, b]). Each
    step: v += F / m acc dt; v = (v . F) F / |F|^2 if v . F > 0 (sums over every block),
    else v = 0; x += v dt, scaled so that no component moves more than ``max_step``. Stops
    when ``|F|_2 < ftol`` or after ``steps`` steps.
    """
    if not (np.isfinite(dt) and dt > 0) or int(steps) < 1 or not max_step > 0:
        raise ValueError(f"quick_min_blocks: dt={dt!r}, steps={steps!r}, max_step={max_step!r};"
                         " valid: dt > 0, steps >= 1, max_step > 0")
    x = [np.array(b, dtype=float, copy=True) for b in x]
    bounds = [None] * len(x) if bounds is None else list(bounds)
    v = [np.zeros_like(b) for b in x]
    it = nf = 0
    converged = False
    for _ in range(int(steps)):
        f = forces(x)
        nf += 1
        fnorm2 = 0.0
        for fb in f:
            fnorm2 += np.sum(fb * fb)
        fnorm2 = float(fnorm2)
        if fnorm2 < ftol * ftol:
            converged = True
            break
        for vb, fb, mb in zip(v, f, mass):
            vb += fb / mb * acc * dt
        vf = 0.0
        for vb, fb in zip(v, f):
            vf += np.sum(vb * fb)
        vf = float(vf)
        for vb, fb in zip(v, f):
            if vf <= 0:
                vb[:] = 0.0
            else:
                vb[:] = vf / fnorm2 * fb
        s = [vb * dt for vb in v]
        big = max(np.abs(sb).max() for sb in s)
        if big > max_step:
            s = [sb * (max_step / big) for sb in s]
        for k, (sb, bd) in enumerate(zip(s, bounds)):
            if bd is None:
                x[k] += sb
            else:
                x[k] = np.clip(x[k] + sb, -bd, bd)
        it += 1
    return ArrayMinimum(x, None, it, nf, converged,
                        "" if converged else f"|F| >= ftol {ftol:g} after {it} steps")


def restarted(result, restart, *, done, max_restarts: int):
    """Restart a minimisation from its own result: while ``done(result)`` is false, at most
    ``max_restarts`` times, ``result = restart(result)``; a ``restart`` that returns None (no
    better start) ends it. Returns ``(result, restarts made)``."""
    n = 0
    while n < int(max_restarts) and not done(result):
        new = restart(result)
        if new is None:
            break
        result = new
        n += 1
    return result, n


def first_lower(starts, minimise, energy, below: float, *, accept_any: bool = False):
    """Minimise from each of ``starts`` in turn and return the first result whose
    ``energy(result)`` is below ``below`` (with ``accept_any``: the first result); None if
    there is none."""
    for x in starts:
        r = minimise(x)
        if energy(r) < below or accept_any:
            return r
    return None


def zero_cell_force(relax, L: float, *, tol: float, max_iter: int = 12,
                    first_step: float = 1e-4, max_step: float = 0.1):
    """Cell length at zero cell force by a secant iteration.

    ``relax(L) -> (result, dE/dL)`` minimises the other unknowns at cell length ``L``. The
    first step is ``L (1 -+ first_step)`` down the force, then
    ``L_new = L2 - g2 (L2 - L1) / (g2 - g1)`` until ``|dE/dL| < tol`` or ``max_iter``
    relaxations. A step is at most ``max_step`` L2 long, so that a noisy cell force (the
    relaxations at two lengths ending in different states) cannot throw the length far, or
    below zero. Returns ``(last result, L, relaxations)``: ``L``
    is the length of the last result if it converged, else the next secant estimate.
    """
    hist = []
    out = None
    for _ in range(int(max_iter)):
        out, g = relax(L)
        hist.append((L, g))
        if abs(g) < tol:
            break
        if len(hist) == 1:
            Lnew = L * (1.0 - first_step * np.sign(g))
        else:
            (L1, g1), (L2, g2) = hist[-2], hist[-1]
            Lnew = L2 - g2 * (L2 - L1) / (g2 - g1)
            Lnew = min(max(Lnew, L2 * (1.0 - max_step)), L2 * (1.0 + max_step))
        L = Lnew
    return out, L, len(hist)
