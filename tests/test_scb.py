"""SCB scene: bad input gives one-line errors naming the value; the geometry is the one of
seed 004 sec. 6.6."""
import numpy as np
import pytest

from upscale.experiments.scenes.scb import SCBScene


@pytest.mark.parametrize("kw,match", [
    ({"alpha_deg": 90.0}, "alpha"), ({"alpha_deg": -1.0}, "alpha"),
    ({"a_over_R": 1.0}, "a/R"), ({"a_over_R": 0.0}, "a/R"),
    ({"dx": 5e-3}, "too coarse"), ({"r_s": 0.0}, "r_s"), ({"r_s": -1e-3}, "r_s"),
    ({"supports": "glued"}, "supports"), ({"nu": 0.5}, "Poisson"),
    ({"r_s": 1e-3, "criterion": "bond"}, "criterion"), ({"r_s": 1e-3, "sequential": 1.5}, "sequential"),
])
def test_bad_input(kw, match):
    kw = {"alpha_deg": 0.0, "dx": 3e-3, **kw}
    alpha = kw.pop("alpha_deg")
    with pytest.raises(ValueError, match=match):
        SCBScene(alpha, **kw)


def test_geometry():
    sc = SCBScene(30.0, dx=3e-3)
    x = sc.system.x0
    assert np.all(x[:, 0] ** 2 + x[:, 1] ** 2 <= 0.05 ** 2) and np.all(x[:, 1] > 0)
    assert np.allclose(sc.tip, 0.015 * np.array([np.sin(np.radians(30)), np.cos(np.radians(30))]))
    # no intact bond crosses the pre-crack
    from upscale.engine import bonds_crossing_segment

    fam = sc.family
    assert not bonds_crossing_segment(x, (0, 0), sc.tip)(fam.owner, fam.neighbors, fam.xi).any()
    # patches: 3 dx boxes at the load point and at x = +-S
    assert np.all(np.abs(x[sc.load, 0]) <= 1.5 * 3e-3 + 1e-12)
    assert np.all(np.abs(np.abs(x[sc.support, 0]) - 0.43 * 0.05) <= 1.5 * 3e-3 + 1e-12)
    assert sc.fixed[sc.support, 1].all() and not sc.fixed[sc.support, 0].any()   # rollers
    # the unbreakable zones are one box per patch: none reaches the mode-I crack's tip or
    # its ligament even at this coarsest allowed spacing (a box over both supports did)
    s0 = SCBScene(0.0, dx=3e-3)
    x = s0.system.x0
    assert not s0.no_fail[np.linalg.norm(x[:, :2] - s0.tip[:2], axis=1) <= 2 * 3e-3].any()
    assert not s0.no_fail[(np.abs(x[:, 0]) < 0.43 * 0.05 - 5 * 3e-3) & (x[:, 1] < 0.03)].any()
    assert s0.no_fail[s0.load | s0.support].all()


def test_williams_fit_recovers_closed_form_tip_field():
    """K_I, K_II, T of the textbook near-tip field (plane stress, right-handed frame (ex, -ey))
    plus a rigid motion, recovered by the Williams least-squares fit; K_II comes back with the
    sign of the mirrored frame of crack_frame."""
    from upscale.experiments.scenes.scb import crack_frame, williams_fit

    E, nu = 3.75e9, 0.35
    mu, kap = E / (2 * (1 + nu)), (3 - nu) / (1 + nu)
    ex, ey = crack_frame(30.0)
    e1, e2 = ex, -ey
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.01, 0.01, (3000, 2))
    x1, x2 = pts @ e1, pts @ e2
    r, th = np.hypot(x1, x2), np.arctan2(x2, x1)
    KI, KII, T = 1.3e6, 0.7e6, 2.0e6
    f = np.sqrt(r / (2 * np.pi)) / (2 * mu)
    u1 = KI * f * np.cos(th / 2) * (kap - 1 + 2 * np.sin(th / 2) ** 2) \
        + KII * f * np.sin(th / 2) * (kap + 1 + 2 * np.cos(th / 2) ** 2) + T * x1 / E
    u2 = KI * f * np.sin(th / 2) * (kap + 1 - 2 * np.cos(th / 2) ** 2) \
        - KII * f * np.cos(th / 2) * (kap - 1 - 2 * np.sin(th / 2) ** 2) - nu * T * x2 / E
    u = np.outer(u1, e1) + np.outer(u2, e2) + np.array([3e-6, -2e-6]) + 1e-4 * np.column_stack([-pts[:, 1], pts[:, 0]])
    ki, kii, t = williams_fit(pts, u, ex, ey, mu, kap, 0.002, 0.009, n_terms=6)
    assert abs(ki / KI - 1) < 1e-6 and abs(kii / -KII - 1) < 1e-6 and abs(t / T - 1) < 1e-6
    with pytest.raises(ValueError, match="annulus"):
        williams_fit(pts, u, ex, ey, mu, kap, 0.00910, 0.00911, n_terms=6)


def test_explicit_rise_bad_input():
    sc = SCBScene(0.0, dx=3e-3)
    with pytest.raises(ValueError, match="rise"):
        sc.explicit(1e-4, 1e-5, rise=2e-4)
    with pytest.raises(ValueError, match="rise"):
        sc.explicit(1e-4, 1e-5, rise=-1e-5)


@pytest.mark.slow
def test_explicit_smooth_rise_removes_the_start_vibration():
    """Elastic SCB driven at constant rate: a velocity jump at t = 0 leaves the load-patch
    reaction vibrating about the static line k d; a smooth rise over a few periods leaves a
    much smaller vibration (SCBScene.explicit docstring), and the patch follows the ramp."""
    sc = SCBScene(0.0, dx=3e-3)
    _, P_static = sc.elastic(d=1e-6)
    k = P_static / 1e-6
    T, u_end = 1e-3, 1e-5
    dev = {}
    for rise in (0.0, 0.5 * T):
        t, d, P, _, _ = sc.explicit(T, u_end, every=1, rise=rise)
        late = t > 0.75 * T
        dev[rise] = np.max(np.abs(P[late] - k * d[late])) / (k * u_end)
        if rise:
            v = u_end / T
            j = np.searchsorted(t, 0.25 * T)
            assert np.isclose(d[j], 0.5 * v * (t[j] - rise / np.pi * np.sin(np.pi * t[j] / rise)), rtol=1e-12)
    assert dev[0.0] > 0.01
    assert dev[0.5 * T] < 0.3 * dev[0.0]


def test_coarse_fracture_scene_warns():
    import warnings

    with pytest.warns(UserWarning, match="a/dx = 15"):
        SCBScene(0.0, dx=2e-3, r_s=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SCBScene(0.0, dx=2e-3)              # elastic: no failure, no warning
        SCBScene(0.0, dx=1e-3, r_s=1e-3)
