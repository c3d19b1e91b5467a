"""numba kernels of the DCBR tube model: Tersoff site energies of a mapped lattice patch.

Tersoff in the LAMMPS form (``pair_style tersoff``; J. Tersoff, PRB 37, 6991 (1988)):

    E_i   = 1/2 sum_j f_C(r_ij) [f_R(r_ij) + b_ij f_A(r_ij)]
    f_R   = A exp(-lambda1 r),  f_A = -B exp(-lambda2 r)
    b_ij  = (1 + beta^n zeta_ij^n)^(-1/(2n))
    zeta  = sum_{k != i,j} f_C(r_ik) g(theta_ijk) exp[(lambda3 (r_ij - r_ik))^m]
    g     = gamma (1 + c^2/d^2 - c^2 / (d^2 + (h - cos theta)^2))
    f_C   = 1 (r < R-D), 1/2 - 1/2 sin(pi/2 (r-R)/D) (|r-R| <= D), 0 (r > R+D)

Parameter vector ``p`` (float64, 14): m, gamma, lambda3, c, d, h, n, beta, lambda2, B, R, D,
lambda1, A (the order of a LAMMPS ``.tersoff`` entry after the three element names).

The cylindrical map (see :mod:`upscale.models.dcbr`) places a patch of the tube's own
atoms, given by reference arc coordinate s = R0 theta, axial z and sublattice flag (0 = A,
1 = B), at

    rho' = lam_t R0 + sub d_rho,  s' = lam_t s + gam z + sub d_s,  z' = lam_z z + sub d_z,
    theta' = s' / (lam_t R0),     x = (rho' cos theta', rho' sin theta', z').

Array suffix convention: ``_p`` per patch atom, ``_n`` per coarse particle.
"""
from __future__ import annotations

import math

import numba
import numpy as np

NPARAM = 6  # lam_t, gam, lam_z, d_rho, d_s, d_z


@numba.njit(cache=True, inline="always")
def _fc(r, R, D):
    if r < R - D:
        return 1.0, 0.0
    if r > R + D:
        return 0.0, 0.0
    a = 0.5 * math.pi * (r - R) / D
    return 0.5 - 0.5 * math.sin(a), -0.25 * math.pi / D * math.cos(a)


@numba.njit(cache=True, inline="always")
def _exp_term(r, rk, m_, lam3):
    """exp[(lambda3 (r - rk))^m] (m = 3, else 1) and its derivative with respect to r; 1 and
    0 without an exponential when lambda3 = 0."""
    if lam3 == 0.0:
        return 1.0, 0.0
    if m_ == 3.0:
        return math.exp((lam3 * (r - rk)) ** 3), 3.0 * lam3 ** 3 * (r - rk) ** 2
    return math.exp(lam3 * (r - rk)), lam3


@numba.njit(cache=True)
def site_energy_grad(pos, i, cand, p, grad):
    """Site energy E_i of atom ``i`` (eV); adds dE_i/dpos to ``grad`` (P, 3).

    ``cand``: indices of candidate neighbours of i (within some radius > R + D). The
    neighbours inside the outer cutoff (usually the three bonded ones) are found first, with
    their distance, f_C and f_C' computed once for every bond and triplet that uses them;
    with lambda3 = 0 (the carbon entries of BNC.tersoff and SiC.tersoff) the exponential
    factor of zeta is 1 and is not evaluated.
    """
    n = cand.shape[0]
    return site_energy_grad_ws(pos, i, cand, p, grad, np.empty(n, np.int64),
                               np.empty((n, 3)), np.empty((3, n)))


@numba.njit(cache=True)
def site_energy_grad_ws(pos, i, cand, p, grad, near, v, w):
    """:func:`site_energy_grad` with its work arrays given (the caller's, reused over many
    sites): ``near`` (n,) int64, ``v`` (n, 3), ``w`` (3, n), n >= len(cand)."""
    m_, gam, lam3, c, d, h, nn, beta, lam2, B, R, D, lam1, A = (
        p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12], p[13])
    c2 = c * c
    d2 = d * d
    c2_d2 = c2 / d2
    rc2 = (R + D) * (R + D)
    E = 0.0
    nmax = cand.shape[0]
    rr = w[0]      # |r_ik|
    fcs = w[1]     # f_C(r_ik)
    dfcs = w[2]    # f_C'(r_ik)
    nc = 0
    for a in range(nmax):
        j = cand[a]
        dx = pos[j, 0] - pos[i, 0]
        dy = pos[j, 1] - pos[i, 1]
        dz = pos[j, 2] - pos[i, 2]
        if dx * dx + dy * dy + dz * dz < rc2:
            r = math.sqrt(dx * dx + dy * dy + dz * dz)
            if r >= R + D:
                continue
            near[nc] = j
            v[nc, 0] = dx
            v[nc, 1] = dy
            v[nc, 2] = dz
            rr[nc] = r
            fcs[nc], dfcs[nc] = _fc(r, R, D)
            nc += 1
    for a in range(nc):
        j = near[a]
        rij0 = v[a, 0]
        rij1 = v[a, 1]
        rij2 = v[a, 2]
        r = rr[a]
        fc = fcs[a]
        dfc = dfcs[a]
        # zeta
        zeta = 0.0
        for b in range(nc):
            if b == a:
                continue
            rk = rr[b]
            cs = (rij0 * v[b, 0] + rij1 * v[b, 1] + rij2 * v[b, 2]) / (r * rk)
            hc = h - cs
            g = gam * (1.0 + c2_d2 - c2 / (d2 + hc * hc))
            zeta += fcs[b] * g * _exp_term(r, rk, m_, lam3)[0]
        fR = A * math.exp(-lam1 * r)
        dfR = -lam1 * fR
        fA = -B * math.exp(-lam2 * r)
        dfA = -lam2 * fA
        if zeta > 0.0:
            tmp = (beta * zeta) ** nn
            bij = (1.0 + tmp) ** (-0.5 / nn)
            dbdz = -0.5 * bij / (1.0 + tmp) * tmp / zeta
        else:
            bij = 1.0
            dbdz = 0.0
        E += 0.5 * fc * (fR + bij * fA)
        dVdr = 0.5 * (dfc * (fR + bij * fA) + fc * (dfR + bij * dfA))
        grad[j, 0] += dVdr * rij0 / r
        grad[j, 1] += dVdr * rij1 / r
        grad[j, 2] += dVdr * rij2 / r
        grad[i, 0] -= dVdr * rij0 / r
        grad[i, 1] -= dVdr * rij1 / r
        grad[i, 2] -= dVdr * rij2 / r
        dVdz = 0.5 * fc * fA * dbdz
        if dVdz == 0.0:
            continue
        for b in range(nc):
            if b == a:
                continue
            k = near[b]
            rik0 = v[b, 0]
            rik1 = v[b, 1]
            rik2 = v[b, 2]
            rk = rr[b]
            fck = fcs[b]
            dfck = dfcs[b]
            cs = (rij0 * rik0 + rij1 * rik1 + rij2 * rik2) / (r * rk)
            hc = h - cs
            den = d2 + hc * hc
            g = gam * (1.0 + c2_d2 - c2 / den)
            dg = -2.0 * gam * c2 * hc / (den * den)
            ex, dex = _exp_term(r, rk, m_, lam3)
            # d(cos)/d r_ij and d(cos)/d r_ik (vectors)
            inv = 1.0 / (r * rk)
            dcj0 = rik0 * inv - cs * rij0 / (r * r)
            dcj1 = rik1 * inv - cs * rij1 / (r * r)
            dcj2 = rik2 * inv - cs * rij2 / (r * r)
            dck0 = rij0 * inv - cs * rik0 / (rk * rk)
            dck1 = rij1 * inv - cs * rik1 / (rk * rk)
            dck2 = rij2 * inv - cs * rik2 / (rk * rk)
            # term t = fck g ex(r - rk)
            aj = fck * g * ex * dex / r        # coefficient of r_ij vec from d ex / d r
            ak = (dfck * g * ex - fck * g * ex * dex) / rk
            bcos = fck * dg * ex
            gj0 = dVdz * (bcos * dcj0 + aj * rij0)
            gj1 = dVdz * (bcos * dcj1 + aj * rij1)
            gj2 = dVdz * (bcos * dcj2 + aj * rij2)
            gk0 = dVdz * (bcos * dck0 + ak * rik0)
            gk1 = dVdz * (bcos * dck1 + ak * rik1)
            gk2 = dVdz * (bcos * dck2 + ak * rik2)
            grad[j, 0] += gj0
            grad[j, 1] += gj1
            grad[j, 2] += gj2
            grad[k, 0] += gk0
            grad[k, 1] += gk1
            grad[k, 2] += gk2
            grad[i, 0] -= gj0 + gk0
            grad[i, 1] -= gj1 + gk1
            grad[i, 2] -= gj2 + gk2
    return E


@numba.njit(cache=True)
def cell_energy_grad(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, p, pos, gpos, out_g):
    """Energy per atom e = (E_A + E_B)/2 of the mapped patch and de/dq (6,) into ``out_g``.

    q = (lam_t, gam, lam_z, d_rho, d_s, d_z); ``pos``/``gpos`` are (P, 3) work arrays.
    """
    n = max(candA.shape[0], candB.shape[0])
    return cell_energy_grad_ws(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, p, pos, gpos,
                               out_g, np.empty(n, np.int64), np.empty((n, 3)),
                               np.empty((3, n)), np.empty((2, s_p.shape[0])))


@numba.njit(cache=True)
def cell_energy_grad_ws(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, p, pos, gpos, out_g,
                        near, v, w, trig):
    """:func:`cell_energy_grad` with the work arrays given: the site energies'
    (:func:`site_energy_grad_ws`, n >= the longer candidate list) and ``trig`` (2, P), the
    cosine and sine of each patch atom's angle, kept for the chain rule."""
    lt, gm, lz, drho, ds, dz = q[0], q[1], q[2], q[3], q[4], q[5]
    rho0 = lt * R0
    P = s_p.shape[0]
    for a in range(P):
        rho = rho0 + sub_p[a] * drho
        sp = lt * s_p[a] + gm * z_p[a] + sub_p[a] * ds
        th = sp / rho0
        trig[0, a] = math.cos(th)
        trig[1, a] = math.sin(th)
        pos[a, 0] = rho * trig[0, a]
        pos[a, 1] = rho * trig[1, a]
        pos[a, 2] = lz * z_p[a] + sub_p[a] * dz
        gpos[a, 0] = 0.0
        gpos[a, 1] = 0.0
        gpos[a, 2] = 0.0
    e = 0.5 * (site_energy_grad_ws(pos, iA, candA, p, gpos, near, v, w)
               + site_energy_grad_ws(pos, iB, candB, p, gpos, near, v, w))
    for k in range(NPARAM):
        out_g[k] = 0.0
    for a in range(P):
        rho = rho0 + sub_p[a] * drho
        sp = lt * s_p[a] + gm * z_p[a] + sub_p[a] * ds
        ct = trig[0, a]
        st = trig[1, a]
        gx = 0.5 * gpos[a, 0]
        gy = 0.5 * gpos[a, 1]
        gz = 0.5 * gpos[a, 2]
        g_rho = gx * ct + gy * st            # dE/d rho
        g_th = rho * (-gx * st + gy * ct)    # dE/d theta
        # theta = s'/(lt R0): d/d lt = s_p/(lt R0) - s'/(lt^2 R0)
        out_g[0] += g_rho * R0 + g_th * (s_p[a] / rho0 - sp / (lt * rho0))
        out_g[1] += g_th * z_p[a] / rho0
        out_g[2] += gz * z_p[a]
        out_g[3] += g_rho * sub_p[a]
        out_g[4] += g_th * sub_p[a] / rho0
        out_g[5] += gz * sub_p[a]
    return e


@numba.njit(cache=True)
def _chol_params(C):
    """(lam_t, gam, lam_z) of the upper-triangular M with M^T M = C (2x2, theta first)."""
    lt = math.sqrt(C[0, 0])
    gm = C[0, 1] / lt
    lz = math.sqrt(C[1, 1] - gm * gm)
    return lt, gm, lz


@numba.njit(cache=True)
def coarse_energy(F_nck, S_nab, delta_n, natoms_n, alive_n, s_p, z_p, sub_p, R0, iA, iB,
                  candA, candB, p, e0, P_out, gdelta_out, e_out, q_out):
    """Energy sum_c N_c (e(C_c, delta_c) - e0) of the coarse tube and its derivatives.

    F_nck (N,3,2): surface maps; S_nab (N,2,2): A0^-1/2 of the reference map (C = S F^T F S);
    delta_n (N,3): sublattice shifts; fills P_out = dW/dF (N,3,2), gdelta_out = dW/d delta,
    e_out (per-atom energy, eV), q_out (N,6) the lattice parameters. Returns the total (eV).
    """
    N = F_nck.shape[0]
    P = s_p.shape[0]
    Etot = 0.0
    pos = np.empty((P, 3))
    gpos = np.empty((P, 3))
    g = np.empty(NPARAM)
    q = np.empty(NPARAM)
    FtF = np.empty((2, 2))
    C = np.empty((2, 2))
    SDS = np.empty((2, 2))
    n_cand = max(candA.shape[0], candB.shape[0])
    wk_near = np.empty(n_cand, np.int64)
    wk_v = np.empty((n_cand, 3))
    wk_w = np.empty((3, n_cand))
    wk_trig = np.empty((2, P))
    for c in range(N):
        for i in range(3):
            P_out[c, i, 0] = 0.0
            P_out[c, i, 1] = 0.0
            gdelta_out[c, i] = 0.0
        if not alive_n[c]:
            e_out[c] = e0
            for k in range(NPARAM):
                q_out[c, k] = 0.0
            q_out[c, 0] = 1.0
            q_out[c, 2] = 1.0
            continue
        for a in range(2):
            for b in range(2):
                acc = 0.0
                for i in range(3):
                    acc += F_nck[c, i, a] * F_nck[c, i, b]
                FtF[a, b] = acc
        for a in range(2):  # C = S FtF S
            for b in range(2):
                acc = 0.0
                for u in range(2):
                    for v in range(2):
                        acc += S_nab[c, a, u] * FtF[u, v] * S_nab[c, v, b]
                C[a, b] = acc
        if not (C[0, 0] > 1e-6 and C[0, 0] * C[1, 1] - C[0, 1] * C[0, 1] > 1e-6 * C[0, 0]):
            # a collapsed map (lam_t or lam_z below 1e-3: atoms a thousandfold closer than in
            # the lattice, or C not positive definite): no lattice to evaluate; NaN, so that
            # the engine stops with its blow-up diagnosis, not a division by zero
            e_out[c] = np.nan
            for i in range(3):
                P_out[c, i, 0] = np.nan
                P_out[c, i, 1] = np.nan
                gdelta_out[c, i] = np.nan
            Etot = np.nan
            continue
        lt, gm, lz = _chol_params(C)
        q[0] = lt
        q[1] = gm
        q[2] = lz
        q[3] = delta_n[c, 0]
        q[4] = delta_n[c, 1]
        q[5] = delta_n[c, 2]
        e = cell_energy_grad_ws(q, s_p, z_p, sub_p, R0, iA, iB, candA, candB, p, pos, gpos, g,
                                wk_near, wk_v, wk_w, wk_trig)
        Nc = natoms_n[c]
        Etot += Nc * (e - e0)
        e_out[c] = e
        for k in range(NPARAM):
            q_out[c, k] = q[k]
        gdelta_out[c, 0] = Nc * g[3]
        gdelta_out[c, 1] = Nc * g[4]
        gdelta_out[c, 2] = Nc * g[5]
        # de/dC (symmetric D) from de/d(lt, gm, lz): lt = sqrt(C11), gm = C12/lt,
        # lz = sqrt(C22 - C12^2/C11)
        C11 = C[0, 0]
        C12 = C[0, 1]
        d11 = g[0] / (2 * lt) - g[1] * C12 / (2 * lt * C11) + g[2] * (C12 * C12 / (C11 * C11)) / (2 * lz)
        d12 = g[1] / lt - g[2] * C12 / (C11 * lz)
        d22 = g[2] / (2 * lz)
        D00, D01, D11 = d11, 0.5 * d12, d22
        for a in range(2):  # SDS = S D S
            for b in range(2):
                acc = 0.0
                for u in range(2):
                    for v in range(2):
                        Duv = D00 if (u == 0 and v == 0) else (D11 if (u == 1 and v == 1) else D01)
                        acc += S_nab[c, a, u] * Duv * S_nab[c, v, b]
                SDS[a, b] = acc
        for i in range(3):
            for a in range(2):
                acc = 0.0
                for b in range(2):
                    acc += F_nck[c, i, b] * SDS[b, a]
                P_out[c, i, a] = 2.0 * Nc * acc
    return Etot


@numba.njit(cache=True)
def mapped_bond_lengths(q_n, s_p, z_p, sub_p, R0, iA, bondsA):
    """Lengths (N, nb) of the bonds A0-bondsA[b] of each particle's mapped lattice (Å)."""
    N = q_n.shape[0]
    nb = bondsA.shape[0]
    out = np.empty((N, nb))
    for c in range(N):
        lt, gm, lz, drho, ds, dz = q_n[c, 0], q_n[c, 1], q_n[c, 2], q_n[c, 3], q_n[c, 4], q_n[c, 5]
        rho0 = lt * R0
        xa = np.empty(3)
        for t in range(nb + 1):
            a = iA if t == 0 else bondsA[t - 1]
            rho = rho0 + sub_p[a] * drho
            sp = lt * s_p[a] + gm * z_p[a] + sub_p[a] * ds
            th = sp / rho0
            x0 = rho * math.cos(th)
            x1 = rho * math.sin(th)
            x2 = lz * z_p[a] + sub_p[a] * dz
            if t == 0:
                xa[0], xa[1], xa[2] = x0, x1, x2
            else:
                out[c, t - 1] = math.sqrt((x0 - xa[0]) ** 2 + (x1 - xa[1]) ** 2 + (x2 - xa[2]) ** 2)
    return out


@numba.njit(cache=True)
def mapped_bonds(q_n, s_p, z_p, sub_p, R0, iA, candA, bondsA, p):
    """Lengths r (N, nb) in Å and bond orders b (N, nb) of the bonds A0-bondsA[b] of each
    particle's mapped lattice (the LAMMPS-form b_ij of the module docstring)."""
    m_, gam, lam3, c, d, h, nn, beta = p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]
    R, D = p[10], p[11]
    N = q_n.shape[0]
    nb = bondsA.shape[0]
    P = s_p.shape[0]
    r_out = np.empty((N, nb))
    b_out = np.empty((N, nb))
    pos = np.empty((P, 3))
    for cpart in range(N):
        lt, gm, lz, drho, ds, dz = (q_n[cpart, 0], q_n[cpart, 1], q_n[cpart, 2], q_n[cpart, 3],
                                    q_n[cpart, 4], q_n[cpart, 5])
        rho0 = lt * R0
        for a in range(P):
            rho = rho0 + sub_p[a] * drho
            sp = lt * s_p[a] + gm * z_p[a] + sub_p[a] * ds
            th = sp / rho0
            pos[a, 0] = rho * math.cos(th)
            pos[a, 1] = rho * math.sin(th)
            pos[a, 2] = lz * z_p[a] + sub_p[a] * dz
        for t in range(nb):
            j = bondsA[t]
            rij = pos[j] - pos[iA]
            r = math.sqrt(rij[0] ** 2 + rij[1] ** 2 + rij[2] ** 2)
            zeta = 0.0
            for bb in range(candA.shape[0]):
                k = candA[bb]
                if k == j:
                    continue
                rik = pos[k] - pos[iA]
                rk = math.sqrt(rik[0] ** 2 + rik[1] ** 2 + rik[2] ** 2)
                if rk >= R + D:
                    continue
                fck, _ = _fc(rk, R, D)
                cs = (rij[0] * rik[0] + rij[1] * rik[1] + rij[2] * rik[2]) / (r * rk)
                g = gam * (1.0 + c * c / (d * d) - c * c / (d * d + (h - cs) ** 2))
                arg = (lam3 * (r - rk)) ** 3 if m_ == 3.0 else lam3 * (r - rk)
                zeta += fck * g * math.exp(arg)
            r_out[cpart, t] = r
            b_out[cpart, t] = (1.0 + (beta * zeta) ** nn) ** (-0.5 / nn) if zeta > 0 else 1.0
    return r_out, b_out


@numba.njit(cache=True)
def _piece_grad(x, Lz, owner, img, cand_off, cand_idx, p, ext, gext, g):
    """dE/dx (n, 3) of a z-periodic piece: real atoms x (n, 3), image copies ext[e] =
    x[owner[e]] + img[e] * Lz e_z; site energies of the real atoms (ext[0:n] = x)."""
    n = x.shape[0]
    for e in range(ext.shape[0]):
        o = owner[e]
        ext[e, 0] = x[o, 0]
        ext[e, 1] = x[o, 1]
        ext[e, 2] = x[o, 2] + img[e] * Lz
        gext[e, 0] = 0.0
        gext[e, 1] = 0.0
        gext[e, 2] = 0.0
    E = 0.0
    for i in range(n):
        E += site_energy_grad(ext, i, cand_idx[cand_off[i]:cand_off[i + 1]], p, gext)
    for i in range(n):
        g[i, 0] = 0.0
        g[i, 1] = 0.0
        g[i, 2] = 0.0
    for e in range(ext.shape[0]):
        o = owner[e]
        g[o, 0] += gext[e, 0]
        g[o, 1] += gext[e, 1]
        g[o, 2] += gext[e, 2]
    return E


@numba.njit(cache=True)
def _sites_grad(x, Lz, owner, img, cand_off, cand_idx, p, sites, ext, gext, g):
    """Gradient (n, 3) of the sum of the site energies of ``sites`` only."""
    for e in range(ext.shape[0]):
        o = owner[e]
        ext[e, 0] = x[o, 0]
        ext[e, 1] = x[o, 1]
        ext[e, 2] = x[o, 2] + img[e] * Lz
        gext[e, 0] = 0.0
        gext[e, 1] = 0.0
        gext[e, 2] = 0.0
    for a in range(sites.shape[0]):
        i = sites[a]
        site_energy_grad(ext, i, cand_idx[cand_off[i]:cand_off[i + 1]], p, gext)
    for i in range(g.shape[0]):
        g[i, 0] = 0.0
        g[i, 1] = 0.0
        g[i, 2] = 0.0
    for e in range(ext.shape[0]):
        o = owner[e]
        g[o, 0] += gext[e, 0]
        g[o, 1] += gext[e, 1]
        g[o, 2] += gext[e, 2]


@numba.njit(cache=True)
def piece_hessian(x, Lz, owner, img, cand_off, cand_idx, p, h, dep_off, dep_idx):
    """Hessian (3n, 3n) of the periodic piece's energy by central differences of the
    analytic gradient (step h, Å), symmetrised. Perturbing atom i changes only the site
    energies dep_idx[dep_off[i]:dep_off[i+1]] (i itself and the sites that list i or one of
    its images as a candidate), so only those are differenced."""
    n = x.shape[0]
    ne = owner.shape[0]
    ext = np.empty((ne, 3))
    gext = np.empty((ne, 3))
    gp = np.empty((n, 3))
    gm = np.empty((n, 3))
    H = np.empty((3 * n, 3 * n))
    xx = x.copy()
    for i in range(n):
        sites = dep_idx[dep_off[i]:dep_off[i + 1]]
        for c in range(3):
            xx[i, c] = x[i, c] + h
            _sites_grad(xx, Lz, owner, img, cand_off, cand_idx, p, sites, ext, gext, gp)
            xx[i, c] = x[i, c] - h
            _sites_grad(xx, Lz, owner, img, cand_off, cand_idx, p, sites, ext, gext, gm)
            xx[i, c] = x[i, c]
            row = 3 * i + c
            for j in range(n):
                for d in range(3):
                    H[row, 3 * j + d] = (gp[j, d] - gm[j, d]) / (2 * h)
    for a in range(3 * n):
        for b in range(a + 1, 3 * n):
            s = 0.5 * (H[a, b] + H[b, a])
            H[a, b] = s
            H[b, a] = s
    return H
