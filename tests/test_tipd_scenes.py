"""The linear static solve (direct, CG, matrix-free agree) and the Ti-PD scenes on coarse
bodies: the manufactured solution converges, the free strip recovers a PMB-equivalent
Poisson ratio, the free-body eigenvalue signs follow the indefiniteness rule."""
import numpy as np
import pytest

from upscale.engine import State, build_family, square_lattice
from upscale.engine.static import solve_linear
from upscale.experiments.scenes.tipd import eigen_counts, mms
from upscale.models.tipd import TiPD


def test_solve_linear_methods_agree():
    s = square_lattice(12, 12, 1e-3)
    f = build_family(s, 3.015e-3)
    m = TiPD(np.array([[5.0, 3.0, 0.4], [3.0, 5.0, 0.1], [0.4, 0.1, 6.0]]) * 1e9, surface="none")
    m.prepare(s, f)
    left = s.x0[:, 0] < 2.5e-3
    right = s.x0[:, 0] > 8.5e-3
    fixed = left | right
    ub = np.zeros((s.n, 3))
    ub[right, 0] = 1e-6
    ub[right, 1] = 3e-7
    fe = np.zeros((s.n, 3))
    fe[~fixed, 1] = 1e-3
    sols = []
    for method in ("direct", "cg", "matrix-free"):
        st = State.reference(s.x0, f.nb)
        info = solve_linear(m, st, fixed=fixed, u_prescribed=ub, f_ext=fe, method=method, tol=1e-13)
        assert info["residual"] < 1e-9
        sols.append(st.y - s.x0)
    assert np.abs(sols[1] - sols[0]).max() < 1e-9 * np.abs(sols[0]).max()
    assert np.abs(sols[2] - sols[0]).max() < 1e-9 * np.abs(sols[0]).max()
    with pytest.raises(ValueError, match="unknown method"):
        solve_linear(m, st, fixed=fixed, method="lu")


def test_mms_discrete_calibration_converges_second_order():
    e = [mms("tipd", dim=2, dx=dx, calibration="discrete", surface="none")["rel_l2"] for dx in (0.05, 0.025)]
    assert np.log2(e[0] / e[1]) > 1.8
    c = mms("tipd", dim=2, dx=0.025, calibration="continuum", surface="none")["rel_l2"]
    assert c > 3 * e[1]        # the continuum calibration's lattice bias


def test_mms_surface_correction_second_order_with_two_horizon_layer():
    """With the correction (the default) and the exact field in a two-horizon layer both
    calibrations converge at second order; a one-horizon layer drops it to first."""
    e = [mms("tipd", dim=2, dx=dx, calibration="continuum")["rel_l2"] for dx in (0.05, 0.025)]
    assert np.log2(e[0] / e[1]) > 1.8
    e1 = [mms("tipd", dim=2, dx=dx, calibration="continuum", layer=1.0)["rel_l2"] for dx in (0.05, 0.025)]
    assert np.log2(e1[0] / e1[1]) < 1.3


def test_free_body_eigen_signs():
    kw = {"calibration": "continuum", "n": 7, "surface": "none"}
    assert eigen_counts("tipd", dim=2, nu=0.3, **kw)["negative"] == 0
    assert eigen_counts("tipd", dim=2, nu=0.4, **kw)["negative"] > 0
    r = eigen_counts("tipd", dim=2, nu=1 / 3, **kw)
    assert r["zero"] == 3 and r["negative"] == 0     # PMB-equivalent: rotation costs nothing


def test_newton_solver_on_tipd_and_nosb_matches_linear_solve():
    from upscale.engine.newton import solve
    from upscale.models.correspondence import Correspondence

    s = square_lattice(10, 6, 1e-3)
    f = build_family(s, 3.015e-3)
    fixed = (s.x0[:, 0] < 0.5e-3) | (s.x0[:, 0] > 8.5e-3)
    ub = np.zeros((s.n, 3))
    ub[s.x0[:, 0] > 8.5e-3, 0] = 1e-6
    for m in (TiPD(E=70e9, nu=0.2), Correspondence(E=70e9, nu=0.2, stabilisation="wan")):
        m.prepare(s, f)
        a = State.reference(s.x0, f.nb)
        solve_linear(m, a, fixed=fixed, u_prescribed=ub)
        b = State.reference(s.x0, f.nb)
        r = solve(m, b, fixed=fixed, u_prescribed=ub)
        assert r.converged
        assert np.abs(a.y - b.y).max() < 1e-9 * np.abs(a.y - s.x0).max()
