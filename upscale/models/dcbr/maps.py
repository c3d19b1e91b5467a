"""Each particle's uniform cylindrical map and its adjoint (numba).

The hourglass control (:mod:`.hourglass`) and the pad atoms of the coupling place points
with a particle's uniform map: with FS = F S (3x2), C = FS^T FS and M = chol(C) =
[[lam_t, gam], [0, lam_z]] (seed 004 eq. 5.13 on the closed tube, :mod:`.cell`),

    q1 = FS_0 / lam_t,   q2 = (FS_1 - gam q1) / lam_z,   n = q1 x q2,   Q3 = [q1 q2 n],

the deformed local frame. :func:`map_frames` evaluates (lam_t, gam, lam_z, Q3) once per
particle; :func:`frame_adjoint` takes the adjoints dE/dQ3 and dE/d(lam_t, gam, lam_z)
gathered per particle back to dE/dF in one reverse pass through the frame and the
Cholesky factor (exact; the same algebra as the validated coarse tube's
``dcbr_coupling_kernels``).

Suffixes: ``_n`` per particle. F (N, 3, 2) dimensionless, lengths Å.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["map_frames", "frame_adjoint", "frame_of"]


@njit(cache=True, error_model="numpy")
def frame_of(FS, par, Q3):
    """(lam_t, gam, lam_z) into ``par`` (3,) and Q3 (3, 3) of one map FS (3, 2) (mutated)."""
    C00 = FS[0, 0] * FS[0, 0] + FS[1, 0] * FS[1, 0] + FS[2, 0] * FS[2, 0]
    C01 = FS[0, 0] * FS[0, 1] + FS[1, 0] * FS[1, 1] + FS[2, 0] * FS[2, 1]
    C11 = FS[0, 1] * FS[0, 1] + FS[1, 1] * FS[1, 1] + FS[2, 1] * FS[2, 1]
    lt = math.sqrt(C00)
    gm = C01 / lt
    lz = math.sqrt(C11 - gm * gm)
    par[0], par[1], par[2] = lt, gm, lz
    for i in range(3):
        Q3[i, 0] = FS[i, 0] / lt
    for i in range(3):
        Q3[i, 1] = (FS[i, 1] - gm * Q3[i, 0]) / lz
    Q3[0, 2] = Q3[1, 0] * Q3[2, 1] - Q3[2, 0] * Q3[1, 1]
    Q3[1, 2] = Q3[2, 0] * Q3[0, 1] - Q3[0, 0] * Q3[2, 1]
    Q3[2, 2] = Q3[0, 0] * Q3[1, 1] - Q3[1, 0] * Q3[0, 1]


@njit(cache=True, inline="always")
def _fs(F_n, S_n, gain_alive_n, c, FS):
    """FS = F_c S_c into ``FS`` (3, 2); eye(3, 2) S_c where G dropped the particle."""
    for i in range(3):
        for b in range(2):
            if gain_alive_n[c]:
                FS[i, b] = F_n[c, i, 0] * S_n[c, 0, b] + F_n[c, i, 1] * S_n[c, 1, b]
            else:
                FS[i, b] = S_n[c, i, b] if i < 2 else 0.0


@njit(cache=True, error_model="numpy")
def map_frames(F_n, S_n, gain_alive_n, par_n, Q3_n):
    """Each particle's (lam_t, gam, lam_z) into ``par_n`` (N, 3) and Q3 into ``Q3_n``
    (N, 3, 3) (mutated); particles G dropped take the map eye(3, 2) (they own no link)."""
    FS = np.empty((3, 2))
    for c in range(F_n.shape[0]):
        _fs(F_n, S_n, gain_alive_n, c, FS)
        frame_of(FS, par_n[c], Q3_n[c])


@njit(cache=True, error_model="numpy")
def frame_adjoint(F_n, S_n, gain_alive_n, par_n, Q3_n, gQ3_n, gpar_n, P_n):
    """Add dE/dF (N, 3, 2) into ``P_n`` (mutated) given dE/dQ3 (N, 3, 3) and
    dE/d(lam_t, gam, lam_z) (N, 3): the reverse pass through :func:`frame_of` and FS = F S.
    Particles with all-zero adjoints are skipped."""
    FS = np.empty((3, 2))
    gFS = np.empty((3, 2))
    for c in range(F_n.shape[0]):
        if not gain_alive_n[c]:  # the frame does not come from F
            continue
        nz = gpar_n[c, 0] != 0.0 or gpar_n[c, 1] != 0.0 or gpar_n[c, 2] != 0.0
        for u in range(3):
            for v in range(3):
                nz = nz or gQ3_n[c, u, v] != 0.0
        if not nz:
            continue
        _fs(F_n, S_n, gain_alive_n, c, FS)
        lt, gm, lz = par_n[c, 0], par_n[c, 1], par_n[c, 2]
        glt, ggm, glz = gpar_n[c, 0], gpar_n[c, 1], gpar_n[c, 2]
        q1 = Q3_n[c, :, 0]
        q2 = Q3_n[c, :, 1]
        gn = gQ3_n[c, :, 2]
        # n = q1 x q2: n . gn = q1 . (q2 x gn) = q2 . (gn x q1)
        gq1 = np.empty(3)
        gq2 = np.empty(3)
        gq1[0] = gQ3_n[c, 0, 0] + (q2[1] * gn[2] - q2[2] * gn[1])
        gq1[1] = gQ3_n[c, 1, 0] + (q2[2] * gn[0] - q2[0] * gn[2])
        gq1[2] = gQ3_n[c, 2, 0] + (q2[0] * gn[1] - q2[1] * gn[0])
        gq2[0] = gQ3_n[c, 0, 1] + (gn[1] * q1[2] - gn[2] * q1[1])
        gq2[1] = gQ3_n[c, 1, 1] + (gn[2] * q1[0] - gn[0] * q1[2])
        gq2[2] = gQ3_n[c, 2, 1] + (gn[0] * q1[1] - gn[1] * q1[0])
        # q2 = (FS_1 - gam q1) / lam_z
        for i in range(3):
            gFS[i, 1] = gq2[i] / lz
        ggm -= (q1[0] * gq2[0] + q1[1] * gq2[1] + q1[2] * gq2[2]) / lz
        glz -= (q2[0] * gq2[0] + q2[1] * gq2[1] + q2[2] * gq2[2]) / lz
        for i in range(3):
            gq1[i] -= gm * gq2[i] / lz
        gC11 = glz / (2.0 * lz)          # lam_z = sqrt(C11 - gam^2)
        ggm -= gm * glz / lz
        for i in range(3):               # q1 = FS_0 / lam_t
            gFS[i, 0] = gq1[i] / lt
        glt -= (q1[0] * gq1[0] + q1[1] * gq1[1] + q1[2] * gq1[2]) / lt
        gC01 = ggm / lt                  # gam = C01 / lam_t
        glt -= gm * ggm / lt
        gC00 = glt / (2.0 * lt)          # lam_t = sqrt(C00)
        for i in range(3):               # C = FS^T FS
            gFS[i, 0] += 2.0 * gC00 * FS[i, 0] + gC01 * FS[i, 1]
            gFS[i, 1] += 2.0 * gC11 * FS[i, 1] + gC01 * FS[i, 0]
        for i in range(3):               # FS_ib = sum_a F_ia S_ab
            for a in range(2):
                P_n[c, i, a] += gFS[i, 0] * S_n[c, a, 0] + gFS[i, 1] * S_n[c, a, 1]
