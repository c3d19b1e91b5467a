"""Triplet / quadruplet families: counts against brute force, filters, slots, guards."""
import itertools

import numpy as np
import pytest

from upscale.engine import multibody
from upscale.engine.families import build_family
from upscale.engine.system import cubic_lattice, square_lattice


def _brute(x0, fam, order, tol):
    out = []
    for i in range(fam.n):
        row = fam.neighbors[fam.offsets[i]:fam.offsets[i + 1]]
        for comb in itertools.combinations(range(len(row)), order):
            v = [x0[row[p]] - x0[i] for p in comb]
            if order == 2:
                meas, ref = np.linalg.norm(np.cross(*v)), np.prod([np.linalg.norm(a) for a in v])
            else:
                meas = abs(np.dot(v[0], np.cross(v[1], v[2])))
                ref = np.prod([np.linalg.norm(a) for a in v])
            if meas > tol * ref:
                out.append((i,) + tuple(int(row[p]) for p in comb))
    return sorted(out)


def test_triplets_match_brute_force_2d():
    s = square_lattice(5, 4, 1.0)
    fam = build_family(s, 2.01)
    tri = multibody.build_triplets(s.x0, fam)
    got = sorted(map(tuple, tri.members(fam).tolist()))
    assert got == _brute(s.x0, fam, 2, tri.tol)
    assert np.array_equal(tri.counts, multibody.count_triplets(s.x0, fam))
    # stored reference areas are |xi_j x xi_k|
    m = tri.members(fam)
    a = np.linalg.norm(np.cross(s.x0[m[:, 1]] - s.x0[m[:, 0]], s.x0[m[:, 2]] - s.x0[m[:, 0]]), axis=1)
    assert np.allclose(tri.area, a)


def test_quadruplets_match_brute_force_3d_and_none_in_2d():
    s = cubic_lattice(3, 3, 3, 1.0)
    fam = build_family(s, 1.5)
    q = multibody.build_quadruplets(s, fam)
    got = sorted(map(tuple, q.members(fam).tolist()))
    assert got == _brute(s.x0, fam, 3, q.tol)
    assert len(got) > 0
    s2 = square_lattice(4, 4, 1.0)
    f2 = build_family(s2, 2.01)
    assert multibody.build_quadruplets(s2, f2).size == 0      # all coplanar


def test_collinear_sets_excluded_on_a_line():
    s = square_lattice(6, 1, 1.0)
    fam = build_family(s, 2.5)
    assert multibody.build_triplets(s, fam).size == 0


def test_centres_subset_and_memory_guard():
    s = cubic_lattice(4, 4, 4, 1.0)
    fam = build_family(s, 1.8)
    full = multibody.build_triplets(s, fam)
    sub = multibody.build_triplets(s, fam, centres=[5, 7])
    assert sub.size == full.counts[5] + full.counts[7]
    with pytest.raises(MemoryError, match="max_sets"):
        multibody.build_quadruplets(s, fam, max_sets=10)


def test_block_pattern_symmetric_with_diagonal():
    s = square_lattice(4, 4, 1.0)
    indptr, idx = multibody.block_pattern(s.x0, 1.5)
    import scipy.sparse as sp
    A = sp.csr_matrix((np.ones(idx.size), idx, indptr), shape=(s.n, s.n))
    assert (A != A.T).nnz == 0 and A.diagonal().all()
