"""The ghost-force correction of the coupling: a dead load from the pristine twin.

An energy-based coupling is not in balance at its interface: under a uniform strain the
atoms and particles next to it feel forces (ghost forces, up to 1-3 eV/Å here) that the
uniform lattice does not. They are removed as a dead load (Shenoy et al., J. Mech. Phys.
Solids 47, 611 (1999)) taken from the tube's pristine twin: the same particles, the same
region of whole cells, every lattice site occupied (an empty site by its lattice position,
an atom off the lattice by none), evaluated at the uniform relaxed state of the load step:

    E' = E - W,   W = sum_rows g . (R(phi)^T (y - ybar) - (y_u - ybar_u))
                      + sum_c g_delta,c . (delta_c - delta_u)

with g = dE_twin/dy at the uniform state u (lam_t and the shift relaxed at the step's axial
stretch lam_z = L / L0, gam = 0: :func:`uniform_lattice`), ybar the rows' centroid (over the
rows with a twin) and R(phi) the turn about the axis that best carries the uniform rows onto
the current ones (2D Procrustes: tan phi = sum x_u x x / sum x_u . x, in-plane about the
centroids; phi = 0 on a finite tube, whose grips hold its turn and whose grips' rows may keep
another stretch's load, a torque that a turning load would spread over every row). A rigid
motion (a turn about the axis, a shift) costs nothing, as a Cartesian dead load does not;
the load stays linear in the rows under any other deformation, so a tube that bends as a
column (a defective tube under compression does, as the all-atom one) keeps a bounded load.
(The validated tube took the load's radial and tangential components about the rows'
centroid: equal to first order about u, but singular where a bent tube carries a row to
that centroid.) A pristine twin then stays exactly uniform; a free atom of the tube that
has no twin (an adatom, a Stone-Wales atom off its site) takes no load; the load of a twin's
site the tube has no atom on (a vacancy's) goes to the nearest row the tube has, so that
the load stays balanced (no net force; a net torque only of that distance). dE'/dL adds the load's work along the uniform path (central difference of x_u).

The twin's sites are at their lattice positions (:meth:`.lattice.LatticeMap.site_uv` on the
registered cylinder), not at the input's atoms: a relaxed input (a defective tube's
displacement fields over the whole wall) would leave the twin non-uniform and its load
several times the interface's. Its choices (each site's particle, the pads' carriers, the
slaves' nearest atoms) are made at the input's atoms, as its tube's (``reference`` of
:class:`.coupling.Coupling`), so the two have the same weights, pads and fits.

This is the correction of the validated defect tube (``DCBRDefectTube.prepare_step``, old
module), on any registered tube: a periodic one at its period L (:meth:`GhostLoad.prepare`),
an open one between grips at an axial stretch lam_z with the grips' rows held at the set-up
stretch's load (:meth:`GhostLoad.prepare_stretch`; the old banded dynamic scene's
``prepare_step(L0 (1 + strain))`` with ``_hold_grip_ghost``). Units: eV, Å.
"""
from __future__ import annotations

import types

import numpy as np

from upscale.engine.array_minimisers import bfgs, newton
from upscale.models.dcbr.coupling import Coupling
from upscale.models.dcbr.tube import CoarseTube

__all__ = ["GhostLoad", "uniform_lattice"]


def uniform_lattice(cell, P_f, lam_z: float):
    """(lam_t, shift (3,)) of the particle lattice relaxed at axial stretch ``lam_z``
    (gam = 0; lam_t and the sublattice shift minimise the energy per atom), by Newton's
    method (:func:`upscale.engine.array_minimisers.newton`, gtol 1e-12 eV per atom; BFGS if it
    fails), as the validated tube."""
    def fun(v):
        e, g = cell.energy(np.array([v[0], 0.0, lam_z, v[1], v[2], v[3]]), P_f)
        return e, np.array([g[0], g[3], g[4], g[5]])

    x0 = np.array([1.0, 0.0, 0.0, 0.0])
    r = newton(fun, x0, gtol=1e-12)
    if not r.converged:
        r = bfgs(fun, x0, gtol=1e-12, max_iter=500)
    return float(r.x[0]), r.x[1:].copy()


def _twin_registration(reg, positions):
    """(registration view, the sites' positions that choose (S, 3), their reference
    positions (S, 3)) of the pristine twin: every expected site, chosen at its atom (an
    empty one at its lattice position), its reference its lattice position on the
    registered cylinder (a periodic tube's: the image nearest its atom), Å."""
    lat = reg.lattice
    ids = np.flatnonzero(lat.expected)
    uv = lat.site_uv(ids)
    ph = uv[:, 0] / (lat.circumference / (2 * np.pi))
    Xs = reg.centre + reg.radius * (np.cos(ph)[:, None] * reg.e1 + np.sin(ph)[:, None] * reg.e2) \
        + uv[:, 1:2] * reg.axis
    X = Xs.copy()
    on = lat.site >= 0
    where = np.full(lat.n_sites, -1, np.int64)
    where[ids] = np.arange(len(ids))
    X[where[lat.site[on]]] = np.asarray(positions, float)[np.asarray(reg.atoms)[on]]
    if reg.periodic:  # each site at the image of its atom
        Xs += np.outer(np.round(((X - Xs) @ reg.axis) / reg.length) * reg.length, reg.axis)
    view = types.SimpleNamespace(
        site=ids, sublattice=ids % 2, empty_sites=np.zeros(0, np.int64), site_uv=lat.site_uv,
        circumference=lat.circumference)
    return (types.SimpleNamespace(atoms=np.arange(len(ids)), lattice=view, centre=reg.centre),
            X, Xs)


class GhostLoad:
    """The dead load of a coupled tube (module docstring).

    Parameters
    ----------
    coupling : Coupling
        The tube's coupling (its particles, region and rows).
    reg : :class:`.structure.Tube`
        The registered tube.
    positions : (K, 3) float
        The structure's positions, Å.
    build : dict
        The CoarseTube arguments (coarsening, horizon_factor, potential, hourglass).
    """

    def __init__(self, coupling, reg, positions, build, potential):
        t = coupling.tube
        twin_reg, X, Xs = _twin_registration(reg, positions)
        self.twin_tube = CoarseTube(reg, len(X), **build,
                                    positions=np.asarray(positions)[reg.atoms])
        self.twin_tube.hourglass.k_stab = t.hourglass.k_stab
        self.twin = Coupling(self.twin_tube, twin_reg, X, None, potential, inside=coupling.inside,
                             reference=Xs)
        tw = self.twin
        if not (np.array_equal(tw.dof_idx, coupling.dof_idx)
                and np.allclose(tw.tube.natoms_n, t.natoms_n)):
            raise RuntimeError("the pristine twin's particles differ from the tube's")
        where = {int(s): k for k, s in enumerate(tw.free_site)}
        self.rows = np.array([where.get(int(s), -1) if s >= 0 else -1
                              for s in coupling.free_site], np.int64)
        self.coupling = coupling
        self.load = None
        self._twin = self.tube_rows() >= 0  # (the rows the load's centroid and turn are of)
        self._E12 = np.column_stack([self.twin_tube.e1, self.twin_tube.e2])

    def uniform_state(self, lam_t, lam_z, shift):
        """The twin's unknowns (nd + nf_twin, 3) on the uniform map and its shifts (N, 3)."""
        tw, t = self.twin, self.twin_tube
        R0 = t.cell.R0
        c, e1, e2, ax = t.centre, t.e1, t.e2, t.axis
        d = tw.y_ref - c
        th, z = np.arctan2(d @ e2, d @ e1), d @ ax
        nd = len(tw.dof_idx)
        sub = np.r_[np.zeros(nd), tw.free_sub.astype(float)]
        th = th + sub * shift[1] / (lam_t * R0)
        rho = lam_t * R0 + sub * shift[0]
        y = c + (rho * np.cos(th))[:, None] * e1 + (rho * np.sin(th))[:, None] * e2 \
            + (lam_z * z + sub * shift[2])[:, None] * ax
        return y, np.tile(np.asarray(shift, float), (t.N, 1))

    def tube_rows(self) -> np.ndarray:
        """Index of each of the tube's rows among the twin's (-1: an atom with no twin)."""
        nd = len(self.coupling.dof_idx)
        return np.r_[np.arange(nd), np.where(self.rows >= 0, nd + self.rows, -1)]

    def tube_uniform_state(self, lam_t, lam_z, shift):
        """The tube's rows (nd + nf, 3) and shifts on the uniform map (atoms without a twin:
        NaN)."""
        y, d = self.uniform_state(lam_t, lam_z, shift)
        r = self.tube_rows()
        out = y[np.maximum(r, 0)]
        out[r < 0] = np.nan
        return out, d

    def _state(self, L=None, lam_z=None):
        t = self.twin_tube
        lam_z = L / t.L if lam_z is None else lam_z
        lt, sh = uniform_lattice(t.cell, t.P_f, lam_z)
        return self.uniform_state(lt, lam_z, sh)

    def _load(self, L=None, lam_z=None) -> dict:
        """The dead load (dict of per-row arrays) at period ``L`` or, on a finite tube,
        axial stretch ``lam_z`` (its work along the uniform path, ``dL``, on a periodic tube
        only)."""
        c = self.coupling
        nd = len(c.dof_idx)
        y, d = self._state(L, lam_z)
        _, gy, gd, _, _ = self.twin.evaluate(y, d, L)
        gy = self._lumped(y, gy, L)
        keep = np.maximum(self.tube_rows(), 0)
        on = np.r_[np.ones(nd), (self.rows >= 0).astype(float)][:, None]
        yu, g = y[keep], gy[keep] * on
        dL = 0.0
        if L is not None:
            h = 1e-6 * L
            yp, dp = self._state(L + h)
            ym, dm = self._state(L - h)
            dL = float(np.sum(g * (yp[keep] - ym[keep])) + np.sum(gd * (dp - dm))) / (2 * h)
        return {"L": None if L is None else float(L), "lam_z": lam_z, "y": yu, "d": d,
                "gd": gd, "dL": dL, "g": g}

    def _lumped(self, y, gy, L):
        """The twin's load (rows, 3) with that of each site the tube has no atom on (a
        vacancy's) added to the nearest row the tube has (the image nearest it)."""
        r = self.tube_rows()
        kept = r[r >= 0]
        lack = np.setdiff1d(np.arange(len(gy)), kept)
        out = gy.copy()
        ax = self.twin_tube.axis
        for k in lack:
            dv = y[kept] - y[k]
            if L is not None:
                dv -= np.outer(np.round((dv @ ax) / L) * L, ax)
            out[kept[np.argmin(np.einsum("ij,ij->i", dv, dv))]] += gy[k]
        return out

    def _report(self):
        nd = len(self.coupling.dof_idx)
        g, gd = self.load["g"], self.load["gd"]
        return {"max_particle_force_eV_A": float(np.abs(g[:nd]).max()),
                "max_atom_force_eV_A": float(np.abs(g[nd:]).max(initial=0.0)),
                "max_shift_force_eV_A": float(np.abs(gd).max())}

    def prepare(self, L) -> dict:
        """Set the dead load for period ``L`` (Å) (mutates); returns the largest ghost
        forces on particles, atoms and shifts, eV/Å."""
        self.load = self._derived(self._load(L))
        return self._report()

    def prepare_stretch(self, lam_z: float, hold=None, lam_hold: float | None = None) -> dict:
        """The dead load of a finite (open) tube at axial stretch ``lam_z`` of its twin's
        reference lattice (mutates), the tube's rows ``hold`` (n,) bool keeping the load of
        stretch ``lam_hold`` (a grip's rows, which do not stretch with the gauge; their
        particles' shift loads too): the old ``prepare_step`` at the grips' strain with
        ``_hold_grip_ghost``. The twin is opened as the tube (its ends' surface loads fall
        on the grips' held rows). Returns the largest ghost forces, eV/Å."""
        if self.twin_tube.periodic:
            raise ValueError("prepare_stretch on a periodic tube; valid: prepare(L)")
        load = self._load(None, float(lam_z))
        if hold is not None and np.any(hold):
            hold = np.asarray(hold, bool)
            lh = float(lam_z if lam_hold is None else lam_hold)
            ref = getattr(self, "_held_load", None)
            if ref is None or ref["lam_z"] != lh:  # (the set-up stretch's, kept)
                ref = self._held_load = self._load(None, lh)
            for k in ("y", "g"):
                load[k] = np.where(hold.reshape((-1,) + (1,) * (load[k].ndim - 1)),
                                   ref[k], load[k])
            nd = len(self.coupling.dof_idx)
            hp = np.zeros(self.twin_tube.N, bool)
            hp[self.coupling.dof_idx] = hold[:nd]
            for k in ("d", "gd"):
                load[k] = np.where(hp[:, None], ref[k], load[k])
        self.load = self._derived(load)
        return self._report()

    def _plane(self, y):
        """Rows' (e1, e2) components (n, 2) about the centroid of the rows with a twin, zero
        on the others."""
        p = y @ self._E12
        return (p - p[self._twin].mean(axis=0)) * self._twin[:, None]

    def _derived(self, load) -> dict:
        """``load`` with its in-plane rows x_u (:meth:`_plane`), axial z_u and the load's
        in-plane and axial components (mutated, returned)."""
        load["xu"] = self._plane(load["y"])
        load["zu"] = load["y"] @ self.twin_tube.axis
        load["gp"], load["gz"] = load["g"] @ self._E12, load["g"] @ self.twin_tube.axis
        return load

    def active(self, L) -> bool:
        """True when the load is set for period ``L`` (a finite tube: ``L`` None)."""
        if self.load is None:
            return False
        if L is None or self.load["L"] is None:
            return L is None and self.load["L"] is None
        return abs(self.load["L"] - L) < 1e-12 * L

    def apply(self, y, delta, E, gy, gd):
        """(E - W, dE'/dy, dE'/d delta, the load's dE'/dL) at rows ``y``, shifts ``delta``
        (module docstring: the load turned with the rows by the Procrustes angle phi,
        dW/dy = R g - (its mean over the twin rows) + dW/dphi dphi/dy)."""
        a, t = self.load, self.twin_tube
        alive = self.coupling.tube.alive
        gp, gz, gdl = a["gp"], a["gz"], a["gd"]
        if not alive.all():  # a dead particle's row and shifts take no load
            nd = len(self.coupling.dof_idx)
            on = np.r_[alive[self.coupling.dof_idx].astype(float), np.ones(len(y) - nd)]
            gp, gz, gdl = gp * on[:, None], gz * on, gdl * alive[:, None]
        x, xu = self._plane(y), a["xu"]
        S = float(np.sum(xu[:, 0] * x[:, 1] - xu[:, 1] * x[:, 0]))
        C = float(np.sum(xu * x))
        turns = t.periodic  # (a finite tube's grips hold its turn)
        phi = np.arctan2(S, C) if turns else 0.0
        c, s = np.cos(phi), np.sin(phi)
        Rt = np.array([[c, s], [-s, c]])                        # R(phi)^T
        W = float(np.sum(gp * (x @ Rt.T - xu)) + gz @ (y @ t.axis - a["zu"])
                  + np.sum(gdl * (delta - a["d"])))
        Rg = gp @ Rt                                            # rows R g
        cplane = Rg - self._twin[:, None] * (Rg.sum(axis=0) / self._twin.sum())
        if turns:
            dWdphi = float(np.sum(gp * (np.column_stack([x[:, 1], -x[:, 0]]) @ Rt.T)))
            dphi = (C * np.column_stack([-xu[:, 1], xu[:, 0]]) - S * xu) / (S * S + C * C)
            cplane += dWdphi * dphi
        dW = cplane @ self._E12.T + np.outer(gz, t.axis)
        return E - W, gy - dW, gd - gdl, a["dL"]
