"""L-BFGS-B with damped dynamics where it stalls (upscale.engine.fallback.LBFGSDamped): a
kink of the energy (a bond at a step cut-off) held by L-BFGS-B is crossed by QuickMin."""
import numpy as np
import pytest

from upscale.engine import ParticleSystem
from upscale.engine.fallback import LBFGSDamped
from upscale.engine.minimisers import LBFGS
from upscale.engine.simulation import Simulation
from upscale.models.base import Model, Needs


class _StepWell(Model):
    """One particle on x: E = k (x - 1)^2 / 2 - H [x < 0.5], a spring to x = 1 and a step
    well of depth H below x = 0.5 (the energy of a bond that ends at a step cut-off). From
    x = 0 the force pushes to +x everywhere; the energy jumps up by H at x = 0.5."""

    name = "step-well"
    needs = Needs(pairs=False, energy=True)
    force_kind = "particle"

    def __init__(self, k=1.0, H=0.5):
        self.k, self.H = k, H

    def add_force(self, state, out):
        out[:, 0] -= self.k * (state.y[:, 0] - 1.0)

    def energy(self, state):
        x = state.y[:, 0]
        return float(np.sum(0.5 * self.k * (x - 1.0) ** 2 - self.H * (x < 0.5)))


def _sim():
    return Simulation(ParticleSystem(np.zeros((1, 3)), 1.0, 1.0, spacing=1.0), None,
                      _StepWell())


def test_lbfgs_stops_at_the_kink_and_quickmin_crosses_it():
    held = _sim()
    r = held.minimise(LBFGS(ftol=1e-8, max_iter=200, energy_rtol=1e-15), raise_on_fail=False)
    assert not r.converged and held.state.y[0, 0] == pytest.approx(0.5, abs=1e-3)
    assert r.fmax == pytest.approx(0.5, abs=1e-3)  # the spring's pull at the kink
    sim = _sim()
    m = LBFGSDamped(1e-8, accept=1e-6, dt=0.1, energy_rtol=1e-15)
    r = sim.minimise(m)
    assert r.converged and r.fmax <= 1e-6
    assert sim.state.y[0, 0] == pytest.approx(1.0, abs=1e-6)
    assert m.runs >= 3  # L-BFGS-B, QuickMin, L-BFGS-B


def test_without_cycles_the_kink_is_reported_not_raised():
    sim = _sim()
    r = sim.minimise(LBFGSDamped(1e-8, accept=1e-6, cycles=0, dt=0.1, energy_rtol=1e-15))
    assert not r.converged and r.fmax > 0.4


@pytest.mark.parametrize("kw", [dict(accept=1e-9), dict(cycles=-1)])
def test_bad_input(kw):
    with pytest.raises(ValueError, match="accept|cycles"):
        LBFGSDamped(1e-8, dt=0.1, **kw)
