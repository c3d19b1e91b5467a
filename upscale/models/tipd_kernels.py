"""Numba kernels of Ti-PD (:mod:`upscale.models.tipd`): the force of the pair model and of
its surface correction, on the directed bonds of a family (``kernel="bond"``) or on the
half bond list of :mod:`upscale.engine.bondlist` (``kernel="pair"``, the default).

Array suffixes: ``_n`` per particle, ``_b`` per directed bond, ``_p`` per pair (each
unordered pair once), ``_k`` per reference-geometry class of pairs, ``_c`` Cartesian
component, ``_t`` per thread, ``_r`` per ring-buffer slot.

Pair layout (``kernel="pair"``)
-------------------------------
Each pair (i, j > i) is read once from the :class:`~upscale.engine.bondlist.BondList`: its
partner ``j_p`` (uint32) and its class ``k_p`` (one byte on a lattice); the directed
indices of i->j and j->i (bond state) only while some bond is broken. Everything else a
pair needs is a function of its reference geometry and lives in a small table per class
(``tab``, one row per distinct bit pattern of (|xi|, beta both ways, xi): 152 rows on the
300 x 100 plate of ``bench-tipd``, in L1): the reference vector ``xi``, the normalised
bond matrix ``Mhat = A : (xi (x) xi) / |xi|^3`` (the Ti-PD bond matrix without
``V_j beta``; symmetric, 3 entries in 2D, 6 in 3D), the partial-volume factors of the two
directions and the squared critical length (columns: 2D ``xi_x, xi_y, Mhat_11, Mhat_12,
Mhat_22, beta_ij, beta_ji, (L (1 + s0))^2``; 3D ``xi (3), Mhat_11, _22, _33, _23, _13, _12,
beta_ij, beta_ji, (L (1 + s0))^2``). With ``w_ij = V_j beta_ij`` (m^3) a pair
contributes::

    Ti-PD:       b_i += w_ij Mhat eta,            b_j -= w_ji Mhat eta,        eta = u_j - u_i
    gradient:    A_i += w_ij eta (x) xi,          A_j += w_ji eta (x) xi
    correction:  b_i += w_ij (Q_i + Q_j) xi,      b_j -= w_ji (Q_i + Q_j) xi

which is the directed-bond model term by term (each direction keeps its own weight and
bond state), so the half list needs no symmetry of the weights. When the volumes are
uniform and beta is the same both ways (a lattice, with or without partial volumes) the
weight is a class constant and is folded into the table (``uni``): the loops then multiply
by no weight and read no volume (on the ``bench-tipd`` plate a step with the correction costs
1.3 PMB steps folded, 2.6 weighted).

Surface correction (module docstring of :mod:`upscale.models.tipd`): per particle
``Q_i = (Delta_i : H_i) K_i^-1`` with ``H_i = A_i K_i^-1``, a linear map of ``A_i`` fixed in
the reference configuration, precomputed once as ``T_i`` (d^2 x d^2,
``Q_i[p, a] = T_i[p a, q e] A_i[q, e]``) and stored once per distinct bit pattern
(``T_ckk`` with a class index ``tc_n`` per particle: about a thousand classes on the plate,
instead of 128 bytes per particle). Two pair passes are needed (``Q_j`` needs all of j's
bonds before any pair of j can use it); the Ti-PD term is computed in the second together
with the correction (the same weight multiplies both). A step is

1. gradient pass: ``A`` (each pair once, i's sum in registers, j scattered);
2. ``Q_i = T_i A_i`` per particle;
3. force pass: Ti-PD + correction (each pair once).

:func:`tipd_surface_2d` / ``_3d`` run the three as ONE sweep over the particles: the
gradient rows run ahead of the force rows by the reach of the pairs (``reach_n[i] = max(i,
max j of i's pairs)``), so when the force row i runs every row up to ``reach_n[i]`` has its
gradient and ``Q`` of every partner is final. The pair arrays are streamed from memory once
and re-read from cache by the force row; ``u = y - x0``, ``A`` and ``Q`` live in ring
buffers of a few hundred rows (power of two ``R > 2 span + 1``, ``span`` the largest
``reach_n[i] - i``: a row's u is needed until its own force row, which runs at most two
spans behind the front), so besides the positions, the output and the class indices no
per-particle array goes through memory, and nothing is allocated per step. Threads: each
sweeps its own block of force rows (balanced by pairs) with its own rings, starting its
gradient rows ``span`` rows before its block (the rows whose pairs reach into it: at most
``span`` rows recomputed per thread) and putting the force on rows beyond its block (at
most ``span`` of them) into its own halo buffer, added to the output after the threads,
serially (race-free: no row is incremented by two threads, nothing is incremented in
``prange`` but a thread's own rows and buffers).

The surface correction is elastic: its gradient and force use every bond, intact or not
(as the directed kernels do); the Ti-PD term honours the bond state of each direction.

Measured on the ``bench-tipd`` plate, one thread: the row helpers are inlined
(``inline="always"``): called as functions each call passes a dozen arrays (reference
counting per array and per row) and the step cost 1.6 PMB steps instead of 1.4; the sweep
without weights and bond state (:func:`_sweep_2d_fast`: uniform weights, every bond intact,
the default elastic case) brings it to 1.25-1.3.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from upscale.engine.kernels import add_to_row

__all__ = ["tipd_force_kernel_2d", "tipd_force_kernel_3d", "tipd_energy_kernel",
           "surface_stress_kernel", "tipd_pair_kernel", "tipd_surface_2d", "tipd_surface_3d",
           "tipd_pair_energy_kernel"]


# ---------------------------------------------------------------------------- directed bonds
@nb.njit(parallel=True, cache=True)
def tipd_force_kernel_2d(offsets, neighbors, q_bc, A, u_nc, y_nc, intact_b, rc2_b, fail, out_nc):
    """Adds Ti-PD force densities (2D) to ``out_nc``: ``b_i = sum_j M_b eta_b`` with
    ``eta_b = u_j - u_i`` (``u_nc = y - x0``), ``M_pq = A[p,q,a,b] q_a q_b``,
    ``q_b = xi sqrt(V_j beta / |xi|^3)`` and ``A`` the normalised induced tensor (4, 4)
    flattened ``[2p+q, 2a+b]``. If ``fail``, mutates ``intact_b``: a bond whose squared
    current length (from ``y_nc``) exceeds ``rc2_b`` breaks after its force is counted.
    Returns the number of directed bonds broken."""
    n = offsets.shape[0] - 1
    broke = np.zeros(n, dtype=np.int64)
    # M11 = A00 qx^2 + 2 A01 qx qy + A03 qy^2, etc. (A[pq, ab], symmetric in ab)
    m11a, m11b, m11c = A[0, 0], 2.0 * A[0, 1], A[0, 3]
    m12a, m12b, m12c = A[1, 0], 2.0 * A[1, 1], A[1, 3]
    m22a, m22b, m22c = A[3, 0], 2.0 * A[3, 1], A[3, 3]
    for i in nb.prange(n):
        f0 = 0.0
        f1 = 0.0
        ui0 = u_nc[i, 0]
        ui1 = u_nc[i, 1]
        k = 0
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            j = neighbors[b]
            e0 = u_nc[j, 0] - ui0
            e1 = u_nc[j, 1] - ui1
            qx = q_bc[b, 0]
            qy = q_bc[b, 1]
            xx = qx * qx
            xy = qx * qy
            yy = qy * qy
            M11 = m11a * xx + m11b * xy + m11c * yy
            M12 = m12a * xx + m12b * xy + m12c * yy
            M22 = m22a * xx + m22b * xy + m22c * yy
            f0 += M11 * e0 + M12 * e1
            f1 += M12 * e0 + M22 * e1
            if fail:
                d0 = y_nc[j, 0] - y_nc[i, 0]
                d1 = y_nc[j, 1] - y_nc[i, 1]
                d2 = y_nc[j, 2] - y_nc[i, 2]
                if d0 * d0 + d1 * d1 + d2 * d2 > rc2_b[b]:
                    intact_b[b] = False
                    k += 1
        add_to_row(out_nc, i, f0, f1, 0.0)
        broke[i] = k
    return broke.sum()


@nb.njit(parallel=True, cache=True)
def tipd_force_kernel_3d(offsets, neighbors, q_bc, A, u_nc, y_nc, intact_b, rc2_b, fail, out_nc):
    """3D analogue of :func:`tipd_force_kernel_2d`; ``A`` (9, 9) flattened
    ``[3p+q, 3a+b]``."""
    n = offsets.shape[0] - 1
    broke = np.zeros(n, dtype=np.int64)
    for i in nb.prange(n):
        f = np.zeros(3)
        e = np.zeros(3)
        qq = np.zeros(9)
        k = 0
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            j = neighbors[b]
            rsq = 0.0
            for c in range(3):
                e[c] = u_nc[j, c] - u_nc[i, c]
                if fail:
                    dc = y_nc[j, c] - y_nc[i, c]
                    rsq += dc * dc
            for a in range(3):
                for c in range(3):
                    qq[3 * a + c] = q_bc[b, a] * q_bc[b, c]
            for p in range(3):
                acc = 0.0
                for r in range(3):
                    m = 0.0
                    row = 3 * p + r
                    for ab in range(9):
                        m += A[row, ab] * qq[ab]
                    acc += m * e[r]
                f[p] += acc
            if fail and rsq > rc2_b[b]:
                intact_b[b] = False
                k += 1
        add_to_row(out_nc, i, f[0], f[1], f[2])
        broke[i] = k
    return broke.sum()


@nb.njit(parallel=True, cache=True)
def tipd_energy_kernel(offsets, neighbors, q_bc, A, x_nc, y_nc, intact_b, d):
    """W_i = (1/4) sum_j eta.M eta (J/m^3), half of each bond's energy to each end."""
    n = offsets.shape[0] - 1
    W = np.zeros(n)
    for i in nb.prange(n):
        acc = 0.0
        e = np.zeros(3)
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            j = neighbors[b]
            for c in range(d):
                e[c] = (y_nc[j, c] - y_nc[i, c]) - (x_nc[j, c] - x_nc[i, c])
            for p in range(d):
                for r in range(d):
                    m = 0.0
                    for a in range(d):
                        for c in range(d):
                            m += A[d * p + r, d * a + c] * q_bc[b, a] * q_bc[b, c]
                    acc += e[p] * m * e[r]
        W[i] = 0.25 * acc
    return W


@nb.njit(parallel=True, cache=True)
def surface_stress_kernel(H_nk, Delta_nkk, Kinv_n, d, Q_nk):
    """Surface correction's ``Q_i = (Delta_i : H_i) K_i^-1`` per particle. ``H_nk``: the
    gradients as rows of d*d (2D) or 9 (3D, a (N, 3, 3) view) entries ``[p, a]``;
    ``Delta_nkk`` (N, d*d, d*d) with row ``p d + a`` and column ``q d + b``; ``Kinv_n``
    (N, 3, 3); ``Q_nk`` laid out as ``H_nk``. (Not used by the pair kernels, which apply
    the precomputed map ``T_i``.)"""
    n = H_nk.shape[0]
    st = 2 if d == 2 else 3                     # row stride of the (p, a) layout
    for i in nb.prange(n):
        P = np.zeros((3, 3))
        for p in range(d):
            for a in range(d):
                v = 0.0
                for q in range(d):
                    for b in range(d):
                        v += Delta_nkk[i, p * d + a, q * d + b] * H_nk[i, q * st + b]
                P[p, a] = v
        for p in range(d):
            for a in range(d):
                v = 0.0
                for c in range(d):
                    v += P[p, c] * Kinv_n[i, c, a]
                Q_nk[i, p * st + a] = v


# ---------------------------------------------------------------------------- pair list: Ti-PD
@nb.njit(cache=True, error_model="numpy")
def _tipd_rows(i0, i1, row_n, j_p, k_p, fwd_n, fwd_p, rev_p, tab, vol_n, uni, u_nc, y_nc,
               intact_b, fail, check, d, out):
    """Ti-PD pairs of the rows i0 <= i < i1 added into ``out`` (N, 3) (i's sum in registers,
    j scattered); returns the directed bonds broken."""
    has_fwd = fwd_p.shape[0] > 0
    cbf = 5 if d == 2 else 9
    nbroke = 0
    for i in range(i0, i1):
        p0 = row_n[i]
        ui0 = u_nc[i, 0]
        ui1 = u_nc[i, 1]
        ui2 = u_nc[i, 2]
        vi = vol_n[i]
        bf0 = np.uint64(fwd_n[i] - p0)
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for p in range(np.uint64(p0), np.uint64(row_n[i + 1])):
            fi = True
            fj = True
            if check:
                fi = intact_b[np.uint64(fwd_p[p]) if has_fwd else bf0 + p]
                fj = intact_b[rev_p[p]]
                if not (fi or fj):
                    continue
            j = j_p[p]
            k = k_p[p]
            e0 = u_nc[j, 0] - ui0
            e1 = u_nc[j, 1] - ui1
            if d == 2:
                m12 = tab[k, 3]
                g0 = tab[k, 2] * e0 + m12 * e1
                g1 = m12 * e0 + tab[k, 4] * e1
                g2 = 0.0
            else:
                e2 = u_nc[j, 2] - ui2
                m23 = tab[k, 6]
                m13 = tab[k, 7]
                m12 = tab[k, 8]
                g0 = tab[k, 3] * e0 + m12 * e1 + m13 * e2
                g1 = m12 * e0 + tab[k, 4] * e1 + m23 * e2
                g2 = m13 * e0 + m23 * e1 + tab[k, 5] * e2
            wf = 1.0
            wr = 1.0
            if not uni:
                wf = tab[k, cbf] * vol_n[j]
                wr = tab[k, cbf + 1] * vi
            if fi:
                f0 += wf * g0
                f1 += wf * g1
                f2 += wf * g2
            if fj:
                out[j, 0] -= wr * g0
                out[j, 1] -= wr * g1
                if d == 3:
                    out[j, 2] -= wr * g2
            if fail:
                d0 = y_nc[j, 0] - y_nc[i, 0]
                d1 = y_nc[j, 1] - y_nc[i, 1]
                d2 = y_nc[j, 2] - y_nc[i, 2]
                if d0 * d0 + d1 * d1 + d2 * d2 > tab[k, cbf + 2]:
                    if fi:
                        intact_b[np.uint64(fwd_p[p]) if has_fwd else bf0 + p] = False
                        nbroke += 1
                    if fj:
                        intact_b[rev_p[p]] = False
                        nbroke += 1
        out[i, 0] += f0
        out[i, 1] += f1
        if d == 3:
            out[i, 2] += f2
    return nbroke


@nb.njit(parallel=True, cache=True, error_model="numpy")
def tipd_pair_kernel(row_n, j_p, k_p, fwd_n, fwd_p, rev_p, tab, uni, chunk_t, vol_n, x0_nc, y_nc,
                     intact_b, fail, check, d, u_nc, buf_tnc, zero):
    """Ti-PD force densities (no surface correction) over the half bond list:
    ``b_i += w_ij Mhat eta`` if i->j is intact, ``b_j -= w_ji Mhat eta`` if j->i is
    (``eta = u_j - u_i``, ``u = y - x0`` written into ``u_nc`` (N, 3) first; ``uni``: the
    weights are folded into the table, module docstring). Thread t adds the rows
    ``chunk_t[t]:chunk_t[t+1]`` into ``buf_tnc[t]`` (zeroed first if ``zero``; one thread:
    the output itself, see :meth:`~upscale.engine.bondlist.BondList.target`). If ``fail``,
    a direction that is intact breaks when the squared current length exceeds the class's
    ``(L (1 + s0))^2``, after its force is counted; ``check`` False: every bond is intact
    and ``fail`` is False (the bond state is not read). Returns the number of directed
    bonds broken."""
    nt = chunk_t.shape[0] - 1
    n = row_n.shape[0] - 1
    cn = (n + nt - 1) // nt
    for t in nb.prange(nt):
        for i in range(t * cn, min(n, (t + 1) * cn)):
            for c in range(3):
                u_nc[i, c] = y_nc[i, c] - x0_nc[i, c]
    broke = np.zeros(nt, dtype=np.int64)
    for t in nb.prange(nt):
        buf = buf_tnc[t]
        if zero:
            buf[:, :] = 0.0
        broke[t] = _tipd_rows(chunk_t[t], chunk_t[t + 1], row_n, j_p, k_p, fwd_n, fwd_p, rev_p,
                              tab, vol_n, uni, u_nc, y_nc, intact_b, fail, check, d, buf)
    return broke.sum()


@nb.njit(cache=True)
def tipd_pair_energy_kernel(row_n, j_p, k_p, fwd_n, fwd_p, rev_p, tab, uni, vol_n, x0_nc, y_nc,
                            intact_b, d, W_n):
    """Adds the Ti-PD energy density ``W_i = (1/4) sum_j w_ij eta.Mhat eta`` (J/m^3, half of
    each intact direction's energy to its owner) to ``W_n``, serially over the pairs (an
    output, not a step)."""
    has_fwd = fwd_p.shape[0] > 0
    cbf = 5 if d == 2 else 9
    n = row_n.shape[0] - 1
    e = np.zeros(3)
    g = np.zeros(3)
    for i in range(n):
        for p in range(row_n[i], row_n[i + 1]):
            j = j_p[p]
            k = k_p[p]
            for c in range(d):
                e[c] = (y_nc[j, c] - x0_nc[j, c]) - (y_nc[i, c] - x0_nc[i, c])
            if d == 2:
                g[0] = tab[k, 2] * e[0] + tab[k, 3] * e[1]
                g[1] = tab[k, 3] * e[0] + tab[k, 4] * e[1]
            else:
                g[0] = tab[k, 3] * e[0] + tab[k, 8] * e[1] + tab[k, 7] * e[2]
                g[1] = tab[k, 8] * e[0] + tab[k, 4] * e[1] + tab[k, 6] * e[2]
                g[2] = tab[k, 7] * e[0] + tab[k, 6] * e[1] + tab[k, 5] * e[2]
            q = 0.0
            for c in range(d):
                q += e[c] * g[c]
            wf = 1.0 if uni else tab[k, cbf] * vol_n[j]
            wr = 1.0 if uni else tab[k, cbf + 1] * vol_n[i]
            if intact_b[fwd_p[p] if has_fwd else fwd_n[i] + (p - row_n[i])]:
                W_n[i] += 0.25 * wf * q
            if intact_b[rev_p[p]]:
                W_n[j] += 0.25 * wr * q


# ---------------------------------------------------------------------------- pair list: 2D correction
@nb.njit(cache=True, inline="always", error_model="numpy")
def _grad_row_2d(i, mask, row_n, j_p, k_p, tab, vol_n, uni, u, A):
    """Gradient sums of row i: ``A_i += w_ij eta (x) xi``, ``A_j += w_ji eta (x) xi``
    (entries 00, 01, 10, 11); ``u`` and ``A`` indexed by ``index & mask``."""
    ii = np.uint64(i) & mask
    ui0 = u[ii, 0]
    ui1 = u[ii, 1]
    vi = vol_n[i]
    s00 = 0.0
    s01 = 0.0
    s10 = 0.0
    s11 = 0.0
    for p in range(np.uint64(row_n[i]), np.uint64(row_n[i + 1])):
        j = j_p[p]
        jj = j & mask
        k = k_p[p]
        e0 = u[jj, 0] - ui0
        e1 = u[jj, 1] - ui1
        x0 = tab[k, 0]
        x1 = tab[k, 1]
        a = e0 * x0
        b = e0 * x1
        c = e1 * x0
        e = e1 * x1
        if uni:
            s00 += a
            s01 += b
            s10 += c
            s11 += e
            A[jj, 0] += a
            A[jj, 1] += b
            A[jj, 2] += c
            A[jj, 3] += e
        else:
            wf = tab[k, 5] * vol_n[j]
            wr = tab[k, 6] * vi
            s00 += wf * a
            s01 += wf * b
            s10 += wf * c
            s11 += wf * e
            A[jj, 0] += wr * a
            A[jj, 1] += wr * b
            A[jj, 2] += wr * c
            A[jj, 3] += wr * e
    A[ii, 0] += s00
    A[ii, 1] += s01
    A[ii, 2] += s10
    A[ii, 3] += s11


@nb.njit(cache=True, inline="always")
def _stress_row_2d(i, mask, tc_n, T_ckk, A, Q):
    """``Q_i = T_c A_i`` (c = ``tc_n[i]``, the class of i's map)."""
    ii = np.uint64(i) & mask
    a0 = A[ii, 0]
    a1 = A[ii, 1]
    a2 = A[ii, 2]
    a3 = A[ii, 3]
    T = T_ckk[tc_n[i]]
    for r in range(4):
        Q[ii, r] = T[r, 0] * a0 + T[r, 1] * a1 + T[r, 2] * a2 + T[r, 3] * a3


@nb.njit(cache=True, inline="always", error_model="numpy")
def _force_row_2d(i, mask, row_n, j_p, k_p, fwd_n, fwd_p, rev_p, tab, vol_n, uni, u, Q, intact_b,
                  check, out, halo, f1):
    """Ti-PD and correction force of row i's pairs: ``g = Mhat eta + (Q_i + Q_j) xi``,
    ``out_i += w_ij g``, ``out_j -= w_ji g`` (the Ti-PD part only for intact directions
    when ``check``); ``u`` and ``Q`` indexed by ``index & mask``, ``out`` by index for
    ``j < f1`` and ``halo`` by ``j - f1`` beyond."""
    has_fwd = fwd_p.shape[0] > 0
    p0 = row_n[i]
    bf0 = np.uint64(fwd_n[i] - p0)
    ii = np.uint64(i) & mask
    ui0 = u[ii, 0]
    ui1 = u[ii, 1]
    qi0 = Q[ii, 0]
    qi1 = Q[ii, 1]
    qi2 = Q[ii, 2]
    qi3 = Q[ii, 3]
    vi = vol_n[i]
    f0 = 0.0
    f1_ = 0.0
    for p in range(np.uint64(p0), np.uint64(row_n[i + 1])):
        j = j_p[p]
        jj = j & mask
        k = k_p[p]
        e0 = u[jj, 0] - ui0
        e1 = u[jj, 1] - ui1
        x0 = tab[k, 0]
        x1 = tab[k, 1]
        m12 = tab[k, 3]
        t0 = tab[k, 2] * e0 + m12 * e1
        t1 = m12 * e0 + tab[k, 4] * e1
        c0 = (qi0 + Q[jj, 0]) * x0 + (qi1 + Q[jj, 1]) * x1
        c1 = (qi2 + Q[jj, 2]) * x0 + (qi3 + Q[jj, 3]) * x1
        wf = 1.0
        wr = 1.0
        if not uni:
            wf = tab[k, 5] * vol_n[j]
            wr = tab[k, 6] * vi
        fi = True
        fj = True
        if check:
            fi = intact_b[np.uint64(fwd_p[p]) if has_fwd else bf0 + p]
            fj = intact_b[rev_p[p]]
        f0 += wf * (c0 + t0 if fi else c0)
        f1_ += wf * (c1 + t1 if fi else c1)
        g0 = wr * (c0 + t0 if fj else c0)
        g1 = wr * (c1 + t1 if fj else c1)
        if j < f1:
            out[j, 0] -= g0
            out[j, 1] -= g1
        else:
            halo[j - f1, 0] -= g0
            halo[j - f1, 1] -= g1
    out[i, 0] += f0
    out[i, 1] += f1_


@nb.njit(cache=True, inline="always", error_model="numpy")
def _force_row_2d_fast(i, mask, row_n, j_p, k_p, tab, u, Q, out, halo, f1):
    """:func:`_force_row_2d` with the weights folded into ``tab`` and every bond intact."""
    ii = np.uint64(i) & mask
    ui0 = u[ii, 0]
    ui1 = u[ii, 1]
    qi0 = Q[ii, 0]
    qi1 = Q[ii, 1]
    qi2 = Q[ii, 2]
    qi3 = Q[ii, 3]
    f0 = 0.0
    f1_ = 0.0
    for p in range(np.uint64(row_n[i]), np.uint64(row_n[i + 1])):
        j = j_p[p]
        jj = j & mask
        k = k_p[p]
        e0 = u[jj, 0] - ui0
        e1 = u[jj, 1] - ui1
        x0 = tab[k, 0]
        x1 = tab[k, 1]
        m12 = tab[k, 3]
        g0 = tab[k, 2] * e0 + m12 * e1 + (qi0 + Q[jj, 0]) * x0 + (qi1 + Q[jj, 1]) * x1
        g1 = m12 * e0 + tab[k, 4] * e1 + (qi2 + Q[jj, 2]) * x0 + (qi3 + Q[jj, 3]) * x1
        f0 += g0
        f1_ += g1
        if j < f1:
            out[j, 0] -= g0
            out[j, 1] -= g1
        else:
            halo[j - f1, 0] -= g0
            halo[j - f1, 1] -= g1
    out[i, 0] += f0
    out[i, 1] += f1_


@nb.njit(cache=True, error_model="numpy")
def _sweep_2d(g0, i0, i1, row_n, j_p, k_p, fwd_n, fwd_p, rev_p, reach_n, tab, uni, vol_n, x0_nc, y_nc,
              tc_n, T_ckk, intact_b, check, mask, u_r2, A_r4, Q_r4, out_nc, halo_h2):
    """The sweep (module docstring) of the force rows ``i0 <= i < i1``, gradient rows from
    ``g0`` (``i0 - span`` or 0: every row that scatters into a row >= i0); the force on rows
    >= i1 goes into ``halo_h2[j - i1]`` (zeroed here). Ring buffers ``u_r2`` (R, 2),
    ``A_r4``, ``Q_r4`` (R, 4) indexed by ``index & mask``. With uniform weights and every
    bond intact :func:`_sweep_2d_fast` is the same, faster."""
    halo_h2[:, :] = 0.0
    f1 = np.uint64(i1)
    z = g0                          # rows < z have u and a zeroed A
    r = g0                          # rows < r have their gradient and Q
    for i in range(i0, i1):
        while r <= reach_n[i]:
            m = reach_n[r]
            while z <= m:
                zz = np.uint64(z) & mask
                u_r2[zz, 0] = y_nc[z, 0] - x0_nc[z, 0]
                u_r2[zz, 1] = y_nc[z, 1] - x0_nc[z, 1]
                A_r4[zz, 0] = 0.0
                A_r4[zz, 1] = 0.0
                A_r4[zz, 2] = 0.0
                A_r4[zz, 3] = 0.0
                z += 1
            _grad_row_2d(r, mask, row_n, j_p, k_p, tab, vol_n, uni, u_r2, A_r4)
            _stress_row_2d(r, mask, tc_n, T_ckk, A_r4, Q_r4)
            r += 1
        _force_row_2d(i, mask, row_n, j_p, k_p, fwd_n, fwd_p, rev_p, tab, vol_n, uni, u_r2, Q_r4,
                      intact_b, check, out_nc, halo_h2, f1)

@nb.njit(cache=True, error_model="numpy")
def _sweep_2d_fast(g0, i0, i1, row_n, j_p, k_p, reach_n, tab, vol_n, x0_nc, y_nc, tc_n, T_ckk, mask,
                   u_r2, A_r4, Q_r4, out_nc, halo_h2):
    """:func:`_sweep_2d` with the weights folded into ``tab`` (``uni``) and every bond
    intact: the loops read no weight and no bond state (the default elastic case on a
    lattice). A function of its own: with both loops in one function the step is 1.5 PMB
    steps instead of 1.25."""
    halo_h2[:, :] = 0.0
    f1 = np.uint64(i1)
    z = g0
    r = g0
    for i in range(i0, i1):
        while r <= reach_n[i]:
            m = reach_n[r]
            while z <= m:
                zz = np.uint64(z) & mask
                u_r2[zz, 0] = y_nc[z, 0] - x0_nc[z, 0]
                u_r2[zz, 1] = y_nc[z, 1] - x0_nc[z, 1]
                A_r4[zz, 0] = 0.0
                A_r4[zz, 1] = 0.0
                A_r4[zz, 2] = 0.0
                A_r4[zz, 3] = 0.0
                z += 1
            _grad_row_2d(r, mask, row_n, j_p, k_p, tab, vol_n, True, u_r2, A_r4)
            _stress_row_2d(r, mask, tc_n, T_ckk, A_r4, Q_r4)
            r += 1
        _force_row_2d_fast(i, mask, row_n, j_p, k_p, tab, u_r2, Q_r4, out_nc, halo_h2, f1)


@nb.njit(parallel=True, cache=True, error_model="numpy")
def tipd_surface_2d(row_n, j_p, k_p, fwd_n, fwd_p, rev_p, reach_n, chunk_t, span, tab, uni, vol_n,
                    x0_nc, y_nc, tc_n, T_ckk, intact_b, check, mask, u_tr2, A_tr4, Q_tr4, halo_th2,
                    out_nc):
    """2D Ti-PD with the surface correction added to ``out_nc`` (N, 3) (module docstring):
    thread t sweeps the force rows ``chunk_t[t]:chunk_t[t+1]`` with its own ring buffers
    (``u_tr2`` (T, R, 2), ``A_tr4``, ``Q_tr4`` (T, R, 4)), its gradient rows starting
    ``span`` (the largest ``reach_n[i] - i``) before its first force row (the gradients of
    a thread's first rows need the pairs of the rows before it: recomputed, at most
    ``span`` rows per thread), its force on the next thread's rows into ``halo_th2[t]``
    (T, span, 2), added to the output after the threads (serially: no row is incremented
    by two threads). One thread: one sweep, no halo."""
    nt = chunk_t.shape[0] - 1
    n = row_n.shape[0] - 1
    fast = uni and not check
    for t in nb.prange(nt):
        i0 = chunk_t[t]
        g0 = max(0, i0 - span)
        if fast:
            _sweep_2d_fast(g0, i0, chunk_t[t + 1], row_n, j_p, k_p, reach_n, tab, vol_n, x0_nc, y_nc,
                           tc_n, T_ckk, mask, u_tr2[t], A_tr4[t], Q_tr4[t], out_nc, halo_th2[t])
        else:
            _sweep_2d(g0, i0, chunk_t[t + 1], row_n, j_p, k_p, fwd_n, fwd_p, rev_p, reach_n, tab, uni,
                      vol_n, x0_nc, y_nc, tc_n, T_ckk, intact_b, check, mask, u_tr2[t], A_tr4[t],
                      Q_tr4[t], out_nc, halo_th2[t])
    for t in range(nt - 1):
        i1 = chunk_t[t + 1]
        for h in range(min(halo_th2.shape[1], n - i1)):
            out_nc[i1 + h, 0] += halo_th2[t, h, 0]
            out_nc[i1 + h, 1] += halo_th2[t, h, 1]


# ---------------------------------------------------------------------------- pair list: 3D correction
@nb.njit(cache=True, inline="always", error_model="numpy")
def _grad_row_3d(i, mask, row_n, j_p, k_p, tab, vol_n, uni, u, A):
    """3D :func:`_grad_row_2d` (entries ``3 r + a``)."""
    ii = np.uint64(i) & mask
    ui0 = u[ii, 0]
    ui1 = u[ii, 1]
    ui2 = u[ii, 2]
    vi = vol_n[i]
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    s4 = 0.0
    s5 = 0.0
    s6 = 0.0
    s7 = 0.0
    s8 = 0.0
    for p in range(np.uint64(row_n[i]), np.uint64(row_n[i + 1])):
        j = j_p[p]
        jj = j & mask
        k = k_p[p]
        e0 = u[jj, 0] - ui0
        e1 = u[jj, 1] - ui1
        e2 = u[jj, 2] - ui2
        x0 = tab[k, 0]
        x1 = tab[k, 1]
        x2 = tab[k, 2]
        wf = 1.0
        wr = 1.0
        if not uni:
            wf = tab[k, 9] * vol_n[j]
            wr = tab[k, 10] * vi
        a0 = e0 * x0
        a1 = e0 * x1
        a2 = e0 * x2
        a3 = e1 * x0
        a4 = e1 * x1
        a5 = e1 * x2
        a6 = e2 * x0
        a7 = e2 * x1
        a8 = e2 * x2
        s0 += wf * a0
        s1 += wf * a1
        s2 += wf * a2
        s3 += wf * a3
        s4 += wf * a4
        s5 += wf * a5
        s6 += wf * a6
        s7 += wf * a7
        s8 += wf * a8
        A[jj, 0] += wr * a0
        A[jj, 1] += wr * a1
        A[jj, 2] += wr * a2
        A[jj, 3] += wr * a3
        A[jj, 4] += wr * a4
        A[jj, 5] += wr * a5
        A[jj, 6] += wr * a6
        A[jj, 7] += wr * a7
        A[jj, 8] += wr * a8
    A[ii, 0] += s0
    A[ii, 1] += s1
    A[ii, 2] += s2
    A[ii, 3] += s3
    A[ii, 4] += s4
    A[ii, 5] += s5
    A[ii, 6] += s6
    A[ii, 7] += s7
    A[ii, 8] += s8


@nb.njit(cache=True, inline="always")
def _stress_row_3d(i, mask, tc_n, T_ckk, A, Q):
    """3D :func:`_stress_row_2d` (9 x 9)."""
    ii = np.uint64(i) & mask
    T = T_ckk[tc_n[i]]
    for r in range(9):
        v = 0.0
        for c in range(9):
            v += T[r, c] * A[ii, c]
        Q[ii, r] = v


@nb.njit(cache=True, inline="always", error_model="numpy")
def _force_row_3d(i, mask, row_n, j_p, k_p, fwd_n, fwd_p, rev_p, tab, vol_n, uni, u, Q, intact_b,
                  check, out, halo, f1):
    """3D :func:`_force_row_2d`."""
    has_fwd = fwd_p.shape[0] > 0
    p0 = row_n[i]
    bf0 = np.uint64(fwd_n[i] - p0)
    ii = np.uint64(i) & mask
    ui0 = u[ii, 0]
    ui1 = u[ii, 1]
    ui2 = u[ii, 2]
    q0 = Q[ii, 0]
    q1 = Q[ii, 1]
    q2 = Q[ii, 2]
    q3 = Q[ii, 3]
    q4 = Q[ii, 4]
    q5 = Q[ii, 5]
    q6 = Q[ii, 6]
    q7 = Q[ii, 7]
    q8 = Q[ii, 8]
    vi = vol_n[i]
    f0 = 0.0
    f1_ = 0.0
    f2 = 0.0
    for p in range(np.uint64(p0), np.uint64(row_n[i + 1])):
        j = j_p[p]
        jj = j & mask
        k = k_p[p]
        e0 = u[jj, 0] - ui0
        e1 = u[jj, 1] - ui1
        e2 = u[jj, 2] - ui2
        x0 = tab[k, 0]
        x1 = tab[k, 1]
        x2 = tab[k, 2]
        m23 = tab[k, 6]
        m13 = tab[k, 7]
        m12 = tab[k, 8]
        t0 = tab[k, 3] * e0 + m12 * e1 + m13 * e2
        t1 = m12 * e0 + tab[k, 4] * e1 + m23 * e2
        t2 = m13 * e0 + m23 * e1 + tab[k, 5] * e2
        c0 = (q0 + Q[jj, 0]) * x0 + (q1 + Q[jj, 1]) * x1 + (q2 + Q[jj, 2]) * x2
        c1 = (q3 + Q[jj, 3]) * x0 + (q4 + Q[jj, 4]) * x1 + (q5 + Q[jj, 5]) * x2
        c2 = (q6 + Q[jj, 6]) * x0 + (q7 + Q[jj, 7]) * x1 + (q8 + Q[jj, 8]) * x2
        wf = 1.0
        wr = 1.0
        if not uni:
            wf = tab[k, 9] * vol_n[j]
            wr = tab[k, 10] * vi
        fi = True
        fj = True
        if check:
            fi = intact_b[np.uint64(fwd_p[p]) if has_fwd else bf0 + p]
            fj = intact_b[rev_p[p]]
        if fi:
            f0 += wf * (c0 + t0)
            f1_ += wf * (c1 + t1)
            f2 += wf * (c2 + t2)
        else:
            f0 += wf * c0
            f1_ += wf * c1
            f2 += wf * c2
        if fj:
            g0 = wr * (c0 + t0)
            g1 = wr * (c1 + t1)
            g2 = wr * (c2 + t2)
        else:
            g0 = wr * c0
            g1 = wr * c1
            g2 = wr * c2
        if j < f1:
            out[j, 0] -= g0
            out[j, 1] -= g1
            out[j, 2] -= g2
        else:
            halo[j - f1, 0] -= g0
            halo[j - f1, 1] -= g1
            halo[j - f1, 2] -= g2
    out[i, 0] += f0
    out[i, 1] += f1_
    out[i, 2] += f2


@nb.njit(cache=True, error_model="numpy")
def _sweep_3d(g0, i0, i1, row_n, j_p, k_p, fwd_n, fwd_p, rev_p, reach_n, tab, uni, vol_n, x0_nc, y_nc,
              tc_n, T_ckk, intact_b, check, mask, u_r3, A_r9, Q_r9, out_nc, halo_h3):
    """3D :func:`_sweep_2d` (ring buffers ``u_r3`` (R, 3), ``A_r9``, ``Q_r9`` (R, 9))."""
    halo_h3[:, :] = 0.0
    f1 = np.uint64(i1)
    z = g0
    r = g0
    for i in range(i0, i1):
        while r <= reach_n[i]:
            m = reach_n[r]
            while z <= m:
                zz = np.uint64(z) & mask
                for c in range(3):
                    u_r3[zz, c] = y_nc[z, c] - x0_nc[z, c]
                for c in range(9):
                    A_r9[zz, c] = 0.0
                z += 1
            _grad_row_3d(r, mask, row_n, j_p, k_p, tab, vol_n, uni, u_r3, A_r9)
            _stress_row_3d(r, mask, tc_n, T_ckk, A_r9, Q_r9)
            r += 1
        _force_row_3d(i, mask, row_n, j_p, k_p, fwd_n, fwd_p, rev_p, tab, vol_n, uni, u_r3, Q_r9,
                      intact_b, check, out_nc, halo_h3, f1)


@nb.njit(parallel=True, cache=True, error_model="numpy")
def tipd_surface_3d(row_n, j_p, k_p, fwd_n, fwd_p, rev_p, reach_n, chunk_t, span, tab, uni, vol_n,
                    x0_nc, y_nc, tc_n, T_ckk, intact_b, check, mask, u_tr3, A_tr9, Q_tr9, halo_th3,
                    out_nc):
    """3D :func:`tipd_surface_2d` (``u_tr3`` (T, R, 3), ``A_tr9``, ``Q_tr9`` (T, R, 9),
    ``halo_th3`` (T, span, 3))."""
    nt = chunk_t.shape[0] - 1
    n = row_n.shape[0] - 1
    for t in nb.prange(nt):
        i0 = chunk_t[t]
        _sweep_3d(max(0, i0 - span), i0, chunk_t[t + 1], row_n, j_p, k_p, fwd_n, fwd_p, rev_p, reach_n,
                  tab, uni, vol_n, x0_nc, y_nc, tc_n, T_ckk, intact_b, check, mask, u_tr3[t],
                  A_tr9[t], Q_tr9[t], out_nc, halo_th3[t])
    for t in range(nt - 1):
        i1 = chunk_t[t + 1]
        for h in range(min(halo_th3.shape[1], n - i1)):
            for c in range(3):
                out_nc[i1 + h, c] += halo_th3[t, h, c]
