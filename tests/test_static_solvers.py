"""The engine's one solver interface (upscale.engine.solvers) through the static solvers:
every method gives the SuperLU solution of the same stiffness, bad names are refused in one
line, and a preconditioned CG that cannot converge falls back to a direct solve and says so."""
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

from upscale.engine import State, build_family, solvers
from upscale.engine.static import solve_linear
from upscale.engine.system import square_lattice
from upscale.models.tipd import TiPD


def _body():
    s = square_lattice(14, 10, 1e-3)
    f = build_family(s, 3.015e-3)
    m = TiPD(np.array([[5.0, 3.0, 0.4], [3.0, 5.0, 0.1], [0.4, 0.1, 6.0]]) * 1e9, surface="none")
    m.prepare(s, f)
    fixed = (s.x0[:, 0] < 2.5e-3) | (s.x0[:, 0] > 10.5e-3)
    ub = np.zeros((s.n, 3))
    ub[s.x0[:, 0] > 10.5e-3, 0] = 1e-6
    fe = np.zeros((s.n, 3))
    fe[~fixed, 1] = 1e-3
    return s, f, m, fixed, ub, fe


def test_every_method_gives_the_superlu_solution():
    s, f, m, fixed, ub, fe = _body()
    sols = {}
    for method in ("direct", "cholmod", "amg", "cg"):
        st = State.reference(s.x0, f.nb)
        info = solve_linear(m, st, fixed=fixed, u_prescribed=ub, f_ext=fe, method=method, tol=1e-13)
        assert info["residual"] < 1e-9, method
        sols[method] = st.y - s.x0
    ref = sols["direct"]
    for method in ("cholmod", "amg", "cg"):
        assert np.abs(sols[method] - ref).max() < 1e-9 * np.abs(ref).max(), method


def test_multigrid_needs_fewer_iterations_than_jacobi():
    s, f, m, fixed, ub, fe = _body()
    its = {}
    for method in ("amg", "cg"):
        st = State.reference(s.x0, f.nb)
        its[method] = solve_linear(m, st, fixed=fixed, u_prescribed=ub, f_ext=fe, method=method,
                                   tol=1e-10)["iterations"]
    assert its["amg"] < its["cg"] / 3


def test_factor_keeps_its_analysis_and_matches_splu():
    rng = np.random.default_rng(0)
    A = sp.random(60, 60, 0.08, random_state=1)
    A = (A @ A.T + 60 * sp.eye(60)).tocsr()
    b = rng.standard_normal(60)
    ch = solvers.Factor("cholmod")
    x1 = ch.factor(A).solve(b)
    A2 = A.copy()
    A2.data *= 2.0                                         # same pattern, new values
    x2 = ch.factor(A2).solve(b)
    assert ch.stats["symbolic"] == 1 and ch.stats["factorisations"] == 2
    assert np.allclose(x1, solvers.direct_solve(A, b, "splu"), rtol=1e-10, atol=0)
    assert np.allclose(x2, 0.5 * x1, rtol=1e-10, atol=0)


def test_bad_names_and_the_direct_fallback():
    with pytest.raises(ValueError, match=r"solver='pardiso'; valid: 'cholmod', 'splu', 'amg'"):
        solvers.Factor("pardiso")
    s, f, m, fixed, ub, fe = _body()
    with pytest.raises(ValueError, match="unknown method 'lu'"):
        solve_linear(m, State.reference(s.x0, f.nb), fixed=fixed, method="lu")
    A = sp.diags(np.linspace(1.0, 1e6, 400)).tocsr()
    b = np.ones(400)
    solvers._WARNED.discard("test fallback")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        for _ in range(2):
            x, its, ok = solvers.pcg(A, b, None, rtol=1e-12, maxiter=3,
                                     direct=lambda r: solvers.direct_solve(A, r), what="test fallback")
    assert ok and its == 3 and np.allclose(A @ x, b)
    said = [str(x.message) for x in w if "test fallback" in str(x.message)]
    assert len(said) == 1 and "solved directly" in said[0]
    x, its, ok = solvers.pcg(A, b, None, rtol=1e-12, maxiter=3)
    assert not ok
