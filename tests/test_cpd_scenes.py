"""CPD scenes: bar and cantilever against closed-form solutions (small, fast versions), CLI."""
import pytest

from upscale.experiments.scenes import cpd_bar


def test_bar_2d_poisson_and_elongation():
    r = cpd_bar.bar_tension(dim=2, nu=0.4, length=30e-3, width=10e-3, dx=1e-3, ratio=3.0)
    assert r["newton"]["converged"]
    assert r["nu_measured"] == pytest.approx(0.4, rel=0.05)          # bond-based: 1/3 only
    assert r["gauge_elongation_m"] == pytest.approx(r["gauge_elongation_ref_m"], rel=0.10)


def test_cantilever_2d_converges_to_timoshenko_with_spacing():
    errs = []
    for dx in (1e-3, 0.5e-3):
        r = cpd_bar.cantilever(dim=2, nu=0.4, length=24e-3, depth=6e-3, dx=dx, ratio=2.0)
        assert r["newton"]["converged"]
        errs.append(abs(r["deflection_err_pct"]))
    assert errs[1] < 0.6 * errs[0]          # surface layer (one horizon) shrinks with dx


def test_cli_bad_input_is_one_line(capsys, tmp_path):
    from upscale.cli import main

    assert main(["cpd", "--nu", "0.2", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    # the prefix is "upscale <args.scene>": cli.main's sub-command dest, which the scene's own
    # ``scene`` option (bar / cantilever) shares
    assert err.startswith("upscale ") and "error: nu=0.2 outside" in err and "\n" not in err
