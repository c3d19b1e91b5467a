"""Numba kernels of the Brenner 1990 (REBO-I) carbon potential.

Array suffixes: ``_n`` per atom, ``_b`` per bond (a directed CSR entry i -> j of a full
neighbour list, see :mod:`potentials.neighbours`), ``_c`` Cartesian component.

The energy is written as a sum over directed bonds b = (i -> j),

    E = sum_b e_b,   e_b = 1/2 [V_R(r_b) - (B_b + F_b / 2) V_A(r_b)],

which equals Brenner's sum over pairs of ``V_R - Bbar_ij V_A`` with
``Bbar_ij = (B_ij + B_ji + F_ij) / 2`` because V_R, V_A and F_ij are symmetric in i, j.
``e_b`` is booked on atom i (per-atom energies). Every term is a function of bond vectors
only, so the kernel accumulates ``g_bc = dE/dr_b`` per bond, each atom writing only its
own rows (race-free ``prange`` over atoms); forces follow from ``g`` and the reverse-bond
index, and the virial is ``W = -sum_b r_b (x) g_b`` (LAMMPS convention, see
:mod:`potentials.calculator`).

The conjugation term F(N_i, N_j, N_conj) depends on atom-level sums (coordinations N and
the sums S_i = sum_{k} f_ik F(x_ik) entering N_conj); their adjoints ``lamN_n``, ``lamS_n``
are collected per atom, using the i <-> j symmetry of F so that each atom again writes only
its own entries, and then propagated back to the bonds.
"""
from __future__ import annotations

import contextlib
import math

import numba
import numpy as np
from numba import njit, prange

__all__ = ["threads_for", "reverse_bonds", "brenner_energy_forces", "conj_switch", "tricubic_hermite",
           "P_D", "P_S", "P_BETA", "P_RE", "P_DELTA", "P_A0", "P_C0", "P_D0", "P_R1", "P_R2",
           "N_PARAMS"]

@contextlib.contextmanager
def threads_for(n_items: int, per_thread: int = 2000):
    """Run numba parallel kernels on at most ``n_items // per_thread`` threads (at least 1).

    Small systems run faster on one thread: the launch and join of a parallel region costs
    more than the work, badly so on a loaded machine (tens of ms instead of < 1 ms).
    """
    old = numba.get_num_threads()
    numba.set_num_threads(max(1, min(old, int(n_items) // per_thread)))
    try:
        yield
    finally:
        numba.set_num_threads(old)


# layout of the parameter vector handed to the kernel
P_D, P_S, P_BETA, P_RE, P_DELTA, P_A0, P_C0, P_D0, P_R1, P_R2 = range(10)
N_PARAMS = 10


@njit(parallel=True, cache=True)
def reverse_bonds(first_n, j_b, shift_bc):
    """Index of the reverse bond j -> i (image ``-shift``) of every bond, -1 if absent."""
    n = first_n.shape[0] - 1
    rev_b = np.full(j_b.shape[0], -1, np.int64)
    for i in prange(n):
        for b in range(first_n[i], first_n[i + 1]):
            j = j_b[b]
            for q in range(first_n[j], first_n[j + 1]):
                if (j_b[q] == i and shift_bc[q, 0] == -shift_bc[b, 0]
                        and shift_bc[q, 1] == -shift_bc[b, 1]
                        and shift_bc[q, 2] == -shift_bc[b, 2]):
                    rev_b[b] = q
                    break
    return rev_b


@njit(cache=True, inline="always")
def _cutoff(r, R1, R2, step):
    """Brenner's f(r) and df/dr; with ``step`` a plain step at R2."""
    if r >= R2:
        return 0.0, 0.0
    if step or r <= R1:
        return 1.0, 0.0
    t = math.pi / (R2 - R1)
    a = t * (r - R1)
    return 0.5 * (1.0 + math.cos(a)), -0.5 * t * math.sin(a)


@njit(cache=True, inline="always")
def conj_switch(x):
    """Brenner's F(x) of the conjugation number and its derivative: 1 for x <= 2,
    [1 + cos(pi (x - 2))]/2 for 2 < x < 3, 0 for x >= 3."""
    if x <= 2.0:
        return 1.0, 0.0
    if x >= 3.0:
        return 0.0, 0.0
    a = math.pi * (x - 2.0)
    return 0.5 * (1.0 + math.cos(a)), -0.5 * math.pi * math.sin(a)


@njit(cache=True, inline="always")
def _h(t):
    """Cubic Hermite basis at t in [0, 1]: values and derivatives of
    (value at 0, value at 1, slope at 0, slope at 1)."""
    t2 = t * t
    t3 = t2 * t
    H0 = 1.0 - 3.0 * t2 + 2.0 * t3
    H1 = 3.0 * t2 - 2.0 * t3
    D0 = t - 2.0 * t2 + t3
    D1 = t3 - t2
    dH0 = -6.0 * t + 6.0 * t2
    dH1 = 6.0 * t - 6.0 * t2
    dD0 = 1.0 - 4.0 * t + 3.0 * t2
    dD1 = 3.0 * t2 - 2.0 * t
    return H0, H1, D0, D1, dH0, dH1, dD0, dD1


@njit(cache=True)
def tricubic_hermite(x, y, z, v_xyz, vx_xyz, vy_xyz):
    """Tricubic Hermite interpolation of a table on the integer nodes x, y in 0..3,
    z in 1..2 (index 0..1), from node values and first derivatives along x and y (the
    derivative along z and all mixed derivatives are zero at the nodes).

    Arguments outside the table are clamped with zero derivative. Returns
    (F, dF/dx, dF/dy, dF/dz).
    """
    cx = 1.0
    cy = 1.0
    cz = 1.0
    if x <= 0.0:
        x = 0.0
        cx = 0.0
    elif x >= 3.0:
        x = 3.0
        cx = 0.0
    if y <= 0.0:
        y = 0.0
        cy = 0.0
    elif y >= 3.0:
        y = 3.0
        cy = 0.0
    z = z - 1.0
    if z <= 0.0:
        z = 0.0
        cz = 0.0
    elif z >= 1.0:
        z = 1.0
        cz = 0.0
    ix = min(int(x), 2)
    iy = min(int(y), 2)
    tx = x - ix
    ty = y - iy
    hx = _h(tx)
    hy = _h(ty)
    hz = _h(z)
    F = 0.0
    Fx = 0.0
    Fy = 0.0
    Fz = 0.0
    for a in range(2):
        Hx = hx[a]
        Dx = hx[2 + a]
        dHx = hx[4 + a]
        dDx = hx[6 + a]
        for b in range(2):
            Hy = hy[b]
            Dy = hy[2 + b]
            dHy = hy[4 + b]
            dDy = hy[6 + b]
            for c in range(2):
                Hz = hz[c]
                dHz = hz[4 + c]
                v = v_xyz[ix + a, iy + b, c]
                vx = vx_xyz[ix + a, iy + b, c]
                vy = vy_xyz[ix + a, iy + b, c]
                F += (v * Hx * Hy + vx * Dx * Hy + vy * Hx * Dy) * Hz
                Fx += (v * dHx * Hy + vx * dDx * Hy + vy * dHx * Dy) * Hz
                Fy += (v * Hx * dHy + vx * Dx * dHy + vy * Hx * dDy) * Hz
                Fz += (v * Hx * Hy + vx * Dx * Hy + vy * Hx * Dy) * dHz
    return F, Fx * cx, Fy * cy, Fz * cz


@njit(parallel=True, cache=True)
def brenner_energy_forces(x_nc, cell, first_n, j_b, shift_bc, rev_b, p, F_v, F_dx, F_dy,
                          step, conj):
    """Energy, per-atom energies, forces and virial of Brenner 1990 carbon.

    Parameters
    ----------
    x_nc : (N, 3) float, positions (Angstrom)
    cell : (3, 3) float, rows are cell vectors (Angstrom)
    first_n, j_b, shift_bc : full CSR neighbour list (``potentials.neighbours``)
    rev_b : (M,) int, reverse bond index (:func:`reverse_bonds`)
    p : (N_PARAMS,) float, parameters in the order ``P_D ... P_R2``
    F_v, F_dx, F_dy : (4, 4, 2) float, conjugation table F(N_i, N_j, N_conj - 1) and its
        tabulated derivatives along N_i, N_j
    step : bool, replace the switching cutoff by a step at R2
    conj : bool, include the conjugation term F

    Returns
    -------
    energy : float (eV); energies_n : (N,) (eV); forces_nc : (N, 3) (eV/Angstrom);
    virial_cc : (3, 3) (eV), ``W = -sum_b r_b (x) dE/dr_b``
    """
    n = first_n.shape[0] - 1
    m = j_b.shape[0]
    De = p[P_D]
    S = p[P_S]
    beta = p[P_BETA]
    re = p[P_RE]
    delta = p[P_DELTA]
    a0 = p[P_A0]
    c2 = p[P_C0] * p[P_C0]
    d2 = p[P_D0] * p[P_D0]
    R1 = p[P_R1]
    R2 = p[P_R2]
    l1 = math.sqrt(2.0 * S) * beta
    l2 = math.sqrt(2.0 / S) * beta
    AR = De / (S - 1.0)
    AA = De * S / (S - 1.0)

    r_bc = np.empty((m, 3))
    r_b = np.empty(m)
    u_bc = np.empty((m, 3))
    f_b = np.empty(m)
    df_b = np.empty(m)
    N_n = np.zeros(n)
    # pass 1: geometry, cutoff function, coordination
    for i in prange(n):
        Ni = 0.0
        for b in range(first_n[i], first_n[i + 1]):
            j = j_b[b]
            rr = 0.0
            for c in range(3):
                d = (x_nc[j, c] - x_nc[i, c] + shift_bc[b, 0] * cell[0, c]
                     + shift_bc[b, 1] * cell[1, c] + shift_bc[b, 2] * cell[2, c])
                r_bc[b, c] = d
                rr += d * d
            r = math.sqrt(rr)
            r_b[b] = r
            for c in range(3):
                u_bc[b, c] = r_bc[b, c] / r
            f, df = _cutoff(r, R1, R2, step)
            f_b[b] = f
            df_b[b] = df
            Ni += f
        N_n[i] = Ni

    # pass 2: S_i = sum_k f_ik F(N_k - f_ik)
    S_n = np.zeros(n)
    if conj:
        for i in prange(n):
            s = 0.0
            for b in range(first_n[i], first_n[i + 1]):
                if r_b[b] >= R2:
                    continue
                Fx, _ = conj_switch(N_n[j_b[b]] - f_b[b])
                s += f_b[b] * Fx
            S_n[i] = s

    # pass 3: energy and the bond-local derivatives
    e_n = np.zeros(n)
    gr_b = np.zeros(m)  # dE/dr at fixed f, N, S
    gf_b = np.zeros(m)  # dE/df (explicit)
    g_bc = np.zeros((m, 3))  # dE/dr_bc (angular part so far)
    lamN_n = np.zeros(n)
    lamS_n = np.zeros(n)
    for i in prange(n):
        ei = 0.0
        lamN = 0.0
        lamS = 0.0
        for b in range(first_n[i], first_n[i + 1]):
            rb = r_b[b]
            if rb >= R2:
                continue
            f = f_b[b]
            zeta = 0.0
            for q in range(first_n[i], first_n[i + 1]):
                if q == b or r_b[q] >= R2:
                    continue
                cs = u_bc[b, 0] * u_bc[q, 0] + u_bc[b, 1] * u_bc[q, 1] + u_bc[b, 2] * u_bc[q, 2]
                h = 1.0 + cs
                zeta += a0 * (1.0 + c2 / d2 - c2 / (d2 + h * h)) * f_b[q]
            B = (1.0 + zeta) ** (-delta)
            Fb = 0.0
            F1 = 0.0
            F2 = 0.0
            F3 = 0.0
            Nie = 0.0
            Nje = 0.0
            if conj:
                j = j_b[b]
                Nie = N_n[i] - f
                Nje = N_n[j] - f
                sxi, _ = conj_switch(Nie)
                sxj, _ = conj_switch(Nje)
                Nc = 1.0 + S_n[i] - f * sxj + S_n[j] - f * sxi
                Fb, F1, F2, F3 = tricubic_hermite(Nie, Nje, Nc, F_v, F_dx, F_dy)
            vr = AR * math.exp(-l1 * (rb - re))
            va = AA * math.exp(-l2 * (rb - re))
            Bt = B + 0.5 * Fb
            ei += 0.5 * f * (vr - Bt * va)
            gr_b[b] += 0.5 * f * (-l1 * vr + Bt * l2 * va)
            gf_b[b] += 0.5 * (vr - Bt * va)
            VA = f * va
            Cz = 0.5 * VA * delta * B / (1.0 + zeta)  # dE/dzeta
            if Cz != 0.0:
                for q in range(first_n[i], first_n[i + 1]):
                    if q == b or r_b[q] >= R2:
                        continue
                    cs = (u_bc[b, 0] * u_bc[q, 0] + u_bc[b, 1] * u_bc[q, 1]
                          + u_bc[b, 2] * u_bc[q, 2])
                    h = 1.0 + cs
                    den = d2 + h * h
                    G = a0 * (1.0 + c2 / d2 - c2 / den)
                    dG = a0 * 2.0 * c2 * h / (den * den)
                    gf_b[q] += Cz * G
                    coef = Cz * dG * f_b[q]
                    cb = coef / rb
                    cq = coef / r_b[q]
                    for c in range(3):
                        g_bc[b, c] += cb * (u_bc[q, c] - cs * u_bc[b, c])
                        g_bc[q, c] += cq * (u_bc[b, c] - cs * u_bc[q, c])
            if conj:
                w = -0.25 * VA  # dE/dF_b
                sxi, dsxi = conj_switch(Nie)
                sxj, dsxj = conj_switch(Nje)
                # F of the pair enters through b and its reverse bond: both have the same
                # w, so the pair's derivative with respect to N_i and S_i is 2 w (...)
                lamN += 2.0 * w * (F1 - F3 * f * dsxi)
                lamS += 2.0 * w * F3
                gf_b[b] += w * (-F1 - F2 + F3 * (-sxj + f * dsxj - sxi + f * dsxi))
        e_n[i] = ei
        lamN_n[i] = lamN
        lamS_n[i] = lamS

    # pass 4: S_i = sum_b f_b F(N_j - f_b) back to the bonds and to N
    if conj:
        for i in prange(n):
            add = 0.0
            for b in range(first_n[i], first_n[i + 1]):
                if r_b[b] >= R2:
                    continue
                j = j_b[b]
                f = f_b[b]
                sx, dsx = conj_switch(N_n[j] - f)
                gf_b[b] += lamS_n[i] * (sx - f * dsx)
                # the reverse bond's term f F(N_i - f) sits in S_j
                _, dsr = conj_switch(N_n[i] - f)
                add += lamS_n[j] * f * dsr
            lamN_n[i] += add

    # pass 5: N_i = sum_b f_b; radial derivative of every bond
    for i in prange(n):
        for b in range(first_n[i], first_n[i + 1]):
            if r_b[b] >= R2:
                continue
            gtot = gr_b[b] + (gf_b[b] + lamN_n[i]) * df_b[b]
            for c in range(3):
                g_bc[b, c] += gtot * u_bc[b, c]

    # pass 6: forces and virial
    F_nc = np.zeros((n, 3))
    W_ncc = np.zeros((n, 3, 3))
    for a in prange(n):
        for b in range(first_n[a], first_n[a + 1]):
            q = rev_b[b]
            for c in range(3):
                gq = g_bc[q, c] if q >= 0 else 0.0
                F_nc[a, c] += g_bc[b, c] - gq
                for d in range(3):
                    W_ncc[a, c, d] -= r_bc[b, c] * g_bc[b, d]
    energy = 0.0
    for i in range(n):
        energy += e_n[i]
    W = np.zeros((3, 3))
    for a in range(n):
        for c in range(3):
            for d in range(3):
                W[c, d] += W_ncc[a, c, d]
    return energy, e_n, F_nc, W
