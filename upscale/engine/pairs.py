"""Half-pair lists: each unordered pair {i, j} of a symmetric family stored once.

A pair force that is equal and opposite on its two ends (``F_i += g``, ``F_j -= g``; bond
models, correspondence in its pair form) costs half the work on a half-pair list: the
pair's terms are read and computed once instead of once per directed bond. The scatter to
both ends is made race-free by thread-private force buffers: the pair list (CSR by its
first end i) is cut into one contiguous chunk of particles per thread
(:meth:`HalfPairs.thread_bounds`), each thread adds into its own buffer ``buf[t]``
(T, N, k), and a second, particle-parallel pass sums the buffers (:func:`reduce_buffers`).
Memory: T x N x k doubles.

Array suffixes: ``_p`` per pair, ``_b`` per directed bond, ``_n`` per particle, ``_c``
Cartesian component.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

__all__ = ["HalfPairs", "half_pairs", "reduce_buffers"]


@dataclass
class HalfPairs:
    """The pairs i < j of a family.

    Attributes
    ----------
    i, j : int32 (np,) (int64 for more than 2^31 - 1 bonds)
        Ends of each pair, ``i < j``; ordered as the forward bonds in the family (by i).
    b, rb : int32 / int64 (np,)
        Index of the directed bond i->j and of its reverse j->i (for the bond state).
    offsets : int64 (N + 1,)
        Pairs of particle i (as their first end) are ``offsets[i] <= p < offsets[i+1]``:
        a pair loop keeps i's sums in registers and scatters only to j.
    """

    i: np.ndarray
    j: np.ndarray
    b: np.ndarray
    rb: np.ndarray
    offsets: np.ndarray

    @property
    def n(self) -> int:
        return int(self.i.shape[0])

    def thread_bounds(self, nthreads: int) -> np.ndarray:
        """Particle boundaries (nthreads + 1,) that cut the pairs into contiguous chunks of
        about equal length (thread t takes particles ``bounds[t] <= i < bounds[t+1]``)."""
        target = np.linspace(0, self.n, nthreads + 1)
        bnd = np.searchsorted(self.offsets, target, side="left").astype(np.int64)
        bnd[0], bnd[-1] = 0, self.offsets.shape[0] - 1
        return np.maximum.accumulate(bnd)

    def buffers(self, n_particles: int, ncomp: int = 3) -> np.ndarray:
        """Zeroed thread-private buffers (T, N, ncomp) for the current numba thread count."""
        return np.zeros((nb.get_num_threads(), n_particles, ncomp))


def half_pairs(family) -> HalfPairs:
    """The half-pair list of a symmetric ``family`` (raises ``ValueError`` if some bond has
    no reverse)."""
    rev = family.reverse
    own, nbr = family.owner, family.neighbors
    b = np.flatnonzero(own < nbr)
    # 32-bit indices when they fit: a third less memory traffic in the pair loops
    it = np.int32 if max(family.nb, family.n) < 2 ** 31 - 1 else np.int64
    off = np.zeros(family.n + 1, dtype=np.int64)
    np.cumsum(np.bincount(own[b], minlength=family.n), out=off[1:])
    return HalfPairs(*(np.ascontiguousarray(a, dtype=it) for a in (own[b], nbr[b], b, rev[b])),
                     offsets=off)


@nb.njit(parallel=True, cache=True)
def reduce_buffers(buf_tnc, scale_n, out_nc, ncomp):
    """Mutates ``out_nc``: ``out[i, c] += scale_i sum_t buf[t, i, c]`` for c < ncomp (e.g.
    ``scale = 1/V`` turns pair forces (N) into force densities (N/m^3))."""
    nt = buf_tnc.shape[0]
    n = buf_tnc.shape[1]
    for i in nb.prange(n):
        s = scale_n[i]
        for c in range(ncomp):
            acc = 0.0
            for t in range(nt):
                acc += buf_tnc[t, i, c]
            out_nc[i, c] += s * acc
