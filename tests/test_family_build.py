"""``build_family`` block by block against the all-pairs construction (cKDTree.query_pairs of
every pair at once, both directions, a lexsort), and the bisection reverse index against a
sort of the bond keys."""
import numpy as np
import pytest

import upscale.engine.families as families
from upscale.engine import ParticleSystem, bonds_crossing_segment, build_family, cubic_lattice, square_lattice


def _all_pairs(system, horizon, partial_volume=None, exclude=None):
    """The family's arrays from one list of all pairs (the construction the blocks replace)."""
    from scipy.spatial import cKDTree

    x, n, h, delta = system.x0, system.n, system.spacing, float(horizon)
    rmax = delta + 0.5 * h if partial_volume == "linear" else delta
    pairs = cKDTree(x).query_pairs(rmax * (1.0 + 1e-9) + 1e-300, output_type="ndarray").astype(np.int64)
    i = np.concatenate([pairs[:, 0], pairs[:, 1]])
    j = np.concatenate([pairs[:, 1], pairs[:, 0]])
    d = x[j] - x[i]
    rsq = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
    keep = np.sqrt(rsq) < rmax if partial_volume == "linear" else rsq <= delta * delta
    if exclude is not None:
        ex = np.asarray(exclude(i, j, d), dtype=bool)
        P = pairs.shape[0]
        keep &= ~np.concatenate([ex[:P] | ex[P:], ex[:P] | ex[P:]])
    i, j, d, rsq = i[keep], j[keep], d[keep], rsq[keep]
    order = np.lexsort((j, i))
    i, j, d, rsq = i[order], j[order], d[order], rsq[order]
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(i, minlength=n), out=offsets[1:])
    return offsets, j, d, np.sqrt(rsq)


def _scenes():
    s2 = square_lattice(40, 30, 0.5e-3, thickness=0.5e-3, centered=True)
    cut = bonds_crossing_segment(s2.x0, (-0.011, 0.0), (0.0, 0.0))
    yield "2d m=3", s2, 3 * 0.5e-3 * (1 + 1e-9), None, None
    yield "2d m=6 linear, pre-crack", s2, 6 * 0.5e-3 * (1 + 1e-9), "linear", cut
    yield "3d lammps", cubic_lattice(9, 8, 7, 1.0), 3.0002, "lammps", None
    rng = np.random.default_rng(3)
    x = rng.uniform(0.0, 10.0, (700, 3))
    x[:, 2] = 0.0
    yield "random 2d cloud", ParticleSystem(x, 0.1, 1.0, dim=2, thickness=1.0, spacing=0.4), 1.3, "linear", None


@pytest.mark.parametrize("block", [families._BLOCK_BONDS, 997])
@pytest.mark.parametrize("name,system,horizon,pv,exclude", list(_scenes()), ids=[s[0] for s in _scenes()])
def test_blocks_give_the_all_pairs_family_bit_for_bit(monkeypatch, block, name, system, horizon, pv, exclude):
    monkeypatch.setattr(families, "_BLOCK_BONDS", block)
    fam = build_family(system, horizon, partial_volume=pv, exclude=exclude)
    offsets, j, d, length = _all_pairs(system, horizon, pv, exclude)
    assert fam.nb > 0
    for got, ref in ((fam.offsets, offsets), (fam.neighbors, j.astype(np.int32)), (fam.xi, d),
                     (fam.length, length)):
        assert got.dtype == ref.dtype and got.flags.c_contiguous
        np.testing.assert_array_equal(got, ref)
    # the partial-volume factors recomputed from the lengths: the taper on the all-pairs
    # lengths, bit for bit
    if pv is None:
        np.testing.assert_array_equal(fam.volume_factor, np.ones_like(length))
    else:
        half = 0.5 * system.spacing
        ref_beta = np.where(np.abs(length - horizon) <= half,
                            (-1.0 / (2 * half)) * length + (1.0 + ((horizon - half) / (2 * half))), 1.0)
        np.testing.assert_array_equal(fam.volume_factor, ref_beta)
    # kept: row pointers and 32-bit partners, nothing per bond beyond them
    assert fam.nbytes() == fam.offsets.nbytes + 4 * fam.nb


def test_bisection_reverse_equals_the_key_sort():
    s = square_lattice(30, 20, 1.0)
    fam = build_family(s, 3.5, partial_volume="linear")
    i, j, n = fam.owner, fam.neighbors, fam.n
    order = np.argsort(i * n + j, kind="stable")
    ref = order[np.searchsorted((i * n + j)[order], j * n + i)]
    assert families.rows_sorted(fam.offsets, fam.neighbors)
    np.testing.assert_array_equal(fam.reverse, ref)
    # an asymmetric family is refused on both paths
    broken = families.Family(fam.offsets, fam.neighbors.copy(), fam.x0, fam.horizon, fam.spacing)
    broken.neighbors[0], broken.neighbors[1] = broken.neighbors[1], broken.neighbors[0]
    assert not families.rows_sorted(broken.offsets, broken.neighbors)
    one_way = [(np.array([0, 1, 1]), np.array([1])),          # sorted rows: bisection
               (np.array([0, 2, 2, 2]), np.array([2, 1]))]     # unsorted row: the key sort
    for off, nbr in one_way:
        k = nbr.size
        lone = families.Family(off, nbr, np.zeros((off.size - 1, 3)), 2.0, 1.0)
        with pytest.raises(ValueError, match="no reverse"):
            lone.reverse


@pytest.mark.parametrize("pv", [None, "lammps", "linear"])
def test_subsets_and_blocks_equal_the_whole_arrays(pv):
    """``xi_of``, ``length_of``, ``volume_factor_of`` and ``owner_of`` of any bonds are the
    whole arrays' entries bit for bit; ``bond_blocks`` covers the bonds in whole rows."""
    s = square_lattice(23, 17, 1e-3, thickness=1e-3)
    fam = build_family(s, 3.2e-3, partial_volume=pv)
    b = np.random.default_rng(4).choice(fam.nb, 500, replace=False)
    np.testing.assert_array_equal(fam.owner_of(b), fam.owner[b])
    np.testing.assert_array_equal(fam.xi_of(b), fam.xi[b])
    np.testing.assert_array_equal(fam.length_of(b), fam.length[b])
    np.testing.assert_array_equal(fam.volume_factor_of(b), fam.volume_factor[b])
    blocks = fam.bond_blocks(1000)
    assert blocks[0][0] == 0 and blocks[-1][1] == fam.nb
    assert all(hi0 == lo1 for (_, hi0), (lo1, _) in zip(blocks[:-1], blocks[1:]))
    assert all(lo in set(fam.offsets.tolist()) for lo, _ in blocks)
    assert max(hi - lo for lo, hi in blocks) <= 1000 + fam.counts.max()


def test_explicit_beta_and_bad_input():
    s = square_lattice(10, 10, 1.0)
    fam = build_family(s, 3.2, partial_volume="linear")
    beta = fam.volume_factor
    beta[::3] *= 0.5
    g = families.Family(fam.offsets, fam.neighbors, fam.x0, fam.horizon, fam.spacing, "linear", beta)
    np.testing.assert_array_equal(g.volume_factor, beta)
    np.testing.assert_array_equal(g.volume_factor_of(np.arange(7)), beta[:7])
    cut = g.remove_bonds(np.arange(g.nb) % 5 == 0)
    assert cut.beta is not None and cut.beta.shape == (cut.nb,)
    with pytest.raises(ValueError, match="x0 must have shape"):
        families.Family(fam.offsets, fam.neighbors, fam.x0[:-1], 3.2, 1.0)
    with pytest.raises(ValueError, match="unknown partial_volume"):
        families.Family(fam.offsets, fam.neighbors, fam.x0, 3.2, 1.0, "cubic")
