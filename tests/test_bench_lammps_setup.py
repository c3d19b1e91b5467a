"""LAMMPS set-up minimisers of the dynamic tension (upscale.experiments.lammps.tension.MinSettings).

Small tube (20 Å (10,10) with the 4-atom vacancy, 316 atoms): every set-up minimiser stops
on the force tolerance in the same minimum; ``min_modify norm inf`` bounds the largest force
component (the coarse set-up's criterion), not the 2-norm; the default settings are the
references' set-up, command for command.
"""
import numpy as np
import pytest

from upscale.build import swcnt, vacancy
from upscale.experiments.lammps.tension import (MinSettings, dynamic_tension, open_tube_setup,
                                       relax_zero_stress)

FTOL = 1e-4


@pytest.fixture(scope="module")
def tube():
    return vacancy(swcnt(10, 10, 20.0), n=4)  # the references' vacancy tube, 20 Å


@pytest.fixture(scope="module")
def relaxed(tube):
    stats = []
    r, _ = relax_zero_stress(tube, ftol=FTOL, minimiser=MinSettings(norm="inf"), stats=stats)
    assert [s["stage"] for s in stats] == ["box_relax_1", "box_relax_2", "fixed_box"]
    assert stats[-1]["stop"] == "force tolerance"
    return r


def test_min_settings_commands():
    assert MinSettings().commands() == ["min_style cg"]  # the references' set-up
    fire = MinSettings(style="fire", norm="inf", fire=("abcfire", "yes"))
    assert fire.commands() == ["min_style fire", "min_modify norm inf",
                               "min_modify abcfire yes", "timestep 0.001"]
    # LAMMPS moves the cell with cg and sd only: box/relax falls back to cg
    assert fire.commands(box_relax=True) == ["min_style cg", "min_modify norm inf"]
    assert MinSettings(style="hftn").style_for(True) == "cg"
    assert MinSettings(style="sd", line="forcezero").commands(box_relax=True) == [
        "min_style sd", "min_modify line forcezero"]


@pytest.mark.parametrize("kw, word", [({"style": "lbfgs"}, "min style"),
                                      ({"norm": "l1"}, "force norm"),
                                      ({"line": "wolfe"}, "line search"),
                                      ({"timestep_ps": -1.0}, "timestep_ps"),
                                      ({"fire": ("tmax", "4")}, "fire"),
                                      ({"maxiter": 0}, "maxiter")])
def test_min_settings_bad_input(kw, word):
    with pytest.raises(ValueError, match=word):
        MinSettings(**kw)


def test_dynamic_tension_rejects_bad_min_style(tube):
    with pytest.raises(ValueError, match="min style='bogus'"):
        dynamic_tension(tube, min_style="bogus")


@pytest.mark.parametrize("kw", [{"style": "cg", "line": "forcezero"}, {"style": "hftn"},
                                {"style": "fire"}, {"style": "fire", "fire": ("abcfire", "yes")},
                                {"style": "quickmin"}])
def test_open_tube_minimisers_same_minimum(tube, relaxed, kw):
    ref = open_tube_setup(tube, ftol=FTOL, relaxed=relaxed, minimiser=MinSettings(norm="inf"))
    r = open_tube_setup(tube, ftol=FTOL, relaxed=relaxed,
                        minimiser=MinSettings(norm="inf", **kw))
    (st,) = r["stages"]
    assert st["stop"] == "force tolerance" and st["style"] == kw["style"]
    assert r["fmax_eV_per_A"] <= FTOL
    # the same minimum: the residual forces (<= 1e-4 eV/Å on ~1e3 components) leave
    # energies ~1e-5 eV apart
    assert abs(r["energy_eV"] - ref["energy_eV"]) < 1e-3
    d = r["positions"] - r["positions"].mean(0) - (ref["positions"] - ref["positions"].mean(0))
    assert np.abs(d).max() < 0.05


def test_norm_inf_bounds_the_largest_component(tube, relaxed):
    inf = open_tube_setup(tube, ftol=FTOL, relaxed=relaxed, minimiser=MinSettings(norm="inf"))
    two = open_tube_setup(tube, ftol=FTOL, relaxed=relaxed, minimiser=MinSettings())
    # both stop on the force tolerance; with inf the 2-norm is left above ftol (the largest
    # component is what is bounded), with two it is below
    assert inf["stages"][0]["stop"] == two["stages"][0]["stop"] == "force tolerance"
    assert inf["fmax_eV_per_A"] <= FTOL < inf["fnorm_eV_per_A"]
    assert two["fnorm_eV_per_A"] <= FTOL
    assert two["force_evaluations"] > inf["force_evaluations"]


def test_default_minimiser_is_the_references_setup(tube):
    a, ia = relax_zero_stress(tube, ftol=FTOL)
    stats = []
    b, ib = relax_zero_stress(tube, ftol=FTOL, minimiser=MinSettings(), stats=stats)
    assert ia["L0_A"] == ib["L0_A"] and ia["energy_eV"] == ib["energy_eV"]
    assert np.array_equal(a.positions, b.positions)
    assert len(stats) == 3 and all(s["force_evaluations"] > 0 for s in stats)
