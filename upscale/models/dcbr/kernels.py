"""numba kernels of the coarse tube: the Tersoff energy of each particle's mapped lattice.

The one Tersoff of the project: every scalar function (f_C, f_C', g, g', the lambda3
exponential, b_ij and its derivative) is :mod:`potentials.tersoff_kernels`' (LAMMPS
``pair_style tersoff``; J. Tersoff, PRB 37, 6991 (1988)), on one row ``P_f`` (24,) of its
parameter table (columns ``IDX_*``). What is here is the many-body driver over a small
patch of the tube and the chain rule of the discrete Cauchy-Born map (seed 004 eq. 5.13):

    E_i = 1/2 sum_j f_C(r_ij) [f_R(r_ij) + b_ij f_A(r_ij)]                  (site energy)
    rho' = lam_t R0 + sub d_rho,  s' = lam_t s + gam z + sub d_s,  z' = lam_z z + sub d_z,
    theta' = s' / (lam_t R0),  x = (rho' cos theta', rho' sin theta', z')  (cylindrical map)
    e(q) = (E_A0 + E_B0) / 2,   q = (lam_t, gam, lam_z, d_rho, d_s, d_z)   (energy per atom)
    W = sum_c N_c (e(C_c, delta_c) - e0),  C_c = S_c F_c^T F_c S_c,  M^T M = C (Cholesky)

(seed 004 eq. 5.15 with V_I = N_c). With a step cutoff (D = 0 in the table) f_C is 1 for
r < R and 0 from R on (``ters_fc``); the old second Tersoff of ``dcbr_kernels`` cut at
r > R + D with a 1e-5 Å sine switch instead, which differs only for distances within 2e-5 Å
of 2.1 Å.

Units: Å, eV. Suffixes: ``_p`` per patch atom, ``_n`` per particle, ``_c`` Cartesian.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from potentials import tersoff_kernels as tk

__all__ = ["site_energy_grad", "cell_energy_grad", "coarse_energy", "relax_cell_shift",
           "relax_shifts", "mapped_bond_lengths", "NPARAM"]

NPARAM = 6  # lam_t, gam, lam_z, d_rho, d_s, d_z


@njit(cache=True)
def site_energy_grad(pos_pc, i, cand, P_f, grad_pc, near, v, w):
    """Site energy E_i (eV) of atom ``i`` of ``pos_pc`` (P, 3); adds dE_i/dpos to
    ``grad_pc`` (mutated). ``cand``: candidate neighbours of i; ``near`` (n,) int64,
    ``v`` (n, 3), ``w`` (3, n): work arrays, n >= len(cand)."""
    m_ = P_f[tk.IDX_M]
    gam = P_f[tk.IDX_GAMMA]
    lam3 = P_f[tk.IDX_LAM3]
    h = P_f[tk.IDX_H]
    nn = P_f[tk.IDX_N]
    beta = P_f[tk.IDX_BETA]
    lam2 = P_f[tk.IDX_LAM2]
    B = P_f[tk.IDX_B]
    R = P_f[tk.IDX_R]
    D = P_f[tk.IDX_BIGD]
    lam1 = P_f[tk.IDX_LAM1]
    A = P_f[tk.IDX_A]
    csq, dsq, csq_dsq = P_f[tk.IDX_CSQ], P_f[tk.IDX_DSQ], P_f[tk.IDX_CSQ_DSQ]
    c1, c2, c3, c4 = P_f[tk.IDX_C1], P_f[tk.IDX_C2], P_f[tk.IDX_C3], P_f[tk.IDX_C4]
    l3c = P_f[tk.IDX_LAM3CUBE]
    rc2 = P_f[tk.IDX_CUTSQ]
    rr, fcs, dfcs = w[0], w[1], w[2]
    nc = 0
    for a in range(cand.shape[0]):
        j = cand[a]
        dx = pos_pc[j, 0] - pos_pc[i, 0]
        dy = pos_pc[j, 1] - pos_pc[i, 1]
        dz = pos_pc[j, 2] - pos_pc[i, 2]
        if dx * dx + dy * dy + dz * dz < rc2:
            r = math.sqrt(dx * dx + dy * dy + dz * dz)
            fc = tk.ters_fc(r, R, D)
            if fc == 0.0:
                continue
            near[nc] = j
            v[nc, 0], v[nc, 1], v[nc, 2] = dx, dy, dz
            rr[nc] = r
            fcs[nc] = fc
            dfcs[nc] = tk.ters_fc_d(r, R, D)
            nc += 1
    E = 0.0
    for a in range(nc):
        j = near[a]
        r = rr[a]
        zeta = 0.0
        for b in range(nc):
            if b != a:
                cs = (v[a, 0] * v[b, 0] + v[a, 1] * v[b, 1] + v[a, 2] * v[b, 2]) / (r * rr[b])
                zeta += (fcs[b] * tk.ters_gijk(cs, gam, csq, dsq, csq_dsq, h)
                         * tk.ters_exp(r, rr[b], m_, lam3, l3c)[0])
        fR = A * math.exp(-lam1 * r)
        fA = -B * math.exp(-lam2 * r)
        bij, dbdz = tk.ters_bij_and_d(zeta, beta, nn, c1, c2, c3, c4)
        E += 0.5 * fcs[a] * (fR + bij * fA)
        dVdr = 0.5 * (dfcs[a] * (fR + bij * fA) + fcs[a] * (-lam1 * fR - lam2 * bij * fA))
        for d in range(3):
            grad_pc[j, d] += dVdr * v[a, d] / r
            grad_pc[i, d] -= dVdr * v[a, d] / r
        dVdz = 0.5 * fcs[a] * fA * dbdz
        if dVdz == 0.0:
            continue
        rij0, rij1, rij2 = v[a, 0], v[a, 1], v[a, 2]
        for b in range(nc):
            if b == a:
                continue
            k = near[b]
            rik0, rik1, rik2 = v[b, 0], v[b, 1], v[b, 2]
            rk = rr[b]
            fck = fcs[b]
            cs = (rij0 * rik0 + rij1 * rik1 + rij2 * rik2) / (r * rk)
            g = tk.ters_gijk(cs, gam, csq, dsq, csq_dsq, h)
            dg = tk.ters_gijk_d(cs, gam, csq, dsq, h)
            ex, dex = tk.ters_exp(r, rk, m_, lam3, l3c)
            inv = 1.0 / (r * rk)
            aj = fck * g * dex / r              # d ex / d r_ij along r_ij
            ak = (dfcs[b] * g * ex - fck * g * dex) / rk
            bcos = fck * dg * ex
            cj = cs / (r * r)
            ck = cs / (rk * rk)
            gj0 = dVdz * (bcos * (rik0 * inv - cj * rij0) + aj * rij0)
            gj1 = dVdz * (bcos * (rik1 * inv - cj * rij1) + aj * rij1)
            gj2 = dVdz * (bcos * (rik2 * inv - cj * rij2) + aj * rij2)
            gk0 = dVdz * (bcos * (rij0 * inv - ck * rik0) + ak * rik0)
            gk1 = dVdz * (bcos * (rij1 * inv - ck * rik1) + ak * rik1)
            gk2 = dVdz * (bcos * (rij2 * inv - ck * rik2) + ak * rik2)
            grad_pc[j, 0] += gj0
            grad_pc[j, 1] += gj1
            grad_pc[j, 2] += gj2
            grad_pc[k, 0] += gk0
            grad_pc[k, 1] += gk1
            grad_pc[k, 2] += gk2
            grad_pc[i, 0] -= gj0 + gk0
            grad_pc[i, 1] -= gj1 + gk1
            grad_pc[i, 2] -= gj2 + gk2
    return E


@njit(cache=True)
def cell_energy_grad(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, P_f, out_g):
    """Energy per atom e(q) (eV) of the mapped patch; de/dq (6,) into ``out_g``."""
    n = max(candA.shape[0], candB.shape[0])
    P = s_p.shape[0]
    return cell_energy_grad_ws(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, P_f,
                               np.empty((P, 3)), np.empty((P, 3)), out_g,
                               np.empty(n, np.int64), np.empty((n, 3)), np.empty((3, n)),
                               np.empty((2, P)))


@njit(cache=True)
def cell_energy_grad_ws(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, P_f, pos, gpos, out_g,
                        near, v, w, trig):
    """:func:`cell_energy_grad` with work arrays: ``pos``, ``gpos`` (P, 3), those of
    :func:`site_energy_grad`, ``trig`` (2, P) (cos, sin of each mapped angle)."""
    lt, gm, lz, drho, ds, dz = q[0], q[1], q[2], q[3], q[4], q[5]
    rho0 = lt * R0
    P = s_p.shape[0]
    for a in range(P):
        rho = rho0 + sub_p[a] * drho
        th = (lt * s_p[a] + gm * z_p[a] + sub_p[a] * ds) / rho0
        trig[0, a] = math.cos(th)
        trig[1, a] = math.sin(th)
        pos[a, 0] = rho * trig[0, a]
        pos[a, 1] = rho * trig[1, a]
        pos[a, 2] = lz * z_p[a] + sub_p[a] * dz
        gpos[a, 0] = 0.0
        gpos[a, 1] = 0.0
        gpos[a, 2] = 0.0
    e = 0.5 * (site_energy_grad(pos, iA, candA, P_f, gpos, near, v, w)
               + site_energy_grad(pos, iB, candB, P_f, gpos, near, v, w))
    for k in range(NPARAM):
        out_g[k] = 0.0
    for a in range(P):
        rho = rho0 + sub_p[a] * drho
        sp = lt * s_p[a] + gm * z_p[a] + sub_p[a] * ds
        ct, st = trig[0, a], trig[1, a]
        gx, gy, gz = 0.5 * gpos[a, 0], 0.5 * gpos[a, 1], 0.5 * gpos[a, 2]
        g_rho = gx * ct + gy * st               # de/d rho'
        g_th = rho * (-gx * st + gy * ct)       # de/d theta'
        out_g[0] += g_rho * R0 + g_th * (s_p[a] / rho0 - sp / (lt * rho0))
        out_g[1] += g_th * z_p[a] / rho0
        out_g[2] += gz * z_p[a]
        out_g[3] += g_rho * sub_p[a]
        out_g[4] += g_th * sub_p[a] / rho0
        out_g[5] += gz * sub_p[a]
    return e


@njit(cache=True, inline="always")
def _metric(F_nck, S_nab, c, C):
    """C = S_c F_c^T F_c S_c (2, 2) into ``C`` (mutated)."""
    FtF00 = F_nck[c, 0, 0] ** 2 + F_nck[c, 1, 0] ** 2 + F_nck[c, 2, 0] ** 2
    FtF11 = F_nck[c, 0, 1] ** 2 + F_nck[c, 1, 1] ** 2 + F_nck[c, 2, 1] ** 2
    FtF01 = (F_nck[c, 0, 0] * F_nck[c, 0, 1] + F_nck[c, 1, 0] * F_nck[c, 1, 1]
             + F_nck[c, 2, 0] * F_nck[c, 2, 1])
    for a in range(2):
        for b in range(2):
            acc = 0.0
            for u in range(2):
                for t in range(2):
                    f = FtF00 if (u == 0 and t == 0) else (FtF11 if (u == 1 and t == 1)
                                                           else FtF01)
                    acc += S_nab[c, a, u] * f * S_nab[c, t, b]
            C[a, b] = acc


@njit(cache=True)
def coarse_energy(F_nck, S_nab, delta_nc, natoms_n, alive_n, s_p, z_p, sub_p, R0, iA, iB,
                  candA, candB, P_f, e0, P_out, gdelta_out, e_out, q_out):
    """W = sum_c N_c (e(C_c, delta_c) - e0) (eV) over the alive particles, and its
    derivatives (all outputs mutated).

    Parameters
    ----------
    F_nck : (N, 3, 2) surface maps (gain); S_nab (N, 2, 2) = (F0^T F0)^(-1/2).
    delta_nc : (N, 3) sublattice shifts (d_rho, d_s, d_z), Å.
    natoms_n : (N,) atoms each particle carries (weights N_c).
    P_out : (N, 3, 2) dW/dF (eV); gdelta_out (N, 3) dW/d delta (eV/Å);
    e_out : (N,) energy per atom e (eV); q_out (N, 6) lattice parameters q.

    de/dC from de/d(lam_t, gam, lam_z) through lam_t = sqrt(C11), gam = C12 / lam_t,
    lam_z = sqrt(C22 - C12^2 / C11); dW/dF = 2 N_c F S (de/dC) S.
    """
    N = F_nck.shape[0]
    P = s_p.shape[0]
    pos, gpos = np.empty((P, 3)), np.empty((P, 3))
    g, q = np.empty(NPARAM), np.empty(NPARAM)
    C, SDS = np.empty((2, 2)), np.empty((2, 2))
    nk = max(candA.shape[0], candB.shape[0])
    near, v, w = np.empty(nk, np.int64), np.empty((nk, 3)), np.empty((3, nk))
    trig = np.empty((2, P))
    Etot = 0.0
    for c in range(N):
        for i in range(3):
            P_out[c, i, 0] = 0.0
            P_out[c, i, 1] = 0.0
            gdelta_out[c, i] = 0.0
        for k in range(NPARAM):
            q_out[c, k] = 0.0
        if not alive_n[c]:
            e_out[c] = e0
            q_out[c, 0] = 1.0
            q_out[c, 2] = 1.0
            continue
        _metric(F_nck, S_nab, c, C)
        lt = math.sqrt(C[0, 0])
        gm = C[0, 1] / lt
        lz = math.sqrt(C[1, 1] - gm * gm)
        q[0], q[1], q[2] = lt, gm, lz
        q[3], q[4], q[5] = delta_nc[c, 0], delta_nc[c, 1], delta_nc[c, 2]
        e = cell_energy_grad_ws(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, P_f, pos, gpos,
                                g, near, v, w, trig)
        Nc = natoms_n[c]
        Etot += Nc * (e - e0)
        e_out[c] = e
        for k in range(NPARAM):
            q_out[c, k] = q[k]
        for k in range(3):
            gdelta_out[c, k] = Nc * g[3 + k]
        C11, C12 = C[0, 0], C[0, 1]
        d11 = (g[0] / (2 * lt) - g[1] * C12 / (2 * lt * C11)
               + g[2] * (C12 * C12 / (C11 * C11)) / (2 * lz))
        d12 = g[1] / lt - g[2] * C12 / (C11 * lz)
        d22 = g[2] / (2 * lz)
        for a in range(2):
            for b in range(2):
                acc = 0.0
                for u in range(2):
                    for t in range(2):
                        Dut = d11 if (u == 0 and t == 0) else (d22 if (u == 1 and t == 1)
                                                               else 0.5 * d12)
                        acc += S_nab[c, a, u] * Dut * S_nab[c, t, b]
                SDS[a, b] = acc
        for i in range(3):
            for a in range(2):
                P_out[c, i, a] = 2.0 * Nc * (F_nck[c, i, 0] * SDS[0, a]
                                             + F_nck[c, i, 1] * SDS[1, a])
    return Etot


@njit(cache=True)
def relax_cell_shift(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, P_f, gtol, max_iter):
    """Newton's method on the shift q[3:6] of one mapped lattice at fixed (lam_t, gam,
    lam_z) = q[0:3] (q mutated), the 3x3 Hessian by forward differences of de/d shift
    (step 1e-6 Å), step length limited to 0.02 Å per component. Returns True when
    max |de/d shift| <= ``gtol`` (eV/Å per atom); False also, the shift unchanged, where the
    Hessian is exactly singular (a lattice pulled apart in some direction, after failure)."""
    g0, g1 = np.empty(NPARAM), np.empty(NPARAM)
    H = np.empty((3, 3))
    qk = np.empty(NPARAM)
    hstep = 1e-6
    for _ in range(max_iter):
        cell_energy_grad(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, P_f, g0)
        if max(abs(g0[3]), abs(g0[4]), abs(g0[5])) <= gtol:
            return True
        for k in range(3):
            for t in range(NPARAM):
                qk[t] = q[t]
            qk[3 + k] += hstep
            cell_energy_grad(qk, s_p, z_p, sub_p, R0, iA, iB, candA, candB, P_f, g1)
            for t in range(3):
                H[t, k] = (g1[3 + t] - g0[3 + t]) / hstep
        Hs = 0.5 * (H + H.T)
        det = np.linalg.det(Hs)
        if not (np.isfinite(det) and det != 0.0):  # (a lattice stretched past its cutoffs
            return False  # in some direction: no Newton step; the shift is left as it is)
        step = np.linalg.solve(Hs, -g0[3:6])
        big = max(abs(step[0]), abs(step[1]), abs(step[2]))
        if big > 0.02:
            step *= 0.02 / big
        for t in range(3):
            q[3 + t] += step[t]
    return False


@njit(cache=True)
def relax_shifts(q_n, alive_n, s_p, z_p, sub_p, R0, iA, iB, candA, candB, P_f, gtol,
                 max_iter, delta_nc):
    """Each alive particle's shift relaxed at its own (lam_t, gam, lam_z) (``q_n`` (N, 6)
    as :func:`coarse_energy` left it, shifts the start), written to ``delta_nc`` (mutated).
    The shift energy is a sum of per-particle terms, each of its own shift alone (the gains
    fixed), so the relaxation is particle by particle. Returns the number of particles
    that did not reach ``gtol``."""
    bad = 0
    q = np.empty(NPARAM)
    for c in range(q_n.shape[0]):
        if not alive_n[c]:
            continue
        for k in range(NPARAM):
            q[k] = q_n[c, k]
        if not relax_cell_shift(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, P_f, gtol,
                                max_iter):
            bad += 1
        delta_nc[c, 0], delta_nc[c, 1], delta_nc[c, 2] = q[3], q[4], q[5]
    return bad


@njit(cache=True)
def mapped_bond_lengths(q_n, s_p, z_p, sub_p, R0, iA, bondsA):
    """Lengths (N, nb) of the bonds A0-bondsA[b] of each particle's mapped lattice, Å."""
    N = q_n.shape[0]
    nb = bondsA.shape[0]
    out = np.empty((N, nb))
    xa = np.empty(3)
    for c in range(N):
        lt, gm, lz, drho, ds, dz = q_n[c, 0], q_n[c, 1], q_n[c, 2], q_n[c, 3], q_n[c, 4], q_n[c, 5]
        rho0 = lt * R0
        for t in range(nb + 1):
            a = iA if t == 0 else bondsA[t - 1]
            rho = rho0 + sub_p[a] * drho
            th = (lt * s_p[a] + gm * z_p[a] + sub_p[a] * ds) / rho0
            x0, x1, x2 = rho * math.cos(th), rho * math.sin(th), lz * z_p[a] + sub_p[a] * dz
            if t == 0:
                xa[0], xa[1], xa[2] = x0, x1, x2
            else:
                out[c, t - 1] = math.sqrt((x0 - xa[0]) ** 2 + (x1 - xa[1]) ** 2 + (x2 - xa[2]) ** 2)
    return out
