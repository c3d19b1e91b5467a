"""The shared dynamic pull (upscale.experiments.pull) on the engine's atomistic tube: the stop
rule, a run killed mid-way resumed bit for bit, seeds, and the tube scene's bad input."""
import numpy as np
import pytest

from upscale import experiments
from upscale.build import swcnt
from upscale.engine.checkpoint import Checkpoint
from upscale.experiments.protocols import Dynamic
from upscale.experiments.pull import pull
from upscale.experiments.scenes.tube_atomistic import AtomisticPull

#: a short, fast pull: (5,5) of 60 Å, 10 Å grips at 10 Å/ps each
FAST = Dynamic(grip=10.0, speed=10.0, sample_every=20, maximum=0.3, seed=3)


@pytest.fixture(scope="module")
def tube():
    return swcnt(5, 5, length=60.0)


@pytest.fixture(scope="module")
def full(tube):
    spec = AtomisticPull(tube, FAST)
    return spec, pull(spec, FAST)


def test_the_pull_stops_by_the_protocols_rule(full):
    spec, out = full
    s = np.array([r["response"] for r in out["records"]])
    e = np.array([r["load"] for r in out["records"]])
    k = out["failed_at"]
    assert k is not None and s[k] < 0.95 * s[:k].max()
    # it stopped at the first sample below 20 % of the peak after failure
    assert s[-1] < 0.2 * s.max() and np.all(s[k:-1] >= 0.2 * s.max())
    de = np.diff(e)  # the samples' strains at equal increments of time
    assert np.allclose(de, de[0]) and de[0] > 0
    assert out["steps"] == len(s) * FAST.sample_every
    assert 80 < s.max() < 150  # GPa: a pristine tube's strength


def test_killed_and_resumed_bit_for_bit(tube, full, tmp_path):
    _, ref = full
    path = tmp_path / "pull.npz"

    class Killed(Exception):
        pass

    def kill(rec, n=[0]):
        n[0] += 1
        if n[0] == 12:  # at step 240, between two checkpoints
            raise Killed

    with pytest.raises(Killed):
        pull(AtomisticPull(tube, FAST), FAST, checkpoint=Checkpoint(path, 150), progress=kill)
    spec = AtomisticPull(tube, FAST)
    out = pull(spec, FAST, checkpoint=Checkpoint(path, 150), resume=True)
    assert out["records"] == ref["records"]
    assert np.array_equal(spec.simulation.state.y, full[0].simulation.state.y)


def test_seeds_are_means_of_single_runs(tube):
    kw = dict(model="atomistic", protocol="dynamic", grip=10.0, maximum=0.3, progress=False)
    both = experiments.tension(tube, seed=5, seeds=2, **kw)
    one = [experiments.tension(tube, seed=s, **kw) for s in (5, 6)]
    for k in ("strength_GPa", "youngs_TPa"):
        assert both.figures[k] == pytest.approx(np.mean([r.figures[k] for r in one]), rel=1e-12)
    assert list(both.curves["seeds/seed"]) == [5.0, 6.0]
    assert both.figures["strength_GPa_sd"] > 0


@pytest.mark.parametrize("kw, word", [
    (dict(seeds=0), "seeds=0"),
    (dict(model="dcbr", protocol="dynamic", load="compression"), "load='compression'"),
    (dict(model="atomistic", protocol="dynamic", load="torsion"), "load='torsion'"),
])
def test_bad_input(kw, word):
    with pytest.raises(ValueError, match=word):
        experiments.tension(chirality=(5, 5), length=60.0, progress=False, **kw)


def test_scene_checkpoints_and_a_finished_run_resumes_as_finished(tube, tmp_path):
    kw = dict(model="atomistic", protocol="dynamic", grip=10.0, maximum=0.3, seed=2,
              progress=False, workdir=str(tmp_path), checkpoint_every=200)
    a = experiments.tension(tube, **kw)
    assert (tmp_path / "tension_seed2.npz").is_file()
    b = experiments.tension(tube, resume=True, **kw)
    assert b.figures["strength_GPa"] == a.figures["strength_GPa"]
    assert np.array_equal(a.curves["curve/stress_GPa"], b.curves["curve/stress_GPa"])
    with pytest.raises(ValueError, match="needs a workdir"):
        experiments.tension(tube, model="atomistic", protocol="dynamic", resume=True)
