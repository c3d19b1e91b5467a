"""The periodic coarse tube as an engine model (upscale.models.dcbr.DCBRTubeModel).

Its force is minus the gradient of the energy with the shifts relaxed (envelope theorem,
central differences), and one load step minimised by the engine's L-BFGS-B reaches the
equilibrium of the tube's own joint minimiser (positions and shifts together)."""
import numpy as np
import pytest

from upscale.constants import CARBON_MASS_AMU
from upscale.engine.minimisers import LBFGS
from upscale.engine.simulation import Simulation
from upscale.engine.system import ParticleSystem
from upscale.models.dcbr import DCBRTube, DCBRTubeModel


def _sim(tube):
    s = ParticleSystem(tube.x0, tube.natoms_n, CARBON_MASS_AMU, spacing=float(min(tube.spacing)))
    model = DCBRTubeModel(tube)
    return Simulation(s, None, model), model


def test_force_is_minus_the_gradient_of_the_relaxed_energy():
    tube = DCBRTube(6, 6, 20.0, coarsening=2)
    sim, model = _sim(tube)
    model.set_cell(1.03 * tube.L)
    rng = np.random.default_rng(2)
    sim.state.y[:, 2] *= 1.03
    sim.state.y += 0.01 * rng.standard_normal(sim.state.y.shape)
    F = sim.internal_forces()
    h = 1e-5
    for i, c in [(0, 0), (3, 2), (7, 1)]:
        st = sim.state
        st.y[i, c] += h
        ep = model.energy(st)
        st.y[i, c] -= 2 * h
        em = model.energy(st)
        st.y[i, c] += h
        assert -(ep - em) / (2 * h) == pytest.approx(F[i, c], rel=1e-5, abs=1e-7)


def test_one_load_step_matches_the_tubes_own_minimiser():
    tube = DCBRTube(6, 6, 20.0, coarsening=2)
    r0 = tube.minimise(tube.x0, tube.delta, tube.L, relax_box=True, gtol=1e-8)
    y, d, L0 = r0.y, r0.delta, r0.Lz
    Lz = 1.04 * L0
    ya = y.copy()
    ya[:, 2] *= 1.04
    ra = tube.minimise(ya, d, Lz, gtol=1e-8)
    ya, Ea, gLa = ra.y, ra.energy, ra.cell_force
    sim, model = _sim(tube)
    sim.state.y[...] = y
    sim.state.y[:, 2] *= 1.04
    sim.state.extra["dcbr.delta"][...] = d
    model.set_cell(Lz)
    r = sim.minimise(LBFGS(ftol=1e-6, memory=30), raise_on_fail=False)
    assert r.fmax < 1e-5
    assert model.energy(sim.state) == pytest.approx(Ea, rel=1e-11)
    assert model.cell_force(sim.state) == pytest.approx(gLa, rel=1e-7)


def test_bad_bodies_are_one_line_errors():
    tube = DCBRTube(6, 6, 20.0, coarsening=2)
    with pytest.raises(ValueError, match="particles, the tube"):
        Simulation(ParticleSystem(tube.x0[:-1], 1.0, 1.0), None, DCBRTubeModel(tube))
    with pytest.raises(ValueError, match="periodic DCBRTube"):
        DCBRTubeModel(object())
    with pytest.raises(ValueError, match="cell length must be positive"):
        DCBRTubeModel(tube).set_cell(-1.0)
    with pytest.raises(ValueError, match="needs a 3D body, got dim=2"):
        Simulation(ParticleSystem(tube.x0[:, :2], 1.0, 1.0, dim=2), None, DCBRTubeModel(tube))
    with pytest.raises(ValueError, match="shorter than two unit cells"):
        DCBRTube(7, 3, 40.0)


def test_engine_driver_reproduces_the_tubes_own_driver(tmp_path):
    """The load steps of the quasi-static tension by the engine's L-BFGS-B are minima of
    the tube's own joint minimiser (DCBRTube.minimise started at the last one moves its
    stress by less than 1e-6 relative); the engine run writes a checkpoint and a frame
    (with damage) per load step."""
    from upscale.constants import EV_PER_A3_IN_GPA
    from upscale.engine.checkpoint import Checkpoint, load_checkpoint
    from upscale.engine.output import Output
    from upscale.experiments.scenes.tube_tension import quasi_static_tension_engine

    tube = DCBRTube(6, 6, 20.0, coarsening=2)
    b = quasi_static_tension_engine(tube, max_strain=0.02,
                                    checkpoint=Checkpoint(tmp_path / "ck.npz", every=1),
                                    output=Output(tmp_path, every=1))
    sb = np.array(b["curve"]["stress_GPa"])
    assert len(sb) == 5 and np.all(np.diff(sb) > 0)
    Lz = b["curve"]["Lz_A"][-1]
    own = tube.minimise(b["positions"], b["delta"], Lz, gtol=1e-6)
    assert abs(own.cell_force / b["area_A2"] * EV_PER_A3_IN_GPA / sb[-1] - 1) < 1e-6
    st, meta = load_checkpoint(tmp_path / "ck.npz")
    assert meta["load_step"] == 4 and "dcbr.delta" in st.extra and "dcbr.intact" in st.extra
    assert (tmp_path / "traj.extxyz").is_file() and (tmp_path / "vtk").is_dir()


def test_engine_driver_resumes_bit_for_bit(tmp_path):
    """Interrupted after its third load step (an exception out of the progress callback, as
    a kill) and resumed from the checkpoint: the curve and the final state are the
    uninterrupted run's, bit for bit."""
    from upscale.engine.checkpoint import Checkpoint
    from upscale.experiments.scenes.tube_tension import quasi_static_tension_engine

    a = quasi_static_tension_engine(DCBRTube(6, 6, 20.0, coarsening=2), max_strain=0.03)

    def die(eps, s):
        if eps > 0.0125:
            raise KeyboardInterrupt("killed")

    ck = tmp_path / "ck.npz"
    with pytest.raises(KeyboardInterrupt):
        quasi_static_tension_engine(DCBRTube(6, 6, 20.0, coarsening=2), max_strain=0.03,
                                    checkpoint=Checkpoint(ck, 1), progress=die)
    tube = DCBRTube(6, 6, 20.0, coarsening=2)
    tube.minimise = None  # a resumed run does not relax the zero-stress state again
    b = quasi_static_tension_engine(tube, max_strain=0.03, checkpoint=Checkpoint(ck, 1),
                                    resume=True)
    assert b["curve"] == a["curve"]
    assert np.array_equal(b["positions"], a["positions"]) and np.array_equal(b["delta"], a["delta"])


def test_tension_scene_runs_the_engine_path():
    """``experiments.tension(model="dcbr")`` drives the coarse tube on the engine: its curve
    is :func:`quasi_static_tension_engine`'s."""
    from upscale import experiments
    from upscale.build import swcnt
    from upscale.experiments.scenes.tube_tension import quasi_static_tension_engine

    tube = swcnt(6, 6, length=20.0)
    run = experiments.tension(tube, model="dcbr", coarsening=2, maximum=0.02, progress=False)
    eng = quasi_static_tension_engine(DCBRTube(6, 6, tube.info["length"], coarsening=2),
                                      max_strain=0.02)
    np.testing.assert_allclose(run.curves["curve/stress_GPa"], eng["curve"]["stress_GPa"],
                               rtol=1e-6, atol=1e-5)   # GPa: the zero-stress residual
    assert run.figures["youngs_TPa"] > 0.5


def _strained_state(tube, strain=0.04):
    """A load step's equilibrium of the tube's own joint minimiser (gtol 1e-6): positions,
    shifts (their gradient ~1e-7 eV/Å, above the model's shift tolerance) and cell."""
    r0 = tube.minimise(tube.x0, tube.delta, tube.L, relax_box=True, gtol=1e-6)
    Lz = (1.0 + strain) * r0.Lz
    y = r0.y.copy()
    y[:, 2] *= 1.0 + strain
    r = tube.minimise(y, r0.delta, Lz, gtol=1e-6)
    return r.y, r.delta, Lz


def test_shift_relaxation_reaches_its_tolerance():
    """The shifts relaxed at a configuration have every gradient component at or below
    ``shift_gtol`` (1e-10 eV/Å, from ~1e-7 after a joint minimisation: block Newton; an
    energy-comparing line search stalls there), at the minimum L-BFGS-B finds (the
    fallback, forced here), and a minimisation by the engine's L-BFGS-B ends there too."""
    tube = DCBRTube(6, 6, 20.0, coarsening=2)
    y, d, Lz = _strained_state(tube)
    sim, model = _sim(tube)
    model.set_cell(Lz)
    sim.state.y[...] = y
    sim.state.extra["dcbr.delta"][...] = d
    assert np.abs(tube.energy_and_gradient(y, d, Lz)[2]).max() > 1e-9  # not yet relaxed
    E = model.energy(sim.state)
    model.hold_internal(True)
    g = model.internal_gradient(sim.state)["dcbr.delta"]
    model.hold_internal(False)
    assert np.abs(g).max() <= model.shift_gtol
    d_newton = sim.state.extra["dcbr.delta"].copy()
    fallback = DCBRTubeModel(tube)
    fallback.NEWTON_ITERATIONS = 0  # L-BFGS-B on the shifts, as before the Newton steps
    fallback.set_cell(Lz)
    dd = d.copy()
    E_lbfgs = fallback._relaxed(np.ascontiguousarray(y), dd)[0]
    assert E <= E_lbfgs + 1e-9 * abs(E_lbfgs)
    assert np.abs(d_newton - dd).max() < 1e-8
    sim.state.y[:, 2] *= 1.01
    model.set_cell(1.01 * Lz)
    r = sim.minimise(LBFGS(ftol=np.sqrt(3.0) * 1e-6, memory=30, maxls=20), raise_on_fail=False)
    assert r.converged
    model.hold_internal(True)
    g = model.internal_gradient(sim.state)["dcbr.delta"]
    model.hold_internal(False)
    assert np.abs(g).max() <= model.shift_gtol


def test_shift_hessian_by_lattice_state_is_the_tubes():
    """The Newton step with the Hessian blocks of each lattice state computed on the
    lattice cell (the pristine tube under uniform strain: one state) is the step with the
    blocks by finite differences of the whole tube's lattice energy."""
    tube = DCBRTube(6, 6, 20.0, coarsening=2)
    y, d, Lz = _strained_state(tube)
    model = DCBRTubeModel(tube)
    model.set_cell(Lz)
    E, gy, gd, gL = tube.energy_and_gradient(y, d, Lz)
    q = tube._q_n.copy()
    assert np.ptp(q, axis=0).max() < 1e-10  # one lattice state
    F = tube.gain.deformation(y, np.array([0.0, 0.0, Lz]))
    lat = tube.lattice

    def lattice_grad(dd):
        gk, qk = np.empty_like(dd), np.zeros_like(q)
        from upscale.models import dcbr_kernels as K
        E = K.coarse_energy(F, tube.S, np.ascontiguousarray(dd), tube.natoms_n, tube.alive,
                            lat.s, lat.z, lat.sub, lat.R0, lat.iA, lat.iB, lat.candA,
                            lat.candB, tube.p, tube.e0, np.empty_like(F), gk,
                            np.empty(tube.N), qk)
        return E, gk, qk

    by_state = model._newton_step(q, d, gd, lattice_grad, 1e-5)
    model.HESSIAN_MAX_GROUPS = 0
    by_tube = model._newton_step(q, d, gd, lattice_grad, 1e-5)
    assert np.abs(by_state).max() > 0
    assert np.abs(by_state - by_tube).max() <= 1e-4 * np.abs(by_tube).max()
    with pytest.raises(ValueError, match="maxls must be >= 1"):
        LBFGS(maxls=0)
