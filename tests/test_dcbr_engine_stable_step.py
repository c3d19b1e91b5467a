"""The stable step of the coarse tube with its atomistic region on the engine
(DCBRDefectTubeModel.largest_eigenvalue / stiffness_bound)."""
import numpy as np
import pytest

from upscale.engine.integrators import BlowUp, VelocityVerlet, stable_time_step
from upscale.engine.simulation import Simulation
from upscale.models.dcbr_defect import DCBRDefectTube
from upscale.models.dcbr_engine import FIELD, DCBRDefectTubeModel

KW = dict(coarsening=2.0, r_atomistic=5.0, region="band")


@pytest.fixture(scope="module")
def relaxed():
    t = DCBRDefectTube(6, 6, 30.0, vacancy=4, **KW)
    y, d, Lz = t.uniform_state(*t.uniform_lattice(1.0))
    r = t.minimise(y, d, Lz, gtol=1e-6)
    return t, r.y, r.delta, Lz


def _dense_hessian_eigenvalue(t, m, y, d, Lz, h=1e-5):
    """lambda_max of M^-1/2 K M^-1/2 from the whole Hessian, column by column."""
    mass = m.masses()
    s = 1 / np.sqrt(np.r_[np.repeat(mass[m.y_rows], 3), np.repeat(0.25 * mass[:m.N], 3)])
    ny, n = y.size, y.size + d.size

    def g(z):
        _, gy, gd, _ = t.energy_and_gradient(y + z[:ny].reshape(y.shape),
                                             d + z[ny:].reshape(d.shape), Lz)
        return np.r_[gy.ravel(), gd.ravel()]
    H = np.empty((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        H[:, j] = (g(e) - g(-e)) / (2 * h)
    return float(np.linalg.eigvalsh(s[:, None] * 0.5 * (H + H.T) * s[None, :])[-1])


def test_largest_eigenvalue_is_the_dense_hessians(relaxed):
    t, y, d, Lz = relaxed
    m = DCBRDefectTubeModel(t, y=y, delta=d, Lz=Lz)
    fs = t.last_maps.copy()
    lam = m.largest_eigenvalue()
    assert np.array_equal(t.last_maps, fs)  # the tube's history is put back
    assert lam == pytest.approx(_dense_hessian_eigenvalue(t, m, y, d, Lz), rel=1e-6)
    # the engine's estimate is velocity Verlet's critical step 2 / sqrt(lambda_max)
    sim = Simulation(m.system(), None, m, m.conditions(), VelocityVerlet(1.0))
    assert stable_time_step(sim.system, sim.models) == pytest.approx(2 / np.sqrt(lam), rel=1e-12)


def _nve(t, y, d, Lz, dt, steps=400, seed=3):
    """(start kinetic energy, largest gain of the total energy, the engine's estimate) of
    an NVE run from the relaxed state with small random velocities; None if the engine's
    blow-up guard stops it."""
    m = DCBRDefectTubeModel(t, y=y, delta=d, Lz=Lz)
    sim = Simulation(m.system(), None, m, m.conditions(), VelocityVerlet(dt, force=True))
    sim.prepare()
    rng = np.random.default_rng(seed)
    sim.state.v[m.y_rows] = 1e-4 * rng.standard_normal((len(m.y_rows), 3))
    sim.state.field_v[FIELD][:m.N] = 1e-4 * rng.standard_normal((m.N, 3))
    mass, inertia = m.masses(), m.fields()[FIELD].inertia

    def total():
        st = sim.state
        return m.energy(st) + 0.5 * (np.sum(mass[m.y_rows, None] * st.v[m.y_rows] ** 2)
                                     + np.sum(inertia[:m.N, None] * st.field_v[FIELD][:m.N] ** 2))
    e0 = total()
    ke0 = e0 - m.energy(sim.state)
    es = []
    try:
        for _ in range(steps // 20):
            sim.run(20)
            es.append(total())
    except BlowUp:
        return None
    return ke0, max(es) - e0, sim.integrator.estimate


def test_verlet_stable_below_the_step_and_blows_up_above(relaxed):
    t, y, d, Lz = relaxed
    dt_c = 2 / np.sqrt(DCBRDefectTubeModel(t, y=y, delta=d, Lz=Lz).largest_eigenvalue())
    ok = _nve(t, y, d, Lz, 0.95 * dt_c)
    assert ok is not None
    ke0, gain, est = ok
    assert est == pytest.approx(dt_c, rel=1e-12)
    assert gain < ke0  # bounded: Verlet's energy error, not growth
    assert _nve(t, y, d, Lz, 1.1 * dt_c) is None  # the guard stops the run
