"""Generic numba kernels of the engine (pure functions of flat arrays).

Suffixes: ``_n`` per particle, ``_b`` per directed bond, ``_c`` Cartesian component.
Every parallel loop runs over particles and writes only that particle's entries (its
output row or its own CSR row of bonds), so there are no races.

The small ``inline="always"`` helpers (:func:`bond_vector_sq`, :func:`bond_vector`,
:func:`bond_length`, :func:`bond_extension`, :func:`add_to_row`) hold the pieces the model kernels share: the
current bond vector ``y_j - y_i`` of bond i->j, its length and its extension, and the
addition of a particle's accumulated force to its output row. numba's cache of a
calling kernel in another module does not notice an edit of these helpers: clear the
``__pycache__`` numba files (``*.nbi``/``*.nbc``) after changing them.
"""
from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["damage_kernel", "bond_stretch", "break_by_stretch", "set_threads", "bond_vector",
           "bond_vector_sq", "bond_length", "bond_extension", "add_to_row"]

#: |r - L| below this is taken as zero extension (LAMMPS peri's NEAR_ZERO, m).
NEAR_ZERO = 2.2204e-16


def set_threads(n: int | None) -> int:
    """Set numba's thread count (None: leave as is); return the count in use."""
    if n is not None:
        nb.set_num_threads(max(1, min(int(n), nb.config.NUMBA_NUM_THREADS)))
    return nb.get_num_threads()


@nb.njit(inline="always", cache=True)
def bond_vector_sq(y_nc, i, j):
    """Current bond vector ``y_j - y_i`` (three components) and its squared length."""
    d0 = y_nc[j, 0] - y_nc[i, 0]
    d1 = y_nc[j, 1] - y_nc[i, 1]
    d2 = y_nc[j, 2] - y_nc[i, 2]
    return d0, d1, d2, d0 * d0 + d1 * d1 + d2 * d2


@nb.njit(inline="always", cache=True)
def bond_vector(y_nc, i, j):
    """Current bond vector ``y_j - y_i`` (three components) and its length r = |y_j - y_i|."""
    d0, d1, d2, rsq = bond_vector_sq(y_nc, i, j)
    return d0, d1, d2, np.sqrt(rsq)


@nb.njit(inline="always", cache=True)
def bond_length(y_nc, i, j):
    """Current bond length r = |y_j - y_i|."""
    return np.sqrt(bond_vector_sq(y_nc, i, j)[3])


@nb.njit(inline="always", cache=True)
def bond_extension(r, length):
    """Extension e = r - |xi|, set to 0 when |e| < NEAR_ZERO (as LAMMPS peri does)."""
    e = r - length
    if abs(e) < NEAR_ZERO:
        e = 0.0
    return e


@nb.njit(inline="always", cache=True)
def add_to_row(out_nc, i, f0, f1, f2):
    """Mutates ``out_nc``: row i += (f0, f1, f2)."""
    out_nc[i, 0] += f0
    out_nc[i, 1] += f1
    out_nc[i, 2] += f2


@nb.njit(parallel=True, cache=True)
def damage_kernel(offsets, neighbors, intact_b, weight_n):
    """mu_i = 1 - sum_{intact} w_j / sum_{all} w_j (0 for particles without bonds)."""
    n = offsets.shape[0] - 1
    mu = np.zeros(n)
    for i in nb.prange(n):
        tot = 0.0
        rem = 0.0
        for b in range(offsets[i], offsets[i + 1]):
            w = weight_n[neighbors[b]]
            tot += w
            if intact_b[b]:
                rem += w
        if tot != 0.0:
            mu[i] = 1.0 - rem / tot
    return mu


@nb.njit(parallel=True, cache=True)
def bond_stretch(offsets, neighbors, length_b, y_nc):
    """Stretch s = (|y_j - y_i| - |xi|) / |xi| of every directed bond (nb,)."""
    n = offsets.shape[0] - 1
    s = np.empty(neighbors.shape[0])
    for i in nb.prange(n):
        for b in range(offsets[i], offsets[i + 1]):
            r = bond_length(y_nc, i, neighbors[b])
            s[b] = (r - length_b[b]) / length_b[b]
    return s


@nb.njit(parallel=True, cache=True)
def break_by_stretch(offsets, neighbors, length_b, y_nc, intact_b, s0_n):
    """Mutates ``intact_b``: break bonds with stretch > min(s0_i, s0_j). Returns count."""
    n = offsets.shape[0] - 1
    cnt = np.zeros(n, dtype=np.int64)
    for i in nb.prange(n):
        c = 0
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            j = neighbors[b]
            s = bond_extension(bond_length(y_nc, i, j), length_b[b]) / length_b[b]
            if s > min(s0_n[i], s0_n[j]):
                intact_b[b] = False
                c += 1
        cnt[i] = c
    return cnt.sum()


@nb.njit(cache=True)
def kick(v_nc, F_nc, inv_m_n, h):
    """Mutates ``v_nc``: v += h F / m."""
    for i in range(v_nc.shape[0]):
        s = h * inv_m_n[i]
        v_nc[i, 0] += s * F_nc[i, 0]
        v_nc[i, 1] += s * F_nc[i, 1]
        v_nc[i, 2] += s * F_nc[i, 2]


@nb.njit(cache=True)
def drift(y_nc, v_nc, dt):
    """Mutates ``y_nc``: y += dt v."""
    for i in range(y_nc.shape[0]):
        y_nc[i, 0] += dt * v_nc[i, 0]
        y_nc[i, 1] += dt * v_nc[i, 1]
        y_nc[i, 2] += dt * v_nc[i, 2]


@nb.njit(cache=True)
def health(y_nc, v_nc, m_n):
    """(kinetic energy, index of the fastest particle, its speed^2, all finite)."""
    ke = 0.0
    vmax2 = 0.0
    imax = 0
    finite = True
    for i in range(y_nc.shape[0]):
        v2 = v_nc[i, 0] * v_nc[i, 0] + v_nc[i, 1] * v_nc[i, 1] + v_nc[i, 2] * v_nc[i, 2]
        ke += m_n[i] * v2
        if v2 > vmax2:
            vmax2 = v2
            imax = i
        if not (np.isfinite(v2) and np.isfinite(y_nc[i, 0]) and np.isfinite(y_nc[i, 1])
                and np.isfinite(y_nc[i, 2])):
            finite = False
    return 0.5 * ke, imax, vmax2, finite
