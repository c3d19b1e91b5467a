"""Tridynamic beams and plates (seed 004, ch. 2-4): three-particle interactions on the engine.

Beams (:class:`TridynEB`, :class:`TridynTimoshenko`) below; the FSDT plate
(:class:`TridynPlate`, variants "consistent" and "text") has its own docstring.

Bodies are 1D chains of particles on the x axis (``line_lattice``); the transverse
displacement w is the z translation, the axial displacement u the x translation and the
rotation phi of the cross-section the field ``"rot"`` (one component, rotation about y,
:mod:`upscale.engine.fields`). Triplets (i; j, k): centre i, j and k in i's family; the
set is built here because the engine's :func:`~upscale.engine.multibody.build_triplets`
keeps only non-collinear triplets, and on a line every triplet is collinear.

Variants (``variant=``)
-----------------------
``"text"``
    The printed equations of motion and calibrations. They differentiate only the
    centre's own energy density with respect to the centre's degrees of freedom
    (after eq. 3.20), so the operator is not the gradient of the energy 3.11-3.13 and
    its tangent is not symmetric.
``"consistent"``
    The energy 3.11-3.13 (EB: the turning-angle energy below), its exact gradient
    (symmetric tangent) and moduli calibrated on the long-wave limit: the energy density
    of a uniform strain, curvature and shear at a bulk particle equals
    ``E eps^2/2``, ``EI/A kappa^2/2``, ``k_s G gamma^2/2``.

Measures (Timoshenko beam, eqs. 3.1-3.9, unsigned distances xi_ab = |x_b - x_a|,
``n_ab = sign(x_b - x_a)``)::

    eps_ijk = (u_j - u_i)/xi_ij + (u_k - u_i)/xi_ik           (3.1-3.2)
    kappa_ijk = (phi_j - phi_i)/xi_ij + (phi_k - phi_i)/xi_ik  (3.4-3.5)
    psi_ijk = psi_ij + psi_ik,  psi_ab = (w_b - w_a)/xi_ab - n_ab (phi_a + phi_b)/2
                                                               (3.6-3.9)

and their permutations ``jki``, ``kij``; an edge term with ``xi_jk = 0`` (j = k) is zero.
Energy per triplet ``(1/6) K (s_ijk^2 + s_jki^2 + s_kij^2) V_i V_j V_k`` summed over
ordered (j, k) (3.13, 3.22, 3.30). The text's EOM (3.27-3.29) for the degree of freedom
q_i is ``-(1/3) sum_jk K sum_s s ds/dq_i V_j V_k``; its calibration (3.38) is
``K^eps = E / V_T^2``, ``K^psi = k_s mu / V_T^2``, ``K^phi = EI/(A V_T^2)``,
``V_T = sum_j V_j`` (3.36).

``edge_factor`` multiplies the j-k edge terms of the shear measures psi_jki, psi_kij
(Appendix C, after C.6: "the value of 2 should be multiplied by terms theta_12 and n_12");
1 is the text's 3.6, 2 the appendix's correction. ``self_pairs`` includes j = k in the
double sums, as the appendix's local limit (C.1-C.3, j, k in {1, 2}) does.

Euler-Bernoulli beam (ch. 2)
----------------------------
``"text"``: the slope jump at i from the one-sided gradients (2.16, reduced to the beam)
``theta_i = (w_{i+1} - w_i)/dx - (w_i - w_{i-1})/dx``, the nonlocal difference
``theta_ijk = (theta_j - theta_i)/xi_ij + (theta_k - theta_i)/xi_ik`` and the force
density of 2.15, ``rho w_i'' = (2/3) sum_{j != k} beta_hat theta_ijk V_j V_k + f_i``, with
``beta_hat = -3 (EI/A) / (4 xi^2 varsigma)`` (2.19) and varsigma = sum over j in the
horizon and k on the right half of it (2.18), j != k. The xi of 2.19 is read as the
spacing (``xi="spacing"``) or the horizon (``xi="horizon"``). In the long-wave limit this
operator is ``-(m + 1)/2 EI/A w''''`` for ``xi = dx`` and delta = m dx (derivation: the
odd moments cancel and ``sum_{j != k} (|xi_ij| + |xi_ik|)/2 = (2m - 1) m (m + 1) dx``):
exact at m = 1 and stiffer than EB by (m+1)/2 beyond, which is what "stiffer than the
classical EB model" (sec. 2.4.1) measures.

``"consistent"``: the turning angle of the chord polygon j-i-k at the centre, the
nonlocal form of 2.16 with j on the left and k on the right,
``theta_ijk = (w_j - w_i)/xi_ij + (w_k - w_i)/xi_ik``, energy
``(1/2) beta theta_ijk^2 V_i V_j V_k`` summed over those pairs, beta calibrated so that
a uniform curvature stores ``EI/A kappa^2 / 2`` per unit volume. (The printed energy
2.9-2.11 in terms of the differences of the slope jumps is of higher order: its gradient
is a sixth-order operator, not EB.)

Force paths
-----------
The models are linear (small deformation), so the force is a fixed operator ``K`` of the
degrees of freedom. ``kernel="operator"`` (default) assembles it once from the measure
tables and applies it by a row-parallel SpMV in difference form
(:meth:`_TripletModel._operator`, :func:`_share_stencils`); ``kernel="fast"`` is the
triplet kernel (geometry on the fly, the reference), ``kernel="table"`` the generic
measure-table kernel. The energy is always the triplet sum. One SpMV pass gives the
translation and the rotation rows; ``add_force`` keeps the rotation rows for
``add_field_force``, which uses them when the degrees of freedom are unchanged
(:func:`dofs_equal`). The plate's bulk rows go in pairs of opposite offsets
(:func:`plate_csr_spmv`). The text EB variant (slope
jumps) has no measure tables and always uses its own kernel.

Supports (:func:`beam`): ``"ss"`` (w = 0, mirror ghosts w odd, phi even), ``"cc"`` (EB:
w = 0 with even mirror ghosts, i.e. zero slope; Timoshenko: u = w = phi = 0 at the
support node, extrapolated ghosts) and ``"free"``; a cantilever is ``("cc", "free")``. Ghost layers are
2 horizons + 1 spacing deep, so a support particle's force sees an unbroken family. A
Timoshenko clamp cannot be a mirror (w = phi = 0 with w' != 0 has no parity): its ghosts
carry the cubic extrapolation of u, w, phi from the support node and the next three.
The text EB beam needs ghosts beyond a free end too (its slope jump 2.16 is two-sided):
they carry ``w'' = w''' = 0`` to second order (``free_end`` of :func:`beam`).

Rotary inertia of the EB beam (Rayleigh beam): :meth:`TridynEB.rotary_mass` gives the
mass coupling for :class:`upscale.engine.mass.MassMatrixVerlet`.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from upscale.models import register
from upscale.models.base import Model, Needs

__all__ = ["TridynEB", "TridynTimoshenko", "TridynPlate", "line_triplets", "beam", "plate",
           "beam_reference", "navier_mindlin", "literal_local_coefficients", "SUPPORTS",
           "VARIANTS"]

VARIANTS = ("text", "consistent")
SUPPORTS = ("ss", "cc", "free")
FREE_ENDS = ("second-order", "linear")
TEXT_PLATE_TRIPLETS = ("lines", "cross")
SHEAR_INTEGRATIONS = ("ends", "bond")


# =========================================================================== triplets
@nb.njit(cache=True)
def _line_triplets(offsets, neighbors, xi_b, self_pairs, opposite, count_only, off_t, mem_t):
    n = offsets.shape[0] - 1
    pos = 0
    for i in range(n):
        if not count_only:
            off_t[i] = pos
        a, b = offsets[i], offsets[i + 1]
        for p in range(a, b):
            for q in range(p if self_pairs else p + 1, b):
                if opposite and xi_b[p] * xi_b[q] >= 0.0:
                    continue
                if not count_only:
                    mem_t[pos, 0] = i
                    mem_t[pos, 1] = neighbors[p]
                    mem_t[pos, 2] = neighbors[q]
                pos += 1
    if not count_only:
        off_t[n] = pos
    return pos


def line_triplets(family, x0, *, self_pairs=False, opposite=False):
    """Triplets (i; j, k) of a 1D family: unordered pairs of i's neighbours (j = k too if
    ``self_pairs``; only j, k on opposite sides of i if ``opposite``). Returns
    ``(offsets (N+1,) int64, members (nt, 3) int64)`` with members (i, j, k), x_j < x_k
    for opposite pairs."""
    xi = np.ascontiguousarray(family.xi[:, 0])
    dummy_o, dummy_m = np.zeros(1, np.int64), np.zeros((1, 3), np.int64)
    nt = _line_triplets(family.offsets, family.neighbors, xi, self_pairs, opposite, True,
                        dummy_o, dummy_m)
    off = np.zeros(family.n + 1, np.int64)
    mem = np.zeros((nt, 3), np.int64)
    _line_triplets(family.offsets, family.neighbors, xi, self_pairs, opposite, False, off, mem)
    if opposite:
        swap = x0[mem[:, 1], 0] > x0[mem[:, 2], 0]
        mem[swap, 1], mem[swap, 2] = mem[swap, 2].copy(), mem[swap, 1].copy()
    return off, mem


# =========================================================================== kernels
@nb.njit(parallel=True, cache=True)
def text_force_kernel(off_t, mem_t, coef, w_tm, q_nd, out_nd):
    """Centre-only operator (the printed EOM): ``out[i, d] -= sum_t sum_m W s C[t, m, 0, d]``
    with ``s = sum_{a, e} C[t, m, a, e] q[mem[t, a], e]`` over the triplets of centre i.
    Writes only row i: race-free."""
    n = off_t.shape[0] - 1
    nm, nd = coef.shape[1], coef.shape[3]
    for i in nb.prange(n):
        for t in range(off_t[i], off_t[i + 1]):
            for m in range(nm):
                s = 0.0
                for a in range(3):
                    p = mem_t[t, a]
                    for e in range(nd):
                        s += coef[t, m, a, e] * q_nd[p, e]
                ws = w_tm[t, m] * s
                for d in range(nd):
                    out_nd[i, d] -= ws * coef[t, m, 0, d]


@nb.njit(parallel=True, cache=True)
def grad_force_kernel(off_t, mem_t, coef, w_tm, q_nd, buf_cnd):
    """Exact gradient of ``E = sum_t sum_m W s^2 / 2``: ``buf[c, p, d] -= W s C[t, m, a, d]``
    for every member p = mem[t, a]; chunk c of the centres writes only its own buffer
    (race-free; the caller sums over c)."""
    n = off_t.shape[0] - 1
    nm, nd = coef.shape[1], coef.shape[3]
    nc = buf_cnd.shape[0]
    for c in nb.prange(nc):
        i0 = c * n // nc
        i1 = (c + 1) * n // nc
        for t in range(off_t[i0], off_t[i1]):
            for m in range(nm):
                s = 0.0
                for a in range(3):
                    p = mem_t[t, a]
                    for e in range(nd):
                        s += coef[t, m, a, e] * q_nd[p, e]
                ws = w_tm[t, m] * s
                for a in range(3):
                    p = mem_t[t, a]
                    for d in range(nd):
                        buf_cnd[c, p, d] -= ws * coef[t, m, a, d]


@nb.njit(parallel=True, cache=True)
def energy_kernel(off_t, mem_t, coef, w_tm, q_nd, out_n):
    """Energy of each centre's triplets ``sum_t sum_m W s^2 / 2`` (J) into ``out_n``."""
    n = off_t.shape[0] - 1
    nm, nd = coef.shape[1], coef.shape[3]
    for i in nb.prange(n):
        acc = 0.0
        for t in range(off_t[i], off_t[i + 1]):
            for m in range(nm):
                s = 0.0
                for a in range(3):
                    p = mem_t[t, a]
                    for e in range(nd):
                        s += coef[t, m, a, e] * q_nd[p, e]
                acc += 0.5 * w_tm[t, m] * s * s
        out_n[i] = acc


@nb.njit(parallel=True, cache=True)
def bound_kernel(off_t, mem_t, coef, w_tm, scale_d, centre_only, buf_cnd):
    """Gershgorin row bounds of the mass-scaled operator: row (p, d) gets
    ``sum W |C[a, d]| sum_{b, e} |C[b, e]| scale[e] / scale[d]`` (scale = 1/sqrt(inertia)
    per dof kind), for the members p = mem[t, a] (only the centre if ``centre_only``)."""
    n = off_t.shape[0] - 1
    nm, nd = coef.shape[1], coef.shape[3]
    nc = buf_cnd.shape[0]
    for c in nb.prange(nc):
        i0 = c * n // nc
        i1 = (c + 1) * n // nc
        for t in range(off_t[i0], off_t[i1]):
            for m in range(nm):
                tot = 0.0
                for a in range(3):
                    for e in range(nd):
                        tot += abs(coef[t, m, a, e]) * scale_d[e]
                na = 1 if centre_only else 3
                for a in range(na):
                    p = mem_t[t, a]
                    for d in range(nd):
                        buf_cnd[c, p, d] += w_tm[t, m] * abs(coef[t, m, a, d]) * tot / scale_d[d]


@nb.njit(cache=True, inline="always")
def _timo_measures(g_t6, t, q_nd, i, j, k, ef):
    """The nine measures of triplet t = (i; j, k) (3.1-3.9); ``g_t6[t]`` holds
    ``1/xi_ij, 1/xi_ik, 1/xi_jk (0 if j = k), n_ij, n_ik, n_jk``."""
    ia = g_t6[t, 0]
    ib = g_t6[t, 1]
    ic = g_t6[t, 2]
    nij = g_t6[t, 3]
    nik = g_t6[t, 4]
    njk = g_t6[t, 5]
    ui, uj, uk = q_nd[i, 0], q_nd[j, 0], q_nd[k, 0]
    wi, wj, wk = q_nd[i, 1], q_nd[j, 1], q_nd[k, 1]
    pi_, pj, pk = q_nd[i, 2], q_nd[j, 2], q_nd[k, 2]
    e1 = (uj - ui) * ia + (uk - ui) * ib
    e2 = (uk - uj) * ic + (ui - uj) * ia
    e3 = (uj - uk) * ic + (ui - uk) * ib
    k1 = (pj - pi_) * ia + (pk - pi_) * ib
    k2 = (pk - pj) * ic + (pi_ - pj) * ia
    k3 = (pj - pk) * ic + (pi_ - pk) * ib
    s1 = (wj - wi) * ia + (wk - wi) * ib - 0.5 * nij * (pi_ + pj) - 0.5 * nik * (pi_ + pk)
    s2 = ef * ((wk - wj) * ic - 0.5 * njk * (pj + pk)) + (wi - wj) * ia + 0.5 * nij * (pj + pi_)
    s3 = ef * ((wj - wk) * ic + 0.5 * njk * (pk + pj)) + (wi - wk) * ib + 0.5 * nik * (pk + pi_)
    return e1, e2, e3, k1, k2, k3, s1, s2, s3, ia, ib, ic, nij, nik, njk


@nb.njit(parallel=True, cache=True)
def timo_text_kernel(off_t, mem_t, pw_t, g_t6, q_nd, Ke, Kp, Ks, ef, out_nd):
    """Printed EOM 3.27-3.29 (particle forces, ``pw_t`` = pair weight x V_i V_j V_k):
    the centre's own derivative of its triplets' energy (geometry ``g_t6`` as in
    ``_timo_measures``)."""
    n = off_t.shape[0] - 1
    for i in nb.prange(n):
        fu = 0.0
        fw = 0.0
        fp = 0.0
        for t in range(off_t[i], off_t[i + 1]):
            j, k = mem_t[t, 1], mem_t[t, 2]
            e1, e2, e3, k1, k2, k3, s1, s2, s3, ia, ib, ic, nij, nik, njk = \
                _timo_measures(g_t6, t, q_nd, i, j, k, ef)
            w = pw_t[t]
            fu -= w * Ke * (-(ia + ib) * e1 + ia * e2 + ib * e3)
            fp -= w * Kp * (-(ia + ib) * k1 + ia * k2 + ib * k3)
            fw -= w * Ks * (-(ia + ib) * s1 + ia * s2 + ib * s3)
            fp -= w * Ks * (-0.5 * (nij + nik) * s1 + 0.5 * nij * s2 + 0.5 * nik * s3)
        out_nd[i, 0] += fu
        out_nd[i, 1] += fw
        out_nd[i, 2] += fp


@nb.njit(parallel=True, cache=True)
def timo_grad_kernel(off_t, mem_t, pw_t, g_t6, q_nd, Ke, Kp, Ks, ef, buf_cnd):
    """Exact gradient of the Timoshenko energy 3.11-3.13 (chunked over centres, race-free:
    chunk c writes only ``buf[c]``; the centre's own share is summed in registers;
    geometry ``g_t6`` as in ``_timo_measures``)."""
    n = off_t.shape[0] - 1
    nc = buf_cnd.shape[0]
    for ch in nb.prange(nc):
        i0 = ch * n // nc
        i1 = (ch + 1) * n // nc
        for i in range(i0, i1):
            fu = 0.0
            fw = 0.0
            fp = 0.0
            for t in range(off_t[i], off_t[i + 1]):
                j, k = mem_t[t, 1], mem_t[t, 2]
                e1, e2, e3, k1, k2, k3, s1, s2, s3, ia, ib, ic, nij, nik, njk = \
                    _timo_measures(g_t6, t, q_nd, i, j, k, ef)
                w = pw_t[t]
                g1, g2, g3 = w * Ke * e1, w * Ke * e2, w * Ke * e3
                fu -= -(ia + ib) * g1 + ia * g2 + ib * g3
                buf_cnd[ch, j, 0] -= ia * g1 - (ic + ia) * g2 + ic * g3
                buf_cnd[ch, k, 0] -= ib * g1 + ic * g2 - (ic + ib) * g3
                h1, h2, h3 = w * Kp * k1, w * Kp * k2, w * Kp * k3
                c1, c2, c3 = w * Ks * s1, w * Ks * s2, w * Ks * s3
                fp -= -(ia + ib) * h1 + ia * h2 + ib * h3 \
                    - 0.5 * (nij + nik) * c1 + 0.5 * nij * c2 + 0.5 * nik * c3
                buf_cnd[ch, j, 2] -= ia * h1 - (ic + ia) * h2 + ic * h3 \
                    - 0.5 * nij * c1 + (0.5 * nij - 0.5 * ef * njk) * c2 + 0.5 * ef * njk * c3
                buf_cnd[ch, k, 2] -= ib * h1 + ic * h2 - (ic + ib) * h3 \
                    - 0.5 * nik * c1 - 0.5 * ef * njk * c2 + (0.5 * ef * njk + 0.5 * nik) * c3
                fw -= -(ia + ib) * c1 + ia * c2 + ib * c3
                buf_cnd[ch, j, 1] -= ia * c1 - (ef * ic + ia) * c2 + ef * ic * c3
                buf_cnd[ch, k, 1] -= ib * c1 + ef * ic * c2 - (ef * ic + ib) * c3
            buf_cnd[ch, i, 0] += fu
            buf_cnd[ch, i, 1] += fw
            buf_cnd[ch, i, 2] += fp


@nb.njit(parallel=True, cache=True)
def eb_grad_kernel(off_t, mem_t, w_t, x_n, w_n, buf_cn):
    """Exact gradient of the turning-angle energy ``sum_t w_t theta_ijk^2 / 2``
    (chunked, race-free)."""
    n = off_t.shape[0] - 1
    nc = buf_cn.shape[0]
    for ch in nb.prange(nc):
        i0 = ch * n // nc
        i1 = (ch + 1) * n // nc
        for t in range(off_t[i0], off_t[i1]):
            i, j, k = mem_t[t, 0], mem_t[t, 1], mem_t[t, 2]
            ia = 1.0 / abs(x_n[j] - x_n[i])
            ib = 1.0 / abs(x_n[k] - x_n[i])
            g = w_t[t] * ((w_n[j] - w_n[i]) * ia + (w_n[k] - w_n[i]) * ib)
            buf_cn[ch, i] += (ia + ib) * g
            buf_cn[ch, j] -= ia * g
            buf_cn[ch, k] -= ib * g


@nb.njit(parallel=True, cache=True)
def plate_grad_kernel(off_t, mem_t, w_t, x_nc, q_nd, K_m, buf_cnd):
    """Exact gradient of the plate energy (``TridynPlate``) over the L-triplets
    (i; j on the x line, k on the y line), geometry on the fly; chunked, race-free.
    ``q`` columns: u, v, w, phi_x, phi_y; ``K_m`` the eight measure moduli."""
    n = off_t.shape[0] - 1
    nc = buf_cnd.shape[0]
    r2 = 1.0 / np.sqrt(2.0)
    for ch in nb.prange(nc):
        i0 = ch * n // nc
        i1 = (ch + 1) * n // nc
        for t in range(off_t[i0], off_t[i1]):
            i, j, k = mem_t[t, 0], mem_t[t, 1], mem_t[t, 2]
            ix = 1.0 / (x_nc[j, 0] - x_nc[i, 0])
            iy = 1.0 / (x_nc[k, 1] - x_nc[i, 1])
            gxu = (q_nd[j, 0] - q_nd[i, 0]) * ix
            gyu = (q_nd[k, 0] - q_nd[i, 0]) * iy
            gxv = (q_nd[j, 1] - q_nd[i, 1]) * ix
            gyv = (q_nd[k, 1] - q_nd[i, 1]) * iy
            gxw = (q_nd[j, 2] - q_nd[i, 2]) * ix
            gyw = (q_nd[k, 2] - q_nd[i, 2]) * iy
            gxa = (q_nd[j, 3] - q_nd[i, 3]) * ix
            gya = (q_nd[k, 3] - q_nd[i, 3]) * iy
            gxb = (q_nd[j, 4] - q_nd[i, 4]) * ix
            gyb = (q_nd[k, 4] - q_nd[i, 4]) * iy
            w = w_t[t]
            g0 = w * K_m[0] * (gxu + gyv) * r2
            g1 = w * K_m[1] * (gxu - gyv) * r2
            g2 = w * K_m[2] * (gyu + gxv)
            g3 = w * K_m[3] * (gxa + gyb) * r2
            g4 = w * K_m[4] * (gxa - gyb) * r2
            g5 = w * K_m[5] * (gya + gxb)
            g6 = w * K_m[6] * (gxw - 0.5 * (q_nd[i, 3] + q_nd[j, 3]))
            g7 = w * K_m[7] * (gyw - 0.5 * (q_nd[i, 4] + q_nd[k, 4]))
            # dE/d(gradient) per dof: (x part, y part)
            ex_u = (g0 + g1) * r2
            ey_u = g2
            ex_v = g2
            ey_v = (g0 - g1) * r2
            ex_w = g6
            ey_w = g7
            ex_a = (g3 + g4) * r2
            ey_a = g5
            ex_b = g5
            ey_b = (g3 - g4) * r2
            buf_cnd[ch, j, 0] -= ex_u * ix
            buf_cnd[ch, k, 0] -= ey_u * iy
            buf_cnd[ch, i, 0] += ex_u * ix + ey_u * iy
            buf_cnd[ch, j, 1] -= ex_v * ix
            buf_cnd[ch, k, 1] -= ey_v * iy
            buf_cnd[ch, i, 1] += ex_v * ix + ey_v * iy
            buf_cnd[ch, j, 2] -= ex_w * ix
            buf_cnd[ch, k, 2] -= ey_w * iy
            buf_cnd[ch, i, 2] += ex_w * ix + ey_w * iy
            buf_cnd[ch, j, 3] -= ex_a * ix - 0.5 * g6
            buf_cnd[ch, k, 3] -= ey_a * iy
            buf_cnd[ch, i, 3] += ex_a * ix + ey_a * iy + 0.5 * g6
            buf_cnd[ch, j, 4] -= ex_b * ix
            buf_cnd[ch, k, 4] -= ey_b * iy - 0.5 * g7
            buf_cnd[ch, i, 4] += ex_b * ix + ey_b * iy + 0.5 * g7


@nb.njit(parallel=True, cache=True)
def slope_jump_kernel(left_n, right_n, x_n, w_n, out_n):
    """theta_i = (w_r - w_i)/(x_r - x_i) - (w_i - w_l)/(x_i - x_l) (eq. 2.16 on a line);
    zero where a neighbour is missing."""
    n = w_n.shape[0]
    for i in nb.prange(n):
        l, r = left_n[i], right_n[i]
        if l < 0 or r < 0:
            out_n[i] = 0.0
        else:
            out_n[i] = (w_n[r] - w_n[i]) / (x_n[r] - x_n[i]) - (w_n[i] - w_n[l]) / (x_n[i] - x_n[l])


@nb.njit(parallel=True, cache=True)
def eb_text_force_kernel(off_t, mem_t, inv_a_t, inv_b_t, g_t, theta_n, out_n):
    """Eq. 2.15: ``out[i] += sum_t g_t ((theta_j - theta_i)/xi_ij + (theta_k - theta_i)/xi_ik)``
    with ``g_t`` = (2/3) beta_hat V_i V_j V_k x 2 (both orders of the pair)."""
    n = off_t.shape[0] - 1
    for i in nb.prange(n):
        acc = 0.0
        for t in range(off_t[i], off_t[i + 1]):
            j, k = mem_t[t, 1], mem_t[t, 2]
            acc += g_t[t] * ((theta_n[j] - theta_n[i]) * inv_a_t[t]
                             + (theta_n[k] - theta_n[i]) * inv_b_t[t])
        out_n[i] += acc


@nb.njit(cache=True)
def _find_col(indices, a, b, col):
    """Position of ``col`` in the sorted ``indices[a:b]`` (binary search)."""
    lo, hi = a, b - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if indices[mid] < col:
            lo = mid + 1
        else:
            hi = mid
    return lo


@nb.njit(cache=True)
def assemble_block_csr(mem_t, coef, w_tm, centre_only, indptr, indices, slot_of, val):
    """Values of the assembled operator ``K = -sum_t sum_m W C_m C_m^T``: for every
    triplet t, measure m, row member a (only the centre if ``centre_only``: the printed,
    centre-only EOM), column member b and dofs (d, e)::

        val[pos(mem[t, a], mem[t, b]), slot_of[d, e]] -= W[t, m] C[t, m, a, d] C[t, m, b, e]

    ``pos`` is the CSR position of the particle pair (row, column). Serial (members of a
    triplet share rows), run once."""
    nt, nm = coef.shape[0], coef.shape[1]
    nd = coef.shape[3]
    na = 1 if centre_only else 3
    for t in range(nt):
        for m in range(nm):
            w = w_tm[t, m]
            for a in range(na):
                r = mem_t[t, a]
                for d in range(nd):
                    cad = coef[t, m, a, d]
                    if cad == 0.0:
                        continue
                    for b in range(3):
                        pos = _find_col(indices, indptr[r], indptr[r + 1], mem_t[t, b])
                        for e in range(nd):
                            cbe = coef[t, m, b, e]
                            if cbe == 0.0:
                                continue
                            val[pos, slot_of[d, e]] -= w * cad * cbe


@nb.njit(parallel=True, cache=True)
def gather_dofs(y, x0, fld, kind_a, comp_a, q):
    """``q[i, a] = y[i, c] - x0[i, c]`` (kind 0) or ``fld[i, c]`` (kind 1), c = comp[a]."""
    n, nd = q.shape
    for i in nb.prange(n):
        for a in range(nd):
            c = comp_a[a]
            if kind_a[a] == 0:
                q[i, a] = y[i, c] - x0[i, c]
            else:
                q[i, a] = fld[i, c]


@nb.njit(cache=True)
def dofs_equal(y, x0, fld, kind_a, comp_a, q):
    """True if :func:`gather_dofs` of (y, x0, fld) would give exactly ``q`` (stops at the
    first difference)."""
    n, nd = q.shape
    if y.shape[0] != n or fld.shape[0] != n:
        return False
    for i in range(n):
        for a in range(nd):
            c = comp_a[a]
            v = y[i, c] - x0[i, c] if kind_a[a] == 0 else fld[i, c]
            if v != q[i, a]:
                return False
    return True


@nb.njit(parallel=True, cache=True)
def block_csr_spmv(row_pat, indptr, indices, val, slot_r, slot_c, q, row_on, dest_kind, dest_comp,
                   inv_v, out0, out1):
    """Row-parallel ``f = K q`` over the slots (row dof, column dof) of the block
    operator: row i uses stencil ``row_pat[i]``, whose entries ``indptr[p]:indptr[p + 1]``
    hold column offsets ``indices`` relative to i and values ``val``:
    ``f[i, r] = R[i, s] q[i, c] + sum val[., s] (q[i + indices[.], c] - q[i, c])`` (entry
    ``a`` of a stencil is i itself and holds the row sum R) for the slots s = (r, c) with ``row_on[r]``, written as ``out[i, comp] += f[i, r] inv_v[i]`` into
    ``out0`` (dest kind 0) or ``out1`` (kind 1). Each i writes only its own row: race-free."""
    n = row_pat.shape[0]
    ns = slot_r.shape[0]
    for i in nb.prange(n):
        a, b = indptr[row_pat[i]], indptr[row_pat[i] + 1]
        for s in range(ns):
            r = slot_r[s]
            if not row_on[r]:
                continue
            c = slot_c[s]
            qi = q[i, c]
            acc = val[a, s] * qi
            for p in range(a + 1, b):
                acc += val[p, s] * (q[i + indices[p], c] - qi)
            if dest_kind[r] == 0:
                out0[i, dest_comp[r]] += acc * inv_v[i]
            else:
                out1[i, dest_comp[r]] += acc * inv_v[i]


@nb.njit(parallel=True, cache=True)
def timo_csr_spmv(row_pat, indptr, indices, val, q, do_t, do_r, inv_v, out_y, out_rot):
    """Block SpMV of the beam (slots u-u, w-w, w-phi, phi-w, phi-phi; q columns u, w,
    phi) in difference form (see :meth:`_TripletModel._operator`; entry ``a`` of a
    stencil is the particle itself and holds the row sums R):
    ``f_i = R_i q_i + sum_{c != i} K_ic (q_c - q_i)``. Translation rows
    ``out_y[i, (0, 2)] += f_i[u, w] / V_i`` if ``do_t``, the rotation row
    ``out_rot[i, 0] += f_i[phi] / V_i`` if ``do_r``. One accumulator per row dof; each i
    writes only its own row: race-free."""
    n = row_pat.shape[0]
    for i in nb.prange(n):
        a, b = indptr[row_pat[i]], indptr[row_pat[i] + 1]
        qu, qw, qp = q[i, 0], q[i, 1], q[i, 2]
        if do_t:
            fu = val[a, 0] * qu
            fw = val[a, 1] * qw + val[a, 2] * qp
            for p in range(a + 1, b):
                c = nb.uint64(i + indices[p])  # >= 0: no wraparound test
                fu += val[p, 0] * (q[c, 0] - qu)
                fw += val[p, 1] * (q[c, 1] - qw) + val[p, 2] * (q[c, 2] - qp)
            out_y[i, 0] += fu * inv_v[i]
            out_y[i, 2] += fw * inv_v[i]
        if do_r:
            fp = val[a, 3] * qw + val[a, 4] * qp
            for p in range(a + 1, b):
                c = nb.uint64(i + indices[p])  # >= 0: no wraparound test
                fp += val[p, 3] * (q[c, 1] - qw) + val[p, 4] * (q[c, 2] - qp)
            out_rot[i, 0] += fp * inv_v[i]


@nb.njit(parallel=True, cache=True)
def plate_csr_spmv(row_pat, indptr, indices, val, bulk, h_off, h_val, q, do_t, do_r, inv_v, out_y,
                   out_rot):
    """Block SpMV of the plate (q columns u, v, w, phi_x, phi_y; slots u-u, u-v, v-u,
    v-v, then w, phi_x, phi_y each against w, phi_x, phi_y) in the difference form of
    :func:`timo_csr_spmv`: translation rows into ``out_y[i, 0:3]`` if ``do_t``, rotation
    rows into ``out_rot[i, 0:2]`` if ``do_r``, divided by V_i; race-free (row i only).

    Rows of the bulk stencil (``row_pat[i] == bulk``; ``bulk = -1``: none) are taken in
    pairs of opposite offsets ``+-o`` (``h_off``, o > 0): a symmetric translation-invariant
    operator has ``K_{-o} = K_o^T``, and the point symmetry of the lattice makes the
    in-plane and rotation-rotation blocks even and the w-phi coupling odd, so
    ``K_o d_+ + K_o^T d_- = S_o (d_+ + d_-) + A_o (d_+ - d_-)`` with the 7 values of the
    even part ``S_o`` (u-u, u-v = v-u, v-v, w-w, phi_x-phi_x, phi_x-phi_y = phi_y-phi_x,
    phi_y-phi_y) and the 2 of the odd part ``A_o`` (w-phi_x = -phi_x-w, w-phi_y =
    -phi_y-w), ``h_val[h] = (uu, uv, vv, ww, xx, xy, yy, wx, wy)``: 9 values and 13
    multiply-adds per pair of neighbours instead of 26 of each (:func:`plate_half_stencil`
    checks the symmetries). The diagonal entry (row sums) is applied in full."""
    n = row_pat.shape[0]
    nh = h_off.shape[0]
    for i in nb.prange(n):
        pat = row_pat[i]
        a, b = indptr[pat], indptr[pat + 1]
        q0, q1, q2, q3, q4 = q[i, 0], q[i, 1], q[i, 2], q[i, 3], q[i, 4]
        fu = val[a, 0] * q0 + val[a, 1] * q1
        fv = val[a, 2] * q0 + val[a, 3] * q1
        fw = val[a, 4] * q2 + val[a, 5] * q3 + val[a, 6] * q4
        fa = val[a, 7] * q2 + val[a, 8] * q3 + val[a, 9] * q4
        fb = val[a, 10] * q2 + val[a, 11] * q3 + val[a, 12] * q4
        if pat == bulk:
            for h in range(nh):
                cp = nb.uint64(i + h_off[h])  # both >= 0 on a bulk row: no wraparound test
                cm = nb.uint64(i - h_off[h])
                su = q[cp, 0] + q[cm, 0] - 2.0 * q0
                sv = q[cp, 1] + q[cm, 1] - 2.0 * q1
                sw = q[cp, 2] + q[cm, 2] - 2.0 * q2
                sa = q[cp, 3] + q[cm, 3] - 2.0 * q3
                sb = q[cp, 4] + q[cm, 4] - 2.0 * q4
                aw = q[cp, 2] - q[cm, 2]
                aa = q[cp, 3] - q[cm, 3]
                ab = q[cp, 4] - q[cm, 4]
                fu += h_val[h, 0] * su + h_val[h, 1] * sv
                fv += h_val[h, 1] * su + h_val[h, 2] * sv
                fw += h_val[h, 3] * sw + h_val[h, 7] * aa + h_val[h, 8] * ab
                fa += h_val[h, 4] * sa + h_val[h, 5] * sb - h_val[h, 7] * aw
                fb += h_val[h, 5] * sa + h_val[h, 6] * sb - h_val[h, 8] * aw
        else:
            for p in range(a + 1, b):
                c = nb.uint64(i + indices[p])  # >= 0: no wraparound test
                du, dv = q[c, 0] - q0, q[c, 1] - q1
                dw, da, db = q[c, 2] - q2, q[c, 3] - q3, q[c, 4] - q4
                fu += val[p, 0] * du + val[p, 1] * dv
                fv += val[p, 2] * du + val[p, 3] * dv
                fw += val[p, 4] * dw + val[p, 5] * da + val[p, 6] * db
                fa += val[p, 7] * dw + val[p, 8] * da + val[p, 9] * db
                fb += val[p, 10] * dw + val[p, 11] * da + val[p, 12] * db
        s = inv_v[i]
        if do_t:
            out_y[i, 0] += fu * s
            out_y[i, 1] += fv * s
            out_y[i, 2] += fw * s
        if do_r:
            out_rot[i, 0] += fa * s
            out_rot[i, 1] += fb * s


# slot of the transposed block entry, plate slot order (see plate_csr_spmv)
_PLATE_T = np.array([0, 2, 1, 3, 4, 7, 10, 5, 8, 11, 6, 9, 12])


def plate_half_stencil(op, tol=1e-12):
    """The plate's bulk stencil as pairs of opposite offsets for :func:`plate_csr_spmv`:
    ``(bulk pattern, h_off (H,) int64, h_val (H, 9))``, or ``(-1, empty, empty)`` when the
    most frequent stencil is not symmetric under ``o -> -o`` with ``K_{-o} = K_o^T`` and
    the parities of :func:`plate_csr_spmv`, each to ``tol`` x (largest |value| of its
    slot); the pair form then is not used and every row goes through the stored entries.
    Offsets of a bulk row must be in-range for every row of that stencil (they are: it is
    the same set of particles shifted)."""
    none = (-1, np.zeros(0, np.int64), np.zeros((0, 9)))
    rp = op["row_pat"]
    if rp.size == 0:
        return none
    bulk = int(np.bincount(rp).argmax())
    a, b = op["indptr"][bulk], op["indptr"][bulk + 1]
    off, V = op["indices"][a:b].astype(np.int64), op["val"][a:b]
    scale = np.abs(op["val"]).max(axis=0)
    scale[scale == 0] = 1.0
    pos = {int(o): r for r, o in enumerate(off)}
    hs, hv = [], []
    for r, o in enumerate(off):
        if o <= 0:
            continue
        m = pos.get(-int(o))
        if m is None:
            return none
        Kp = V[r]
        sl = np.arange(13)
        bad = np.abs(V[m] - Kp[_PLATE_T]) > tol * scale                        # K_{-o} = K_o^T
        bad |= np.isin(sl, (1, 9)) & (np.abs(Kp - Kp[_PLATE_T]) > tol * scale)  # even
        bad |= np.isin(sl, (5, 6)) & (np.abs(Kp + Kp[_PLATE_T]) > tol * scale)  # odd
        if bad.any():
            return none
        hs.append(o)
        hv.append([Kp[0], Kp[1], Kp[3], Kp[4], Kp[8], Kp[9], Kp[12], Kp[5], Kp[6]])
    return bulk, np.array(hs, np.int64), np.ascontiguousarray(np.array(hv).reshape(-1, 9))


@nb.njit(cache=True)
def assemble_bond_shear(mem_t, coef, w_tm, m0, rank, order, dxo, slot_of, indptr, indices, val,
                        rsum):
    """Operator values and row sums of the bond-integrated shear measures (Timoshenko,
    ``shear_integration="bond"``): measure ``m0 + p`` (p = 0, 1, 2) of triplet t is
    ``sum_a C[t, m, a, 1] chi[mem[t, a]]`` with ``chi = w - Phi``; written on (w, phi) of
    the particles of the triplet's window (ranks ``rmin..rmax`` along the chain, ``order``
    the particle at each rank, ``dxo`` the spacings) as ``c_w[a] = C[a]`` and
    ``c_phi[l] = -sum_a C[a] d(Phi_a - Phi_i)/d phi_l`` (the differences of the cumulative
    trapezoid, exact: ``sum_a C[a] = 0``); then ``K -= W c c^T`` and the row sums as in
    :func:`assemble_row_sums`. Serial, run once."""
    nt = mem_t.shape[0]
    cl = np.zeros((64, 2))
    for t in range(nt):
        i = mem_t[t, 0]
        r0 = rank[i]
        rmin, rmax = r0, r0
        for a in range(1, 3):
            ra = rank[mem_t[t, a]]
            rmin = min(rmin, ra)
            rmax = max(rmax, ra)
        L = rmax - rmin + 1
        for p in range(3):
            m = m0 + p
            w = w_tm[t, m]
            if w == 0.0:
                continue
            cl[:L, :] = 0.0
            tot = 0.0
            for a in range(3):
                al = coef[t, m, a, 1]
                if al == 0.0:
                    continue
                ra = rank[mem_t[t, a]]
                cl[ra - rmin, 0] += al
                tot += abs(al)
                # d(Phi_ra - Phi_r0)/d phi: +-d/2 on both ends of every edge between them
                lo, hi, sg = (r0, ra, 1.0) if ra > r0 else (ra, r0, -1.0)
                for e in range(lo, hi):
                    h = 0.5 * dxo[e] * al * sg
                    cl[e - rmin, 1] -= h
                    cl[e + 1 - rmin, 1] -= h
            mu_w = 0.0
            mu_p = 0.0
            for l in range(L):
                mu_w += cl[l, 0]
                mu_p += cl[l, 1]
            if abs(mu_w) <= 1e-12 * tot:
                mu_w = 0.0
            for la in range(L):
                ra_ = order[rmin + la]
                for d in range(2):
                    cad = cl[la, d]
                    if cad == 0.0:
                        continue
                    sd = 1 + d            # dof index in (u, w, phi)
                    rsum[ra_, slot_of[sd, 1]] -= w * cad * mu_w
                    rsum[ra_, slot_of[sd, 2]] -= w * cad * mu_p
                    for lb in range(L):
                        pos = _find_col(indices, indptr[ra_], indptr[ra_ + 1], order[rmin + lb])
                        for e in range(2):
                            cbe = cl[lb, e]
                            if cbe != 0.0:
                                val[pos, slot_of[sd, 1 + e]] -= w * cad * cbe


@nb.njit(cache=True)
def assemble_row_sums(mem_t, coef, w_tm, centre_only, slot_of, rsum):
    """Row sums ``R[i, slot(d, e)] = sum_c K[(i, d), (c, e)]``, the force on dof d of i
    under a uniform unit field in dof e, assembled per triplet as
    ``-W C[a, d] mu_e`` with ``mu_e = sum_b C[t, m, b, e]`` the measure of that uniform
    field, snapped to zero where it is a cancelling difference
    (``|mu_e| <= 1e-12 sum_b |C|``): derivative measures of a uniform field vanish
    exactly, so translation-invariant rows get R = 0 exactly, not round-off."""
    nt, nm = coef.shape[0], coef.shape[1]
    nd = coef.shape[3]
    na = 1 if centre_only else 3
    for t in range(nt):
        for m in range(nm):
            w = w_tm[t, m]
            for e in range(nd):
                mu = 0.0
                mabs = 0.0
                for b in range(3):
                    mu += coef[t, m, b, e]
                    mabs += abs(coef[t, m, b, e])
                if abs(mu) <= 1e-12 * mabs:
                    continue
                for a in range(na):
                    r = mem_t[t, a]
                    for d in range(nd):
                        cad = coef[t, m, a, d]
                        if cad != 0.0:
                            rsum[r, slot_of[d, e]] -= w * cad * mu


def _share_stencils(indptr, indices, val, tol):
    """Rows of the assembled operator that are the same stencil share one stored copy.

    Row i is the list of (column offset ``indices - i``, values); two rows are the same
    stencil when the offsets are equal and every value agrees on the grid
    ``tol x (largest |value| of its slot)`` (``np.rint``). On a uniform lattice the bulk
    rows differ only by the round-off of the reference coordinates in ``1/xi``
    (relative ``eps |x| / dx``, 1e-11 on a 1e5-particle chain), so they collapse to one
    stencil and the SpMV streams one int32 per row instead of its values and columns; a
    row is stored with the values of the first row of its class, so a row changes by at
    most ``tol`` x (slot maximum) per entry (the models' default ``stencil_tol = 1e-12``,
    the size of that coordinate round-off; ``K`` is then symmetric to the same level, not
    bit for bit). A coarse grid is not harmless: the long-wave dispersion (flexural
    frequencies ~ (k dx)^2 (k h)^2 / 12 of the entries) feels the mismatch between
    shared rows first. ``tol = 0`` keeps every row (plain CSR with relative columns,
    memory-bound). Returns ``(row_pat (N,) int32, indptr (P+1,) int64, offsets int32,
    values (nnz_P, n_slots))``."""
    n = indptr.shape[0] - 1
    lens = np.diff(indptr)
    rel = (indices.astype(np.int64) - np.repeat(np.arange(n), lens)).astype(np.int32)
    if tol <= 0:
        return np.arange(n, dtype=np.int32), indptr, rel, val
    scale = np.abs(val).max(axis=0) if val.size else np.ones(val.shape[1])
    scale[scale == 0] = 1.0
    grid = np.rint(val / (scale * tol)).astype(np.int64)
    seen = {}
    row_pat = np.empty(n, np.int32)
    reps = []
    for i in range(n):
        a, b = indptr[i], indptr[i + 1]
        k = (rel[a:b].tobytes(), grid[a:b].tobytes())
        pid = seen.get(k)
        if pid is None:
            pid = seen[k] = len(reps)
            reps.append(i)
        row_pat[i] = pid
    reps = np.array(reps, np.int64)
    plen = lens[reps]
    pptr = np.zeros(reps.size + 1, np.int64)
    pptr[1:] = np.cumsum(plen)
    take = np.concatenate([np.arange(indptr[r], indptr[r + 1]) for r in reps]) if reps.size \
        else np.zeros(0, np.int64)
    return (row_pat, pptr, np.ascontiguousarray(rel[take]),
            np.ascontiguousarray(val[take]))


def _nchunks(n):
    return max(1, min(int(nb.get_num_threads()), n))


# =========================================================================== helpers
def _positive(**kw):
    for k, v in kw.items():
        if not (v is not None and np.isfinite(v) and v > 0):
            raise ValueError(f"{k} must be positive, got {v!r}")


def _variant(v):
    if v not in VARIANTS:
        raise ValueError(f"unknown variant {v!r}; valid: {', '.join(VARIANTS)}")
    return v


def _check_triplets(family, off_t, ends_only=True):
    """Refuse a horizon that leaves a particle without triplets: only a chain's end
    particle (one neighbour; or, for opposite pairs, all neighbours on one side) may have
    none."""
    none = np.diff(off_t) == 0
    bad = none & (family.counts == 0) if not ends_only else none & (family.counts != 1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"horizon {family.horizon:.6g} m leaves particle {i} without triplets "
                         f"({int(family.counts[i])} neighbours); valid: a horizon that gives every "
                         f"particle two neighbours (delta/dx >= 1 on a uniform chain)")


def _check_line(system, family, name):
    if system.dim != 1:
        raise ValueError(f"model {name!r} needs a 1D body (line_lattice), got dim={system.dim}")


class _TripletModel(Model):
    """Shared machinery: measure tables ``coef (nt, M, 3, nd)``, weights ``W (nt, M)``,
    dof gather/scatter, forces, energy, bounds."""

    force_kind = "density"
    nd = 1
    dof_map: tuple = ()  # ("y", c) or (field, c) per generalised dof

    def _gather(self, state):
        n = state.y.shape[0]
        q = np.empty((n, self.nd))
        for a, (kind, c) in enumerate(self.dof_map):
            q[:, a] = (state.y[:, c] - state.x0[:, c]) if kind == "y" else state.fields[kind][:, c]
        return q

    kernel = "operator"
    stencil_tol = 1e-12     # rows equal on this grid share one stored stencil (0: none)
    fuse_rows = True        # add_force also computes the rotation rows (False: two passes)

    def _fast_force(self, q):
        return None

    def _has_operator(self):
        return self.kernel == "operator" and getattr(self, "coef", None) is not None

    def _operator(self):
        """The model's linear force operator ``K`` ((N nd) x (N nd), ``f = K q``) assembled
        once from the measure tables: a block CSR with one row per particle, int32 column
        indices (the particles sharing a triplet with it, sorted) and float64 values
        ``(nnz, n_slots)``, one slot per structurally nonzero (row dof, column dof) pair of
        the blocks (Timoshenko: u-u, w-w, w-phi, phi-w, phi-phi; plate: 13 of 25).
        ``K = -sum_t sum_m W_tm C_tm C_tm^T`` (the exact gradient of the energy, so
        ``K`` is symmetric) for "consistent"; for "text" only the centre's rows
        ``-sum_t sum_m W_tm C_tm[0] C_tm^T`` (the printed EOM, not symmetric). Because
        the models are linear (small deformation), the triplet sums are a fixed operator
        of the dofs and one SpMV per step replaces them: a row costs (number of coupled
        particles) x (slots) multiply-adds instead of a centre's m(2m-1) (beam) or 4 m^2
        (plate) triplets of eight or nine measures over three particles.

        The product is taken in difference form, ``f_i = R_i q_i + sum_{c != i} K_ic
        (q_c - q_i)`` with the row sums ``R`` (exactly zero for the translation-invariant
        rows) in the diagonal entry, which is stored first: like the triplet kernel, it
        differences the field before multiplying by the large ``1/xi^2`` entries, so a
        long wave keeps its digits (the flexural frequency is ~ (k dx)^2 (k h)^2 of the
        entries and the plain ``sum_c K_ic q_c`` loses it to cancellation)."""
        op = getattr(self, "_op", None)
        if op is not None and op[0] is self.coef and op[2] == self.stencil_tol \
                and op[3] == getattr(self, "pair_stencil", None):
            return op[1]
        n = self.system.n
        coef, mem = self.coef, self.mem_t
        nd = self.nd
        centre_only = self.variant == "text"
        # structurally coupled (d, e) pairs: dofs that share a measure
        used = np.abs(coef).max(axis=(0, 2)) > 0            # (M, nd)
        cpl = np.zeros((nd, nd), bool)
        for um in used:
            cpl |= np.outer(um, um)
        slot_r, slot_c = np.nonzero(cpl)
        slot_of = np.full((nd, nd), -1, np.int64)
        slot_of[slot_r, slot_c] = np.arange(slot_r.size)
        rows_a = (0,) if centre_only else (0, 1, 2)
        rows = np.concatenate([np.repeat(mem[:, a], 3) for a in rows_a])
        cols = np.concatenate([mem.reshape(-1) for _ in rows_a])
        ar = np.arange(n, dtype=np.int64)
        extra = self._op_extra_pairs()
        if extra is not None:
            rows, cols = np.concatenate([rows, extra[0]]), np.concatenate([cols, extra[1]])
        key = np.unique(np.concatenate([rows.astype(np.int64) * n + cols, ar * n + ar]))
        r_u, c_u = key // n, key % n
        indptr = np.zeros(n + 1, np.int64)
        indptr[1:] = np.cumsum(np.bincount(r_u, minlength=n))
        indices = np.ascontiguousarray(c_u.astype(np.int32))
        val = np.zeros((key.size, slot_r.size))
        rsum = np.zeros((n, slot_r.size))
        w_op = self._op_weights()
        assemble_block_csr(mem, coef, w_op, centre_only, indptr, indices, slot_of, val)
        assemble_row_sums(mem, coef, w_op, centre_only, slot_of, rsum)
        self._op_assemble_more(indptr, indices, slot_of, val, rsum)
        # difference form: the diagonal entry (first in its row) holds the row sums
        rid = np.repeat(np.arange(n), np.diff(indptr))
        order = np.lexsort((indices, indices != rid, rid))
        indices, val = np.ascontiguousarray(indices[order]), np.ascontiguousarray(val[order])
        if np.any(indices[indptr[:-1]] != np.arange(n)):
            raise RuntimeError("operator row without its diagonal entry")
        val[indptr[:-1]] = rsum
        row_pat, indptr, rel, val = _share_stencils(indptr, indices, val, self.stencil_tol)
        kinds = np.array([0 if kind == "y" else 1 for kind, _ in self.dof_map], np.int64)
        comps = np.array([c for _, c in self.dof_map], np.int64)
        fld = next((kind for kind, _ in self.dof_map if kind != "y"), None)
        res = {"row_pat": row_pat, "indptr": indptr, "indices": rel, "val": val,
               "slot_r": slot_r.astype(np.int64), "slot_c": slot_c.astype(np.int64),
               "slots": tuple(zip(slot_r.tolist(), slot_c.tolist())),
               "kind": kinds, "comp": comps, "field": fld,
               "trans": kinds == 0, "rot": kinds == 1,
               "inv_v": np.ascontiguousarray(1.0 / self.system.volume)}
        self._op_finish(res)
        self._op = (self.coef, res, self.stencil_tol, getattr(self, "pair_stencil", None))
        return res

    def _op_gather(self, state, op):
        q = np.empty((state.y.shape[0], self.nd))
        fld = state.fields[op["field"]] if op["field"] is not None else np.zeros((1, 1))
        gather_dofs(state.y, state.x0, fld, op["kind"], op["comp"], q)
        return q

    _op_kernel = None       # specialised SpMV (beam, plate) and the slot layout it assumes
    _op_slots = None
    _op_extra = ()          # keys of the operator dict passed to _op_kernel before q

    def _op_finish(self, op):
        """Model-specific additions to the assembled operator ``op`` (in place)."""

    def _op_extra_pairs(self):
        """Particle pairs (rows, cols) coupled beyond the triplets' members, or None."""
        return None

    def _op_weights(self):
        """Weights of the measure tables in the assembled operator."""
        return self.w_tm

    def _op_assemble_more(self, indptr, indices, slot_of, val, rsum):
        """Model-specific terms added to the operator values and row sums (columns sorted
        within each row at this point)."""

    def _op_rows(self, op, q, do_t, do_r, out_y, out_rot):
        """Translation rows (``do_t``) and/or rotation rows (``do_r``) of ``K q / V`` added
        into the engine's force arrays: the model's specialised kernel when the assembled
        slots are the ones it assumes, else the generic block SpMV."""
        if self._op_kernel is not None and op["slots"] == self._op_slots:
            type(self)._op_kernel(op["row_pat"], op["indptr"], op["indices"], op["val"],
                                  *(op[k] for k in self._op_extra), q, do_t, do_r,
                                  op["inv_v"], out_y, out_rot)
            return
        on = (op["trans"] if do_t else np.zeros(self.nd, bool)) | \
             (op["rot"] if do_r else np.zeros(self.nd, bool))
        self._op_apply(op, q, on, out_y, out_rot)

    def _op_apply(self, op, q, row_on, out0, out1, inv_v=None, dest_kind=None, dest_comp=None):
        block_csr_spmv(op["row_pat"], op["indptr"], op["indices"], op["val"], op["slot_r"], op["slot_c"], q,
                       row_on, op["kind"] if dest_kind is None else dest_kind,
                       op["comp"] if dest_comp is None else dest_comp,
                       op["inv_v"] if inv_v is None else inv_v, out0, out1)

    def _operator_force(self, q):
        """Generalised particle forces (N, nd) (N; N m for rotations) of the dofs q.

        The model attribute ``kernel`` selects the path, all the same linear operator:
        ``"operator"`` (default) the block CSR assembled once (:meth:`_operator`) and one
        row-parallel SpMV; ``"fast"`` the model's triplet kernel (geometry on the fly;
        the reference the operator is checked against); ``"table"`` the generic
        measure-table kernels. The energy is always the triplet sum
        ``sum_t sum_m W s^2 / 2``, which equals ``-q.K q / 2`` to round-off."""
        n = q.shape[0]
        if self._has_operator():
            op = self._operator()
            f = np.zeros((n, self.nd))
            nd_ = np.arange(self.nd, dtype=np.int64)
            self._op_apply(op, np.ascontiguousarray(q, dtype=np.float64),
                           np.ones(self.nd, bool), f, f, np.ones(n),
                           np.zeros(self.nd, np.int64), nd_)
            return f
        if self.kernel == "fast":
            f = self._fast_force(q)
            if f is not None:
                return f
        if self.variant == "text":
            out = np.zeros((n, self.nd))
            text_force_kernel(self.off_t, self.mem_t, self.coef, self.w_tm, q, out)
            return out
        buf = np.zeros((_nchunks(n), n, self.nd))
        grad_force_kernel(self.off_t, self.mem_t, self.coef, self.w_tm, q, buf)
        return buf.sum(axis=0)

    def _generalised(self, state, q=None):
        return self._operator_force(self._gather(state) if q is None else q)

    def add_force(self, state, out):
        if self._has_operator():
            op = self._operator()
            q = self._op_gather(state, op)
            if op["field"] is None or not self.fuse_rows:
                self._op_rows(op, q, True, False, out, np.zeros((1, 2)))
                return
            # translation and rotation rows in one pass; the rotation rows are kept for
            # add_field_force, which uses them if the dofs are still those of q
            buf = getattr(self, "_rot_buf", None)
            if buf is None or buf.shape != state.fields[op["field"]].shape:
                buf = self._rot_buf = np.zeros_like(state.fields[op["field"]])
            buf[...] = 0.0
            self._op_rows(op, q, True, True, out, buf)
            self._rot_q = q
            return
        q = self._gather(state)
        f = self._generalised(state, q)
        inv_v = 1.0 / self.system.volume
        for a, (kind, c) in enumerate(self.dof_map):
            if kind == "y":
                out[:, c] += f[:, a] * inv_v
        if any(kind != "y" for kind, _ in self.dof_map):
            # the field part of the same evaluation, reused by add_field_force when the
            # degrees of freedom have not changed in between (one triplet pass per step)
            self._cache = (q, f)

    def add_field_force(self, state, out):
        if self._has_operator():
            # the rotation rows only: with add_force's translation rows, one SpMV per step
            op = self._operator()
            if op["field"] is None:
                return
            q0 = getattr(self, "_rot_q", None)
            self._rot_q = None
            fld = state.fields[op["field"]]
            if q0 is not None and dofs_equal(state.y, state.x0, fld, op["kind"], op["comp"], q0):
                out[op["field"]] += self._rot_buf
                return
            q = self._op_gather(state, op)
            self._op_rows(op, q, False, True, np.zeros((1, 3)), out[op["field"]])
            return
        cache = getattr(self, "_cache", None)
        if cache is not None and np.array_equal(cache[0], self._gather(state)):
            f = cache[1]
        else:
            f = self._generalised(state)
        self._cache = None
        inv_v = 1.0 / self.system.volume
        for a, (kind, c) in enumerate(self.dof_map):
            if kind != "y":
                out[kind][:, c] += f[:, a] * inv_v

    @property
    def translations(self):
        return tuple(c for kind, c in self.dof_map if kind == "y")

    def energy_density(self, state):
        if self.variant == "text":
            raise ValueError(f"model {self.name!r} variant 'text' has no energy whose gradient is "
                             "its force (use variant='consistent')")
        e = np.zeros(self.system.n)
        energy_kernel(self.off_t, self.mem_t, self.coef, self.w_tm, self._gather(state), e)
        return e / self.system.volume

    def _inertia_d(self):
        return np.ones(self.nd)

    def _bounds(self):
        n = self.system.n
        buf = np.zeros((_nchunks(n), n, self.nd))
        scale = 1.0 / np.sqrt(self._inertia_d())
        bound_kernel(self.off_t, self.mem_t, self.coef, self.w_tm, scale, self.variant == "text", buf)
        return buf.sum(axis=0) / self.system.volume[:, None]

    def stiffness_bound(self):
        b = self._bounds()
        cols = [a for a, (kind, _) in enumerate(self.dof_map) if kind == "y"]
        return b[:, cols].max(axis=1)

    def field_stiffness_bound(self):
        b = self._bounds()
        out = {}
        for a, (kind, c) in enumerate(self.dof_map):
            if kind != "y":
                out.setdefault(kind, np.zeros(self.system.n))
                out[kind] = np.maximum(out[kind], b[:, a])
        return out

    def influence_radius(self):
        return 2.0 * self.family.horizon + 2.0 * self.system.spacing

    def _bulk_centre(self):
        """A particle with the most triplets, nearest the middle of the body."""
        counts = np.diff(self.off_t)
        cand = np.flatnonzero(counts == counts.max())
        x = self.system.x0[cand]
        mid = 0.5 * (self.system.x0.min(axis=0) + self.system.x0.max(axis=0))
        return int(cand[np.argmin(np.sum((x - mid) ** 2, axis=1))])

    def _bulk_energy(self, q, groups):
        """Energy density (J/m^3) at the bulk centre of field q with unit weights, per
        measure group (list of measure-index arrays)."""
        i = self._bulk_centre()
        t0, t1 = self.off_t[i], self.off_t[i + 1]
        out = []
        for g in groups:
            e = 0.0
            for t in range(t0, t1):
                for m in g:
                    s = float(np.sum(self.coef[t, m] * q[self.mem_t[t]]))
                    e += 0.5 * self.w0_tm[t, m] * s * s
            out.append(e / self.system.volume[i])
        return out


# =========================================================================== Timoshenko
class TridynTimoshenko(_TripletModel):
    """Tridynamic Timoshenko beam (seed 004 ch. 3): dofs u (x), w (z), phi (field "rot").

    Parameters
    ----------
    E : float
        Young's modulus (Pa).
    nu : float
        Poisson ratio (shear modulus ``mu = E / (2 (1 + nu))``), in (-1, 0.5).
    area, second_moment : float
        Cross-section A (m^2) and I (m^4); a rectangle b x h has I/A = h^2/12.
    shear_factor : float
        k_s in (0, 1] (5/6 for a rectangle).
    variant : {"text", "consistent"}
    edge_factor : float
        Factor on the j-k edge terms of the shear measure (1: eq. 3.6; 2: Appendix C).
    self_pairs : bool, optional
        Include j = k in the double sums (default: True for "text", as in C.1; False for
        "consistent").
    shear_integration : {"bond", "ends"}, optional
        Rotation in the shear measure of a pair. ``"ends"`` (default; 3.6-3.9, the text
        variant's only choice): the mean of the two ends' rotations, ``psi_ab = (w_b -
        w_a)/xi_ab - n_ab (phi_a + phi_b)/2``. ``"bond"`` (consistent variant): the mean
        of phi over the bond
        by the trapezoidal rule over every particle between a and b, ``psi_ab = (chi_b -
        chi_a)/xi_ab`` with ``chi = w - Phi`` and ``Phi(x) = int phi dx`` (cumulative
        trapezoid along the chain), i.e. the mean of the nearest-neighbour shear strains
        along the bond. With "ends", a pair longer than one spacing sees the shear
        ``-xi^2 w'''/12`` of a bending field with ``phi = w'`` exactly, and asking every
        pair within the horizon to vanish over-constrains the Kirchhoff limit (2 N
        conditions on 2 N dofs for delta = 2 dx): thin beams lock. With "bond" every
        psi_ab is an average of the nearest-neighbour ones, so they all vanish together
        and the thin limit is free. Its operator is assembled on each triplet's window of
        particles (:func:`assemble_bond_shear`); ``kernel="fast"`` is the triplet kernel on
        (u, chi, phi) with the chain rule through Phi; the stable-step bound is the
        Gershgorin bound of the assembled operator (tighter than the triplet-sum bound of
        "ends": 0.89 of the sharp step against 0.61, so 0.8 x the estimate is closer to the
        limit and velocity Verlet's energy error is larger, see the results).
    """

    name = "tridyn-timoshenko"
    needs = Needs(pairs=True, energy=True)
    nd = 3
    _op_kernel = timo_csr_spmv
    _op_slots = ((0, 0), (1, 1), (1, 2), (2, 1), (2, 2))
    dof_map = (("y", 0), ("y", 2), ("rot", 0))

    def __init__(self, E, nu=0.3, *, area, second_moment, shear_factor=5.0 / 6.0,
                 variant="consistent", edge_factor=1.0, self_pairs=None, shear_integration=None):
        _positive(E=E, area=area, second_moment=second_moment)
        if shear_integration is None:
            shear_integration = "ends"
        if shear_integration not in SHEAR_INTEGRATIONS:
            raise ValueError(f"unknown shear_integration {shear_integration!r}; valid: "
                             f"{', '.join(SHEAR_INTEGRATIONS)}")
        if shear_integration == "bond" and variant != "consistent":
            raise ValueError("shear_integration 'bond' is for variant 'consistent'")
        self.shear_integration = shear_integration
        if not (-1.0 < nu < 0.5):
            raise ValueError(f"Poisson ratio must be in (-1, 0.5), got {nu!r}")
        if not (0.0 < shear_factor <= 1.0):
            raise ValueError(f"shear correction factor must be in (0, 1], got {shear_factor!r}")
        _positive(edge_factor=edge_factor)
        self.E, self.nu, self.A, self.I = float(E), float(nu), float(area), float(second_moment)
        self.mu = self.E / (2.0 * (1.0 + self.nu))
        self.ks = float(shear_factor)
        self.variant = _variant(variant)
        self.edge_factor = float(edge_factor)
        self.self_pairs = (variant == "text") if self_pairs is None else bool(self_pairs)

    def fields(self):
        from upscale.engine.fields import FieldSpec

        rho = self.system.density if self.system is not None else 1.0
        return {"rot": FieldSpec(1, rho * self.I / self.A, "rad")}

    def _inertia_d(self):
        rho = float(np.mean(self.system.density))
        return np.array([rho, rho, rho * self.I / self.A])

    def prepare(self, system, family, **kw):
        super().prepare(system, family, **kw)
        _check_line(system, family, self.name)
        self.off_t, self.mem_t = line_triplets(family, system.x0, self_pairs=self.self_pairs)
        _check_triplets(family, self.off_t)
        x = system.x0[:, 0]
        V = system.volume
        mem = self.mem_t
        i, j, k = mem[:, 0], mem[:, 1], mem[:, 2]
        nt = mem.shape[0]
        a = np.abs(x[j] - x[i])
        b = np.abs(x[k] - x[i])
        c = np.abs(x[k] - x[j])
        ia, ib = 1.0 / a, 1.0 / b
        ic = np.where(c > 0, 1.0 / np.where(c > 0, c, 1.0), 0.0)
        nij, nik, njk = np.sign(x[j] - x[i]), np.sign(x[k] - x[i]), np.sign(x[k] - x[j])
        ef = self.edge_factor
        # measures: 0-2 eps (u, dof 0), 3-5 kappa (phi, dof 2), 6-8 psi (w dof 1, phi dof 2)
        C = np.zeros((nt, 9, 3, 3))
        for base, dof in ((0, 0), (3, 2), (6, 1)):
            # s_ijk
            C[:, base, 0, dof] = -(ia + ib)
            C[:, base, 1, dof] = ia
            C[:, base, 2, dof] = ib
            e = ef if base == 6 else 1.0
            # s_jki = (q_k - q_j)/xi_jk + (q_i - q_j)/xi_ji
            C[:, base + 1, 1, dof] = -e * ic - ia
            C[:, base + 1, 2, dof] = e * ic
            C[:, base + 1, 0, dof] = ia
            # s_kij = (q_j - q_k)/xi_kj + (q_i - q_k)/xi_ki
            C[:, base + 2, 2, dof] = -e * ic - ib
            C[:, base + 2, 1, dof] = e * ic
            C[:, base + 2, 0, dof] = ib
        # psi rotation parts: -n_ab (phi_a + phi_b)/2 per edge
        C[:, 6, 0, 2] = -(nij + nik) / 2
        C[:, 6, 1, 2] = -nij / 2
        C[:, 6, 2, 2] = -nik / 2
        # psi_jki = psi_jk + psi_ji, n_ji = -n_ij
        C[:, 7, 1, 2] = -ef * njk / 2 + nij / 2
        C[:, 7, 2, 2] = -ef * njk / 2
        C[:, 7, 0, 2] = nij / 2
        # psi_kij = psi_kj + psi_ki, n_kj = -n_jk, n_ki = -n_ik
        C[:, 8, 2, 2] = ef * njk / 2 + nik / 2
        C[:, 8, 1, 2] = ef * njk / 2
        C[:, 8, 0, 2] = nik / 2
        self.coef = np.ascontiguousarray(C)
        pair_w = np.where(j == k, 1.0 / 3.0, 2.0 / 3.0) * V[i] * V[j] * V[k]
        self.w0_tm = np.repeat(pair_w[:, None], 9, axis=1)
        EIA = self.E * self.I / self.A
        targets = (self.E, EIA, self.ks * self.mu)
        if self.variant == "text":
            i0 = self._bulk_centre()
            VT = float(np.sum(V[family.neighbors[family.offsets[i0]:family.offsets[i0 + 1]]]))
            K = np.array(targets) / VT ** 2  # eq. 3.38
        else:
            n = system.n
            xs = x - x[self._bulk_centre()]
            q_u = np.zeros((n, 3))
            q_u[:, 0] = xs
            q_k = np.zeros((n, 3))
            q_k[:, 2] = xs
            q_s = np.zeros((n, 3))
            q_s[:, 1] = xs
            e = [self._bulk_energy(q_u, [range(0, 3)])[0], self._bulk_energy(q_k, [range(3, 6)])[0],
                 self._bulk_energy(q_s, [range(6, 9)])[0]]
            K = np.array([0.5 * tv / ev for tv, ev in zip(targets, e)])
        self.K = K  # (K^eps, K^phi, K^psi)
        self.pw_t = np.ascontiguousarray(pair_w)
        self._x = np.ascontiguousarray(x)
        self._g6 = np.ascontiguousarray(np.stack([ia, ib, ic, nij, nik, njk], axis=1))
        self.w_tm = np.ascontiguousarray(self.w0_tm * np.repeat(K, 3)[None, :])
        if self.shear_integration == "bond":
            # the shear measures on (u, chi, phi): the w column reads chi, no phi terms
            Cb = C.copy()
            Cb[:, 6:9, :, 2] = 0.0
            self._coef_bond = np.ascontiguousarray(Cb)
            self._order = np.argsort(x, kind="stable")
            self._dxo = np.diff(x[self._order])

    def _to_bond(self, q):
        """(u, w, phi) -> (u, chi = w - Phi, phi), Phi the cumulative trapezoid of phi."""
        o, d = self._order, self._dxo
        p = q[o, 2]
        Phi = np.zeros(q.shape[0])
        Phi[1:] = np.cumsum(d * 0.5 * (p[:-1] + p[1:]))
        qb = q.copy()
        qb[o, 1] -= Phi
        return qb

    def _op_extra_pairs(self):
        if self.shear_integration != "bond":
            return None
        # every pair within the widest triplet window along the chain
        rank = np.empty(self.system.n, np.int64)
        rank[self._order] = np.arange(self.system.n)
        r = rank[self.mem_t]
        span = int((r.max(axis=1) - r.min(axis=1)).max()) if r.size else 0
        o = self._order
        rows, cols = [], []
        for sft in range(-span, span + 1):
            a = np.arange(max(0, -sft), min(o.size, o.size - sft))
            rows.append(o[a])
            cols.append(o[a + sft])
        return np.concatenate(rows), np.concatenate(cols)

    def _op_weights(self):
        if self.shear_integration != "bond":
            return self.w_tm
        w = self.w_tm.copy()
        w[:, 6:9] = 0.0        # the shear measures are assembled on their windows
        return w

    def _op_assemble_more(self, indptr, indices, slot_of, val, rsum):
        if self.shear_integration != "bond":
            return
        rank = np.empty(self.system.n, np.int64)
        rank[self._order] = np.arange(self.system.n)
        r = rank[self.mem_t]
        if r.size and int((r.max(axis=1) - r.min(axis=1)).max()) >= 64:
            raise ValueError("shear_integration 'bond' supports triplet windows up to 64 "
                             "particles along the chain; valid: a smaller horizon / spacing ratio")
        assemble_bond_shear(self.mem_t, self._coef_bond, self.w_tm, 6, rank, self._order,
                            np.ascontiguousarray(self._dxo), slot_of, indptr, indices, val, rsum)

    def _operator_force(self, q):
        if self.shear_integration != "bond" or self._has_operator():
            return super()._operator_force(q)
        return self._bond_force(q)

    def _bond_force(self, q):
        """Forces of the bond-integrated shear through the triplet kernel on (u, chi, phi)
        and the chain rule through Phi (the reference for the assembled operator)."""
        n = q.shape[0]
        buf = np.zeros((_nchunks(n), n, 3))
        grad_force_kernel(self.off_t, self.mem_t, self._coef_bond, self.w_tm, self._to_bond(q), buf)
        g = buf.sum(axis=0)
        # chain rule through Phi: f_phi[o_s] -= (d_s/2) S_{s+1} + (d_{s-1}/2) S_s, with
        # S_s = sum_{r >= s} g_chi[o_r] (Phi_{o_r} = sum_{t < r} d_t (phi_t + phi_{t+1})/2)
        o, d = self._order, self._dxo
        G = g[o, 1]
        S = np.cumsum(G[::-1])[::-1]
        S_next = np.append(S[1:], 0.0)
        f_phi = np.zeros(n)
        f_phi[:-1] -= 0.5 * d * S_next[:-1]
        f_phi[1:] -= 0.5 * d * S[1:]
        g[o, 2] += f_phi
        return g

    def _bounds(self):
        if self.shear_integration != "bond":
            return super()._bounds()
        # Gershgorin rows of the mass-scaled assembled operator (the diagonal entry of a
        # stored row holds the row sum R: K_ii = R - sum of the off-diagonal entries)
        op = self._operator()
        scale = 1.0 / np.sqrt(self._inertia_d())
        ptr, val = op["indptr"], op["val"]
        b = np.zeros((self.system.n, self.nd))
        for pat in np.unique(op["row_pat"]):
            v = val[ptr[pat]:ptr[pat + 1]].copy()
            v[0] = v[0] - v[1:].sum(axis=0)
            tot = np.zeros(self.nd)
            for sl, (d, e) in enumerate(op["slots"]):
                tot[d] += np.abs(v[:, sl]).sum() * scale[e] / scale[d]
            b[op["row_pat"] == pat] = tot
        return b / self.system.volume[:, None]

    def energy_density(self, state):
        if self.shear_integration != "bond":
            return super().energy_density(state)
        e = np.zeros(self.system.n)
        energy_kernel(self.off_t, self.mem_t, self._coef_bond, self.w_tm,
                      self._to_bond(self._gather(state)), e)
        return e / self.system.volume

    def _fast_force(self, q):
        n = q.shape[0]
        Ke, Kp, Ks = (float(v) for v in self.K)
        if self.variant == "text":
            out = np.zeros((n, 3))
            timo_text_kernel(self.off_t, self.mem_t, self.pw_t, self._g6, q, Ke, Kp, Ks,
                             self.edge_factor, out)
            return out
        nc = _nchunks(n)
        buf = np.zeros((nc, n, 3))
        timo_grad_kernel(self.off_t, self.mem_t, self.pw_t, self._g6, q, Ke, Kp, Ks,
                         self.edge_factor, buf)
        return buf[0] if nc == 1 else buf.sum(axis=0)

    def describe(self):
        d = {"model": self.name, "variant": self.variant, "E_Pa": self.E, "nu": self.nu,
             "area_m2": self.A, "second_moment_m4": self.I, "shear_factor": self.ks,
             "edge_factor": self.edge_factor, "self_pairs": self.self_pairs,
             "shear_integration": self.shear_integration}
        if hasattr(self, "K"):
            d.update(K_eps=float(self.K[0]), K_phi=float(self.K[1]), K_psi=float(self.K[2]))
        return d


# =========================================================================== Euler-Bernoulli
class TridynEB(_TripletModel):
    """Tridynamic Euler-Bernoulli beam (seed 004 ch. 2): dof w (z translation).

    Parameters
    ----------
    E : float
        Young's modulus (Pa).
    area, second_moment : float
        A (m^2), I (m^4).
    variant : {"text", "consistent"}
    xi : {"spacing", "horizon"}
        Reading of the xi in the calibration 2.19 (text variant).
    """

    name = "tridyn-eb"
    needs = Needs(pairs=True, energy=True)
    nd = 1
    dof_map = (("y", 2),)

    def __init__(self, E, *, area, second_moment, variant="consistent", xi="spacing"):
        _positive(E=E, area=area, second_moment=second_moment)
        if xi not in ("spacing", "horizon"):
            raise ValueError(f"unknown xi reading {xi!r}; valid: 'spacing', 'horizon'")
        self.E, self.A, self.I = float(E), float(area), float(second_moment)
        self.variant = _variant(variant)
        self.xi = xi

    def prepare(self, system, family, **kw):
        super().prepare(system, family, **kw)
        _check_line(system, family, self.name)
        x = system.x0[:, 0]
        V = system.volume
        EIA = self.E * self.I / self.A
        if self.variant == "text":
            self.off_t, self.mem_t = line_triplets(family, system.x0, self_pairs=False)
            _check_triplets(family, self.off_t)
            i, j, k = self.mem_t.T
            self.inv_a = 1.0 / np.abs(x[j] - x[i])
            self.inv_b = 1.0 / np.abs(x[k] - x[i])
            # nearest neighbours for the slope jump
            order = np.argsort(x)
            self.left = np.full(system.n, -1, np.int64)
            self.right = np.full(system.n, -1, np.int64)
            self.left[order[1:]] = order[:-1]
            self.right[order[:-1]] = order[1:]
            i0 = self._bulk_centre()
            nb_ = family.neighbors[family.offsets[i0]:family.offsets[i0 + 1]]
            right = nb_[x[nb_] > x[i0]]
            vs = float(np.sum(V[nb_]) * np.sum(V[right]) - np.sum(V[right] ** 2))  # eq. 2.18, j != k
            xi_ = system.spacing if self.xi == "spacing" else family.horizon
            self.beta_hat = -3.0 * EIA / (4.0 * xi_ ** 2 * vs)  # eq. 2.19
            self.g_t = 2.0 * (2.0 / 3.0) * self.beta_hat * V[j] * V[k] * V[i]
            return
        self.off_t, self.mem_t = line_triplets(family, system.x0, self_pairs=False, opposite=True)
        _check_triplets(family, self.off_t, ends_only=False)
        i, j, k = self.mem_t.T
        a = np.abs(x[j] - x[i])
        b = np.abs(x[k] - x[i])
        C = np.zeros((self.mem_t.shape[0], 1, 3, 1))
        C[:, 0, 0, 0] = -(1 / a + 1 / b)
        C[:, 0, 1, 0] = 1 / a
        C[:, 0, 2, 0] = 1 / b
        self.coef = np.ascontiguousarray(C)
        self.w0_tm = (V[i] * V[j] * V[k])[:, None].copy()
        q = np.zeros((system.n, 1))
        q[:, 0] = 0.5 * (x - x[self._bulk_centre()]) ** 2
        e = self._bulk_energy(q, [range(1)])[0]
        self.beta = 0.5 * EIA / e
        self.w_tm = np.ascontiguousarray(self.w0_tm * self.beta)
        self._wt = np.ascontiguousarray(self.w_tm[:, 0])
        self._x = np.ascontiguousarray(x)

    def _fast_force(self, q):
        if self.variant == "text":
            return None
        n = q.shape[0]
        nc = _nchunks(n)
        buf = np.zeros((nc, n))
        eb_grad_kernel(self.off_t, self.mem_t, self._wt, self._x,
                       np.ascontiguousarray(q[:, 0]), buf)
        return (buf[0] if nc == 1 else buf.sum(axis=0))[:, None]

    def _generalised(self, state, q=None):
        if self.variant != "text":
            return super()._generalised(state, q)
        w = np.ascontiguousarray(state.y[:, 2] - state.x0[:, 2])
        th = np.empty_like(w)
        slope_jump_kernel(self.left, self.right, np.ascontiguousarray(self.system.x0[:, 0]), w, th)
        out = np.zeros(w.shape[0])
        eb_text_force_kernel(self.off_t, self.mem_t, self.inv_a, self.inv_b, self.g_t, th, out)
        return out[:, None]

    def _bounds(self):
        if self.variant != "text":
            return super()._bounds()
        # |F_i| <= sum_t |g_t| (|theta_j| + |theta_k| + 2 |theta_i|)/xi, |theta| <= 4 |w|/dx
        h = self.system.spacing
        n = self.system.n
        r = np.zeros(n)
        np.add.at(r, self.mem_t[:, 0], np.abs(self.g_t) * 2 * (self.inv_a + self.inv_b) * 4.0 / h)
        return (r / self.system.volume)[:, None]

    def influence_radius(self):
        return 2.0 * self.family.horizon + 2.0 * self.system.spacing

    def rotary_mass(self, mask=None):
        """Rotary inertia of the sections (Rayleigh beam): the coupling ``B`` (N x N, kg,
        sparse) of the kinetic energy ``(1/2) int rho I (dw'/dt)^2 dx`` on the chain,
        ``(1/2) sum_edges rho I (v_b - v_a)^2 / xi_ab`` over the edges between consecutive
        particles both in ``mask`` (all if None; ghosts, whose velocities are not
        integrated, are left out). With the lumped masses it is the mass matrix of w for
        :class:`upscale.engine.mass.MassMatrixVerlet`; the plane-wave symbol is
        ``rho A dx + rho I (2 - 2 cos k dx)/dx``, i.e. ``rho (A + I k^2) dx`` at long
        waves (Rayleigh)."""
        from upscale.engine.mass import edge_coupling

        x = self.system.x0[:, 0]
        order = np.argsort(x)
        a, b = order[:-1], order[1:]
        keep = np.ones(a.size, bool) if mask is None else (mask[a] & mask[b])
        rho = np.broadcast_to(np.asarray(self.system.density, float), x.shape)
        coef = 0.5 * (rho[a] + rho[b]) * self.I / np.abs(x[b] - x[a])
        return edge_coupling(x, np.stack([a[keep], b[keep]], axis=1), coef[keep])

    def describe(self):
        d = {"model": self.name, "variant": self.variant, "E_Pa": self.E, "area_m2": self.A,
             "second_moment_m4": self.I}
        if self.variant == "text":
            d.update(xi=self.xi, beta_hat=getattr(self, "beta_hat", None))
        else:
            d.update(beta=getattr(self, "beta", None))
        return d


register("tridyn-eb", TridynEB)
register("tridyn-timoshenko", TridynTimoshenko)


# =========================================================================== beam bodies
def beam(*, length, n, horizon_ratio=1.0, theory="eb", supports=("ss", "ss"), E=200e9,
         nu=0.3, width=0.05, height=0.001, density=7850.0, shear_factor=5.0 / 6.0,
         variant="consistent", load=0.0, free_end="second-order", **model_kw):
    """A beam of ``n`` spacings on [0, length] with supports, ghost layers, a uniform load.

    Nodes at ``x_i = i dx`` (dx = length/n), free end nodes with half volume (full where
    ghosts continue the chain, see ``free_end``); ghosts beyond a supported end. ``supports`` = (left, right), each in ``SUPPORTS``; ``load`` q (N/m,
    in +z). Returns ``(system, family, model, conditions, body_mask)`` (``body_mask``: the
    particles of [0, length]).

    ``free_end`` sets the ghosts beyond a free end of the text EB beam (whose slope jump
    2.16 needs neighbours on both sides; the other beams need no ghosts there), from the
    end conditions ``w'' = w''' = 0``: ``"second-order"`` (default) the polynomial
    ``w(L + s) = a0 + a1 s + a4 s^4 + a5 s^5`` through the end node and the next three
    (:func:`free_end_weights`; ghost error O(dx^6 w^(6)), O(dx^2) in the fourth-order
    operator at the end), ``"linear"`` the linear extrapolation ``w_{end+g} = w_end +
    g (w_end - w_{end-1})`` (exact only for a straight end: error O(dx^4 w'''') in the
    ghosts, O(1) in the end node's equation)."""
    from upscale.engine import conditions as cnd
    from upscale.engine.families import build_family
    from upscale.engine.fields import FixedField, Tie
    from upscale.engine.system import ParticleSystem

    if theory not in ("eb", "timoshenko"):
        raise ValueError(f"unknown theory {theory!r}; valid: 'eb', 'timoshenko'")
    for s in supports:
        if s not in SUPPORTS:
            raise ValueError(f"unknown support {s!r}; valid: {', '.join(SUPPORTS)}")
    _positive(length=length, width=width, height=height, E=E, density=density)
    if int(n) < 4:
        raise ValueError(f"a beam needs at least 4 spacings, got n={n!r}")
    if free_end not in FREE_ENDS:
        raise ValueError(f"unknown free_end {free_end!r}; valid: {', '.join(FREE_ENDS)}")
    if not horizon_ratio >= 1.0:
        raise ValueError(f"horizon_ratio delta/dx must be >= 1, got {horizon_ratio!r}")
    n = int(n)
    dx = length / n
    delta = horizon_ratio * dx * (1 + 1e-9)
    ng = int(np.ceil(2 * delta / dx)) + 1
    def n_ghost(s):
        if s in ("ss", "cc"):
            return ng
        if s == "free" and theory == "eb" and variant == "text":
            return ng  # extrapolated: the slope jump 2.16 needs both neighbours
        return 0

    gl, gr = n_ghost(supports[0]), n_ghost(supports[1])
    idx = np.arange(-gl, n + 1 + gr)
    x = idx * dx
    A = width * height
    I = width * height ** 3 / 12.0
    V = np.full(x.size, A * dx)
    # a free end node has half volume, unless ghosts continue the chain beyond it (text EB):
    # then it is an inner node of the extended chain, weighted in its neighbours' triplet
    # sums like one (a half weight there changes the operator at the node before it by
    # O(1): half the load in the residual of a quartic)
    if supports[0] == "free" and not gl:
        V[idx == 0] *= 0.5
    if supports[1] == "free" and not gr:
        V[idx == n] *= 0.5
    system = ParticleSystem(x[:, None], V, density, dim=1, spacing=dx)
    family = build_family(system, delta)
    if theory == "eb":
        model = TridynEB(E, area=A, second_moment=I, variant=variant, **model_kw)
    else:
        model = TridynTimoshenko(E, nu, area=A, second_moment=I, shear_factor=shear_factor,
                                 variant=variant, **model_kw)
    body = (idx >= 0) & (idx <= n)
    conds = []
    pos = {int(v): p for p, v in enumerate(idx)}
    for side, s in ((0, supports[0]), (1, supports[1])):
        end = 0 if side == 0 else n
        sgn = -1 if side == 0 else 1
        tag = "left" if side == 0 else "right"
        em = np.zeros(x.size, bool)
        em[pos[end]] = True
        reg_e = cnd.Region(f"support_{tag}", em)
        if (gl, gr)[side]:
            ghosts = np.array([pos[end + sgn * g] for g in range(1, ng + 1)])
            masters = np.array([pos[end - sgn * g] for g in range(1, ng + 1)])
            gm = np.zeros(x.size, bool)
            gm[ghosts] = True
            reg_g = cnd.Region(f"ghosts_{tag}", gm)
            image = dict(zip(ghosts.tolist(), masters.tolist()))
            depth = {gh: g for g, gh in enumerate(ghosts.tolist(), start=1)}
            masters = np.array([image[g] for g in reg_g.index.tolist()])  # region order
        if s == "free":
            if (gl, gr)[side]:
                # w'' = w''' = 0 at the end (see free_end above)
                gdep = np.array([depth[g] for g in reg_g.index.tolist()], float)
                nm = 2 if free_end == "linear" else 4
                ms = np.repeat(np.array([pos[end - sgn * t] for t in range(nm)])[None, :], ng, axis=0)
                wts = np.stack([1 + gdep, -gdep], axis=1) if free_end == "linear" \
                    else free_end_weights(gdep)
                conds.append(Tie(reg_g, ms, wts, ("y", 2)))
            continue
        if theory == "eb":
            conds.append(cnd.Fixed(reg_e, components=(2,)))
            conds.append(Tie(reg_g, masters[:, None], np.full((ng, 1), -1.0 if s == "ss" else 1.0),
                             ("y", 2)))
        else:
            if s == "ss":
                conds.append(cnd.Fixed(reg_e, components=(0, 2)))
                conds.append(Tie(reg_g, masters[:, None], -np.ones((ng, 1)), ("y", 0)))
                conds.append(Tie(reg_g, masters[:, None], -np.ones((ng, 1)), ("y", 2)))
                conds.append(Tie(reg_g, masters[:, None], np.ones((ng, 1)), ("rot", 0)))
            else:
                # clamp: u = w = phi = 0 at the support node, ghosts continue the body's
                # fields smoothly (cubic extrapolation from the support node and the next 3)
                conds.append(cnd.Fixed(reg_e, components=(0, 2)))
                conds.append(FixedField(reg_e, "rot", (0,)))
                gdep = np.array([depth[g] for g in reg_g.index.tolist()], float)
                nodes = np.array([pos[end - sgn * t] for t in range(4)])
                wts = _lagrange_weights(np.arange(4.0), -gdep)
                ms = np.repeat(nodes[None, :], ng, axis=0)
                for target in (("y", 0), ("y", 2), ("rot", 0)):
                    conds.append(Tie(reg_g, ms, wts, target))
    if load:
        conds.append(cnd.BodyForce(cnd.Region("beam", body), (0.0, 0.0, load / A)))
    return system, family, model, conds, body


def free_end_weights(depths):
    """Weights (len(depths), 4) of the ghost at ``g`` spacings beyond a free end on the end
    node and the three before it, from the polynomial ``p(s) = a0 + a1 s + a4 s^4 + a5 s^5``
    (``p'' = p''' = 0`` at s = 0: no moment, no shear force) through ``s = 0, -1, -2, -3``
    spacings: exact for every quintic satisfying the two end conditions."""
    def basis(s):
        return np.stack([np.ones_like(s), s, s ** 4, s ** 5], axis=-1)

    coef = np.linalg.inv(basis(-np.arange(4.0)))          # a = coef @ w_nodes
    return basis(np.asarray(depths, float)) @ coef


def _lagrange_weights(t, at):
    """Weights (len(at), len(t)) of the Lagrange polynomial through nodes t at points at."""
    at = np.atleast_1d(at)
    w = np.ones((at.size, t.size))
    for a in range(t.size):
        for b in range(t.size):
            if a != b:
                w[:, a] *= (at - t[b]) / (t[a] - t[b])
    return w


def beam_reference(x, length, q, EI, supports, kGA=None):
    """Closed-form deflection under uniform load q (EB; plus the Timoshenko shear term
    ``q x (L - x)/(2 k G A)`` (ss), ``q x (2L - x)/(2 k G A)`` (cantilever)).

    Simply supported ``q x (L^3 - 2 L x^2 + x^3)/(24 EI)``; clamped-clamped
    ``q x^2 (L - x)^2 / (24 EI)``; cantilever ``q x^2 (6 L^2 - 4 L x + x^2)/(24 EI)``."""
    L = length
    key = tuple(supports)
    if key == ("ss", "ss"):
        w = q * x * (L ** 3 - 2 * L * x ** 2 + x ** 3) / (24 * EI)
        ws = q * x * (L - x) / (2 * kGA) if kGA else 0.0
    elif key == ("cc", "cc"):
        w = q * x ** 2 * (L - x) ** 2 / (24 * EI)
        ws = q * x * (L - x) / (2 * kGA) if kGA else 0.0
    elif key == ("cc", "free"):
        w = q * x ** 2 * (6 * L ** 2 - 4 * L * x + x ** 2) / (24 * EI)
        ws = q * x * (2 * L - x) / (2 * kGA) if kGA else 0.0
    else:
        raise ValueError(f"no closed form for supports {supports!r}; valid: ss-ss, cc-cc, cc-free")
    return w + ws


# =========================================================================== FSDT plate
class TridynPlate(_TripletModel):
    """Energy-consistent tridynamic FSDT (Mindlin) plate (seed 004 ch. 4, corrected).

    Degrees of freedom u, v, w (translations x, y, z) and the rotations phi_x, phi_y
    (field ``"rot"``, two components; ``phi_x ~ w,x`` in the Kirchhoff limit). The printed
    plate cannot be built literally: its x-measures divide by xi^y, zero for the x-aligned
    pairs it prescribes; its energy has no eps_xx eps_yy coupling, so the constants 4.63
    give the classical in-plane shear only for nu = 0 (see
    :func:`literal_local_coefficients`). This model keeps the chapter's one-sided
    difference measures on the two lines through the centre and puts Mindlin's quadratic
    form on them: for every triplet (i; j, k) with j on the x line and k on the y line of
    i (an engine triplet, non-collinear)::

        g_x f = (f_j - f_i)/(x_j - x_i),   g_y f = (f_k - f_i)/(y_k - y_i)
        eps = (g_x u, g_y v, g_y u + g_x v),   kappa = (g_x phi_x, g_y phi_y, g_y phi_x + g_x phi_y)
        gamma_xz = g_x w - (phi_x,i + phi_x,j)/2,   gamma_yz = g_y w - (phi_y,i + phi_y,k)/2
        U_t = w_t [ W_m(eps) + (h^2/12) W_m(kappa) + k_s mu (gamma_xz^2 + gamma_yz^2)/2 ]
        W_m(e) = E/(2(1 - nu^2)) (e_xx^2 + e_yy^2 + 2 nu e_xx e_yy) + mu e_xy^2 / 2

    (the shear measures are 4.10-4.11's edge terms with the sign of the bond). Weights
    ``w_t = V_i V_j V_k / sum_{t' of i} V_j' V_k'`` make the energy density of every
    uniform strain, curvature and shear exact at a bulk particle (the triangle's gradient
    of a linear field is exact), which fixes the long-wave limit to Mindlin's 4.62. Every
    ``U_t`` is a positive semi-definite form, so the energy is non-negative. Forces are
    its exact gradient (symmetric tangent).

    Variant ``"text"``: the printed plate. Measures 4.1-4.14 (difference quotients of u, v,
    w, phi_x, phi_y over the x or y separation ``xi^x = |x_b - x_a|``, ``xi^y``), the
    printed EOM 4.48-4.52 (the centre-only derivative ``-(1/3) sum_jk K s ds/dq_i V_j V_k``,
    as for the beam) with the constants 4.53/4.63 and ``V_T = sum_j V_j`` over the x and y
    lines (4.61, 4V at delta = dx). In the in-plane and twisting shear the EOM couples the
    two halves ``1eps = u over y``, ``2eps = v over x`` by the matrix
    ``[[2 1K, 1K + 2K], [1K + 2K, 2 2K]]`` (4.48-4.49), indefinite for 1K != 2K; it is
    diagonalised into two measures with weights of both signs. A term whose separation
    in its direction is zero (``xi^x_ab = 0`` for a pair on the y line, the 0/0 of the
    printed measures) is dropped: the limit does not exist (``q_b - q_a`` stays finite as
    the separation goes to zero) and dropping it is the chapter's own convention for a
    zero-length edge (j = k in 3.6-3.9). The prescribed triangles ("all edges on the x or
    y axis") are read as ``text_triplets="lines"`` (default: j and k both on the x line
    or both on the y line of i, j = k included) or ``"cross"`` (j and k anywhere on the
    two lines, right triangles included). The text variant has no energy (its operator is
    not symmetric).

    Parameters
    ----------
    E, nu : float
        Young's modulus (Pa) and Poisson ratio.
    thickness : float
        Plate thickness h (m); must equal the body's ``thickness``.
    shear_factor : float
        k_s in (0, 1].
    variant : {"consistent", "text"}
    text_triplets : {"lines", "cross"}
        The triplets of the text variant (above).
    """

    name = "tridyn-plate"
    needs = Needs(pairs=True, energy=True)
    nd = 5
    _op_kernel = plate_csr_spmv
    _op_extra = ("bulk", "h_off", "h_val")
    pair_stencil = True     # bulk rows in pairs of opposite offsets (False: stored entries)

    def _op_finish(self, op):
        half = plate_half_stencil(op) if self.pair_stencil else \
            (-1, np.zeros(0, np.int64), np.zeros((0, 9)))
        op.update(zip(self._op_extra, half))
    _op_slots = ((0, 0), (0, 1), (1, 0), (1, 1), (2, 2), (2, 3), (2, 4), (3, 2), (3, 3),
                 (3, 4), (4, 2), (4, 3), (4, 4))
    dof_map = (("y", 0), ("y", 1), ("y", 2), ("rot", 0), ("rot", 1))
    variant = "consistent"

    def __init__(self, E, nu=0.3, *, thickness, shear_factor=5.0 / 6.0, variant="consistent",
                 text_triplets="lines"):
        _positive(E=E, thickness=thickness)
        if not (-1.0 < nu < 0.5):
            raise ValueError(f"Poisson ratio must be in (-1, 0.5), got {nu!r}")
        if not (0.0 < shear_factor <= 1.0):
            raise ValueError(f"shear correction factor must be in (0, 1], got {shear_factor!r}")
        self.variant = _variant(variant)
        if text_triplets not in TEXT_PLATE_TRIPLETS:
            raise ValueError(f"unknown text_triplets {text_triplets!r}; valid: "
                             f"{', '.join(TEXT_PLATE_TRIPLETS)}")
        self.text_triplets = text_triplets
        self.E, self.nu, self.h = float(E), float(nu), float(thickness)
        self.mu = self.E / (2 * (1 + self.nu))
        self.ks = float(shear_factor)

    def fields(self):
        from upscale.engine.fields import FieldSpec

        rho = self.system.density if self.system is not None else 1.0
        return {"rot": FieldSpec(2, rho * self.h ** 2 / 12.0, "rad")}

    def _inertia_d(self):
        rho = float(np.mean(self.system.density))
        r = rho * self.h ** 2 / 12.0
        return np.array([rho, rho, rho, r, r])

    def prepare(self, system, family, **kw):
        from upscale.engine.multibody import build_triplets

        Model.prepare(self, system, family, **kw)
        if system.dim != 2:
            raise ValueError(f"model {self.name!r} needs a 2D body (square_lattice), "
                             f"got dim={system.dim}")
        if not np.isclose(system.thickness, self.h, rtol=1e-12):
            raise ValueError(f"plate thickness {self.h!r} m differs from the body's "
                             f"{system.thickness!r} m; valid: the same value")
        if self.variant == "text":
            self._prepare_text(system, family)
            return
        tri = build_triplets(system.x0, family)
        mem = tri.members(family)
        x0 = system.x0
        dj = x0[mem[:, 1]] - x0[mem[:, 0]]
        dk = x0[mem[:, 2]] - x0[mem[:, 0]]
        tol = 1e-9 * system.spacing
        onx_j = (np.abs(dj[:, 1]) < tol)
        ony_j = (np.abs(dj[:, 0]) < tol)
        onx_k = (np.abs(dk[:, 1]) < tol)
        ony_k = (np.abs(dk[:, 0]) < tol)
        swap = ony_j & onx_k
        keep = (onx_j & ony_k) | swap
        mem = mem[keep]
        sw = swap[keep]
        mem[sw, 1], mem[sw, 2] = mem[sw, 2].copy(), mem[sw, 1].copy()
        counts = np.bincount(mem[:, 0], minlength=system.n)
        self.off_t = np.zeros(system.n + 1, np.int64)
        self.off_t[1:] = np.cumsum(counts)
        order = np.argsort(mem[:, 0], kind="stable")
        self.mem_t = np.ascontiguousarray(mem[order])
        if (counts == 0).any():
            i = int(np.flatnonzero(counts == 0)[0])
            if family.counts[i] == 0:
                raise ValueError(f"horizon {family.horizon:.6g} m leaves particle {i} without "
                                 f"triplets; valid: delta/dx >= 1")
        i, j, k = self.mem_t.T
        sx = x0[j, 0] - x0[i, 0]
        sy = x0[k, 1] - x0[i, 1]
        nt = i.size
        V = system.volume
        pv = V[j] * V[k]
        tot = np.bincount(i, weights=pv, minlength=system.n)
        w = V[i] * pv / tot[i]
        C = np.zeros((nt, 8, 3, 5))
        r2 = 1.0 / np.sqrt(2.0)

        def gx(m, dof, f=1.0):
            C[:, m, 0, dof] += -f / sx
            C[:, m, 1, dof] += f / sx

        def gy(m, dof, f=1.0):
            C[:, m, 0, dof] += -f / sy
            C[:, m, 2, dof] += f / sy

        for base, (a, b) in ((0, (0, 1)), (3, (3, 4))):
            gx(base, a, r2)
            gy(base, b, r2)           # (e_xx + e_yy)/sqrt 2
            gx(base + 1, a, r2)
            gy(base + 1, b, -r2)      # (e_xx - e_yy)/sqrt 2
            gy(base + 2, a)
            gx(base + 2, b)           # e_xy (engineering)
        gx(6, 2)
        C[:, 6, 0, 3] += -0.5
        C[:, 6, 1, 3] += -0.5
        gy(7, 2)
        C[:, 7, 0, 4] += -0.5
        C[:, 7, 2, 4] += -0.5
        self.coef = np.ascontiguousarray(C)
        Cm = self.E / (1 - self.nu ** 2)
        r = self.h ** 2 / 12.0
        K = np.array([Cm * (1 + self.nu), Cm * (1 - self.nu), self.mu,
                      r * Cm * (1 + self.nu), r * Cm * (1 - self.nu), r * self.mu,
                      self.ks * self.mu, self.ks * self.mu])
        self.K = K
        self._wt = np.ascontiguousarray(w)
        self.w0_tm = np.repeat(w[:, None], 8, axis=1)
        self.w_tm = np.ascontiguousarray(self.w0_tm * K[None, :])

    def _prepare_text(self, system, family):
        """Measure tables of the printed plate (4.1-4.14) for the printed EOM 4.48-4.52
        with the constants 4.53/4.63 (see :class:`TridynPlate`, variant "text")."""
        x0 = system.x0
        V = system.volume
        tol = 1e-9 * system.spacing
        rows = []
        for i in range(system.n):
            nb_ = family.neighbors[family.offsets[i]:family.offsets[i + 1]]
            d = x0[nb_, :2] - x0[i, :2]
            onx, ony = nb_[np.abs(d[:, 1]) < tol], nb_[np.abs(d[:, 0]) < tol]
            sets = ((onx, onx), (ony, ony)) if self.text_triplets == "lines" else \
                ((np.concatenate([onx, ony]),) * 2,)
            for a_, b_ in sets:
                if a_.size and b_.size:
                    jj, kk = np.meshgrid(a_, b_, indexing="ij")
                    rows.append(np.stack([np.full(jj.size, i), jj.ravel(), kk.ravel()], axis=1))
        mem = np.concatenate(rows).astype(np.int64) if rows else np.zeros((0, 3), np.int64)
        if np.unique(mem[:, 0]).size < system.n:
            raise ValueError(f"horizon {family.horizon:.6g} m leaves a particle without "
                             f"neighbours on its x or y line; valid: delta/dx >= 1")
        mem = mem[np.argsort(mem[:, 0], kind="stable")]
        counts = np.bincount(mem[:, 0], minlength=system.n)
        self.off_t = np.zeros(system.n + 1, np.int64)
        self.off_t[1:] = np.cumsum(counts)
        self.mem_t = np.ascontiguousarray(mem)
        i, j, k = mem.T
        nt = i.size

        def inv(a, b, c):
            """1/xi^c_ab, zero where xi^c_ab = 0 (the term is dropped) and its sign n^c_ab."""
            dd = x0[b, c] - x0[a, c]
            z = np.abs(dd) < tol
            return np.where(z, 0.0, 1.0 / np.where(z, 1.0, np.abs(dd))), np.where(z, 0.0, np.sign(dd))

        # the three permutations (centre, first, second) = (i, j, k), (j, k, i), (k, i, j) as
        # member slots (0, 1, 2): s_abc = (q_b - q_a)/xi_ab + (q_c - q_a)/xi_ac
        perms = ((0, 1, 2), (1, 2, 0), (2, 0, 1))
        members = (i, j, k)

        def diff_measure(C, m, dof, c, f=1.0):
            for p, (a, b, cc) in enumerate(perms):
                ib, _ = inv(members[a], members[b], c)
                ic, _ = inv(members[a], members[cc], c)
                C[:, m + p, a, dof] += -f * (ib + ic)
                C[:, m + p, b, dof] += f * ib
                C[:, m + p, cc, dof] += f * ic

        def shear_measure(C, m, wdof, pdof, c):
            diff_measure(C, m, wdof, c)
            for p, (a, b, cc) in enumerate(perms):
                for o in (b, cc):
                    _, n_ = inv(members[a], members[o], c)
                    C[:, m + p, a, pdof] += -n_ / 2
                    C[:, m + p, o, pdof] += -n_ / 2

        mu, Cm = self.mu, self.E / (1 - self.nu ** 2)
        r = self.h ** 2 / 12.0
        i0 = self._text_bulk(family, x0, tol)
        nb0 = family.neighbors[family.offsets[i0]:family.offsets[i0 + 1]]
        d0 = x0[nb0, :2] - x0[i0, :2]
        VT = float(np.sum(V[nb0[(np.abs(d0[:, 0]) < tol) | (np.abs(d0[:, 1]) < tol)]]))  # 4.61
        K1e, K2e = mu / 2, Cm * self.nu + mu / 2                 # 4.63 times V_T^2
        K1p, K2p = r * mu / 2, r * (Cm * self.nu + mu / 2)
        Kex = np.array([[2 * K1e, K1e + K2e], [K1e + K2e, 2 * K2e]])
        Kpx = np.array([[2 * K1p, K1p + K2p], [K1p + K2p, 2 * K2p]])
        C = np.zeros((nt, 30, 3, 5))
        lam = np.zeros(30)
        diff_measure(C, 0, 0, 0)                 # eps^xx: u over x
        diff_measure(C, 3, 1, 1)                 # eps^yy: v over y
        diff_measure(C, 12, 3, 0)                # kappa^xx: phi_x over x
        diff_measure(C, 15, 4, 1)                # kappa^yy: phi_y over y
        shear_measure(C, 24, 2, 3, 0)            # psi^x: w over x, phi_x
        shear_measure(C, 27, 2, 4, 1)            # psi^y: w over y, phi_y
        lam[0:6] = Cm
        lam[12:18] = r * Cm
        lam[24:30] = self.ks * mu
        # eps^xy = 1eps (u over y) + 2eps (v over x), coupled by the printed EOM's matrix
        # [[2 1K, 1K + 2K], [1K + 2K, 2 2K]]: diagonalised, one measure per eigenvector
        for base, (dofa, dofb), Kmat in ((6, (0, 1), Kex), (18, (3, 4), Kpx)):
            ev, Q = np.linalg.eigh(Kmat)
            one = np.zeros((nt, 3, 3, 5))
            two = np.zeros((nt, 3, 3, 5))
            diff_measure(one, 0, dofa, 1)
            diff_measure(two, 0, dofb, 0)
            for e in range(2):
                C[:, base + 3 * e:base + 3 * e + 3] = Q[0, e] * one + Q[1, e] * two
                lam[base + 3 * e:base + 3 * e + 3] = ev[e]
        self.coef = np.ascontiguousarray(C)
        self.K = lam / VT ** 2
        w = V[i] * V[j] * V[k] / 3.0             # (1/3) sum_jk ... V_j V_k (4.48-4.52), per particle
        self.w0_tm = np.repeat(w[:, None], 30, axis=1)
        self.w_tm = np.ascontiguousarray(self.w0_tm * self.K[None, :])
        self.VT = VT

    @staticmethod
    def _text_bulk(family, x0, tol):
        counts = family.counts
        cand = np.flatnonzero(counts == counts.max())
        mid = 0.5 * (x0.min(axis=0) + x0.max(axis=0))
        return int(cand[np.argmin(np.sum((x0[cand] - mid) ** 2, axis=1))])

    def _fast_force(self, q):
        if self.variant == "text":
            return None
        n = q.shape[0]
        nc = _nchunks(n)
        buf = np.zeros((nc, n, 5))
        plate_grad_kernel(self.off_t, self.mem_t, self._wt, self.system.x0, q, self.K, buf)
        return buf[0] if nc == 1 else buf.sum(axis=0)

    def _bounds(self):
        if self.variant != "text":
            return super()._bounds()
        n = self.system.n
        buf = np.zeros((_nchunks(n), n, self.nd))
        bound_kernel(self.off_t, self.mem_t, self.coef, np.abs(self.w_tm),
                     1.0 / np.sqrt(self._inertia_d()), True, buf)
        return buf.sum(axis=0) / self.system.volume[:, None]

    def influence_radius(self):
        return 2.0 * self.family.horizon + 2.0 * self.system.spacing

    def describe(self):
        d = {"model": self.name, "variant": self.variant, "E_Pa": self.E, "nu": self.nu,
             "thickness_m": self.h, "shear_factor": self.ks}
        if self.variant == "text":
            d["text_triplets"] = self.text_triplets
        return d


register("tridyn-plate", TridynPlate)


def literal_local_coefficients(E, nu, shear_factor=5.0 / 6.0, I_over_A=1.0):
    """Coefficients of the printed local limit 4.60 with the printed constants 4.63, beside
    Mindlin's 4.62: ``{term: (literal, Mindlin)}`` (V_T cancels). The v,xx and phi_y,xx
    terms carry ``2 (2K^exy) V_T^2 = mu + 2 E nu/(1 - nu^2)`` instead of mu."""
    mu = E / (2 * (1 + nu))
    C = E / (1 - nu ** 2)
    K1, K2 = mu / 2, E * nu / (1 - nu ** 2) + mu / 2     # 1K^exy V_T^2, 2K^exy V_T^2
    r = I_over_A
    return {
        "u: u,xx": (C, C), "u: u,yy": (2 * K1, mu), "u: v,xy": (K1 + K2, E * nu / (1 - nu ** 2) + mu),
        "v: v,yy": (C, C), "v: v,xx": (2 * K2, mu), "v: u,xy": (K1 + K2, E * nu / (1 - nu ** 2) + mu),
        "w: w,xx - phi_x,x": (shear_factor * mu, shear_factor * mu),
        "phi_x: phi_x,xx": (r * C, r * C), "phi_x: phi_x,yy": (2 * r * K1, r * mu),
        "phi_x: phi_y,xy": (r * (K1 + K2), r * (E * nu / (1 - nu ** 2) + mu)),
        "phi_y: phi_y,yy": (r * C, r * C), "phi_y: phi_y,xx": (2 * r * K2, r * mu),
        "phi_y: phi_x,xy": (r * (K1 + K2), r * (E * nu / (1 - nu ** 2) + mu)),
    }


def plate(*, a, n, thickness, horizon_ratio=1.0, E=200e9, nu=0.3, density=7850.0,
          shear_factor=5.0 / 6.0, load=0.0, support="ss"):
    """A square plate [0, a]^2 with ``n`` spacings per side, simply supported ("hard":
    w = 0 and the tangential rotation = 0 on the edges, mirror ghosts: w odd, phi_x even
    in x and odd in y, phi_y the converse) or free, in-plane displacements held, uniform
    transverse load q (N/m^2). Returns ``(system, family, model, conditions, body_mask)``."""
    from upscale.engine import conditions as cnd
    from upscale.engine.families import build_family
    from upscale.engine.fields import FixedField, Tie
    from upscale.engine.system import ParticleSystem

    if support not in ("ss", "free"):
        raise ValueError(f"unknown plate support {support!r}; valid: 'ss', 'free'")
    _positive(a=a, thickness=thickness)
    n = int(n)
    dx = a / n
    delta = horizon_ratio * dx * (1 + 1e-9)
    ng = int(np.ceil(2 * delta / dx)) + 1 if support == "ss" else 0
    ii = np.arange(-ng, n + 1 + ng)
    I, J = np.meshgrid(ii, ii, indexing="ij")
    I, J = I.ravel(), J.ravel()
    x = np.stack([I * dx, J * dx, np.zeros(I.size)], axis=1)
    system = ParticleSystem(x, dx * dx * thickness, density, dim=2, thickness=thickness,
                            spacing=dx)
    family = build_family(system, delta)
    model = TridynPlate(E, nu, thickness=thickness, shear_factor=shear_factor)
    body = (I >= 0) & (I <= n) & (J >= 0) & (J <= n)
    conds = [cnd.Fixed(cnd.Region("all", np.ones(I.size, bool)), components=(0, 1))]
    if support == "ss":
        key = {(int(p), int(q)): s for s, (p, q) in enumerate(zip(I, J))}

        def refl(t):
            return -t if t < 0 else (2 * n - t if t > n else t)

        ghost = ~body
        reg = cnd.Region("ghosts", ghost)
        gi = reg.index
        masters = np.array([key[(refl(int(I[g])), refl(int(J[g])))] for g in gi])
        fx = np.array([-1.0 if (I[g] < 0 or I[g] > n) else 1.0 for g in gi])
        fy = np.array([-1.0 if (J[g] < 0 or J[g] > n) else 1.0 for g in gi])
        # parities: w odd-odd; phi_x even in x, odd in y; phi_y odd in x, even in y
        conds.append(Tie(reg, masters[:, None], (fx * fy)[:, None], ("y", 2)))
        conds.append(Tie(reg, masters[:, None], fy[:, None], ("rot", 0)))
        conds.append(Tie(reg, masters[:, None], fx[:, None], ("rot", 1)))
        edge = body & ((I == 0) | (I == n) | (J == 0) | (J == n))
        conds.append(cnd.Fixed(cnd.Region("edges", edge), components=(2,)))
        ex = body & ((J == 0) | (J == n))   # edges y = 0, a: phi_x tangential
        ey = body & ((I == 0) | (I == n))   # edges x = 0, a: phi_y tangential
        conds.append(FixedField(cnd.Region("edges_y", ex), "rot", (0,)))
        conds.append(FixedField(cnd.Region("edges_x", ey), "rot", (1,)))
    if load:
        conds.append(cnd.BodyForce(cnd.Region("plate", body), (0.0, 0.0, load / thickness)))
    return system, family, model, conds, body


def navier_mindlin(x, y, a, q, E, nu, h, shear_factor=5.0 / 6.0, terms=199):
    """Deflection of a simply supported square plate under uniform load q: the Navier
    series ``sum_{m,n odd} 16 q/(pi^2 m n) sin(m pi x/a) sin(n pi y/a)
    [1/(D alpha^4) + 1/(k_s mu h alpha^2)]``, ``alpha^2 = (m^2 + n^2) pi^2/a^2``,
    ``D = E h^3/(12 (1 - nu^2))`` (Kirchhoff term plus Mindlin's shear term; exact for the
    hard simply supported Mindlin plate). Returns (Mindlin, Kirchhoff)."""
    D = E * h ** 3 / (12 * (1 - nu ** 2))
    mu = E / (2 * (1 + nu))
    m = np.arange(1, terms + 1, 2)
    M, Nn = np.meshgrid(m, m, indexing="ij")
    al2 = (M ** 2 + Nn ** 2) * np.pi ** 2 / a ** 2
    qmn = 16 * q / (np.pi ** 2 * M * Nn)
    sx = np.sin(np.multiply.outer(np.atleast_1d(x), m) * np.pi / a)
    sy = np.sin(np.multiply.outer(np.atleast_1d(y), m) * np.pi / a)
    kb = qmn / (D * al2 ** 2)
    ks_ = qmn / (shear_factor * mu * h * al2)
    wk = np.einsum("pm,pn,mn->p", sx, sy, kb)
    ws = np.einsum("pm,pn,mn->p", sx, sy, ks_)
    return wk + ws, wk
