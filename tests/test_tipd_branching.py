"""The branching scene's crack measurement (``upscale.experiments.scenes.tipd_branching.measure``) on
synthetic damage histories whose speed, branch point and angle are known, and the
sampling that lets it be repeated without rerunning the dynamics."""
import numpy as np
import pytest

from upscale.experiments.scenes.tipd_branching import LX, LY, branch_angle, measure, rayleigh_speed, simulate


def _lattice(dx):
    nx, ny = int(round(LX / dx)), int(round(LY / dx))
    xs = (np.arange(nx) - (nx - 1) / 2) * dx
    ys = (np.arange(ny) - (ny - 1) / 2) * dx
    return np.column_stack([np.repeat(xs, ny), np.tile(ys, nx)]), nx, ny


def _run(onset_time, dx=0.5e-3, dt=0.05e-6, t_end=30e-6):
    """A run dict as :func:`simulate` returns it, from the time (s) at which each particle's
    damage reaches 0.35 (inf: never)."""
    x, nx, ny = _lattice(dx)
    steps = int(round(t_end / dt))
    t = onset_time(x)
    on = np.where(np.isfinite(t), np.ceil(np.minimum(t, 1e3) / dt), steps + 1).astype(np.int64)
    on = np.clip(on, 1, steps + 1)
    final = np.where(on <= steps, 0.6, 0.0)
    return {"model": "pmb", "critical": None, "stress_Pa": 12e6, "dx_m": dx, "m": 3.0,
            "delta_m": 3 * dx, "horizon_m": 3 * dx, "partial_volume": None, "nx": nx, "ny": ny, "load_rows": 1,
            "particles": x.shape[0], "dt_s": dt, "steps": steps, "t_end_s": steps * dt, "s0": 0.0,
            "broken_bonds": 0, "sample_every": 1,
            "sample_times": {k: k * dt for k in range(1, steps + 1)}, "onset_step": {0.35: on},
            "positions_m": x, "damage": final}


def _line_crack(v, dx):
    """A straight crack along the two middle rows from the notch at x = 0, at speed v."""
    def onset(x):
        on_line = (np.abs(x[:, 1]) < dx) & (x[:, 0] > -dx)
        return np.where(on_line, np.maximum(x[:, 0], 0) / v, np.inf)
    return onset


def test_straight_crack_speed_is_recovered():
    v, dx = 1500.0, 0.5e-3
    r = measure(_run(_line_crack(v, dx), dx=dx))
    # the path's points are timed to the step (0.05 us): ~dt / (window / 2) = 5 %
    assert r["v_max_m_per_s"] == pytest.approx(v, rel=0.05)
    assert r["branching_x_m"] is None and r["branch_angle_deg"] is None
    assert r["asymmetry_fraction"] == 0.0
    assert r["v_max_over_cR"] == pytest.approx(r["v_max_m_per_s"] / rayleigh_speed())


@pytest.mark.parametrize("theta", [20.0, 35.0])
def test_symmetric_branches_angle_and_origin(theta):
    """A crack at v to x_b, then two straight branches at +-theta: the measured angle and
    origin are the true ones; the detection point lies 2 delta / tan(theta) past x_b."""
    v, dx, xb = 1500.0, 0.5e-3, 20e-3
    delta, tb = 3 * dx, xb / v
    tn = np.tan(np.radians(theta))
    line = _line_crack(v, dx)

    def onset(x):
        t = np.where(x[:, 0] <= xb, line(x), np.inf)
        s = x[:, 0] - xb
        for sgn in (1, -1):
            near = (s > 0) & (np.abs(sgn * x[:, 1] - s * tn) * np.cos(np.radians(theta)) < 0.75 * dx)
            t = np.where(near, np.minimum(t, tb + s / np.cos(np.radians(theta)) / v), t)
        return t

    r = measure(_run(onset, dx=dx))
    assert r["branch_angle_deg"] == pytest.approx(theta, abs=1.5)
    assert r["branch_origin_x_m"] == pytest.approx(xb, abs=2 * dx)
    assert r["branching_x_m"] == pytest.approx(xb + 2 * delta / tn, abs=2 * dx)
    assert r["asymmetry_fraction"] == 0.0


def test_coalescence_jump_is_not_a_speed():
    """Damage that grows ahead, apart from the crack, and joins it: the join moves the tip by
    more than delta at once; ``v_max`` leaves that window out, the other peak keeps it."""
    v, dx = 1500.0, 0.5e-3
    line = _line_crack(v, dx)

    def onset(x):
        t = line(x)
        blob = (np.abs(x[:, 1]) < dx) & (x[:, 0] > 12e-3) & (x[:, 0] < 18e-3)
        return np.where(blob, np.minimum(t, 2e-6), t)

    r = measure(_run(onset, dx=dx))
    assert any(c["advances_tip"] for c in r["coalescence"])
    assert r["v_max_with_coalescence_m_per_s"] > 2 * v
    assert r["v_max_m_per_s"] == pytest.approx(v, rel=0.15)


@pytest.mark.parametrize("v", [1000.0, 1500.0, 2500.0, 3000.0])
def test_peak_of_the_recorded_tip_is_biased_and_the_path_is_not(v):
    """The recorded tip crosses a 0.5 mm particle every dx / v: the largest sliding 2 us slope
    of that staircase reads high (+29 % at 1000 m/s). The path's points are exact in x and
    timed to the step, dt = 0.05 us: their slope errs by at most ~dt / (window / 2) = 5 %
    (measured +2.5 to +4.1 %); the mean of the recorded slopes is within 2 %."""
    dx = 0.5e-3
    r = measure(_run(_line_crack(v, dx), dx=dx))
    assert r["v_max_m_per_s"] == pytest.approx(v, rel=0.05)
    assert r["v_mean_m_per_s"] == pytest.approx(v, rel=0.02)
    assert r["v_max_records_m_per_s"] >= r["v_max_m_per_s"] - 1e-9 * v
    if v == 1000.0:
        assert r["v_max_records_m_per_s"] > 1.2 * v
        assert measure(_run(_line_crack(v, dx), dx=dx), speed_window=4e-6)["v_max_records_m_per_s"] < 1.1 * v


def test_branch_angle_from_two_points():
    ang, origin = branch_angle((3.0, 1.0), (6.0, 4.0))
    assert ang == pytest.approx(45.0) and origin == pytest.approx(2.0)
    ang, origin = branch_angle((3.0, -1.0), (3.0 + np.sqrt(3), -2.0))
    assert ang == pytest.approx(30.0) and origin == pytest.approx(3.0 - np.sqrt(3))
    assert branch_angle((3.0, 1.0), (2.0, 4.0)) is None


def test_measure_rejects_unsampled_choices():
    run = _run(_line_crack(1500.0, 0.5e-3))
    with pytest.raises(ValueError, match="tip_damage 0.5 was not sampled"):
        measure(run, tip_damage=0.5)
    with pytest.raises(ValueError, match="tip_damage must lie in"):
        measure(run, tip_damage=1.2)
    run["sample_every"] = 4
    with pytest.raises(ValueError, match="not a multiple"):
        measure(run, record_dt=0.25e-6)


def test_sampling_every_step_gives_the_recorded_crack():
    """Damage never decreases, so a run sampled every step and measured at the record
    interval equals a run sampled at that interval (same dynamics, same records)."""
    kw = dict(stress=24e6, dx=1e-3, t_end=20e-6)
    a = simulate("pmb", sample_dt=None, thresholds=(0.25, 0.35), **kw)
    b = simulate("pmb", sample_dt=0.25e-6, thresholds=(0.35,), **kw)
    ra, rb = measure(a), measure(b)
    assert ra["tip_x_m"] == rb["tip_x_m"] and ra["tip_t_s"] == rb["tip_t_s"]
    assert ra["v_max_m_per_s"] == rb["v_max_m_per_s"]
    assert max(ra["tip_x_m"]) > 5e-3          # the crack ran
    assert measure(a, tip_damage=0.25)["tip_x_m"][-1] >= ra["tip_x_m"][-1]


def test_command_line_branching_writes_result_and_map(tmp_path, capsys):
    """``upscale tipd --case branching`` at dx = 1 mm: the printed figures, the JSON (the
    damage per particle in it) and the picture."""
    from upscale.cli import main
    from upscale.experiments.result import Result

    out = tmp_path / "br"
    assert main(["tipd", "--case", "branching", "--stress", "24e6", "--quiet", "--out", str(out)]) == 0
    printed = {ln.split()[0]: ln.split()[1] for ln in capsys.readouterr().out.splitlines()[2:]}
    saved = Result.from_json(out / "tipd.json")
    assert saved.meta["settings"]["partial_volume"] == "linear"
    assert 0 < saved.figures["v_max_over_cR"] < 1
    assert float(printed["v_max_over_cR"]) == pytest.approx(saved.figures["v_max_over_cR"], rel=1e-5)
    assert saved.fields["damage"].shape == (4000,) and saved.fields["x0"].shape == (4000, 3)
    assert (out / "tipd.png").read_bytes()[:4] == b"\x89PNG"


def test_lattice_fracture_energy_by_hand():
    """m = 1 without partial volumes keeps only the four nearest neighbours: along the lattice
    axis one bond of length dx crosses the cut per dx, so G = (1/2) c s0^2 dx^4 t, twice the
    continuum c s0^2 t delta^4 / 4; along the diagonal sqrt(2)/dx bonds per length cross:
    2 sqrt(2). The isotropic Ti-PD bond energy is PMB's, so the two ratios are equal."""
    from upscale.experiments.scenes.tipd_branching import lattice_fracture_energy

    for model in ("pmb", "tipd"):
        r = lattice_fracture_energy(model, dx=5e-4, m=1.0, partial_volume=None)
        assert r["G_lattice_over_G0"] == pytest.approx(2.0, rel=1e-8)
        r = lattice_fracture_energy(model, dx=5e-4, m=1.0, partial_volume=None, angle_deg=45.0)
        assert r["G_lattice_over_G0"] == pytest.approx(2 * np.sqrt(2), rel=3e-3)


def test_lattice_fracture_energy_tends_to_the_continuum():
    from upscale.experiments.scenes.tipd_branching import lattice_fracture_energy

    err = {}
    for m in (3.0, 6.0):
        g = [lattice_fracture_energy("tipd", dx=1.5e-3 / m, m=m, angle_deg=a)["G_lattice_over_G0"]
             for a in (0.0, 30.0)]
        err[m] = max(abs(v - 1) for v in g)
    assert err[6.0] < 0.02 < err[3.0] < 0.08
    tipd = lattice_fracture_energy("tipd", dx=5e-4, m=3.0, angle_deg=30.0)
    pmb = lattice_fracture_energy("pmb", dx=5e-4, m=3.0, angle_deg=30.0)
    assert tipd["G_lattice_over_G0"] == pytest.approx(pmb["G_lattice_over_G0"], rel=1e-10)
    assert tipd["stiffness_1111_over_continuum"] == pytest.approx(1.0316, abs=1e-3)


@pytest.mark.parametrize("kw, match", [({"model": "lps"}, "pair model"), ({"window": 2.5}, "whole number"),
                                       ({"angle_deg": float("nan")}, "finite"), ({"offsets": 0}, "positive")])
def test_lattice_fracture_energy_rejects_bad_input(kw, match):
    from upscale.experiments.scenes.tipd_branching import lattice_fracture_energy

    with pytest.raises(ValueError, match=match):
        lattice_fracture_energy(**kw)


def test_a_run_resumed_from_its_checkpoint_ends_as_the_uninterrupted_one(tmp_path, monkeypatch):
    """The checkpoint carries the state, the onset steps and the sample times: a run killed
    after an intermediate checkpoint (its file put back as the last one written) and resumed
    gives the uninterrupted run's damage, onsets and times bit for bit."""
    import shutil

    from upscale.engine.checkpoint import Checkpoint, load_checkpoint

    kw = dict(stress=24e6, dx=2e-3, t_end=6e-6, sample_dt=None)
    ref = simulate("pmb", **kw)
    ck, kept = tmp_path / "ck.npz", []
    write = Checkpoint.write

    def keep(self, state, *a, **k):  # every generation kept, as a kill would find it
        p = write(self, state, *a, **k)
        kept.append(shutil.copy(p, tmp_path / f"ck_{state.step}.npz"))
        return p

    monkeypatch.setattr(Checkpoint, "write", keep)
    simulate("pmb", checkpoint=ck, checkpoint_every=7, **kw)
    monkeypatch.undo()
    mid = [f for f in kept if 0 < load_checkpoint(f)[0].step < ref["steps"]][-1]
    shutil.copy(mid, ck)
    res = simulate("pmb", checkpoint=ck, checkpoint_every=7, **kw)
    assert res["steps"] == ref["steps"] and res["broken_bonds"] == ref["broken_bonds"] > 0
    assert np.array_equal(res["damage"], ref["damage"])
    assert np.array_equal(res["onset_step"][0.35], ref["onset_step"][0.35])
    assert res["sample_times"] == ref["sample_times"]
