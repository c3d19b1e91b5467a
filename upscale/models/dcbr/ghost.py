"""The ghost-force correction of the coupling: a dead load from the pristine twin.

An energy-based coupling is not in balance at its interface: under a uniform strain the
atoms and particles next to it feel forces (ghost forces, up to 1-3 eV/Å here) that the
uniform lattice does not. They are removed as a dead load (Shenoy et al., J. Mech. Phys.
Solids 47, 611 (1999)) taken from the tube's pristine twin: the same particles, the same
region of whole cells, every lattice site occupied (an empty site by its lattice position,
an atom off the lattice by none), evaluated at the uniform relaxed state of the load step:

    E' = E - W,   W = sum_rows [g_r (rho - rho_u) + g_t rho_u (theta - theta_u) + g_z (z - z_u)]
                      + sum_c g_delta,c . (delta_c - delta_u)

with g = dE_twin/dy at the uniform state u (lam_t and the shift relaxed at the step's axial
stretch lam_z = L / L0, gam = 0: :func:`uniform_lattice`), taken in each row's cylindrical
components about the rows' centroid (a Cartesian dead load is not invariant under a rigid
turn about the axis). A pristine twin then stays exactly uniform; a free atom of the tube
that has no twin (an adatom, a Stone-Wales atom off its site) takes no load.
dE'/dL adds the load's work along the uniform path (central difference of x_u).

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
    """(registration view, positions (S, 3)) of the pristine twin: every expected site."""
    lat = reg.lattice
    ids = np.flatnonzero(lat.expected)
    X = np.empty((len(ids), 3))
    pos = {int(s): k for k, s in enumerate(lat.site) if s >= 0}
    uv = lat.site_uv(ids)
    Rl = lat.circumference / (2 * np.pi)
    for k, s in enumerate(ids):
        if int(s) in pos:
            X[k] = positions[reg.atoms[pos[int(s)]]]
        else:
            ph = uv[k, 0] / Rl
            X[k] = reg.centre + reg.radius * (np.cos(ph) * reg.e1 + np.sin(ph) * reg.e2) \
                + uv[k, 1] * reg.axis
    view = types.SimpleNamespace(
        site=ids, sublattice=ids % 2, empty_sites=np.zeros(0, np.int64), site_uv=lat.site_uv,
        circumference=lat.circumference)
    return types.SimpleNamespace(atoms=np.arange(len(ids)), lattice=view, centre=reg.centre), X


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
        twin_reg, X = _twin_registration(reg, positions)
        self.twin_tube = CoarseTube(reg, len(X), **build,
                                    positions=np.asarray(positions)[reg.atoms])
        self.twin_tube.hourglass.k_stab = t.hourglass.k_stab
        self.twin = Coupling(self.twin_tube, twin_reg, X, None, potential, inside=coupling.inside)
        tw = self.twin
        if not (np.array_equal(tw.dof_idx, coupling.dof_idx)
                and np.allclose(tw.tube.natoms_n, t.natoms_n)):
            raise RuntimeError("the pristine twin's particles differ from the tube's")
        where = {int(s): k for k, s in enumerate(tw.free_site)}
        self.rows = np.array([where.get(int(s), -1) if s >= 0 else -1
                              for s in coupling.free_site], np.int64)
        self.coupling = coupling
        self.load = None

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
        keep = np.maximum(self.tube_rows(), 0)
        on = np.r_[np.ones(nd), (self.rows >= 0).astype(float)][:, None]
        yu, g = y[keep], gy[keep] * on
        dL = 0.0
        if L is not None:
            h = 1e-6 * L
            yp, dp = self._state(L + h)
            ym, dm = self._state(L - h)
            dL = float(np.sum(g * (yp[keep] - ym[keep])) + np.sum(gd * (dp - dm))) / (2 * h)
        t = self.twin_tube
        xu = self._plane(yu)
        thu = np.arctan2(xu[:, 1], xu[:, 0])
        cs, sn = np.cos(thu), np.sin(thu)
        gplane = np.column_stack([g @ t.e1, g @ t.e2])
        rhou = np.hypot(xu[:, 0], xu[:, 1])
        gt = -gplane[:, 0] * sn + gplane[:, 1] * cs
        return {"L": None if L is None else float(L), "lam_z": lam_z, "y": yu, "d": d,
                "gd": gd, "dL": dL, "thu": thu, "rhou": rhou,
                "gr": gplane[:, 0] * cs + gplane[:, 1] * sn, "gtr": gt * rhou,
                "gz": g @ t.axis, "g": g}

    def _report(self):
        nd = len(self.coupling.dof_idx)
        g, gd = self.load["g"], self.load["gd"]
        return {"max_particle_force_eV_A": float(np.abs(g[:nd]).max()),
                "max_atom_force_eV_A": float(np.abs(g[nd:]).max(initial=0.0)),
                "max_shift_force_eV_A": float(np.abs(gd).max())}

    def prepare(self, L) -> dict:
        """Set the dead load for period ``L`` (Å) (mutates); returns the largest ghost
        forces on particles, atoms and shifts, eV/Å."""
        self.load = self._load(L)
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
            for k in ("y", "thu", "rhou", "gr", "gtr", "gz", "g"):
                load[k] = np.where(hold.reshape((-1,) + (1,) * (load[k].ndim - 1)),
                                   ref[k], load[k])
            nd = len(self.coupling.dof_idx)
            hp = np.zeros(self.twin_tube.N, bool)
            hp[self.coupling.dof_idx] = hold[:nd]
            for k in ("d", "gd"):
                load[k] = np.where(hp[:, None], ref[k], load[k])
        self.load = load
        return self._report()

    def _plane(self, y):
        """Rows' (e1, e2) components about their centroid (n, 2)."""
        t = self.twin_tube
        p = np.column_stack([y @ t.e1, y @ t.e2])
        return p - p.mean(axis=0)

    def active(self, L) -> bool:
        """True when the load is set for period ``L`` (a finite tube: ``L`` None)."""
        if self.load is None:
            return False
        if L is None or self.load["L"] is None:
            return L is None and self.load["L"] is None
        return abs(self.load["L"] - L) < 1e-12 * L

    def apply(self, y, delta, E, gy, gd):
        """(E - W, dE'/dy, dE'/d delta, the load's dE'/dL) at rows ``y``, shifts ``delta``."""
        a, t = self.load, self.twin_tube
        alive = self.coupling.tube.alive
        nd = len(self.coupling.dof_idx)
        on = np.r_[alive[self.coupling.dof_idx].astype(float), np.ones(len(y) - nd)]
        gr, gtr, gz = a["gr"] * on, a["gtr"] * on, a["gz"] * on
        gdl = a["gd"] * alive[:, None]
        x = self._plane(y)
        rho = np.hypot(x[:, 0], x[:, 1])
        th = np.arctan2(x[:, 1], x[:, 0])
        turn = float(np.angle(np.mean(np.exp(1j * (th - a["thu"])))))
        dth = turn + (th - a["thu"] - turn + np.pi) % (2 * np.pi) - np.pi
        W = float(np.sum(gr * (rho - a["rhou"]) + gtr * dth + gz * (y @ t.axis - a["y"] @ t.axis))
                  + np.sum(gdl * (delta - a["d"])))
        cplane = (gr[:, None] * x + (gtr / rho)[:, None] * np.column_stack([-x[:, 1], x[:, 0]])) \
            / rho[:, None]
        cplane -= cplane.mean(axis=0)
        dW = cplane[:, :1] * t.e1 + cplane[:, 1:] * t.e2 + gz[:, None] * t.axis
        return E - W, gy - dW, gd - gdl, a["dL"]
