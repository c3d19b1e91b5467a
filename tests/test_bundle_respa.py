"""Multiple time stepping of the bundle: the force split of the assembled models adds up
to the total, r-RESPA with one inner step is velocity Verlet, and bad options."""
import numpy as np
import pytest

from upscale.experiments.bundle import BundleScene, TubeSpec, dynamic_tension

RATIOS = {"axial": 1.0142, "radial": 1.0159}


def _mixed(**kw):
    return BundleScene.create((10, 10), 60.0, [TubeSpec("tersoff"), TubeSpec("dcbr", 2.0)],
                              ratios=RATIOS, grip=15.0, **kw)


def test_group_forces_add_up_to_the_total():
    from upscale.engine.respa import RESPA

    scene = _mixed()
    st = scene.state_at_rest()
    rng = np.random.default_rng(0)
    sim = scene.assembly.simulation(integrator=RESPA(5.0, 5, force=True))
    sim.state.y[...] = st.y + 0.01 * rng.standard_normal(st.y.shape)
    for k, v in st.fields.items():
        sim.state.fields[k][...] = v
    sim.prepare()
    sim.update_forces()
    F, G = sim.F.copy(), {k: v.copy() for k, v in sim.G.items()}
    sim.integrator.update_forces(sim)
    ig = sim.integrator
    scale = np.abs(F).max()
    assert scale > 0.1
    assert np.abs(ig._F["fast"] + ig._F["slow"] - F).max() < 1e-12 * scale
    assert np.abs(ig._F["slow"]).max() > 1e-3 * scale  # the split is not all fast
    for k, v in G.items():
        assert np.abs(ig._G["fast"][k] + ig._G["slow"][k] - v).max() < \
            1e-12 * max(np.abs(v).max(), 1.0)


def test_respa_with_one_inner_step_is_verlet():
    kw = dict(max_strain=0.012, progress=False, temperature=10.0, sample_every=50)
    a = dynamic_tension(_mixed(), **kw)
    b = dynamic_tension(_mixed(), integrator="respa", inner=1, **kw)
    sa, sb = np.array(a["curve"]["stress_GPa"]), np.array(b["curve"]["stress_GPa"])
    assert sa.shape == sb.shape and sa.size >= 3
    assert np.abs(sa - sb).max() < 1e-7 * np.abs(sa).max()
    assert b["protocol_detail"]["integrator"] == "r-respa"


def test_bad_options():
    with pytest.raises(ValueError, match="inner=3"):
        dynamic_tension(_mixed(), integrator="respa", inner=3, progress=False)
    with pytest.raises(ValueError, match="vdw_every=4"):
        dynamic_tension(_mixed(vdw_every=4), integrator="respa", inner=5, progress=False)
    with pytest.raises(ValueError, match="integrator='leapfrog'"):
        dynamic_tension(_mixed(), integrator="leapfrog", progress=False)
