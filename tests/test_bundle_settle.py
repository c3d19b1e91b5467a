"""The bundle's start: the quench of every tube after the set-up minimisation leaves the
coarse tubes in equilibrium with the van der Waals forces; the thermostat's chain."""
import pytest

from upscale.experiments.scenes.bundle import BundleScene, TubeSpec
from upscale.experiments.scenes.bundle_pull import dynamic_tension

RATIOS = {"axial": 1.0142, "radial": 1.0159}


def _mixed():
    return BundleScene.create((10, 10), 60.0, [TubeSpec("tersoff"), TubeSpec("dcbr", 2.0)],
                              ratios=RATIOS, grip=15.0)


@pytest.mark.slow
def test_settle_lowers_the_coarse_tubes_unbalanced_vdw_force_and_chain_is_used():
    """The coarse tube starts with the vdW's unbalanced force (it is held in the set-up
    minimisation); the quench lowers it (slowly), and the run uses the chain asked for."""
    kw = dict(max_strain=0.012, progress=False, temperature=10.0, sample_every=50,
              integrator="verlet")  # (as the thresholds were set: velocity Verlet at 1 fs)
    r = dynamic_tension(_mixed(), settle_ps=0.5, chain=2, **kw)
    s = r["protocol_detail"]["settle"]
    # the coarse tube, held in the minimisation, starts with the vdW's unbalanced force
    assert s["fmax_start_eV_A"] > 0.05
    assert s["fmax_eV_A"] < 0.95 * s["fmax_start_eV_A"]
    assert "chain of 2" in r["protocol_detail"]["thermostat"]
    r0 = dynamic_tension(_mixed(), settle_ps=0.0, **kw)
    assert r0["protocol_detail"]["settle"] is None


def test_bad_chain_and_settle():
    with pytest.raises(ValueError, match="chain=0"):
        dynamic_tension(_mixed(), chain=0, progress=False)
    with pytest.raises(ValueError, match="settle_ps=-1"):
        dynamic_tension(_mixed(), settle_ps=-1.0, progress=False)
    with pytest.raises(ValueError, match="max_strain=-0.1; valid: a number > 0"):
        dynamic_tension(_mixed(), max_strain=-0.1, progress=False)
    with pytest.raises(ValueError, match="max_strain=0.001 gives fewer than 3 samples"):
        dynamic_tension(_mixed(), max_strain=0.001, progress=False)
