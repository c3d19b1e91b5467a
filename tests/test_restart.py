"""Exact restart: a run killed with SIGKILL at a random step and resumed from its last
checkpoint ends bit for bit where the uninterrupted run ends.

Each run is its own process (:mod:`upscale.experiments.kill_resume`); the step is drawn at random
and printed with any failure, so a failure can be replayed with ``kill_at=``. The plate
breaks thousands of bonds (a resume that recomputes the last step's forces with failure
ends with a different count: the cause of the mismatch this test guards against), and the
CPD solve is killed inside a load step after at least one checkpoint.
"""
import numpy as np
import pytest

from upscale.experiments.kill_resume import (cpd_kill_resume, dcbr_kill_resume,
                                             dcbr_vacancy_kill_resume, plate_kill_resume)


@pytest.mark.parametrize("model", ["pmb", "lps"])
def test_plate_killed_and_resumed_is_bit_identical(tmp_path, model):
    seed = int(np.random.SeedSequence().entropy % 2**32)
    kill = int(np.random.default_rng(seed).integers(11, 100))  # after the first checkpoint
    r = plate_kill_resume(tmp_path, model=model, kill_at=kill, n=40 if model == "pmb" else 30)
    assert r["resumed"] and r["resumed_from_step"] > 0, r
    assert r["resumed_from_step"] <= r["killed_at_step"] < r["steps"], r
    assert r["broken_bonds_uninterrupted"] > 1000, r  # failure is exercised
    assert r["broken_bonds_resumed"] == r["broken_bonds_uninterrupted"], (kill, r)
    assert r["bit_identical"], (kill, r)


def test_cpd_newton_killed_and_resumed_is_bit_identical(tmp_path):
    seed = int(np.random.SeedSequence().entropy % 2**32)
    r = cpd_kill_resume(tmp_path, seed=seed)
    # it resumed (did not start over): fewer iterations after the resume than in all
    assert r["newton_iterations_resumed_total"] == r["newton_iterations"], (seed, r)
    if r["checkpoint_before_kill"]:
        assert r["newton_iterations_after_resume"] < r["newton_iterations"], (seed, r)
    assert r["bit_identical"], (seed, r)


def test_cpd_checkpoint_of_another_solve_is_refused(tmp_path):
    """A checkpoint of a solve with other load steps: a one-line error naming both."""
    from upscale.experiments.scenes.cpd_bar import bar_tension

    ck = tmp_path / "newton.npz"
    bar_tension(dim=2, dx=4e-3, strain=0.01, steps=2, checkpoint=ck)
    with pytest.raises(ValueError, match="3 load steps"):
        bar_tension(dim=2, dx=4e-3, strain=0.01, steps=3, checkpoint=ck, resume=True)


@pytest.mark.slow
def test_dcbr_periodic_tube_on_the_engine_killed_and_resumed_is_bit_identical(tmp_path):
    """The periodic coarse tube stretched on the engine with a Nose-Hoover chain, links
    breaking (shifts, links and the chain are in the checkpoint)."""
    seed = int(np.random.SeedSequence().entropy % 2**32)
    r = dcbr_kill_resume(tmp_path, steps=150, every=20, strain_rate=2e-3, seed=seed)
    assert r["resumed_from_step"] > 0 and r["broken_links_uninterrupted"] > 0, r
    assert r["broken_links_resumed"] == r["broken_links_uninterrupted"], (seed, r)
    assert r["bit_identical"], (seed, r)


@pytest.mark.slow
def test_dcbr_vacancy_dynamic_tension_killed_and_resumed_is_bit_identical(tmp_path):
    """The open vacancy tube's dynamic tension on the engine, pulled to failure: the state
    (positions, velocities, shifts, links, last maps, ghost dead load, the scene's records)
    and the result (stress curve, strength, first damage) bit for bit."""
    seed = int(np.random.SeedSequence().entropy % 2**32)
    r = dcbr_vacancy_kill_resume(tmp_path, tube="small", every=50, seed=seed)
    assert 0 < r["resumed_from_step"] <= r["killed_at_step"] < r["steps"], r
    assert r["bit_identical"], (seed, r)
