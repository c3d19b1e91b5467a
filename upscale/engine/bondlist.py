"""A compact half bond list for the pair loops of the pair models (PMB, LPS, Ti-PD,
correspondence), derived from a :class:`~upscale.engine.families.Family`.

Why another layout
------------------
The :class:`Family` holds both directions of every bond (its rows are what the bond state,
the damage and the directed-bond loops index), so a loop over it does the arithmetic of
every pair twice and would need the pair's coefficients per directed bond. This list
holds each pair once: the pair's current length, its stretch and its failure
test are computed once and applied to both ends (Newton's third law), and per pair it
streams only

``j_p`` (uint32)
    the partner j > i; the pairs of particle i are ``row_n[i]:row_n[i+1]``, in the
    family's row order;
``k_p`` (uint8; uint16 or int32 when needed)
    the pair's *class*: the index of its reference geometry in small tables. A class is
    a distinct bit pattern of (reference length L, partial-volume factor of each
    direction, and any per-bond factor a model adds). On a lattice a stencil of a few
    distinct bond lengths gives a few dozen classes (round-off in the lattice
    coordinates splits each ideal length into a handful of bit patterns), so the tables
    stay in L1 cache and the model precomputes per class what it would otherwise store
    per bond (1/L, c beta, (L (1 + s0))^2, ...). On an irregular point cloud the classes
    are as many as the pairs and the tables are per-pair arrays: correct, only no
    smaller. Reading L from a table rather than recomputing it from ``x0`` spares a
    square root and a division per pair, and keeps L bit for bit the family's;
``rev_p`` (uint32; uint64 beyond 2^32 bonds)
    the directed index of j->i in the family. The bond state stays the engine's
    ``state.intact (nb,) bool`` (read, not copied: anything that sets or checkpoints it
    keeps working); i->j is ``fwd_n[i] + (p - row_n[i])`` when the forward bonds of a row
    are contiguous (rows sorted, as :func:`~upscale.engine.families.build_family` and
    :meth:`Family.remove_bonds` make them), else ``fwd_p[p]``. Each direction that is
    intact contributes its force to its own particle, exactly as in the directed loop,
    so a bond state that differs between the two directions is honoured;

and reads per particle the positions ``y``, the volumes ``V`` and the output.

The indices are unsigned and the kernels' inner loops run over unsigned pair indices:
numba then emits no negative-index wraparound test per array access (signed indices cost
a compare and a select on every load of the loop).

Force densities with Newton's third law: a pair term ``g (y_j - y_i)`` acts as
``b_i += g V_j beta_ij (y_j - y_i)`` and ``b_j -= g V_i beta_ji (y_j - y_i)``.

Race-free threads: the pair rows are cut into one contiguous block of particles per
thread, balanced by pair count (:meth:`BondList.chunks`). A thread adds its pairs' terms
on i and on j into its own buffer ``buf[t] (N, 3)`` (or ``(N,)``), and the buffers are
summed per particle in a second parallel loop (:func:`reduce_buffers`). With one thread
the kernel adds into the output directly (:meth:`BondList.target`). The summation order
differs from the directed loop's: results agree to round-off.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from upscale.engine.families import Family, reverse_in_sorted_rows, rows_sorted

__all__ = ["BondList", "reduce_buffers", "reduce_buffers_scalar"]

# pairs per block when the classes are found: bounds the temporaries (about 100 bytes per
# pair of the block) independently of the number of bonds
_CLASS_BLOCK = 1 << 20


@nb.njit(parallel=True, cache=True)
def reduce_buffers(buf_tnc, out_nc):
    """Mutates ``out_nc``: ``out[i] += sum_t buf[t, i]`` (N, 3)."""
    nt = buf_tnc.shape[0]
    n = out_nc.shape[0]
    for i in nb.prange(n):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for t in range(nt):
            s0 += buf_tnc[t, i, 0]
            s1 += buf_tnc[t, i, 1]
            s2 += buf_tnc[t, i, 2]
        out_nc[i, 0] += s0
        out_nc[i, 1] += s1
        out_nc[i, 2] += s2


@nb.njit(parallel=True, cache=True)
def reduce_buffers_scalar(buf_tn, out_n):
    """Mutates ``out_n``: ``out[i] += sum_t buf[t, i]`` (N,)."""
    nt = buf_tn.shape[0]
    n = out_n.shape[0]
    for i in nb.prange(n):
        s = 0.0
        for t in range(nt):
            s += buf_tn[t, i]
        out_n[i] += s


@nb.njit(cache=True)
def _forward_rows(offsets, neighbors):
    """Per particle the number of forward bonds (j > i) and the directed index of the first
    (0 where none); whether every row's forward bonds are contiguous; False if some bond
    is a self-bond."""
    n = offsets.shape[0] - 1
    cnt = np.zeros(n, dtype=np.int64)
    first = np.zeros(n, dtype=np.int64)
    contiguous = True
    ok = True
    for i in range(n):
        c = 0
        last = -2
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            if j == i:
                ok = False
            elif j > i:
                if c == 0:
                    first[i] = b
                elif b != last + 1:
                    contiguous = False
                last = b
                c += 1
        cnt[i] = c
    return cnt, first, contiguous, ok


@nb.njit(cache=True)
def _fill_forward(offsets, neighbors, row_n, j_p, fwd_p):
    """Mutates ``j_p`` (and ``fwd_p`` unless empty): partner and directed index of every
    forward bond, pair by pair in row order."""
    n = offsets.shape[0] - 1
    keep = fwd_p.shape[0] > 0
    for i in range(n):
        p = row_n[i]
        for b in range(offsets[i], offsets[i + 1]):
            if neighbors[b] > i:
                j_p[p] = neighbors[b]
                if keep:
                    fwd_p[p] = b
                p += 1


class BondList:
    """Half bond list of a :class:`Family` (see the module docstring for the layout).

    Parameters
    ----------
    family : Family
    volume : (N,) float64 or scalar
        Particle volumes V (the partner volumes of the force densities).

    Attributes
    ----------
    n, npairs : int
        Particles, pairs (``family.nb / 2``).
    row_n : int64 (N+1,)
        Pair rows: particle i's pairs (partners j > i) are ``row_n[i]:row_n[i+1]``.
    j_p : uint32 (npairs,)
    fwd_n : int64 (N,)
        Directed index of i's first forward bond (used when ``fwd_p`` is empty).
    fwd_p : uint32/uint64 (npairs,) or (0,)
        Directed index of i->j, only when forward bonds are not contiguous in a row.
    rev_p : uint32/uint64 (npairs,)
        Directed index of j->i.
    volume : float64 (N,)
    """

    def __init__(self, family: Family, volume):
        n = family.n
        self.family = family
        self.n = n
        self.volume = np.ascontiguousarray(np.broadcast_to(np.asarray(volume, dtype=np.float64), (n,)))
        off, nbr = family.offsets, family.neighbors
        cnt, first, contiguous, ok = _forward_rows(off, nbr)
        if not ok or 2 * int(cnt.sum()) != family.nb:
            raise ValueError("the family must hold both directions of every bond and no self-bonds")
        self.npairs = int(cnt.sum())
        itype = np.uint64 if family.nb >= 2 ** 32 else np.uint32
        self.row_n = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(cnt, out=self.row_n[1:])
        self.j_p = np.empty(self.npairs, dtype=np.uint64 if n >= 2 ** 32 else np.uint32)
        self.fwd_p = np.empty(0 if contiguous else self.npairs, dtype=itype)
        _fill_forward(off, nbr, self.row_n, self.j_p, self.fwd_p)
        self.fwd_n = first
        self.rev_p = self._reverse(family, itype)
        self._buffers: dict = {}
        self._chunks: dict = {}
        self._classes: dict = {}

    def _reverse(self, family: Family, itype) -> np.ndarray:
        """Directed index of j->i per pair: bisection when the rows are sorted (as
        ``build_family`` makes them), else the family's own ``reverse``."""
        nbr, off = family.neighbors, family.offsets
        if not rows_sorted(off, nbr):
            return np.ascontiguousarray(family.reverse[self.forward_index()].astype(itype))
        rev = reverse_in_sorted_rows(off, nbr, self.row_n, self.j_p)
        if np.any(rev < 0):
            raise ValueError("family is not symmetric: some bond has no reverse")
        return np.ascontiguousarray(rev.astype(itype))

    # ------------------------------------------------------------------ classes
    def classes(self, *factors_b) -> tuple:
        """Reference-geometry classes of the pairs.

        Parameters
        ----------
        *factors_b : (nb,) arrays or callables
            Per-directed-bond factors a model adds (e.g. a surface correction), as arrays or
            as ``f(bonds) -> (k,)`` of directed-bond indices (evaluated block by block:
            nothing per bond is made); they become part of the class key.

        Returns
        -------
        (k_p, L_k, beta_f_k, beta_r_k, [factor_f_k, factor_r_k, ...])
            ``k_p`` (npairs,) the class of each pair (uint8 up to 256 classes, uint16 up to
            65536, else int32); per class the reference length ``L``, the partial-volume
            factors of i->j (``f``) and j->i (``r``), and the same for each given factor.
            Cached for the call without factors.

        The key of a pair is the bit pattern of its row of columns; the classes are found
        in blocks of pairs (the distinct rows of each block, then of all blocks, then each
        block's rows looked up among them), so the temporaries are one block's, whatever
        the number of bonds.
        """
        key = len(factors_b)
        if key == 0 and 0 in self._classes:
            return self._classes[0]
        fam = self.family
        getters = [lambda b: fam.length_of(b), lambda b: fam.volume_factor_of(b)]
        for f in factors_b:
            if callable(f):
                getters.append(f)
            else:
                arr = np.asarray(f, dtype=np.float64)
                getters.append(lambda b, arr=arr: arr[b])
        k = 2 * len(getters) - 1            # the length once: equal in both directions

        def rows(lo, hi):
            fwd = self.forward_index(lo, hi)
            rev = self.rev_p[lo:hi].astype(np.int64)
            out = np.empty((hi - lo, k))
            out[:, 0] = getters[0](fwd)
            for c, g in enumerate(getters[1:]):
                out[:, 1 + 2 * c] = g(fwd)
                out[:, 2 + 2 * c] = g(rev)
            return out.view(np.dtype((np.void, 8 * k))).ravel()

        blocks = [(lo, min(self.npairs, lo + _CLASS_BLOCK)) for lo in range(0, self.npairs, _CLASS_BLOCK)]
        table = np.unique(np.concatenate([np.unique(rows(lo, hi)) for lo, hi in blocks]
                                         or [np.empty(0, np.dtype((np.void, 8 * k)))]))
        ncls = table.size
        ktype = np.uint8 if ncls <= 256 else (np.uint16 if ncls <= 65536 else np.int32)
        k_p = np.empty(self.npairs, dtype=ktype)
        for lo, hi in blocks:
            k_p[lo:hi] = np.searchsorted(table, rows(lo, hi))
        vals = table.view(np.float64).reshape(ncls, k)
        out = (k_p, *(np.ascontiguousarray(vals[:, c]) for c in range(k)))
        if key == 0:
            self._classes[0] = out
        return out

    def forward_index(self, lo: int = 0, hi: int | None = None) -> np.ndarray:
        """Directed index of i->j for the pairs ``lo:hi`` (default all) (int64, a new
        array)."""
        hi = self.npairs if hi is None else hi
        if self.fwd_p.size:
            return self.fwd_p[lo:hi].astype(np.int64)
        p = np.arange(lo, hi, dtype=np.int64)
        own_p = np.searchsorted(self.row_n, p, side="right") - 1
        return self.fwd_n[own_p] + (p - self.row_n[own_p])

    def nbytes(self) -> int:
        """Bytes the list keeps: per pair ``j_p``, ``rev_p``, ``fwd_p`` and the class index
        (once computed), per particle ``row_n``, ``fwd_n`` and ``volume``, and the class
        tables."""
        arrays = [self.j_p, self.rev_p, self.fwd_p, self.row_n, self.fwd_n, self.volume]
        for out in self._classes.values():
            arrays += list(out)
        return int(sum(a.nbytes for a in arrays))

    # ------------------------------------------------------------------ threads
    def chunks(self, nthreads: int) -> np.ndarray:
        """Particle ranges ``[c[t], c[t+1])`` per thread, balanced by pair count (T+1,)."""
        c = self._chunks.get(nthreads)
        if c is None:
            target = np.linspace(0, self.npairs, nthreads + 1)
            c = np.searchsorted(self.row_n, target, side="left").astype(np.int64)
            c[0], c[-1] = 0, self.n
            c = np.maximum.accumulate(c)
            self._chunks[nthreads] = c
        return c

    def target(self, out: np.ndarray, nthreads: int) -> tuple[np.ndarray, bool]:
        """Where a kernel accumulates: ``(buf (T, N[, 3]), zero)``. One thread and a
        C-contiguous float64 ``out``: a view of ``out`` itself (no zeroing, no
        reduction); else the reused per-thread buffers, which the kernel zeroes. Call
        :meth:`finish` afterwards."""
        if nthreads == 1 and out.dtype == np.float64 and out.flags.c_contiguous:
            return out.reshape((1,) + out.shape), False
        key = (nthreads, out.shape[1:])
        buf = self._buffers.get(key)
        if buf is None:
            buf = np.zeros((nthreads,) + out.shape)
            self._buffers[key] = buf
        return buf, True

    @staticmethod
    def finish(buf: np.ndarray, zero: bool, out: np.ndarray) -> None:
        """Mutates ``out``: adds the per-thread buffers into it (nothing when the kernel
        wrote into ``out`` directly)."""
        if not zero:
            return
        if out.ndim == 2:
            reduce_buffers(buf, out)
        else:
            reduce_buffers_scalar(buf, out)

    # ------------------------------------------------------------------ accounting
    def stream_bytes(self, class_tables=(), per_particle_bytes: int = 0) -> int:
        """Bytes a pair kernel reads (and writes) once per evaluation: the per-pair arrays
        (``j_p``, ``k_p``, ``rev_p``, ``fwd_p``), the bond state (one byte per directed
        bond), the row pointers and volumes, positions read and output read and written
        (3 x 24 bytes per particle), the class tables, and ``per_particle_bytes`` more
        per particle for a model's own per-particle arrays."""
        k_p = self.classes()[0]
        nbytes = sum(a.nbytes for a in (self.j_p, k_p, self.rev_p, self.fwd_p, self.row_n,
                                        self.fwd_n, self.volume))
        nbytes += sum(np.asarray(a).nbytes for a in class_tables)
        nbytes += self.family.nb
        nbytes += self.n * (3 * 24 + per_particle_bytes)
        return int(nbytes)

    def __repr__(self) -> str:
        ncls = self.classes()[1].size
        return f"BondList(n={self.n}, pairs={self.npairs}, classes={ncls})"
