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


def test_convergence_fixed_ratio_alone_runs_the_coarsest_spacing():
    """``scb-convergence --modes "fixed r_s/dx"``: the coarsest spacing is the start of both
    modes, so it is run under the one mode asked for, and the change to the finer spacing
    is reported (r_s = ratio * dx at both)."""
    import argparse

    from validation.cases.scb import run_convergence

    args = argparse.Namespace(quick=True, dxs="3e-3,2e-3", alphas="0", r_s=6e-3,
                              modes="fixed r_s/dx", criterion="principal")
    out = run_convergence(args)
    assert [(r["dx mm"], r["r_s mm"], r["mode"]) for r in out["rows"]] == [
        (3.0, 6.0, "fixed r_s/dx"), (2.0, 4.0, "fixed r_s/dx")]
    (c,) = out["changes"]
    a, b = (r["P_c kN"] for r in out["rows"])
    assert c["mode"] == "fixed r_s/dx" and np.isclose(c["change_pct"], 100 * (b / a - 1))
    assert out["P_c_change_pct_max_fixed_ratio"] == abs(c["change_pct"])
    assert out["P_c_change_pct_max"] is None


def test_convergence_both_modes_share_the_coarsest_spacing():
    """With both modes the coarsest spacing runs once (stored as "fixed m") and is the start
    of both changes; the finer spacing runs once per mode."""
    import argparse

    from validation.cases.scb import run_convergence

    args = argparse.Namespace(quick=True, dxs="3e-3,2e-3", alphas="0", r_s=6e-3,
                              modes="fixed m,fixed r_s/dx", criterion="principal")
    out = run_convergence(args)
    assert [(r["dx mm"], r["r_s mm"], r["mode"]) for r in out["rows"]] == [
        (3.0, 6.0, "fixed m"), (2.0, 6.0, "fixed m"), (2.0, 4.0, "fixed r_s/dx")]
    P = [r["P_c kN"] for r in out["rows"]]
    by_mode = {c["mode"]: c["change_pct"] for c in out["changes"]}
    assert set(by_mode) == {"fixed m", "fixed r_s/dx"}
    assert np.isclose(by_mode["fixed m"], 100 * (P[1] / P[0] - 1))
    assert np.isclose(by_mode["fixed r_s/dx"], 100 * (P[2] / P[0] - 1))


def test_front_limit_kink_and_load():
    """The front criterion's continuum limit: no kink in mode I, a kink that changes sign
    with K_II, and a mode-I initiation load at K_I = K_Ic whatever r_s."""
    from validation.cases.scb import A_CRACK, R, T_THICK, _front_limit_kink, _front_limit_load

    assert _front_limit_kink(2.0, 0.0, -0.7, 1e-3) == 0.0
    a, b = _front_limit_kink(1.0, 0.8, 1.2, 1e-3), _front_limit_kink(1.0, -0.8, 1.2, 1e-3)
    assert -90 < a < -20 and abs(a + b) < 1e-9
    P_lefm = 2.13e6 * 2 * R * T_THICK / (2.0 * np.sqrt(np.pi * A_CRACK))
    for rs in (0.5e-3, 2e-3):
        assert abs(_front_limit_load(2.0, 0.0, 0.0, rs) / P_lefm - 1) < 1e-4


def test_path_offset_against_the_experimental_path():
    """The experimental alpha = 30 deg path read as a model path is 0 mm off; shifted 1 mm
    sideways it is 1 mm off at every height; the heights skip 2 mm at each end."""
    import json

    from validation.cases.scb import PATH_30, path_offset

    exp = json.loads(PATH_30.read_text())
    pts = np.column_stack([exp["x_m"], exp["y_m"]])
    y, xe, xm, off = path_offset(pts, 1e-4)
    assert len(y) >= 10 and y.min() >= exp["y_m"][0] + 2e-3 and y.max() <= exp["y_m"][-1] - 2e-3
    assert np.allclose(off, 0.0, atol=1e-12)
    off1 = path_offset(pts + [1e-3, 0.0], 1e-4)[3]
    assert np.allclose(off1, 1e-3, atol=1e-12)


def test_convergence_reuses_a_finished_run(tmp_path):
    """``scb-convergence --reuse``: an ``upscale scb`` run (stopped later, at half the peak)
    stands in for the sweep's run of the same alpha, dx, m, r_s and gives the P_c the sweep
    computes itself; a run of another growth rule is refused with a one-line error."""
    import argparse

    from upscale.experiments.scenes.scb import run_scb
    from validation.cases.scb import run_convergence

    run_scb(0.0, dx=3e-3, r_s=6e-3, stop_fraction=0.5, outdir=tmp_path / "a", growth="free")
    kw = dict(quick=True, dxs="3e-3", alphas="0", r_s=6e-3, modes="fixed m", criterion="principal",
              growth="free")
    fresh = run_convergence(argparse.Namespace(**kw, reuse=""))
    reused = run_convergence(argparse.Namespace(**kw, reuse=str(tmp_path / "a")))
    (r0,), (r1,) = fresh["rows"], reused["rows"]
    assert r0["source"] == "run" and r1["source"].endswith("scb.json")
    assert np.isclose(r1["P_c kN"], r0["P_c kN"], rtol=1e-9, atol=0) and r1["equilibria"] == r0["equilibria"]
    with pytest.raises(ValueError, match="growth='free'"):
        run_convergence(argparse.Namespace(**{**kw, "growth": "front"}, reuse=str(tmp_path / "a")))
    # an earlier sweep's JSON (as the case writes it) serves too, row by row
    import json

    (tmp_path / "conv.json").write_text(json.dumps({"result": fresh}))
    again = run_convergence(argparse.Namespace(**kw, reuse=str(tmp_path / "conv.json")))
    assert again["rows"][0]["P_c kN"] == r0["P_c kN"] and "row 0" in again["rows"][0]["source"]
    with pytest.raises(ValueError, match="tip_factor='solved'"):
        run_convergence(argparse.Namespace(**kw, tip_factor="lattice", reuse=str(tmp_path / "conv.json")))


def test_calibration_scan_prefers_the_candidate_in_a_tie(monkeypatch):
    """At dx = 1 mm, r_s = 1 and 1.2 mm hold the same particles in the disc and give P_c
    equal to round-off: the scan keeps the scanned candidate, not the interpolant."""
    import upscale.experiments.scenes.scb as scb
    from validation.cases.scb import calibrate_r_s_scan

    def fake(alpha, *, r_s, **kw):
        P = 2339.342037639868 + max(0.0, r_s - 1.3e-3) / 0.7e-3 * 203.7
        return {"P_c_N": P + (1e-10 if r_s > 1e-3 else 0.0), "wall_s": 0.0}

    monkeypatch.setattr(scb, "run_scb", fake)
    r, hist = calibrate_r_s_scan(1e-3, 2380.0, [1e-3, 2e-3], log=lambda *a: None)
    assert len(hist) == 3 and r == 1e-3
    r, _ = calibrate_r_s_scan(1e-3, 2450.0, [1e-3, 2e-3], log=lambda *a: None)
    assert r not in (1e-3, 2e-3)        # no tie: the interpolant, closer to the target


def test_energy_calibration_secant_reaches_the_target(monkeypatch):
    """The particle-energy criterion's secant on log P_c(log r_s): with P_c ~ r_s^-1/2 it lands
    on the target r_s."""
    import upscale.experiments.scenes.scb as scb
    from validation.cases.scb import calibrate_r_s

    monkeypatch.setattr(scb, "run_scb", lambda alpha, *, r_s, **kw: {"P_c_N": 2380.0 * (0.07 / r_s) ** 0.5,
                                                                      "wall_s": 0.0})
    r, hist = calibrate_r_s(2e-3, 2380.0, log=lambda *a: None)
    assert abs(r / 0.07 - 1) < 0.01 and len(hist) <= 4


def test_coarse_fracture_scene_warns():
    import warnings

    with pytest.warns(UserWarning, match="a/dx = 15"):
        SCBScene(0.0, dx=2e-3, r_s=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SCBScene(0.0, dx=2e-3)              # elastic: no failure, no warning
        SCBScene(0.0, dx=1e-3, r_s=1e-3)
