"""Generic numba kernels of the engine (pure functions of flat arrays).

Suffixes: ``_n`` per particle, ``_b`` per directed bond, ``_c`` Cartesian component.
Every parallel loop runs over particles and writes only that particle's entries (its
output row or its own CSR row of bonds), so there are no races.
"""
from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["damage_kernel", "bond_stretch", "break_by_stretch", "set_threads"]


def set_threads(n: int | None) -> int:
    """Set numba's thread count (None: leave as is); return the count in use."""
    if n is not None:
        nb.set_num_threads(max(1, min(int(n), nb.config.NUMBA_NUM_THREADS)))
    return nb.get_num_threads()


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
        yi0, yi1, yi2 = y_nc[i, 0], y_nc[i, 1], y_nc[i, 2]
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            d0 = yi0 - y_nc[j, 0]
            d1 = yi1 - y_nc[j, 1]
            d2 = yi2 - y_nc[j, 2]
            r = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            s[b] = (r - length_b[b]) / length_b[b]
    return s


@nb.njit(parallel=True, cache=True)
def break_by_stretch(offsets, neighbors, length_b, y_nc, intact_b, s0_n):
    """Mutates ``intact_b``: break bonds with stretch > min(s0_i, s0_j). Returns count."""
    n = offsets.shape[0] - 1
    cnt = np.zeros(n, dtype=np.int64)
    for i in nb.prange(n):
        yi0, yi1, yi2 = y_nc[i, 0], y_nc[i, 1], y_nc[i, 2]
        c = 0
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            j = neighbors[b]
            d0 = yi0 - y_nc[j, 0]
            d1 = yi1 - y_nc[j, 1]
            d2 = yi2 - y_nc[j, 2]
            r = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            dr = r - length_b[b]
            if abs(dr) < 2.2204e-16:
                dr = 0.0
            s = dr / length_b[b]
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
