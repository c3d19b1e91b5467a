"""The Nose-Hoover chain (upscale.engine.thermostats.NoseHooverChain) on chosen components
and fields, under velocity Verlet and r-RESPA; the molecular-dynamics quench."""
import numpy as np
import pytest

from upscale.engine.integrators import VelocityVerlet
from upscale.engine.respa import RESPA
from upscale.engine.simulation import Simulation
from upscale.engine.system import ParticleSystem
from upscale.engine.thermostats import NoseHooverChain, Quench, kinetic_temperature
from upscale.models.base import Model, Needs


class SplitSprings(Model):
    """Independent particles on springs to centres c, E = sum k_i (|d|^2 / 2 + a |d|^4 / 4),
    d = y - c: the harmonic part the fast force group, the quartic part the slow one (the
    r-RESPA contract of upscale.engine.respa)."""

    name = "split-springs"
    needs = Needs(pairs=False, energy=True)
    force_kind = "particle"

    def __init__(self, c, k, a=0.0):
        self.c, self.k, self.a = np.asarray(c, float), np.asarray(k, float), float(a)

    def add_group_force(self, state, out, group):
        d = state.y - self.c
        if group == "fast":
            out -= self.k[:, None] * d
        else:
            out -= (self.k * self.a * np.sum(d * d, axis=1))[:, None] * d

    def add_force(self, state, out):
        self.add_group_force(state, out, "fast")
        self.add_group_force(state, out, "slow")

    def group_energy(self, state, group):
        r2 = np.sum((state.y - self.c) ** 2, axis=1)
        return float(np.sum(self.k * (0.5 * r2 if group == "fast" else 0.25 * self.a * r2 * r2)))

    def energy(self, state):
        return self.group_energy(state, "fast") + self.group_energy(state, "slow")

    def stiffness_bound(self):
        return self.k * 3.0


def _sim(n, a, integrator, seed=0, v_scale=0.3):
    rng = np.random.default_rng(seed)
    x0 = rng.uniform(0, 10, (n, 3))
    c = x0 + rng.normal(scale=0.3, size=x0.shape)
    k = rng.uniform(0.5, 2.0, n)
    sim = Simulation(ParticleSystem(x0, 1.0, 1.0, spacing=1.0), None, SplitSprings(c, k, a),
                     integrator=integrator)
    sim.state.v[...] = rng.normal(scale=v_scale, size=(n, 3))
    return sim


@pytest.mark.parametrize("integ", ["verlet", "respa"])
def test_chain_on_x_y_holds_T_and_conserves_the_extended_energy(integ):
    """Anharmonic springs, the chain (M = 3) on x, y only: the time-averaged x, y
    temperature is T, and H' (eq. 2) stays within 1e-4 of the kinetic energy scale while
    the physical energy alone changes by far more (the thermostat's part is needed)."""
    T = 0.5
    th = NoseHooverChain(T, tau=1.0, chain=3, components=(0, 1), k_B=1.0)
    it = VelocityVerlet(dt=0.01, thermostat=th) if integ == "verlet" else \
        RESPA(0.01, 2, thermostat=th)
    sim = _sim(100, 2.0, it, seed=2)
    sim.prepare()
    assert th.nf == 200
    e0 = sim.kinetic_energy() + sim.energy()
    h0 = e0 + th.conserved_extra()
    temps, dev, de = [], [], []
    for _ in range(100):
        sim.run(50)
        temps.append(th.temperature(sim))
        e = sim.kinetic_energy() + sim.energy()
        de.append(e - e0)
        dev.append(e + th.conserved_extra() - h0)
    scale = 1.5 * 100 * T   # the kinetic energy at T
    assert np.mean(temps[30:]) == pytest.approx(T, rel=0.05)
    assert np.max(np.abs(dev)) < 1e-4 * scale
    assert np.max(np.abs(de)) > 100 * np.max(np.abs(dev))
    # z is not thermostatted: its own temperature is what the coupling gives it, x, y's
    assert kinetic_temperature(sim, k_B=1.0) != pytest.approx(th.temperature(sim), rel=1e-6)


@pytest.mark.slow
def test_chain_makes_one_harmonic_oscillator_canonical():
    """One oscillator's x under one Nose-Hoover variable is not ergodic (its velocity's
    distribution is not the Gaussian: Martyna, Klein & Tuckerman 1992); the chain of 3 makes
    it canonical: <v^4> / <v^2>^2 = 3 and <v^2> = k_B T / m."""
    out = {}
    for M in (1, 3):
        th = NoseHooverChain(1.0, tau=1.0, chain=M, components=(0,), k_B=1.0)
        sim = Simulation(ParticleSystem(np.zeros((1, 3)), 1.0, 1.0, spacing=1.0), None,
                         SplitSprings(np.zeros((1, 3)), np.ones(1)),
                         integrator=VelocityVerlet(dt=0.05, thermostat=th))
        sim.state.v[0, 0] = 1.0
        vs = []
        sim.run(2000, callback=lambda s: vs.append(s.state.v[0, 0]) and False)
        vs.clear()
        sim.run(30000, callback=lambda s: vs.append(s.state.v[0, 0]) and False)
        v = np.asarray(vs)
        out[M] = (np.mean(v * v), np.mean(v ** 4) / np.mean(v * v) ** 2)
    assert out[3][0] == pytest.approx(1.0, rel=0.1)
    assert out[3][1] == pytest.approx(3.0, rel=0.1)
    assert abs(out[1][1] - 3.0) > 0.3


def test_chain_of_one_is_a_single_variable_and_bad_input_is_refused():
    """M = 1 keeps one variable (its conserved part N_f k_B T eta_1 + Q_1 p_1^2 / 2), and
    a chain length or components out of range are one-line errors."""
    th = NoseHooverChain(0.5, tau=1.0, chain=1, k_B=1.0)
    sim = _sim(20, 0.0, VelocityVerlet(dt=0.01, thermostat=th))
    sim.prepare()
    h0 = sim.kinetic_energy() + sim.energy() + th.conserved_extra()
    sim.run(500)
    assert th.eta.shape == (1,) and th.eta[0] != 0.0
    h = sim.kinetic_energy() + sim.energy() + th.conserved_extra()
    assert abs(h - h0) < 1e-4 * 1.5 * 20 * 0.5
    for kw in ({"chain": 0}, {"chain": 2.5}, {"components": (0, 3)}, {"ndf": 0}):
        with pytest.raises(ValueError):
            NoseHooverChain(1.0, 1.0, **kw)


def test_quench_brings_springs_to_rest_at_their_centres():
    """The quench on velocity Verlet relaxes anharmonic springs to their minimum; its
    power test zeroes the velocities only when the forces oppose them."""
    q = Quench()
    sim = _sim(30, 1.0, VelocityVerlet(dt=0.05, thermostat=q), seed=4, v_scale=0.0)
    c = sim.models[0].c
    sim.run(3000)
    assert np.abs(sim.state.y - c).max() < 1e-6
    assert 0 < q.zeroed < 3000
