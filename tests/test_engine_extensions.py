"""The engine's minimisers, thermostats, grips and multi-body assemblies.

References: closed forms (a quadratic's minimum; the equipartition temperature), the
Lennard-Jones 13-atom cluster's global minimum from the Cambridge Cluster Database
(-44.326801 eps, Wales & Doye, J. Phys. Chem. A 101, 5111 (1997)), and force balance.
"""
import numpy as np
import pytest

from upscale.engine import ParticleSystem, build_family, cubic_lattice
from upscale.engine.conditions import Grip, region
from upscale.engine.integrators import VelocityVerlet
from upscale.engine.minimisers import FIRE, LBFGS, NotConverged, QuickMin
from upscale.engine.simulation import Simulation
from upscale.engine.thermostats import Langevin, NoseHooverChain, kinetic_temperature
from upscale.models.base import Model, Needs


class Springs(Model):
    """Independent particles on springs to centres c: E = sum k_i (|y - c|^2 / 2 + a |y - c|^4 / 4)."""

    name = "springs"
    needs = Needs(pairs=False, energy=True)
    force_kind = "particle"

    def __init__(self, c, k, a=0.0):
        self.c, self.k, self.a = np.asarray(c, float), np.asarray(k, float), float(a)

    def add_force(self, state, out):
        d = state.y - self.c
        out -= self.k[:, None] * d * (1.0 + self.a * np.sum(d * d, axis=1))[:, None]

    def energy(self, state):
        r2 = np.sum((state.y - self.c) ** 2, axis=1)
        return float(np.sum(self.k * (0.5 * r2 + 0.25 * self.a * r2 * r2)))

    def stiffness_bound(self):
        return self.k * 3.0


class LJCluster(Model):
    """All-pairs Lennard-Jones, eps = sigma = 1 (a minimal particle model for the tests)."""

    name = "lj-cluster"
    needs = Needs(pairs=False, energy=True)
    force_kind = "particle"

    def _pairs(self, y):
        d = y[None, :, :] - y[:, None, :]
        r2 = np.sum(d * d, axis=2)
        np.fill_diagonal(r2, np.inf)
        return d, r2

    def add_force(self, state, out):
        d, r2 = self._pairs(state.y)
        s6 = r2 ** -3
        g = (48 * s6 * s6 - 24 * s6) / r2        # -dphi/dr / r
        out -= np.sum(g[:, :, None] * d, axis=1)

    def energy(self, state):
        _, r2 = self._pairs(state.y)
        s6 = r2 ** -3
        return float(0.5 * np.sum(4 * (s6 * s6 - s6)))


def _springs_sim(n=50, seed=0, a=0.0, integrator=None):
    rng = np.random.default_rng(seed)
    x0 = rng.uniform(0, 10, (n, 3))
    system = ParticleSystem(x0, 1.0, 1.0, spacing=1.0)
    c = x0 + rng.normal(scale=0.3, size=x0.shape)
    k = rng.uniform(0.5, 2.0, n)
    return Simulation(system, None, Springs(c, k, a), integrator=integrator), c


@pytest.mark.parametrize("method", [FIRE(ftol=1e-9), LBFGS(ftol=1e-9), QuickMin(ftol=1e-9)])
def test_minimisers_find_a_quadratics_minimum(method):
    sim, c = _springs_sim()
    r = sim.minimise(method)
    assert r.converged and r.fmax <= 1e-9 and r.method == method.name
    assert np.abs(sim.state.y - c).max() < 1e-8
    assert r.energy == pytest.approx(0.0, abs=1e-16)


def _ico13():
    """The Mackay icosahedron (centre + 12 vertices) at the LJ spacing."""
    p = (1 + 5 ** 0.5) / 2
    v = np.array([[0, s1, s2 * p] for s1 in (-1, 1) for s2 in (-1, 1)], float)
    v = np.concatenate([v, np.roll(v, 1, axis=1), np.roll(v, 2, axis=1)])
    v *= 1.1 / np.linalg.norm(v[0])
    return np.vstack([np.zeros(3), v])


@pytest.mark.parametrize("method", [FIRE(ftol=1e-7, max_iter=20000, dt=0.005), LBFGS(ftol=1e-5)])
def test_lj13_reaches_the_cluster_database_minimum(method):
    rng = np.random.default_rng(3)
    x = _ico13() + rng.normal(scale=0.05, size=(13, 3))
    sim = Simulation(ParticleSystem(x, 1.0, 1.0, spacing=1.0), None, LJCluster())
    r = sim.minimise(method)
    assert r.converged
    assert r.energy == pytest.approx(-44.326801, abs=2e-6)


def test_not_converged_is_one_line_and_keeps_the_last_iterate():
    sim, c = _springs_sim()
    y0 = sim.state.y.copy()
    with pytest.raises(NotConverged, match=r"fire did not converge: fmax .* > ftol 1e-12 after 3 "
                                           r"iterations") as e:
        sim.minimise(FIRE(ftol=1e-12, max_iter=3))
    assert "\n" not in str(e.value)
    assert e.value.result.iterations == 3 and not e.value.result.converged
    assert np.isfinite(sim.state.y).all() and not np.array_equal(sim.state.y, y0)
    r = sim.minimise(FIRE(ftol=1e-12, max_iter=3), raise_on_fail=False)
    assert not r.converged and "fmax" in r.message


def test_lbfgs_bounds_stop_at_the_bound():
    """The minimum of the springs lies at c; with y_x <= c_x - 0.1 every particle stops at
    the bound, and the bound-projected force is zero there."""
    sim, c = _springs_sim()
    hi = np.full(c.shape, np.inf)
    hi[:, 0] = c[:, 0] - 0.1
    sim.state.y[:, 0] = np.minimum(sim.state.y[:, 0], hi[:, 0] - 0.5)
    r = sim.minimise(LBFGS(ftol=1e-7, bounds=(None, hi)))
    assert r.converged
    assert np.allclose(sim.state.y[:, 0], hi[:, 0], atol=1e-12)
    assert np.abs(sim.state.y[:, 1:] - c[:, 1:]).max() < 1e-6
    with pytest.raises(ValueError, match="outside"):
        LBFGS(bounds=(None, hi - 10)).minimise(sim)


def test_fire_checkpoint_resume_is_bit_identical(tmp_path):
    from upscale.engine.checkpoint import Checkpoint

    sim, _ = _springs_sim(a=0.3)
    r_full = sim.minimise(FIRE(ftol=1e-10, max_iter=5000))
    sim2, _ = _springs_sim(a=0.3)
    ck = Checkpoint(tmp_path / "fire.npz", every=7)
    with pytest.raises(NotConverged):
        sim2.minimise(FIRE(ftol=1e-10, max_iter=40), checkpoint=ck)
    sim3, _ = _springs_sim(a=0.3)
    r3 = sim3.minimise(FIRE(ftol=1e-10, max_iter=5000), checkpoint=Checkpoint(ck.path, 7),
                       resume=True)
    assert r3.iterations == r_full.iterations
    assert np.array_equal(sim3.state.y, sim.state.y)


def test_langevin_equipartition_on_a_region():
    """Harmonic springs (k_B = 1, T = 0.7): the thermostatted half samples T within 3 %;
    the other half, at rest on its springs' centres, stays at rest."""
    sim, c = _springs_sim(n=200, seed=1)
    sim.state.y[...] = c
    half = np.arange(200) < 100
    th = Langevin(0.7, damping=1.0, region=half, seed=5, k_B=1.0)
    sim.integrator = VelocityVerlet(dt=0.05, thermostat=th)
    sim.run(400)
    temps = []
    for _ in range(60):
        sim.run(25)
        temps.append(kinetic_temperature(sim, half, k_B=1.0))
    assert np.mean(temps) == pytest.approx(0.7, rel=0.03)
    assert np.abs(sim.state.v[~half]).max() == 0.0


def test_nose_hoover_chain_temperature_and_conserved_energy():
    """Anharmonic springs of different stiffness, NHC (M = 3): the time-averaged kinetic
    temperature is T, and H' (eq. 2 of upscale.engine.thermostats) is conserved."""
    sim, c = _springs_sim(n=100, seed=2, a=2.0)
    rng = np.random.default_rng(0)
    sim.state.v[...] = rng.normal(scale=0.3, size=sim.state.v.shape)
    th = NoseHooverChain(0.5, tau=1.0, chain=3, k_B=1.0)
    sim.integrator = VelocityVerlet(dt=0.01, thermostat=th)

    def hprime():
        return sim.kinetic_energy() + sim.energy() + th.conserved_extra()

    sim.prepare()
    h0 = hprime()
    temps, dev = [], []
    for _ in range(200):
        sim.run(50)
        temps.append(kinetic_temperature(sim, k_B=1.0))
        dev.append(hprime() - h0)
    assert np.mean(temps[40:]) == pytest.approx(0.5, rel=0.05)
    assert np.max(np.abs(dev)) < 1e-3 * 0.5 * 300 * 0.5


def test_thermostat_restart_is_bit_identical(tmp_path):
    """Langevin (its random stream) and NHC (its chain) survive a checkpoint exactly."""
    from upscale.engine.checkpoint import Checkpoint

    for make in (lambda: Langevin(0.7, 1.0, seed=9, k_B=1.0),
                 lambda: NoseHooverChain(0.7, 1.0, k_B=1.0)):
        a, _ = _springs_sim(a=0.5, integrator=VelocityVerlet(dt=0.02, thermostat=make()))
        a.state.v[:] = 0.1
        a.run(60)
        b, _ = _springs_sim(a=0.5, integrator=VelocityVerlet(dt=0.02, thermostat=make()))
        b.state.v[:] = 0.1
        ck = Checkpoint(tmp_path / "th.npz", every=10)
        b.run(33, checkpoint=ck)
        c2, _ = _springs_sim(a=0.5, integrator=VelocityVerlet(dt=0.02, thermostat=make()))
        assert c2.resume(tmp_path / "th.npz")
        c2.run(60 - c2.state.step)
        assert np.array_equal(c2.state.y, a.state.y) and np.array_equal(c2.state.v, a.state.v)


def _bar():
    from upscale.models.bond_based import PMB

    s = cubic_lattice(12, 3, 3, 1e-3, density=1000.0)
    fam = build_family(s, 3.015e-3)
    lo = region(s, "bottom", box=((None, None, None), (1.5e-3, None, None)))
    hi = region(s, "top", box=((9.5e-3, None, None), (None, None, None)))
    return s, fam, PMB(E=1e9), lo, hi


def test_grip_reaction_is_minus_the_internal_forces_of_its_region():
    s, fam, pmb, lo, hi = _bar()
    g0 = Grip(lo, displacement=(0.0, 0.0, 0.0))
    g1 = Grip(hi, velocity=(0.5, 0.0, 0.0), components=(0,))
    sim = Simulation(s, fam, pmb, [g0, g1])
    sim.run(30)
    F = sim.internal_forces()
    assert np.allclose(g0.reaction_now, -F[lo.index].sum(axis=0), rtol=1e-12, atol=0)
    assert g1.reaction_now[1:].tolist() == [0.0, 0.0]
    assert g1.reaction_now[0] == pytest.approx(-F[hi.index, 0].sum(), rel=1e-12)
    assert g1.reaction_now[0] > 0  # the grip pulls the bar in +x (the bar pulls it back)
    u_top = sim.state.y[hi.index, 0] - s.x0[hi.index, 0]
    assert np.allclose(u_top, 0.5 * sim.state.t, rtol=1e-12)
    assert len(g1.history) >= 30


def test_grips_balance_in_static_equilibrium():
    """A bar held by two grips and relaxed by FIRE: the reactions cancel (force balance)."""
    s, fam, pmb, lo, hi = _bar()
    g0 = Grip(lo, displacement=(0.0, 0.0, 0.0))
    g1 = Grip(hi, displacement=(1e-5, 0.0, 0.0))
    sim = Simulation(s, fam, pmb, [g0, g1])
    r = sim.minimise(FIRE(ftol=1e-9 * 1e9 * 1e-6, max_iter=20000))
    sim.update_forces()
    assert r.converged
    assert g1.reaction_now[0] > 0
    assert abs(g0.reaction_now[0] + g1.reaction_now[0]) < 1e-6 * abs(g1.reaction_now[0]) * 100


def test_grip_outside_the_body_and_bad_grips_are_one_line_errors():
    s, fam, pmb, lo, hi = _bar()
    with pytest.raises(ValueError, match="selects no particle"):
        region(s, "far", box=((1.0, None, None), (None, None, None)))
    with pytest.raises(ValueError, match="exactly one of"):
        Grip(lo)
    with pytest.raises(ValueError, match="must be finite"):
        Grip(lo, velocity=(np.nan, 0, 0))


def test_two_bodies_each_with_its_model_and_lj_between_them(tmp_path):
    """Two PMB blocks in one run: each body's forces are those it has alone; the
    Lennard-Jones between them is minus the gradient of its energy and sums to zero; the
    assembled run checkpoints and resumes bit for bit."""
    from upscale.engine.bodies import Body, assemble
    from upscale.engine.checkpoint import Checkpoint
    from upscale.models.bond_based import PMB
    from upscale.models.lennard_jones import LennardJonesBetweenBodies

    h = 1e-3
    a = cubic_lattice(4, 4, 4, h, density=1000.0)
    b = cubic_lattice(3, 3, 3, h, density=1000.0, origin=(4.2e-3, 0.5e-3, 0.5e-3))
    fa, fb = build_family(a, 3.015 * h), build_family(b, 2.015 * h)
    lj = LennardJonesBetweenBodies(epsilon=1e-9, sigma=0.8e-3, rc=2.5e-3)

    def scene():
        return assemble([Body(a, fa, [PMB(E=1e9)], "a"), Body(b, fb, [PMB(E=2e9)], "b")],
                        interactions=[LennardJonesBetweenBodies(1e-9, 0.8e-3, rc=2.5e-3)])

    sc = scene()
    sim = sc.simulation(integrator=VelocityVerlet(dt=1e-8))
    rng = np.random.default_rng(4)
    sim.state.y += rng.normal(scale=2e-5, size=sim.state.y.shape)
    F = sim.internal_forces()
    # body a alone
    sa = Simulation(a, fa, PMB(E=1e9))
    sa.state.y[...] = sim.state.y[sc.rows("a")]
    sb = Simulation(b, fb, PMB(E=2e9))
    sb.state.y[...] = sim.state.y[sc.rows("b")]
    lj.prepare(sc.system)
    Flj = lj.force(sim.state)
    assert np.abs(Flj).max() > 0 and np.abs(Flj.sum(axis=0)).max() < 1e-12 * np.abs(Flj).max() * 10
    assert np.allclose(F[sc.rows("a")], sa.internal_forces() + Flj[sc.rows("a")], rtol=1e-12,
                       atol=1e-12 * np.abs(F).max())
    assert np.allclose(F[sc.rows("b")], sb.internal_forces() + Flj[sc.rows("b")], rtol=1e-12,
                       atol=1e-12 * np.abs(F).max())
    # LJ force = -dE/dy (central differences)
    i = int(np.argmax(np.abs(Flj[:, 0])))
    e = 1e-9
    st = sim.state
    st.y[i, 0] += e
    ep = lj.energy(st)
    st.y[i, 0] -= 2 * e
    em = lj.energy(st)
    st.y[i, 0] += e
    assert -(ep - em) / (2 * e) == pytest.approx(Flj[i, 0], rel=1e-5)
    # the assembled run restarts exactly
    y_start = sim.state.y.copy()
    sim.run(40)
    s2 = scene().simulation(integrator=VelocityVerlet(dt=1e-8))
    s2.state.y[...] = y_start
    s2.run(17, checkpoint=Checkpoint(tmp_path / "two.npz", every=5))
    s3 = scene().simulation(integrator=VelocityVerlet(dt=1e-8))
    assert s3.resume(tmp_path / "two.npz")
    s3.run(40 - s3.state.step)
    assert np.array_equal(s3.state.y, sim.state.y)


def test_assembly_refuses_mismatched_bodies():
    from upscale.engine.bodies import Body, assemble
    from upscale.engine.system import square_lattice
    from upscale.models.bond_based import PMB

    a = cubic_lattice(3, 3, 3, 1.0)
    b = square_lattice(3, 3, 1.0, thickness=1.0)
    with pytest.raises(ValueError, match="all bodies must agree"):
        assemble([Body(a, build_family(a, 2.0), PMB(E=1.0), "a"),
                  Body(b, build_family(b, 2.0), PMB(E=1.0), "b")])
    with pytest.raises(ValueError, match="names must differ"):
        assemble([Body(a, build_family(a, 2.0), PMB(E=1.0), "a"),
                  Body(a, build_family(a, 2.0), PMB(E=1.0), "a")])


def test_adr_interrupted_and_resumed_is_bit_identical(tmp_path):
    """Adaptive dynamic relaxation of the gripped bar, interrupted at an iteration (an
    exception out of the force evaluation, as a kill) and resumed from its checkpoint."""
    from upscale.engine.checkpoint import Checkpoint
    from upscale.engine.integrators import AdaptiveDynamicRelaxation

    def sim():
        s, fam, pmb, lo, hi = _bar()
        return Simulation(s, fam, pmb, [Grip(lo, displacement=(0.0, 0.0, 0.0)),
                                        Grip(hi, displacement=(1e-5, 0.0, 0.0))])

    a = sim()
    ra = a.relax(AdaptiveDynamicRelaxation(tol=1e-8, max_steps=400))
    b = sim()
    calls = {"n": 0}
    orig = b.update_forces

    def dying():
        calls["n"] += 1
        if calls["n"] == 57:
            raise KeyboardInterrupt("killed")
        return orig()

    b.update_forces = dying
    ck = Checkpoint(tmp_path / "adr.npz", every=10)
    with pytest.raises(KeyboardInterrupt):
        b.relax(AdaptiveDynamicRelaxation(tol=1e-8, max_steps=400), checkpoint=ck)
    c = sim()
    rc = c.relax(AdaptiveDynamicRelaxation(tol=1e-8, max_steps=400),
                 checkpoint=Checkpoint(ck.path, 10), resume=True)
    assert rc["iterations"] == ra["iterations"] and rc["residual"] == ra["residual"]
    assert np.array_equal(c.state.y, a.state.y)


class SpringsWithField(Model):
    """E = sum k/2 |y - c - a e_x|^2 + kappa/2 (a - a0)^2, a (N,) a massless internal field
    (state.extra["a"]), relaxed in closed form unless held."""

    name = "springs-field"
    needs = Needs(pairs=False, energy=True)
    force_kind = "particle"

    def __init__(self, c, a0, lo, hi, k=1.0, kappa=3.0):
        self.c, self.a0, self.lo, self.hi, self.k, self.kappa = c, a0, lo, hi, k, kappa
        self.held = False
        self.internal_fields = {"a": (lo, hi)}

    def init_state(self, state):
        state.extra["a"] = np.zeros(len(self.c))

    def hold_internal(self, flag):
        self.held = flag

    def _a(self, state):
        a = state.extra["a"]
        if not self.held:  # argmin over a at fixed y, then the bound
            a[...] = np.clip((self.k * (state.y[:, 0] - self.c[:, 0]) + self.kappa * self.a0)
                             / (self.k + self.kappa), self.lo, self.hi)
        return a

    def add_force(self, state, out):
        d = state.y - self.c
        d[:, 0] -= self._a(state)
        out -= self.k * d

    def energy(self, state):
        a = self._a(state)
        d = state.y - self.c
        d[:, 0] -= a
        return float(0.5 * self.k * np.sum(d * d) + 0.5 * self.kappa * np.sum((a - self.a0) ** 2))

    def internal_gradient(self, state):
        a = state.extra["a"]
        return {"a": -self.k * (state.y[:, 0] - self.c[:, 0] - a) + self.kappa * (a - self.a0)}


def test_lbfgs_minimises_internal_fields_with_the_positions():
    """The joint minimum is y = c + a0 e_x, a = a0; with the bound a <= 0.2 (below every a0)
    the field sits at the bound and the positions follow it (y_x = c_x + 0.2)."""
    rng = np.random.default_rng(8)
    n = 20
    x0 = rng.uniform(0, 10, (n, 3))
    c = x0 + 0.2
    a0 = rng.uniform(0.3, 0.5, n)
    for hi, a_star in ((np.inf, a0), (0.2, np.full(n, 0.2))):
        m = SpringsWithField(c, a0, -np.inf, hi)
        sim = Simulation(ParticleSystem(x0, 1.0, 1.0, spacing=1.0), None, m)
        r = sim.minimise(LBFGS(ftol=1e-9))
        assert r.converged and not m.held
        assert np.abs(sim.state.extra["a"] - a_star).max() < 1e-8
        assert np.abs(sim.state.y - c - a_star[:, None] * [1, 0, 0]).max() < 1e-8
