"""The reduction of thread-private pair buffers with a per-particle scale.

A pair loop over the half bond list (:mod:`upscale.engine.bondlist`, each pair once)
scatters to both ends race-free through thread-private buffers ``buf[t]`` (T, N, k), one
contiguous chunk of particles per thread; :func:`reduce_buffers` sums them per particle,
scaled (e.g. by 1/V to turn pair forces into force densities). Memory: T x N x k doubles.

Array suffixes: ``_p`` per pair, ``_b`` per directed bond, ``_n`` per particle, ``_c``
Cartesian component.
"""
from __future__ import annotations

import numba as nb

__all__ = ["reduce_buffers"]


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
