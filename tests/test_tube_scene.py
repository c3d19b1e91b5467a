"""The tube scene, its protocols and the Result type: API and command line agree, the
protocol objects refuse what they cannot run, the figures follow the stated rules."""
import json
import math
import os

import numpy as np
import pytest

from upscale import experiments
from upscale.cli import main
from upscale.experiments.protocols import (Dynamic, QuasiStatic, StopRule, curve_figures,
                                           ramp)
from upscale.experiments.result import Result

SMALL = dict(chirality=(5, 5), length=25.0, model="atomistic", progress=False)


# ----------------------------------------------------------------- protocols
def test_stop_rule_first_drop_in_magnitude():
    rule = StopRule(drop=0.05, after=1)
    s = [0, 1, 2, 3, 2.9, 2.86, 1.0, 0.5]
    assert rule.failed_at(s) == 6          # 2.86 is within 5 % of 3, 1.0 is not
    assert not rule.done(s[:7]) and rule.done(s[:8])
    assert rule.failed_at([-x for x in s]) == 6   # compression: magnitudes
    dyn = StopRule(drop=0.05, below=0.2)
    assert not dyn.done([0, 5, 10, 9, 3]) and dyn.done([0, 5, 10, 9, 1.9])


def test_protocols_refuse_bad_parameters():
    for bad, word in [(dict(step=0), "step=0"), (dict(step=-1e-3), "step=-0.001"),
                      (dict(maximum=0), "maximum=0"), (dict(load="shear"), "load='shear'"),
                      (dict(load="torsion"), "periodic"), (dict(periodic=False), "grip=0"),
                      (dict(step=0.5, maximum=0.4), "step=0.5")]:
        with pytest.raises(ValueError, match=word.replace("(", r"\(")):
            QuasiStatic(**bad)
    with pytest.raises(ValueError, match="speed"):
        Dynamic(speed=0.0)
    with pytest.raises(ValueError, match="temperature"):
        Dynamic(temperature=-1.0)


def test_curve_figures_tension_compression_torsion():
    e = np.arange(0, 0.1001, 0.005)
    s = 1000.0 * e - 2000.0 * e ** 2          # 1 TPa initial slope, peak at 0.25
    s[-1] = 0.5 * s[-2]                       # a drop at the last point
    f = curve_figures(e, s, QuasiStatic())
    assert f["failed"] and f["strain_at_peak"] == pytest.approx(e[-2])
    assert f["strength_GPa"] == pytest.approx(s[-2])
    assert f["youngs_TPa"] == pytest.approx(np.polyfit(e[:5], s[:5], 1)[0] / 1000)
    g = curve_figures(-e, -s, QuasiStatic(load="compression"))
    assert g["strength_GPa"] == pytest.approx(-s[-2]) and g["strain_at_peak"] < 0
    assert g["youngs_TPa"] == pytest.approx(f["youngs_TPa"])
    t = curve_figures(e * 100, s, QuasiStatic(load="torsion", periodic=False, grip=5.0))
    assert t["twist_at_peak_deg"] == pytest.approx(e[-2] * 100)


def test_ramp_stops_one_step_after_the_drop():
    class Spring:
        def __init__(self):
            self.v = 0.0

        def apply(self, v):
            self.v = v

        def relax(self):
            return 0

        def record(self):
            return {"response": self.v if self.v < 0.02 else 0.0}

    out = ramp(Spring(), QuasiStatic(step=0.005, maximum=0.1))
    assert out["failed_at"] == 4 and len(out["curve"]["load"]) == 6


# ----------------------------------------------------------------- Result
def test_result_round_trip_compare_csv_plot(tmp_path):
    r = Result(figures={"strength_GPa": 100.0, "n": 3}, curves={"curve/strain": [0, 0.1],
               "curve/stress_GPa": [0, 50.0], "other/x": [1, 2, 3]},
               fields={"x0": np.zeros((2, 3)), "damage": [0.0, 1.0]},
               meta={"scene": "demo", "schema": 1})
    path = r.to_json(tmp_path / "r.json")
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask      # not mkstemp's 0600
    back = Result.from_json(path)
    assert back.figures == r.figures and np.array_equal(back.fields["x0"], r.fields["x0"])
    ref = Result(figures={"strength_GPa": 80.0}, meta={"scene": "demo"})
    assert r.compare(ref)["strength_GPa"] == pytest.approx(25.0)
    files = r.to_csv(tmp_path)
    assert {p.name for p in files} == {"demo_curve.csv", "demo_other.csv"}
    assert r.plot(tmp_path / "r.png", other=back).stat().st_size > 1000
    with pytest.raises(ValueError, match="figure 'x'"):
        Result(figures={"x": "text"})
    (tmp_path / "bad.json").write_text(json.dumps({"schema": 99}))
    with pytest.raises(ValueError, match="schema 99"):
        Result.from_json(tmp_path / "bad.json")


# ----------------------------------------------------------------- the tube scene
def test_atomistic_tension_api_equals_cli(tmp_path):
    api = experiments.tension(**SMALL, maximum=0.02)
    argv = ["tension", "--chirality", "5,5", "--length", "25", "--model", "atomistic",
            "--maximum", "0.02", "--quiet", "--threads", "1", "--out", str(tmp_path)]
    assert main(argv) == 0
    cli = Result.from_json(tmp_path / "tension.json")
    for k, v in api.figures.items():
        if k != "wall_s" and not (isinstance(v, float) and math.isnan(v)):
            assert cli.figures[k] == pytest.approx(v, rel=1e-9), k
    assert 0.9 < api.figures["youngs_TPa"] < 1.1          # a (5,5) tube with Tersoff
    assert cli.meta["command"].startswith("upscale tension")
    assert (tmp_path / "tension.png").is_file() and (tmp_path / "tension_curve.csv").is_file()


def test_compression_is_negative_with_the_tension_modulus():
    t = experiments.tension(**SMALL, maximum=0.01)
    c = experiments.tension(**SMALL, load="compression", maximum=0.01)
    assert c.figures["strength_GPa"] < 0 and c.figures["strain_at_peak"] < 0
    # the curve softens with strain: the secant over 0-1 % is stiffer in compression, and
    # the two bracket the tangent at zero (a central difference of the same runs)
    Et, Ec = t.figures["youngs_TPa"], c.figures["youngs_TPa"]
    e, st, sc = 0.005, t.curves["curve/stress_GPa"][1], c.curves["curve/stress_GPa"][1]
    E0 = (st - sc) / (2 * e) / 1000
    assert Et < E0 < Ec and (Ec - Et) / E0 < 0.06


def test_torsion_of_a_gripped_tube_gives_a_torque_with_the_twist():
    r = experiments.tension(chirality=(5, 5), length=30.0, model="atomistic", load="torsion",
                            grip=5.0, step=2.0, maximum=6.0, progress=False)
    T = r.curves["curve/torque_eV"]
    assert T[0] == pytest.approx(0.0, abs=1e-3) and np.all(np.diff(T) > 0)
    assert r.figures["twist_at_peak_deg"] == pytest.approx(6.0)


@pytest.mark.parametrize("kw, word", [
    (dict(model="nope"), "model='nope'"),
    (dict(load="shear"), "load='shear'"),
    (dict(protocol="slow"), "protocol='slow'"),
    (dict(load="torsion", grip=0.0), "periodic"),
    (dict(step=-0.01), "step=-0.01"),
    (dict(defects="xx@0.5@0"), "xx"),
    (dict(model="dcbr", defects="sw@0.5@0"), "nothing is left to coarse-grain"),
])
def test_bad_input_is_one_line(kw, word):
    with pytest.raises(ValueError) as exc:
        experiments.tension(**{**SMALL, **kw})
    assert word in str(exc.value) and "\n" not in str(exc.value)


def test_structure_of_other_elements_is_refused():
    from upscale.build import swcnt

    a = swcnt(5, 5, length=25.0)
    a.symbols[0] = "N"
    with pytest.raises(ValueError, match="elements"):
        experiments.tension(a, model="atomistic", progress=False)


def test_unwritable_output_folder_and_removed_flag(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("")
    assert main(["tension", "--model", "atomistic", "--out", str(f / "sub")]) == 2
    assert "cannot write" in capsys.readouterr().err
    assert main(["tension", "--outdir", "x"]) == 2
    assert "use --out" in capsys.readouterr().err


def test_sweep_of_the_tube_scene_by_name(tmp_path):
    """chirality x defects x seed over the scene registered as "tension"."""
    import csv

    from upscale.experiments import sweep

    spec = {"scene": "tension", "output": str(tmp_path / "sw"),
            "params": {"model": "atomistic", "length": 25.0, "maximum": 0.01,
                       "progress": False},
            "grid": {"chirality": [[5, 5], [6, 6]], "defects": ["", "v1@0.5@0"]},
            "seeds": [1, 2], "run": {"workers": 1, "processes": False}}
    rep = sweep.run_sweep(spec, progress=False)
    rows = list(csv.DictReader(open(rep["table"])))
    assert len(rows) == 8 and all(r["status"] == "ok" for r in rows), rep
    E = {(r["chirality"], r["defects"]): float(r["youngs_TPa"]) for r in rows}
    assert len(set(E.values())) == 4 and all(0.8 < e < 1.1 for e in E.values())


@pytest.mark.lammps
def test_lammps_reference_is_run_once_then_cached(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("UPSCALE_CACHE", str(tmp_path / "cache"))
    kw = dict(SMALL, model="lammps", maximum=0.01)
    with pytest.raises(LookupError, match="reference=True"):
        experiments.tension(**kw, reference=False)
    a = experiments.tension(**kw)
    assert "running it now" in capsys.readouterr().out
    b = experiments.tension(**kw, reference=False)          # from the cache now
    assert b.figures["youngs_TPa"] == a.figures["youngs_TPa"]
    ours = experiments.tension(**SMALL, maximum=0.01)
    assert ours.compare(a)["youngs_TPa"] == pytest.approx(0.0, abs=0.05)


def test_no_reference_skips_the_comparison(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("UPSCALE_CACHE", str(tmp_path / "cache"))
    argv = ["tension", "--chirality", "5,5", "--length", "25", "--model", "atomistic",
            "--maximum", "0.01", "--compare", "lammps", "--no-reference", "--quiet",
            "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    assert "no comparison" in capsys.readouterr().err
    assert (tmp_path / "o" / "tension.json").is_file()
