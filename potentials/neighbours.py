"""Neighbour lists with a skin and an explicit rebuild rule, as CSR arrays for numba kernels.

Periodic boundaries in any subset of the three cell directions are supported, including the
rank-deficient cells of ``ase.build.nanotube`` (zero-length cell vectors along the
non-periodic directions): only the periodic cell vectors are used, the basis is completed
with unit vectors orthogonal to them.

Method: atoms are wrapped into the cell along periodic directions, periodic images ("ghosts")
within the cutoff of the cell faces are added (a point within distance ``r`` of the cell has
fractional coordinate ``s_d`` within ``r |b_d|`` of ``[0, 1)``, ``b_d`` the reciprocal vector),
and all points are binned into a Cartesian cell list of bin size >= cutoff. Both search passes
(count, fill) run in parallel over atoms and write only each atom's own row.

Array suffixes: ``_n`` per atom, ``_b`` per bond (a CSR entry i -> j), ``_c`` Cartesian
component. A bond ``b`` of atom ``i`` (``first_n[i] <= b < first_n[i + 1]``) points to atom
``j_b[b]`` in the periodic image ``shift_bc[b]`` (integers), and its vector is

    r_ij = positions[j] - positions[i] + shift_bc[b] @ cell

with the positions as they were handed to :meth:`NeighbourList.update` (not wrapped).
An atom can be its own neighbour (``j == i`` with a non-zero shift) in a small periodic cell.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

__all__ = ["NeighbourList", "neighbour_list", "complete_cell", "bond_vectors",
           "min_bond_distance"]

# the smallest cell-vector length (Angstrom) treated as non-zero along a periodic direction
_ZERO_LENGTH = 1e-10


def complete_cell(cell, pbc) -> np.ndarray:
    """The cell with every non-periodic vector replaced by a unit vector orthogonal to the
    periodic ones (and to each other), so the 3x3 matrix is invertible.

    Parameters
    ----------
    cell : (3, 3) array, rows are the cell vectors (Angstrom)
    pbc : (3,) bool

    Raises
    ------
    ValueError
        When a periodic cell vector has zero length or the periodic vectors are linearly
        dependent.
    """
    cell = np.asarray(cell, dtype=float).reshape(3, 3)
    pbc = np.asarray(pbc, dtype=bool).reshape(3)
    periodic = [d for d in range(3) if pbc[d]]
    for d in periodic:
        if np.linalg.norm(cell[d]) < _ZERO_LENGTH:
            raise ValueError(
                f"cell vector {d} has zero length but the system is periodic along it; "
                f"give the cell a length there or set pbc[{d}] = False")
    out = np.zeros((3, 3))
    for d in periodic:
        out[d] = cell[d]
    if periodic:
        _, sv, vt = np.linalg.svd(cell[periodic])  # vt is 3x3: rows past the rank span
        if sv[-1] < 1e-8 * sv[0]:                  # the orthogonal complement
            raise ValueError(f"the periodic cell vectors {periodic} are linearly dependent")
        complement = vt[len(periodic):]
    else:
        complement = np.eye(3)
    k = 0
    for d in range(3):
        if not pbc[d]:
            out[d] = complement[k]
            k += 1
    if np.linalg.det(out) < 0:  # keep a right-handed completed basis (cosmetic)
        for d in range(3):
            if not pbc[d]:
                out[d] = -out[d]
                break
    return out


@njit(cache=True)
def _ghost_pass(s_nc, pbc, margin_c, nimg_c, write, src, img):
    """Count (``write`` False) or store the images of wrapped fractional coordinates that
    lie within ``margin_c`` of the unit cell along periodic directions."""
    g = 0
    for a in range(-nimg_c[0], nimg_c[0] + 1):
        for b in range(-nimg_c[1], nimg_c[1] + 1):
            for c in range(-nimg_c[2], nimg_c[2] + 1):
                if a == 0 and b == 0 and c == 0:
                    continue
                for i in range(s_nc.shape[0]):
                    t0 = s_nc[i, 0] + a
                    t1 = s_nc[i, 1] + b
                    t2 = s_nc[i, 2] + c
                    if pbc[0] and (t0 < -margin_c[0] or t0 >= 1.0 + margin_c[0]):
                        continue
                    if pbc[1] and (t1 < -margin_c[1] or t1 >= 1.0 + margin_c[1]):
                        continue
                    if pbc[2] and (t2 < -margin_c[2] or t2 >= 1.0 + margin_c[2]):
                        continue
                    if write:
                        src[g] = i
                        img[g, 0] = a
                        img[g, 1] = b
                        img[g, 2] = c
                    g += 1
    return g


@njit(cache=True)
def _make_ghosts(s_nc, pbc, margin_c, nimg_c):
    """Source atom and integer image of every ghost point."""
    src = np.empty(0, np.int64)
    img = np.empty((0, 3), np.int64)
    count = _ghost_pass(s_nc, pbc, margin_c, nimg_c, False, src, img)
    src = np.empty(count, np.int64)
    img = np.empty((count, 3), np.int64)
    _ghost_pass(s_nc, pbc, margin_c, nimg_c, True, src, img)
    return src, img


@njit(cache=True)
def _bin_points(x_pc, lo_c, inv_bin_c, nbin_c):
    """Counting sort of points into a Cartesian grid; returns (bin start, sorted point ids)."""
    npts = x_pc.shape[0]
    nb = nbin_c[0] * nbin_c[1] * nbin_c[2]
    bin_p = np.empty(npts, np.int64)
    start = np.zeros(nb + 1, np.int64)
    for p in range(npts):
        b0 = min(max(int((x_pc[p, 0] - lo_c[0]) * inv_bin_c[0]), 0), nbin_c[0] - 1)
        b1 = min(max(int((x_pc[p, 1] - lo_c[1]) * inv_bin_c[1]), 0), nbin_c[1] - 1)
        b2 = min(max(int((x_pc[p, 2] - lo_c[2]) * inv_bin_c[2]), 0), nbin_c[2] - 1)
        b = (b0 * nbin_c[1] + b1) * nbin_c[2] + b2
        bin_p[p] = b
        start[b + 1] += 1
    for b in range(nb):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    order = np.empty(npts, np.int64)
    for p in range(npts):
        b = bin_p[p]
        order[fill[b]] = p
        fill[b] += 1
    return start, order


@njit(cache=True, inline="always")
def _row(i, x_pc, src_p, img_pc, wrap_nc, lo_c, inv_bin_c, nbin_c, start, order, rc2, half,
         write, c, j_b, shift_bc):
    """Visit the points within sqrt(rc2) of atom i; with ``write`` store them from CSR
    position ``c`` on. Returns the position after the last one."""
    xi0 = x_pc[i, 0]
    xi1 = x_pc[i, 1]
    xi2 = x_pc[i, 2]
    b0 = min(max(int((xi0 - lo_c[0]) * inv_bin_c[0]), 0), nbin_c[0] - 1)
    b1 = min(max(int((xi1 - lo_c[1]) * inv_bin_c[1]), 0), nbin_c[1] - 1)
    b2 = min(max(int((xi2 - lo_c[2]) * inv_bin_c[2]), 0), nbin_c[2] - 1)
    for a0 in range(max(b0 - 1, 0), min(b0 + 2, nbin_c[0])):
        for a1 in range(max(b1 - 1, 0), min(b1 + 2, nbin_c[1])):
            for a2 in range(max(b2 - 1, 0), min(b2 + 2, nbin_c[2])):
                b = (a0 * nbin_c[1] + a1) * nbin_c[2] + a2
                for q in range(start[b], start[b + 1]):
                    p = order[q]
                    if p == i:
                        continue
                    d0 = x_pc[p, 0] - xi0
                    d1 = x_pc[p, 1] - xi1
                    d2 = x_pc[p, 2] - xi2
                    if d0 * d0 + d1 * d1 + d2 * d2 >= rc2:
                        continue
                    j = src_p[p]
                    if half and not _keep_half(i, j, img_pc, p):
                        continue
                    if write:
                        j_b[c] = j
                        # image relative to the unwrapped input positions
                        shift_bc[c, 0] = img_pc[p, 0] - wrap_nc[j, 0] + wrap_nc[i, 0]
                        shift_bc[c, 1] = img_pc[p, 1] - wrap_nc[j, 1] + wrap_nc[i, 1]
                        shift_bc[c, 2] = img_pc[p, 2] - wrap_nc[j, 2] + wrap_nc[i, 2]
                    c += 1
    return c


@njit(parallel=True, cache=True)
def _search(x_pc, n_real, src_p, img_pc, wrap_nc, lo_c, inv_bin_c, nbin_c, start, order,
            rc2, half):
    """Two-pass CSR construction of all pairs within sqrt(rc2); rows are real atoms."""
    j_b = np.empty(0, np.int32)
    shift_bc = np.empty((0, 3), np.int32)
    count_n = np.zeros(n_real, np.int64)
    for i in prange(n_real):
        count_n[i] = _row(i, x_pc, src_p, img_pc, wrap_nc, lo_c, inv_bin_c, nbin_c, start,
                          order, rc2, half, False, 0, j_b, shift_bc)
    first_n = np.zeros(n_real + 1, np.int64)
    for i in range(n_real):
        first_n[i + 1] = first_n[i] + count_n[i]
    j_b = np.empty(first_n[n_real], np.int32)
    shift_bc = np.empty((first_n[n_real], 3), np.int32)
    for i in prange(n_real):
        _row(i, x_pc, src_p, img_pc, wrap_nc, lo_c, inv_bin_c, nbin_c, start, order, rc2,
             half, True, first_n[i], j_b, shift_bc)
        _sort_row(first_n[i], first_n[i + 1], j_b, shift_bc)
    return first_n, j_b, shift_bc


@njit(cache=True)
def _sort_row(a, b, j_b, shift_bc):
    """Order one row by (neighbour, image): the list, and so every sum over it, is then the
    same whenever and wherever it was built (the bins depend on the box at the build), which
    keeps a run resumed from a checkpoint bit-identical. Insertion sort: rows are short."""
    for c in range(a + 1, b):
        j = j_b[c]
        s0, s1, s2 = shift_bc[c, 0], shift_bc[c, 1], shift_bc[c, 2]
        d = c - 1
        while d >= a and (j_b[d] > j or (j_b[d] == j and (
                shift_bc[d, 0], shift_bc[d, 1], shift_bc[d, 2]) > (s0, s1, s2))):
            j_b[d + 1] = j_b[d]
            shift_bc[d + 1, 0] = shift_bc[d, 0]
            shift_bc[d + 1, 1] = shift_bc[d, 1]
            shift_bc[d + 1, 2] = shift_bc[d, 2]
            d -= 1
        j_b[d + 1] = j
        shift_bc[d + 1, 0], shift_bc[d + 1, 1], shift_bc[d + 1, 2] = s0, s1, s2


@njit(cache=True)
def _keep_half(i, j, img_pc, p):
    """Half-list rule: keep i -> j if i < j, or i == j with a lexicographically positive
    image (each unordered pair once). Images are relative to wrapped positions here, which
    is consistent for both directions of a pair."""
    if i < j:
        return True
    if i > j:
        return False
    if img_pc[p, 0] != 0:
        return img_pc[p, 0] > 0
    if img_pc[p, 1] != 0:
        return img_pc[p, 1] > 0
    return img_pc[p, 2] > 0


@njit(parallel=True, cache=True)
def bond_vectors(positions, cell, first_n, j_b, shift_bc):
    """Bond vectors ``r_ij`` (Angstrom), shape (M, 3), of a CSR neighbour list."""
    n = first_n.shape[0] - 1
    r_bc = np.empty((j_b.shape[0], 3))
    for i in prange(n):
        for b in range(first_n[i], first_n[i + 1]):
            j = j_b[b]
            s0 = shift_bc[b, 0]
            s1 = shift_bc[b, 1]
            s2 = shift_bc[b, 2]
            for c in range(3):
                r_bc[b, c] = (positions[j, c] - positions[i, c]
                              + s0 * cell[0, c] + s1 * cell[1, c] + s2 * cell[2, c])
    return r_bc


@njit(cache=True)
def min_bond_distance(positions, cell, first_n, j_b, shift_bc):
    """(smallest bond length, i, j) over a CSR list; (inf, -1, -1) when it is empty."""
    n = first_n.shape[0] - 1
    best = np.inf
    bi = -1
    bj = -1
    for i in range(n):
        for b in range(first_n[i], first_n[i + 1]):
            j = j_b[b]
            d2 = 0.0
            for c in range(3):
                d = (positions[j, c] - positions[i, c] + shift_bc[b, 0] * cell[0, c]
                     + shift_bc[b, 1] * cell[1, c] + shift_bc[b, 2] * cell[2, c])
                d2 += d * d
            if d2 < best:
                best = d2
                bi = i
                bj = j
    return np.sqrt(best), bi, bj


def neighbour_list(positions, cell, pbc, cutoff: float, half: bool = False):
    """All pairs closer than ``cutoff`` (Angstrom), as CSR arrays.

    Parameters
    ----------
    positions : (N, 3) float, Angstrom
    cell : (3, 3) float, rows are cell vectors; only periodic rows are used
    pbc : (3,) bool
    cutoff : float
    half : bool
        If True each unordered pair appears once (``i < j``); otherwise both ``i -> j`` and
        ``j -> i`` (a full list, what many-body potentials need).

    Returns
    -------
    first_n : (N + 1,) int64, row offsets
    j_b : (M,) int32, neighbour index
    shift_bc : (M, 3) int32, image, ``r_ij = x_j - x_i + shift @ cell``
    """
    x = np.ascontiguousarray(positions, dtype=float)
    n = len(x)
    pbc = np.asarray(pbc, dtype=bool).reshape(3)
    cell = np.asarray(cell, dtype=float).reshape(3, 3)
    if not np.all(np.isfinite(x)):
        bad = int(np.nonzero(~np.all(np.isfinite(x), axis=1))[0][0])
        raise ValueError(f"atom {bad} has a non-finite position {x[bad].tolist()}")
    if cutoff <= 0:
        raise ValueError(f"cutoff must be positive, got {cutoff}")
    if n == 0:
        return np.zeros(1, np.int64), np.zeros(0, np.int32), np.zeros((0, 3), np.int32)
    full = complete_cell(cell, pbc)
    inv = np.linalg.inv(full)
    s = x @ inv
    wrap = np.zeros((n, 3), np.int64)
    wrap[:, pbc] = np.floor(s[:, pbc]).astype(np.int64)
    s_w = s - wrap
    # guard against s_w == 1.0 by rounding
    for d in range(3):
        if pbc[d]:
            over = s_w[:, d] >= 1.0
            if np.any(over):
                s_w[over, d] -= 1.0
                wrap[over, d] += 1
    xw = x - wrap @ full
    recip_len = np.linalg.norm(inv, axis=0)  # |b_d|, s_d = x . inv[:, d]
    margin = np.where(pbc, cutoff * recip_len, 0.0)
    nimg = np.where(pbc, np.ceil(margin).astype(np.int64), 0).astype(np.int64)
    src_g, img_g = _make_ghosts(s_w, pbc, margin, nimg)
    x_all = np.concatenate([xw, xw[src_g] + img_g @ full]) if len(src_g) else xw
    src_all = np.concatenate([np.arange(n, dtype=np.int64), src_g])
    img_all = np.concatenate([np.zeros((n, 3), np.int64), img_g])
    lo = x_all.min(axis=0)
    hi = x_all.max(axis=0)
    ext = np.maximum(hi - lo, 0.0)
    nbin = np.maximum(np.floor(ext / cutoff).astype(np.int64), 1)
    # cap the grid at a few bins per point (sparse systems in a large box)
    while np.prod(nbin) > 4 * len(x_all) + 27:
        nbin = np.maximum(nbin // 2, 1)
    binw = np.where(ext > 0, ext / nbin, 1.0)
    binw = np.maximum(binw, cutoff)  # never smaller than the cutoff
    inv_bin = 1.0 / binw
    start, order = _bin_points(x_all, lo, inv_bin, nbin)
    return _search(x_all, n, src_all, img_all, wrap, lo, inv_bin, nbin, start, order,
                   float(cutoff) ** 2, bool(half))


class NeighbourList:
    """A neighbour list with a skin and an explicit rebuild rule.

    The list holds every pair closer than ``cutoff + skin``. :meth:`update` rebuilds it when
    the number of atoms, the cell or ``pbc`` changed, or when any atom moved more than
    ``skin / 2`` since the last build (then no pair can have come within ``cutoff`` unseen).
    Kernels must still test ``r < cutoff`` themselves.

    Parameters
    ----------
    cutoff : float
        Interaction cutoff, Angstrom.
    skin : float
        Extra distance, Angstrom (default 0.3).
    half : bool
        Each pair once (``i < j``) instead of a full list.

    Attributes
    ----------
    first_n, j_b, shift_bc
        CSR arrays, see :func:`neighbour_list`.
    nbuilds : int
        How many times the list was built (for tests and diagnostics).
    displacement : float
        Largest displacement of an atom since the last build, Angstrom, as of the last
        :meth:`update` (see there).
    """

    def __init__(self, cutoff: float, skin: float = 0.3, half: bool = False):
        if cutoff <= 0 or skin < 0:
            raise ValueError(f"need cutoff > 0 and skin >= 0, got {cutoff}, {skin}")
        self.cutoff = float(cutoff)
        self.skin = float(skin)
        self.half = bool(half)
        self.nbuilds = 0
        self._x0 = None
        self._cell = None
        self._pbc = None
        self.first_n = self.j_b = self.shift_bc = None
        self.displacement = 0.0

    def _rebuild_test(self, positions, cell, pbc):
        """(stale, largest squared displacement since the build or None if not measured)."""
        if self._x0 is None or len(positions) != len(self._x0):
            return True, None
        if not np.array_equal(np.asarray(pbc, bool).reshape(3), self._pbc):
            return True, None
        if not np.array_equal(np.asarray(cell, float).reshape(3, 3), self._cell):
            return True, None
        if len(positions) == 0:
            return False, 0.0
        d2 = _max_disp2(np.ascontiguousarray(positions, dtype=float), self._x0)
        return d2 > (0.5 * self.skin) ** 2, d2

    def needs_rebuild(self, positions, cell, pbc) -> bool:
        """True when the rebuild rule says the list is stale (see class docstring)."""
        return self._rebuild_test(positions, cell, pbc)[0]

    def update(self, positions, cell, pbc) -> bool:
        """Rebuild if needed; returns True if the list was rebuilt.

        Afterwards :attr:`displacement` is the largest distance (Angstrom) an atom of
        ``positions`` lies from where it was at the last build (0.0 right after a build);
        every pair of the list is then at most ``2 * displacement`` shorter than it was at
        the build, which lets callers bound the shortest distance without a pass over the
        list.
        """
        stale, d2 = self._rebuild_test(positions, cell, pbc)
        if not stale:
            self.displacement = float(np.sqrt(d2))
            return False
        self.build(positions, cell, pbc)
        return True

    def build(self, positions, cell, pbc) -> None:
        """Build unconditionally."""
        x = np.array(positions, dtype=float, copy=True)
        self.first_n, self.j_b, self.shift_bc = neighbour_list(
            x, cell, pbc, self.cutoff + self.skin, half=self.half)
        self._x0 = x
        self._cell = np.array(cell, dtype=float).reshape(3, 3)
        self._pbc = np.array(pbc, dtype=bool).reshape(3)
        self.nbuilds += 1
        self.displacement = 0.0

    def bond_vectors(self, positions) -> np.ndarray:
        """(M, 3) bond vectors ``r_ij`` of the current positions (Angstrom)."""
        return bond_vectors(np.ascontiguousarray(positions, dtype=float), self._cell,
                            self.first_n, self.j_b, self.shift_bc)

    def pairs(self):
        """(i_b, j_b, shift_bc): the list as flat pair arrays (i repeated per row)."""
        n = len(self.first_n) - 1
        i_b = np.repeat(np.arange(n, dtype=np.int32), np.diff(self.first_n))
        return i_b, self.j_b, self.shift_bc

    @property
    def n_bonds(self) -> int:
        return 0 if self.j_b is None else len(self.j_b)


@njit(cache=True)
def _max_disp2(x, x0):
    m = 0.0
    for i in range(x.shape[0]):
        d = 0.0
        for c in range(3):
            t = x[i, c] - x0[i, c]
            d += t * t
        if d > m:
            m = d
    return m
