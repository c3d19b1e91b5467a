"""numba kernels of the unified gain-matrix model (:mod:`upscale.models.unified`).

Flat arrays: ``_n`` per particle, ``_b`` per directed bond (CSR rows ``offsets``,
``neighbors``, ``reverse_b`` the reverse bond), ``_c`` / ``_k`` Cartesian components of
the body's dimension ``dim``. Forces in N per particle, stresses in Pa, energies in J.

The residual is one fused kernel (:func:`residual_kernel`): the quasi-static solvers call
it once per Newton iteration and once per matrix-free tangent product, so deformation
gradient, stress, body force and bond penalty share two passes over the bonds instead of
four kernels with their intermediate arrays.
"""
from __future__ import annotations

import numba
import numpy as np

__all__ = ["deformation_kernel", "stress_kernel", "residual_kernel", "residual_2d", "failure_index_kernel",
           "normal_index_kernel", "two_hop_pattern", "tangent_kernel"]


@numba.njit(cache=True, inline="always")
def _green_pk2(F, C4, dim, E, S):
    """One particle's Green strain E = (F^T F - I) / 2 (6.24) and PK2 stress S = C : E
    (6.23) into ``E``, ``S`` (dim, dim); returns S : E (twice the energy density, 6.26)."""
    for a in range(dim):
        for b in range(dim):
            s = 0.0
            for k in range(dim):
                s += F[k, a] * F[k, b]
            E[a, b] = 0.5 * (s - (1.0 if a == b else 0.0))
    w = 0.0
    for a in range(dim):
        for b in range(dim):
            s = 0.0
            for k in range(dim):
                for m in range(dim):
                    s += C4[a, b, k, m] * E[k, m]
            S[a, b] = s
            w += s * E[a, b]
    return w


@numba.njit(parallel=True, cache=True)
def deformation_kernel(y_nc, offsets, neighbors, coef_bk, dim, F_nij):
    """F_c = sum_b (y_j - y_c) (x) a_b (eq. 6.19 with G = F - I); mutates ``F_nij``."""
    n = offsets.shape[0] - 1
    for c in numba.prange(n):
        for i in range(dim):
            for a in range(dim):
                F_nij[c, i, a] = 0.0
        for b in range(offsets[c], offsets[c + 1]):
            j = neighbors[b]
            for i in range(dim):
                d = y_nc[j, i] - y_nc[c, i]
                for a in range(dim):
                    F_nij[c, i, a] += d * coef_bk[b, a]
    return F_nij


@numba.njit(parallel=True, cache=True)
def stress_kernel(F_nij, C4, alive_n, printed, dim, E_nij, S_nij, P_nij, W_n):
    """Green strain (6.24), PK2 stress S = C:E (6.23), energy density W = S:E/2 (6.26) and
    the force stress P (F S, or S F^T for the printed 6.22); dead particles get zeros."""
    n = F_nij.shape[0]
    for c in numba.prange(n):
        for i in range(dim):
            for a in range(dim):
                E_nij[c, i, a] = 0.0
                S_nij[c, i, a] = 0.0
                P_nij[c, i, a] = 0.0
        W_n[c] = 0.0
        if not alive_n[c]:
            continue
        W_n[c] = 0.5 * _green_pk2(F_nij[c], C4, dim, E_nij[c], S_nij[c])
        for i in range(dim):
            for a in range(dim):
                s = 0.0
                for k in range(dim):
                    if printed:
                        s += S_nij[c, i, k] * F_nij[c, a, k]
                    else:
                        s += F_nij[c, i, k] * S_nij[c, k, a]
                P_nij[c, i, a] = s
    return W_n


@numba.njit(parallel=True, cache=True)
def residual_kernel(y_nc, offsets, neighbors, reverse_b, coef_bk, xi_bc, w_b, ok_b, kv_n, C4, alive_n,
                    volume_n, printed, dim, F_nij, E_nij, B_nij, own_nk, g_bk, out_nc):
    """Adds the internal force of the gain model and its bond penalty to ``out_nc`` (N, 3)
    and returns the stored energy sum_c V_c W_c + U_s (J).

    Pass 1, per particle c: F_c = sum_b (y_j - y_c) (x) a_b, E_c = (F^T F - I)/2,
    S_c = C : E_c, P_c = F S (``printed``: S F^T), zero for dead particles; the penalty
    z_b = (y_j - y_c) - F_c xi_b, g_b = kv_c w_b z_b (bonds with ``ok_b``),
    Q_c = sum_b g_b (x) xi_b; kept: B_c = V_c P_c - Q_c, own_c = V_c P_c sum_b a_b.
    Pass 2, per particle i (its own row only: no races):

        f_i = own_i + sum_{b in row i} [ -B_j a_b' + g_b - g_b' ],

    which is sum_b [V_i P_i a_b - V_j P_j a_b'] (the body force) plus sum_b [g_b - g_b' +
    Q_j a_b'] (the penalty's). Work arrays: ``F_nij``, ``E_nij``, ``B_nij`` (N, dim, dim),
    ``own_nk`` (N, dim), ``g_bk`` (nb, dim); on return ``F_nij`` holds F."""
    n = offsets.shape[0] - 1
    en = np.zeros(n)
    for c in numba.prange(n):
        lo, hi = offsets[c], offsets[c + 1]
        for i in range(dim):
            own_nk[c, i] = 0.0
            for a in range(dim):
                F_nij[c, i, a] = 0.0
        for b in range(lo, hi):
            j = neighbors[b]
            for i in range(dim):
                d = y_nc[j, i] - y_nc[c, i]
                for a in range(dim):
                    F_nij[c, i, a] += d * coef_bk[b, a]
        for i in range(dim):
            for a in range(dim):
                B_nij[c, i, a] = 0.0
        if alive_n[c]:
            w = _green_pk2(F_nij[c], C4, dim, E_nij[c], B_nij[c])  # B: S for now
            en[c] = 0.5 * w * volume_n[c]
            for a in range(dim):                 # E_nij[c] <- S, B_nij[c] <- V P
                for b2 in range(dim):
                    E_nij[c, a, b2] = B_nij[c, a, b2]
            for i in range(dim):
                for a in range(dim):
                    s = 0.0
                    for k in range(dim):
                        if printed:
                            s += E_nij[c, i, k] * F_nij[c, a, k]
                        else:
                            s += F_nij[c, i, k] * E_nij[c, k, a]
                    B_nij[c, i, a] = volume_n[c] * s
            for b in range(lo, hi):
                for a in range(dim):
                    for i in range(dim):
                        own_nk[c, i] += B_nij[c, i, a] * coef_bk[b, a]
        kv = kv_n[c]
        for b in range(lo, hi):
            for i in range(dim):
                g_bk[b, i] = 0.0
            if kv == 0.0 or not ok_b[b]:
                continue
            j = neighbors[b]
            for i in range(dim):
                z = y_nc[j, i] - y_nc[c, i]
                for a in range(dim):
                    z -= F_nij[c, i, a] * xi_bc[b, a]
                g = kv * w_b[b] * z
                g_bk[b, i] = g
                en[c] += 0.5 * g * z
                for a in range(dim):
                    B_nij[c, i, a] -= g * xi_bc[b, a]
    for i in numba.prange(n):
        for k in range(dim):
            s = own_nk[i, k]
            for b in range(offsets[i], offsets[i + 1]):
                j = neighbors[b]
                r = reverse_b[b]
                s += g_bk[b, k] - g_bk[r, k]
                for a in range(dim):
                    s -= B_nij[j, k, a] * coef_bk[r, a]
            out_nc[i, k] += s
    return en.sum()


@numba.njit(parallel=True, cache=True)
def residual_2d(y_nc, offsets, neighbors, reverse_b, coef_bk, xi_bc, w_b, ok_b, kv_n, C4, alive_n,
                volume_n, printed, B_n4, own_n2, g_b2, out_nc):
    """:func:`residual_kernel` for ``dim = 2`` in scalars (the SCB's hot loop): the same
    two passes, with B_c = V_c P_c - Q_c flat (N, 4) in the order 00, 01, 10, 11 and
    own_c (N, 2); C4 is symmetric in (k, m). Returns the energy (J)."""
    n = offsets.shape[0] - 1
    e = 0.0
    for c in numba.prange(n):
        lo, hi = offsets[c], offsets[c + 1]
        yc0 = y_nc[c, 0]; yc1 = y_nc[c, 1]
        f00 = 0.0; f01 = 0.0; f10 = 0.0; f11 = 0.0; sa0 = 0.0; sa1 = 0.0
        for b in range(lo, hi):
            j = neighbors[b]
            d0 = y_nc[j, 0] - yc0; d1 = y_nc[j, 1] - yc1
            a0 = coef_bk[b, 0]; a1 = coef_bk[b, 1]
            f00 += d0 * a0; f01 += d0 * a1; f10 += d1 * a0; f11 += d1 * a1
            sa0 += a0; sa1 += a1
        p00 = 0.0; p01 = 0.0; p10 = 0.0; p11 = 0.0
        if alive_n[c]:
            e00 = 0.5 * (f00 * f00 + f10 * f10 - 1.0)
            e11 = 0.5 * (f01 * f01 + f11 * f11 - 1.0)
            e01 = 0.5 * (f00 * f01 + f10 * f11)
            s00 = C4[0, 0, 0, 0] * e00 + C4[0, 0, 1, 1] * e11 + 2.0 * C4[0, 0, 0, 1] * e01
            s11 = C4[1, 1, 0, 0] * e00 + C4[1, 1, 1, 1] * e11 + 2.0 * C4[1, 1, 0, 1] * e01
            s01 = C4[0, 1, 0, 0] * e00 + C4[0, 1, 1, 1] * e11 + 2.0 * C4[0, 1, 0, 1] * e01
            e += 0.5 * volume_n[c] * (s00 * e00 + s11 * e11 + 2.0 * s01 * e01)
            v = volume_n[c]
            if printed:
                p00 = v * (s00 * f00 + s01 * f01); p01 = v * (s00 * f10 + s01 * f11)
                p10 = v * (s01 * f00 + s11 * f01); p11 = v * (s01 * f10 + s11 * f11)
            else:
                p00 = v * (f00 * s00 + f01 * s01); p01 = v * (f00 * s01 + f01 * s11)
                p10 = v * (f10 * s00 + f11 * s01); p11 = v * (f10 * s01 + f11 * s11)
        own_n2[c, 0] = p00 * sa0 + p01 * sa1
        own_n2[c, 1] = p10 * sa0 + p11 * sa1
        kv = kv_n[c]
        for b in range(lo, hi):
            g_b2[b, 0] = 0.0; g_b2[b, 1] = 0.0
            if kv == 0.0 or not ok_b[b]:
                continue
            j = neighbors[b]
            x0 = xi_bc[b, 0]; x1 = xi_bc[b, 1]
            z0 = y_nc[j, 0] - yc0 - f00 * x0 - f01 * x1
            z1 = y_nc[j, 1] - yc1 - f10 * x0 - f11 * x1
            k = kv * w_b[b]
            g0 = k * z0; g1 = k * z1
            g_b2[b, 0] = g0; g_b2[b, 1] = g1
            e += 0.5 * (g0 * z0 + g1 * z1)
            p00 -= g0 * x0; p01 -= g0 * x1; p10 -= g1 * x0; p11 -= g1 * x1
        B_n4[c, 0] = p00; B_n4[c, 1] = p01; B_n4[c, 2] = p10; B_n4[c, 3] = p11
    for i in numba.prange(n):
        s0 = own_n2[i, 0]; s1 = own_n2[i, 1]
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            r = reverse_b[b]
            a0 = coef_bk[r, 0]; a1 = coef_bk[r, 1]
            s0 += g_b2[b, 0] - g_b2[r, 0] - B_n4[j, 0] * a0 - B_n4[j, 1] * a1
            s1 += g_b2[b, 1] - g_b2[r, 1] - B_n4[j, 2] * a0 - B_n4[j, 3] * a1
        out_nc[i, 0] += s0
        out_nc[i, 1] += s1
    return e


@numba.njit(parallel=True, cache=True)
def failure_index_kernel(y_nc, x_nc, offsets, neighbors, W_n, intact_b, no_fail_n, factor, out_b):
    """Failure index G_b / G_c = factor (e_c + e_n) per directed bond, 0 for broken bonds,
    bonds in compression and bonds touching ``no_fail``; ``factor = 2 r_s / (3 pi G_c)``."""
    n = offsets.shape[0] - 1
    for c in numba.prange(n):
        for b in range(offsets[c], offsets[c + 1]):
            j = neighbors[b]
            out_b[b] = 0.0
            if not intact_b[b] or no_fail_n[c] or no_fail_n[j]:
                continue
            l2 = 0.0
            l02 = 0.0
            for k in range(3):
                d = y_nc[j, k] - y_nc[c, k]
                d0 = x_nc[j, k] - x_nc[c, k]
                l2 += d * d
                l02 += d0 * d0
            if l2 <= l02:
                continue
            out_b[b] = factor * (W_n[c] + W_n[j])
    return out_b


@numba.njit(parallel=True, cache=True)
def normal_index_kernel(xi_bc, offsets, neighbors, Sbar_nij, intact_b, no_fail_n, dim, inv_sc, out_b):
    """Failure index (s_b / sigma_c)^2 per directed bond, s_b = n_b . (S_bar_c + S_bar_j)/2 .
    n_b the averaged stress resolved on the unit reference bond vector n_b; 0 for broken
    bonds, bonds in compression (s_b <= 0) and bonds touching ``no_fail``;
    ``inv_sc = 1 / sigma_c`` (1/Pa)."""
    n = offsets.shape[0] - 1
    for c in numba.prange(n):
        for b in range(offsets[c], offsets[c + 1]):
            j = neighbors[b]
            out_b[b] = 0.0
            if not intact_b[b] or no_fail_n[c] or no_fail_n[j]:
                continue
            l2 = 0.0
            for k in range(dim):
                l2 += xi_bc[b, k] * xi_bc[b, k]
            sn = 0.0
            for k in range(dim):
                for m in range(dim):
                    sn += xi_bc[b, k] * 0.5 * (Sbar_nij[c, k, m] + Sbar_nij[j, k, m]) * xi_bc[b, m]
            sn /= l2
            if sn <= 0.0:
                continue
            sn *= inv_sc
            out_b[b] = sn * sn
    return out_b


@numba.njit(cache=True)
def two_hop_pattern(offsets, neighbors, n):
    """Particles coupled by the tangent: for each p every q in {c} + H_c of some
    c in {p} + H_p (families symmetric). Returns (ptr (n+1,), q sorted per row) int64."""
    mark = np.full(n, -1, np.int64)
    ptr = np.zeros(n + 1, np.int64)
    for rnd in range(2):
        q_p = np.empty(ptr[n] if rnd else 0, np.int64)
        mark[:] = -1
        for p in range(n):
            k = 0
            for t in range(offsets[p], offsets[p + 1] + 1):
                c = p if t == offsets[p + 1] else neighbors[t]
                for u in range(offsets[c], offsets[c + 1] + 1):
                    q = c if u == offsets[c + 1] else neighbors[u]
                    if mark[q] != p:
                        mark[q] = p
                        if rnd:
                            q_p[ptr[p] + k] = q
                        k += 1
            if rnd:
                q_p[ptr[p]:ptr[p] + k] = np.sort(q_p[ptr[p]:ptr[p] + k])
            else:
                ptr[p + 1] = ptr[p] + k
    return ptr, q_p


@numba.njit(cache=True)
def tangent_kernel(F_nij, S_nij, C4, alive_n, volume_n, offsets, neighbors, coef_bk, xi_bc, w_b, ok_b, kv_n,
                   ptr, q_p, dim, parts, data):
    """Adds the contributions of the particles ``parts`` to K = -dF_int/dy to the CSR values
    ``data`` of the pattern of :func:`two_hop_pattern` (row 3p + i, i < dim, holds columns
    3q + k, q in ``q_p[ptr[p]:ptr[p+1]]``, k < dim).

    Per particle c with members m_0 = c, m_1+t = the neighbour of its t-th bond:
    the gain part V_c g_P . dP/dF . g_Q with dF_c/dy_P = g_P (g_1+t = a_b,
    g_0 = -sum_b a_b) and dP_ia/dF_jb = delta_ij S_ab + F_ic C_cakb F_jk (energy form);
    the penalty part delta_ik kv_c sum_b w_b e_bP e_bQ over the bonds b of c with
    ``ok_b``, z_b = sum_P e_bP y_P (e_b,1+t(b) = 1, e_b0 = -1, and -(a_b' . xi_b) at
    1 + t(b'), +(a_b' . xi_b) at 0). Serial: the members of different particles overlap."""
    n = offsets.shape[0] - 1
    A = np.zeros((dim, dim, dim, dim))
    for c in parts:
        base = offsets[c]
        M = offsets[c + 1] - base + 1
        g = np.zeros((M, dim))
        for t in range(M - 1):
            for a in range(dim):
                g[1 + t, a] = coef_bk[base + t, a]
                g[0, a] -= coef_bk[base + t, a]
        A[:] = 0.0
        if alive_n[c]:
            for i in range(dim):
                for a in range(dim):
                    for j in range(dim):
                        for b in range(dim):
                            s = S_nij[c, a, b] if i == j else 0.0
                            for cc in range(dim):
                                for k in range(dim):
                                    s += F_nij[c, i, cc] * C4[cc, a, k, b] * F_nij[c, j, k]
                            A[i, a, j, b] = volume_n[c] * s
        T = np.zeros((M, dim, dim, dim))
        for P in range(M):
            for i in range(dim):
                for a in range(dim):
                    if g[P, a] == 0.0:
                        continue
                    for j in range(dim):
                        for b in range(dim):
                            T[P, i, j, b] += g[P, a] * A[i, a, j, b]
        H = np.zeros((M, M))
        if kv_n[c] > 0.0 and M > 1:
            # z_b = sum_t X[b, t] (y_t - y_c), X = I - (a_t . xi_b); over the neighbours
            # H = X^T diag(wt) X = diag(wt) - wt_Q (a_P . xi_Q) - wt_P (a_Q . xi_P) + a_P^T Mx a_Q,
            # wt_b = kv_c w_b ok_b, Mx = sum_b wt_b xi_b xi_b^T; the centre's row and column
            # are minus the row sums
            m1 = M - 1
            Mx = np.zeros((dim, dim))
            wt = np.zeros(m1)
            for t in range(m1):
                b = base + t
                if ok_b[b]:
                    wt[t] = kv_n[c] * w_b[b]
                    for a in range(dim):
                        for a2 in range(dim):
                            Mx[a, a2] += wt[t] * xi_bc[b, a] * xi_bc[b, a2]
            for P in range(m1):
                for Q in range(P, m1):
                    ax = 0.0
                    xa = 0.0
                    aMa = 0.0
                    for a in range(dim):
                        ax += coef_bk[base + P, a] * xi_bc[base + Q, a]
                        xa += coef_bk[base + Q, a] * xi_bc[base + P, a]
                        for a2 in range(dim):
                            aMa += coef_bk[base + P, a] * Mx[a, a2] * coef_bk[base + Q, a2]
                    h = aMa - wt[Q] * ax - wt[P] * xa
                    if P == Q:
                        h += wt[P]
                    H[1 + P, 1 + Q] = h
                    H[1 + Q, 1 + P] = h
            tot = 0.0
            for P in range(m1):
                rs = 0.0
                for Q in range(m1):
                    rs += H[1 + P, 1 + Q]
                H[1 + P, 0] = -rs
                H[0, 1 + P] = -rs
                tot += rs
            H[0, 0] = tot
        for P in range(M):
            p = c if P == 0 else neighbors[base + P - 1]
            lo0, hi0 = ptr[p], ptr[p + 1]
            rlen = hi0 - lo0
            for Q in range(M):
                q = c if Q == 0 else neighbors[base + Q - 1]
                lo, hi = lo0, hi0
                while lo < hi:
                    mid = (lo + hi) // 2
                    if q_p[mid] < q:
                        lo = mid + 1
                    else:
                        hi = mid
                s = lo - lo0
                for i in range(dim):
                    row0 = dim * dim * lo0 + i * dim * rlen + dim * s
                    for k in range(dim):
                        v = H[P, Q] if i == k else 0.0
                        for b in range(dim):
                            v += T[P, i, k, b] * g[Q, b]
                        data[row0 + k] += v
    return data
