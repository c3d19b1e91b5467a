"""r-RESPA multiple time stepping (upscale.engine.respa) on the coarse tube's force split
(upscale.models.dcbr_engine.DCBRDefectTubeModel.add_group_force), and the tube's
atomistic region shapes (upscale.models.dcbr_defect, region="disc" / "ellipse")."""
import numpy as np
import pytest

from upscale.constants import ACC_EV_A_AMU_IN_A_FS2, K_B_EV
from upscale.engine.checkpoint import Checkpoint
from upscale.engine.integrators import VelocityVerlet
from upscale.engine.respa import RESPA
from upscale.engine.simulation import Simulation
from upscale.models.dcbr_defect import DCBRDefectTube
from upscale.models.dcbr_engine import FIELD, DCBRDefectTubeModel


@pytest.fixture(scope="module", params=["band", "disc", "ellipse"])
def tube(request):
    kw = dict(r_arc=9.0) if request.param == "ellipse" else {}
    return DCBRDefectTube(10, 10, 40.0, coarsening=2.0, vacancy=4, r_atomistic=5.0,
                          region=request.param, **kw)


def _perturbed_model(tube, seed=0):
    rng = np.random.default_rng(seed)
    lt, lz, sh = tube.uniform_lattice(1.01)
    y, d, Lz = tube.uniform_state(lt, lz, sh)
    tube.prepare_step(Lz)
    y = y + 0.02 * rng.standard_normal(y.shape)
    d = d + 0.01 * rng.standard_normal(d.shape)
    return DCBRDefectTubeModel(tube, y=y, delta=d, Lz=Lz)


def _split(m, st):
    out = {}
    for g in ("fast", "slow"):
        F = np.zeros_like(st.y)
        G = {FIELD: np.zeros_like(st.y)}
        m.add_group_force(st, F, g)
        m.add_group_field_force(st, G, g)
        out[g] = (F, G[FIELD], m.group_energy(st, g))
    return out


def _assert_split_adds_up(m, st):
    """fast + slow == total for the forces (1e-12 relative), the shift forces and the
    energy; returns (the split, the total force)."""
    F = np.zeros_like(st.y)
    G = {FIELD: np.zeros_like(st.y)}
    m.add_force(st, F)
    m.add_field_force(st, G)
    s = _split(m, st)
    scale = max(np.abs(F).max(), 1.0)
    assert np.abs(s["fast"][0] + s["slow"][0] - F).max() < 1e-12 * scale
    assert np.abs(s["fast"][1] + s["slow"][1] - G[FIELD]).max() < 1e-12 * scale
    assert s["fast"][2] + s["slow"][2] == pytest.approx(m.energy(st), abs=1e-9)
    return s, F


def test_split_adds_up_to_the_total(tube):
    """fast + slow == total (forces, shift forces, energy) to round-off, with and without
    the transfer of prepare_split, and the fast group alone is not the total."""
    m = _perturbed_model(tube)
    sim = Simulation(m.system(), None, m, m.conditions(), VelocityVerlet(1.0, force=True))
    st = sim.state
    for transfer in (False, True):
        if transfer:
            m.prepare_split(st)
            st.y[m.y_rows] += 0.005
            st.fields[FIELD][:m.N] -= 0.002
        s, F = _assert_split_adds_up(m, st)
        assert np.abs(s["slow"][0]).max() > 1e-3 * np.abs(F).max()  # both groups carry something
    with pytest.raises(ValueError, match="valid: 'fast' or 'slow'"):
        m.add_group_force(st, np.zeros_like(st.y), "medium")


def test_slow_group_without_the_atoms(tube):
    """fast_interface + fast_ghost: the split still adds up to the total, and the slow group
    exerts no force at all on the atoms (the interface particles' lattice energy and
    hourglass links and the ghost-force dead load are fast), with and without the
    transfer; the coarse split does act on them (through the slaves and the dead load)."""
    m0 = _perturbed_model(tube, 5)
    m = DCBRDefectTubeModel(tube, y=m0.y0, delta=m0.delta0, Lz=m0.Lz, fast_interface=True,
                            fast_ghost=True)
    assert len(m._interface()[0][0]) > 0  # (interface rows)
    sims = [Simulation(k.system(), None, k, k.conditions(), VelocityVerlet(1.0, force=True))
            for k in (m0, m)]
    s0 = _split(m0, sims[0].state)
    assert np.abs(s0["slow"][0][m0.atom_rows]).max() > 1e-3
    st = sims[1].state
    for transfer in (False, True):
        if transfer:
            m.prepare_split(st)
            st.y[m.y_rows] += 0.01 * np.random.default_rng(1).standard_normal((len(m.y_rows), 3))
            st.fields[FIELD][:m.N] -= 0.002
        s, F = _assert_split_adds_up(m, st)
        assert np.abs(s["slow"][0][m.atom_rows]).max() == 0.0
        assert np.abs(s["slow"][0]).max() > 1e-3 * np.abs(F).max()


@pytest.mark.parametrize("split", ["interface", "ghost"])
def test_one_flag_splits_add_up(tube, split):
    """The two one-flag splits add up to the total too (with the transfer), and the ghost
    split's slow group is the coarse split's less the ghost-force dead load: the slow forces of
    the two differ by exactly the dead load's (the tube's own apply_ghost_load)."""
    m0 = _perturbed_model(tube, 6)
    m = DCBRDefectTubeModel(tube, y=m0.y0, delta=m0.delta0, Lz=m0.Lz, split=split)
    sim = Simulation(m.system(), None, m, m.conditions(), VelocityVerlet(1.0, force=True))
    st = sim.state
    m.prepare_split(st)
    st.y[m.y_rows] += 0.01 * np.random.default_rng(2).standard_normal((len(m.y_rows), 3))
    s, F = _assert_split_adds_up(m, st)
    if split == "ghost":
        y, d = m.unknowns(st)
        _, gy, gd = m0._coarse_eval(y, d)
        _, gys, gds = m._coarse_eval(y, d)
        _, gy_ghost, gd_ghost, applied = tube.apply_ghost_load(
            y, d, m.Lz, 0.0, np.zeros_like(y), np.zeros_like(d))
        assert applied and np.abs(gy_ghost).max() > 1e-6
        assert np.abs(gy - gys - gy_ghost).max() < 1e-12 * np.abs(gy).max()
        assert np.abs(gd - gds - gd_ghost).max() < 1e-12 * max(np.abs(gd).max(), 1.0)
        # its gradient and its work apart are the combined call's, bit for bit (the fast
        # group takes the gradient at every step and the work only for its energy)
        gy1, gd1 = np.random.default_rng(3).standard_normal(y.shape), np.ones_like(d)
        E2, gy2, gd2, _ = tube.apply_ghost_load(y, d, m.Lz, 1.5, gy1, gd1)
        gy3, gd3 = tube.ghost_load_gradient(y, m.Lz, gy1, gd1)
        assert np.array_equal(gy2, gy3) and np.array_equal(gd2, gd3)
        assert E2 == 1.5 - tube.ghost_load_work(y, d, m.Lz) and E2 != 1.5
        # no load for another cell length: nothing applied, no work
        assert tube.ghost_load_work(y, d, 1.1 * m.Lz) == 0.0
        assert tube.ghost_load_gradient(y, 1.1 * m.Lz, gy1, gd1)[0] is gy1


def test_split_by_name(tube):
    """``split=`` sets both flags of the split by name (each of the four); an unknown name is a one-line error."""
    m = DCBRDefectTubeModel(tube, split="atoms-free")
    assert m.fast_interface and m.fast_ghost
    m = DCBRDefectTubeModel(tube, fast_interface=True, split="coarse")
    assert not (m.fast_interface or m.fast_ghost)
    m = DCBRDefectTubeModel(tube, split="interface")
    assert m.fast_interface and not m.fast_ghost
    m = DCBRDefectTubeModel(tube, fast_interface=True, split="ghost")
    assert m.fast_ghost and not m.fast_interface
    with pytest.raises(ValueError, match="split='none'; valid: 'coarse', 'atoms-free'"):
        DCBRDefectTubeModel(tube, split="none")


def test_interface_rows_and_the_rest_add_up_to_the_coarse_part(tube):
    """The interface particles and all the others partition the particles, own every
    hourglass link between them, and their restricted parts (G, maps and G^T on their rows
    only) add up to the whole coarse part: energy, dE/d(particle positions), dE/d delta."""
    m0 = _perturbed_model(tube, 4)
    m = DCBRDefectTubeModel(tube, y=m0.y0, delta=m0.delta0, Lz=m0.Lz, fast_interface=True,
                            fast_ghost=True)
    iface, rest = m._interface()
    rows = np.sort(np.r_[iface[0], rest[0]])
    assert np.array_equal(rows, np.arange(m.N)) and len(iface[0]) and len(rest[0])
    st = tube._st
    nl = [len(p[2]["c"]) if p[2] is not None else 0 for p in (iface, rest)]
    assert sum(nl) == len(st["c"]) and min(nl) > 0
    yp = m._particle_positions(m.y0)
    d = np.ascontiguousarray(m.delta0)
    E, _, P, gd, gys, _ = tube._coarse_part(yp, d, m.Lz)
    gy = gys - tube.gain.forces(P)
    parts = [m._rows_part(yp, d, p) for p in (iface, rest)]
    scale = np.abs(gy).max()
    assert parts[0][0] + parts[1][0] == pytest.approx(E, rel=1e-12, abs=1e-10)
    assert np.abs(parts[0][1] + parts[1][1] - gy).max() < 1e-12 * scale
    assert np.abs(parts[0][2] + parts[1][2] - gd).max() < 1e-12 * max(np.abs(gd).max(), 1.0)
    assert np.abs(parts[0][1]).max() > 1e-6 * scale


def test_transfer_takes_the_constant_part_of_the_slow_forces(tube):
    """At the reference of prepare_split the slow group has no force left (its gradient
    and the shift stiffness went to the fast group)."""
    m = _perturbed_model(tube, 3)
    sim = Simulation(m.system(), None, m, m.conditions(), VelocityVerlet(1.0, force=True))
    m.prepare_split(sim.state)
    s = _split(m, sim.state)
    assert np.abs(s["slow"][0]).max() < 1e-12 and np.abs(s["slow"][1]).max() < 1e-12


_RELAXED = {}


def _nve(tube, integ, steps, T=10.0, seed=7, ck=None):
    if id(tube) not in _RELAXED:  # the relaxed periodic tube (the dcbr-defect-nve scene)
        r0 = tube.minimise(None, None, None, relax_box=True, gtol=1e-6)
        _RELAXED[id(tube)] = (r0.y, r0.delta, r0.Lz)
    y, d, Lz = _RELAXED[id(tube)]
    m = DCBRDefectTubeModel(tube, y=y, delta=d, Lz=Lz)
    sim = Simulation(m.system(), None, m, m.conditions(), integ)
    mass, mass_d = tube.masses()
    rng = np.random.default_rng(seed)
    acc = ACC_EV_A_AMU_IN_A_FS2
    v = rng.standard_normal(y.shape) * np.sqrt(K_B_EV * T * acc / mass)[:, None]
    vd = rng.standard_normal(d.shape) * np.sqrt(K_B_EV * T * acc / mass_d)[:, None]
    vd[tube.slave_idx] = 0.0
    st = sim.state
    st.v[m.y_rows] = v
    if len(tube.slave_idx):
        st.v[tube.slave_idx] = tube.Phi @ v[m.nd:]
    st.field_v[FIELD][:m.N] = vd
    return m, sim


def test_one_inner_step_is_velocity_verlet():
    t = DCBRDefectTube(10, 10, 40.0, coarsening=2.0, vacancy=4, r_atomistic=5.0, region="disc")
    _, a = _nve(t, VelocityVerlet(1.0, force=True), 0)
    _, b = _nve(t, RESPA(1.0, 1, force=True), 0)
    a.run(20)
    b.run(20)
    assert np.abs(a.state.y - b.state.y).max() < 1e-11
    assert np.abs(a.state.v - b.state.v).max() < 1e-11
    assert np.abs(a.state.fields[FIELD] - b.state.fields[FIELD]).max() < 1e-11


def test_energy_is_conserved_at_a_long_outer_step():
    """NVE from 10 K: with the outer step at 6 fs (6 inner steps of 1 fs) the total energy
    stays as close to its start as velocity Verlet's at 1 fs does; without the split's
    transfer the shifts' optical mode makes the same outer step unstable."""
    t = DCBRDefectTube(10, 10, 40.0, coarsening=2.0, vacancy=4, r_atomistic=5.0, region="disc")
    dev = {}
    for name, integ, steps in (("vv", VelocityVerlet(1.0, force=True), 600),
                               ("respa", RESPA(6.0, 6, force=True), 100)):
        m, sim = _nve(t, integ, steps)
        st, mass = sim.state, sim.system.mass
        inert = m.fields()[FIELD].inertia

        def kinetic():  # the unknowns' and the shifts' (a slave row's follows its atoms)
            v, w = st.v[m.y_rows], st.field_v[FIELD][:m.N]
            return 0.5 * (np.sum(mass[m.y_rows, None] * v * v)
                          + np.sum(inert[:m.N, None] * w * w))

        def total():
            return sim.energy() + kinetic()
        e0 = total()
        k0 = kinetic()
        e = []
        sim.run(steps, callback=lambda s: e.append(total()) and False)
        dev[name] = np.abs(np.array(e) - e0).max() / k0
    assert dev["respa"] < 2.0 * dev["vv"] and dev["vv"] < 0.05


def test_restart_is_exact(tmp_path):
    t = DCBRDefectTube(10, 10, 40.0, coarsening=2.0, vacancy=4, r_atomistic=5.0, region="disc")
    from upscale.engine.thermostats import NoseHoover

    def make():
        th = NoseHoover(10.0, 100.0, components=(0, 1), fields=(FIELD,), k_B=K_B_EV)
        return _nve(t, RESPA(4.0, 4, thermostat=th, force=True), 0)
    _, a = make()
    a.run(12)
    path = tmp_path / "ck.npz"
    _, b = make()
    b.run(6, checkpoint=Checkpoint(path, 6))
    _, c = make()
    assert c.resume(path)
    c.run(6)
    assert np.array_equal(a.state.y, c.state.y) and np.array_equal(a.state.v, c.state.v)
    assert np.array_equal(a.state.field_v[FIELD], c.state.field_v[FIELD])
    assert a.integrator.thermostat.xi == c.integrator.thermostat.xi


@pytest.mark.parametrize("region, kw", [("disc", {}), ("ellipse", {"r_arc": 9.0})])
def test_shaped_region_has_no_force_at_rest(region, kw):
    """Patch test: a pristine tube with the region, uniformly stretched, with the ghost-force
    correction is an equilibrium (both groups together), while the uncorrected coupling is
    not; after 20 RESPA steps from rest nothing has moved."""
    t = DCBRDefectTube(10, 10, 40.0, coarsening=2.0, vacancy=0, r_atomistic=5.0,
                       region=region, **kw)
    assert t.ghost_forces(0.02)["max_atom_force_eV_A"] > 1e-3
    lt, lz, sh = t.uniform_lattice(1.02)
    y, d, Lz = t.uniform_state(lt, lz, sh)
    t.prepare_step(Lz)
    m = DCBRDefectTubeModel(t, y=y, delta=d, Lz=Lz)
    sim = Simulation(m.system(), None, m, m.conditions(), RESPA(4.0, 4, force=True))
    sim.prepare()
    assert np.abs(sim.F).max() < 1e-9 and np.abs(sim.G[FIELD]).max() < 1e-9
    y0 = sim.state.y.copy()
    sim.run(20)
    assert np.abs(sim.state.y - y0).max() < 1e-9


def test_ellipse_is_between_disc_and_band():
    kw = dict(coarsening=2.0, vacancy=4, r_atomistic=5.0)
    nf = {r: DCBRDefectTube(10, 10, 40.0, region=r, **k, **kw).nf
          for r, k in (("disc", {}), ("ellipse", {"r_arc": 12.0}), ("band", {}))}
    assert nf["disc"] < nf["ellipse"] < nf["band"]


@pytest.mark.parametrize("kw, word", [
    (dict(region="ellipse"), "r_arc=None"),
    (dict(region="disc", r_arc=5.0), "r_arc=5.0"),
    (dict(region="ellipse", r_arc=-1.0), "r_arc=-1.0"),
])
def test_region_bad_input(kw, word):
    with pytest.raises(ValueError) as e:
        DCBRDefectTube(10, 10, 40.0, coarsening=2.0, vacancy=4, r_atomistic=5.0, **kw)
    assert word in str(e.value) and "valid" in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("kw, word", [(dict(outer_dt=0.0), "outer time step"),
                                      (dict(outer_dt=4.0, inner=0), "inner=0"),
                                      (dict(outer_dt=4.0, inner=2.5), "inner=2.5")])
def test_respa_bad_input(kw, word):
    with pytest.raises(ValueError, match=word):
        RESPA(**kw)


def test_dynamic_tension_respa_bad_input():
    from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension

    t = DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)
    with pytest.raises(ValueError, match="integrator='leapfrog'"):
        dynamic_tension(t, grip=10.0, integrator="leapfrog")
    with pytest.raises(ValueError, match="sample=100"):
        dynamic_tension(t, grip=10.0, integrator="respa", outer_dt=3.0)
    with pytest.raises(ValueError, match="split='none'"):
        dynamic_tension(t, grip=10.0, integrator="respa", outer_dt=4.0, split="none")
    with pytest.raises(ValueError, match="split='atoms-free' with integrator='verlet'"):
        dynamic_tension(t, grip=10.0, split="atoms-free")


def test_dynamic_tension_splits():
    """split= reaches the model: the same tension test (NVE from rest, 15 outer steps of
    4 fs) gives another trajectory under 'atoms-free' and 'ghost', within 1 % of the largest
    stress of the 'coarse' split's; no split given is 'ghost' (MTS_SPLIT)."""
    from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension

    t = DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)
    s = {sp: np.asarray(dynamic_tension(t, grip=10.0, integrator="respa", outer_dt=4.0,
                                        inner=4, sample=20, max_strain=0.01, speed=5.0,
                                        temperature=0.0, split=sp)["curve"]["stress_GPa"])
         for sp in ("coarse", "atoms-free", "ghost", None)}
    for sp in ("atoms-free", "ghost"):
        diff = np.abs(s["coarse"] - s[sp]).max()
        assert 0.0 < diff < 0.01 * np.abs(s["coarse"]).max()
    assert np.array_equal(s[None], s["ghost"])  # the scene's split when none is given
