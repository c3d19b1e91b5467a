"""The coarse tube built from a registered tube: particle placement, gain, lattice energy.

Seed 004 sec. 5.3.1, eqs. 5.13-5.16 (discrete Cauchy-Born rule on the stochastic-projection
gain). From one registered tube (:func:`.structure.register`: axis, centre, frame e1/e2,
chirality (n, m), period) and a coarsening K (particle spacing / lattice constant
a = sqrt(3) a_cc):

* particles on the wall of the ideal radius R0 in a regular (theta, z) arrangement,
  n_theta = round(2 pi R0 / (K a)) around (at least 3), n_z = round(L / (K a)) along the
  length L (at least 3), at theta_i = 2 pi (i + 1/2) / n_theta from the registered e1 and
  z_k = z_0 + L (k + 1/2) / n_z (z_0 = 0 of the cell along a periodic tube's axis, the
  lowest atom of a finite one); particle index i n_z + k (theta-major), as the validated
  coarse tube (the old ``upscale.models.dcbr.DCBRTube``) places them;
* a_cc from the registered lattice: of a periodic tube from its period (L = k T exactly,
  T = 3 a_cc sqrt(n^2 + nm + m^2) / d_R), of a finite one the registered mean bond;
* each particle carries N_c = (atoms of the tube) / N atoms and the lattice of
  :class:`.cell.TubeCell`; influence radius ``horizon_factor`` x the larger spacing;
* energy W = sum_c N_c (e(C_c, delta_c) - e0) (:func:`.kernels.coarse_energy`), e0 the
  unstrained lattice's energy per atom (shift zero), plus the hourglass control
  (:mod:`.hourglass`).

Units: Å, eV.
"""
from __future__ import annotations

import math

import numpy as np

from upscale.models.dcbr import kernels as K
from upscale.models.dcbr.cell import TubeCell, tersoff_row
from upscale.models.dcbr.gain import TubeGain
from upscale.models.dcbr.hourglass import Hourglass

__all__ = ["CoarseTube", "registered_bond", "SHIFT_BOUND_FRACTION"]

#: Each shift component is held within this fraction of a_cc (graphene's basin; the lattice
#: energy of BNC.tersoff with the step cutoff has a spurious basin half a bond away).
SHIFT_BOUND_FRACTION = 0.25


#: a_cc from a period is rounded to this many decimals (1e-6 Å): the grid's row counts
#: round L / (K a), which sits exactly on .5 for some tubes ((10,10), 41 cells, K = 2), and
#: the last bits of a_cc must not decide them.
BOND_DIGITS = 6


def registered_bond(tube) -> float:
    """a_cc (Å) of a registered tube, rounded to :data:`BOND_DIGITS`: from the period of a
    periodic one, else from its fitted radius, 2 pi R = sqrt(3) a_cc sqrt(n^2 + nm + m^2)
    (so that the particles sit on the atoms' wall; the mean bond of a finite tube's atoms
    is not that of its rolled lattice)."""
    n, m = tube.chirality
    q = n * n + n * m + m * m
    if not tube.periodic:  # from the fitted radius: the particles' wall is the atoms'
        return round(float(2 * math.pi * tube.radius / (math.sqrt(3.0 * q))), BOND_DIGITS)
    dR = math.gcd(2 * n + m, 2 * m + n)
    T = 3.0 * tube.bond * math.sqrt(q) / dR
    ncell = max(1, int(round(tube.length / T)))
    return round(float(tube.length * dR / (3.0 * math.sqrt(q) * ncell)), BOND_DIGITS)


def refined_axis(X, axis, centre, radius):
    """(axis, centre, radius) of the cylinder through the atoms ``X`` (K, 3) Å by least
    squares on the distances to the axis (soft-L1, so an adatom does not pull it), started
    from the registered ones: the finite tube's axis from the bond-plane normals is off
    by ~1e-4 rad, which leaves the particles ~4e-3 Å off a 120 Å tube's wall."""
    from scipy.optimize import least_squares  # noqa: PLC0415

    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    Xc = X - centre

    def res(p):
        a = axis + p[0] * e1 + p[1] * e2
        a /= np.linalg.norm(a)
        d = Xc - (p[2] * e1 + p[3] * e2)
        return np.linalg.norm(d - np.outer(d @ a, a), axis=1) - p[4]

    r = least_squares(res, [0.0, 0.0, 0.0, 0.0, radius], loss="soft_l1", f_scale=0.05,
                      xtol=1e-15, ftol=1e-15, gtol=1e-15)
    a = axis + r.x[0] * e1 + r.x[1] * e2
    a /= np.linalg.norm(a)
    c = centre + r.x[2] * e1 + r.x[3] * e2
    return a, c - np.dot(c - centre, a) * a, float(r.x[4])


def _grid(n_theta, n_z, R0, L, z0):
    """(theta (N,), reference (x, y, z) in the tube frame (N, 3)), theta-major order."""
    th = 2 * math.pi * (np.arange(n_theta) + 0.5) / n_theta
    zz = z0 + L * (np.arange(n_z) + 0.5) / n_z
    T, Z = np.meshgrid(th, zz, indexing="ij")
    theta = T.ravel()
    return theta, np.column_stack([R0 * np.cos(theta), R0 * np.sin(theta), Z.ravel()])


class CoarseTube:
    """Coarse particles of one registered tube and their energy (module docstring).

    Parameters
    ----------
    tube : :class:`.structure.Tube`
    n_atoms : int
        Atoms the particles stand for.
    coarsening, horizon_factor, potential, hourglass : see :class:`.model.DCBRModel`.
    positions : (K, 3) float, optional
        The tube's atoms, Å (a finite tube's axis is refined on them: :func:`refined_axis`).
    """

    def __init__(self, tube, n_atoms: int, coarsening: float, horizon_factor: float,
                 potential: str, hourglass: float, positions=None):
        n, m = tube.chirality
        self.P_f = tersoff_row(potential)
        self.P_std = tersoff_row(potential, step_cutoff=False)
        self.cutoff = float(self.P_f[10])
        self.periodic = bool(tube.periodic)
        self.L = float(tube.length)
        self.axis, self.e1, self.e2 = tube.axis, tube.e1, tube.e2
        if self.periodic:
            self.centre = tube.centre - np.dot(tube.centre, tube.axis) * tube.axis
            self.bond = registered_bond(tube)
            z0 = 0.0
        else:
            if positions is None:
                raise ValueError("a finite tube needs its atoms' positions (K, 3)")
            X = np.asarray(positions, float)
            self.axis, self.centre, radius = refined_axis(
                X, tube.axis, np.asarray(tube.centre, float), tube.radius)
            self.e1 = tube.e1 - np.dot(tube.e1, self.axis) * self.axis
            self.e1 /= np.linalg.norm(self.e1)
            self.e2 = np.cross(self.axis, self.e1)
            z0 = float(((X - self.centre) @ self.axis).min())
            q = n * n + n * m + m * m
            self.bond = round(2 * math.pi * radius / math.sqrt(3.0 * q), BOND_DIGITS)
        self.cell = TubeCell.build(n, m, self.bond)
        a = math.sqrt(3.0) * self.bond
        R0 = self.cell.R0
        self.n_theta = max(3, int(round(2 * math.pi * R0 / (coarsening * a))))
        self.n_z = int(round(self.L / (coarsening * a)))
        if self.n_z < 3:
            kmax = self.L / (2.5 * a)
            valid = (f"1 <= coarsening <= {kmax:.3g} (at least 3 rows)" if kmax >= 1 else
                     "none: the tube is shorter than 3 rows of one lattice constant")
            raise ValueError(f"coarsening={coarsening:g} leaves {self.n_z} particle rows along "
                             f"the tube's {self.L:.2f} Å; valid: {valid}")
        self.theta, xt = _grid(self.n_theta, self.n_z, R0, self.L, z0)
        R = np.column_stack([self.e1, self.e2, self.axis])  # tube frame -> Cartesian
        self.x0 = np.ascontiguousarray(self.centre + xt @ R.T)
        self.N = len(self.x0)
        self.n_atoms = int(n_atoms)
        self.natoms_n = np.full(self.N, self.n_atoms / self.N)
        ds, dz = 2 * math.pi * R0 / self.n_theta, self.L / self.n_z
        self.spacing = (ds, dz)
        self.horizon = horizon_factor * max(ds, dz)
        self.coarsening = float(coarsening)
        self.shift_bound = SHIFT_BOUND_FRACTION * self.bond
        self.gain = TubeGain.build(self.x0, self.horizon, max(ds, dz),
                                   self.L if self.periodic else None, self.axis, self.centre)
        self.e0 = self.cell.energy(np.array([1.0, 0, 1.0, 0, 0, 0]), self.P_f)[0]
        self.alive = self.gain.alive.copy()
        self.hourglass = Hourglass(self, float(hourglass))
        self.link_bond = self._link_bonds()
        self.n_links0 = np.bincount(self.gain.owner_b, minlength=self.N)

    def _link_bonds(self) -> np.ndarray:
        """The lattice bond each link stands for: best aligned in reference tangent
        coordinates (nb,) (index into ``cell.bondsA``)."""
        c, g = self.cell, self.gain
        bdir = np.column_stack([c.s_p[c.bondsA], c.z_p[c.bondsA]])
        bdir /= np.linalg.norm(bdir, axis=1)[:, None]
        t = np.einsum("bia,bi->ba", g.frame_nck[g.owner_b], g.beta())
        t /= np.maximum(np.linalg.norm(t, axis=1), 1e-12)[:, None]
        return np.argmax(np.abs(t @ bdir.T), axis=1)

    def rebuild(self, intact_b, alive=None) -> None:
        """G on the intact links (mutates); particles failed otherwise stay dead."""
        self.gain.rebuild(intact_b)
        self.alive = self.gain.alive.copy() if alive is None else self.gain.alive & alive
        self.hourglass.rebuild()

    def lattice_part(self, y, delta, L):
        """(W eV, F (N,3,2), P = dW/dF, dW/d delta (N,3), e_n (N,), q_n (N,6)) of the
        particles' lattice energy at positions ``y`` (N,3), shifts ``delta``, period L."""
        F = self.gain.deformation(y, L)
        P = np.empty_like(F)
        gd = np.empty((self.N, 3))
        e_n = np.empty(self.N)
        q_n = np.empty((self.N, 6))
        E = K.coarse_energy(F, self.gain.S, np.ascontiguousarray(delta), self.natoms_n,
                            self.alive, *self.cell.args(), self.P_f, self.e0, P, gd, e_n, q_n)
        return E, F, P, gd, e_n, q_n

    def evaluate(self, y, delta, L):
        """(E eV, dE/dy (N,3) eV/Å, dE/d delta (N,3), dE/dL eV/Å, q_n (N,6), e_n (N,)):
        lattice energy plus hourglass term at (y, delta, L)."""
        y = np.ascontiguousarray(y, dtype=float)
        E, F, P, gd, e_n, q_n = self.lattice_part(y, delta, L)
        Es, Ps, gys, dLs = self.hourglass.energy_and_gradient(y, F, L)
        P += Ps
        gy = gys - self.gain.forces(P)
        dL = self.gain.cell_derivative(P) + dLs
        return E + Es, gy, gd, dL, q_n, e_n

    def relax_shifts(self, y, delta, L, gtol: float, mask=None) -> int:
        """Mutates ``delta`` (N,3) to each particle's relaxed shift at positions ``y``
        (:func:`.kernels.relax_shifts`, per atom gtol / N_c; only the ``mask`` (N,) ones
        if given); returns the number of particles that did not converge. Shifts stay
        within +-``shift_bound``."""
        q_n = self.lattice_part(y, delta, L)[5]
        q_n[:, 3:] = delta
        on = self.alive if mask is None else self.alive & np.asarray(mask, bool)
        bad = K.relax_shifts(q_n, on, *self.cell.args(), self.P_f,
                             gtol / float(self.natoms_n.max()), 50, delta)
        np.clip(delta, -self.shift_bound, self.shift_bound, out=delta)
        return int(bad)
