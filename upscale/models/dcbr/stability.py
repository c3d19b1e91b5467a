"""The lattice-stability failure rule: is a particle's mapped lattice stable?

The rule that decides the strength of a perfect tube (seed 004 sec. 5.3; the phonon
instability by which a perfect lattice fails under load, cf. E & Ming 2007): the smallest
periodic piece of the ideal (n, m) tube at least twice the potential's cutoff long (no atom
meets its own image twice) is mapped by the cylindrical map of a particle's
q = (lam_t, gam, lam_z, d_rho, d_s, d_z) (gam set to 0: a twist is not periodic; the
shift moves the piece's B atoms against its A atoms, labelled as the cell's); its
Hessian at fixed cell (central differences of the analytic Tersoff gradient, step 1e-4 Å,
only the site energies an atom's move changes) is projected off the four zero modes (three
translations, the turn about the axis). The lattice is unstable when an eigenvalue is below
-``tol`` (1e-3 eV/Å^2, far above the differences' noise of ~1e-8); no parameter is fitted.

:func:`check_stability` applies it to the most loaded particle (largest lattice energy per
atom; with atomistic regions only particles carrying at least half their nominal atoms):
an unstable one fails (loses all its links); with ``all_equal`` every particle in the same
lattice state fails with it (a uniformly loaded tube). This is the rule of the validated
coarse tube (``LatticeStability``, ``DCBRTube.check_stability``, old module), on the
project's one Tersoff (:func:`.kernels.site_energy_grad`).

Units: Å, eV. Suffixes: ``_e`` per extended atom (the piece and its images).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from potentials import tersoff_kernels as tk
from upscale.models.dcbr.cell import TubeCell
from upscale.models.dcbr.kernels import site_energy_grad

__all__ = ["LatticeStability", "check_stability", "piece_hessian"]


@njit(cache=True)
def _sites_grad(x, Lz, owner, img, cand_off, cand_idx, P_f, sites, ext, gext, g):
    """Gradient (n, 3) into ``g`` of the sum of the site energies of ``sites`` of the
    z-periodic piece x (n, 3) with period Lz (image copies ext[e] = x[owner[e]] + img[e] Lz)."""
    for e in range(ext.shape[0]):
        o = owner[e]
        ext[e, 0], ext[e, 1], ext[e, 2] = x[o, 0], x[o, 1], x[o, 2] + img[e] * Lz
        gext[e, 0] = gext[e, 1] = gext[e, 2] = 0.0
    nmax = 0
    for i in range(cand_off.shape[0] - 1):
        nmax = max(nmax, cand_off[i + 1] - cand_off[i])
    near, v, w = np.empty(nmax, np.int64), np.empty((nmax, 3)), np.empty((3, nmax))
    for a in range(sites.shape[0]):
        i = sites[a]
        site_energy_grad(ext, i, cand_idx[cand_off[i]:cand_off[i + 1]], P_f, gext, near, v, w)
    g[:] = 0.0
    for e in range(ext.shape[0]):
        o = owner[e]
        g[o, 0] += gext[e, 0]
        g[o, 1] += gext[e, 1]
        g[o, 2] += gext[e, 2]


@njit(cache=True)
def piece_hessian(x, Lz, owner, img, cand_off, cand_idx, P_f, h, dep_off, dep_idx):
    """Hessian (3n, 3n) eV/Å^2 of the periodic piece by central differences (step h) of
    the analytic gradient, symmetrised; perturbing atom i differences only the site
    energies dep_idx[dep_off[i]:dep_off[i+1]] (i and the sites that list i or an image)."""
    n, ne = x.shape[0], owner.shape[0]
    ext, gext = np.empty((ne, 3)), np.empty((ne, 3))
    gp, gm = np.empty((n, 3)), np.empty((n, 3))
    H = np.empty((3 * n, 3 * n))
    xx = x.copy()
    for i in range(n):
        sites = dep_idx[dep_off[i]:dep_off[i + 1]]
        for c in range(3):
            xx[i, c] = x[i, c] + h
            _sites_grad(xx, Lz, owner, img, cand_off, cand_idx, P_f, sites, ext, gext, gp)
            xx[i, c] = x[i, c] - h
            _sites_grad(xx, Lz, owner, img, cand_off, cand_idx, P_f, sites, ext, gext, gm)
            xx[i, c] = x[i, c]
            for j in range(n):
                for d in range(3):
                    H[3 * i + c, 3 * j + d] = (gp[j, d] - gm[j, d]) / (2 * h)
    for a in range(3 * n):
        for b in range(a + 1, 3 * n):
            s = 0.5 * (H[a, b] + H[b, a])
            H[a, b] = s
            H[b, a] = s
    return H


def _sublattice(x, Lz, bond):
    """0/1 per atom of the periodic piece by 2-colouring its bond graph."""
    d = x[:, None, :] - x[None, :, :]
    d[..., 2] -= Lz * np.round(d[..., 2] / Lz)
    r = np.linalg.norm(d, axis=2)
    nb = (r > 0.1) & (r < 1.1 * bond)
    sub = -np.ones(len(x))
    sub[0], front = 0, [0]
    while front:
        nxt = []
        for a in front:
            for b in np.nonzero(nb[a])[0]:
                if sub[b] < 0:
                    sub[b] = 1 - sub[a]
                    nxt.append(b)
        front = nxt
    return sub


def _oriented(sub, x, Lz, bond, cell):
    """``sub`` relabelled, if need be, so that sublattice 0 is the cell's A (the sublattice
    the shift of q moves B against): the bonds of the piece's first atom of sublattice 0,
    in the unrolled (R0 dtheta, dz) plane, are the cell's A0 bonds, not their negatives (a B
    atom's). The 2-colouring starts from the piece's first atom, whose sublattice depends on
    how ASE orders the (n, m) tube; a swapped labelling maps the piece with the shift
    reversed, off its equilibrium, and its Hessian there can be negative on a stable
    lattice."""
    vA = np.column_stack([cell.s_p[cell.bondsA] - cell.s_p[cell.iA],
                          cell.z_p[cell.bondsA] - cell.z_p[cell.iA]])
    a = int(np.flatnonzero(sub == 0)[0])
    th = np.arctan2(x[:, 1], x[:, 0])
    d = x - x[a]
    d[:, 2] -= Lz * np.round(d[:, 2] / Lz)
    nb = (np.linalg.norm(d, axis=1) > 0.1) & (np.linalg.norm(d, axis=1) < 1.1 * bond)
    R0 = float(np.hypot(x[:, 0], x[:, 1]).mean())
    v = np.column_stack([R0 * ((th[nb] - th[a] + np.pi) % (2 * np.pi) - np.pi), d[nb, 2]])

    def miss(V):
        return float(np.max(np.min(np.linalg.norm(V[:, None] - v[None], axis=2), axis=1)))

    same, swapped = miss(vA), miss(-vA)
    if min(same, swapped) > 0.1 * bond:
        raise RuntimeError(f"the stability piece's bonds match neither sublattice of the "
                           f"({cell.n}, {cell.m}) cell (off by {min(same, swapped):.3f} Å)")
    return sub if same <= swapped else 1.0 - sub


class LatticeStability:
    """Stability of the ideal (n, m) tube lattice mapped uniformly by q (module docstring).

    Parameters
    ----------
    n, m : int
    P_f : (24,) float
        The Tersoff row (:func:`.cell.tersoff_row`).
    bond : float
        a_cc of the reference tube, Å.
    """

    def __init__(self, n, m, P_f, bond=1.42):
        from ase.build import nanotube  # noqa: PLC0415

        from upscale.build import chirality  # noqa: PLC0415

        self.P_f = np.ascontiguousarray(P_f)
        self.cut = float(P_f[tk.IDX_CUT])
        ch = chirality(n, m, bond)
        ncell = max(1, int(math.ceil(2 * self.cut / ch.cell_length)))
        x = nanotube(n, m, length=ncell, bond=bond).get_positions()
        self.Lz = ncell * ch.cell_length
        self.R0 = float(np.hypot(x[:, 0], x[:, 1]).mean())
        self.theta, self.z = np.arctan2(x[:, 1], x[:, 0]), x[:, 2]
        self.sub = _oriented(_sublattice(x, self.Lz, bond), x, self.Lz, bond,
                             TubeCell.build(n, m, bond))
        nat = len(x)
        self.owner = np.concatenate([np.arange(nat)] * 3).astype(np.int64)
        self.img = np.concatenate([np.zeros(nat), -np.ones(nat), np.ones(nat)])
        xe = x[self.owner] + np.outer(self.img, [0.0, 0.0, self.Lz])
        dd = np.linalg.norm(x[:, None, :] - xe[None, :, :], axis=2)
        off, idx = [0], []
        for i in range(nat):
            idx.extend(np.nonzero((dd[i] < 1.6 * self.cut) & (np.arange(len(xe)) != i))[0])
            off.append(len(idx))
        self.cand_off, self.cand_idx = np.array(off, np.int64), np.array(idx, np.int64)
        deps = [{i} for i in range(nat)]  # the sites whose energy depends on atom i
        for j in range(nat):
            for e in self.cand_idx[self.cand_off[j]:self.cand_off[j + 1]]:
                deps[self.owner[e]].add(j)
        self.dep_off = np.cumsum([0] + [len(d) for d in deps]).astype(np.int64)
        self.dep_idx = np.array([j for d in deps for j in sorted(d)], np.int64)
        self._cache: dict = {}

    def positions(self, q) -> np.ndarray:
        """The piece (n, 3) mapped by q (gam ignored), Å."""
        lt, _gm, lz, drho, ds, dz = q
        rho = lt * self.R0 + self.sub * drho
        th = self.theta + self.sub * ds / (lt * self.R0)
        return np.column_stack([rho * np.cos(th), rho * np.sin(th), lz * self.z + self.sub * dz])

    def hessian(self, q, h=1e-4):
        """(H (3n, 3n) eV/Å^2, U (3n, 4) orthonormal zero modes)."""
        x = self.positions(q)
        H = piece_hessian(x, q[2] * self.Lz, self.owner, self.img, self.cand_off,
                          self.cand_idx, self.P_f, h, self.dep_off, self.dep_idx)
        U = np.zeros((3 * len(x), 4))
        for c in range(3):
            U[c::3, c] = 1.0
        U[0::3, 3], U[1::3, 3] = -x[:, 1], x[:, 0]
        return H, np.linalg.qr(U)[0]

    def min_eigenvalue(self, q, h=1e-4) -> float:
        """Smallest eigenvalue (eV/Å^2) of the Hessian projected off the zero modes."""
        H, U = self.hessian(q, h)
        Pj = np.eye(len(H)) - U @ U.T
        w = np.linalg.eigvalsh(Pj @ H @ Pj)
        return float(np.delete(w, np.argsort(np.abs(w))[:4]).min())

    def stable(self, q, tol=1e-3) -> bool:
        """True when H + U U^T + tol I is positive definite (Cholesky)."""
        key = tuple(np.round(np.asarray(q, float), 7))
        if key not in self._cache:
            H, U = self.hessian(np.asarray(q, float))
            try:
                np.linalg.cholesky(H + U @ U.T + tol * np.eye(len(H)))
                self._cache[key] = True
            except np.linalg.LinAlgError:
                self._cache[key] = False
        return self._cache[key]


def check_stability(tube, rule, e_n, q_n, candidates, all_equal=False) -> np.ndarray:
    """(N,) bool: the particles that fail by the lattice-stability rule (module docstring):
    the candidate (alive, ``candidates``) with the largest lattice energy per atom ``e_n``,
    if its lattice q_n is unstable, and with ``all_equal`` every alive particle in its state
    (to 1e-7)."""
    failed = np.zeros(tube.N, bool)
    cand = tube.alive & candidates
    if not cand.any():
        return failed
    c = int(np.argmax(np.where(cand, e_n, -np.inf)))
    if rule.stable(q_n[c]):
        return failed
    failed[c] = True
    if all_equal:
        failed |= np.all(np.abs(q_n - q_n[c]) < 1e-7, axis=1) & tube.alive
    return failed
