"""The half bond list (upscale.engine.bondlist) against the directed-bond equations written
out in numpy: PMB and LPS forces and bond failure, with per-particle volumes, LAMMPS's
partial volumes, a bond state that differs between the two directions of some bonds,
one and two threads, a family whose rows are not sorted and an irregular point cloud."""
import numpy as np
import pytest

from upscale.engine import Family, ParticleSystem, State, build_family, cubic_lattice
from upscale.engine.bondlist import BondList
from upscale.engine.kernels import set_threads
from upscale.models.bond_based import PMB
from upscale.models.state_based import LPS

H = 1e-3


def _body(irregular=False, seed=0):
    rng = np.random.default_rng(seed)
    if irregular:
        x = rng.uniform(0, 7 * H, size=(300, 3))
        sysm = ParticleSystem(x, H ** 3 * (1 + 0.2 * rng.uniform(-1, 1, 300)), 2000.0, spacing=H)
        fam = build_family(sysm, 2.2 * H)
    else:
        lat = cubic_lattice(7, 7, 7, H)
        vol = H ** 3 * (1 + 0.2 * rng.uniform(-1, 1, lat.n))
        sysm = ParticleSystem(lat.x0, vol, 2000.0, spacing=H)
        fam = build_family(sysm, 3.0002 * H, partial_volume="lammps")
    st = State.reference(sysm.x0, fam.nb)
    st.y += rng.normal(scale=2e-3 * H, size=st.y.shape)
    st.intact[rng.uniform(size=fam.nb) < 0.1] = False  # directions broken independently
    return sysm, fam, st


def _shuffled_rows(fam, seed=1):
    """The same family with the bonds of every row in a random order."""
    rng = np.random.default_rng(seed)
    order = np.concatenate([fam.offsets[i] + rng.permutation(fam.counts[i]) for i in range(fam.n)])
    return Family(fam.offsets.copy(), fam.neighbors[order].copy(), fam.x0, fam.horizon,
                  fam.spacing, fam.partial_volume), order


def _pmb_reference(model, fam, st):
    i, j = fam.owner, fam.neighbors
    d = st.y[j] - st.y[i]
    r = np.linalg.norm(d, axis=1)
    fb = model.c * model.w_b * (1.0 / fam.length - 1.0 / r) * st.intact
    out = np.zeros_like(st.y)
    np.add.at(out, i, fb[:, None] * d)
    broken = st.intact & (r * r > (fam.length * (1 + model.s0)) ** 2)
    return out, broken


def _lps_reference(model, fam, st):
    i, j = fam.owner, fam.neighbors
    d = st.y[j] - st.y[i]
    r = np.linalg.norm(d, axis=1)
    L, om = fam.length, model.omega_b
    e = (r - L) * st.intact
    theta = model.dm * np.bincount(i, weights=om * L * e * model.w_b, minlength=fam.n)
    im = model.inv_m
    rk = (model.A * model.w_b * om * L * (theta[i] * im[i] + theta[j] * im[j])
          + model.wd_b * om * (im[i] + im[j]) * e) * st.intact
    out = np.zeros_like(st.y)
    np.add.at(out, i, (rk / r)[:, None] * d)
    broken = st.intact & ((r - L) / L > model.s0)
    return out, broken, theta


def _run(model, st, threads):
    set_threads(threads)
    try:
        s = State(st.x0, st.y.copy(), st.v.copy(), st.intact.copy())
        out = np.zeros_like(st.y)
        nbroke = model.step_force(s, out)
        return out, s.intact, nbroke
    finally:
        set_threads(1)


CASES = [("lattice", False, False), ("unsorted rows", False, True), ("irregular", True, False)]


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("name,irregular,shuffle", CASES)
@pytest.mark.parametrize("surface_correction", [False, True])
def test_pmb_half_list_matches_directed_equations(name, irregular, shuffle, threads, surface_correction):
    sysm, fam, st = _body(irregular)
    if shuffle:
        fam, order = _shuffled_rows(fam)
        st.intact[...] = st.intact[order]
    m = PMB(E=70e9, s0=1e-3, surface_correction=surface_correction)
    m.prepare(sysm, fam)
    if shuffle:
        assert m.bonds.fwd_p.size == m.bonds.npairs
    ref, broken = _pmb_reference(m, fam, st)
    assert broken.any() and not broken.all()
    out, intact, nbroke = _run(m, st, threads)
    assert np.abs(out - ref).max() <= 1e-13 * np.abs(ref).max()
    np.testing.assert_array_equal(intact, st.intact & ~broken)
    assert nbroke == broken.sum()


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("name,irregular,shuffle", CASES)
@pytest.mark.parametrize("surface_correction", [False, True])
def test_lps_half_list_matches_directed_equations(name, irregular, shuffle, threads, surface_correction):
    sysm, fam, st = _body(irregular, seed=2)
    if shuffle:
        fam, order = _shuffled_rows(fam)
        st.intact[...] = st.intact[order]
    m = LPS(E=70e9, nu=0.3, s0=1e-3, surface_correction=surface_correction)
    m.prepare(sysm, fam)
    ref, broken, theta = _lps_reference(m, fam, st)
    assert broken.any() and not broken.all()
    out, intact, nbroke = _run(m, st, threads)
    assert np.abs(m._theta - theta).max() <= 1e-13 * np.abs(theta).max()
    assert np.abs(out - ref).max() <= 1e-13 * np.abs(ref).max()
    np.testing.assert_array_equal(intact, st.intact & ~broken)
    assert nbroke == broken.sum()


def test_layout_of_a_lattice():
    """A lattice needs one byte of class per pair and unsigned 32-bit partners."""
    sysm, fam, _ = _body()
    bl = BondList(fam, sysm.volume)
    k_p, L_k, bf_k, br_k = bl.classes()
    assert bl.npairs * 2 == fam.nb and k_p.dtype == np.uint8 and bl.j_p.dtype == np.uint32
    assert bl.fwd_p.size == 0
    fwd = bl.forward_index()
    np.testing.assert_array_equal(L_k[k_p], fam.length[fwd])
    np.testing.assert_array_equal(bf_k[k_p], fam.volume_factor[fwd])
    np.testing.assert_array_equal(br_k[k_p], fam.volume_factor[bl.rev_p])
    np.testing.assert_array_equal(fam.owner[bl.rev_p], bl.j_p)
    np.testing.assert_array_equal(fam.neighbors[bl.rev_p], fam.owner[fwd])


def test_thread_chunks_cover_every_particle_once():
    sysm, fam, _ = _body()
    bl = BondList(fam, sysm.volume)
    for t in (1, 2, 3, 7):
        c = bl.chunks(t)
        assert c[0] == 0 and c[-1] == fam.n and np.all(np.diff(c) >= 0) and c.size == t + 1


@pytest.mark.parametrize("threads", [1, 2])
def test_lammps_contact_half_list_matches_directed_equations(threads):
    from upscale.models.bond_based import LammpsContact

    sysm, fam, st = _body()
    st.y[...] = 0.8 * sysm.x0 + np.random.default_rng(4).normal(scale=0.05 * H, size=st.y.shape)
    ct = LammpsContact(1e20, H)
    ct.prepare(sysm, fam)
    i, j = fam.owner, fam.neighbors
    d = st.y[j] - st.y[i]
    r = np.linalg.norm(d, axis=1)
    dij = np.minimum(0.9 * fam.length, 1.35 * H)
    on = r < dij
    assert on.any() and not on.all()
    ref = np.zeros_like(st.y)
    np.add.at(ref, i, (on * 1e20 * sysm.volume[j] * (r - dij) / r)[:, None] * d)
    set_threads(threads)
    try:
        out = ct.force(st)
    finally:
        set_threads(1)
    assert np.abs(out - ref).max() <= 1e-13 * np.abs(ref).max()
    assert ct.last_active == on.sum()


def test_reverse_index_by_bisection_matches_the_family():
    sysm, fam, _ = _body()
    bl = BondList(fam, sysm.volume)
    np.testing.assert_array_equal(bl.rev_p, fam.reverse[bl.forward_index()])
    shuffled, _ = _shuffled_rows(fam)
    bl2 = BondList(shuffled, sysm.volume)  # unsorted rows: the family's own reverse
    np.testing.assert_array_equal(bl2.rev_p, shuffled.reverse[bl2.forward_index()])
    one_way = Family(fam.offsets, fam.neighbors, fam.x0, fam.horizon, fam.spacing)
    one_way.neighbors = fam.neighbors.copy()
    row = slice(fam.offsets[5], fam.offsets[6])
    one_way.neighbors[row] = np.where(one_way.neighbors[row] > 5, one_way.neighbors[row], 0)
    with pytest.raises(ValueError, match="not symmetric"):
        BondList(one_way, sysm.volume)


def test_classes_in_blocks_and_from_callables(monkeypatch):
    """The classes found block by block are those of one pass, and a factor given as a
    callable of bond indices gives the same tables as the factor's array."""
    import upscale.engine.bondlist as bondlist

    sysm, fam, _ = _body()
    g = np.random.default_rng(7).choice([1.0, 1.25, 0.8], size=fam.n)
    fac = 0.5 * (g[fam.owner] + g[fam.neighbors])
    whole = BondList(fam, sysm.volume).classes(fac)
    monkeypatch.setattr(bondlist, "_CLASS_BLOCK", 97)
    blocked = BondList(fam, sysm.volume).classes(lambda b: 0.5 * (g[fam.owner_of(b)] + g[fam.neighbors[b]]))
    for a, b in zip(whole, blocked):
        np.testing.assert_array_equal(a, b)
    bl = BondList(fam, sysm.volume)
    k_p, L_k, bf_k, br_k, ff_k, fr_k = blocked
    fwd, rev = bl.forward_index(), bl.rev_p
    np.testing.assert_array_equal(L_k[k_p], fam.length[fwd])
    np.testing.assert_array_equal(ff_k[k_p], fac[fwd])
    np.testing.assert_array_equal(fr_k[k_p], fac[rev])
