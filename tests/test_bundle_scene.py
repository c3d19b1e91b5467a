"""The bundle scene as a function returning a Result: a quick variant run as
``experiments.bundle(**kw)`` and as ``upscale bundle ...`` in-process gives the same figures;
the stored LAMMPS reference as a Result with the same figure names; one default per setting;
bad input as one-line errors."""
import argparse
import inspect
import json
import math

import numpy as np
import pytest

from upscale import experiments
from upscale.cli import main
from upscale.experiments import registry
from upscale.experiments.result import Result

#: the smallest bundle the scene takes (two tubes: the atomistic centre and one coarse tube;
#: the van der Waals needs two) on the tests' 60 Å (10,10) tubes, three 100-step samples
QUICK = registry.QUICK["bundle"]


pytestmark = pytest.mark.usefixtures("one_numba_thread")   # as the CLI's --threads 1


def _argv(kw: dict) -> list[str]:
    out = []
    for k, v in kw.items():
        opt = "--" + k.replace("_", "-")
        if isinstance(v, bool):
            out.append(opt if v else "--no-" + k.replace("_", "-"))
        elif isinstance(v, tuple):
            out.append(f"{opt}={','.join(repr(x) for x in v)}")
        else:
            out.append(f"{opt}={v}")
    return out


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, (bool, int)) and isinstance(b, (bool, int)):
        return a == b
    return a == pytest.approx(b, rel=1e-12, abs=0.0)


def test_api_and_command_line_give_the_same_figures(tmp_path, capsys):
    api = experiments.bundle(**QUICK, progress=False)
    assert isinstance(api, Result) and api.scene == "bundle"
    assert main(["bundle", "--out", str(tmp_path), "--quiet", "--threads", "1",
                 *_argv(QUICK)]) == 0
    cli = Result.from_json(tmp_path / "bundle.json")
    assert list(cli.figures) == list(api.figures)
    bad = {k: (cli.figures[k], api.figures[k]) for k in api.figures
           if k != "wall_s" and not _same(cli.figures[k], api.figures[k])}
    assert not bad, bad
    assert cli.meta["params"] == json.loads(json.dumps(api.meta["params"]))  # tuples as lists
    for k, v in api.curves.items():
        np.testing.assert_allclose(cli.curves[k], v, rtol=1e-12, atol=0)
    # what the Result holds: the bundle's figures, per-tube strengths and curves, fields
    f = api.figures
    for k in ("strength_GPa", "strain_at_peak", "youngs_TPa", "tube1_strength_GPa",
              "tube2_strength_GPa", "atoms", "particles", "dof", "wall_s"):
        assert k in f, k
    assert 5.0 < f["strength_GPa"] < 40.0 and 0.7 < f["youngs_TPa"] < 1.2
    assert f["particles"] < f["atoms"] and f["dof"] < 3 * f["atoms"]
    assert {"curve/strain", "curve/stress_GPa", "curve/tube1_stress_GPa",
            "curve/tube2_stress_GPa"} <= set(api.curves)
    assert len(api.curves["curve/strain"]) >= 3
    n = f["particles"]
    assert api.fields["x0"].shape == (n, 3) and api.fields["damage"].shape == (n,)
    assert cli.fields["damage"].shape == (n,)
    m = api.meta
    assert m["seeds"] == [4928459] and m["plot"]["curve"] == {"x": "strain", "y": ["stress_GPa"]}
    assert "2 pi R t" in m["conventions"]["stress_area"]
    assert m["params"]["integrator"] == "respa" and m["params"]["coarse_pairs"] == "atoms"
    assert m["protocol"]["integrator"] == "r-respa" and m["bundle"]["coarse_pairs"] == "atoms"
    assert (tmp_path / "bundle.png").read_bytes()[:4] == b"\x89PNG"
    assert "strength_GPa" in capsys.readouterr().out


def test_lammps_model_is_the_stored_reference_with_the_same_figure_names():
    ref = experiments.bundle(model="lammps", progress=False)
    f = ref.figures
    assert f["strength_GPa"] == pytest.approx(72.86628505732224, rel=1e-12)
    assert f["youngs_TPa"] == pytest.approx(0.963440396934839, rel=1e-12)
    assert f["atoms"] == f["particles"] == 17076 and f["dof"] == 3 * 17076
    for k in range(1, 8):  # per-tube curves from the kept run's rerun file
        assert math.isfinite(f[f"tube{k}_strength_GPa"])
    assert f["central_tube_fails_first"] is True
    assert ref.fields["x0"].shape == (17076, 3)
    assert ref.meta["source"] == ["dyn_10-10_vac4_bundle7.json",
                                  "dyn_10-10_vac4_bundle7_rerun.json"]
    other = experiments.bundle(model="lammps", seed=4928460, progress=False)
    assert other.figures["strength_GPa"] == pytest.approx(73.13987162656849, rel=1e-12)
    # the engine's figure names are the reference's: --compare lammps compares them all
    eng_names = ["strength_GPa", "strain_at_peak", "youngs_TPa", "failure_strain"]
    eng_names += [f"tube{k}_strength_GPa" for k in range(1, 8)]
    assert set(eng_names) <= set(f)
    with pytest.raises(ValueError, match=r"no stored LAMMPS reference dyn_10-10_vac4_bundle2"
                                         r"\.json in .*; compute it with python -m validation"):
        experiments.bundle(**QUICK, model="lammps", progress=False)
    with pytest.raises(ValueError, match="length=60: the stored LAMMPS reference "
                                         "dyn_10-10_vac4_bundle7 has length 150"):
        experiments.bundle(length=60.0, model="lammps", progress=False)


def test_one_default_per_setting():
    """The validated setting (r-RESPA 5 x 1 fs, reconstructed atoms between coarse tubes)
    is the default of the scene function, its command line, BundleScene.create,
    dynamic_tension and the validation case's options."""
    from upscale.experiments.scenes import bundle as b
    from upscale.experiments.scenes.bundle_pull import dynamic_tension

    assert (b.INTEGRATOR, b.INNER, b.COARSE_PAIRS) == ("respa", 5, "atoms")
    scene = inspect.signature(experiments.bundle).parameters
    dyn = inspect.signature(dynamic_tension).parameters
    create = inspect.signature(b.BundleScene.create).parameters
    p = argparse.ArgumentParser()
    b.add_run_options(p)
    case = vars(p.parse_args([]))
    for name, want in (("integrator", "respa"), ("inner", 5), ("coarse_pairs", "atoms"),
                       ("chain", 3), ("thermostat", "bundle"), ("vdw_every", 1),
                       ("max_strain", 0.40)):
        assert scene[name].default == want, name
        assert case[name] == want, name
        if name in dyn:
            assert dyn[name].default == want, name
        if name in create:
            assert create[name].default == want, name
    assert scene["settle"].default == dyn["settle_ps"].default == case["settle"] == 0.0
    assert scene["seed"].default == dyn["seed"].default == 4928459
    assert create["grip_keep"].default is None   # whole coarse tubes (trimming is opt-in)


def test_documented_signature():
    from upscale.experiments.registry import _param_help

    func = registry.get("bundle")
    assert experiments.bundle is func
    helps = _param_help(inspect.getdoc(func))
    for p in inspect.signature(func, eval_str=True).parameters.values():
        assert p.kind is p.KEYWORD_ONLY and p.annotation is not p.empty, p.name
        assert p.default is not p.empty and helps.get(p.name), p.name


@pytest.mark.parametrize("kw,needle", [
    (dict(chirality="ten,ten"), "chirality='ten,ten'; valid: two integers N,M"),
    (dict(chirality=(10,)), "chirality=(10,); valid: two integers N,M"),
    (dict(speed=-1.0), "speed=-1.0 Å/ps; valid: a grip speed > 0"),
    (dict(length=-150.0), "length=-150.0 Å; valid: a tube length > 0"),
    (dict(ntubes=1), "ntubes=1; valid: 2 to 7"),
    (dict(tubes="tersoff,pmb"), "unknown tube model 'pmb'"),
    (dict(integrator="respa", vdw_every=4), "vdw_every=4 with integrator='respa'"),
    (dict(model="nope"), "model='nope'; valid: coarse, lammps"),
])
def test_bad_input_is_a_one_line_error_naming_the_value(kw, needle):
    with pytest.raises(ValueError) as e:
        experiments.bundle(**kw, progress=False)
    msg = str(e.value)
    assert needle in msg and "\n" not in msg


def test_command_line_bad_input(tmp_path, capsys):
    assert main(["bundle", "--speed=-1", "--out", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "upscale bundle: error: speed=-1.0 Å/ps; valid: a grip speed > 0 Å/ps"
    with pytest.raises(SystemExit) as e:
        main(["bundle", "--chirality", "ten,ten", "--out", str(tmp_path)])
    assert e.value.code == 2
    assert "--chirality" in capsys.readouterr().err
    assert not (tmp_path / "bundle.json").exists()
