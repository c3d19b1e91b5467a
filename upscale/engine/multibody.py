"""Higher families: triplets (i; j, k) and quadruplets (i; j, k, l) built from a pair CSR.

Generic multi-neighbour interaction sets for models that need them (CPD two- and
three-neighbour interactions, seed 000 "The contributing neighbours"; tridynamics).
They are built on demand from the engine's pair family and never otherwise.

Conventions
-----------
* Every set belongs to a **centre** particle ``i`` and lists *unordered* neighbours of
  ``i`` taken from its own family row: a triplet is ``{j, k}`` with slot ``p < q`` in row
  ``i``, a quadruplet ``{j, k, l}`` with slots ``p < q < r``. The same geometric triangle
  ``{i, j, k}`` can therefore also appear in the families of ``j`` and ``k`` (as centres);
  that is intended -- a model that sums "over the neighbourhood of every point" (CPD's
  double and triple integrals over H_0 x H_0) sees it once per centre.
* Neighbours are stored as **slots**: ``slot_j`` is the position of ``j`` inside the centre's
  pair row, so the global index is ``family.neighbors[family.offsets[i] + slot_j]`` and the
  pair-level data of the bond (reference vector, bond state) are at that same position.
  :meth:`TripletFamily.members` returns global indices.
* **Filter** (seed 000: "the points ... should be non-collinear", else the stiffness is
  singular): a triplet is kept only if its reference area ``A = |xi_j x xi_k|`` exceeds
  ``tol * |xi_j| |xi_k|`` (sine of the angle > tol); a quadruplet only if
  ``|V| = |xi_j . (xi_k x xi_l)| > tol * |xi_j| |xi_k| |xi_l|``. Default ``tol = 1e-6``.

Array suffixes: ``_n`` per particle, ``_t`` per triplet, ``_q`` per quadruplet.

Cost. With ``m`` neighbours per point there are up to ``m(m-1)/2`` triplets and
``m(m-1)(m-2)/6`` quadruplets per point. Measured on a simple-cubic lattice (``bench-cpd``,
horizon ``(k + 0.01) dx``): ``m = 32, 122, 256`` bonds, 468, 7260, 32400 non-collinear
triplets and 3488, 259048, 2579264 non-coplanar quadruplets per interior point for
``k = 2, 3, 4``; 2D: 12, 28, 48 bonds and 52, 332, 1048 triplets. Storing the quadruplets
of a whole 3D body beyond ``delta/dx = 2`` is not feasible (20 bytes each). :func:`count_triplets` / :func:`count_quadruplets` count without storing, the
builders accept a subset of ``centres`` and refuse (one-line ``MemoryError``) to store more
than ``max_sets`` sets.
"""
from __future__ import annotations

import dataclasses

import numba
import numpy as np

__all__ = ["TripletFamily", "QuadrupletFamily", "build_triplets", "build_quadruplets",
           "count_triplets", "count_quadruplets", "block_pattern", "member_pattern"]

DEFAULT_TOL = 1e-6
DEFAULT_MAX_SETS = 30_000_000


@dataclasses.dataclass(eq=False)
class TripletFamily:
    """Non-collinear neighbour pairs ``{j, k}`` of every centre ``i`` (CSR over centres).

    Attributes
    ----------
    offsets : int64 (N+1,)
        Centre i's triplets are ``offsets[i]:offsets[i+1]``.
    slot_j, slot_k : int32 (nt,)
        Slots (positions in the centre's pair row) of the two neighbours, ``slot_j < slot_k``.
    area : float64 (nt,)
        Reference area measure ``A = |Xi_j x Xi_k|`` (m^2; twice the triangle area).
    tol : float
        Non-collinearity tolerance used (sine of the angle).
    """

    offsets: np.ndarray
    slot_j: np.ndarray
    slot_k: np.ndarray
    area: np.ndarray
    tol: float

    @property
    def n(self) -> int:
        return self.offsets.shape[0] - 1

    @property
    def size(self) -> int:
        """Number of triplets."""
        return self.slot_j.shape[0]

    @property
    def counts(self) -> np.ndarray:
        """Triplets per centre (N,)."""
        return np.diff(self.offsets)

    @property
    def nbytes(self) -> int:
        return int(self.offsets.nbytes + self.slot_j.nbytes + self.slot_k.nbytes + self.area.nbytes)

    def members(self, family) -> np.ndarray:
        """Global indices ``(i, j, k)`` of every triplet, (nt, 3) int64."""
        i = np.repeat(np.arange(self.n, dtype=np.int64), self.counts)
        base = family.offsets[i]
        return np.stack([i, family.neighbors[base + self.slot_j],
                         family.neighbors[base + self.slot_k]], axis=1)

    def __repr__(self) -> str:
        return (f"TripletFamily(n={self.n}, triplets={self.size}, "
                f"per centre={self.size / max(self.n, 1):.1f}, {self.nbytes / 1e6:.1f} MB)")


@dataclasses.dataclass(eq=False)
class QuadrupletFamily:
    """Non-coplanar neighbour triples ``{j, k, l}`` of every centre ``i`` (CSR over centres).

    Attributes
    ----------
    offsets : int64 (N+1,)
    slot_j, slot_k, slot_l : int32 (nq,)
        Slots of the three neighbours in the centre's pair row, ``slot_j < slot_k < slot_l``.
    volume : float64 (nq,)
        Reference volume measure ``|V| = |Xi_j . (Xi_k x Xi_l)|`` (m^3; six times the
        tetrahedron volume).
    tol : float
    """

    offsets: np.ndarray
    slot_j: np.ndarray
    slot_k: np.ndarray
    slot_l: np.ndarray
    volume: np.ndarray
    tol: float

    @property
    def n(self) -> int:
        return self.offsets.shape[0] - 1

    @property
    def size(self) -> int:
        return self.slot_j.shape[0]

    @property
    def counts(self) -> np.ndarray:
        return np.diff(self.offsets)

    @property
    def nbytes(self) -> int:
        return int(self.offsets.nbytes + 3 * self.slot_j.nbytes + self.volume.nbytes)

    def members(self, family) -> np.ndarray:
        """Global indices ``(i, j, k, l)`` of every quadruplet, (nq, 4) int64."""
        i = np.repeat(np.arange(self.n, dtype=np.int64), self.counts)
        base = family.offsets[i]
        nb = family.neighbors
        return np.stack([i, nb[base + self.slot_j], nb[base + self.slot_k],
                         nb[base + self.slot_l]], axis=1)

    def __repr__(self) -> str:
        return (f"QuadrupletFamily(n={self.n}, quadruplets={self.size}, "
                f"per centre={self.size / max(self.n, 1):.1f}, {self.nbytes / 1e6:.1f} MB)")


# --------------------------------------------------------------------------- kernels
@numba.njit(cache=True)
def _triplet_pass(x0, offsets, neighbors, centre_mask, tol, fill, out_off, sj, sk, area):
    """Count (fill=False) or fill (fill=True) the non-collinear triplets of each centre."""
    n = offsets.shape[0] - 1
    pos = 0
    for i in range(n):
        if fill:
            out_off[i] = pos
        if not centre_mask[i]:
            continue
        a, b = offsets[i], offsets[i + 1]
        for p in range(a, b):
            j = neighbors[p]
            u0 = x0[j, 0] - x0[i, 0]
            u1 = x0[j, 1] - x0[i, 1]
            u2 = x0[j, 2] - x0[i, 2]
            lu = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
            for q in range(p + 1, b):
                k = neighbors[q]
                v0 = x0[k, 0] - x0[i, 0]
                v1 = x0[k, 1] - x0[i, 1]
                v2 = x0[k, 2] - x0[i, 2]
                c0 = u1 * v2 - u2 * v1
                c1 = u2 * v0 - u0 * v2
                c2 = u0 * v1 - u1 * v0
                A = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
                lv = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                if A > tol * lu * lv:
                    if fill:
                        sj[pos] = p - a
                        sk[pos] = q - a
                        area[pos] = A
                    pos += 1
    if fill:
        out_off[n] = pos
    return pos


@numba.njit(cache=True)
def _triplet_counts(x0, offsets, neighbors, centre_mask, tol, out_counts):
    n = offsets.shape[0] - 1
    for i in range(n):
        if not centre_mask[i]:
            continue
        a, b = offsets[i], offsets[i + 1]
        c = 0
        for p in range(a, b):
            j = neighbors[p]
            u0 = x0[j, 0] - x0[i, 0]
            u1 = x0[j, 1] - x0[i, 1]
            u2 = x0[j, 2] - x0[i, 2]
            lu = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
            for q in range(p + 1, b):
                k = neighbors[q]
                v0 = x0[k, 0] - x0[i, 0]
                v1 = x0[k, 1] - x0[i, 1]
                v2 = x0[k, 2] - x0[i, 2]
                c0 = u1 * v2 - u2 * v1
                c1 = u2 * v0 - u0 * v2
                c2 = u0 * v1 - u1 * v0
                A = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
                lv = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                if A > tol * lu * lv:
                    c += 1
        out_counts[i] = c


@numba.njit(cache=True)
def _quad_pass(x0, offsets, neighbors, centre_mask, tol, fill, out_off, sj, sk, sl, vol,
               out_counts):
    """Count or fill the non-coplanar quadruplets of each centre (counts per centre always
    written to ``out_counts``)."""
    n = offsets.shape[0] - 1
    pos = 0
    for i in range(n):
        if fill:
            out_off[i] = pos
        if not centre_mask[i]:
            continue
        a, b = offsets[i], offsets[i + 1]
        m = b - a
        xi = np.empty((m, 3))
        ln = np.empty(m)
        for p in range(m):
            j = neighbors[a + p]
            for c in range(3):
                xi[p, c] = x0[j, c] - x0[i, c]
            ln[p] = np.sqrt(xi[p, 0] ** 2 + xi[p, 1] ** 2 + xi[p, 2] ** 2)
        start = pos
        for p in range(m):
            for q in range(p + 1, m):
                c0 = xi[p, 1] * xi[q, 2] - xi[p, 2] * xi[q, 1]
                c1 = xi[p, 2] * xi[q, 0] - xi[p, 0] * xi[q, 2]
                c2 = xi[p, 0] * xi[q, 1] - xi[p, 1] * xi[q, 0]
                lpq = ln[p] * ln[q]
                for r in range(q + 1, m):
                    V = c0 * xi[r, 0] + c1 * xi[r, 1] + c2 * xi[r, 2]
                    if abs(V) > tol * lpq * ln[r]:
                        if fill:
                            sj[pos] = p
                            sk[pos] = q
                            sl[pos] = r
                            vol[pos] = abs(V)
                        pos += 1
        out_counts[i] = pos - start
    if fill:
        out_off[n] = pos
    return pos


# --------------------------------------------------------------------------- builders
def _centre_mask(n, centres):
    if centres is None:
        return np.ones(n, dtype=np.bool_)
    mask = np.zeros(n, dtype=np.bool_)
    mask[np.asarray(centres, dtype=np.int64)] = True
    return mask


def _arrays(x0, family):
    if hasattr(x0, "x0"):           # a ParticleSystem
        x0 = x0.x0
    x0 = np.ascontiguousarray(x0, dtype=np.float64)
    if x0.ndim != 2 or x0.shape[1] != 3:
        raise ValueError(f"positions must have shape (N, 3), got {x0.shape}")
    offsets = np.ascontiguousarray(family.offsets, dtype=np.int64)
    neighbors = np.ascontiguousarray(family.neighbors, dtype=np.int64)
    if offsets.shape[0] != x0.shape[0] + 1:
        raise ValueError(f"family has {offsets.shape[0] - 1} particles, positions {x0.shape[0]}")
    return x0, offsets, neighbors


def _check_tol(tol):
    if not (0.0 <= tol < 1.0):
        raise ValueError(f"tol must be in [0, 1), got {tol!r}")


def count_triplets(x0, family, *, centres=None, tol: float = DEFAULT_TOL) -> np.ndarray:
    """Non-collinear triplets per centre (N,) int64, without storing them."""
    _check_tol(tol)
    x0, off, nb = _arrays(x0, family)
    out = np.zeros(off.shape[0] - 1, dtype=np.int64)
    _triplet_counts(x0, off, nb, _centre_mask(x0.shape[0], centres), float(tol), out)
    return out


def count_quadruplets(x0, family, *, centres=None, tol: float = DEFAULT_TOL) -> np.ndarray:
    """Non-coplanar quadruplets per centre (N,) int64, without storing them."""
    _check_tol(tol)
    x0, off, nb = _arrays(x0, family)
    n = x0.shape[0]
    out = np.zeros(n, dtype=np.int64)
    d_i, d_f = np.zeros(1, np.int64), np.zeros(1)
    d_s = np.zeros(1, np.int32)
    _quad_pass(x0, off, nb, _centre_mask(n, centres), float(tol), False, d_i, d_s, d_s, d_s,
               d_f, out)
    return out


def build_triplets(x0, family, *, centres=None, tol: float = DEFAULT_TOL,
                   max_sets: int = DEFAULT_MAX_SETS) -> TripletFamily:
    """Build the non-collinear triplet family of every centre (or of ``centres`` only).

    Parameters
    ----------
    x0 : (N, 3) float64 or ParticleSystem
        Reference positions (m).
    family : pair family with ``offsets`` (N+1,) and ``neighbors`` (nb,) (engine ``Family``)
    centres : int array, optional
        Build only these centres' triplets (others get empty rows).
    tol : float
        Non-collinearity tolerance on the sine of the angle between the two bonds.
    max_sets : int
        Refuse to store more triplets than this (``MemoryError``).
    """
    _check_tol(tol)
    x0, off, nb = _arrays(x0, family)
    n = x0.shape[0]
    mask = _centre_mask(n, centres)
    d_i, d_f, d_s = np.zeros(1, np.int64), np.zeros(1), np.zeros(1, np.int32)
    total = _triplet_pass(x0, off, nb, mask, float(tol), False, d_i, d_s, d_s, d_f)
    if total > max_sets:
        raise MemoryError(f"{total} triplets ({total * 16 / 1e9:.2f} GB) exceed max_sets="
                          f"{max_sets}; use a smaller horizon, fewer centres or raise max_sets")
    out_off = np.zeros(n + 1, dtype=np.int64)
    sj = np.empty(total, np.int32)
    sk = np.empty(total, np.int32)
    area = np.empty(total)
    _triplet_pass(x0, off, nb, mask, float(tol), True, out_off, sj, sk, area)
    return TripletFamily(out_off, sj, sk, area, float(tol))


def build_quadruplets(x0, family, *, centres=None, tol: float = DEFAULT_TOL,
                      max_sets: int = DEFAULT_MAX_SETS) -> QuadrupletFamily:
    """Build the non-coplanar quadruplet family of every centre (or of ``centres`` only).

    Same parameters as :func:`build_triplets`; ``tol`` bounds
    ``|V| / (|xi_j| |xi_k| |xi_l|)`` from below. Memory: 20 bytes per quadruplet.
    """
    _check_tol(tol)
    x0, off, nb = _arrays(x0, family)
    n = x0.shape[0]
    mask = _centre_mask(n, centres)
    counts = count_quadruplets(x0, family, centres=centres, tol=tol)
    total = int(counts.sum())
    if total > max_sets:
        raise MemoryError(f"{total} quadruplets ({total * 20 / 1e9:.2f} GB) exceed max_sets="
                          f"{max_sets}; use a smaller horizon, fewer centres or raise max_sets")
    out_off = np.zeros(n + 1, dtype=np.int64)
    sj = np.empty(total, np.int32)
    sk = np.empty(total, np.int32)
    sl = np.empty(total, np.int32)
    vol = np.empty(total)
    _quad_pass(x0, off, nb, mask, float(tol), True, out_off, sj, sk, sl, vol, counts)
    return QuadrupletFamily(out_off, sj, sk, sl, vol, float(tol))


def block_pattern(x0, radius: float, *, dim: int = 3):
    """Block-CSR sparsity pattern (``indptr``, ``indices``) of all particle pairs within
    ``radius`` plus the diagonal, columns sorted per row.

    A multi-neighbour interaction centred at ``i`` couples any two members, which lie within
    twice the horizon of each other: pass ``radius = 2 * max bond length`` for models with
    triplets/quadruplets and the bond length for pair-only models. ``dim`` only selects the
    coordinates used for the distance.
    """
    from scipy.spatial import cKDTree

    x = np.ascontiguousarray(np.asarray(x0, dtype=np.float64)[:, :dim])
    n = x.shape[0]
    pairs = cKDTree(x).query_pairs(float(radius), output_type="ndarray")
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(n)])
    order = np.lexsort((cols, rows))
    rows, cols = rows[order], cols[order]
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return indptr, np.ascontiguousarray(cols, dtype=np.int64)


def member_pattern(family, centres, n: int | None = None):
    """Exact block-CSR pattern (``indptr``, ``indices``) of the interactions owned by
    ``centres``: every pair of members of ``{i} + H_i`` for each centre ``i``, plus the
    diagonal. Use it when only a few centres own interactions (the geometric
    :func:`block_pattern` would cover the whole body)."""
    n = family.n if n is None else int(n)
    keys = [np.arange(n, dtype=np.int64) * (n + 1)]
    for c in np.asarray(centres, dtype=np.int64):
        mem = np.concatenate([[c], family.neighbors[family.offsets[c]:family.offsets[c + 1]]])
        keys.append((mem[:, None] * n + mem[None, :]).ravel())
    k = np.unique(np.concatenate(keys))
    rows, cols = k // n, k % n
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return indptr, np.ascontiguousarray(cols)
