"""The numba kernels of the terms through the particles' maps (hourglass links, pad atoms,
Verlet list of the atomistic region) against the straightforward numpy implementation
(``method="numpy"``: complex-step derivatives, a new k-d tree pair list per call)."""
import numpy as np
import pytest

from upscale.models.dcbr import DCBRTube
from upscale.models.dcbr_defect import DCBRDefectTube

TOL = 1e-9


def _diff(a, b, scale):
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / scale)


def _both(m, fn):
    out = {}
    for meth in ("numpy", "numba"):
        m.method = meth
        out[meth] = fn()
    m.method = "numba"
    return out["numpy"], out["numba"]


def _check(m, y, d, Lz):
    """Raw and ghost-corrected energy and gradients, per-particle and per-atom energies."""
    def run():
        raw = m._raw_energy_and_gradient(y, d, Lz)
        e_n = m._e_n.copy()
        e_at = m._e_atoms.copy()
        return raw, m.energy_and_gradient(y, d, Lz), e_n, e_at
    (raw0, cor0, en0, ea0), (raw1, cor1, en1, ea1) = _both(m, run)
    E, gy, gd, dL = raw0
    gscale = max(np.abs(gy).max(), np.abs(gd).max())
    assert abs(raw1[0] - E) <= TOL * abs(E)
    assert abs(cor1[0] - cor0[0]) <= TOL * abs(E)
    for k in (1, 2):  # gy, gd; the corrected ones on the scale of the raw gradient
        assert _diff(raw0[k], raw1[k], gscale) <= TOL
        assert _diff(cor0[k], cor1[k], gscale) <= TOL
    assert abs(raw1[3] - dL) <= TOL * max(abs(dL), gscale)
    assert abs(cor1[3] - cor0[3]) <= TOL * max(abs(dL), gscale)
    assert _diff(en0, en1, np.abs(en0).max()) <= TOL
    assert _diff(ea0, ea1, np.abs(ea0).max()) <= TOL


def _fail_particle(m, c):
    """What :meth:`DCBRTube.check_stability` does to a failed particle."""
    failed = np.zeros(m.N, bool)
    failed[c] = True
    g = m.gain
    m.intact &= ~(failed[g.pair_i] | failed[g.pair_j])
    m._build_gain(m.intact)
    m.alive &= ~failed


def _break_links(m, rng, frac=0.05):
    g = m.gain
    kill = rng.choice(len(m.intact), size=max(1, int(frac * len(m.intact))), replace=False)
    m.intact[kill] = False
    # both directions of a broken link, as update_links breaks them
    pairs = set(zip(g.pair_i[kill].tolist(), g.pair_j[kill].tolist()))
    back = np.array([(j, i) in pairs for i, j in zip(g.pair_i, g.pair_j)])
    m.intact &= ~back
    m._build_gain(m.intact)


@pytest.mark.parametrize("periodic, kw", [(True, {}), (False, {}),
                                          (False, {"hourglass": 0.0}),
                                          (True, {"relax_shift": False})])
def test_defect_tube_kernels_match_numpy(periodic, kw):
    m = DCBRDefectTube(6, 6, 30.0, coarsening=2.0, vacancy=4, r_atomistic=5.0, **kw)
    rng = np.random.default_rng(5)
    if not periodic:
        m.periodic = False
        m._build_gain(None)
    lt, lz, sh = m.uniform_lattice(1.02)
    y, d, Lz = m.uniform_state(lt, lz, sh)
    m.prepare_step(Lz)
    _check(m, y, d, Lz)  # (a) uniform state
    yp = y + rng.normal(scale=0.05, size=y.shape)
    dp = d + rng.normal(scale=0.01, size=d.shape)
    _check(m, yp, dp, Lz)  # (b) perturbed
    _break_links(m, rng)  # (c) links broken
    _check(m, yp, dp, Lz)
    c = int(m._pad["c"][0])  # a carrier of pad atoms fails: its pads keep its last map
    _fail_particle(m, c)
    assert not m.gain.alive[c]
    _check(m, yp, dp, Lz)
    m.alive[int(m._pad["c"][-1])] = False  # dead carrier that G still has
    _check(m, yp, dp, Lz)


@pytest.mark.parametrize("periodic", [True, False])
def test_plain_tube_hourglass_kernel_matches_numpy(periodic):
    t = DCBRTube(10, 10, 25.0, coarsening=2.0, stability=False)
    if not periodic:
        t.periodic = False
        t._build_gain(None)
    rng = np.random.default_rng(2)
    y = t.x0 + 0.05 * rng.standard_normal(t.x0.shape)
    d = 0.01 * rng.standard_normal((t.N, 3))
    L = 1.03 * t.L
    for step in range(3):
        if step == 1:
            _break_links(t, rng, 0.1)
        if step == 2:
            _fail_particle(t, 3)
        F = t.gain.deformation(y, [0, 0, L])
        (Es0, P0, gy0, dL0), (Es1, P1, gy1, dL1) = _both(
            t, lambda: t.stab_energy_and_gradient(y, F, L))
        w0, w1 = _both(t, lambda: (t.stab_energy_and_gradient(y, F, L), t._w_stab_n.copy())[1])
        assert Es0 > 0 and abs(Es1 - Es0) <= TOL * Es0
        assert _diff(P0, P1, np.abs(P0).max()) <= TOL
        assert _diff(gy0, gy1, np.abs(gy0).max()) <= TOL
        assert abs(dL1 - dL0) <= TOL * max(abs(dL0), np.abs(gy0).max())
        assert _diff(w0, w1, w0.max()) <= TOL
        (E0, g0, gd0, L0), (E1, g1, gd1, L1) = _both(t, lambda: t.energy_and_gradient(y, d, L))
        assert abs(E1 - E0) <= TOL * abs(E0)
        assert _diff(g0, g1, np.abs(g0).max()) <= TOL
        assert _diff(gd0, gd1, np.abs(gd0).max()) <= TOL
        assert abs(L1 - L0) <= TOL * abs(L0)


def test_verlet_list_rebuilds_and_stays_exact():
    """The atomistic region's Verlet list: kept while the atoms move less than half the
    skin, rebuilt beyond; energies equal the per-call k-d tree pair list's either way; a
    non-finite position raises."""
    m = DCBRDefectTube(6, 6, 30.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)
    lt, lz, sh = m.uniform_lattice(1.0)
    y, d, Lz = m.uniform_state(lt, lz, sh)
    nd = len(m.dof_idx)
    m.energy_and_gradient(y, d, Lz)
    b0 = m._nl["builds"]
    rng = np.random.default_rng(0)
    small = y.copy()
    small[nd:] += 0.2 * m.nl_skin / np.sqrt(3) * rng.uniform(-1, 1, size=(m.nf, 3))
    _check(m, small, d, Lz)
    assert m._nl["builds"] == b0  # moved < skin/2: no rebuild
    far = y.copy()
    far[nd:] += rng.normal(scale=0.3, size=(m.nf, 3))  # several atoms move > skin/2
    far[nd + 3] += [1.5, 0.0, 0.0]
    _check(m, far, d, Lz)
    assert m._nl["builds"] > b0
    bad = y.copy()
    bad[nd + 7, 1] = np.nan
    with pytest.raises(FloatingPointError, match="atom 7 of the atomistic region"):
        m.energy_and_gradient(bad, d, Lz)
    m.nl_skin = 2.0  # a wider skin than the list was built with: rebuilt
    b1 = m._nl["builds"]
    _check(m, y, d, Lz)
    assert m._nl["builds"] == b1 + 1


def test_forces_do_not_depend_on_the_verlet_skin():
    """The atomistic region's Verlet list sorts each atom's partners, so two tubes whose
    lists have different skins (and are rebuilt at different steps of a walk) give the
    same energy and gradients to the last bit; the narrow default holds the first
    neighbours only."""
    a = DCBRDefectTube(6, 6, 30.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)
    b = DCBRDefectTube(6, 6, 30.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)
    b.nl_skin = 1.0
    lt, lz, sh = a.uniform_lattice(1.03)
    y, d, Lz = a.uniform_state(lt, lz, sh)
    nd = len(a.dof_idx)
    rng = np.random.default_rng(3)
    for _ in range(8):  # a walk of 0.05 Å steps: the two lists are rebuilt at other steps
        y = y.copy()
        y[nd:] += 0.05 / np.sqrt(3) * rng.uniform(-1, 1, size=(a.nf, 3))
        ea, gya, gda, _ = a._raw_energy_and_gradient(y, d, Lz)
        eb, gyb, gdb, _ = b._raw_energy_and_gradient(y, d, Lz)
        assert ea == eb and np.array_equal(gya, gyb) and np.array_equal(gda, gdb)
    assert a._nl["builds"] > b._nl["builds"]  # the narrow list was rebuilt more often
    assert len(a._nl["jl"]) < 0.4 * len(b._nl["jl"])  # 3 partners an atom, not 12


def test_method_is_validated_and_reaches_the_twin():
    m = DCBRDefectTube(6, 6, 30.0, coarsening=2.0, vacancy=4, r_atomistic=5.0,
                       method="numpy")
    assert m.method == "numpy" and m._twin.method == "numpy"
    m.method = "numba"
    assert m._twin.method == "numba"
    with pytest.raises(ValueError, match="method='fortran'.*valid"):
        m.method = "fortran"


@pytest.mark.parametrize("n", [7, 1818])
def test_ghost_gradient_kernel_equals_the_array_expression(n):
    """The dead load's gradient kernel against its numpy expression (centroid offsets,
    cylindrical components, the centroid's mean taken out), bit for bit."""
    from upscale.models import dcbr_coupling_kernels as CK

    rng = np.random.default_rng(n)
    y = rng.standard_normal((n, 3)) * 30 + [3.0, -2.0, 50.0]
    gr, gt, gz = rng.standard_normal((3, n))
    gy, gd, gdl = rng.standard_normal((n, 3)), rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
    xc = y[:, :2] - y[:, :2].mean(axis=0)
    rho = np.hypot(xc[:, 0], xc[:, 1])
    corr = np.empty_like(gy)
    corr[:, 0] = (gr * xc[:, 0] - gt * xc[:, 1] / rho) / rho
    corr[:, 1] = (gr * xc[:, 1] + gt * xc[:, 0] / rho) / rho
    corr[:, :2] -= corr[:, :2].mean(axis=0)
    corr[:, 2] = gz
    oy, od = np.empty_like(gy), np.empty_like(gd)
    CK.ghost_gradient(y, gr, gt, gz, gy, gd, gdl, oy, od)
    assert np.array_equal(oy, gy - corr) and np.array_equal(od, gd - gdl)


@pytest.mark.parametrize("far", [True, False])
@pytest.mark.parametrize("rc", [2.4, 3.1])
def test_cluster_pairs_equal_the_kd_tree_pairs(rc, far):
    """The atomistic region's Verlet list builder against scipy's k-d tree: the same pairs,
    each row's partners sorted, rows past n_rows empty; on a tube wall (a dense grid over
    its box) and with two atoms flown far off (the box's cells too many for a grid: the
    cells are keyed and sorted)."""
    from ase.build import nanotube
    from scipy.spatial import cKDTree

    from upscale.models import dcbr_coupling_kernels as CK

    x = nanotube(12, 6, length=3).positions
    x = x + np.random.default_rng(0).normal(scale=0.05, size=x.shape)
    if far:
        x[3] += [400.0, -2500.0, 30.0]
        x[-1] -= [0.0, 0.0, 900.0]
    cells = np.prod(np.floor((x.max(axis=0) - x.min(axis=0)) / rc) + 1)
    assert (cells > CK.GRID_CELLS_PER_ATOM * len(x)) == far  # each path taken once
    nf = int(0.7 * len(x))
    pr = cKDTree(x).query_pairs(rc, output_type="ndarray")
    ii = np.concatenate([pr[:, 0], pr[:, 1]])
    jj = np.concatenate([pr[:, 1], pr[:, 0]])
    keep = ii < nf
    ii, jj = ii[keep], jj[keep]
    order = np.lexsort((jj, ii))
    first = np.zeros(len(x) + 1, np.int64)
    np.cumsum(np.bincount(ii, minlength=len(x)), out=first[1:])
    got_first, got = CK.cluster_pairs(x, nf, rc)
    assert np.array_equal(got_first, first) and np.array_equal(got, jj[order])
    assert first[nf + 1] - first[nf] == 0 and len(got) > 2 * nf
    e_first, e = CK.cluster_pairs(x[:0], 0, rc)
    assert e_first.tolist() == [0] and len(e) == 0
