"""The surface gain G of each coarse particle of a tube wall, on an engine pair family.

Seed 004 eqs. 5.9 and 6.1-6.5 (the stochastic-projection gain matrix), the algorithm of
:mod:`upscale.models.gain` for a surface: each particle c gets a tangent frame
T_c = [t1 t2] (3x2) from the weighted covariance of its family's reference links beta_b
(normal n = the eigenvector of the smallest eigenvalue, oriented away from the axis;
t2 = the axis projected on the tangent plane, t1 = t2 x n), the links' tangent
coordinates s_b = T_c^T beta_b, weights w_b = kappa(|beta_b|) (quartic,
kappa = (1 - (r/delta)^2)^2, unit particle volumes), and

    s_bar = sum_b w_b s_b / W,   M_c = sum_b w_b (s_b - s_bar)(s_b - s_bar)^T,
    a_b = w_b M_c^-1 (s_b - s_bar),     F_c = sum_b (y_j(b) + k_b L e_z) (x) a_b   (3x2)

(the centred Upsilon of eq. 6.5; :func:`upscale.models.gain.gain_coefficients` with
dim = 2 computes a_b on the flat arrays). sum_b a_b = 0, so F_c is the gain of the
displacements plus the fitted reference chords F0_c. k_b is the periodic image (integer
number of periods L along the axis) of the link's partner. S_c = (F0_c^T F0_c)^-1/2 makes
C_c = S_c F_c^T F_c S_c the identity at the reference.

The family is the engine's (:func:`upscale.engine.build_family`); a periodic tube's is
built on the particles and their images one period either side and folded back onto the
particles (the engine's families have no periodic images of their own).

Units: Å. Suffixes: ``_n`` per particle, ``_b`` per link, ``_c``/``_k`` Cartesian/tangent.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from numba import njit

from upscale.engine import ParticleSystem, build_family
from upscale.models.gain import gain_coefficients

__all__ = ["TubeGain", "tube_links"]


def tube_links(x0_nc, horizon: float, spacing: float, period: float | None):
    """Links within ``horizon`` (strictly, as ``upscale.models.gain``): CSR ``offsets``
    (N+1,), partner ``j_b`` (nb,) and image ``k_b`` (nb,) float (periods along the axis
    e_z), from :func:`upscale.engine.build_family`."""
    n = len(x0_nc)
    if period is None:
        ext = x0_nc
    else:
        shift = np.array([0.0, 0.0, period])
        ext = np.vstack([x0_nc, x0_nc - shift, x0_nc + shift])
    fam = build_family(ParticleSystem(ext, 1.0, spacing=spacing), horizon * (1 - 1e-12))
    offs = fam.offsets[:n + 1].copy()
    jext = np.asarray(fam.neighbors[:offs[-1]], dtype=np.int64)
    k_b = np.choose(jext // n, [0.0, -1.0, 1.0]) if period is not None else np.zeros(len(jext))
    return offs, jext % n, np.ascontiguousarray(k_b, dtype=float)


@njit(cache=True)
def deformation(y_nc, L, offsets, j_b, k_b, a_bk, F_nck):
    """F_c = sum_b (y_j + k_b L e_z) (x) a_b into ``F_nck`` (N, 3, 2) (mutated)."""
    for c in range(offsets.shape[0] - 1):
        for i in range(3):
            F_nck[c, i, 0] = 0.0
            F_nck[c, i, 1] = 0.0
        for b in range(offsets[c], offsets[c + 1]):
            j = j_b[b]
            for i in range(3):
                d = y_nc[j, i] + (k_b[b] * L if i == 2 else 0.0)
                F_nck[c, i, 0] += d * a_bk[b, 0]
                F_nck[c, i, 1] += d * a_bk[b, 1]
    return F_nck


@njit(cache=True)
def forces(P_nck, offsets, j_b, a_bk, f_nc):
    """f_j = -sum_{b: j(b) = j} P_c(b) a_b into ``f_nc`` (N, 3) (mutated): the forces of an
    energy sum_c W_c(F_c), P_c = dW_c/dF_c (eV), serial (rows share partners)."""
    f_nc[:] = 0.0
    for c in range(offsets.shape[0] - 1):
        for b in range(offsets[c], offsets[c + 1]):
            j = j_b[b]
            for i in range(3):
                f_nc[j, i] -= P_nck[c, i, 0] * a_bk[b, 0] + P_nck[c, i, 1] * a_bk[b, 1]
    return f_nc


@njit(cache=True)
def cell_derivative(P_nck, offsets, k_b, a_bk):
    """dW/dL (eV/Å) of an energy sum_c W_c(F_c) with respect to the period L."""
    s = 0.0
    for c in range(offsets.shape[0] - 1):
        for b in range(offsets[c], offsets[c + 1]):
            if k_b[b] != 0.0:
                s += k_b[b] * (P_nck[c, 2, 0] * a_bk[b, 0] + P_nck[c, 2, 1] * a_bk[b, 1])
    return s


def _frames(x0, owner, beta, w, n, axis, centre):
    """Tangent frames T (n, 3, 2) and normals (n, 3) by weighted local PCA of the links."""
    W = np.bincount(owner, w, n)
    mean = np.stack([np.bincount(owner, w * beta[:, k], n) for k in range(3)], 1)
    mean /= np.where(W > 0, W, 1.0)[:, None]
    d = beta - mean[owner]
    cov = np.zeros((n, 3, 3))
    np.add.at(cov, owner, w[:, None, None] * d[:, :, None] * d[:, None, :])
    cov[W <= 0] = np.eye(3)
    nrm = np.linalg.eigh(cov)[1][:, :, 0]
    rad = x0 - centre
    rad -= (rad @ axis)[:, None] * axis
    nrm[np.einsum("ni,ni->n", nrm, rad) < 0] *= -1.0
    t2 = axis - (nrm @ axis)[:, None] * nrm
    flat = np.linalg.norm(t2, axis=1) < 1e-8  # the axis along the normal: any tangent
    if flat.any():
        alt = np.cross(nrm[flat], [1.0, 0.0, 0.0])
        bad = np.linalg.norm(alt, axis=1) < 1e-8
        alt[bad] = np.cross(nrm[flat][bad], [0.0, 1.0, 0.0])
        t2[flat] = alt
    t2 /= np.linalg.norm(t2, axis=1)[:, None]
    return np.stack([np.cross(t2, nrm), t2], axis=2), nrm


@dataclasses.dataclass
class TubeGain:
    """G of every particle of one tube wall (module docstring).

    Attributes
    ----------
    x0 : (N, 3) reference positions, Å; period : float or None, Å.
    offsets, j_b, k_b : the links (:func:`tube_links`); intact_b (nb,) bool.
    a_bk : (nb, 2) coefficients a_b, 1/Å (zero on broken links and dead rows).
    frame_nck : (N, 3, 2) tangent frames; normal_nc (N, 3).
    F0 : (N, 3, 2) reference maps; S : (N, 2, 2) (F0^T F0)^-1/2; alive : (N,) bool.
    """

    x0: np.ndarray
    horizon: float
    period: float | None
    axis: np.ndarray
    centre: np.ndarray
    offsets: np.ndarray
    j_b: np.ndarray
    k_b: np.ndarray
    intact_b: np.ndarray = None
    a_bk: np.ndarray = None
    frame_nck: np.ndarray = None
    normal_nc: np.ndarray = None
    F0: np.ndarray = None
    S: np.ndarray = None
    alive: np.ndarray = None

    @classmethod
    def build(cls, x0, horizon, spacing, period, axis, centre) -> "TubeGain":
        offs, j_b, k_b = tube_links(x0, horizon, spacing, period)
        g = cls(np.ascontiguousarray(x0, dtype=float), float(horizon), period,
                np.asarray(axis, float), np.asarray(centre, float), offs, j_b, k_b)
        g.rebuild(np.ones(len(j_b), dtype=bool))
        return g

    @property
    def n(self) -> int:
        return len(self.x0)

    @property
    def owner_b(self) -> np.ndarray:
        return np.repeat(np.arange(self.n), np.diff(self.offsets))

    def beta(self) -> np.ndarray:
        """Reference links x_j + k L e_z - x_c (nb, 3), Å."""
        L = 0.0 if self.period is None else self.period
        b = self.x0[self.j_b] - self.x0[self.owner_b]
        b[:, 2] += self.k_b * L
        return b

    def rebuild(self, intact_b) -> None:
        """Frames, coefficients, F0 and S on the ``intact_b`` links (mutates self): broken
        links leave G; a particle left with a singular M_c is dead (``alive`` False)."""
        self.intact_b = np.asarray(intact_b, dtype=bool).copy()
        owner, beta = self.owner_b, self.beta()
        q = np.linalg.norm(beta, axis=1) / self.horizon
        w = np.where(q < 1.0, (1.0 - q * q) ** 2, 0.0)
        wi = np.where(self.intact_b, w, 0.0)
        self.frame_nck, self.normal_nc = _frames(self.x0, owner, beta, wi, self.n,
                                                 self.axis, self.centre)
        s = np.zeros((len(beta), 3))
        s[:, :2] = np.einsum("bia,bi->ba", self.frame_nck[owner], beta)
        a = np.zeros((len(beta), 2))
        alive = np.zeros(self.n, dtype=bool)
        gain_coefficients(s, self.offsets, w, self.intact_b & (w > 0), 2, 1e-10, a, alive)
        a[~alive[owner]] = 0.0
        self.a_bk, self.alive = a, alive
        self.F0 = self.deformation(self.x0, self.period)
        self.F0[~alive] = self.frame_nck[~alive]
        A0 = np.einsum("nia,nib->nab", self.F0, self.F0)
        ev, V = np.linalg.eigh(A0)
        self.S = np.ascontiguousarray(np.einsum("nab,nb,ncb->nac", V, ev ** -0.5, V))

    def deformation(self, y, L=None) -> np.ndarray:
        """F (N, 3, 2) at positions ``y`` (N, 3) and period ``L`` (Å)."""
        L = 0.0 if L is None else float(L)
        return deformation(np.ascontiguousarray(y, dtype=float), L, self.offsets, self.j_b,
                           self.k_b, self.a_bk, np.empty((self.n, 3, 2)))

    def forces(self, P_nck) -> np.ndarray:
        """-dW/dy (N, 3) of W = sum_c W_c(F_c) from P_c = dW_c/dF_c (N, 3, 2)."""
        return forces(np.ascontiguousarray(P_nck), self.offsets, self.j_b, self.a_bk,
                      np.empty((self.n, 3)))

    def cell_derivative(self, P_nck) -> float:
        """dW/dL (eV/Å) of W = sum_c W_c(F_c)."""
        return float(cell_derivative(np.ascontiguousarray(P_nck), self.offsets, self.k_b,
                                     self.a_bk))
