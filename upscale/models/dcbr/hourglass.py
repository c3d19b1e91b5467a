"""Zero-energy-mode (hourglass) control of the coarse tube.

G_c does not see u_c itself, so checkerboard patterns of the regular grid leave every G
unchanged and cost nothing. A penalty on the non-affine part of each link restores their
stiffness (Silling 2017; Breitenfeld et al. 2014, hourglass control of correspondence
peridynamics), with the link predicted by the owner's uniform cylindrical map (the map
the lattice energy uses, :mod:`.maps`):

    W_stab = 1/2 k_s sum_c sum_{b of c, intact} |rt_b|^2 / |beta_b|^2,
    p_b = Q3_c (h_b + r0_b),  h_b = (R' sin phi, lam_z dz, -R' (1 - cos phi)),
    R' = lam_t R0,  phi = (lam_t ds + gam dz) / R',
    r_b = y_j + k_b L e_z - y_c - p_b,   rt_b = r_b - (sum_b' r_b' (x) a_b') s_b

(ds, dz: the link's reference arc and axial offsets in c's frame; s_b its tangent
coordinates; a_b G's coefficients, so rt is r with G's own linear fit removed; r0_b the
residual at the reference, zero on a full symmetric family). W_stab is zero for every
rigid motion and uniform radial/axial stretch. Stiffness from the lattice itself:
k_s = hourglass N_c c_zz / 8, c_zz = d^2 e / d lam_z^2 (eV/atom, shift relaxed, central
difference with step 1e-3), so a non-affine link strain eps on the 8 links of the 3x3
stencil costs ``hourglass`` times the particle's uniaxial energy N_c c_zz eps^2 / 2.

This is the term of the validated coarse tube (``upscale.models.dcbr.DCBRTube``, old
module), written once here. Units: eV, Å. Suffixes: ``_b`` per link, ``_n`` per particle.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from upscale.models.dcbr.maps import frame_adjoint, map_frames

__all__ = ["Hourglass", "stab_links"]


@njit(cache=True, error_model="numpy")
def stab_links(y_n, L, c_b, j_b, k_b, w_b, ds_b, dz_b, r0_b, a_b, s_b, k_stab, R0, par_n,
               Q3_n, gy_n, wn_n, gQ3_n, gpar_n):
    """W_stab (eV) and its direct dW/dL (eV/Å); adds dW/dy into ``gy_n``, each owner's
    share into ``wn_n`` and the adjoints dW/dQ3, dW/d(lam_t, gam, lam_z) of the owners'
    frames into ``gQ3_n``, ``gpar_n`` (all mutated)."""
    nb, N = c_b.shape[0], y_n.shape[0]
    r_b = np.empty((nb, 3))
    hr_b = np.empty((nb, 3))
    Fr = np.zeros((N, 3, 2))
    for e in range(nb):
        c, j = c_b[e], j_b[e]
        lt, gm, lz = par_n[c, 0], par_n[c, 1], par_n[c, 2]
        Rp = lt * R0
        phi = (lt * ds_b[e] + gm * dz_b[e]) / Rp
        hr_b[e, 0] = Rp * math.sin(phi) + r0_b[e, 0]
        hr_b[e, 1] = lz * dz_b[e] + r0_b[e, 1]
        hr_b[e, 2] = -Rp * (1.0 - math.cos(phi)) + r0_b[e, 2]
        for i in range(3):
            p = Q3_n[c, i, 0] * hr_b[e, 0] + Q3_n[c, i, 1] * hr_b[e, 1] + Q3_n[c, i, 2] * hr_b[e, 2]
            lk = y_n[j, i] - y_n[c, i] + (k_b[e] * L if i == 2 else 0.0)
            r_b[e, i] = lk - p
            Fr[c, i, 0] += r_b[e, i] * a_b[e, 0]
            Fr[c, i, 1] += r_b[e, i] * a_b[e, 1]
    B = np.zeros((N, 3, 2))
    E = 0.0
    for e in range(nb):
        c = c_b[e]
        kw = k_stab * w_b[e]
        rr = 0.0
        for i in range(3):
            rt = r_b[e, i] - (Fr[c, i, 0] * s_b[e, 0] + Fr[c, i, 1] * s_b[e, 1])
            rr += rt * rt
            r_b[e, i] = kw * rt
            B[c, i, 0] += r_b[e, i] * s_b[e, 0]
            B[c, i, 1] += r_b[e, i] * s_b[e, 1]
        wn_n[c] += 0.5 * kw * rr
        E += 0.5 * kw * rr
    dL = 0.0
    g = np.empty(3)
    for e in range(nb):
        c, j = c_b[e], j_b[e]
        for i in range(3):
            kr = r_b[e, i] - (B[c, i, 0] * a_b[e, 0] + B[c, i, 1] * a_b[e, 1])
            gy_n[j, i] += kr
            gy_n[c, i] -= kr
            g[i] = -kr                   # dW/dp
        dL -= g[2] * k_b[e]
        _link_adjoint(e, c, g, hr_b, ds_b, dz_b, R0, par_n, Q3_n, gQ3_n, gpar_n)
    return E, dL


@njit(cache=True, inline="always")
def _link_adjoint(e, c, g, hr_b, ds_b, dz_b, R0, par_n, Q3_n, gQ3_n, gpar_n):
    """Pull dW/dp_b = g (3,) back to the owner's Q3 and (lam_t, gam, lam_z) (mutated)."""
    lt, gm, lz = par_n[c, 0], par_n[c, 1], par_n[c, 2]
    for i in range(3):
        for v in range(3):
            gQ3_n[c, i, v] += g[i] * hr_b[e, v]
    gh0 = Q3_n[c, 0, 0] * g[0] + Q3_n[c, 1, 0] * g[1] + Q3_n[c, 2, 0] * g[2]
    gh1 = Q3_n[c, 0, 1] * g[0] + Q3_n[c, 1, 1] * g[1] + Q3_n[c, 2, 1] * g[2]
    gh2 = Q3_n[c, 0, 2] * g[0] + Q3_n[c, 1, 2] * g[1] + Q3_n[c, 2, 2] * g[2]
    ds, dz = ds_b[e], dz_b[e]
    Rp = lt * R0
    phi = (lt * ds + gm * dz) / Rp
    sp, cp = math.sin(phi), math.cos(phi)
    dphi_lt = -gm * dz / (lt * Rp)
    dphi_gm = dz / Rp
    gpar_n[c, 0] += gh0 * (R0 * sp + Rp * cp * dphi_lt) + gh2 * (R0 * cp - Rp * sp * dphi_lt - R0)
    gpar_n[c, 1] += (gh0 * Rp * cp - gh2 * Rp * sp) * dphi_gm
    gpar_n[c, 2] += gh1 * dz


class Hourglass:
    """The hourglass term of a :class:`.tube.CoarseTube` (module docstring).

    Parameters
    ----------
    tube : CoarseTube
        Its gain, cell, particles (read at :meth:`rebuild`).
    fraction : float
        ``hourglass``: k_s as a fraction of the lattice stiffness; 0 switches it off.
    """

    def __init__(self, tube, fraction: float):
        if not (np.isfinite(fraction) and fraction >= 0.0):
            raise ValueError(f"hourglass={fraction!r}; valid: a number >= 0 (0 = off)")
        self.tube = tube
        self.fraction = float(fraction)
        self.scale_n = None  # per-owner scale of the links (the coupling's w_c / nominal)
        self.k_stab = 0.0
        if self.fraction > 0.0:
            h = 1e-3
            ez = [tube.cell.relaxed(1.0, 0.0, 1.0 + t, tube.P_f)[0] for t in (-h, 0.0, h)]
            self.c_zz = (ez[0] - 2 * ez[1] + ez[2]) / h ** 2
            self.k_stab = self.fraction * float(tube.natoms_n[0]) * self.c_zz / 8.0
        self.rebuild()

    def rebuild(self) -> None:
        """Link data over the intact links of alive rows: owner, partner, image, 1/|beta|^2,
        reference (ds, dz), G's coefficients a and tangent coordinates s, residual r0."""
        t, g = self.tube, self.tube.gain
        owner = g.owner_b
        keep = g.alive[owner] & g.intact_b
        beta = g.beta()[keep]
        c = owner[keep]
        T = g.frame_nck[c]
        nrm = np.cross(T[:, :, 0], T[:, :, 1])
        R0 = t.cell.R0
        dth = np.arctan2(np.einsum("bi,bi->b", beta, T[:, :, 0]),
                         R0 + np.einsum("bi,bi->b", beta, nrm))
        self.c_b = c.astype(np.int64)
        self.j_b = g.j_b[keep].astype(np.int64)
        self.kz_b = np.ascontiguousarray(g.k_b[keep])
        self.w_b = 1.0 / np.einsum("bi,bi->b", beta, beta)
        if self.scale_n is not None:
            self.w_b = self.w_b * self.scale_n[c]
        self.ds_b = R0 * dth
        self.dz_b = np.einsum("bi,bi->b", beta, T[:, :, 1])
        self.a_b = np.ascontiguousarray(g.a_bk[keep])
        self.s_b = np.ascontiguousarray(np.einsum("bia,bi->ba", T, beta))
        self.r0_b = np.zeros((len(c), 3))
        F0 = g.deformation(t.x0, t.L if t.periodic else None)
        par, Q3 = self._frames(F0)
        h = self._chords(par)
        self.r0_b = np.ascontiguousarray(np.einsum("bia,bi->ba", Q3[self.c_b], beta) - h)

    def _frames(self, F):
        g = self.tube.gain
        par, Q3 = np.empty((g.n, 3)), np.empty((g.n, 3, 3))
        map_frames(np.ascontiguousarray(F), g.S, g.alive, par, Q3)
        return par, Q3

    def _chords(self, par):
        """h_b (nb, 3): the chord of each link under its owner's uniform map."""
        c = self.c_b
        Rp = par[c, 0] * self.tube.cell.R0
        phi = (par[c, 0] * self.ds_b + par[c, 1] * self.dz_b) / Rp
        return np.stack([Rp * np.sin(phi), par[c, 2] * self.dz_b, -Rp * (1.0 - np.cos(phi))], 1)

    def energy_and_gradient(self, y, F, L):
        """(W_stab eV, dW/dF (N,3,2), direct dW/dy (N,3), direct dW/dL eV/Å); sets
        ``w_n`` (N,), each particle's share (its own links)."""
        g = self.tube.gain
        N = g.n
        P, gy = np.zeros((N, 3, 2)), np.zeros((N, 3))
        self.w_n = np.zeros(N)
        if self.k_stab == 0.0 or len(self.c_b) == 0:
            return 0.0, P, gy, 0.0
        par, Q3 = self._frames(F)
        gQ3, gpar = np.zeros((N, 3, 3)), np.zeros((N, 3))
        E, dL = stab_links(y, 0.0 if L is None else float(L), self.c_b, self.j_b, self.kz_b,
                           self.w_b, self.ds_b, self.dz_b, self.r0_b, self.a_b, self.s_b,
                           self.k_stab, self.tube.cell.R0, par, Q3, gy, self.w_n, gQ3, gpar)
        frame_adjoint(np.ascontiguousarray(F), g.S, g.alive, par, Q3, gQ3, gpar, P)
        return float(E), P, gy, float(dL)
