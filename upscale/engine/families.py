"""Neighbour families within a horizon, as CSR arrays, and the bond state on them.

A :class:`Family` holds *both* directions of every bond: particle ``i``'s bonds are
``offsets[i]:offsets[i+1]`` and the bond i->j appears once in i's row and once (as j->i) in
j's row. Parallel kernels therefore loop over particles and each particle sums only its own
row: no two threads write the same particle.

Partial-volume factors (``volume_factor``, beta, per bond) correct the volume a neighbour
near the horizon edge contributes. Options of :func:`build_family`:

``None``
    beta = 1, bonds with ``|xi| <= horizon``.
``"lammps"``
    LAMMPS PERI (pair peri/*, fix PERI_NEIGH): bonds with ``|xi|^2 <= horizon^2``, and
    beta = ``(horizon + h/2 - |xi|) / h`` when ``| |xi| - horizon | <= h/2``, else 1, where
    ``h`` is the lattice constant (``lc``). A linear taper over one spacing centred on the
    horizon, of which LAMMPS keeps the inner half.
``"linear"``
    The same taper, but bonds up to ``|xi| < horizon + h/2`` are kept so the full taper is
    used (beta in (0, 1]).

Bond state: ``intact (nb,) bool``; damage ``mu = 1 - R/T`` per particle (seed 004
eq. 5.16: R remaining, T initial bonds), see :func:`damage`.
"""
from __future__ import annotations

import dataclasses
from functools import cached_property

import numba as nb
import numpy as np

from upscale.engine.system import ParticleSystem

__all__ = ["Family", "FamilyRecipe", "build_family", "build_family_rows", "candidate_counts",
           "damage", "bonds_crossing_segment", "index_type", "reference_vectors",
           "reference_lengths"]

PARTIAL_VOLUME = (None, "lammps", "linear")
# candidate bonds per block of rows in build_family: bounds its temporaries (about
# 150 bytes per candidate) independently of the system size
_BLOCK_BONDS = 2_000_000


@dataclasses.dataclass(eq=False)
class Family:
    """Pair family (neighbour list) in CSR form, both directions of every bond stored.

    Kept per directed bond: the partner index alone (4 bytes). The reference geometry of
    a bond is a function of ``x0`` and the two indices, so it is recomputed on demand
    rather than kept (a family of 480 M bonds would otherwise hold 23 GB of it):
    ``xi``, ``length``, ``volume_factor``, ``owner`` and ``reverse`` are computed at each
    access (new arrays, not cached), bit for bit as :func:`build_family` evaluated them.
    A kernel computes ``x0[j] - x0[i]`` and its length inline
    (:func:`~upscale.engine.kernels.bond_vector` on ``x0``); ``*_of(bonds)`` give them for
    a subset of bonds, and :meth:`bond_blocks` ranges of whole rows to sweep in blocks.

    Attributes
    ----------
    offsets : int64 (N+1,)
        Row pointers: particle i's bonds are ``offsets[i]:offsets[i+1]`` (64-bit, so a
        family may hold more than 2^31 bonds).
    neighbors : int32 (nb,)
        Neighbour index j of each directed bond i->j (int64 only when N >= 2^31).
    x0 : float64 (N, 3)
        Reference positions (the system's array, not a copy), m.
    horizon : float
        Horizon delta used to build the family.
    spacing : float
        Particle spacing h used for the check and the partial-volume factor.
    partial_volume : str or None
        Which partial-volume rule gives ``volume_factor``.
    beta : float64 (nb,) or None
        Partial-volume factors given explicitly (kept, 8 bytes per bond); None (the
        default): computed from the length by the ``partial_volume`` rule.
    partial_rows : bool (N,) or None
        Rows that may miss bonds (a part of a larger body: the outer halo of an MPI
        rank), whose per-particle quantities no force that is used depends on: a model's
        checks of every family (e.g. a shape tensor that must be invertible) skip them.
        None: every row is complete.
    """

    offsets: np.ndarray
    neighbors: np.ndarray
    x0: np.ndarray
    horizon: float
    spacing: float
    partial_volume: str | None = None
    beta: np.ndarray | None = None
    partial_rows: np.ndarray | None = None

    def __post_init__(self):
        self.offsets = np.ascontiguousarray(self.offsets, dtype=np.int64)
        self.neighbors = np.ascontiguousarray(self.neighbors, dtype=index_type(self.offsets.shape[0] - 1))
        self.x0 = np.ascontiguousarray(self.x0, dtype=np.float64)
        if self.x0.ndim != 2 or self.x0.shape != (self.offsets.shape[0] - 1, 3):
            raise ValueError(f"x0 must have shape ({self.offsets.shape[0] - 1}, 3), got {self.x0.shape}")
        if self.partial_volume not in PARTIAL_VOLUME:
            raise ValueError(f"unknown partial_volume {self.partial_volume!r}; valid: "
                             f"{', '.join(repr(p) for p in PARTIAL_VOLUME)}")
        if self.beta is not None:
            self.beta = np.ascontiguousarray(self.beta, dtype=np.float64)
            if self.beta.shape != self.neighbors.shape:
                raise ValueError(f"beta must have shape {self.neighbors.shape}, got {self.beta.shape}")

    @property
    def n(self) -> int:
        """Number of particles."""
        return self.offsets.shape[0] - 1

    @property
    def nb(self) -> int:
        """Number of directed bonds (twice the number of pairs)."""
        return self.neighbors.shape[0]

    @cached_property
    def counts(self) -> np.ndarray:
        """Bonds per particle (N,)."""
        return np.diff(self.offsets)

    @property
    def owner(self) -> np.ndarray:
        """Particle i of each directed bond i->j (nb,) int64 (a new array)."""
        return np.repeat(np.arange(self.n, dtype=np.int64), self.counts)

    @property
    def xi(self) -> np.ndarray:
        """Reference bond vectors ``x0[j] - x0[i]`` (nb, 3) (a new array)."""
        return reference_vectors(self.offsets, self.neighbors, self.x0)

    @property
    def length(self) -> np.ndarray:
        """Reference bond lengths ``|xi|`` (nb,) (a new array), evaluated as LAMMPS does
        (``sqrt(dx*dx + dy*dy + dz*dz)``)."""
        return reference_lengths(self.offsets, self.neighbors, self.x0)

    @property
    def volume_factor(self) -> np.ndarray:
        """Partial-volume factors beta (nb,) (a new array; see the module docstring)."""
        if self.beta is not None:
            return self.beta.copy()
        if self.partial_volume is None:
            return np.ones(self.nb)
        return _lammps_beta(self.length, self.horizon, self.spacing)

    def bond_blocks(self, size: int) -> list[tuple[int, int]]:
        """Ranges ``lo:hi`` of directed bonds covering the family, each of whole rows and
        about ``size`` bonds (a longer row is a block of its own): a per-particle sum over
        the blocks adds each particle's bonds in the order of one pass over all of them."""
        targets = np.arange(0, self.nb, max(int(size), 1))
        b = np.unique(np.concatenate([self.offsets[np.searchsorted(self.offsets, targets, side="left")],
                                      [self.nb]]))
        return [(int(lo), int(hi)) for lo, hi in zip(b[:-1], b[1:])]

    def owner_of(self, bonds) -> np.ndarray:
        """Particle i of each of the directed bonds ``bonds`` (k,) int64."""
        return np.searchsorted(self.offsets, np.asarray(bonds), side="right") - 1

    def xi_of(self, bonds) -> np.ndarray:
        """``x0[j] - x0[i]`` of the directed bonds ``bonds`` (k, 3) (the same numbers as
        ``xi[bonds]`` without the whole array)."""
        b = np.asarray(bonds)
        return self.x0[self.neighbors[b]] - self.x0[self.owner_of(b)]

    def length_of(self, bonds) -> np.ndarray:
        """``|xi|`` of the directed bonds ``bonds`` (k,), bit for bit ``length[bonds]``."""
        d = self.xi_of(bonds)
        return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])

    def volume_factor_of(self, bonds) -> np.ndarray:
        """beta of the directed bonds ``bonds`` (k,), bit for bit ``volume_factor[bonds]``."""
        b = np.asarray(bonds)
        if self.beta is not None:
            return self.beta[b]
        if self.partial_volume is None:
            return np.ones(b.shape[0])
        return _lammps_beta(self.length_of(b), self.horizon, self.spacing)

    @property
    def reverse(self) -> np.ndarray:
        """Index of the reverse bond j->i for each bond i->j (nb,) int64 (a new array).

        Rows sorted by neighbour (as :func:`build_family` makes them): bisection for i in row
        j, no memory beyond the result. Otherwise a sort of the keys i N + j (five (nb,)
        int64 temporaries)."""
        if rows_sorted(self.offsets, self.neighbors):
            rev = reverse_in_sorted_rows(self.offsets, self.neighbors, self.offsets, self.neighbors)
            if np.any(rev < 0):
                raise ValueError("family is not symmetric: some bond has no reverse")
            return rev
        i, j = self.owner, self.neighbors.astype(np.int64)
        key_fwd = i * self.n + j
        key_rev = j * self.n + i
        order = np.argsort(key_fwd, kind="stable")
        pos = np.minimum(np.searchsorted(key_fwd[order], key_rev), max(self.nb - 1, 0))
        rev = order[pos]
        if not np.array_equal(key_fwd[rev], key_rev):
            raise ValueError("family is not symmetric: some bond has no reverse")
        return rev

    def nbytes(self) -> int:
        """Bytes the family keeps: row pointers, partner indices and explicit factors
        (``x0`` is the system's)."""
        return int(self.offsets.nbytes + self.neighbors.nbytes
                   + (0 if self.beta is None else self.beta.nbytes))

    def all_intact(self) -> np.ndarray:
        """A fresh bond state with every bond intact (nb,) bool."""
        return np.ones(self.nb, dtype=bool)

    def remove_bonds(self, mask) -> "Family":
        """A new family without the bonds where ``mask`` (nb,) is True.

        Removal is symmetric (a bond and its reverse go together). Removed bonds do not count
        in the total T of the damage index nor in any weighted volume a model computes in
        ``prepare``: this is how LAMMPS sees a pre-crack made by not creating bonds. To model
        a pre-crack as bonds *broken* at t = 0 instead, set ``intact[mask] = False``.
        """
        m = np.asarray(mask, dtype=bool)
        if m.shape != (self.nb,):
            raise ValueError(f"bond mask must have shape ({self.nb},), got {m.shape}")
        m = m | m[self.reverse]
        keep = ~m
        counts = np.bincount(self.owner[keep], minlength=self.n).astype(np.int64)
        offsets = np.zeros(self.n + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        return Family(offsets, np.ascontiguousarray(self.neighbors[keep]), self.x0, self.horizon,
                      self.spacing, self.partial_volume,
                      None if self.beta is None else np.ascontiguousarray(self.beta[keep]))

    def pairs(self) -> np.ndarray:
        """Unique pairs (i < j) as an (nb/2, 2) int64 array."""
        i, j = self.owner, self.neighbors
        sel = i < j
        return np.stack([i[sel], j[sel].astype(np.int64)], axis=1)

    def __repr__(self) -> str:
        return (f"Family(n={self.n}, nb={self.nb}, horizon={self.horizon:.6g}, "
                f"bonds/particle={self.nb / max(self.n, 1):.2f}, "
                f"partial_volume={self.partial_volume!r})")


@dataclasses.dataclass(eq=False)
class FamilyRecipe:
    """A family described, not built: :func:`build_family`'s arguments, and the bonds
    that start broken (``broken(i, j, xi) -> (k,) bool`` on directed bonds, e.g. a
    pre-crack by :func:`bonds_crossing_segment`; None: all intact).

    Passed to :class:`~upscale.engine.simulation.Simulation` as its ``family``: on one
    process the simulation builds the whole family (:meth:`build`) and the initial bond
    state (:meth:`initial_intact`); on several MPI ranks each rank builds only the rows
    of its part (:func:`build_family_rows`), so no rank ever holds the whole family.
    """

    system: ParticleSystem
    horizon: float
    partial_volume: str | None = None
    spacing: float | None = None
    exclude: object = None
    broken: object = None

    def build(self) -> Family:
        """The whole family (:func:`build_family`)."""
        return build_family(self.system, self.horizon, partial_volume=self.partial_volume,
                            spacing=self.spacing, exclude=self.exclude)

    def rows(self, rows) -> tuple[np.ndarray, np.ndarray]:
        """``(counts, neighbors)`` of the particles ``rows`` (:func:`build_family_rows`)."""
        return build_family_rows(self.system, self.horizon, rows,
                                 partial_volume=self.partial_volume, spacing=self.spacing,
                                 exclude=self.exclude)

    def initial_intact(self, offsets, neighbors, gid=None) -> np.ndarray:
        """Bond state at the start (nb,) bool of the CSR rows ``offsets``/``neighbors``
        whose particle and partner indices are ``gid`` of the body's (default: the
        body's own)."""
        intact = np.ones(neighbors.shape[0], dtype=bool)
        if self.broken is None or neighbors.shape[0] == 0:
            return intact
        x = self.system.x0
        n = offsets.shape[0] - 1
        rows = np.arange(n, dtype=np.int64) if gid is None else np.asarray(gid, dtype=np.int64)
        for a, b in _row_blocks(offsets, _BLOCK_BONDS // 2):  # bounded temporaries
            lo, hi = offsets[a], offsets[b]
            i = np.repeat(rows[a:b], np.diff(offsets[a:b + 1]))
            j = rows[neighbors[lo:hi]]
            intact[lo:hi] = ~np.asarray(self.broken(i, j, x[j] - x[i]), dtype=bool)
        return intact


def _row_blocks(offsets, size: int) -> list[tuple[int, int]]:
    """Ranges ``a:b`` of rows of about ``size`` bonds each, covering all rows."""
    n = offsets.shape[0] - 1
    cuts = np.searchsorted(offsets, np.arange(0, int(offsets[-1]), max(int(size), 1)))
    b = np.unique(np.concatenate([[0], np.minimum(cuts, n), [n]]))
    return [(int(lo), int(hi)) for lo, hi in zip(b[:-1], b[1:])]


def index_type(n: int):
    """The partner-index type for ``n`` particles: int32, int64 from 2^31 particles on."""
    return np.int32 if n < 2 ** 31 else np.int64


@nb.njit(parallel=True, cache=True)
def reference_vectors(offsets, neighbors, x0_nc):
    """``x0[j] - x0[i]`` of every directed bond (nb, 3)."""
    n = offsets.shape[0] - 1
    xi = np.empty((neighbors.shape[0], 3))
    for i in nb.prange(n):
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            xi[b, 0] = x0_nc[j, 0] - x0_nc[i, 0]
            xi[b, 1] = x0_nc[j, 1] - x0_nc[i, 1]
            xi[b, 2] = x0_nc[j, 2] - x0_nc[i, 2]
    return xi


@nb.njit(parallel=True, cache=True)
def reference_lengths(offsets, neighbors, x0_nc):
    """``|x0[j] - x0[i]|`` of every directed bond (nb,), as ``sqrt(dx*dx + dy*dy + dz*dz)``."""
    n = offsets.shape[0] - 1
    L = np.empty(neighbors.shape[0])
    for i in nb.prange(n):
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            d0 = x0_nc[j, 0] - x0_nc[i, 0]
            d1 = x0_nc[j, 1] - x0_nc[i, 1]
            d2 = x0_nc[j, 2] - x0_nc[i, 2]
            L[b] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    return L


def _lammps_beta(length: np.ndarray, horizon: float, h: float) -> np.ndarray:
    """LAMMPS's linear edge taper, written exactly as pair_peri_*.cpp evaluates it."""
    half = 0.5 * h
    beta = np.ones_like(length)
    edge = np.abs(length - horizon) <= half
    beta[edge] = (-1.0 / (2 * half)) * length[edge] + (1.0 + ((horizon - half) / (2 * half)))
    return beta


@nb.njit(cache=True)
def rows_sorted(offsets, neighbors) -> bool:
    """True when every row ``offsets[i]:offsets[i+1]`` of ``neighbors`` is strictly
    increasing."""
    for i in range(offsets.shape[0] - 1):
        for k in range(offsets[i] + 1, offsets[i + 1]):
            if neighbors[k] <= neighbors[k - 1]:
                return False
    return True


@nb.njit(parallel=True, cache=True)
def reverse_in_sorted_rows(offsets, neighbors, row_n, j_p):
    """Directed index of j->i for every entry p of rows ``row_n`` (``j_p[p]`` = j, the row
    i the one holding p), by bisection for i in row j of the family ``(offsets,
    neighbors)``, whose rows must be sorted; -1 where row j does not hold i. With ``row_n =
    offsets`` and ``j_p = neighbors`` this is the family's whole reverse index."""
    n = row_n.shape[0] - 1
    rev = np.empty(j_p.shape[0], dtype=np.int64)
    for i in nb.prange(n):
        for p in range(row_n[i], row_n[i + 1]):
            j = j_p[p]
            lo = offsets[j]
            end = offsets[j + 1]
            hi = end
            while lo < hi:
                mid = (lo + hi) // 2
                if neighbors[mid] < i:
                    lo = mid + 1
                else:
                    hi = mid
            rev[p] = lo if (lo < end and neighbors[lo] == i) else -1
    return rev


def build_family(system: ParticleSystem, horizon: float, *, partial_volume: str | None = None,
                 spacing: float | None = None, exclude=None) -> Family:
    """Build the pair family of ``system`` within ``horizon`` (cKDTree).

    Rows are found block by block (a tree of each block of rows against the whole system)
    and written into one array allocated once, so the memory needed is the family's own
    (4 bytes per directed bond) plus one block's temporaries: about 1 GB at any size,
    instead of about 100 bytes per bond for a list of all pairs at once.

    Parameters
    ----------
    system : ParticleSystem
    horizon : float
        delta; must exceed the particle spacing.
    partial_volume : None, "lammps" or "linear"
        Edge correction (see module docstring).
    spacing : float, optional
        Spacing h for the check and the taper (default ``system.spacing``).
    exclude : callable, optional
        ``exclude(i, j, xi) -> bool (nb,)`` for candidate directed bonds; True drops the
        bond (both directions). E.g. a pre-crack: :func:`bonds_crossing_segment`.

    Raises
    ------
    ValueError
        horizon not finite/positive or not larger than the spacing; unknown partial-volume
        option.
    """
    from scipy.spatial import cKDTree

    delta, h, rmax, r_query = _radii(system, horizon, partial_volume, spacing)
    x = system.x0
    n = system.n
    tree = cKDTree(x)
    # capacity: every candidate within a slightly larger ball (self included), so the
    # output arrays are allocated once and rows are written block by block
    cap = int(tree.query_ball_point(x, r_query * (1.0 + 1e-9), return_length=True).sum()) - n
    neighbors = np.empty(cap, dtype=index_type(n))
    counts = np.zeros(n, dtype=np.int64)
    per_row = max(1.0, cap / max(n, 1))
    block = max(1, int(_BLOCK_BONDS // per_row))
    pos = 0
    for a in range(0, n, block):
        b = min(n, a + block)
        sdm = cKDTree(x[a:b]).sparse_distance_matrix(tree, r_query, output_type="ndarray")
        i = sdm["i"].astype(np.int64) + a
        j = sdm["j"].astype(np.int64)
        del sdm
        off = i != j
        i, j = _kept_sorted(x, i[off], j[off], rmax, delta, partial_volume, exclude)
        k = i.shape[0]
        neighbors[pos:pos + k] = j
        counts[a:b] = np.bincount(i - a, minlength=b - a)
        pos += k
    if pos < cap:                         # shrink in place (realloc): no second copy
        neighbors.resize((pos,), refcheck=False)
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return Family(offsets, neighbors, x, delta, h, partial_volume)


def _radii(system, horizon, partial_volume, spacing):
    """``(delta, h, rmax, r_query)`` of a family build, checked (see :func:`build_family`)."""
    if partial_volume not in PARTIAL_VOLUME:
        raise ValueError(f"unknown partial_volume {partial_volume!r}; valid: "
                         f"{', '.join(repr(p) for p in PARTIAL_VOLUME)}")
    delta = float(horizon)
    h = float(spacing) if spacing is not None else system.spacing
    if not (np.isfinite(delta) and delta > 0):
        raise ValueError(f"horizon must be positive, got {horizon!r}")
    if not delta > h:
        raise ValueError(f"horizon {delta:.6g} is not larger than the particle spacing {h:.6g}")
    rmax = delta + 0.5 * h if partial_volume == "linear" else delta
    return delta, h, rmax, rmax * (1.0 + 1e-9) + 1e-300


def _kept_sorted(x, i, j, rmax, delta, partial_volume, exclude):
    """The candidate bonds ``i -> j`` (no self pairs) that are bonds, sorted by (i, j)."""
    # reference vectors and lengths evaluated as LAMMPS does (dx*dx + dy*dy + dz*dz)
    d = x[j] - x[i]
    rsq = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
    keep = np.sqrt(rsq) < rmax if partial_volume == "linear" else rsq <= delta * delta
    if exclude is not None:
        # symmetric whatever the callable did (a bond through a segment's end point can
        # test differently from its two ends): both directions of each candidate
        ex = np.asarray(exclude(i, j, d), dtype=bool)
        if ex.shape != i.shape:
            raise ValueError(f"exclude returned shape {ex.shape}, expected {i.shape}")
        ex_back = np.asarray(exclude(j, i, -d), dtype=bool)
        keep &= ~(ex | ex_back)
    i, j = i[keep], j[keep]
    order = np.lexsort((j, i))
    return i[order], j[order]


def build_family_rows(system: ParticleSystem, horizon: float, rows, *,
                      partial_volume: str | None = None, spacing: float | None = None,
                      exclude=None) -> tuple[np.ndarray, np.ndarray]:
    """The rows of the particles ``rows`` of the family :func:`build_family` builds with
    the same arguments, without the others: ``(counts, neighbors)``, bonds per row (k,)
    int64 and the partners' global indices, row after row (the same partners in the same
    order as those rows of the whole family: the same candidates and the same test).

    Memory: the rows themselves plus one block's temporaries; the candidates are the
    particles within the rows' bounding box grown by the horizon (a part of the body
    builds its own rows without the family of the whole). ``rows`` (k,) sorted, unique.
    """
    from scipy.spatial import cKDTree

    delta, h, rmax, r_query = _radii(system, horizon, partial_volume, spacing)
    x = system.x0
    rows = np.asarray(rows, dtype=np.int64)
    if rows.size and np.any(np.diff(rows) <= 0):
        raise ValueError("rows must be sorted and unique")
    counts = np.zeros(rows.shape[0], dtype=np.int64)
    if rows.size == 0:
        return counts, np.empty(0, dtype=index_type(system.n))
    pad = 1.01 * r_query
    xr = x[rows]
    box = np.all((x >= xr.min(axis=0) - pad) & (x <= xr.max(axis=0) + pad), axis=1)
    cand = np.flatnonzero(box)
    del box
    tree = cKDTree(x[cand])
    per_row = max(1.0, float(tree.query_ball_point(xr[: min(rows.shape[0], 1000)], r_query,
                                                   return_length=True).mean()))
    block = max(1, int(_BLOCK_BONDS // 4 // per_row))  # a quarter: a part's rows are few
    parts = []
    for a in range(0, rows.shape[0], block):
        b = min(rows.shape[0], a + block)
        sdm = cKDTree(xr[a:b]).sparse_distance_matrix(tree, r_query, output_type="ndarray")
        i = rows[sdm["i"].astype(np.int64) + a]
        j = cand[sdm["j"]]
        del sdm
        off = i != j
        i, j = _kept_sorted(x, i[off], j[off], rmax, delta, partial_volume, exclude)
        parts.append(j.astype(index_type(system.n)))
        counts[a:b] = np.bincount(np.searchsorted(rows[a:b], i), minlength=b - a)
    return counts, (np.concatenate(parts) if len(parts) > 1 else parts[0])


def candidate_counts(system: ParticleSystem, horizon: float, *,
                     partial_volume: str | None = None, spacing: float | None = None,
                     rows=None) -> np.ndarray:
    """Particles within the horizon of each particle of ``rows`` (default all) (k,)
    int64, itself excluded: the family's row lengths before an ``exclude`` (an estimate of
    each row's work that needs no family). The tree holds the particles within the rows'
    bounding box grown by the horizon only."""
    from scipy.spatial import cKDTree

    _, _, rmax, r_query = _radii(system, horizon, partial_volume, spacing)
    x = system.x0
    xr = x if rows is None else x[np.asarray(rows, dtype=np.int64)]
    if xr.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    pad = 1.01 * r_query
    cand = np.all((x >= xr.min(axis=0) - pad) & (x <= xr.max(axis=0) + pad), axis=1)
    tree = cKDTree(x[cand] if rows is not None else x)
    del cand
    return tree.query_ball_point(xr, rmax, return_length=True).astype(np.int64) - 1


def damage(family: Family, intact: np.ndarray, *, weights: str = "count",
           volume: np.ndarray | None = None) -> np.ndarray:
    """Damage index per particle, ``mu = 1 - R/T`` (seed 004 eq. 5.16).

    ``weights="count"`` counts bonds (R remaining, T in the family); ``"volume"`` weighs
    each bond by the neighbour volume ``volume[j]`` (LAMMPS ``compute damage/atom``).
    Particles without bonds get 0.
    """
    from upscale.engine.kernels import damage_kernel

    if weights not in ("count", "volume"):
        raise ValueError(f"unknown damage weights {weights!r}; valid: 'count', 'volume'")
    w = np.ones(family.n) if weights == "count" else np.asarray(volume, dtype=np.float64)
    return damage_kernel(family.offsets, family.neighbors, np.asarray(intact, dtype=np.bool_), w)


def bonds_crossing_segment(x0: np.ndarray, a, b):
    """An ``exclude`` callable dropping bonds whose segment crosses the segment a-b.

    The test is done in the x-y plane (a through-thickness crack in 3D, a line crack in 2D).
    Use as ``build_family(system, delta, exclude=bonds_crossing_segment(system.x0, a, b))``
    or on an existing family: ``fam.remove_bonds(bonds_crossing_segment(x0, a, b)(
    fam.owner, fam.neighbors, fam.xi))``.
    """
    a = np.asarray(a, dtype=np.float64)[:2]
    b = np.asarray(b, dtype=np.float64)[:2]

    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    def exclude(i, j, xi):
        p = x0[i, :2]
        r = xi[:, :2]
        s = b - a
        denom = cross(r, s)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = cross(a - p, s) / denom
            u = cross(a - p, r) / denom
        return (denom != 0) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)

    return exclude
