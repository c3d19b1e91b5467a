"""Pad atoms: the neighbours the atomistic region needs, slaved to their carrier's map.

A pad atom a follows its carrier particle c (the nearest non-slave particle) through c's
uniform cylindrical map (:mod:`.maps`), the map that gives c its lattice energy (seed 004
eq. 5.13), with the sublattice shift for atoms of sublattice B:

    x_a = y_c + Q3_c (h_a + r0_a),
    h_a = (rho sin phi, lam_z dz + sig d_z, rho cos phi - lam_t R0),
    rho = lam_t R0 + sig d_rho,   phi = (lam_t ds + gam dz + sig d_s) / (lam_t R0),

(ds, dz) the atom's reference arc and axial offset from c, sig = 1 on sublattice B, r0_a
the reference residual (the pad sits on its reference position at the reference state).
:func:`pad_backward` pulls dE/dx_a back to the carrier's position, shift and frame
(whose adjoints :func:`.maps.frame_adjoint` takes to dE/dF), exactly. A carrier G has
dropped keeps its frame fixed at ``Q3_fixed`` (no adjoint).

Suffixes: ``_a`` per pad atom, ``_n`` per particle. Units: Å.
"""
from __future__ import annotations

import math

from numba import njit

__all__ = ["pad_positions", "pad_backward"]


@njit(cache=True, error_model="numpy")
def pad_positions(y_n, delta_n, par_n, Q3_n, c_a, ds_a, dz_a, sig_a, r0_a, R0, x_out):
    """Positions (npad, 3) of the pad atoms into ``x_out`` (mutated)."""
    for a in range(c_a.shape[0]):
        c = c_a[a]
        lt, gm, lz = par_n[c, 0], par_n[c, 1], par_n[c, 2]
        sig = sig_a[a]
        rp = lt * R0
        rho = rp + sig * delta_n[c, 0]
        phi = (lt * ds_a[a] + gm * dz_a[a] + sig * delta_n[c, 1]) / rp
        h0 = rho * math.sin(phi) + r0_a[a, 0]
        h1 = lz * dz_a[a] + sig * delta_n[c, 2] + r0_a[a, 1]
        h2 = rho * math.cos(phi) - rp + r0_a[a, 2]
        for i in range(3):
            x_out[a, i] = y_n[c, i] + (Q3_n[c, i, 0] * h0 + Q3_n[c, i, 1] * h1 + Q3_n[c, i, 2] * h2)


@njit(cache=True, error_model="numpy")
def pad_backward(g_a, delta_n, par_n, Q3_n, own_n, c_a, ds_a, dz_a, sig_a, r0_a, R0, gy_n,
                 gd_n, gQ3_n, gpar_n):
    """Add dE/dx of the pad atoms (npad, 3) into their carriers' dE/dy (``gy_n``),
    dE/d delta (``gd_n``) and, where the frame is the carrier's own (``own_n``), the
    frame adjoints ``gQ3_n``, ``gpar_n`` (all mutated)."""
    for a in range(c_a.shape[0]):
        c = c_a[a]
        lt, gm, lz = par_n[c, 0], par_n[c, 1], par_n[c, 2]
        g0, g1, g2 = g_a[a, 0], g_a[a, 1], g_a[a, 2]
        gy_n[c, 0] += g0
        gy_n[c, 1] += g1
        gy_n[c, 2] += g2
        sig, ds, dz = sig_a[a], ds_a[a], dz_a[a]
        rp = lt * R0
        rho = rp + sig * delta_n[c, 0]
        phi = (lt * ds + gm * dz + sig * delta_n[c, 1]) / rp
        sp, cp = math.sin(phi), math.cos(phi)
        gh0 = Q3_n[c, 0, 0] * g0 + Q3_n[c, 1, 0] * g1 + Q3_n[c, 2, 0] * g2
        gh1 = Q3_n[c, 0, 1] * g0 + Q3_n[c, 1, 1] * g1 + Q3_n[c, 2, 1] * g2
        gh2 = Q3_n[c, 0, 2] * g0 + Q3_n[c, 1, 2] * g1 + Q3_n[c, 2, 2] * g2
        gd_n[c, 0] += sig * (gh0 * sp + gh2 * cp)
        gd_n[c, 1] += (gh0 * rho * cp - gh2 * rho * sp) * sig / rp
        gd_n[c, 2] += gh1 * sig
        if not own_n[c]:
            continue
        h = (rho * sp + r0_a[a, 0], lz * dz + sig * delta_n[c, 2] + r0_a[a, 1],
             rho * cp - rp + r0_a[a, 2])
        for i in range(3):
            gi = g0 if i == 0 else (g1 if i == 1 else g2)
            gQ3_n[c, i, 0] += gi * h[0]
            gQ3_n[c, i, 1] += gi * h[1]
            gQ3_n[c, i, 2] += gi * h[2]
        dphi_lt = -(gm * dz + sig * delta_n[c, 1]) / (lt * rp)
        dphi_gm = dz / rp
        gpar_n[c, 0] += (gh0 * (R0 * sp + rho * cp * dphi_lt)
                         + gh2 * (R0 * cp - rho * sp * dphi_lt - R0))
        gpar_n[c, 1] += (gh0 * rho * cp - gh2 * rho * sp) * dphi_gm
        gpar_n[c, 2] += gh1 * dz
