"""Multiple time stepping of the bundle: the force split of the assembled models adds up
to the total, r-RESPA with one inner step is velocity Verlet, and bad options."""
import numpy as np
import pytest

from upscale.experiments.scenes.bundle import BundleScene, TubeSpec
from upscale.experiments.scenes.bundle_pull import dynamic_tension

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
    a = dynamic_tension(_mixed(), integrator="verlet", **kw)
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


def test_body_view_kept_while_the_state_is_and_renewed_otherwise():
    scene = _mixed()
    st = scene.state_at_rest()
    bm = scene.coarse_models()[0][1]
    a = bm.sub(st)
    st.t, st.step = 7.0, 3
    b = bm.sub(st)
    assert b is a and (b.t, b.step) == (7.0, 3)
    b.y[0, 0] += 0.25  # a view: writes go through
    assert st.y[bm.rows][0, 0] == b.y[0, 0]
    st.y = st.y.copy()  # a new array: a new view on it
    c = bm.sub(st)
    assert c is not a and np.shares_memory(c.y, st.y)
    key = next(iter(st.extra))
    st.extra["tube2/new"] = np.zeros(2)  # a key added: the view is rebuilt and shows it
    assert "new" in bm.sub(st).extra
    assert key in st.extra


def test_per_tube_thermostat_members_and_dofs():
    kw = dict(max_strain=0.006, progress=False, temperature=10.0, sample_every=50)
    r = dynamic_tension(_mixed(), thermostat="per-tube", **kw)
    T = np.array(r["curve"]["temperature_per_tube_K"])
    assert T.shape[1:] == (2, 2) and np.all(np.isfinite(T[:, :, 0]))
    assert "one per tube" in r["protocol_detail"]["thermostat"]
    with pytest.raises(ValueError, match="thermostat='global'"):
        dynamic_tension(_mixed(), thermostat="global", progress=False)


class _Springs:
    """Independent particles on harmonic springs to their start positions (no heat flows
    between particles)."""

    name = "springs"
    force_kind = "particle"

    def __init__(self, c, k):
        from upscale.models.base import Needs

        self.needs = Needs(pairs=False, energy=True)
        self.c, self.k = np.asarray(c, float), np.asarray(k, float)

    def prepare(self, system, family=None, **kw):
        """Nothing to prepare: the springs need no family and no pair list."""

    def init_state(self, state):
        """Nothing to add to the state: the springs carry no history."""

    def add_force(self, state, out):
        out -= self.k[:, None] * (state.y - self.c)

    def step_force(self, state, out, *, failure=True):
        self.add_force(state, out)
        return 0

    def energy(self, state):
        return float(0.5 * np.sum(self.k[:, None] * (state.y - self.c) ** 2))

    def stiffness_bound(self):
        return self.k


def test_thermostat_group_holds_each_region_where_one_holds_only_the_mean():
    """Two halves that exchange no heat, one started at 4 T, one at T/4: one Nose-Hoover
    per half brings each half's time-averaged temperature to T; one on all of them scales
    both alike and keeps the halves apart."""
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import ParticleSystem
    from upscale.engine.thermostats import NoseHoover, ThermostatGroup, kinetic_temperature

    n = 200
    rng = np.random.default_rng(3)
    x0 = rng.uniform(0, 10, (n, 3))
    k = rng.uniform(0.5, 2.0, n)
    half = np.arange(n) < n // 2
    out = {}
    for kind in ("group", "one"):
        sim = Simulation(ParticleSystem(x0, 1.0, 1.0, spacing=1.0), None, _Springs(x0, k))
        v = rng.standard_normal((n, 3))
        v[half] *= 2.0
        v[~half] *= 0.5
        sim.state.v[...] = v
        th = ThermostatGroup([NoseHoover(1.0, 2.0, region=half, k_B=1.0),
                              NoseHoover(1.0, 2.0, region=~half, k_B=1.0)]) \
            if kind == "group" else NoseHoover(1.0, 2.0, k_B=1.0)
        sim.integrator = VelocityVerlet(dt=0.02, thermostat=th)
        sim.run(2000)
        t = []
        for _ in range(400):
            sim.run(10)
            t.append([kinetic_temperature(sim, m, k_B=1.0) for m in (half, ~half)])
        out[kind] = np.mean(t, axis=0)
    assert np.all(np.abs(out["group"] - 1.0) < 0.1)
    assert out["one"][0] > 3.0 * out["one"][1]  # (measured: 1.87 and 0.47)


def test_weighted_chain_weights_the_kinetic_energy_and_is_the_chain_at_unit_weights():
    """The bundle's thermostat (bundle_thermostat, the chain's ``weights``): its
    temperature is eq. (2), the weighted kinetic energy over the represented dofs; with unit
    weights and the explicit N_f it is the unweighted chain step for step."""
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import ParticleSystem
    from upscale.engine.thermostats import NoseHooverChain

    n = 60
    rng = np.random.default_rng(5)
    x0 = rng.uniform(0, 10, (n, 3))
    k = rng.uniform(0.5, 2.0, n)
    half = np.arange(n) < n // 2
    v0 = rng.standard_normal((n, 3))
    v0[half] *= 3.0
    ends = []
    for th in (NoseHooverChain(1.0, 2.0, components=(0, 1), k_B=1.0),
               NoseHooverChain(1.0, 2.0, components=(0, 1), k_B=1.0, weights=np.ones(n),
                               ndf=2 * n)):
        sim = Simulation(ParticleSystem(x0, 1.0, 1.0, spacing=1.0), None, _Springs(x0, k))
        sim.state.v[...] = v0
        sim.integrator = VelocityVerlet(dt=0.02, thermostat=th)
        sim.run(200)
        ends.append(sim.state.v.copy())
    assert np.array_equal(ends[0], ends[1])
    # half B stands for 3 times its dofs: T = (2 K_A + 3 (2 K_B)) / ((n_A + 3 n_B) k_B)
    w = np.where(half, 1.0, 3.0)
    th = NoseHooverChain(1.0, 2.0, components=(0, 1), k_B=1.0, weights=w, ndf=n + 3 * n)
    sim = Simulation(ParticleSystem(x0, 1.0, 1.0, spacing=1.0), None, _Springs(x0, k))
    sim.state.v[...] = v0
    sim.integrator = VelocityVerlet(dt=0.02, thermostat=th)
    sim.prepare()
    K2 = np.sum(v0[:, :2] ** 2, axis=1)
    assert th.temperature(sim) == pytest.approx((K2[half].sum() + 3 * K2[~half].sum())
                                                / (n + 3 * n), rel=1e-12)


def test_bundle_thermostat_counts_the_atoms_between_the_planes():
    """The mixed bundle's one thermostat counts N_f = 2 x the atoms of every tube between
    the grip planes (LAMMPS's free atoms), the atomistic tube's rows with weight 1."""
    from upscale.experiments.scenes.bundle_pull import _grips, _minimised_start, _free_shifts
    from upscale.experiments.scenes.bundle_thermostat import represented_weights

    scene = _mixed()
    start = _minimised_start(scene, 1.0, 0.0, 1e-2, 5)
    grips, free, zb, sep0 = _grips(scene, start["y"], start["hold"], 15.0, 1.0)
    w, ndf, per = represented_weights(scene, start["sim"].state, free, _free_shifts(scene, grips),
                                      (zb, zb + sep0))
    rows0 = scene.assembly.rows("tube1")
    assert np.all(w[rows0] == 1.0) and per[0][0] == per[0][1] == 2 * int(free[rows0].sum())
    bm = scene.coarse_models()[0][1]
    z = bm.model.atom_positions(bm.sub(start["sim"].state))[:, 2]
    assert per[1][1] == 2 * int(((z > zb) & (z < zb + sep0)).sum())
    assert per[1][1] > per[1][0]          # the coarse tube stands for more dofs than it has
    assert ndf == per[0][1] + per[1][1]
    r = dynamic_tension(scene, max_strain=0.006, progress=False, sample_every=50)
    assert "represented atoms" in r["protocol_detail"]["thermostat"]
