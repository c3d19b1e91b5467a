"""Correspondence (non-ordinary state-based, NOSB) peridynamics with zero-energy-mode
stabilisation (seed 001; Silling et al., J. Elasticity 88 (2007) 151).

Array suffixes: ``_n`` per particle, ``_b`` per directed bond, ``_c`` Cartesian component.
With the bond weight ``w_b = omega(|xi|) V_j beta_ij`` of bond i->j (omega = 1 or
delta/|xi|), reference bond ``xi`` and current bond ``Y = y_j - y_i``::

    K_i = sum_j w xi (x) xi                       (shape tensor, fixed at prepare)
    F_i = (sum_j w Y (x) xi) K_i^-1               (deformation gradient)
    P_i = dPsi/dF (F_i)                           (first Piola-Kirchhoff stress, Pa)
    t_ij = omega P_i K_i^-1 xi_ij                 (force state)
    b_i  = sum_j (t_ij - t_ji) V_j = sum_j w (P_i K_i^-1 + P_j K_j^-1) xi_ij

Material laws (``law``): ``"linear"`` (geometrically linear: P = C : sym(F - I)),
``"svk"`` (Saint Venant-Kirchhoff: P = F (C : E), E = (F^T F - I)/2) and
``"neo-hookean"`` (isotropic, compressible: Psi = mu/2 (tr F^T F - d) - mu ln J +
lambda/2 (ln J)^2, P = mu (F - F^-T) + lambda ln J F^-T, with the Lame constants of C in
the body's dimension). Every law has an energy ``sum_i V_i Psi(F_i)`` whose negative
gradient is the force.

Zero-energy modes (seed 001 eq. (30)): any non-affine ``z_ij = Y - F_i xi`` with
``sum_j w z (x) xi = 0`` leaves F unchanged and costs no energy. Stabilisations
(``stabilisation``), both adding ``t_ij += omega B_i z_ij`` with an energy
``(1/2) sum_i V_i sum_j w z_ij . B_i z_ij`` (its derivative through F vanishes because
``sum_j w z (x) xi = 0``):

* ``"silling"`` (Silling 2017, "Stability of peridynamic correspondence material models
  and their particle discretizations", CMAME 322, 42): ``B_i = C_s c_b / (delta omega0_i) I``
  with ``omega0_i = sum_j omega_ij`` and the bond-based micromodulus of the material's bulk
  modulus, ``c_b = 18 K / (pi delta^4)`` (3D) or ``12 k / (pi h delta^3)`` (2D, k the 2D
  bulk modulus). The leading Julia PD package uses ``C_s c_b omega / omega0`` (default
  ``C_s = 100``), which lacks a length to be a force density; the ``1/delta`` restores
  it. ``C_s = 100`` here too.
* ``"wan"`` (Wan et al. 2019, Acta Mech. Sin. 35, 1021; parameter-free):
  ``B_i = C1_i``, ``(C1_i)_pq = C_pqab (K_i^-1)_ab``.

Bond-associated correspondence (``bond_associated=True``; Chen & Spencer, IJNME 120
(2019) 1099; Breitzman & Dayal, JMPS 110 (2018) 192): every bond b = i->j gets its own
gradient over the bond-associated family ``h_b = {k in H_i : |x_k - x_j| <= r}`` (r =
``ba_radius`` delta), ``H_b = sum_{k in h_b} w (u_k - u_i) (x) K_b^-1 xi_ik``, and the
energy density of i is the average ``sum_j (w_j / sum w) (1/2) H_b : C : H_b``. A
non-affine mode that leaves every bond-level gradient unchanged would have to be affine
on every lens h_b, so the zero-energy modes of the particle-level gradient disappear
without a stabilisation parameter. Implemented for the linear law through its assembled
stiffness ``K = G^T D G`` (symmetric, positive semi-definite).

Bond failure is not modelled here. A particle whose shape tensor is singular (a family
that does not span the dimension) is refused at ``prepare`` with its index.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from upscale.models import register
from upscale.models.base import Model, Needs
from upscale.models.tipd import isotropic_voigt, rotate_tensor, rotation_matrix, voigt_to_tensor

__all__ = ["Correspondence", "LAWS", "STABILISATIONS", "gradient_operators", "shape_tensors",
           "bond_associated_operator"]

LAWS = {"linear": 0, "svk": 1, "neo-hookean": 2}
STABILISATIONS = (None, "silling", "wan")


# ---------------------------------------------------------------------------- kernels
@nb.njit(parallel=True, cache=True)
def defgrad_kernel(offsets, neighbors, xi_bc, wv_b, Kinv_n, y_nc, d, F_n):
    """Mutates ``F_n`` (N, 3, 3): F_i = (sum_j w Y (x) xi) K_i^-1 (first d x d block; the
    xi and Kinv components beyond d are zero)."""
    n = offsets.shape[0] - 1
    for i in nb.prange(n):
        a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            w = wv_b[b]
            Y0 = (y_nc[j, 0] - y_nc[i, 0]) * w
            Y1 = (y_nc[j, 1] - y_nc[i, 1]) * w
            Y2 = (y_nc[j, 2] - y_nc[i, 2]) * w if d == 3 else 0.0
            x0 = xi_bc[b, 0]
            x1 = xi_bc[b, 1]
            x2 = xi_bc[b, 2]
            a00 += Y0 * x0
            a01 += Y0 * x1
            a02 += Y0 * x2
            a10 += Y1 * x0
            a11 += Y1 * x1
            a12 += Y1 * x2
            a20 += Y2 * x0
            a21 += Y2 * x1
            a22 += Y2 * x2
        K = Kinv_n[i]
        for a in range(d):
            F_n[i, 0, a] = a00 * K[0, a] + a01 * K[1, a] + a02 * K[2, a]
            F_n[i, 1, a] = a10 * K[0, a] + a11 * K[1, a] + a12 * K[2, a]
            if d == 3:
                F_n[i, 2, a] = a20 * K[0, a] + a21 * K[1, a] + a22 * K[2, a]


@nb.njit(cache=True)
def _inv_det(F, d):
    """Inverse and determinant of the d x d block of F (3, 3)."""
    G = np.zeros((3, 3))
    if d == 2:
        J = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
        G[0, 0] = F[1, 1] / J
        G[1, 1] = F[0, 0] / J
        G[0, 1] = -F[0, 1] / J
        G[1, 0] = -F[1, 0] / J
        return G, J
    J = (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1])
         - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
         + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))
    G[0, 0] = (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]) / J
    G[0, 1] = (F[0, 2] * F[2, 1] - F[0, 1] * F[2, 2]) / J
    G[0, 2] = (F[0, 1] * F[1, 2] - F[0, 2] * F[1, 1]) / J
    G[1, 0] = (F[1, 2] * F[2, 0] - F[1, 0] * F[2, 2]) / J
    G[1, 1] = (F[0, 0] * F[2, 2] - F[0, 2] * F[2, 0]) / J
    G[1, 2] = (F[0, 2] * F[1, 0] - F[0, 0] * F[1, 2]) / J
    G[2, 0] = (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]) / J
    G[2, 1] = (F[0, 1] * F[2, 0] - F[0, 0] * F[2, 1]) / J
    G[2, 2] = (F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]) / J
    return G, J


@nb.njit(parallel=True, cache=True)
def stress_kernel(F_n, Kinv_n, C, law, lam, mu, d, PK_n, psi_n):
    """Mutates ``PK_n`` (N, 3, 3) = P(F_i) K_i^-1 and ``psi_n`` (N,) = Psi(F_i) (J/m^3)
    (the stress law of :func:`_stress_point`)."""
    n = F_n.shape[0]
    for i in nb.prange(n):
        P = np.zeros((3, 3))
        E = np.zeros((3, 3))
        S = np.zeros((3, 3))
        psi = _stress_point(F_n[i], Kinv_n[i], C, law, lam, mu, d, P, E, S)
        psi_n[i] = psi
        for p in range(d):
            for a in range(d):
                s = 0.0
                for c in range(d):
                    s += P[p, c] * Kinv_n[i, c, a]
                PK_n[i, p, a] = s


@nb.njit(parallel=True, cache=True)
def nosb_force_kernel(offsets, neighbors, xi_bc, wv_b, PK_n, F_n, B_n, y_nc, d, stab, out_nc):
    """Adds b_i = sum_j w (PK_i + PK_j) xi + [stab] sum_j w (B_i z_ij - B_j z_ji) to
    ``out_nc``, ``z_ij = Y - F_i xi``, ``z_ji = -Y + F_j xi``; ``B_n`` (N, 3, 3). Scalar
    accumulators (no allocation per particle); the z components beyond d are zero."""
    n = offsets.shape[0] - 1
    for i in nb.prange(n):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            w = wv_b[b]
            x0 = xi_bc[b, 0]
            x1 = xi_bc[b, 1]
            x2 = xi_bc[b, 2]
            # (PK_i + PK_j) xi (PK rows/cols beyond d are zero)
            f0 += w * ((PK_n[i, 0, 0] + PK_n[j, 0, 0]) * x0 + (PK_n[i, 0, 1] + PK_n[j, 0, 1]) * x1
                       + (PK_n[i, 0, 2] + PK_n[j, 0, 2]) * x2)
            f1 += w * ((PK_n[i, 1, 0] + PK_n[j, 1, 0]) * x0 + (PK_n[i, 1, 1] + PK_n[j, 1, 1]) * x1
                       + (PK_n[i, 1, 2] + PK_n[j, 1, 2]) * x2)
            if d == 3:
                f2 += w * ((PK_n[i, 2, 0] + PK_n[j, 2, 0]) * x0 + (PK_n[i, 2, 1] + PK_n[j, 2, 1]) * x1
                           + (PK_n[i, 2, 2] + PK_n[j, 2, 2]) * x2)
            if stab:
                Y0 = y_nc[j, 0] - y_nc[i, 0]
                Y1 = y_nc[j, 1] - y_nc[i, 1]
                Y2 = y_nc[j, 2] - y_nc[i, 2] if d == 3 else 0.0
                zi0 = Y0 - (F_n[i, 0, 0] * x0 + F_n[i, 0, 1] * x1 + F_n[i, 0, 2] * x2)
                zi1 = Y1 - (F_n[i, 1, 0] * x0 + F_n[i, 1, 1] * x1 + F_n[i, 1, 2] * x2)
                zj0 = -Y0 + (F_n[j, 0, 0] * x0 + F_n[j, 0, 1] * x1 + F_n[j, 0, 2] * x2)
                zj1 = -Y1 + (F_n[j, 1, 0] * x0 + F_n[j, 1, 1] * x1 + F_n[j, 1, 2] * x2)
                zi2 = 0.0
                zj2 = 0.0
                if d == 3:
                    zi2 = Y2 - (F_n[i, 2, 0] * x0 + F_n[i, 2, 1] * x1 + F_n[i, 2, 2] * x2)
                    zj2 = -Y2 + (F_n[j, 2, 0] * x0 + F_n[j, 2, 1] * x1 + F_n[j, 2, 2] * x2)
                f0 += w * (B_n[i, 0, 0] * zi0 + B_n[i, 0, 1] * zi1 + B_n[i, 0, 2] * zi2
                           - B_n[j, 0, 0] * zj0 - B_n[j, 0, 1] * zj1 - B_n[j, 0, 2] * zj2)
                f1 += w * (B_n[i, 1, 0] * zi0 + B_n[i, 1, 1] * zi1 + B_n[i, 1, 2] * zi2
                           - B_n[j, 1, 0] * zj0 - B_n[j, 1, 1] * zj1 - B_n[j, 1, 2] * zj2)
                if d == 3:
                    f2 += w * (B_n[i, 2, 0] * zi0 + B_n[i, 2, 1] * zi1 + B_n[i, 2, 2] * zi2
                               - B_n[j, 2, 0] * zj0 - B_n[j, 2, 1] * zj1 - B_n[j, 2, 2] * zj2)
        out_nc[i, 0] += f0
        out_nc[i, 1] += f1
        out_nc[i, 2] += f2


@nb.njit(cache=True)
def _stress_point(F, Kinv, C, law, lam, mu, d, P, E, S):
    """P = dPsi/dF (F) into ``P`` (3, 3) (``E``, ``S`` (3, 3) scratch); returns Psi (J/m^3)."""
    psi = 0.0
    for p in range(3):
        for q in range(3):
            P[p, q] = 0.0
    if law == 0 or law == 1:
        for p in range(d):
            for q in range(d):
                if law == 0:
                    E[p, q] = 0.5 * (F[p, q] + F[q, p]) - (1.0 if p == q else 0.0)
                else:
                    s = 0.0
                    for k in range(d):
                        s += F[k, p] * F[k, q]
                    E[p, q] = 0.5 * (s - (1.0 if p == q else 0.0))
        for p in range(d):
            for q in range(d):
                s = 0.0
                for a in range(d):
                    for b in range(d):
                        s += C[p, q, a, b] * E[a, b]
                S[p, q] = s
                psi += 0.5 * s * E[p, q]
        for p in range(d):
            for q in range(d):
                if law == 0:
                    P[p, q] = S[p, q]
                else:
                    s = 0.0
                    for k in range(d):
                        s += F[p, k] * S[k, q]
                    P[p, q] = s
    else:
        G, J = _inv_det(F, d)
        lnJ = np.log(J) if J > 0 else np.nan
        tr = 0.0
        for p in range(d):
            for q in range(d):
                tr += F[p, q] * F[p, q]
                P[p, q] = mu * (F[p, q] - G[q, p]) + lam * lnJ * G[q, p]
        psi = 0.5 * mu * (tr - d) - mu * lnJ + 0.5 * lam * lnJ * lnJ
    return psi


@nb.njit(cache=True)
def _pair_defgrad_chunk(i0, i1, poff, pj, x0_nc, k_p, c_k, y_nc, d, buf):
    """Pairs of the particles i0 <= i < i1: ``c Y (x) xi`` (``xi = x0_j - x0_i``, c the
    pair weight of the pair's class) added to both ends' rows of one thread's buffer
    (N, 9) (zeroed here), entry ``3 r + a``."""
    buf[:, :] = 0.0
    xi = np.zeros(3)
    for i in range(i0, i1):
        for p in range(poff[i], poff[i + 1]):
            j = pj[p]
            c = c_k[k_p[p]]
            for a in range(3):
                xi[a] = x0_nc[j, a] - x0_nc[i, a]
            for r in range(d):
                Y = (y_nc[j, r] - y_nc[i, r]) * c
                for a in range(d):
                    v = Y * xi[a]
                    buf[i, 3 * r + a] += v
                    buf[j, 3 * r + a] += v


@nb.njit(cache=True)
def _pair_stress_chunk(i0, i1, buf_tnk, inv_vol_n, Kinv_n, C, law, lam, mu, d, F_n, PK_n, psi_n):
    """Particles i0 <= i < i1: ``F_i = (sum_t buf[t, i] / V_i) K_i^-1``, ``P(F_i)``,
    ``PK_i = P K_i^-1`` and ``psi_i`` (one scratch set per chunk, none per particle)."""
    nt = buf_tnk.shape[0]
    A = np.zeros((3, 3))
    P = np.zeros((3, 3))
    E = np.zeros((3, 3))
    S = np.zeros((3, 3))
    for i in range(i0, i1):
        s = inv_vol_n[i]
        for r in range(3):
            for a in range(3):
                acc = 0.0
                for t in range(nt):
                    acc += buf_tnk[t, i, 3 * r + a]
                A[r, a] = acc * s
        K = Kinv_n[i]
        F = F_n[i]
        for r in range(d):
            for a in range(d):
                v = 0.0
                for c in range(d):
                    v += A[r, c] * K[c, a]
                F[r, a] = v
        psi_n[i] = _stress_point(F, K, C, law, lam, mu, d, P, E, S)
        for r in range(d):
            for a in range(d):
                v = 0.0
                for c in range(d):
                    v += P[r, c] * K[c, a]
                PK_n[i, r, a] = v


@nb.njit(parallel=True, cache=True)
def nosb_pair_update(bounds, poff, pj, x0_nc, k_p, c_k, y_nc, inv_vol_n, Kinv_n, C, law, lam, mu, d,
                     buf_tnk, F_n, PK_n, psi_n):
    """Pair form of :func:`defgrad_kernel` and :func:`stress_kernel`: mutates ``F_n``,
    ``PK_n`` (N, 3, 3) and ``psi_n``. Pairs i < j in rows ``poff`` with partners ``pj``;
    ``c_k[k_p[p]] = V_i w_ij = V_j w_ji`` (pair weight, m^6 with omega = 1, per class);
    ``xi = x0_j - x0_i`` recomputed; ``buf_tnk`` (T, N, 9) thread-private buffers, thread t
    taking the pairs of the particles ``bounds[t] <= i < bounds[t+1]``."""
    nt = buf_tnk.shape[0]
    n = F_n.shape[0]
    for t in nb.prange(nt):
        _pair_defgrad_chunk(bounds[t], bounds[t + 1], poff, pj, x0_nc, k_p, c_k, y_nc, d, buf_tnk[t])
    cn = (n + nt - 1) // nt
    for t in nb.prange(nt):
        _pair_stress_chunk(t * cn, min((t + 1) * cn, n), buf_tnk, inv_vol_n, Kinv_n, C, law,
                           lam, mu, d, F_n, PK_n, psi_n)


@nb.njit(cache=True)
def _pair_force_chunk(i0, i1, poff, pj, x0_nc, k_p, c_k, PK_n, F_n, B_n, y_nc, d, stab, buf):
    """Pairs of the particles i0 <= i < i1 of :func:`nosb_pair_force` into one thread's
    buffer (N, 3), zeroed here."""
    buf[:, :] = 0.0
    z_i = np.zeros(3)
    z_j = np.zeros(3)
    g = np.zeros(3)
    xi = np.zeros(3)
    for i in range(i0, i1):
        for p in range(poff[i], poff[i + 1]):
            j = pj[p]
            for a in range(3):
                xi[a] = x0_nc[j, a] - x0_nc[i, a]
            for r in range(d):
                v = 0.0
                for a in range(d):
                    v += (PK_n[i, r, a] + PK_n[j, r, a]) * xi[a]
                g[r] = v
            if stab:
                for r in range(d):
                    Y = y_nc[j, r] - y_nc[i, r]
                    fi = 0.0
                    fj = 0.0
                    for a in range(d):
                        fi += F_n[i, r, a] * xi[a]
                        fj += F_n[j, r, a] * xi[a]
                    z_i[r] = Y - fi
                    z_j[r] = -Y + fj
                for r in range(d):
                    v = 0.0
                    for q in range(d):
                        v += B_n[i, r, q] * z_i[q] - B_n[j, r, q] * z_j[q]
                    g[r] += v
            c = c_k[k_p[p]]
            for r in range(d):
                buf[i, r] += c * g[r]
                buf[j, r] -= c * g[r]


@nb.njit(parallel=True, cache=True)
def nosb_pair_force(bounds, poff, pj, x0_nc, k_p, c_k, PK_n, F_n, B_n, y_nc, d, stab, buf_tnc):
    """Pair form of :func:`nosb_force_kernel`: per pair i < j the force (N)
    ``g = c [(PK_i + PK_j) xi + stab (B_i z_ij - B_j z_ji)]`` is added to ``buf[t, i]`` and
    subtracted from ``buf[t, j]`` (thread-private buffers (T, N, 3), zeroed here; thread t
    takes the particles ``bounds[t] <= i < bounds[t+1]``)."""
    nt = buf_tnc.shape[0]
    for t in nb.prange(nt):
        _pair_force_chunk(bounds[t], bounds[t + 1], poff, pj, x0_nc, k_p, c_k, PK_n, F_n, B_n,
                          y_nc, d, stab, buf_tnc[t])


@nb.njit(cache=True)
def _pair_defgrad_chunk_2d(i0, i1, poff, pj, x0_nc, k_p, c_k, y_nc, buf):
    """2D :func:`_pair_defgrad_chunk` into a compact buffer (N, 4): entries (00, 01, 10, 11)."""
    buf[:, :] = 0.0
    for i in range(i0, i1):
        yi0 = y_nc[i, 0]
        yi1 = y_nc[i, 1]
        xi0 = x0_nc[i, 0]
        xi1 = x0_nc[i, 1]
        s00 = 0.0
        s01 = 0.0
        s10 = 0.0
        s11 = 0.0
        for p in range(poff[i], poff[i + 1]):
            j = pj[p]
            c = c_k[k_p[p]]
            x0 = x0_nc[j, 0] - xi0
            x1 = x0_nc[j, 1] - xi1
            Y0 = (y_nc[j, 0] - yi0) * c
            Y1 = (y_nc[j, 1] - yi1) * c
            a = Y0 * x0
            b = Y0 * x1
            e = Y1 * x0
            f = Y1 * x1
            s00 += a
            s01 += b
            s10 += e
            s11 += f
            buf[j, 0] += a
            buf[j, 1] += b
            buf[j, 2] += e
            buf[j, 3] += f
        buf[i, 0] += s00
        buf[i, 1] += s01
        buf[i, 2] += s10
        buf[i, 3] += s11


@nb.njit(cache=True)
def _pair_stress_chunk_2d(i0, i1, buf_tn4, inv_vol_n, Kinv_n, C, law, lam, mu, F_n, F4_n,
                          PK4_n, psi_n):
    """2D :func:`_pair_stress_chunk`: F and PK also into the compact (N, 4) arrays; the
    linear law written out (the common case), the others through :func:`_stress_point`."""
    nt = buf_tn4.shape[0]
    P = np.zeros((3, 3))
    E = np.zeros((3, 3))
    S = np.zeros((3, 3))
    c00, c01, c0x = C[0, 0, 0, 0], C[0, 0, 1, 1], C[0, 0, 0, 1] + C[0, 0, 1, 0]
    c10, c11, c1x = C[1, 1, 0, 0], C[1, 1, 1, 1], C[1, 1, 0, 1] + C[1, 1, 1, 0]
    cx0, cx1, cxx = C[0, 1, 0, 0], C[0, 1, 1, 1], C[0, 1, 0, 1] + C[0, 1, 1, 0]
    for i in range(i0, i1):
        s = inv_vol_n[i]
        a00 = 0.0
        a01 = 0.0
        a10 = 0.0
        a11 = 0.0
        for t in range(nt):
            a00 += buf_tn4[t, i, 0]
            a01 += buf_tn4[t, i, 1]
            a10 += buf_tn4[t, i, 2]
            a11 += buf_tn4[t, i, 3]
        k00 = Kinv_n[i, 0, 0]
        k01 = Kinv_n[i, 0, 1]
        k10 = Kinv_n[i, 1, 0]
        k11 = Kinv_n[i, 1, 1]
        f00 = s * (a00 * k00 + a01 * k10)
        f01 = s * (a00 * k01 + a01 * k11)
        f10 = s * (a10 * k00 + a11 * k10)
        f11 = s * (a10 * k01 + a11 * k11)
        F_n[i, 0, 0] = f00
        F_n[i, 0, 1] = f01
        F_n[i, 1, 0] = f10
        F_n[i, 1, 1] = f11
        F4_n[i, 0] = f00
        F4_n[i, 1] = f01
        F4_n[i, 2] = f10
        F4_n[i, 3] = f11
        if law == 0:
            e00 = f00 - 1.0
            e11 = f11 - 1.0
            e01 = 0.5 * (f01 + f10)
            p00 = c00 * e00 + c01 * e11 + c0x * e01
            p11 = c10 * e00 + c11 * e11 + c1x * e01
            p01 = cx0 * e00 + cx1 * e11 + cxx * e01
            p10 = p01
            psi_n[i] = 0.5 * (p00 * e00 + p11 * e11 + 2.0 * p01 * e01)
        else:
            psi_n[i] = _stress_point(F_n[i], Kinv_n[i], C, law, lam, mu, 2, P, E, S)
            p00 = P[0, 0]
            p01 = P[0, 1]
            p10 = P[1, 0]
            p11 = P[1, 1]
        PK4_n[i, 0] = p00 * k00 + p01 * k10
        PK4_n[i, 1] = p00 * k01 + p01 * k11
        PK4_n[i, 2] = p10 * k00 + p11 * k10
        PK4_n[i, 3] = p10 * k01 + p11 * k11


@nb.njit(cache=True)
def _pair_force_chunk_2d(i0, i1, poff, pj, x0_nc, k_p, c_k, PK4_n, F4_n, B4_n, y_nc, stab, buf):
    """2D :func:`_pair_force_chunk` on the compact (N, 4) arrays, buffer (N, 2)."""
    buf[:, :] = 0.0
    for i in range(i0, i1):
        pk0 = PK4_n[i, 0]
        pk1 = PK4_n[i, 1]
        pk2 = PK4_n[i, 2]
        pk3 = PK4_n[i, 3]
        F0 = F4_n[i, 0]
        F1 = F4_n[i, 1]
        F2 = F4_n[i, 2]
        F3 = F4_n[i, 3]
        B0 = B4_n[i, 0]
        B1 = B4_n[i, 1]
        B2 = B4_n[i, 2]
        B3 = B4_n[i, 3]
        yi0 = y_nc[i, 0]
        yi1 = y_nc[i, 1]
        xi0 = x0_nc[i, 0]
        xi1 = x0_nc[i, 1]
        s0 = 0.0
        s1 = 0.0
        for p in range(poff[i], poff[i + 1]):
            j = pj[p]
            c = c_k[k_p[p]]
            x0 = x0_nc[j, 0] - xi0
            x1 = x0_nc[j, 1] - xi1
            g0 = (pk0 + PK4_n[j, 0]) * x0 + (pk1 + PK4_n[j, 1]) * x1
            g1 = (pk2 + PK4_n[j, 2]) * x0 + (pk3 + PK4_n[j, 3]) * x1
            if stab:
                Y0 = y_nc[j, 0] - yi0
                Y1 = y_nc[j, 1] - yi1
                zi0 = Y0 - (F0 * x0 + F1 * x1)
                zi1 = Y1 - (F2 * x0 + F3 * x1)
                zj0 = -Y0 + (F4_n[j, 0] * x0 + F4_n[j, 1] * x1)
                zj1 = -Y1 + (F4_n[j, 2] * x0 + F4_n[j, 3] * x1)
                g0 += B0 * zi0 + B1 * zi1 - B4_n[j, 0] * zj0 - B4_n[j, 1] * zj1
                g1 += B2 * zi0 + B3 * zi1 - B4_n[j, 2] * zj0 - B4_n[j, 3] * zj1
            g0 *= c
            g1 *= c
            s0 += g0
            s1 += g1
            buf[j, 0] -= g0
            buf[j, 1] -= g1
        buf[i, 0] += s0
        buf[i, 1] += s1


@nb.njit(parallel=True, cache=True)
def nosb_pair_update_2d(bounds, poff, pj, x0_nc, k_p, c_k, y_nc, inv_vol_n, Kinv_n, C, law, lam, mu,
                        buf_tn4, F_n, F4_n, PK4_n, psi_n):
    """2D :func:`nosb_pair_update` with compact (N, 4) F and PK (entries 00, 01, 10, 11)."""
    nt = buf_tn4.shape[0]
    n = F_n.shape[0]
    for t in nb.prange(nt):
        _pair_defgrad_chunk_2d(bounds[t], bounds[t + 1], poff, pj, x0_nc, k_p, c_k, y_nc, buf_tn4[t])
    cn = (n + nt - 1) // nt
    for t in nb.prange(nt):
        _pair_stress_chunk_2d(t * cn, min((t + 1) * cn, n), buf_tn4, inv_vol_n, Kinv_n, C,
                              law, lam, mu, F_n, F4_n, PK4_n, psi_n)


@nb.njit(parallel=True, cache=True)
def nosb_pair_force_2d(bounds, poff, pj, x0_nc, k_p, c_k, PK4_n, F4_n, B4_n, y_nc, stab, buf_tn2):
    """2D :func:`nosb_pair_force` on the compact arrays, buffers (T, N, 2)."""
    nt = buf_tn2.shape[0]
    for t in nb.prange(nt):
        _pair_force_chunk_2d(bounds[t], bounds[t + 1], poff, pj, x0_nc, k_p, c_k, PK4_n, F4_n,
                             B4_n, y_nc, stab, buf_tn2[t])


@nb.njit(parallel=True, cache=True)
def stab_energy_kernel(offsets, neighbors, xi_bc, wv_b, F_n, B_n, y_nc, d, W_n):
    """Adds (1/2) sum_j w z_ij . B_i z_ij to ``W_n`` (J/m^3)."""
    n = offsets.shape[0] - 1
    for i in nb.prange(n):
        acc = 0.0
        z = np.zeros(3)
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            for p in range(d):
                s = 0.0
                for a in range(d):
                    s += F_n[i, p, a] * xi_bc[b, a]
                z[p] = (y_nc[j, p] - y_nc[i, p]) - s
            e = 0.0
            for p in range(d):
                for q in range(d):
                    e += z[p] * B_n[i, p, q] * z[q]
            acc += wv_b[b] * e
        W_n[i] += 0.5 * acc


def gradient_operators(family, wv_b, Kinv_n, d):
    """Sparse factors of the linear correspondence force: ``G`` (N d^2, 3N) with
    ``H = G u`` (``H_i[p, a] = sum_j w (u_j - u_i)_p (K_i^-1 xi)_a``, row ``i d^2 + p d + a``)
    and ``Bs`` (3N, N d^2) with ``b = Bs sigma`` (``b_i = sum_j w (sigma_i K_i^-1 +
    sigma_j K_j^-1) xi``). ``wv_b`` the bond weights ``omega V_j beta``, ``Kinv_n``
    (N, 3, 3) the inverse shape tensors."""
    import scipy.sparse as sp

    n = family.n
    i, j = family.owner, family.neighbors
    xi = family.xi[:, :d]
    Kinv = Kinv_n[:, :d, :d]
    g = wv_b[:, None] * np.einsum("kab,kb->ka", Kinv[i], xi)     # w K_i^-1 xi
    gp = wv_b[:, None] * np.einsum("kab,kb->ka", Kinv[j], xi)    # w K_j^-1 xi
    dd = d * d
    r, c, v = [], [], []
    for p in range(d):
        for a in range(d):
            r += [i * dd + p * d + a] * 2
            c += [3 * j + p, 3 * i + p]
            v += [g[:, a], -g[:, a]]
    G = sp.csr_matrix((np.concatenate(v), (np.concatenate(r), np.concatenate(c))),
                      shape=(n * dd, 3 * n))
    r, c, v = [], [], []
    for p in range(d):
        for a in range(d):
            r += [3 * i + p] * 2
            c += [i * dd + p * d + a, j * dd + p * d + a]
            v += [g[:, a], gp[:, a]]
    Bs = sp.csr_matrix((np.concatenate(v), (np.concatenate(r), np.concatenate(c))),
                       shape=(3 * n, n * dd))
    return G, Bs


def shape_tensors(family, wv_b, d, horizon):
    """Shape tensors ``K_i = sum_j w xi (x) xi`` (N, d, d) and their inverses padded to
    (N, 3, 3). Raises ``ValueError`` naming the first particle whose family does not span
    d dimensions, except on the rows the family marks partial (``family.partial_rows``:
    rows missing bonds, whose per-particle quantities nobody uses): their inverse is 0."""
    xi = family.xi[:, :d]
    K = np.zeros((family.n, d, d))
    np.add.at(K, family.owner, wv_b[:, None, None] * np.einsum("ka,kb->kab", xi, xi))
    det = np.linalg.det(K)
    scale = np.einsum("kab,kab->k", K, K) ** (d / 2.0)
    bad = ~(np.abs(det) > 1e-10 * np.maximum(scale, 1e-300))
    partial = getattr(family, "partial_rows", None)
    if partial is not None and (bad & partial).any():
        skip = bad & partial
        Kc = K.copy()
        Kc[skip] = np.eye(d)
        Kinv = np.zeros((family.n, 3, 3))
        Kinv[:, :d, :d] = np.linalg.inv(Kc)
        Kinv[skip] = 0.0
        bad &= ~partial
        if not bad.any():
            return K, np.ascontiguousarray(Kinv)
    if bad.any():
        p = int(np.flatnonzero(bad)[0])
        raise ValueError(f"shape tensor of particle {p} is singular (its {int(family.counts[p])} "
                         f"bonds do not span {d}D); use a horizon larger than "
                         f"{horizon:.6g} m so that every family spans the body")
    Kinv = np.zeros((family.n, 3, 3))
    Kinv[:, :d, :d] = np.linalg.inv(K)
    return K, np.ascontiguousarray(Kinv)


@nb.njit(cache=True)
def _ba_members(offsets, neighbors, x_nc, r2, count_only, bond_b, member_b):
    """Bond-associated families: for each bond b = i->j the bonds c = i->k of i's family
    with ``|x_k - x_j|^2 <= r2`` (k = j included). First call (``count_only``) returns the
    number of (b, c) entries; the second fills ``bond_b``, ``member_b``."""
    n = offsets.shape[0] - 1
    m = 0
    for i in range(n):
        for b in range(offsets[i], offsets[i + 1]):
            j = neighbors[b]
            for c in range(offsets[i], offsets[i + 1]):
                k = neighbors[c]
                d0 = x_nc[k, 0] - x_nc[j, 0]
                d1 = x_nc[k, 1] - x_nc[j, 1]
                d2 = x_nc[k, 2] - x_nc[j, 2]
                if d0 * d0 + d1 * d1 + d2 * d2 <= r2:
                    if not count_only:
                        bond_b[m] = b
                        member_b[m] = c
                    m += 1
    return m


def bond_associated_operator(family, x_nc, wv_b, radius, d):
    """The bond-associated gradient operator (Chen & Spencer 2019; Breitzman & Dayal
    2018): for each bond b = i->j the gradient over its bond-associated family
    ``h_b = {k in H_i : |x_k - x_j| <= radius}``::

        K_b = sum_{c in h_b} w_c xi_c (x) xi_c,   H_b = sum_{c in h_b} w_c (u_k - u_i) (x) K_b^-1 xi_c

    Returns ``G`` (nb d^2, 3N) with ``H = G u`` (row ``b d^2 + p d + a``). Raises
    ``ValueError`` naming the first bond (and its particle) whose bond-associated family
    does not span d dimensions."""
    import scipy.sparse as sp

    off, nbr = family.offsets, family.neighbors
    r2 = float(radius) ** 2
    dummy = np.zeros(1, dtype=np.int64)
    m = _ba_members(off, nbr, x_nc, r2, True, dummy, dummy)
    bb = np.zeros(m, dtype=np.int64)
    cc = np.zeros(m, dtype=np.int64)
    _ba_members(off, nbr, x_nc, r2, False, bb, cc)
    xi = family.xi[:, :d]
    wc = wv_b[cc]
    K = np.zeros((family.nb, d, d))
    np.add.at(K, bb, wc[:, None, None] * np.einsum("ka,kb->kab", xi[cc], xi[cc]))
    det = np.linalg.det(K)
    scale = np.einsum("kab,kab->k", K, K) ** (d / 2.0)
    bad = ~(np.abs(det) > 1e-10 * np.maximum(scale, 1e-300))
    if bad.any():
        b = int(np.flatnonzero(bad)[0])
        raise ValueError(f"bond-associated shape tensor of bond {b} (particle {int(family.owner[b])}) "
                         f"is singular; use a bond-associated radius larger than {radius:.6g} m")
    Kinv = np.linalg.inv(K)
    g = wc[:, None] * np.einsum("kab,kb->ka", Kinv[bb], xi[cc])
    i, k = family.owner[cc], nbr[cc]
    dd = d * d
    rows, cols, vals = [], [], []
    for p in range(d):
        for a in range(d):
            rows += [bb * dd + p * d + a] * 2
            cols += [3 * k + p, 3 * i + p]
            vals += [g[:, a], -g[:, a]]
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(family.nb * dd, 3 * family.n))


# ---------------------------------------------------------------------------- model
class Correspondence(Model):
    """Correspondence (NOSB) peridynamics, 2D and 3D; see the module docstring.

    Parameters
    ----------
    C : Voigt matrix (3, 3)/(6, 6) or tensor (d, d, d, d), optional
        Elastic stiffness in the material axes (Pa); or ``E``, ``nu`` (isotropic).
    order : {"standard", "tian"}
        3D Voigt order of ``C`` (see :mod:`upscale.models.tipd`).
    angle, axes
        Material axes (as :class:`~upscale.models.tipd.TiPD`).
    law : {"linear", "svk", "neo-hookean"}
    stabilisation : {None, "silling", "wan"}
    Cs : float
        Silling's stabilisation factor (dimensionless).
    influence : {"constant", "inverse"}
        omega = 1 or delta/|xi|.
    kernel : {"pair", "bond"}
        Loops over the half bond list (each pair once, :mod:`upscale.engine.bondlist`;
        needs symmetric pair weights, else falls back to "bond") or over the directed bonds.
        Same forces to round-off.
    bond_associated : bool
        Bond-associated correspondence (module docstring): one gradient per bond over the
        bond-associated family, energy averaged over the bonds; linear law only, no
        stabilisation (none is needed). Forces from the assembled stiffness.
    ba_radius : float
        Radius of the bond-associated family around the bond's far end, in horizons
        (default 0.5: of 0.5, 0.75, 1 and 1.5 the smallest manufactured-solution error and
        oscillation at delta = 3 dx).
    """

    name = "nosb"
    force_kind = "density"

    def __init__(self, C=None, *, E: float | None = None, nu: float | None = None,
                 order: str = "standard", angle: float | None = None, axes=None,
                 law: str = "linear", stabilisation: str | None = None, Cs: float = 100.0,
                 influence: str = "constant", kernel: str = "pair",
                 bond_associated: bool = False, ba_radius: float = 0.5):
        if (C is None) == (E is None):
            raise ValueError("Correspondence needs exactly one of C (elastic stiffness) or E, nu")
        if E is not None and nu is None:
            raise ValueError("isotropic Correspondence needs nu with E")
        if law not in LAWS:
            raise ValueError(f"unknown material law {law!r}; valid: {', '.join(repr(k) for k in LAWS)}")
        if stabilisation not in STABILISATIONS:
            raise ValueError(f"unknown stabilisation {stabilisation!r}; valid: None, 'silling', 'wan'")
        if influence not in ("constant", "inverse"):
            raise ValueError(f"unknown influence function {influence!r}; valid: 'constant', 'inverse'")
        if kernel not in ("pair", "bond"):
            raise ValueError(f"unknown force kernel {kernel!r}; valid: 'pair', 'bond'")
        self.kernel = kernel
        if bond_associated and (law != "linear" or stabilisation is not None):
            raise ValueError("bond-associated correspondence is implemented for law='linear' "
                             f"without stabilisation (got law={law!r}, stabilisation={stabilisation!r})")
        if not (np.isfinite(ba_radius) and 0 < ba_radius <= 2):
            raise ValueError(f"ba_radius must be in (0, 2] horizons, got {ba_radius!r}")
        self.bond_associated, self.ba_radius = bool(bond_associated), float(ba_radius)
        if not (np.isfinite(Cs) and Cs >= 0):
            raise ValueError(f"stabilisation factor Cs must be >= 0, got {Cs!r}")
        if angle is not None and not np.isfinite(angle):
            raise ValueError(f"material-axis angle must be finite (radians), got {angle!r}")
        if C is not None and np.asarray(C).ndim == 2:
            voigt_to_tensor(np.asarray(C, dtype=np.float64), order)
        self.C_in, self.E, self.nu, self.order = C, E, nu, order
        self.angle, self.axes = angle, axes
        self.law, self.stabilisation, self.Cs, self.influence = law, stabilisation, float(Cs), influence
        self.needs = Needs(pairs=True, energy=True, tangent=(law == "linear"))

    def prepare(self, system, family, **kw) -> None:
        super().prepare(system, family, **kw)
        d = system.dim
        if d not in (2, 3):
            raise ValueError(f"correspondence is implemented in 2D and 3D, not dim={d}")
        self.dim = d
        if self.E is not None:
            Cm = voigt_to_tensor(isotropic_voigt(self.E, self.nu, d, system.plane))
        else:
            Ca = np.asarray(self.C_in, dtype=np.float64)
            Cm = voigt_to_tensor(Ca, self.order) if Ca.ndim == 2 else Ca
            if Cm.shape != (d,) * 4:
                raise ValueError(f"elastic stiffness is for dim {Cm.shape[0]}, body has dim {d}")
        Cm = rotate_tensor(Cm, rotation_matrix(self.angle, self.axes, d))
        self.C = Cm
        C3 = np.zeros((3, 3, 3, 3))
        C3[:d, :d, :d, :d] = Cm
        self.C3 = C3
        self.lam, self.mu = float(Cm[0, 0, 1, 1]), float(Cm[0, 1, 0, 1])
        if self.law == "neo-hookean":
            iso = (self.lam * np.einsum("ij,kl->ijkl", np.eye(d), np.eye(d))
                   + self.mu * (np.einsum("ik,jl->ijkl", np.eye(d), np.eye(d))
                                + np.einsum("il,jk->ijkl", np.eye(d), np.eye(d))))
            if not np.allclose(iso, Cm, rtol=1e-10, atol=1e-10 * np.abs(Cm).max()):
                raise ValueError("the neo-Hookean law needs an isotropic material (E, nu)")
        self._wv_b = self._xi_bc = None
        wv = self.bond_weights()
        K, Kinv = shape_tensors(family, wv, d, family.horizon)
        self.K_n = K
        self.Kinv_n = Kinv
        B = np.zeros((family.n, 3, 3))
        if self.stabilisation == "silling":
            if d == 3:
                Kb = np.einsum("iijj->", Cm) / 9.0
                cb = 18.0 * Kb / (np.pi * family.horizon ** 4)
            else:
                kb = np.einsum("iijj->", Cm) / 4.0
                cb = 12.0 * kb / (np.pi * system.thickness * family.horizon ** 3)
            omega0 = np.bincount(family.owner, weights=self.omega_b, minlength=family.n)
            self.beta = self.Cs * cb / (family.horizon * omega0)
            B[:, :d, :d] = self.beta[:, None, None] * np.eye(d)
        elif self.stabilisation == "wan":
            B[:, :d, :d] = np.einsum("pqab,nab->npq", Cm, Kinv[:, :d, :d])
        self.B_n = np.ascontiguousarray(B)
        self._F = np.zeros((family.n, 3, 3))
        self._PK = np.zeros((family.n, 3, 3))
        self._psi = np.zeros(family.n)
        self._set_pairs(wv)
        if self.bond_associated:
            self._prepare_bond_associated()

    def _prepare_bond_associated(self) -> None:
        """``K = G^T D G`` with D the block-diagonal ``V_i (V_j beta / sum_j V_j beta) C``
        per bond (the bond energies averaged over i's family)."""
        import scipy.sparse as sp

        fam, d, n = self.family, self.dim, self.system.n
        dd = d * d
        wv = self.system.volume[fam.neighbors] * fam.volume_factor
        G = bond_associated_operator(fam, self.system.x0, wv, self.ba_radius * fam.horizon, d)
        wsum = np.bincount(fam.owner, weights=wv, minlength=n)
        coef = self.system.volume[fam.owner] * wv / wsum[fam.owner]
        Cm = self.C.reshape(dd, dd)
        blk = coef[:, None, None] * Cm[None]
        base = np.arange(fam.nb)[:, None, None] * dd
        r = np.broadcast_to(base + np.arange(dd)[None, :, None], blk.shape)
        c = np.broadcast_to(base + np.arange(dd)[None, None, :], blk.shape)
        D = sp.csr_matrix((blk.ravel(), (r.ravel(), c.ravel())), shape=(fam.nb * dd, fam.nb * dd))
        self._ba_G = G
        self._ba_coef = coef
        self._ba_K = (G.T @ D @ G).tocsr()

    # ------------------------------------------------------------------ per-bond quantities
    @property
    def omega_b(self) -> np.ndarray:
        """Influence function of every directed bond (nb,) (a new array)."""
        L = self.family.length
        return np.ones_like(L) if self.influence == "constant" else self.family.horizon / L

    def bond_weights(self) -> np.ndarray:
        """``w = omega V_j beta_ij`` of every directed bond (nb,) (m^3; a new array)."""
        fam = self.family
        return self.omega_b * self.system.volume[fam.neighbors] * fam.volume_factor

    @property
    def wv_b(self) -> np.ndarray:
        """:meth:`bond_weights` (kept only for the directed-bond kernels)."""
        return self._wv_b if self._wv_b is not None else self.bond_weights()

    @property
    def xi_bc(self) -> np.ndarray:
        """Reference bond vectors (nb, 3) (kept only for the directed-bond kernels)."""
        return self._xi_bc if self._xi_bc is not None else self.family.xi

    def _set_pairs(self, wv) -> None:
        """Half bond list (:class:`~upscale.engine.bondlist.BondList`) when the pair weight is
        symmetric, ``V_i w_ij = V_j w_ji`` (symmetric partial volumes): each pair's terms are
        computed once from ``xi = x0_j - x0_i`` and the pair weight of its class
        (``c = (V_i w_ij + V_j w_ji)/2``); nothing per bond is kept but the list. Otherwise
        (or ``kernel="bond"``) the directed-bond kernels, which keep ``xi`` and ``w`` per
        bond (32 bytes)."""
        from upscale.engine.bondlist import BondList

        fam, V = self.family, self.system.volume
        self._pair = False
        self.bonds = None
        if self.kernel == "pair":
            bl = BondList(fam, V)
            k_p, _, _, _, ci_k, cj_k = bl.classes(wv * V[fam.owner])
            self._pair = bool(np.abs(ci_k - cj_k).max(initial=0.0)
                              <= 1e-12 * max(np.abs(ci_k).max(initial=0.0), 1e-300))
        if not self._pair:
            self._wv_b = np.ascontiguousarray(wv)
            self._xi_bc = np.ascontiguousarray(fam.xi)
            return
        self.bonds = bl
        self._k_p = k_p
        self._c_k = np.ascontiguousarray(0.5 * (ci_k + cj_k))
        self._inv_vol = np.ascontiguousarray(1.0 / V)
        if self.dim == 2:     # compact (N, 4) per-particle tensors
            self._F4 = np.zeros((fam.n, 4))
            self._PK4 = np.zeros((fam.n, 4))
            self._B4 = np.ascontiguousarray(self.B_n[:, :2, :2].reshape(fam.n, 4))
        self._alloc_buffers()

    def _alloc_buffers(self) -> None:
        n, d = self.family.n, self.dim
        nt = nb.get_num_threads()
        self._bufA = np.zeros((nt, n, 4 if d == 2 else 9))
        self._bufF = np.zeros((nt, n, d))
        self._bounds = self.bonds.chunks(nt)

    # ------------------------------------------------------------------ forces
    def deformation_gradient(self, state) -> np.ndarray:
        """F (N, d, d) on the current state (a new array)."""
        self._update(state)
        return self._F[:, :self.dim, :self.dim].copy()

    def _update(self, state):
        f = self.family
        if self._pair:
            if self._bufA.shape[0] != nb.get_num_threads():
                self._alloc_buffers()
            bl, x0 = self.bonds, self.system.x0
            if self.dim == 2:
                nosb_pair_update_2d(self._bounds, bl.row_n, bl.j_p, x0, self._k_p, self._c_k, state.y, self._inv_vol,
                                    self.Kinv_n, self.C3, LAWS[self.law], self.lam, self.mu,
                                    self._bufA, self._F, self._F4, self._PK4, self._psi)
            else:
                nosb_pair_update(self._bounds, bl.row_n, bl.j_p, x0, self._k_p, self._c_k, state.y, self._inv_vol,
                                 self.Kinv_n, self.C3, LAWS[self.law], self.lam, self.mu, 3,
                                 self._bufA, self._F, self._PK, self._psi)
            return
        defgrad_kernel(f.offsets, f.neighbors, self.xi_bc, self.wv_b, self.Kinv_n, state.y,
                       self.dim, self._F)
        stress_kernel(self._F, self.Kinv_n, self.C3, LAWS[self.law], self.lam, self.mu,
                      self.dim, self._PK, self._psi)

    def add_force(self, state, out):
        if self.bond_associated:
            u = (state.y - self.system.x0).ravel()
            out += -(self._ba_K @ u).reshape(-1, 3) / self.system.volume[:, None]
            return
        self._update(state)
        f = self.family
        if self._pair:
            from upscale.engine.pairs import reduce_buffers

            bl, x0, stab = self.bonds, self.system.x0, self.stabilisation is not None
            if self.dim == 2:
                nosb_pair_force_2d(self._bounds, bl.row_n, bl.j_p, x0, self._k_p, self._c_k, self._PK4, self._F4,
                                   self._B4, state.y, stab, self._bufF)
            else:
                nosb_pair_force(self._bounds, bl.row_n, bl.j_p, x0, self._k_p, self._c_k, self._PK, self._F, self.B_n,
                                state.y, 3, stab, self._bufF)
            reduce_buffers(self._bufF, self._inv_vol, out, self.dim)
            return
        nosb_force_kernel(f.offsets, f.neighbors, self.xi_bc, self.wv_b, self._PK, self._F,
                          self.B_n, state.y, self.dim, self.stabilisation is not None, out)

    def energy_density(self, state):
        if self.bond_associated:
            d, fam = self.dim, self.family
            H = (self._ba_G @ (state.y - self.system.x0).ravel()).reshape(fam.nb, d, d)
            e = 0.5 * np.einsum("kpa,paqb,kqb->k", H, self.C, H) * self._ba_coef
            return np.bincount(fam.owner, weights=e, minlength=fam.n) / self.system.volume
        self._update(state)
        W = self._psi.copy()
        if self.stabilisation is not None:
            f = self.family
            stab_energy_kernel(f.offsets, f.neighbors, self.xi_bc, self.wv_b, self._F, self.B_n,
                               state.y, self.dim, W)
        return W

    # ------------------------------------------------------------------ stiffness
    def linear_stiffness(self):
        """Stiffness ``K = -dF_int/dy`` (scipy.sparse CSR (3N, 3N), N/m) of the linear law
        (exact for ``law="linear"``, the small-displacement tangent of the others):
        ``F_int = V (B_sig C G + stabilisation) u`` assembled from sparse factors
        (H = G u the displacement gradients, sigma = C : H, b = B_sig sigma)."""
        import scipy.sparse as sp

        fam, d, n = self.family, self.dim, self.system.n
        i, j = fam.owner, fam.neighbors
        xi = fam.xi[:, :d]
        wv = self.wv_b
        dd = d * d
        G, Bs = gradient_operators(fam, wv, self.Kinv_n, d)
        Cb = sp.kron(sp.identity(n, format="csr"), sp.csr_matrix(self.C.reshape(dd, dd)), format="csr")
        A = Bs @ Cb @ G
        if self.stabilisation is not None:
            Bn = self.B_n[:, :d, :d]
            Bsum = Bn[i] + Bn[j]                                    # (nb, d, d)
            r, c, v = [], [], []
            for p in range(d):
                for q in range(d):
                    val = wv * Bsum[:, p, q]
                    r += [3 * i + p] * 2
                    c += [3 * j + q, 3 * i + q]
                    v += [val, -val]
            Eta = sp.csr_matrix((np.concatenate(v), (np.concatenate(r), np.concatenate(c))),
                                shape=(3 * n, 3 * n))
            # -sum_b w (B_i H_i xi + B_j H_j xi): row (i, p), col (k, q, a): -w B_k[p, q] xi[a]
            r, c, v = [], [], []
            for p in range(d):
                for q in range(d):
                    for a in range(d):
                        r += [3 * i + p] * 2
                        c += [i * dd + q * d + a, j * dd + q * d + a]
                        v += [-wv * Bn[i][:, p, q] * xi[:, a], -wv * Bn[j][:, p, q] * xi[:, a]]
            Hz = sp.csr_matrix((np.concatenate(v), (np.concatenate(r), np.concatenate(c))),
                               shape=(3 * n, n * dd))
            A = A + Eta + Hz @ G
        Vd = sp.diags(np.repeat(self.system.volume, 3))
        return (-(Vd @ A)).tocsr()

    def tangent(self, state=None):
        """The assembled stiffness for the linear law; the base class's finite differences
        for the others."""
        if self.bond_associated:
            return self._ba_K.copy()
        if self.law == "linear":
            return self.linear_stiffness()
        return super().tangent(state)

    def stiffness_bound(self):
        """Gershgorin row bound (N/m^4) of the small-displacement stiffness, from per-bond
        weights without assembling it: with ``g_b = w K_i^-1 xi`` and
        ``G_k = sum_{b of k} |g_b|_1`` (so that ``|H_k| <= 2 G_k max|u|``),
        ``R_i = c sum_b (|g_b|_1 2 G_i + |g'_b|_1 2 G_j)`` plus the stabilisation's
        ``sum_b w (|B_i| + |B_j|)(2 + |xi|_1 2 G)``; ``c = max_p sum |C_p...|``."""
        if self.bond_associated:     # row sums of the assembled stiffness
            A = abs(self._ba_K)
            r = np.asarray(A.sum(axis=1)).ravel().reshape(-1, 3).max(axis=1)
            return r / self.system.volume
        fam, d = self.family, self.dim
        i, j = fam.owner, fam.neighbors
        xi = np.abs(fam.xi[:, :d])
        Kinv = self.Kinv_n[:, :d, :d]
        wv = self.wv_b
        g = np.abs(wv[:, None] * np.einsum("kab,kb->ka", Kinv[i], fam.xi[:, :d])).sum(1)
        gp = np.abs(wv[:, None] * np.einsum("kab,kb->ka", Kinv[j], fam.xi[:, :d])).sum(1)
        G = np.bincount(i, weights=g, minlength=fam.n)
        c = np.abs(self.C).reshape(d, -1).sum(1).max()
        R = c * np.bincount(i, weights=g * 2 * G[i] + gp * 2 * G[j], minlength=fam.n)
        if self.stabilisation is not None:
            Bn = np.abs(self.B_n[:, :d, :d]).sum(2).max(1)
            xs = xi.sum(1)
            R = R + np.bincount(i, weights=wv * (Bn[i] * (2 + xs * 2 * G[i]) + Bn[j] * (2 + xs * 2 * G[j])),
                                minlength=fam.n)
        return R

    def describe(self):
        d = {"model": self.name, "law": self.law, "stabilisation": self.stabilisation,
             "bond_associated": self.bond_associated,
             "kernel": "pair" if getattr(self, "_pair", self.kernel == "pair") else "bond",
             "influence": self.influence}
        if self.stabilisation == "silling":
            d["Cs"] = self.Cs
        if self.E is not None:
            d.update(E_Pa=self.E, nu=self.nu)
        return d


register("nosb", Correspondence)
register("correspondence", Correspondence)
