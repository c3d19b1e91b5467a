"""Atoms where the lattice is not perfect, coarse particles elsewhere: the coupling, once.

An energy-based concurrent coupling (the quasicontinuum method's, seed 004 sec. 5.3's
arrangement refined to the lattice near a defect):

    E = sum_{a free} (E_a - e0) + sum_c w_c (e(C_c, delta_c) - e0) + W_stab

* **Region, whole cells.** Every lattice site (the registered lattice map's, occupied or
  empty) belongs to its nearest particle on the unrolled wall (Voronoi in (R0 dtheta, dz)).
  A particle owning a site of an atom of the atomistic regions (:mod:`.regions`: every atom
  within r_atomistic of a defect, plus a user selection), an empty site, or an atom off
  the lattice gives all its atoms to the region; the others keep all of theirs. The free
  atoms are the region's atoms: unknowns with their own Tersoff site energies E_a
  (:func:`potentials.tersoff_kernels.tersoff_range` on the free atoms' sites).
* **Weights.** w_c = N_c - g_c (clipped to [0, N_c]; 0 when all its sites are explicit),
  g_c the explicit or empty sites it owns, then all scaled by one factor so that
  sum_c w_c = (atoms of the tube) - (free atoms).
* **Slave particles** (g_c / sites_c >= 1/2) are no unknowns: their displacement is a
  weighted quadratic fit (weights 1 / (1 + d^2), arc terms those of the cylinder so rigid
  motions are exact) of the 10 nearest free atoms of sublattice A (more where 10 cannot
  fix the six terms, else linear), y_s = X_s + sum_a Phi_sa (x_a - X_a).
* **Pad atoms**: tube atoms within ``pad`` (3.5 Å > the 2.1 Å cutoff) of a free atom,
  slaved to the nearest non-slave particle's uniform map (:mod:`.pads`); a carrier that
  has failed (or whose map degenerates) leaves its pads on its last good map.
* The hourglass links of particle c are scaled by w_c / max_c w_c.

This is the coupling of the validated defect tube (``DCBRDefectTube``, old module), written
once and taken from the registered structure (any defects, any number of regions) instead
of a band about one vacancy. The ghost-force dead load is :mod:`.ghost`. A region may
cross a periodic tube's boundary: its atoms see each other through the period, a slave
follows the images of its atoms nearest it.

Ties: on a symmetric lattice a site, a pad atom or a slave's 10th atom can be equally far
(to 1e-14 Å) from two particles or atoms; the nearest is taken by round-off, as the
validated tube does (so the two agree where their coordinates agree bit for bit; a moved
input can flip a tie, which changes the model only off uniform states). A deterministic
rule (lowest index within 1e-9 Å) would be better once the old tube is gone.

Rows of the unknowns: the non-slave particles (``dof_idx``), then the free atoms
(``free_idx``, structure order). Units: Å, eV.
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from potentials import tersoff_kernels as tk
from potentials.neighbours import NeighbourList
from potentials.tersoff import read_tersoff_file
from upscale.models.dcbr.maps import frame_adjoint, frame_of, map_frames
from upscale.models.dcbr.pads import pad_backward, pad_positions

__all__ = ["Coupling", "PAD", "atom_geometry", "carriers", "carried_positions"]

#: width (Å) of the band of pad atoms about the free atoms (> the 2.1 Å cutoff)
PAD = 3.5
#: skin (Å) of the atoms' Verlet list (rebuilt when an atom has moved half of it): 2.4 Å
#: stays short of the wall's second neighbours (2.5 Å)
NL_SKIN = 0.3


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def _cyl(tube, X):
    """(theta (K,), z (K,)) of Cartesian points in the particles' frame."""
    d = X - tube.centre
    return np.arctan2(d @ tube.e2, d @ tube.e1), d @ tube.axis


def _nearest(tube, th, z, cand):
    """Index into ``cand`` of the nearest particle on the unrolled wall (K,)."""
    R0 = tube.cell.R0
    ds = R0 * _wrap(th[:, None] - tube.theta[cand][None, :])
    zc = (tube.x0[cand] - tube.centre) @ tube.axis
    dz = z[:, None] - zc[None, :]
    if tube.periodic:
        dz -= tube.L * np.round(dz / tube.L)
    k = np.argmin(ds ** 2 + dz ** 2, axis=1)
    return k, ds[np.arange(len(k)), k], dz[np.arange(len(k)), k]


def _patch_sublattice(tube, th, z, X, lat_sub, on_site):
    """Sublattice flags (K,) in the particle lattice's convention (A = the patch's A0)."""
    c, R0 = tube.cell, tube.cell.R0
    star = np.column_stack([c.s_p[c.bondsA], c.z_p[c.bondsA]])
    pairs = cKDTree(X).query_pairs(1.2 * tube.bond, output_type="ndarray")
    deg = np.bincount(pairs.ravel(), minlength=len(X))
    for a in np.flatnonzero((deg == 3) & on_site):
        nb = np.concatenate([pairs[pairs[:, 0] == a, 1], pairs[pairs[:, 1] == a, 0]])
        if not on_site[nb].all():
            continue
        v = np.column_stack([R0 * _wrap(th[nb] - th[a]), z[nb] - z[a]])
        plus = max(np.min(np.linalg.norm(star - w, axis=1)) for w in v)
        minus = max(np.min(np.linalg.norm(star + w, axis=1)) for w in v)
        if min(plus, minus) < 0.3:
            return np.where(lat_sub == lat_sub[a], 0, 1) if plus < minus else \
                np.where(lat_sub == lat_sub[a], 1, 0)
    raise RuntimeError("cannot match the atoms' sublattices to the particle lattice")


def _offsets(R0, th_c, z_c, th, z, period):
    """Arc and axial offsets (k,) of points from a particle at (th_c, z_c) to their images
    nearest it, and those images' periods (k,)."""
    dz = z - z_c
    img = np.round(dz / period) if period else np.zeros(len(z))
    return R0 * _wrap(th - th_c), dz - img * (period or 0.0), img


def _slave_fit(R0, th_c, z_c, thA, zA, period, rank=None):
    """Weights (k,), rows (k,) into the A atoms and their periodic images (k,) (periods
    between an atom and the image nearest the slave) of one slave particle's fit; the
    nearest atoms by ``rank`` (k,) if given (the distances that chose them), else by
    their distance."""
    dsf, dzf, img = _offsets(R0, th_c, z_c, thA, zA, period)
    dist = np.hypot(dsf, dzf)
    order = np.argsort(dist if rank is None else rank)
    if len(order) < 10:
        raise ValueError(f"a slave particle has {len(order)} free atoms to follow (10 "
                         "needed); valid: a larger r_atomistic")
    for nn, ncol in ((10, 6), (14, 6), (20, 6), (10, 3)):
        near = order[:nn]
        a_, b_ = dsf[near], dzf[near]
        sa = R0 * np.sin(a_ / R0)
        A = np.column_stack([np.ones(len(near)), sa, b_, 2.0 * R0 * R0 * (1.0 - np.cos(a_ / R0)),
                             sa * b_, b_ * b_])[:, :ncol]
        Aw = A * (1.0 / (1.0 + dist[near] ** 2))[:, None]
        M = A.T @ Aw
        if np.linalg.cond(M) < 1e10:
            return np.linalg.solve(M, Aw.T)[0], near, img[near]
    raise ValueError("a slave particle's nearest free atoms are degenerate for a fit; valid: "
                     "a larger r_atomistic")


def atom_geometry(tube, reg, positions):
    """The tube's atoms: (structure indices (K,), positions (K, 3) Å, theta (K,) rad,
    axial z (K,) Å in the particles' frame, sublattice in the particle lattice's
    convention (K,), on a lattice site (K,) bool)."""
    ids = np.asarray(reg.atoms)
    X = np.asarray(positions, float)[ids]
    th, z = _cyl(tube, X)
    on_site = reg.lattice.site >= 0
    sub = _patch_sublattice(tube, th, z, X, reg.lattice.sublattice, on_site)
    return ids, X, th, z, sub, on_site


def _ref_frames(tube):
    """(par (N, 3), Q3 (N, 3, 3)) of every particle's map at the reference."""
    F0 = tube.gain.deformation(tube.x0, tube.L if tube.periodic else None)
    par, Q3 = np.empty((tube.N, 3)), np.empty((tube.N, 3, 3))
    map_frames(F0, tube.gain.S, tube.gain.alive, par, Q3)
    return par, Q3


def carriers(tube, dof_idx, X, th, z, sub, choose=None):
    """Atoms that follow a particle's uniform map (:mod:`.pads`): carrier c (the nearest of
    ``dof_idx``, or the nearest to the points ``choose`` = (theta, z) if given), reference
    offsets (ds, dz), sublattice flag, residual r0 (so that the map puts each atom on its
    reference position ``X`` (k, 3) at the reference)."""
    k, ds, dz = _nearest(tube, th, z, dof_idx)
    c = np.asarray(dof_idx, np.int64)[k]
    if choose is not None:
        c = np.asarray(dof_idx, np.int64)[_nearest(tube, *choose, dof_idx)[0]]
        zc = (tube.x0[c] - tube.centre) @ tube.axis
        ds, dz, _ = _offsets(tube.cell.R0, tube.theta[c], zc, th, z,
                             tube.L if tube.periodic else None)
    sig = np.asarray(sub, float)
    par, Q3 = _ref_frames(tube)
    x = np.empty((len(c), 3))
    pad_positions(tube.x0, np.zeros((tube.N, 3)), par, Q3, c, ds, dz, sig,
                  np.zeros((len(c), 3)), tube.cell.R0, x)
    dX = X - x
    if tube.periodic:
        dX -= np.outer(np.round((dX @ tube.axis) / tube.L), tube.L * tube.axis)
    return c, ds, dz, sig, np.ascontiguousarray(np.einsum("aij,ai->aj", Q3[c], dX))


def carried_positions(tube, car, yp, delta, L, fs_last=None) -> np.ndarray:
    """Positions (k, 3) of atoms following their carriers' maps (``car``: the tuple of
    :func:`carriers`) at particle positions ``yp`` (N, 3), shifts, period ``L``; a carrier
    that has failed uses ``fs_last`` (N, 3, 2), its last good map."""
    F = tube.gain.deformation(yp, L)
    par, Q3 = np.empty((tube.N, 3)), np.empty((tube.N, 3, 3))
    map_frames(F, tube.gain.S, tube.gain.alive, par, Q3)
    if fs_last is not None:
        for k in np.flatnonzero(~(tube.alive & tube.gain.alive)):
            frame_of(fs_last[k], par[k], Q3[k])
    c, ds, dz, sig, r0 = car
    x = np.empty((len(c), 3))
    pad_positions(np.ascontiguousarray(yp), np.ascontiguousarray(delta), par, Q3, c, ds, dz,
                  sig, r0, tube.cell.R0, x)
    return x


class Coupling:
    """The coupled tube: particles of a :class:`.tube.CoarseTube` and the free atoms of
    the atomistic regions (module docstring).

    Parameters
    ----------
    tube : CoarseTube
        Built with ``n_atoms`` = the lattice's sites; its weights are set here (mutated).
    reg : :class:`.structure.Tube`
        The registered tube (its atoms, lattice map).
    positions : (K, 3) float
        The structure's positions, Å (reference).
    region : (K,) bool
        The structure's atoms to keep atomistic.
    potential : str
        Tersoff file (step cutoff).
    pad : float
        Width of the pad band, Å.
    inside : (N,) bool, optional
        The particles that give their atoms to the region, instead of those ``region``
        gives (the pristine twin of :mod:`.ghost` takes its tube's).
    more_inside : (N,) bool, optional
        Particles given to the region besides (a region grown by :mod:`.switch`).
    reference : (K, 3) float, optional
        The atoms' reference positions, Å, where they differ from ``positions``, which then
        only choose (each site's particle, the free atoms, the pads and their carriers, a
        slave's nearest atoms): the pristine twin of :mod:`.ghost`, its sites at their
        lattice positions, chosen as its tube's atoms choose (the same weights, pads and
        fits, and the same tie breaks on a symmetric lattice).
    """

    def __init__(self, tube, reg, positions, region, potential="BNC.tersoff", pad=PAD,
                 inside=None, more_inside=None, reference=None):
        self.tube = tube
        self.period = tube.L if tube.periodic else None
        ids, X, th, z, sub, on_site = atom_geometry(tube, reg, positions)
        ref = None
        if reference is not None:  # reference geometry; X, th, z only choose
            Xr = np.asarray(reference, float)[ids]
            ref = (Xr, *_cyl(tube, Xr))
        lat = reg.lattice
        # every expected site: occupied ones at their atom, empty ones at the lattice's site
        empty = lat.empty_sites
        uv = lat.site_uv(empty)
        Rl = lat.circumference / (2 * np.pi)
        th_e = _wrap(uv[:, 0] / Rl)
        z_e = uv[:, 1] + np.dot(reg.centre - tube.centre, tube.axis)
        allc = np.arange(tube.N)
        own_a = _nearest(tube, th, z, allc)[0]
        own_e = _nearest(tube, th_e, z_e, allc)[0]
        if inside is None:
            reg_a = np.asarray(region, bool)[ids]
            inside = np.zeros(tube.N, bool)
            inside[own_a[reg_a | ~on_site]] = True
            inside[own_e] = True
        self.inside = np.asarray(inside, bool).copy()
        if more_inside is not None:
            self.inside |= np.asarray(more_inside, bool)
        if self.inside.all():
            raise ValueError(f"the atomistic regions cover all {tube.N} particles of the tube: "
                             "nothing is left to coarse-grain; valid: a longer tube, a smaller "
                             "r_atomistic, or model='atomistic'")
        free = self.inside[own_a]
        tot = np.bincount(own_a[on_site], minlength=tube.N) + np.bincount(own_e, minlength=tube.N)
        gone = (np.bincount(own_a[on_site & free], minlength=tube.N)
                + np.bincount(own_e, minlength=tube.N)).astype(float)
        nominal = float(tube.natoms_n[0])
        w = np.where(gone >= tot, 0.0, np.clip(nominal - gone, 0.0, nominal))
        w *= float(len(ids) - free.sum()) / w.sum()
        tube.natoms_n = w
        self.nominal = float(w.max())
        slave = gone / np.maximum(tot, 1) >= 0.5
        self.dof_idx, self.slave_idx = np.flatnonzero(~slave), np.flatnonzero(slave)
        self.free_local = np.flatnonzero(free)
        self.free_idx = ids[self.free_local]
        self.free_site = lat.site[self.free_local]
        self.free_sub = sub[self.free_local]
        self.nf = len(self.free_idx)
        self.Xf = (X if ref is None else ref[0])[self.free_local]
        self._slaves(th, z, sub, on_site, ref)
        self._pads(X, th, z, sub, free, pad, ids, ref)
        tube.hourglass.scale_n = w / self.nominal
        tube.hourglass.rebuild()
        par = read_tersoff_file(potential, ["C"]).with_step_cutoff(True)
        self._tP, self._te2p, self._tcut = par.table, par.e2p, float(par.cutoff)
        self._nl = NeighbourList(self._tcut, NL_SKIN)
        self.y_ref = np.vstack([tube.x0[self.dof_idx], self.Xf])

    def _slaves(self, th, z, sub, on_site, ref=None):
        """Phi (slaves x free atoms), the offsets, and kphi_s = sum_a Phi_sa k_sa (the
        fitted atoms' images: y_s = X_s + sum_a Phi_sa (x_a - X_a) - kphi_s (L - L0) e_z);
        with ``ref`` (X, theta, z) the fit on the reference geometry, its atoms chosen by
        ``th``, ``z``."""
        t = self.tube
        fA = np.flatnonzero((sub[self.free_local] == 0) & on_site[self.free_local])
        thA, zA = th[self.free_local][fA], z[self.free_local][fA]
        if ref is not None:
            thA, zA, chA = ref[1][self.free_local][fA], ref[2][self.free_local][fA], (thA, zA)
        zc = (t.x0 - t.centre) @ t.axis
        rows, cols, vals, off, kphi = [], [], [], [], []
        for k, c in enumerate(self.slave_idx):
            rank = None if ref is None else \
                np.hypot(*_offsets(t.cell.R0, t.theta[c], zc[c], *chA, self.period)[:2])
            phi, near, img = _slave_fit(t.cell.R0, t.theta[c], zc[c], thA, zA, self.period,
                                        rank)
            rows += [k] * len(near)
            cols += list(fA[near])
            vals += list(phi)
            off.append(t.x0[c] - phi @ self.Xf[fA[near]])
            kphi.append(float(phi @ img))
        self.Phi = csr_matrix((vals, (rows, cols)), shape=(len(self.slave_idx), self.nf))
        self.PhiT = self.Phi.T.tocsr()
        self.slave_off = np.array(off).reshape(-1, 3)
        self.kphi = np.array(kphi)

    def _pads(self, X, th, z, sub, free, pad, ids, ref=None):
        """The pad atoms (chosen by ``X``) and their carriers (on the reference geometry
        ``ref`` = (X, theta, z) if given, chosen by ``th``, ``z``)."""
        t = self.tube
        Xf = X[free]
        if self.period:  # free atoms' images one period either side
            Xf = np.vstack([Xf, Xf + self.period * t.axis, Xf - self.period * t.axis])
        near = cKDTree(Xf).query(X, distance_upper_bound=pad)[0] < pad
        loc = np.flatnonzero(~free & near)
        self.pad_idx = ids[loc]
        geo = (X, th, z) if ref is None else ref
        self.pad_c, self.pad_ds, self.pad_dz, self.pad_sig, self.pad_r0 = carriers(
            t, self.dof_idx, geo[0][loc], geo[1][loc], geo[2][loc], sub[loc],
            None if ref is None else (th[loc], z[loc]))
        F0 = t.gain.deformation(t.x0, t.L if t.periodic else None)
        self.fs_last = np.einsum("nia,nab->nib", F0, t.gain.S)

    def _keep_maps(self, F) -> np.ndarray:
        """(N,) bool: the particles whose map is their own (alive, C_00 > 1e-6, det C >
        1e-9); their FS = F S becomes the last good map (``fs_last``, mutated), which the
        pads of the others keep (no jump when a carrier fails)."""
        t = self.tube
        FS = np.einsum("nia,nab->nib", F, t.gain.S)
        C = np.einsum("nia,nib->nab", FS, FS)
        ok = t.alive & t.gain.alive & (C[:, 0, 0] > 1e-6) & \
            (C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] ** 2 > 1e-9)
        self.fs_last[ok] = FS[ok]
        return ok

    def _frames(self, F):
        t = self.tube
        par, Q3 = np.empty((t.N, 3)), np.empty((t.N, 3, 3))
        map_frames(np.ascontiguousarray(F), t.gain.S, t.gain.alive, par, Q3)
        return par, Q3

    # ------------------------------------------------------------------ evaluation
    def particle_positions(self, y, L=None) -> np.ndarray:
        """All N particle positions from the unknowns y (non-slave particles, free atoms)
        at period ``L`` (a periodic tube's slaves may follow atoms across its boundary)."""
        t = self.tube
        yp = np.empty((t.N, 3))
        nd = len(self.dof_idx)
        yp[self.dof_idx] = y[:nd]
        if len(self.slave_idx):
            yp[self.slave_idx] = self.Phi @ y[nd:] + self.slave_off
            if self.period and L is not None:
                yp[self.slave_idx] -= np.outer(self.kphi * (L - self.period), t.axis)
        return yp

    def atomistic(self, x, L=None):
        """(sum of the free atoms' site energies eV, dE/dx (nf + npad, 3), dE/dL eV/Å at
        fixed x): a periodic tube's atoms see each other across its boundary, and
        dE/dL = -(W_zz - sum_i x_i,z f_i,z) / L (W the kernel's virial: the bonds' image
        terms are what remains of it)."""
        x = np.ascontiguousarray(x, dtype=float)
        if self.period and L is not None:
            cell, pbc = np.diag([1.0, 1.0, float(L)]), (False, False, True)
        else:
            cell, pbc = np.zeros((3, 3)), (False, False, False)
        if self._nl.update(x, cell, pbc):  # each row's partners in index order: the sums
            # do not depend on where the list was built (a resumed run is bit-identical)
            nl = self._nl
            i_b = np.repeat(np.arange(len(x)), np.diff(nl.first_n))
            order = np.lexsort((nl.shift_bc[:, 2], nl.j_b, i_b))
            self._pairs = (nl.first_n, np.ascontiguousarray(nl.j_b[order]),
                           np.ascontiguousarray(nl.shift_bc[order]))
        first, j_b, sh = self._pairs
        f, e_n, W = np.zeros_like(x), np.zeros(len(x)), np.zeros((3, 3))
        E = tk.tersoff_range(0, self.nf, x, cell, first, j_b, sh, np.zeros(len(x), np.int64),
                             self._te2p, self._tP, self._tcut ** 2, f, e_n, W)
        self.e_atoms = e_n[:self.nf]
        dL = -(W[2, 2] - float(x[:, 2] @ f[:, 2])) / L if pbc[2] else 0.0
        return float(E), -f, dL

    def evaluate(self, y, delta, L):
        """(E eV, dE/dy (nd + nf, 3), dE/d delta (N, 3), dE/dL eV/Å, q_n (N, 6)) of the
        coupled tube at unknowns ``y``, shifts ``delta`` and period ``L``."""
        t = self.tube
        y = np.asarray(y, float)
        delta = np.ascontiguousarray(delta, dtype=float)
        nd = len(self.dof_idx)
        yp = self.particle_positions(y, L)
        E, F, P, gd, e_n, q_n = t.lattice_part(yp, delta, L)
        Es, Ps, gyp, dLs = t.hourglass.energy_and_gradient(yp, F, L)
        P += Ps
        par, Q3 = self._frames(F)
        own = self._keep_maps(F)
        for k in np.flatnonzero(~own):  # a failed carrier's pads keep its last good map
            frame_of(self.fs_last[k], par[k], Q3[k])
        x = np.empty((self.nf + len(self.pad_c), 3))
        x[:self.nf] = y[nd:]
        pad_positions(yp, delta, par, Q3, self.pad_c, self.pad_ds, self.pad_dz, self.pad_sig,
                      self.pad_r0, t.cell.R0, x[self.nf:])
        Ea, gx, dLa = self.atomistic(x, L)
        E += Es + Ea - self.nf * t.e0
        gQ3, gpar = np.zeros((t.N, 3, 3)), np.zeros((t.N, 3))
        pad_backward(np.ascontiguousarray(gx[self.nf:]), delta, par, Q3, own, self.pad_c,
                     self.pad_ds, self.pad_dz, self.pad_sig, self.pad_r0, t.cell.R0, gyp, gd,
                     gQ3, gpar)
        frame_adjoint(F, t.gain.S, t.gain.alive, par, Q3, gQ3, gpar, P)
        gyp = gyp - t.gain.forces(P)
        dL = t.gain.cell_derivative(P) + dLs + dLa
        if self.period and len(self.slave_idx):
            dL -= float(gyp[self.slave_idx] @ t.axis @ self.kphi)
        gy = np.empty_like(y)
        gy[:nd] = gyp[self.dof_idx]
        gy[nd:] = gx[:self.nf]
        if len(self.slave_idx):
            gy[nd:] += self.PhiT @ gyp[self.slave_idx]
        self.e_n = e_n
        return E, gy, gd, dL, q_n
