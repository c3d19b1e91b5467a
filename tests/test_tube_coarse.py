"""The coarse tube of any structure in the quasi-static scene (DCBRModel through
``experiments.tension(model="dcbr")``), and the damped-dynamics minimisers on a model's
massless internal fields."""
import numpy as np
import pytest

from upscale.build import swcnt
from upscale.engine.minimisers import FIRE, LBFGS, QuickMin
from upscale.engine.simulation import Simulation
from upscale.models.dcbr.model import FIELD, DCBRModel


def _strained_tube():
    model = DCBRModel(swcnt(10, 10, length=40.0), 2.0)
    model.set_cell(1.02 * model.tube.L)
    sim = Simulation(model.system(), None, [model])
    c = model.tube.centre
    sim.state.y[...] = c + (model.x0 - c) * np.array([1.0, 1.0, 1.02])
    sim.state.y += 0.01 * np.random.default_rng(1).standard_normal(sim.state.y.shape)
    return model, sim


@pytest.mark.parametrize("method", [FIRE, QuickMin])
def test_damped_dynamics_minimises_the_internal_fields_with_the_rows(method):
    """FIRE and QuickMin move the shifts (held, as L-BFGS-B holds them) with the rows: the
    minimum they reach is L-BFGS-B's (energy to 1e-9 relative, shifts to 1e-4 Å), and the
    model relaxes its shifts itself again afterwards."""
    model, sim = _strained_tube()
    y0 = sim.state.y.copy()
    r = sim.minimise(method(ftol=1e-6, max_iter=20_000, dt=1.0, max_step=0.02))
    assert r.converged and not model.held
    assert np.abs(model.internal_gradient(sim.state)[FIELD]).max() <= 1e-6
    E_dyn, d_dyn = model.energy(sim.state), sim.state.extra[FIELD].copy()
    sim.state.y[...] = y0
    sim.state.extra[FIELD][...] = 0.0
    sim.minimise(LBFGS(ftol=1e-6, max_iter=5000, memory=30), raise_on_fail=False)
    assert E_dyn == pytest.approx(model.energy(sim.state), rel=1e-9, abs=1e-9)
    assert np.abs(d_dyn).max() > 1e-3
    np.testing.assert_allclose(d_dyn, sim.state.extra[FIELD], atol=1e-4)


def test_any_defects_run_the_coarse_quasi_static_scene():
    """Two defects of different kinds (not the seed's vacancy): the scene builds the coarse
    model from the atoms, with a region at each defect, and ramps it."""
    from upscale import experiments

    r = experiments.tension(chirality=(10, 10), length=40.0, defects="v1@0.3@0,v2@0.7@180",
                            model="dcbr", step=0.01, maximum=0.02, progress=False)
    assert r.figures["particles"] < r.figures["atoms"]
    s = r.curves["curve/stress_GPa"]
    assert len(s) == 3 and abs(s[0]) < 0.05 and 0 < s[1] < s[2]
    # 2 % of strain at about 1 TPa
    assert 0.8 < r.figures["youngs_TPa"] < 1.1


def test_any_defects_run_the_coarse_dynamic_pull():
    """A tube with a divacancy in the scene's dynamic pull (the new model's open tube): a
    few samples of rising stress."""
    from upscale import experiments

    r = experiments.tension(chirality=(6, 6), length=80.0, defects="v2@0.5@0", model="dcbr",
                            protocol="dynamic", grip=20.0, maximum=0.01, progress=False)
    s = r.curves["curve/stress_GPa"]
    assert r.figures["particles"] < r.figures["atoms"] and len(s) >= 2 and s[-1] > s[0] > 0


def test_coarse_compression_of_a_pristine_tube_is_the_atomistic_one():
    """A uniform state is exact under the discrete Cauchy-Born rule: the pristine periodic
    tube's compression curve on the coarse model equals the all-atom one."""
    from upscale import experiments

    kw = dict(chirality=(10, 10), length=30.0, load="compression", maximum=0.01,
              progress=False)
    c = experiments.tension(model="dcbr", **kw)
    a = experiments.tension(model="atomistic", **kw)
    assert c.figures["particles"] < a.figures["particles"]
    np.testing.assert_allclose(c.curves["curve/stress_GPa"], a.curves["curve/stress_GPa"],
                               rtol=1e-6, atol=1e-6)
    assert c.figures["strength_GPa"] < 0


def test_coarse_torsion_is_refused_in_one_line():
    from upscale import experiments

    with pytest.raises(ValueError, match="load='torsion'") as exc:
        experiments.tension(chirality=(10, 10), length=30.0, model="dcbr", load="torsion",
                            grip=5.0, progress=False)
    assert "\n" not in str(exc.value)
