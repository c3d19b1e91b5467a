"""Quasi-static fracture driver: its equilibrium agrees with the Newton solver, and the
energy-quadratic step lands on the first failure."""
import numpy as np

from upscale.engine import State, build_family, square_lattice
from upscale.engine.newton import solve
from upscale.engine.quasistatic import Equilibrium, quasi_static_fracture
from upscale.models.unified import UnifiedModel

H = 1e-3


def _strip(**kw):
    s = square_lattice(24, 8, H, thickness=5e-3)
    fam = build_family(s, 3.0 * H)
    m = UnifiedModel(E=3.75e9, nu=0.35, stabilisation=0.1, **kw)
    m.prepare(s, fam)
    x = s.x0[:, 0]
    left, right = x < 2.5 * H, x > x.max() - 2.5 * H
    fixed = np.zeros((s.n, 3), bool)
    fixed[left | right, :2] = True
    u = np.zeros((s.n, 3))
    u[right, 0] = 1.0
    return s, fam, m, fixed, u


def test_equilibrium_matches_newton():
    s, fam, m, fixed, u = _strip()
    a = State.reference(s.x0, fam.nb)
    b = State.reference(s.x0, fam.nb)
    ref = solve(m, a, fixed=fixed, u_prescribed=2e-5 * u, steps=1)
    reaction, _ = Equilibrium(m, fixed).solve(b, 2e-5 * u)
    assert np.abs(a.y - b.y).max() < 1e-6 * 2e-5
    assert np.isclose(reaction[:, 0].sum() * 0 + reaction[fixed[:, 0] & (u[:, 0] > 0), 0].sum(),
                      ref.reaction[fixed[:, 0] & (u[:, 0] > 0), 0].sum(), rtol=1e-6)


def test_step_lands_on_first_failure():
    # r_s large enough that the strip fails at ~0.2 % strain: the index is quadratic in the
    # load to O(strain) (Green strain), so the prediction lands within a few 1e-3
    s, fam, m, fixed, u = _strip(K_Ic=2.13e6, r_s=0.2, criterion="energy")
    st = State.reference(s.x0, fam.nb)
    curve = quasi_static_fracture(m, st, fixed=fixed, u_dir=u, u_max=1e-3, d_lambda=1e-3,
                                  stop_fraction=0.5)
    first = int(np.flatnonzero(curve.broken > 0)[0])
    # the equilibrium before the first breaking round sits on the criterion
    assert 1.0 <= curve.index_max[first - 1] < 1.005
    assert curve.load[-1] < 0.5 * curve.peak[0]          # the strip failed
    assert (~st.intact).sum() > 0


def test_solver_options_give_the_same_fracture_curve():
    # forward differences, adaptive inner tolerance, amortised refactorisation and the local
    # correction of the preconditioner (the defaults) against central differences, fixed
    # cg_tol, one factorisation and no local correction: the same equilibria to the outer
    # tolerance, so the same bonds break and the same curve
    import upscale.engine.quasistatic as qs

    curves = []
    for kw in ({}, dict(difference="central", forcing="fixed", refactor="never", local_hops=None)):
        s, fam, m, fixed, u = _strip(K_Ic=2.13e6, r_s=1e-3)
        st = State.reference(s.x0, fam.nb)
        orig = qs.Equilibrium.__init__

        def init(self, *a, _kw=kw, **k):
            orig(self, *a, **{**k, **_kw})

        qs.Equilibrium.__init__ = init
        try:
            curves.append((quasi_static_fracture(m, st, fixed=fixed, u_dir=u, u_max=1e-3, d_lambda=2e-5,
                                                 stop_fraction=0.5, max_equilibria=60), st.intact.copy()))
        finally:
            qs.Equilibrium.__init__ = orig
    (a, ia), (b, ib) = curves
    assert (a.broken > 0).sum() >= 3                      # the run does break bonds
    assert a.time_split_s["solver"]["local_blocks"] > 0 and b.time_split_s["solver"]["local_blocks"] == 0
    assert a.load.size == b.load.size and np.array_equal(ia, ib)
    assert np.allclose(a.load, b.load, rtol=1e-7, atol=1e-9 * np.abs(b.load).max())


def test_equilibrium_bad_options():
    s, fam, m, fixed, u = _strip()
    import pytest

    for kw in (dict(difference="backward"), dict(forcing="ew3"), dict(refactor="always"), dict(eta_max=1.5),
               dict(local_hops=-1)):
        with pytest.raises(ValueError, match=list(kw)[0]):
            Equilibrium(m, fixed, **kw)
