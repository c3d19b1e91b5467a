"""Sparse linear solves of the engine: one interface for the static, Newton and quasi-static
solvers (:mod:`upscale.engine.static`, :mod:`upscale.engine.newton`,
:mod:`upscale.engine.quasistatic`).

A :class:`Factor` is made once with a method name and then factorises matrices of one
sparsity pattern again and again (``factor(A)``), keeping the pattern's symbolic analysis
(ordering, elimination tree, supernodes) while the pattern stays the same; ``solve(b)``
applies the inverse (or, for ``"amg"``, one multigrid cycle, an approximate inverse). Every
method is a maintained library:

``"cholmod"``
    Supernodal sparse Cholesky ``A = L L^T`` (CHOLMOD through cvxopt, AMD ordering) of a
    symmetric positive definite matrix; only the lower triangle is read. The default of the
    quasi-static fracture solver: on the SCB tangent (2D, 31k free dofs, 200 nonzeros a
    row) its numerical factorisation is 7x faster than SuperLU's with the same solve cost
    (the triangular solves stream the factor once each way either way), so a factor can be
    renewed far more often, and the symbolic analysis is paid once per pattern.
``"splu"``
    SuperLU (``scipy.sparse.linalg.splu``, minimum degree on A + A^T): any regular
    matrix, symmetric or not (Newton on a non-symmetric tangent).
``"amg"``
    Smoothed-aggregation algebraic multigrid (pyamg), with the rigid-body modes as near
    null space when given: a preconditioner for conjugate gradients whose set-up and memory
    grow only linearly with the size (large elastic solves where a factor does not fit).

:func:`pcg` is the preconditioned conjugate gradient of all of them (scipy's), and falls
back to a direct solve when it does not converge, saying so once per process.

Unknown names raise a one-line ValueError listing :data:`METHODS`.
"""
from __future__ import annotations

import time
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["METHODS", "Factor", "check_method", "pcg", "direct_solve", "rigid_body_modes", "say_once"]

METHODS = ("cholmod", "splu", "amg")
_WARNED: set = set()


def check_method(method: str, valid=METHODS, what: str = "solver") -> str:
    """``method`` if it is one of ``valid``; else a one-line ValueError naming both."""
    if method not in valid:
        raise ValueError(f"{what}={method!r}; valid: {', '.join(repr(v) for v in valid)}")
    return method


def say_once(key, msg):
    """Warn with ``msg`` the first time ``key`` is seen in this process."""
    if key not in _WARNED:
        _WARNED.add(key)
        warnings.warn(msg, RuntimeWarning, stacklevel=3)


def rigid_body_modes(x, free, dim):
    """Rigid-body displacement modes (translations, rotations) of particles at ``x`` (N, 3)
    restricted to the flat free dofs ``free`` of the (3N,) vector: (n_free, 3) in 2D, (n_free,
    6) in 3D; the near null space of an elastic stiffness (for ``"amg"``)."""
    n = x.shape[0]
    xc = x - x.mean(axis=0)
    cols = []
    for i in range(dim):
        v = np.zeros((n, 3))
        v[:, i] = 1.0
        cols.append(v)
    for a, b in ((0, 1), (1, 2), (0, 2))[:1 if dim == 2 else 3]:
        v = np.zeros((n, 3))
        v[:, a] = -xc[:, b]
        v[:, b] = xc[:, a]
        cols.append(v)
    return np.column_stack([c.ravel()[free] for c in cols])


class Factor:
    """A reusable factorisation (module docstring) of one sparsity pattern.

    Parameters
    ----------
    method : {"cholmod", "splu", "amg"}
    near_null : (n, k) array, optional
        Near null space for ``"amg"`` (e.g. :func:`rigid_body_modes`).

    Attributes
    ----------
    stats : dict
        ``factorisations``, ``symbolic`` (analyses), ``factor_s`` (wall seconds).
    """

    def __init__(self, method: str = "cholmod", *, near_null=None):
        self.method = check_method(method)
        self.near_null = near_null
        self._pattern = None
        self._sym = None
        self._S = None
        self._F = None
        self.stats = {"factorisations": 0, "symbolic": 0, "factor_s": 0.0}
        if method == "cholmod":
            import cvxopt.cholmod  # noqa: F401  (fail here, not at the first factorisation)

    def factor(self, A):
        """Factorise ``A`` (scipy sparse, square); mutates the factor. Raises
        ``ArithmeticError`` (cholmod) when A is not positive definite, RuntimeError (splu)
        when it is singular."""
        t = time.perf_counter()
        if self.method == "cholmod":
            self._cholmod(A)
        elif self.method == "splu":
            self._F = spla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A")
        else:
            import pyamg

            kw = {} if self.near_null is None else {"B": self.near_null}
            self._F = pyamg.smoothed_aggregation_solver(sp.csr_matrix(A), **kw)
            self._M = self._F.aspreconditioner(cycle="V")
        self.stats["factor_s"] += time.perf_counter() - t
        self.stats["factorisations"] += 1
        return self

    def _cholmod(self, A):
        """Numeric factorisation of A's lower triangle; the symbolic analysis and the map
        from A's values to the triangle's are kept while A's pattern is the same."""
        import cvxopt
        import cvxopt.cholmod as cm

        A = sp.csr_matrix(A)
        if not A.has_canonical_format:
            A = A.copy()
            A.sum_duplicates()
        pat = self._pattern
        if pat is None or not (pat[0].shape == A.indptr.shape and pat[1].shape == A.indices.shape
                               and np.array_equal(pat[0], A.indptr) and np.array_equal(pat[1], A.indices)):
            probe = sp.csr_matrix((np.arange(1, A.nnz + 1, dtype=float), A.indices, A.indptr), shape=A.shape)
            L = sp.tril(probe, format="csc")
            L.sort_indices()
            take = L.data.astype(np.int64) - 1        # 1-based in the probe: a value 0 would be dropped
            n = L.shape[0]
            cols = np.repeat(np.arange(n), np.diff(L.indptr))
            self._S = cvxopt.spmatrix(cvxopt.matrix(A.data[take].astype(float)), cvxopt.matrix(L.indices.astype(int)),
                                      cvxopt.matrix(cols.astype(int)), (n, n))
            if len(self._S.V) != L.nnz:   # the triplets were summed or zeros dropped: values would misalign
                raise RuntimeError("cvxopt changed the pattern of the lower triangle; cannot reuse it")
            self._sym = cm.symbolic(self._S, uplo="L")
            self._pattern = (A.indptr.copy(), A.indices.copy(), take)
            self.stats["symbolic"] += 1
        else:
            self._S.V = cvxopt.matrix(A.data[pat[2]].astype(float))
        cm.numeric(self._S, self._sym)
        self._F = self._sym

    def solve(self, b):
        """``A^-1 b`` (one V-cycle for ``"amg"``), a new (n,) array."""
        if self._F is None:
            raise RuntimeError("Factor.solve before factor")
        if self.method == "cholmod":
            import cvxopt
            import cvxopt.cholmod as cm

            x = cvxopt.matrix(np.asarray(b, dtype=float))
            cm.solve(self._F, x)
            return np.asarray(x).ravel()
        if self.method == "splu":
            return self._F.solve(np.asarray(b, dtype=float))
        return self._M.matvec(np.asarray(b, dtype=float))

    def operator(self, n):
        """The inverse as a scipy LinearOperator (n, n) (a CG preconditioner)."""
        return spla.LinearOperator((n, n), matvec=self.solve, dtype=np.float64)


def pcg(A, b, M, *, rtol, maxiter=20000, x0=None, direct=None, what="conjugate gradients", callback=None):
    """Preconditioned CG on ``A`` (matrix or LinearOperator) with the preconditioner ``M``
    (LinearOperator or None): (x, iterations, converged). When CG does not reach ``rtol``
    in ``maxiter`` iterations and ``direct`` (a callable b -> x) is given, x is the direct
    solve instead (converged True), and a warning says so once per process. ``callback``
    is called with the iterate after every iteration."""
    count = [0]

    def cb(xk):
        count[0] += 1
        if callback is not None:
            callback(xk)

    x, info = spla.cg(A, b, x0=x0, rtol=rtol, atol=0.0, maxiter=maxiter, M=M, callback=cb)
    if info == 0 and np.all(np.isfinite(x)):
        return x, count[0], True
    if direct is None:
        return x, count[0], False
    say_once(what, f"{what} did not reach rtol={rtol:g} in {maxiter} iterations; solved directly instead")
    return direct(b), count[0], True


def direct_solve(A, b, method="splu"):
    """``A^-1 b`` by a fresh factorisation (``"cholmod"`` or ``"splu"``)."""
    check_method(method, ("cholmod", "splu"))
    return Factor(method).factor(A).solve(b)
