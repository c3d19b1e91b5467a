"""The engine's run loop: conditions, stable step, NVE drift, blow-up, checkpoint/restart,
output files, ADR."""
import json

import numpy as np
import pytest

from upscale.engine import Simulation, build_family, square_lattice
from upscale.engine.checkpoint import Checkpoint, load_checkpoint
from upscale.engine.conditions import BodyForce, Displacement, Fixed, Force, Velocity, region
from upscale.engine.integrators import (AdaptiveDynamicRelaxation, BlowUp, VelocityVerlet,
                                        linearised_critical_dt, stable_time_step)
from upscale.engine.output import Output
from upscale.models.bond_based import PMB


@pytest.fixture(autouse=True)
def _one_thread():
    from upscale.engine.kernels import set_threads

    n = set_threads(None)
    set_threads(1)
    yield
    set_threads(n)


def plate(n=12, **kw):
    sysm = square_lattice(n, n, 1e-3, density=2000.0)
    fam = build_family(sysm, 3.015e-3)
    return sysm, fam


def test_stable_estimate_is_a_safe_bound_and_refusal_names_it():
    sysm, fam = plate()
    sim = Simulation(sysm, fam, PMB(E=70e9))
    sim.prepare()
    est = sim.integrator.estimate
    assert sim.integrator.dt == pytest.approx(0.8 * est)
    sharp = linearised_critical_dt(sim)
    assert est < sharp < 3 * est
    bad = Simulation(sysm, fam, PMB(E=70e9), integrator=VelocityVerlet(dt=1.01 * est))
    with pytest.raises(ValueError, match=f"exceeds the stable estimate {est:.6g} s") as exc:
        bad.run(1)
    assert "\n" not in str(exc.value)
    forced = Simulation(sysm, fam, PMB(E=70e9), integrator=VelocityVerlet(dt=1.01 * est, force=True))
    forced.run(3)
    # a forced step needs no estimate before the run: it is computed when first read
    assert forced.integrator._estimate_of is not None
    assert forced.integrator.estimate == est and forced.integrator._estimate_of is None


def test_messages_carry_the_systems_time_unit():
    """A body in Å, fs, eV (the tube scenes) names its steps in fs, not s."""
    from upscale.engine.system import ParticleSystem

    with pytest.raises(ValueError, match="units='metal'; valid: 'si' or 'atomic'"):
        ParticleSystem(np.zeros((1, 3)), 1.0, units="metal")
    sysm, fam = plate()
    ref = Simulation(sysm, fam, PMB(E=70e9))
    ref.prepare()
    est = ref.integrator.estimate
    atomic = ParticleSystem(sysm.x0, sysm.volume, sysm.density, dim=sysm.dim,
                            thickness=sysm.thickness, spacing=sysm.spacing, units="atomic")
    bad = Simulation(atomic, build_family(atomic, 3.015e-3), PMB(E=70e9),
                     integrator=VelocityVerlet(dt=1.01 * est))
    with pytest.raises(ValueError, match=f"time step {1.01 * est:.6g} fs exceeds the stable "
                                         f"estimate {est:.6g} fs"):
        bad.run(1)
    forced = Simulation(atomic, build_family(atomic, 3.015e-3), PMB(E=70e9),
                        integrator=VelocityVerlet(dt=50 * est, force=True))
    forced.state.v[:] = np.random.default_rng(0).standard_normal(forced.state.v.shape)
    with pytest.raises(BlowUp, match=r"\(t = [\d.e+-]+ fs\).* fs vs stable estimate [\d.e+-]+ fs"):
        forced.run(200)


def test_nve_energy_drift_over_10000_steps():
    """Velocity Verlet at 0.8 of the stable estimate conserves a shadow energy: the secular
    part of H = kinetic + strain energy (least-squares slope times the run length, over the
    mean) stays below 1e-4 over 10,000 steps from a smooth velocity field."""
    sysm = square_lattice(14, 14, 1e-3, density=2000.0)
    sim = Simulation(sysm, build_family(sysm, 3.015e-3), PMB(E=70e9),
                     integrator=VelocityVerlet(safety=0.8))
    x, span = sysm.x0, np.ptp(sysm.x0[:, :2], axis=0)
    sim.state.v[:, 0] = np.sin(np.pi * x[:, 0] / span[0]) * np.cos(np.pi * x[:, 1] / span[1])
    sim.state.v[:, 1] = 0.5 * np.cos(np.pi * x[:, 0] / span[0])
    sim.prepare()
    H = []
    sim.run(10_000, callback=lambda s: H.append(s.kinetic_energy() + s.energy())
            if s.state.step % 10 == 0 else None)
    H = np.asarray(H)
    drift = abs(np.polyfit(np.arange(len(H), dtype=float), H, 1)[0]) * (len(H) - 1) / H.mean()
    assert drift < 1e-4, drift


def test_forced_blowup_is_detected_and_last_good_checkpoint_kept(tmp_path):
    """Twice the stable estimate with force=True blows up; the error names the step and the
    estimate, and the last checkpoint on disk is finite and earlier than the blow-up."""
    sysm = square_lattice(16, 16, 1e-3, density=2000.0)
    fam = build_family(sysm, 3.015e-3)
    model = PMB(E=70e9)
    model.prepare(sysm, fam)
    est = stable_time_step(sysm, [model])
    sim = Simulation(sysm, fam, model, integrator=VelocityVerlet(dt=2.0 * est, force=True))
    sim.state.v[:, :2] = np.random.default_rng(1).normal(scale=1e-3, size=(sysm.n, 2))
    ck = Checkpoint(tmp_path / "blowup_checkpoint.npz", every=5)
    with pytest.raises(BlowUp) as ei:
        sim.run(5000, checkpoint=ck)
    msg = str(ei.value)
    assert "blew up" in msg and "stable estimate" in msg and "last good checkpoint" in msg
    st, _ = load_checkpoint(ck.path, sysm.x0, nb=fam.nb)
    assert np.isfinite(st.y).all() and np.isfinite(st.v).all() and st.step < sim.state.step


def test_checkpoint_restart_reproduces_straight_run(tmp_path):
    sysm, fam = plate(10)

    def make():
        top = region(sysm, "top", box=((None, 8.5e-3, None), (None, None, None)))
        bot = region(sysm, "bottom", box=((None, None, None), (None, 0.5e-3, None)))
        m = PMB(E=70e9, s0=2e-3)
        return Simulation(sysm, fam, m, [Velocity(top, (0, 5.0, 0), components=(1,)), Fixed(bot)],
                          integrator=VelocityVerlet(safety=0.8))

    ref = make()
    ref.run(120)
    assert np.count_nonzero(~ref.state.intact) > 0
    # a run killed at step 70 (checkpoints every 25) resumes from step 50
    ck = Checkpoint(tmp_path / "ck.npz", every=25)
    sim = make()

    class Killed(Exception):
        pass

    def kill(s):
        if s.state.step == 70:
            raise Killed

    with pytest.raises(Killed):
        sim.run(120, checkpoint=ck, callback=kill)
    st, meta = load_checkpoint(ck.path, sysm.x0, nb=fam.nb)
    assert st.step == 50 and meta["n"] == sysm.n
    again = make()
    assert again.resume(ck.path)
    again.run(120 - again.state.step)
    assert again.state.step == 120
    np.testing.assert_array_equal(again.state.y, ref.state.y)
    np.testing.assert_array_equal(again.state.intact, ref.state.intact)
    assert [p.name for p in tmp_path.iterdir()] == ["ck.npz"]  # no temporary left over


def test_output_files_readable_by_ase_and_meshio(tmp_path):
    import ase.io
    import meshio

    sysm, fam = plate(8)
    sim = Simulation(sysm, fam, PMB(E=70e9, s0=0.01))
    sim.state.v[:, 0] = 1.0
    out = Output(tmp_path, every=5, energy=True)
    sim.run(10, output=out)
    frames = ase.io.read(tmp_path / "traj.extxyz", index=":")
    assert len(frames) == 3
    last = frames[-1]
    unit = last.info["length_unit_m"]
    assert unit == pytest.approx(1e-6)  # spacing 1 mm = 1000 units
    np.testing.assert_allclose(last.arrays["displacement"] * unit, sim.state.u, rtol=0, atol=0.6e-8 * unit)
    assert last.arrays["damage"].shape == (sysm.n,) and last.info["step"] == 10
    mesh = meshio.read(tmp_path / "vtk" / "frame_000010.vtu")
    np.testing.assert_allclose(mesh.point_data["displacement"], sim.state.u, rtol=1e-8, atol=1e-15)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [f["step"] for f in summary["frames"]] == [0, 5, 10]
    assert "strain_energy_J" in summary["frames"][-1]


def test_loads_conditions_and_momentum():
    sysm, fam = plate(8)
    every = region(sysm, "all", where=lambda x: np.ones(len(x), bool))
    b = np.array([3.0e6, 0.0, 0.0])
    sim = Simulation(sysm, fam, PMB(E=70e9), [BodyForce(every, b)])
    sim.run(20)
    p = (sysm.mass[:, None] * sim.state.v).sum(axis=0)
    total = b[0] * sysm.volume.sum()
    assert p[0] == pytest.approx(total * sim.state.t, rel=1e-9)
    corner = region(sysm, "corner", box=((None, None, None), (0.5e-3, 0.5e-3, None)))
    sim2 = Simulation(sysm, fam, PMB(E=70e9), [Force(corner, lambda t: (0, 1.0 if t < 1 else 0, 0))])
    sim2.run(5)
    assert (sysm.mass[:, None] * sim2.state.v).sum(axis=0)[1] == pytest.approx(sim2.state.t, rel=1e-9)
    # prescribed, time-dependent displacement is honoured exactly
    right = region(sysm, "right", box=((6.5e-3, None, None), (None, None, None)))
    sim3 = Simulation(sysm, fam, PMB(E=70e9), [Displacement(right, lambda t: (1e3 * t, 0, 0))])
    sim3.run(7)
    np.testing.assert_allclose(sim3.state.u[right.index, 0], 1e3 * sim3.state.t)


def test_adr_reaches_equilibrium_of_a_stretched_plate():
    sysm, fam = plate(16)
    left = region(sysm, "left", box=((None, None, None), (2.5e-3, None, None)))
    right = region(sysm, "right", box=((12.5e-3, None, None), (None, None, None)))
    sim = Simulation(sysm, fam, PMB(E=70e9), [Fixed(left), Displacement(right, (1e-6, 0, 0))])
    r = sim.relax(AdaptiveDynamicRelaxation(tol=1e-8))
    assert r["converged"]
    F = sim.forces()
    free = ~sim.constrained
    assert np.linalg.norm(F[free]) < 1e-7 * np.linalg.norm(F[~free])
    u = sim.state.u[:, 0]
    assert np.all(np.diff(u[np.argsort(sysm.x0[:, 0])][::16]) >= -1e-15)


def test_engine_skips_what_no_model_needs():
    sysm, fam = plate(8)
    sim = Simulation(sysm, fam, PMB(E=70e9))
    assert not sim.failure and sim.triplets is None
    sim.state.y[0, 0] += 1e-3  # a huge stretch: still no breaking without a criterion
    sim.update_forces()
    assert sim.state.intact.all()
    with pytest.raises(ValueError, match="needs the pair family"):
        Simulation(sysm, None, PMB(E=70e9))


def test_stable_time_step_combines_models():
    from upscale.models.state_based import LPS

    sysm, fam = plate(8)
    a, b = PMB(E=70e9), LPS(E=70e9, nu=0.3)
    for m in (a, b):
        m.prepare(sysm, fam)
    both = stable_time_step(sysm, [a, b])
    assert both < min(stable_time_step(sysm, [a]), stable_time_step(sysm, [b]))


def test_blowup_message_without_checkpoint():
    sysm, fam = plate(8)
    m = PMB(E=70e9)
    m.prepare(sysm, fam)
    est = stable_time_step(sysm, [m])
    sim = Simulation(sysm, fam, m, integrator=VelocityVerlet(dt=3 * est, force=True))
    sim.state.v[:, :2] = np.random.default_rng(0).normal(scale=1e-3, size=(sysm.n, 2))
    with pytest.raises(BlowUp, match="no checkpoint was written"):
        sim.run(10_000)
