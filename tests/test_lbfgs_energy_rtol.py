"""The engine L-BFGS-B's energy-change stop (LBFGS(energy_rtol=...), scipy's ftol)."""
import numpy as np
import pytest

from upscale.engine import ParticleSystem
from upscale.engine.minimisers import LBFGS
from upscale.engine.simulation import Simulation
from upscale.models.base import Model, Needs


class _Quartic(Model):
    """Independent particles in wells E = sum k_i |y - c|^4 / 4 (flat at the bottom, so an
    L-BFGS run to a tight force tolerance takes many small energy decreases)."""

    name = "quartic"
    needs = Needs(pairs=False, energy=True)
    force_kind = "particle"

    def __init__(self, c, k):
        self.c, self.k = np.asarray(c, float), np.asarray(k, float)

    def add_force(self, state, out):
        d = state.y - self.c
        out -= self.k[:, None] * d * np.sum(d * d, axis=1)[:, None]

    def energy(self, state):
        r2 = np.sum((state.y - self.c) ** 2, axis=1)
        return float(np.sum(0.25 * self.k * r2 * r2))


def _sim(seed=0, n=20):
    rng = np.random.default_rng(seed)
    x0 = rng.uniform(0, 10, (n, 3))
    c = x0 + rng.normal(scale=0.5, size=x0.shape)
    return Simulation(ParticleSystem(x0, 1.0, 1.0, spacing=1.0), None,
                      _Quartic(c, rng.uniform(0.5, 2.0, n)))


def test_energy_rtol_stops_on_the_energy_change():
    """Off (0, the default) the run goes on to the force tolerance; with a relative energy
    change test it stops once an iteration lowers the energy by less than that share."""
    off = _sim().minimise(LBFGS(ftol=1e-6, max_iter=2000), raise_on_fail=False)
    on = _sim().minimise(LBFGS(ftol=1e-6, max_iter=2000, energy_rtol=1e-3),
                         raise_on_fail=False)
    assert off.converged and off.fmax <= 1e-6
    assert on.n_force < off.n_force and on.fmax > 1e-6 and not on.converged


def test_energy_rtol_bad_input():
    for bad in (-1e-15, 1.0):
        with pytest.raises(ValueError, match="energy_rtol"):
            LBFGS(energy_rtol=bad)
