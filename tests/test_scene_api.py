"""The continuum scenes as plain functions returning a Result: for each, a quick variant run
as ``experiments.NAME(**kw)`` and through the command line in-process (``upscale NAME --out
DIR --threads 1 ...`` with the same values as options) gives the same figures; the
registry's and the scenes' errors."""
import json
import math

import numpy as np
import pytest

from upscale import experiments
from upscale.cli import main
from upscale.experiments import registry
from upscale.experiments.result import Result

#: relative tolerance of the figures per scene: the quasi-static solver of scb refactors its
#: preconditioner on a wall-time budget (upscale.engine.quasistatic.Equilibrium,
#: refactor="amortised"): two runs agree to its tolerance, not to round-off (P_c to ~1e-11)
REL = {"scb": 1e-8}
QUICK = [(name, kw, REL.get(name, 1e-12)) for name, kw in registry.QUICK.items()
         if name not in ("tension", "bundle")]   # tests/test_tube_scene.py, test_bundle_scene.py


pytestmark = pytest.mark.usefixtures("one_numba_thread")   # as the CLI's --threads 1


def _same(a, b, rel) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, (bool, int)) and isinstance(b, (bool, int)):
        return a == b
    return a == pytest.approx(b, rel=rel, abs=0.0)


@pytest.mark.filterwarnings("ignore:dx=0.003 m leaves the crack:UserWarning")   # scb's quick grid
@pytest.mark.parametrize("name,kw,rel", QUICK, ids=[q[0] for q in QUICK])
def test_api_and_command_line_give_the_same_figures(tmp_path, capsys, name, kw, rel):
    api = getattr(experiments, name.replace("-", "_"))(**kw)
    assert isinstance(api, Result) and api.scene == name and api.figures
    assert main([*registry.argv_of(name, kw), "--out", str(tmp_path), "--threads", "1", "--quiet"]) == 0
    stem = name.replace("-", "_")
    cli = Result.from_json(tmp_path / f"{stem}.json")
    assert list(cli.figures) == list(api.figures)
    bad = {k: (cli.figures[k], api.figures[k]) for k in api.figures
           if not _same(cli.figures[k], api.figures[k], rel)}
    assert not bad, bad
    assert cli.meta["params"] == json.loads(json.dumps(api.meta["params"]))  # tuples as lists
    for k, v in api.curves.items():       # the tables too
        if name == "scb" and k == "curve/newton_iterations":
            continue                      # the solver's refactoring decides them (QUICK)
        np.testing.assert_allclose(cli.curves[k], v, rtol=rel, atol=0)
    assert (tmp_path / f"{stem}.png").read_bytes()[:4] == b"\x89PNG"
    printed = capsys.readouterr().out
    assert all(k in printed for k in list(api.figures)[:3])
    if {"x0", "damage"} <= set(api.fields):     # Result.plot draws the damage map from these
        n = api.fields["damage"].shape[0]
        assert api.fields["x0"].shape == (n, 3) and cli.fields["damage"].shape == (n,)


def test_every_registered_continuum_scene_is_a_function_with_documented_parameters():
    import inspect

    from upscale.experiments.registry import _param_help

    for name in ("plate", "cpd", "beam", "plate-bending", "dispersion", "tipd", "scb"):
        func = registry.get(name)
        assert getattr(experiments, name.replace("-", "_")) is func
        sig = inspect.signature(func, eval_str=True)
        helps = _param_help(inspect.getdoc(func))
        for p in sig.parameters.values():
            assert p.annotation is not p.empty, (name, p.name)
            assert p.default is not p.empty, (name, p.name)
            assert helps.get(p.name), (name, p.name)


def test_unknown_scene_lists_the_valid_ones():
    with pytest.raises(ValueError, match="unknown scene 'nope'; valid: ") as e:
        registry.get("nope")
    for name in ("plate", "cpd", "beam", "plate-bending", "dispersion", "tipd", "scb"):
        assert name in str(e.value)


@pytest.mark.parametrize("argv", [["cpd", "--scene", "disc"], ["tipd", "--case", "nope"],
                                  ["plate", "--model", "nope"], ["cpd", "--dim", "4"],
                                  ["beam", "--support", "free"], ["scb", "--supports", "glued"]])
def test_a_bad_choice_on_the_command_line_exits_with_2(tmp_path, capsys, argv):
    with pytest.raises(SystemExit) as e:
        main([*argv, "--out", str(tmp_path)])
    assert e.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


@pytest.mark.parametrize("name,kw,needle", [
    ("cpd", dict(dx=-1e-3), "dx=-0.001 m; valid: 0 < dx"),
    ("scb", dict(dx=-1e-3), "dx=-0.001 m; valid: a positive spacing"),
    ("tipd", dict(dx=(0.05, -0.025)), "dx=-0.025 m; valid: positive spacings"),
    ("plate", dict(n=20, dt=-1e-7), "dt=-1e-07 s; valid:"),
    ("plate", dict(n=3), "at least 10 particles a side, got 3"),
    ("beam", dict(ratios=(1.0, -2.0)), "ratios=(1.0, -2.0)"),
    ("plate-bending", dict(thickness=-0.1), "thickness=-0.1 m"),
    ("dispersion", dict(ratio=0.0), "ratio=0.0; valid:"),
])
def test_an_out_of_range_parameter_is_a_one_line_error_naming_it(name, kw, needle):
    with pytest.raises(ValueError) as e:
        getattr(experiments, name.replace("-", "_"))(**kw)
    msg = str(e.value)
    assert needle in msg and "\n" not in msg


def test_command_line_out_of_range_is_one_line_exit_2(tmp_path, capsys):
    assert main(["scb", "--dx=-1e-3", "--out", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "upscale scb: error: dx=-0.001 m; valid: a positive spacing"
    assert not (tmp_path / "scb.json").exists()
