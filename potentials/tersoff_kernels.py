"""Numba kernels of the Tersoff potential in the form of LAMMPS ``pair_style tersoff``.

    E = 1/2 sum_i sum_{j != i} V_ij,   V_ij = f_C(r_ij) [f_R(r_ij) + b_ij f_A(r_ij)]
    f_R = A exp(-lambda1 r),  f_A = -B exp(-lambda2 r)
    f_C = 1 (r < R - D),  1/2 - 1/2 sin(pi/2 (r - R)/D) (|r - R| <= D),  0 (r > R + D)
    b_ij = (1 + (beta zeta_ij)^n)^(-1/(2n))
    zeta_ij = sum_{k != i, j} f_C(r_ik) g(theta_ijk) exp[(lambda3 (r_ij - r_ik))^m]
    g(theta) = gamma (1 + c^2/d^2 - c^2 / (d^2 + (h - cos theta)^2))

Parameters of a triplet come from the file entry "i j k", the two-body ones (n, beta,
lambda2, B, lambda1, A and the cutoff of r_ij) from "i j j". Like LAMMPS, b_ij and its
derivative switch to asymptotic expansions when beta zeta leaves [c4, c1] (thresholds
c1 = (2n 1e-16)^(-1/n), c2 = (2n 1e-8)^(-1/n), c3 = 1/c2, c4 = 1/c1), the exponential of the
lambda3 term is clipped at |argument| > 69.0776, and a neighbour is inside the cutoff when
r^2 < (R + D)^2. A step cutoff (``D = 0``) is f_C = 1 for r < R, else 0.

Two-body terms are evaluated per directed bond, half each way. LAMMPS evaluates the
repulsive term once per pair with the "i j j" entry of whichever atom comes first by its
ID-parity rule; the two agree whenever "i j j" and "j i i" share A, lambda1, R and D (true
in the files shipped with LAMMPS), otherwise this is the average of the two.

Per-atom energies follow LAMMPS's ``compute pe/atom`` split: the energy of each directed
bond i -> j, (f_C f_R + b_ij f_C f_A) / 2, goes half to i and half to j.

Array suffixes: ``_n`` per atom, ``_b`` per bond of the CSR list, ``_c`` Cartesian, ``_s``
per entry of an atom's short neighbour list (scratch). The parameter table ``P_pf`` has one
row per file entry, columns given by the ``IDX_*`` constants below.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# columns of the parameter table (one row per "i j k" entry)
IDX_M, IDX_GAMMA, IDX_LAM3, IDX_C, IDX_D, IDX_H, IDX_N, IDX_BETA, IDX_LAM2, IDX_B, \
    IDX_R, IDX_BIGD, IDX_LAM1, IDX_A, IDX_CUT, IDX_CUTSQ, IDX_C1, IDX_C2, IDX_C3, IDX_C4, \
    IDX_CSQ, IDX_DSQ, IDX_CSQ_DSQ, IDX_LAM3CUBE = range(24)
N_COLUMNS = 24

_PI2 = math.pi / 2.0  # MY_PI2
_PI4 = math.pi / 4.0  # MY_PI4


def derived_columns(raw_p14: np.ndarray) -> np.ndarray:
    """The parameter table from the 14 numbers of each file entry.

    Parameters
    ----------
    raw_p14 : (n_entries, 14) float
        m, gamma, lambda3, c, d, h (cos theta0), n, beta, lambda2, B, R, D, lambda1, A.
    """
    raw = np.atleast_2d(np.asarray(raw_p14, dtype=float))
    P = np.zeros((len(raw), N_COLUMNS))
    P[:, :14] = raw
    for p in P:
        p[IDX_CUT] = p[IDX_R] + p[IDX_BIGD]
        p[IDX_CUTSQ] = p[IDX_CUT] * p[IDX_CUT]
        n = p[IDX_N]
        if n > 0:
            p[IDX_C1] = (2.0 * n * 1.0e-16) ** (-1.0 / n)
            p[IDX_C2] = (2.0 * n * 1.0e-8) ** (-1.0 / n)
            p[IDX_C3] = 1.0 / p[IDX_C2]
            p[IDX_C4] = 1.0 / p[IDX_C1]
        else:  # n = 0 only in entries whose two-body part is never used (b_ij unused)
            p[IDX_C1] = p[IDX_C2] = np.inf
            p[IDX_C3] = p[IDX_C4] = 0.0
        p[IDX_CSQ] = p[IDX_C] * p[IDX_C]
        p[IDX_DSQ] = p[IDX_D] * p[IDX_D]
        p[IDX_CSQ_DSQ] = p[IDX_CSQ] / p[IDX_DSQ] if p[IDX_DSQ] > 0 else 0.0
        p[IDX_LAM3CUBE] = p[IDX_LAM3] ** 3
    return P


# -- the scalar functions -------------------------------------------------------------------
@njit(cache=True, inline="always")
def ters_fc(r, R, D):
    if r < R - D:
        return 1.0
    if r >= R + D:
        return 0.0
    return 0.5 * (1.0 - math.sin(_PI2 * (r - R) / D))


@njit(cache=True, inline="always")
def ters_fc_d(r, R, D):
    if r < R - D:
        return 0.0
    if r >= R + D:
        return 0.0
    return -(_PI4 / D) * math.cos(_PI2 * (r - R) / D)


@njit(cache=True, inline="always")
def ters_bij(zeta, beta, n, c1, c2, c3, c4):
    tmp = beta * zeta
    if tmp > c1:
        return 1.0 / math.sqrt(tmp)
    if tmp > c2:
        return (1.0 - tmp ** (-n) / (2.0 * n)) / math.sqrt(tmp)
    if tmp < c4:
        return 1.0
    if tmp < c3:
        return 1.0 - tmp ** n / (2.0 * n)
    return (1.0 + tmp ** n) ** (-1.0 / (2.0 * n))


@njit(cache=True, inline="always")
def ters_bij_d(zeta, beta, n, c1, c2, c3, c4):
    tmp = beta * zeta
    if tmp > c1:
        return beta * -0.5 * tmp ** -1.5
    if tmp > c2:
        return beta * (-0.5 * tmp ** -1.5 * (1.0 - (1.0 + 1.0 / (2.0 * n)) * tmp ** (-n)))
    if tmp < c4:
        return 0.0
    if tmp < c3:
        return -0.5 * beta * tmp ** (n - 1.0)
    tmp_n = tmp ** n
    return -0.5 * (1.0 + tmp_n) ** (-1.0 - 1.0 / (2.0 * n)) * tmp_n / zeta


@njit(cache=True, inline="always")
def ters_bij_and_d(zeta, beta, n, c1, c2, c3, c4):
    """``(ters_bij(...), ters_bij_d(...))`` with the same branches, the power of ``beta zeta``
    shared between the two. In the central branch the derivative reuses b_ij,

        d b_ij / d zeta = -1/2 b_ij (beta zeta)^n / ((1 + (beta zeta)^n) zeta),

    one ``pow`` instead of two (LAMMPS evaluates ``(1 + t^n)^(-1 - 1/(2n))`` separately); the
    value agrees with :func:`ters_bij_d` to round-off. ``pow`` is most of the kernel's
    library time (about 14 ns a call here, against 6 ns for ``exp``)."""
    tmp = beta * zeta
    if tmp > c1:
        return 1.0 / math.sqrt(tmp), beta * -0.5 * tmp ** -1.5
    if tmp > c2:
        tmp_mn = tmp ** (-n)
        return ((1.0 - tmp_mn / (2.0 * n)) / math.sqrt(tmp),
                beta * (-0.5 * tmp ** -1.5 * (1.0 - (1.0 + 1.0 / (2.0 * n)) * tmp_mn)))
    if tmp < c4:
        return 1.0, 0.0
    if tmp < c3:
        return 1.0 - tmp ** n / (2.0 * n), -0.5 * beta * tmp ** (n - 1.0)
    tmp_n = tmp ** n
    bij = (1.0 + tmp_n) ** (-1.0 / (2.0 * n))
    return bij, -0.5 * bij * tmp_n / ((1.0 + tmp_n) * zeta)


@njit(cache=True, inline="always")
def ters_gijk(costheta, gamma, csq, dsq, csq_dsq, h):
    hcth = h - costheta
    return gamma * (1.0 + csq_dsq - csq / (dsq + hcth * hcth))


@njit(cache=True, inline="always")
def ters_gijk_d(costheta, gamma, csq, dsq, h):
    hcth = h - costheta
    den = 1.0 / (dsq + hcth * hcth)
    return gamma * (-2.0 * csq * hcth) * den * den


@njit(cache=True, inline="always")
def ters_exp(rij, rik, m, lam3, lam3cube):
    """exp[(lambda3 (rij - rik))^m] and its derivative with respect to rij."""
    if lam3 == 0.0:
        return 1.0, 0.0
    dr = rij - rik
    if m == 3.0:
        t = lam3 * dr
        arg = t * t * t
    else:
        arg = lam3 * dr
    if arg > 69.0776:
        ex = 1.0e30
    elif arg < -69.0776:
        ex = 0.0
    else:
        ex = math.exp(arg)
    if m == 3.0:
        return ex, 3.0 * lam3cube * dr * dr * ex
    return ex, lam3 * ex


# -- the driver -----------------------------------------------------------------------------
@njit(cache=True)
def tersoff_range(lo, hi, x_nc, cell, first_n, j_b, shift_bc, type_n, e2p, P, cutmaxsq,
                  f_nc, e_n, W_cc):
    """Add the energy, forces, per-atom energies and virial of atoms lo..hi-1 (their
    bonds and triplets) into f_nc, e_n, W_cc. Returns the energy.

    ``P``: the parameter table (:attr:`potentials.tersoff.Tersoff.table`), ``e2p`` the
    element-triplet to row map (:attr:`potentials.tersoff.Tersoff.e2p`), ``type_n`` (N,)
    element indices, ``cutmaxsq`` the largest squared cutoff; the neighbour list is the
    full CSR list of :func:`potentials.neighbours.neighbour_list`."""
    maxn = 0
    for i in range(lo, hi):
        maxn = max(maxn, first_n[i + 1] - first_n[i])
    idx_s = np.empty(maxn, np.int64)
    t_s = np.empty(maxn, np.int64)
    d_sc = np.empty((maxn, 3))
    rsq_s = np.empty(maxn)
    r_s = np.empty(maxn)
    rinv_s = np.empty(maxn)
    # per-k values of the current (i, j): f_C, f_C', g, g', exp term, its derivative, cos
    ok_s = np.empty(maxn, np.bool_)
    fc_s = np.empty(maxn)
    dfc_s = np.empty(maxn)
    g_s = np.empty(maxn)
    gd_s = np.empty(maxn)
    ex_s = np.empty(maxn)
    exd_s = np.empty(maxn)
    cos_s = np.empty(maxn)
    energy = 0.0
    w00 = w01 = w02 = w10 = w11 = w12 = w20 = w21 = w22 = 0.0
    for i in range(lo, hi):
        ti = type_n[i]
        # short list: neighbours within the largest cutoff
        ns = 0
        for b in range(first_n[i], first_n[i + 1]):
            j = j_b[b]
            s0 = shift_bc[b, 0]
            s1 = shift_bc[b, 1]
            s2 = shift_bc[b, 2]
            dx = x_nc[j, 0] - x_nc[i, 0] + s0 * cell[0, 0] + s1 * cell[1, 0] + s2 * cell[2, 0]
            dy = x_nc[j, 1] - x_nc[i, 1] + s0 * cell[0, 1] + s1 * cell[1, 1] + s2 * cell[2, 1]
            dz = x_nc[j, 2] - x_nc[i, 2] + s0 * cell[0, 2] + s1 * cell[1, 2] + s2 * cell[2, 2]
            rsq = dx * dx + dy * dy + dz * dz
            if rsq < cutmaxsq:
                idx_s[ns] = j
                t_s[ns] = type_n[j]
                d_sc[ns, 0] = dx
                d_sc[ns, 1] = dy
                d_sc[ns, 2] = dz
                rsq_s[ns] = rsq
                r = math.sqrt(rsq)
                r_s[ns] = r
                rinv_s[ns] = 1.0 / r
                ns += 1
        fix = fiy = fiz = 0.0
        ei = 0.0
        for jj in range(ns):
            tj = t_s[jj]
            pij = e2p[ti, tj, tj]
            if rsq_s[jj] >= P[pij, IDX_CUTSQ]:
                continue
            j = idx_s[jj]
            rij = r_s[jj]
            rijinv = rinv_s[jj]
            dx1 = d_sc[jj, 0]
            dy1 = d_sc[jj, 1]
            dz1 = d_sc[jj, 2]
            hx1 = dx1 * rijinv
            hy1 = dy1 * rijinv
            hz1 = dz1 * rijinv
            # zeta_ij, keeping the per-k pieces for the derivative pass
            zeta = 0.0
            for kk in range(ns):
                if kk == jj:
                    ok_s[kk] = False
                    continue
                pijk = e2p[ti, tj, t_s[kk]]
                if rsq_s[kk] >= P[pijk, IDX_CUTSQ]:
                    ok_s[kk] = False
                    continue
                ok_s[kk] = True
                rik = r_s[kk]
                cs = (dx1 * d_sc[kk, 0] + dy1 * d_sc[kk, 1] + dz1 * d_sc[kk, 2]) \
                    * rijinv * rinv_s[kk]
                R = P[pijk, IDX_R]
                D = P[pijk, IDX_BIGD]
                fc = ters_fc(rik, R, D)
                gamma = P[pijk, IDX_GAMMA]
                h = P[pijk, IDX_H]
                g = ters_gijk(cs, gamma, P[pijk, IDX_CSQ], P[pijk, IDX_DSQ],
                              P[pijk, IDX_CSQ_DSQ], h)
                ex, exd = ters_exp(rij, rik, P[pijk, IDX_M], P[pijk, IDX_LAM3],
                                   P[pijk, IDX_LAM3CUBE])
                zeta += fc * g * ex
                fc_s[kk] = fc
                dfc_s[kk] = ters_fc_d(rik, R, D)
                g_s[kk] = g
                gd_s[kk] = ters_gijk_d(cs, gamma, P[pijk, IDX_CSQ], P[pijk, IDX_DSQ], h)
                ex_s[kk] = ex
                exd_s[kk] = exd
                cos_s[kk] = cs
            # two-body parts of the directed bond i -> j
            R = P[pij, IDX_R]
            D = P[pij, IDX_BIGD]
            fc = ters_fc(rij, R, D)
            fcd = ters_fc_d(rij, R, D)
            A = P[pij, IDX_A]
            lam1 = P[pij, IDX_LAM1]
            erep = math.exp(-lam1 * rij)
            # dE/dr of 1/2 f_C f_R (each pair is visited from both ends)
            dedr = 0.5 * A * erep * (fcd - fc * lam1)
            e_bond = 0.5 * fc * A * erep
            if fc != 0.0:
                B = P[pij, IDX_B]
                lam2 = P[pij, IDX_LAM2]
                eatt = math.exp(-lam2 * rij)
                fa = -B * eatt * fc
                fa_d = B * eatt * (lam2 * fc - fcd)
                beta = P[pij, IDX_BETA]
                n = P[pij, IDX_N]
                c1 = P[pij, IDX_C1]
                c2 = P[pij, IDX_C2]
                c3 = P[pij, IDX_C3]
                c4 = P[pij, IDX_C4]
                bij, bij_d = ters_bij_and_d(zeta, beta, n, c1, c2, c3, c4)
                dedr += 0.5 * bij * fa_d
                e_bond += 0.5 * bij * fa
                prefactor = -0.5 * fa * bij_d
            else:
                prefactor = 0.0
            energy += e_bond
            ei += 0.5 * e_bond
            e_n[j] += 0.5 * e_bond
            # pair force: on j along -r_ij hat times dE/dr, on i the opposite
            fjx = -dedr * hx1
            fjy = -dedr * hy1
            fjz = -dedr * hz1
            w00 += dx1 * fjx
            w01 += dx1 * fjy
            w02 += dx1 * fjz
            w10 += dy1 * fjx
            w11 += dy1 * fjy
            w12 += dy1 * fjz
            w20 += dz1 * fjx
            w21 += dz1 * fjy
            w22 += dz1 * fjz
            fix -= fjx
            fiy -= fjy
            fiz -= fjz
            if prefactor != 0.0:
                # three-body forces from d zeta_ij / d x_j and d x_k
                gx = gy = gz = 0.0  # force on j
                for kk in range(ns):
                    if not ok_s[kk]:
                        continue
                    rikinv = rinv_s[kk]
                    hx2 = d_sc[kk, 0] * rikinv
                    hy2 = d_sc[kk, 1] * rikinv
                    hz2 = d_sc[kk, 2] * rikinv
                    cs = cos_s[kk]
                    fck = fc_s[kk]
                    a_cos = prefactor * fck * gd_s[kk] * ex_s[kk]
                    a_exp = prefactor * fck * g_s[kk] * exd_s[kk]
                    a_fc = prefactor * dfc_s[kk] * g_s[kk] * ex_s[kk]
                    # d cos / d x_j = (rik_hat - cos rij_hat) / rij, likewise for k
                    t1 = a_cos * rijinv
                    fjx3 = t1 * (hx2 - cs * hx1) + a_exp * hx1
                    fjy3 = t1 * (hy2 - cs * hy1) + a_exp * hy1
                    fjz3 = t1 * (hz2 - cs * hz1) + a_exp * hz1
                    t2 = a_cos * rikinv
                    t3 = a_fc - a_exp
                    fkx = t2 * (hx1 - cs * hx2) + t3 * hx2
                    fky = t2 * (hy1 - cs * hy2) + t3 * hy2
                    fkz = t2 * (hz1 - cs * hz2) + t3 * hz2
                    k = idx_s[kk]
                    f_nc[k, 0] += fkx
                    f_nc[k, 1] += fky
                    f_nc[k, 2] += fkz
                    gx += fjx3
                    gy += fjy3
                    gz += fjz3
                    fix -= fjx3 + fkx
                    fiy -= fjy3 + fky
                    fiz -= fjz3 + fkz
                    dx2 = d_sc[kk, 0]
                    dy2 = d_sc[kk, 1]
                    dz2 = d_sc[kk, 2]
                    w00 += dx2 * fkx
                    w01 += dx2 * fky
                    w02 += dx2 * fkz
                    w10 += dy2 * fkx
                    w11 += dy2 * fky
                    w12 += dy2 * fkz
                    w20 += dz2 * fkx
                    w21 += dz2 * fky
                    w22 += dz2 * fkz
                fjx += gx
                fjy += gy
                fjz += gz
                w00 += dx1 * gx
                w01 += dx1 * gy
                w02 += dx1 * gz
                w10 += dy1 * gx
                w11 += dy1 * gy
                w12 += dy1 * gz
                w20 += dz1 * gx
                w21 += dz1 * gy
                w22 += dz1 * gz
            f_nc[j, 0] += fjx
            f_nc[j, 1] += fjy
            f_nc[j, 2] += fjz
        f_nc[i, 0] += fix
        f_nc[i, 1] += fiy
        f_nc[i, 2] += fiz
        e_n[i] += ei
    W_cc[0, 0] += w00
    W_cc[0, 1] += w01
    W_cc[0, 2] += w02
    W_cc[1, 0] += w10
    W_cc[1, 1] += w11
    W_cc[1, 2] += w12
    W_cc[2, 0] += w20
    W_cc[2, 1] += w21
    W_cc[2, 2] += w22
    return energy


@njit(parallel=True, cache=True)
def tersoff(x_nc, cell, first_n, j_b, shift_bc, type_n, e2p, P, cutmax, nchunks):
    """Energy, per-atom energies, forces and virial of the Tersoff potential.

    Parameters
    ----------
    x_nc : (N, 3) float, positions (Angstrom), as given to the neighbour list
    cell : (3, 3) float, cell vectors as rows (Angstrom)
    first_n, j_b, shift_bc : full CSR neighbour list, see :mod:`potentials.neighbours`
    type_n : (N,) int64, element index of each atom (into ``e2p``)
    e2p : (nel, nel, nel) int64, row of ``P`` for the triplet (i, j, k)
    P : (n_entries, N_COLUMNS) float, see :func:`derived_columns`
    cutmax : float, the largest cutoff R + D in ``P`` (Angstrom)
    nchunks : int, number of independent slices of atoms (1 for serial); each writes to
        its own buffers, summed at the end (no races)

    Returns
    -------
    energy : float (eV); e_n : (N,) eV; f_nc : (N, 3) eV/Angstrom; W_cc : (3, 3) virial
    (eV), ``W = sum over terms of r (x) f``, LAMMPS's sign (pressure = W / V).
    """
    n = x_nc.shape[0]
    nchunks = max(1, min(nchunks, n))
    f_tnc = np.zeros((nchunks, n, 3))
    e_tn = np.zeros((nchunks, n))
    W_tcc = np.zeros((nchunks, 3, 3))
    en_t = np.zeros(nchunks)
    cutmaxsq = cutmax * cutmax
    for t in prange(nchunks):
        lo = t * n // nchunks
        hi = (t + 1) * n // nchunks
        en_t[t] = tersoff_range(lo, hi, x_nc, cell, first_n, j_b, shift_bc, type_n, e2p, P,
                         cutmaxsq, f_tnc[t], e_tn[t], W_tcc[t])
    if nchunks == 1:
        return en_t[0], e_tn[0], f_tnc[0], W_tcc[0]
    f_nc = np.zeros((n, 3))
    e_n = np.zeros(n)
    for i in prange(n):
        for t in range(nchunks):
            f_nc[i, 0] += f_tnc[t, i, 0]
            f_nc[i, 1] += f_tnc[t, i, 1]
            f_nc[i, 2] += f_tnc[t, i, 2]
            e_n[i] += e_tn[t, i]
    W_cc = np.zeros((3, 3))
    for t in range(nchunks):
        W_cc += W_tcc[t]
    return en_t.sum(), e_n, f_nc, W_cc
