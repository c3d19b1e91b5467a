"""Which sublattice shifts a clamped grip holds (upscale.experiments.scenes.dcbr_dynamic, "Masses"), and
the pass rule of the dynamic dcbr-table (single thermal draws against seed-mean budgets)."""
import numpy as np
import pytest

from upscale.models.dcbr_defect import DCBRDefectTube

KW = dict(coarsening=2.0, r_atomistic=5.0, region="band")


@pytest.fixture(scope="module")
def clamped():
    from upscale.experiments.scenes.dcbr_dynamic import open_tube_with_grips

    m = DCBRDefectTube(6, 6, 60.0, vacancy=4, **KW)
    st = open_tube_with_grips(m, 12.0, gtol=1e-6)
    return m, st


@pytest.mark.slow
def test_grip_edges_are_the_held_particles_linked_to_the_gauge(clamped):
    m, _ = clamped
    rigid = np.asarray(m.clamp[2], bool)
    g = m.gain
    edge = np.zeros(m.N, bool)
    np.logical_or.at(edge, g.pair_i, rigid[g.pair_i] & ~rigid[g.pair_j])
    e = m.grip_edges
    assert e.any() and not np.any(e & ~rigid) and not np.any(e & ~edge)
    assert np.all(m.natoms_n[e] > 0)
    assert np.array_equal(e, edge & rigid & (m.natoms_n > 0))


@pytest.mark.slow
def test_only_the_edges_shifts_feel_the_gauge(clamped):
    """The gauge stretched between the rigid grips, the shifts left at the set-up state: the
    shift gradient is non-zero on the grip edges (their energy is the gap's, between the
    plane and the first free row: free material whose sublattices relax), and zero on the
    particles deep in a grip (their G does not change), so holding those changes nothing."""
    m, st = clamped
    y0, d0, L0 = st["y"], st["delta"], st["L0"]
    grips = st["bottom"] | st["top"]
    eps = 0.01
    u = 0.5 * eps * st["gauge"]
    y = y0.copy()
    y[st["bottom"], 2] -= u
    y[st["top"], 2] += u
    zc = 0.5 * (st["gb"] + st["gt"])
    y[~grips, 2] = zc + (y0[~grips, 2] - zc) * (1 + eps)
    _, _, gd0, _ = m.energy_and_gradient(y0, d0, L0)
    _, _, gd, _ = m.energy_and_gradient(y, d0, L0)
    dg = np.linalg.norm(gd - gd0, axis=1)
    rigid = np.asarray(m.clamp[2], bool)
    deep = rigid & ~m.grip_edges & (m.natoms_n > 0)
    assert deep.any()
    assert dg[m.grip_edges].min() > 1e3 * max(dg[deep].max(), 1e-14), \
        (dg[m.grip_edges].min(), dg[deep].max())
