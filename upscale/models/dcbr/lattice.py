"""The lattice map of one tube: each atom's ideal honeycomb site in the tube's (phi, z) frame.

The wall is unrolled to sheet coordinates ``u = (t, z)``, Å: ``t = R phi`` along the
circumference (right-handed about the axis, so ``(t, z, r)`` is right-handed; the
circumference is ``L_c = 2 pi R``) and ``z`` along the axis. With the graphene basis a1, a2
(60 degrees apart, |a| = sqrt(3) a_cc, a1 -> a2 counter-clockwise in (t, z)) the chiral
vector ``C = n a1 + m a2`` closes the circumference. The map uses the unimodular basis
``c1 = C / g`` (g = gcd(n, m)) and ``c2 = (u, v)`` with ``n' v - m' u = 1`` (extended
Euclid, n' = n/g, m' = m/g), so a lattice point is ``i c1 + j c2`` with i = 0..g-1 around the
tube (mod g) and one value of j per row of sites along the axis:

    u(i, j, s) = c + B [i + s delta_i, j + s delta_j]^T,     B = [[L_c/g, b_t], [0, b_z]]

with s = 0, 1 the sublattice (the second site ``delta = (a1 + a2) / 3`` further, in
(i, j) coordinates ``delta = (v - u, n' - m') / 3``). The first column of B is fixed by the
closed circumference; ``b = (b_t, b_z)`` (row shear and spacing: twist and axial stretch)
and the shift ``c`` (rotation about and shift along the axis) are fitted by least squares
on the atoms' offsets from their nearest sites. The fit starts from the ideal rolled-up
sheet (``b_t = (L_c/g) (c1.c2)/|c1|^2``, ``b_z = (sqrt(3)/2) a^2 / |c1|``) on atoms within
a few Å of a seed atom and doubles the window until it spans the tube, so an error in
``b`` never accumulates over a long tube. A periodic tube of period L then has exactly
``J = round(L / b_z)`` rows per period and ``b`` is snapped to ``b_z = L/J``,
``b_t = K L_c / (g J)`` (K the integer nearest ``b_t J g / L_c``), the period lattice
vector being ``(i, j) -> (i - K, j + J)``.

An atom's distance to its site is ``d = sqrt(|u - u_site|^2 + (r - R)^2)`` Å (the radial
part catches atoms above the wall); sites are claimed by their nearest atom within
:data:`OFF_SITE` Å.
"""
from __future__ import annotations

import dataclasses
import math

import numba as nb
import numpy as np

__all__ = ["OFF_SITE", "LatticeMap", "fit_lattice"]

#: An atom further than this from every free site is off the lattice, Å (half a bond).
OFF_SITE = 0.7
#: Atoms within this of their site take part in the fit, Å.
_FIT_INLIER = 0.45
#: Half-width of the first fitting window along the axis, Å (about two rows of hexagons).
_FIRST_WINDOW = 6.0


def _ext_gcd(a, b):
    """(g, x, y) with a x + b y = g = gcd(a, b)."""
    if b == 0:
        return a, 1, 0
    g, x, y = _ext_gcd(b, a % b)
    return g, y, x - (a // b) * y


@dataclasses.dataclass
class LatticeMap:
    """Honeycomb sites of one tube and each atom's site.

    Attributes
    ----------
    n, m : int
        Chiral indices with a1 -> a2 counter-clockwise in (t, z).
    circumference : float
        L_c = 2 pi R, Å.
    B : (2, 2) float
        Sheet coordinates (Å) per unit of (i, j) (see the module docstring).
    c : (2,) float
        Shift of site (0, 0, s=0), Å.
    delta : (2,) float
        Second sublattice offset in (i, j).
    g, rows : int
        Sites around the tube per sublattice; rows of sites (per period if periodic).
    row0 : int
        j of the first row.
    period_i : int or None
        K of the period vector (i, j) -> (i - K, j + J) of a periodic tube, else None.
    site : (K,) int
        Site id of each atom (``(row * g + i) * 2 + s``), -1 if off the lattice.
    nearest : (K,) int
        Id of the nearest site (claimed or not).
    distance : (K,) float
        Distance to the nearest site, Å.
    expected : (S,) bool
        Sites inside the tube (all of a periodic tube; within the atoms' axial extent of a
        finite one).
    """

    n: int
    m: int
    radius: float
    circumference: float
    B: np.ndarray
    c: np.ndarray
    delta: np.ndarray
    g: int
    rows: int
    row0: int
    period_i: int | None
    site: np.ndarray
    nearest: np.ndarray
    distance: np.ndarray
    expected: np.ndarray

    @property
    def n_sites(self) -> int:
        return 2 * self.g * self.rows

    @property
    def empty_sites(self) -> np.ndarray:
        """Expected sites no atom occupies (ids)."""
        taken = np.zeros(self.n_sites, dtype=bool)
        taken[self.site[self.site >= 0]] = True
        return np.flatnonzero(self.expected & ~taken)

    @property
    def sublattice(self) -> np.ndarray:
        """0 or 1 per atom (of the nearest site)."""
        return self.nearest % 2

    def indices(self, ids) -> np.ndarray:
        """Lattice indices (i, j, s) of sites: the point i c1 + j c2 (i = 0..g-1 round the
        tube, j the row), sublattice s; (S, 3) int."""
        ids = np.asarray(ids, dtype=np.int64)
        return np.stack([(ids // 2) % self.g, (ids // 2) // self.g + self.row0, ids % 2], 1)

    def quality(self) -> dict:
        """Fraction of atoms on a site and their RMS distance to it, Å."""
        on = self.site >= 0
        rms = float(np.sqrt(np.mean(self.distance[on] ** 2))) if on.any() else float("nan")
        return {"on_site_fraction": float(on.mean()), "rms_A": rms}

    def site_uv(self, ids) -> np.ndarray:
        """Sheet coordinates (t in [0, L_c), z) of sites, (S, 2) Å."""
        ids = np.asarray(ids, dtype=np.int64)
        s = ids % 2
        i = (ids // 2) % self.g
        j = (ids // 2) // self.g + self.row0
        y = np.stack([i + s * self.delta[0], j + s * self.delta[1]], axis=1)
        u = self.c + y @ self.B.T
        u[:, 0] = np.mod(u[:, 0], self.circumference)
        return u


def _basis(n, m, bond, circumference):
    """Unimodular (c1, c2), delta in (i, j), and the ideal B for this circumference."""
    g = math.gcd(n, m)
    n1, m1 = n // g, m // g
    gg, x, y = _ext_gcd(n1, m1)  # n1 x + m1 y = 1  ->  c2 = (u, v) = (-y, x)
    u, v = -y, x
    a2 = 3.0 * bond * bond
    G = a2 * np.array([[1.0, 0.5], [0.5, 1.0]])
    c1, c2 = np.array([n1, m1], float), np.array([u, v], float)
    len1 = math.sqrt(c1 @ G @ c1)
    bt = (circumference / g) * (c1 @ G @ c2) / len1 ** 2
    bz = (math.sqrt(3.0) / 2.0) * a2 / len1
    B = np.array([[circumference / g, bt], [0.0, bz]])
    delta = np.array([v - u, n1 - m1], float) / 3.0
    return g, B, delta


@nb.njit(cache=True)
def _nearest_kernel(uv, dr, Binv, B, c, delta, Lc, best, dist):
    for k in range(len(uv)):
        x0 = uv[k, 0] - c[0]
        x1 = uv[k, 1] - c[1]
        y0 = Binv[0, 0] * x0 + Binv[0, 1] * x1
        y1 = Binv[1, 0] * x0 + Binv[1, 1] * x1
        bd = np.inf
        for s in range(2):
            ys0 = y0 - s * delta[0]
            ys1 = y1 - s * delta[1]
            f0 = np.floor(ys0)
            f1 = np.floor(ys1)
            for di in range(2):
                for dj in range(2):
                    e0 = ys0 - f0 - di
                    e1 = ys1 - f1 - dj
                    du0 = B[0, 0] * e0 + B[0, 1] * e1
                    du1 = B[1, 0] * e0 + B[1, 1] * e1
                    du0 -= Lc * np.round(du0 / Lc)
                    d2 = du0 * du0 + du1 * du1
                    if d2 < bd:
                        bd = d2
                        best[k, 0] = int(f0) + di
                        best[k, 1] = int(f1) + dj
                        best[k, 2] = s
        dist[k] = np.sqrt(bd + dr[k] * dr[k])


def _nearest(uv, dr, B, c, delta, Lc):
    """Nearest site (i, j, s) of each point and the distance, Å (8 candidates each: the
    corners of the lattice cell holding the point, on both sublattices)."""
    best = np.zeros((len(uv), 3), dtype=np.int64)
    dist = np.empty(len(uv))
    _nearest_kernel(np.ascontiguousarray(uv, dtype=np.float64), np.asarray(dr, np.float64),
                    np.linalg.inv(B), B, np.asarray(c, np.float64), delta, float(Lc), best, dist)
    return best, dist


def _refit(uv, dr, B, c, delta, Lc, sel, fit_b):
    """One least-squares update of ``c`` (and ``b`` if ``fit_b``) on the atoms ``sel``."""
    ijs, d = _nearest(uv[sel], dr[sel], B, c, delta, Lc)
    ok = d < _FIT_INLIER
    if ok.sum() < (3 if fit_b else 1):
        return B, c, 0.0
    yi = ijs[ok, 0] + ijs[ok, 2] * delta[0]
    yj = ijs[ok, 1] + ijs[ok, 2] * delta[1]
    pred = c + np.stack([yi, yj], axis=1) @ B.T
    res = uv[sel][ok] - pred
    res[:, 0] -= Lc * np.round(res[:, 0] / Lc)
    B, c = B.copy(), c.copy()
    if fit_b:
        jc = yj - yj.mean()
        A = np.stack([np.ones_like(jc), jc], axis=1)
        sol, *_ = np.linalg.lstsq(A, res, rcond=None)  # (2 params, 2 components)
        B[:, 1] += sol[1]
        c += sol[0] - sol[1] * yj.mean()
    else:
        c += res.mean(axis=0)
    return B, c, float(ok.mean())


def _fit(uv, dr, B, c, delta, Lc, seed_z):
    """Grow the window from the seed until it spans the tube, refitting (b, c)."""
    dz = np.abs(uv[:, 1] - seed_z)
    w = _FIRST_WINDOW
    while True:
        sel = dz < w
        B, c, frac = _refit(uv, dr, B, c, delta, Lc, sel, fit_b=True)
        if sel.all():
            return _refit(uv, dr, B, c, delta, Lc, sel, fit_b=True)
        w *= 2.0


def _snap_periodic(B, c, uv, dr, delta, Lc, g, period):
    """Exact b of a periodic tube (integer rows J per period, twist K)."""
    J = int(round(period / B[1, 1]))
    K = int(round(B[0, 1] * J * g / Lc))
    B = B.copy()
    B[1, 1] = period / J
    B[0, 1] = K * Lc / (g * J)
    for _ in range(2):
        B, c, _ = _refit(uv, dr, B, c, delta, Lc, np.ones(len(uv), bool), fit_b=False)
    return B, c, J, K


def _claim(ids, d):
    """Site per atom: the nearest atom within OFF_SITE claims a site, others get -1."""
    site = np.where(d <= OFF_SITE, ids, -1)
    order = np.lexsort((d, ids))
    first = np.ones(len(ids), dtype=bool)
    first[1:] = ids[order][1:] != ids[order][:-1]
    loser = order[~first]
    site[loser] = -1
    return site


def fit_lattice(n, m, bond, radius, t, z, r, period=None, seed=0) -> LatticeMap:
    """Register the honeycomb of an (n, m) tube on its atoms.

    Parameters
    ----------
    n, m : int
        Chirality with a1 -> a2 counter-clockwise in (t, z).
    bond : float
        a_cc, Å (only the starting guess of the row spacing).
    radius : float
        R, Å.
    t, z, r : (K,) float
        Atoms' arc coordinate R phi in [0, 2 pi R), axial coordinate (continuous along the
        tube) and radial distance, Å.
    period : float or None
        Period of a periodic tube along the axis, Å.
    seed : int
        Atom (index into t) the first window is centred on and whose site starts the fit.

    Returns
    -------
    LatticeMap
    """
    Lc = 2.0 * math.pi * radius
    g, B, delta = _basis(n, m, bond, Lc)
    uv = np.stack([t, z], axis=1)
    dr = r - radius
    first = np.abs(z - z[seed]) < _FIRST_WINDOW
    trials = []
    for s in (0, 1):  # the seed atom on either sublattice: keep the better start
        c = uv[seed] - s * (B @ delta)
        trials.append(_refit(uv, dr, B, c, delta, Lc, first, fit_b=True))
    B, c, _ = max(trials, key=lambda x: x[2])
    B, c, _ = _fit(uv, dr, B, c, delta, Lc, z[seed])
    K = None
    if period is not None:
        B, c, rows, K = _snap_periodic(B, c, uv, dr, delta, Lc, g, period)
    ijs, d = _nearest(uv, dr, B, c, delta, Lc)
    i, j = ijs[:, 0], ijs[:, 1]
    if period is not None:
        w = np.floor_divide(j, rows)
        j, i, row0 = j - w * rows, i + w * K, 0
    else:
        row0 = int(j.min())
        rows = int(j.max()) - row0 + 1
        j = j - row0
    ids = (j * g + np.mod(i, g)) * 2 + ijs[:, 2]
    lm = LatticeMap(n, m, radius, Lc, B, c, delta, g, rows, row0, K, _claim(ids, d), ids, d,
                    np.ones(2 * g * rows, dtype=bool))
    if period is None:
        zs = lm.site_uv(np.arange(lm.n_sites))[:, 1]
        lm.expected = (zs >= z.min() - 0.25) & (zs <= z.max() + 0.25)
    return lm
