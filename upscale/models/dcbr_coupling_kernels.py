"""numba kernels of the DCBR terms that go through each particle's uniform cylindrical map.

The hourglass penalty of :class:`~upscale.models.dcbr.DCBRTube` and the pad atoms of
:class:`~upscale.models.dcbr_defect.DCBRDefectTube` both place points with a particle's
uniform map (see :func:`upscale.models.dcbr.uniform_map_frame`): with FS = F S (3x2),
C = FS^T FS, M = chol(C) = [[lam_t, gam], [0, lam_z]],

    q1 = FS_0 / lam_t,  q2 = (FS_1 - gam q1) / lam_z,  n = q1 x q2,  Q3 = [q1 q2 n],
    x = y_c + Q3 (h + r0),
    h = (rho sin phi, lam_z dz + sig d_z, rho cos phi - lam_t R0),
    rho = lam_t R0 + sig d_rho,  phi = (lam_t ds + gam dz + sig d_s) / (lam_t R0)

(sig = 0 for a hourglass link, the sublattice flag for a pad atom). The numpy versions
differentiate this by complex steps (nine whole-array evaluations per call); here the map
is evaluated once per particle (:func:`map_frames`), each point's gradient is pulled back
to the particle's (Q3, lam_t, gam, lam_z) (adjoints accumulated per particle), and one
reverse pass per particle through the Cholesky factor and the frame takes them to
dE/dF (:func:`frame_adjoint`). Serial loops: the scatter to owners is race-free and the
problem sizes (thousands of points) are far below where threads pay on a shared machine.

Array suffixes: ``_n`` per particle, ``_e`` per hourglass link, ``_a`` per pad atom.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from upscale.engine.fields import pairwise_sum

__all__ = ["map_frames", "frame_adjoint", "stab_links", "pad_positions", "pad_backward",
           "max_displacement2", "take_rows", "sub_rows", "particle_positions", "fold_gradient",
           "transfer", "same", "ghost_gradient", "cluster_pairs"]


@njit(cache=True, error_model="numpy")
def _frame(FS, par, Q3):
    """(lam_t, gam, lam_z) into par[0:3] and Q3 (3,3) of one surface map FS (3,2)."""
    C00 = FS[0, 0] * FS[0, 0] + FS[1, 0] * FS[1, 0] + FS[2, 0] * FS[2, 0]
    C01 = FS[0, 0] * FS[0, 1] + FS[1, 0] * FS[1, 1] + FS[2, 0] * FS[2, 1]
    C11 = FS[0, 1] * FS[0, 1] + FS[1, 1] * FS[1, 1] + FS[2, 1] * FS[2, 1]
    lt = math.sqrt(C00)
    gm = C01 / lt
    lz = math.sqrt(C11 - gm * gm)
    par[0] = lt
    par[1] = gm
    par[2] = lz
    for i in range(3):
        Q3[i, 0] = FS[i, 0] / lt
    for i in range(3):
        Q3[i, 1] = (FS[i, 1] - gm * Q3[i, 0]) / lz
    Q3[0, 2] = Q3[1, 0] * Q3[2, 1] - Q3[2, 0] * Q3[1, 1]
    Q3[1, 2] = Q3[2, 0] * Q3[0, 1] - Q3[0, 0] * Q3[2, 1]
    Q3[2, 2] = Q3[0, 0] * Q3[1, 1] - Q3[1, 0] * Q3[0, 1]


@njit(cache=True, error_model="numpy")
def map_frames(F_n, S_n, gain_alive_n, alive_n, FS_n, par_n, Q3_n, flag_n):
    """Per particle: FS = F S (the raw map, into ``FS_n``), (lam_t, gam, lam_z) into
    ``par_n`` (N,3) and Q3 into ``Q3_n`` (N,3,3) of the map the hourglass term uses (F
    replaced by eye(3,2) on particles G dropped: they own no link), and ``flag_n``:
    1 if the particle is alive with a regular raw map (C_00 > 1e-6, det C > 1e-9: its map
    is kept as the last good one), -1 if it is dead or its raw map is degenerate (C_00 <
    1e-6 or det C < 1e-9: its pads keep the last good map), 0 otherwise."""
    N = F_n.shape[0]
    FSe = np.empty((3, 2))
    for c in range(N):
        for i in range(3):
            for b in range(2):
                FS_n[c, i, b] = F_n[c, i, 0] * S_n[c, 0, b] + F_n[c, i, 1] * S_n[c, 1, b]
        C00 = FS_n[c, 0, 0] * FS_n[c, 0, 0] + FS_n[c, 1, 0] * FS_n[c, 1, 0] \
            + FS_n[c, 2, 0] * FS_n[c, 2, 0]
        C01 = FS_n[c, 0, 0] * FS_n[c, 0, 1] + FS_n[c, 1, 0] * FS_n[c, 1, 1] \
            + FS_n[c, 2, 0] * FS_n[c, 2, 1]
        C11 = FS_n[c, 0, 1] * FS_n[c, 0, 1] + FS_n[c, 1, 1] * FS_n[c, 1, 1] \
            + FS_n[c, 2, 1] * FS_n[c, 2, 1]
        det = C00 * C11 - C01 * C01
        if (not alive_n[c]) or C00 < 1e-6 or det < 1e-9:
            flag_n[c] = -1
        elif C00 > 1e-6 and det > 1e-9:
            flag_n[c] = 1
        else:
            flag_n[c] = 0
        if gain_alive_n[c]:
            _frame(FS_n[c], par_n[c], Q3_n[c])
        else:
            for i in range(3):
                for b in range(2):
                    FSe[i, b] = S_n[c, i, b] if i < 2 else 0.0
            _frame(FSe, par_n[c], Q3_n[c])


@njit(cache=True, error_model="numpy")
def frame_adjoint(F_n, S_n, gain_alive_n, par_n, Q3_n, gQ3_n, gpar_n, P_n):
    """Add dE/dF (N,3,2) into ``P_n`` given the adjoints dE/dQ3 (N,3,3) and
    dE/d(lam_t, gam, lam_z) (N,3) of each particle's frame (reverse pass through
    :func:`_frame` and FS = F S). Particles with all-zero adjoints are skipped."""
    N = F_n.shape[0]
    FS = np.empty((3, 2))
    gFS = np.empty((3, 2))
    for c in range(N):
        nz = gpar_n[c, 0] != 0.0 or gpar_n[c, 1] != 0.0 or gpar_n[c, 2] != 0.0
        for u in range(3):
            for v in range(3):
                if gQ3_n[c, u, v] != 0.0:
                    nz = True
        if not nz:
            continue
        for i in range(3):
            for b in range(2):
                if gain_alive_n[c]:
                    FS[i, b] = F_n[c, i, 0] * S_n[c, 0, b] + F_n[c, i, 1] * S_n[c, 1, b]
                else:
                    FS[i, b] = S_n[c, i, b] if i < 2 else 0.0
        lt, gm, lz = par_n[c, 0], par_n[c, 1], par_n[c, 2]
        glt, ggm, glz = gpar_n[c, 0], gpar_n[c, 1], gpar_n[c, 2]
        q10, q11, q12 = Q3_n[c, 0, 0], Q3_n[c, 1, 0], Q3_n[c, 2, 0]
        q20, q21, q22 = Q3_n[c, 0, 1], Q3_n[c, 1, 1], Q3_n[c, 2, 1]
        gn0, gn1, gn2 = gQ3_n[c, 0, 2], gQ3_n[c, 1, 2], gQ3_n[c, 2, 2]
        # n = q1 x q2: n . gn = q1 . (q2 x gn) = q2 . (gn x q1)
        gq10 = gQ3_n[c, 0, 0] + (q21 * gn2 - q22 * gn1)
        gq11 = gQ3_n[c, 1, 0] + (q22 * gn0 - q20 * gn2)
        gq12 = gQ3_n[c, 2, 0] + (q20 * gn1 - q21 * gn0)
        gq20 = gQ3_n[c, 0, 1] + (gn1 * q12 - gn2 * q11)
        gq21 = gQ3_n[c, 1, 1] + (gn2 * q10 - gn0 * q12)
        gq22 = gQ3_n[c, 2, 1] + (gn0 * q11 - gn1 * q10)
        # q2 = (FS_1 - gam q1) / lam_z
        gFS[0, 1] = gq20 / lz
        gFS[1, 1] = gq21 / lz
        gFS[2, 1] = gq22 / lz
        ggm -= (q10 * gq20 + q11 * gq21 + q12 * gq22) / lz
        glz -= (q20 * gq20 + q21 * gq21 + q22 * gq22) / lz
        gq10 -= gm * gq20 / lz
        gq11 -= gm * gq21 / lz
        gq12 -= gm * gq22 / lz
        # lam_z = sqrt(C11 - gam^2)
        gC11 = glz / (2.0 * lz)
        ggm -= gm * glz / lz
        # q1 = FS_0 / lam_t
        gFS[0, 0] = gq10 / lt
        gFS[1, 0] = gq11 / lt
        gFS[2, 0] = gq12 / lt
        glt -= (q10 * gq10 + q11 * gq11 + q12 * gq12) / lt
        # gam = C01 / lam_t
        gC01 = ggm / lt
        glt -= gm * ggm / lt
        # lam_t = sqrt(C00)
        gC00 = glt / (2.0 * lt)
        # C = FS^T FS
        for i in range(3):
            g0 = 2.0 * gC00 * FS[i, 0] + gC01 * FS[i, 1]
            g1 = 2.0 * gC11 * FS[i, 1] + gC01 * FS[i, 0]
            gFS[i, 0] += g0
            gFS[i, 1] += g1
        if not gain_alive_n[c]:  # the frame did not come from F
            continue
        # FS_ib = sum_a F_ia S_ab
        for i in range(3):
            for a in range(2):
                P_n[c, i, a] += gFS[i, 0] * S_n[c, a, 0] + gFS[i, 1] * S_n[c, a, 1]


@njit(cache=True, error_model="numpy")
def stab_links(y_n, Lz, c_e, j_e, imz_e, w_e, ds_e, dz_e, r0_e, a_e, s_e, k_stab, R0,
               par_n, Q3_n, gy_n, wn_n, gQ3_n, gpar_n):
    """The hourglass penalty W_stab (:meth:`upscale.models.dcbr.DCBRTube.stab_energy_and_gradient`).

    Adds dW/dy (direct terms) into ``gy_n``, each owner's share into ``wn_n`` and the
    adjoints dW/dQ3, dW/d(lam_t, gam, lam_z) of the owners' frames into ``gQ3_n``,
    ``gpar_n``. Returns (W, dW/dLz direct)."""
    ne = c_e.shape[0]
    N = y_n.shape[0]
    r_e = np.empty((ne, 3))
    hr_e = np.empty((ne, 3))
    Fr = np.zeros((N, 3, 2))
    for e in range(ne):
        c = c_e[e]
        j = j_e[e]
        lt, gm, lz = par_n[c, 0], par_n[c, 1], par_n[c, 2]
        Rp = lt * R0
        phi = (lt * ds_e[e] + gm * dz_e[e]) / Rp
        h0 = Rp * math.sin(phi) + r0_e[e, 0]
        h1 = lz * dz_e[e] + r0_e[e, 1]
        h2 = -Rp * (1.0 - math.cos(phi)) + r0_e[e, 2]
        hr_e[e, 0] = h0
        hr_e[e, 1] = h1
        hr_e[e, 2] = h2
        for i in range(3):
            p = Q3_n[c, i, 0] * h0 + Q3_n[c, i, 1] * h1 + Q3_n[c, i, 2] * h2
            lk = y_n[j, i] - y_n[c, i]
            if i == 2:
                lk += imz_e[e] * Lz
            r = lk - p
            r_e[e, i] = r
            Fr[c, i, 0] += r * a_e[e, 0]
            Fr[c, i, 1] += r * a_e[e, 1]
    # rt = r - Fr_c s (the part G cannot see); krt = k w rt; B_c = sum krt (x) s
    B = np.zeros((N, 3, 2))
    E = 0.0
    for e in range(ne):
        c = c_e[e]
        kw = k_stab * w_e[e]
        rr = 0.0
        for i in range(3):
            rt = r_e[e, i] - (Fr[c, i, 0] * s_e[e, 0] + Fr[c, i, 1] * s_e[e, 1])
            rr += rt * rt
            krt = kw * rt
            r_e[e, i] = krt
            B[c, i, 0] += krt * s_e[e, 0]
            B[c, i, 1] += krt * s_e[e, 1]
        we = 0.5 * kw * rr
        wn_n[c] += we
        E += we
    dL = 0.0
    for e in range(ne):
        c = c_e[e]
        j = j_e[e]
        lt, gm, lz = par_n[c, 0], par_n[c, 1], par_n[c, 2]
        g0 = 0.0
        g1 = 0.0
        g2 = 0.0
        for i in range(3):
            kr = r_e[e, i] - (B[c, i, 0] * a_e[e, 0] + B[c, i, 1] * a_e[e, 1])
            gy_n[j, i] += kr
            gy_n[c, i] -= kr
            if i == 0:
                g0 = -kr
            elif i == 1:
                g1 = -kr
            else:
                g2 = -kr
                dL += kr * imz_e[e]
        # dW/dp = -kr; p = Q3 (h + r0)
        for i in range(3):
            gi = g0 if i == 0 else (g1 if i == 1 else g2)
            for v in range(3):
                gQ3_n[c, i, v] += gi * hr_e[e, v]
        gh0 = Q3_n[c, 0, 0] * g0 + Q3_n[c, 1, 0] * g1 + Q3_n[c, 2, 0] * g2
        gh1 = Q3_n[c, 0, 1] * g0 + Q3_n[c, 1, 1] * g1 + Q3_n[c, 2, 1] * g2
        gh2 = Q3_n[c, 0, 2] * g0 + Q3_n[c, 1, 2] * g1 + Q3_n[c, 2, 2] * g2
        ds = ds_e[e]
        dz = dz_e[e]
        Rp = lt * R0
        phi = (lt * ds + gm * dz) / Rp
        sp = math.sin(phi)
        cp = math.cos(phi)
        dphi_lt = -gm * dz / (lt * Rp)
        dphi_gm = dz / Rp
        gpar_n[c, 0] += gh0 * (R0 * sp + Rp * cp * dphi_lt) \
            + gh2 * (R0 * cp - Rp * sp * dphi_lt - R0)
        gpar_n[c, 1] += (gh0 * Rp * cp - gh2 * Rp * sp) * dphi_gm
        gpar_n[c, 2] += gh1 * dz
    return E, dL


@njit(cache=True, error_model="numpy")
def _pad_frame(c, flag_n, FS_last_n, par_n, Q3_n, par_w, Q3_w):
    """The frame a pad of carrier c follows: the carrier's own, or (a dead or degenerate
    carrier) the frame of its last good map, into the work arrays; True if it is the
    carrier's own (its derivatives go to F)."""
    if flag_n[c] < 0:
        _frame(FS_last_n[c], par_w, Q3_w)
        return False
    for k in range(3):
        par_w[k] = par_n[c, k]
        for v in range(3):
            Q3_w[k, v] = Q3_n[c, k, v]
    return True


@njit(cache=True, error_model="numpy")
def pad_positions(y_n, delta_n, par_n, Q3_n, flag_n, FS_last_n, c_a, ds_a, dz_a, sig_a, r0_a,
                  R0, x_out):
    """Positions (npad,3) of the pad atoms into ``x_out``."""
    par = np.empty(3)
    Q3 = np.empty((3, 3))
    for a in range(c_a.shape[0]):
        c = c_a[a]
        _pad_frame(c, flag_n, FS_last_n, par_n, Q3_n, par, Q3)
        lt, gm, lz = par[0], par[1], par[2]
        sig = sig_a[a]
        rp = lt * R0
        rho = rp + sig * delta_n[c, 0]
        phi = (lt * ds_a[a] + gm * dz_a[a] + sig * delta_n[c, 1]) / rp
        h0 = rho * math.sin(phi) + r0_a[a, 0]
        h1 = lz * dz_a[a] + sig * delta_n[c, 2] + r0_a[a, 1]
        h2 = rho * math.cos(phi) - rp + r0_a[a, 2]
        for i in range(3):
            x_out[a, i] = y_n[c, i] + (Q3[i, 0] * h0 + Q3[i, 1] * h1 + Q3[i, 2] * h2)


@njit(cache=True, error_model="numpy")
def pad_backward(g_a, delta_n, par_n, Q3_n, flag_n, FS_last_n, c_a, ds_a, dz_a, sig_a, r0_a,
                 R0, relax_shift, gy_n, gd_n, gQ3_n, gpar_n):
    """Pull the gradient dE/dx of the pad atoms (npad,3) back to their carriers: adds into
    dE/dy (``gy_n``), dE/d delta (``gd_n``, if ``relax_shift``) and the adjoints of the
    carriers' frames (``gQ3_n``, ``gpar_n``; not for a carrier whose pads keep its last
    good map, which does not depend on F)."""
    par = np.empty(3)
    Q3 = np.empty((3, 3))
    for a in range(c_a.shape[0]):
        c = c_a[a]
        own = _pad_frame(c, flag_n, FS_last_n, par_n, Q3_n, par, Q3)
        lt, gm, lz = par[0], par[1], par[2]
        g0, g1, g2 = g_a[a, 0], g_a[a, 1], g_a[a, 2]
        gy_n[c, 0] += g0
        gy_n[c, 1] += g1
        gy_n[c, 2] += g2
        sig = sig_a[a]
        ds = ds_a[a]
        dz = dz_a[a]
        rp = lt * R0
        rho = rp + sig * delta_n[c, 0]
        num = lt * ds + gm * dz + sig * delta_n[c, 1]
        phi = num / rp
        sp = math.sin(phi)
        cp = math.cos(phi)
        gh0 = Q3[0, 0] * g0 + Q3[1, 0] * g1 + Q3[2, 0] * g2
        gh1 = Q3[0, 1] * g0 + Q3[1, 1] * g1 + Q3[2, 1] * g2
        gh2 = Q3[0, 2] * g0 + Q3[1, 2] * g1 + Q3[2, 2] * g2
        if relax_shift:
            dphi_d1 = sig / rp
            gd_n[c, 0] += sig * (gh0 * sp + gh2 * cp)
            gd_n[c, 1] += (gh0 * rho * cp - gh2 * rho * sp) * dphi_d1
            gd_n[c, 2] += gh1 * sig
        if not own:
            continue
        h0 = rho * sp + r0_a[a, 0]
        h1 = lz * dz + sig * delta_n[c, 2] + r0_a[a, 1]
        h2 = rho * cp - rp + r0_a[a, 2]
        for i in range(3):
            gi = g0 if i == 0 else (g1 if i == 1 else g2)
            gQ3_n[c, i, 0] += gi * h0
            gQ3_n[c, i, 1] += gi * h1
            gQ3_n[c, i, 2] += gi * h2
        dphi_lt = -(gm * dz + sig * delta_n[c, 1]) / (lt * rp)
        dphi_gm = dz / rp
        gpar_n[c, 0] += gh0 * (R0 * sp + rho * cp * dphi_lt) \
            + gh2 * (R0 * cp - rho * sp * dphi_lt - R0)
        gpar_n[c, 1] += (gh0 * rho * cp - gh2 * rho * sp) * dphi_gm
        gpar_n[c, 2] += gh1 * dz


@njit(cache=True, error_model="numpy")
def max_displacement2(x, x_ref):
    """(largest squared displacement of a row of x from x_ref, index of the first row of x
    with a non-finite entry or -1)."""
    m = 0.0
    for i in range(x.shape[0]):
        d2 = 0.0
        for k in range(3):
            v = x[i, k]
            if not math.isfinite(v):
                return math.inf, i
            d = v - x_ref[i, k]
            d2 += d * d
        if d2 > m:
            m = d2
    return m, -1


# --------------------------------------------------------------------------- row glue
# The engine model's per-step array glue (gathering the unknown rows, scattering their
# forces, the slaves' interpolation y_s = Phi (x - X) + X_s and its transpose) in single
# loops: numpy's fancy indexing and scipy's sparse products cost tens of microseconds of
# overhead each at these sizes, a few times per inner step. Every sum runs in the order
# of the numpy / scipy expression it replaces (``csr_matvecs``: zero, then each stored
# entry in turn), so the numbers are the same to the last bit.

@njit(cache=True)
def keep_maps(FS_ck, flag_c, rows_c, last_nck, out_ck):
    """The carriers' maps for their pads: a carrier whose map is valid (``flag > 0``) records
    it as its last map, ``last[rows[c]] = FS[c]``; every carrier's pads then use
    ``out[c] = last[rows[c]]`` (its last valid map if the current one failed). ``rows``
    distinct."""
    for c in range(rows_c.shape[0]):
        r = rows_c[c]
        if flag_c[c] > 0:
            for i in range(FS_ck.shape[1]):
                for a in range(FS_ck.shape[2]):
                    last_nck[r, i, a] = FS_ck[c, i, a]
        for i in range(FS_ck.shape[1]):
            for a in range(FS_ck.shape[2]):
                out_ck[c, i, a] = last_nck[r, i, a]
    return out_ck


@njit(cache=True)
def take_rows(a_nc, rows_i):
    """a[rows] (a new (k, 3) array)."""
    out = np.empty((rows_i.shape[0], 3))
    for i in range(rows_i.shape[0]):
        r = rows_i[i]
        out[i, 0] = a_nc[r, 0]
        out[i, 1] = a_nc[r, 1]
        out[i, 2] = a_nc[r, 2]
    return out


@njit(cache=True)
def same_rows(c_ic, a_nc, rows_i):
    """Whether c == a[rows] everywhere (:func:`take_rows` then :func:`same`, without the
    copy)."""
    if c_ic.shape[0] != rows_i.shape[0]:
        return False
    for i in range(rows_i.shape[0]):
        r = rows_i[i]
        if not (c_ic[i, 0] == a_nc[r, 0] and c_ic[i, 1] == a_nc[r, 1]
                and c_ic[i, 2] == a_nc[r, 2]):
            return False
    return True


@njit(cache=True)
def sub_rows(out_nc, rows_i, g_ic):
    """out[rows] -= g (rows distinct)."""
    for i in range(rows_i.shape[0]):
        r = rows_i[i]
        out_nc[r, 0] = out_nc[r, 0] - g_ic[i, 0]
        out_nc[r, 1] = out_nc[r, 1] - g_ic[i, 1]
        out_nc[r, 2] = out_nc[r, 2] - g_ic[i, 2]


@njit(cache=True)
def particle_positions(y_uc, nd, dof_i, slave_i, indptr, indices, data, off_sc, yp_nc):
    """All particle positions into ``yp_nc`` (N, 3) from the unknowns y (nd non-slave
    particles, then the free atoms): yp[dof] = y[:nd], yp[slave_s] = sum_a Phi_sa
    y[nd + a] + off_s (Phi in CSR: ``indptr``, ``indices``, ``data``)."""
    for i in range(dof_i.shape[0]):
        r = dof_i[i]
        for k in range(3):
            yp_nc[r, k] = y_uc[i, k]
    for s in range(slave_i.shape[0]):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for jj in range(indptr[s], indptr[s + 1]):
            w = data[jj]
            j = nd + indices[jj]
            a0 += w * y_uc[j, 0]
            a1 += w * y_uc[j, 1]
            a2 += w * y_uc[j, 2]
        r = slave_i[s]
        yp_nc[r, 0] = a0 + off_sc[s, 0]
        yp_nc[r, 1] = a1 + off_sc[s, 1]
        yp_nc[r, 2] = a2 + off_sc[s, 2]


@njit(cache=True)
def fold_gradient(gyp_nc, gx_ac, nd, dof_i, slave_i, indptrT, indicesT, dataT, gy_uc):
    """dE/d(unknowns) into ``gy_uc`` (nd + nf, 3) from dE/d(particle positions) ``gyp_nc``
    and dE/d(free atoms) ``gx_ac`` (nf, 3; or an empty (0, 3) array: zero): gy[:nd] =
    gyp[dof], gy[nd + a] = gx_a + sum_s Phi_sa gyp[slave_s] (Phi^T in CSR)."""
    for i in range(dof_i.shape[0]):
        r = dof_i[i]
        for k in range(3):
            gy_uc[i, k] = gyp_nc[r, k]
    nf = gy_uc.shape[0] - nd
    have = gx_ac.shape[0] > 0
    for a in range(nf):
        b0 = gx_ac[a, 0] if have else 0.0
        b1 = gx_ac[a, 1] if have else 0.0
        b2 = gx_ac[a, 2] if have else 0.0
        if slave_i.shape[0] > 0:
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for jj in range(indptrT[a], indptrT[a + 1]):
                w = dataT[jj]
                r = slave_i[indicesT[jj]]
                a0 += w * gyp_nc[r, 0]
                a1 += w * gyp_nc[r, 1]
                a2 += w * gyp_nc[r, 2]
            b0 = b0 + a0
            b1 = b1 + a1
            b2 = b2 + a2
        gy_uc[nd + a, 0] = b0
        gy_uc[nd + a, 1] = b1
        gy_uc[nd + a, 2] = b2


@njit(cache=True)
def transfer(y_uc, yr_uc, d_nc, dr_nc, gy_uc, gd_nc, H_n33, gq_nc):
    """The split's transfer (:meth:`DCBRDefectTubeModel.prepare_split`): returns
    Q = g_y . (y - y_r) + g_d . (delta - delta_r) + 1/2 (delta - delta_r) . H (delta -
    delta_r) and writes dQ/d delta = g_d + H (delta - delta_r) into ``gq_nc``. The sums in
    numpy's order (``np.sum`` of the products, pairwise; H dd as ``np.einsum`` pairs it,
    (H_0 dd_0 + H_2 dd_2) + H_1 dd_1), so the numbers equal the numpy expression's."""
    nu = y_uc.shape[0]
    n = d_nc.shape[0]
    a = np.empty(3 * nu)
    for i in range(nu):
        for k in range(3):
            a[3 * i + k] = gy_uc[i, k] * (y_uc[i, k] - yr_uc[i, k])
    s1 = pairwise_sum(a, 3 * nu)
    b = np.empty(3 * n)
    c = np.empty(3 * n)
    for i in range(n):
        e0 = d_nc[i, 0] - dr_nc[i, 0]
        e1 = d_nc[i, 1] - dr_nc[i, 1]
        e2 = d_nc[i, 2] - dr_nc[i, 2]
        for k in range(3):
            hd = (H_n33[i, k, 0] * e0 + H_n33[i, k, 2] * e2) + H_n33[i, k, 1] * e1
            gq_nc[i, k] = gd_nc[i, k] + hd
            ek = e0 if k == 0 else (e1 if k == 1 else e2)
            b[3 * i + k] = gd_nc[i, k] * ek
            c[3 * i + k] = ek * hd
    s2 = pairwise_sum(b, 3 * n)
    s3 = pairwise_sum(c, 3 * n)
    return s1 + s2 + 0.5 * s3


@njit(cache=True)
def same(a, b):
    """Whether a == b everywhere (``np.array_equal`` of two arrays of one shape)."""
    fa = a.ravel()
    fb = b.ravel()
    if fa.shape[0] != fb.shape[0]:
        return False
    for i in range(fa.shape[0]):
        if not fa[i] == fb[i]:
            return False
    return True


@njit(cache=True, inline="always")
def _mean_xy(a_uc):
    """The means of columns 0 and 1 of a (n, >= 2) array, summed row by row from the first
    (numpy's order for a column mean of an (n, 2) view)."""
    n = a_uc.shape[0]
    sx = a_uc[0, 0]
    sy = a_uc[0, 1]
    for u in range(1, n):
        sx += a_uc[u, 0]
        sy += a_uc[u, 1]
    return sx / n, sy / n


@njit(cache=True, error_model="numpy")
def ghost_gradient(y_uc, gr_u, gt_u, gz_u, gy_uc, gd_nc, gdl_nc, gy_out, gd_out):
    """The gradient of the ghost-force dead load's work W
    (:meth:`~upscale.models.dcbr_defect.DCBRDefectTube.ghost_load_work`) added to (gy, gd):
    with each row's offset from the rows' centroid, x_u = y_u - mean(y) (x, y components),
    rho_u = |x_u|, the load's components gr, gt (times the uniform radius) and gz,

        c_u = (gr x_u + gt (-x_u,2, x_u,1) / rho_u) / rho_u,
        gy_out = gy - (c_u - mean(c), gz_u),   gd_out = gd - g_delta

    (the centroid's own dependence on y_u takes the mean of c out). The operations and the
    order of every sum are numpy's (a column mean of an (n, 2) view sums row by row), so
    the result equals the array expression bit for bit."""
    n = y_uc.shape[0]
    cx, cy = _mean_xy(y_uc)
    for u in range(n):
        x0 = y_uc[u, 0] - cx
        x1 = y_uc[u, 1] - cy
        rho = math.hypot(x0, x1)
        gy_out[u, 0] = (gr_u[u] * x0 - gt_u[u] * x1 / rho) / rho
        gy_out[u, 1] = (gr_u[u] * x1 + gt_u[u] * x0 / rho) / rho
    mx, my = _mean_xy(gy_out)
    for u in range(n):
        gy_out[u, 0] = gy_uc[u, 0] - (gy_out[u, 0] - mx)
        gy_out[u, 1] = gy_uc[u, 1] - (gy_out[u, 1] - my)
        gy_out[u, 2] = gy_uc[u, 2] - gz_u[u]
    for c in range(gd_nc.shape[0]):
        for k in range(3):
            gd_out[c, k] = gd_nc[c, k] - gdl_nc[c, k]


#: largest number of grid cells per atom for which :func:`cluster_pairs` uses a dense grid
#: (a tube wall fills a few per cent of its box's cells of side 2.4 Å: a 62 Å tube's 24 Å
#: band, about 2,800 atoms, has some 9,000 cells)
GRID_CELLS_PER_ATOM = 16


@njit(cache=True)
def _lower_bound(a, v):
    """The first index p with a[p] >= v in the sorted array a (numba's np.searchsorted
    measured about 2x slower per call on these short arrays)."""
    lo = 0
    hi = a.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if a[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def _collect_pairs(x_ac, n_rows, rc, c_ac, ny, nz, ks, order, buf, cnt):
    """Each row's partners within rc into buf[i, :cnt[i]]; False when a row has more than
    buf.shape[1] (the caller retries with room for more)."""
    n = x_ac.shape[0]
    cap = buf.shape[1]
    rc2 = rc * rc
    for i in range(n_rows):
        for d0 in range(-1, 2):
            for d1 in range(-1, 2):
                c1 = c_ac[i, 1] + d1
                if c1 < 0 or c1 >= ny:
                    continue
                # the three cells along z of this column have consecutive keys
                base = ((c_ac[i, 0] + d0) * ny + c1) * nz
                k_hi = base + min(c_ac[i, 2] + 1, nz - 1)
                p = _lower_bound(ks, base + max(c_ac[i, 2] - 1, 0))
                while p < n and ks[p] <= k_hi:
                    j = order[p]
                    p += 1
                    if j == i:
                        continue
                    e0 = x_ac[j, 0] - x_ac[i, 0]
                    e1 = x_ac[j, 1] - x_ac[i, 1]
                    e2 = x_ac[j, 2] - x_ac[i, 2]
                    if e0 * e0 + e1 * e1 + e2 * e2 <= rc2:
                        if cnt[i] == cap:
                            return False
                        buf[i, cnt[i]] = j
                        cnt[i] += 1
    return True


@njit(cache=True)
def _collect_pairs_grid(x_ac, n_rows, rc, c_ac, nx, ny, nz, start, order, buf, cnt):
    """As :func:`_collect_pairs` on a dense grid: ``start`` (nx ny nz + 1) the first
    position in ``order`` of every cell (z the fastest index, so a column's three cells
    along z are one run of ``order``). (The distance test and append are written out in
    both collectors: a shared numba helper, even with ``inline="always"``, made this
    build 4x slower, 0.74 -> 3.0 ms on a 3,660-atom wall.)"""
    cap = buf.shape[1]
    rc2 = rc * rc
    for i in range(n_rows):
        z_lo = max(c_ac[i, 2] - 1, 0)
        z_hi = min(c_ac[i, 2] + 1, nz - 1)
        for d0 in range(-1, 2):
            c0 = c_ac[i, 0] + d0
            if c0 < 0 or c0 >= nx:
                continue
            for d1 in range(-1, 2):
                c1 = c_ac[i, 1] + d1
                if c1 < 0 or c1 >= ny:
                    continue
                base = (c0 * ny + c1) * nz
                for p in range(start[base + z_lo], start[base + z_hi + 1]):
                    j = order[p]
                    if j == i:
                        continue
                    e0 = x_ac[j, 0] - x_ac[i, 0]
                    e1 = x_ac[j, 1] - x_ac[i, 1]
                    e2 = x_ac[j, 2] - x_ac[i, 2]
                    if e0 * e0 + e1 * e1 + e2 * e2 <= rc2:
                        if cnt[i] == cap:
                            return False
                        buf[i, cnt[i]] = j
                        cnt[i] += 1
    return True


@njit(cache=True)
def cluster_pairs(x_ac, n_rows, rc):
    """Verlet list of an open cluster: CSR ``(first (n+1,) int64, partners int32)`` of the
    pairs (i, j), i < ``n_rows``, j any row but i, with |x_j - x_i| <= ``rc``, each row's
    partners in increasing order (rows from ``n_rows`` on have none): the pair set of a
    k-d tree's ``query_pairs(rc)``. Cells of side rc: a dense grid over the cluster's box
    (each cell's atoms found by a counting sort, O(n + cells)) while the box holds at most
    :data:`GRID_CELLS_PER_ATOM` cells per atom; beyond that (a few atoms flown far off,
    after failure) the cells are keyed by their integer coordinates and sorted, O(n log
    n) however far they have flown. Both give the same list."""
    n = x_ac.shape[0]
    if n == 0 or n_rows == 0:
        return np.zeros(n + 1, np.int64), np.empty(0, np.int32)
    inv = 1.0 / rc
    lo0, lo1, lo2 = x_ac[0, 0], x_ac[0, 1], x_ac[0, 2]
    for a in range(1, n):
        lo0 = min(lo0, x_ac[a, 0])
        lo1 = min(lo1, x_ac[a, 1])
        lo2 = min(lo2, x_ac[a, 2])
    c_ac = np.empty((n, 3), np.int64)
    m0 = 0
    m1 = 0
    m2 = 0
    for a in range(n):
        c_ac[a, 0] = int(math.floor((x_ac[a, 0] - lo0) * inv))
        c_ac[a, 1] = int(math.floor((x_ac[a, 1] - lo1) * inv))
        c_ac[a, 2] = int(math.floor((x_ac[a, 2] - lo2) * inv))
        m0 = max(m0, c_ac[a, 0])
        m1 = max(m1, c_ac[a, 1])
        m2 = max(m2, c_ac[a, 2])
    nx = m0 + 1
    ny = m1 + 1
    nz = m2 + 1
    key = np.empty(n, np.int64)
    for a in range(n):
        key[a] = (c_ac[a, 0] * ny + c_ac[a, 1]) * nz + c_ac[a, 2]
    # (the cell count as a float: a far-flung atom can make it overflow an integer)
    grid = float(nx) * float(ny) * float(nz) <= GRID_CELLS_PER_ATOM * n
    if grid:  # counting sort of the atoms by cell
        ncell = nx * ny * nz
        start = np.zeros(ncell + 1, np.int64)
        for a in range(n):
            start[key[a] + 1] += 1
        for c in range(ncell):
            start[c + 1] += start[c]
        fill = start[:ncell].copy()
        order = np.empty(n, np.int64)
        for a in range(n):
            order[fill[key[a]]] = a
            fill[key[a]] += 1
    else:
        order = np.argsort(key)
        ks = key[order]
    cap = 32
    while True:
        buf = np.empty((max(n_rows, 1), cap), np.int32)
        cnt = np.zeros(max(n_rows, 1), np.int64)
        if grid:
            ok = _collect_pairs_grid(x_ac, n_rows, rc, c_ac, nx, ny, nz, start, order, buf,
                                     cnt)
        else:
            ok = _collect_pairs(x_ac, n_rows, rc, c_ac, ny, nz, ks, order, buf, cnt)
        if ok:
            break
        cap *= 4
    first = np.zeros(n + 1, np.int64)
    for i in range(n_rows):
        first[i + 1] = first[i] + cnt[i]
    for i in range(n_rows, n):
        first[i + 1] = first[i]
    part = np.empty(first[n], np.int32)
    for i in range(n_rows):  # each row's partners in increasing order (insertion sort)
        b0 = first[i]
        for b in range(cnt[i]):
            v = buf[i, b]
            c = b0 + b - 1
            while c >= b0 and part[c] > v:
                part[c + 1] = part[c]
                c -= 1
            part[c + 1] = v
    return first, part
