"""Ordinary state-based peridynamics: the linear peridynamic solid (LPS).

Silling, Epton, Weckner, Xu & Askari, J. Elasticity 88 (2007) 151 (3D); the 2D form
follows Le, Silling & Gerstle (2014) with the dilatation of the in-plane trace.
In d dimensions (d = 2, 3), with influence function omega, reference bond length
``L = |xi|``, extension ``e = |y_j - y_i| - L`` and weight ``w = V_j beta_ij``::

    m_i     = sum_j omega L^2 w                       (weighted volume, fixed at prepare)
    theta_i = (d / m_i) sum_{j intact} omega L e w     (dilatation)
    t_ij    = (d k' theta_i / m_i) omega L + (alpha / m_i) omega e^d,  e^d = e - theta_i L / d
    b_i     = sum_j (t_ij + t_ji) w (y_j - y_i)/|y_j - y_i|

3D: k' = K, alpha = 15 G; 2D plane stress k' = E / (2 (1 - nu)), plane strain
k' = E / (2 (1 + nu)(1 - 2 nu)), alpha = 8 G. Collecting terms,
``t_ij + t_ji = A omega L (theta_i/m_i + theta_j/m_j) + alpha omega e (1/m_i + 1/m_j)``
with ``A = d k' - alpha/d`` (3D: 3K - 5G, exactly LAMMPS pair peri/lps).
Strain energy density ``W_i = k' theta_i^2 / 2 + (alpha / (2 m_i)) sum_j omega (e^d)^2 w``.

The influence function is ``omega = 1/|xi|`` ("inverse", LAMMPS) or ``1`` ("constant").
Critical stretch from G_c (Madenci & Oterkus 2014, their eqs. for the OSB model):
3D ``s0 = sqrt(G_c / ((3G + (3/4)^4 (K - 5G/3)) delta))``,
2D ``s0 = sqrt(G_c / ((6G/pi + 16/(9 pi^2) (k' - 2G)) delta))``.
m_i is computed from each particle's real family, which is LPS's own surface correction
for the dilatation. ``surface_correction=True`` additionally scales the deviatoric bond
stiffness by ``(g_i + g_j)/2``, ``g = W_bulk / W_i`` under simple shear (energy method);
near a surface the corrected forces are then not exactly the gradient of an energy.

Force loop: two passes over the half bond list of :mod:`upscale.engine.bondlist` (each
pair once, both ends updated): the dilatation sums, then the forces
(:func:`lps_pair_dilatation_kernel`, :func:`lps_pair_force_kernel`).
"""
from __future__ import annotations

import numba as nb
import numpy as np

from upscale.engine.bondlist import BondList
from upscale.engine.kernels import bond_extension, bond_length, bond_vector
from upscale.models import register
from upscale.models.base import Model, Needs
from upscale.models.base import check_positive as _check_positive

__all__ = ["LPS"]


@nb.njit(parallel=True, cache=True)
def lps_dilatation_kernel(offsets, neighbors, length_b, w_b, omega_b, y_nc, intact_b, dm_n, theta_n):
    """theta_i = (d/m_i) sum omega L e w over intact bonds; ``dm_n = d / m_i``."""
    n = offsets.shape[0] - 1
    for i in nb.prange(n):
        acc = 0.0
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            dr = bond_extension(bond_length(y_nc, i, neighbors[b]), length_b[b])
            acc += omega_b[b] * length_b[b] * dr * w_b[b]
        theta_n[i] = dm_n[i] * acc


@nb.njit(parallel=True, cache=True, error_model="numpy")
def lps_pair_dilatation_kernel(row_n, j_p, k_p, fwd_n, fwd_p, rev_p, L_k, omL_f_k, omL_r_k,
                               chunk_t, vol_n, y_nc, intact_b, buf_tn, zero):
    """Dilatation sums over the half bond list: per pair of class k with extension
    ``e = r - L`` (0 below NEAR_ZERO), ``acc_i += omega L beta_ij V_j e`` if i->j is intact
    and ``acc_j += omega L beta_ji V_i e`` if j->i is intact (``omL_f_k = omega L
    beta_ij``, ``omL_r_k = omega L beta_ji``). Thread t adds into ``buf_tn[t]``; theta is
    ``(d / m) acc``."""
    nt = chunk_t.shape[0] - 1
    has_fwd = fwd_p.shape[0] > 0
    for t in nb.prange(nt):
        buf = buf_tn[t]
        if zero:
            buf[:] = 0.0
        for i in range(chunk_t[t], chunk_t[t + 1]):
            p0 = row_n[i]
            vi = vol_n[i]
            bf0 = np.uint64(fwd_n[i] - p0)
            acc = 0.0
            for p in range(np.uint64(p0), np.uint64(row_n[i + 1])):
                j = j_p[p]
                bi = np.uint64(fwd_p[p]) if has_fwd else bf0 + p
                ii = intact_b[bi]
                ij = intact_b[rev_p[p]]
                if not (ii or ij):
                    continue
                k = k_p[p]
                e = bond_extension(bond_length(y_nc, i, j), L_k[k])
                if ii:
                    acc += omL_f_k[k] * (vol_n[j] * e)
                if ij:
                    buf[j] += omL_r_k[k] * (vi * e)
            buf[i] += acc


@nb.njit(parallel=True, cache=True, error_model="numpy")
def lps_pair_force_kernel(row_n, j_p, k_p, fwd_n, fwd_p, rev_p, L_k, aom_f_k, aom_r_k,
                          dom_f_k, dom_r_k, chunk_t, vol_n, y_nc, intact_b, theta_n, inv_m_n,
                          s0, fail, buf_tnc, zero):
    """LPS force densities over the half bond list. Per pair of class k, with
    ``S = theta_i/m_i + theta_j/m_j``, ``M = 1/m_i + 1/m_j``, extension e and d = y_j - y_i::

        b_i += V_j (aom_f S + dom_f M e) d / r      if i->j is intact
        b_j -= V_i (aom_r S + dom_r M e) d / r      if j->i is intact

    where ``aom = A omega L beta`` and ``dom = alpha omega beta g`` per direction
    (g: the surface-correction factor), i.e. ``(t_ij + t_ji) V_j beta_ij`` along the
    bond. With ``fail`` an intact direction breaks when ``e / L > s0`` (after its force;
    mutates ``intact_b``). Returns the number of directed bonds broken."""
    nt = chunk_t.shape[0] - 1
    has_fwd = fwd_p.shape[0] > 0
    broke = np.zeros(nt, dtype=np.int64)
    for t in nb.prange(nt):
        buf = buf_tnc[t]
        if zero:
            buf[:, :] = 0.0
        nbroke = 0
        for i in range(chunk_t[t], chunk_t[t + 1]):
            p0 = row_n[i]
            ti = theta_n[i] * inv_m_n[i]
            imi = inv_m_n[i]
            vi = vol_n[i]
            bf0 = np.uint64(fwd_n[i] - p0)
            f0 = 0.0
            f1 = 0.0
            f2 = 0.0
            for p in range(np.uint64(p0), np.uint64(row_n[i + 1])):
                j = j_p[p]
                bi = np.uint64(fwd_p[p]) if has_fwd else bf0 + p
                bj = rev_p[p]
                ii = intact_b[bi]
                ij = intact_b[bj]
                if not (ii or ij):
                    continue
                k = k_p[p]
                d0, d1, d2, r = bond_vector(y_nc, i, j)
                L = L_k[k]
                e = bond_extension(r, L)
                S = ti + theta_n[j] * inv_m_n[j]
                Me = (imi + inv_m_n[j]) * e
                inv_r = 1.0 / r
                if ii:
                    gi = (aom_f_k[k] * S + dom_f_k[k] * Me) * (vol_n[j] * inv_r)
                    f0 += gi * d0
                    f1 += gi * d1
                    f2 += gi * d2
                if ij:
                    gj = (aom_r_k[k] * S + dom_r_k[k] * Me) * (vi * inv_r)
                    buf[j, 0] -= gj * d0
                    buf[j, 1] -= gj * d1
                    buf[j, 2] -= gj * d2
                if fail and e / L > s0:
                    if ii:
                        intact_b[bi] = False
                        nbroke += 1
                    if ij:
                        intact_b[bj] = False
                        nbroke += 1
            buf[i, 0] += f0
            buf[i, 1] += f1
            buf[i, 2] += f2
        broke[t] = nbroke
    return broke.sum()


@nb.njit(parallel=True, cache=True)
def lps_energy_kernel(offsets, neighbors, length_b, wd_b, omega_b, y_nc, intact_b, theta_n,
                      inv_m_n, kprime, d):
    n = offsets.shape[0] - 1
    W = np.zeros(n)
    for i in nb.prange(n):
        acc = 0.0
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            r = bond_length(y_nc, i, neighbors[b])
            ed = (r - length_b[b]) - theta_n[i] * length_b[b] / d
            acc += omega_b[b] * ed * ed * wd_b[b]
        W[i] = 0.5 * kprime * theta_n[i] * theta_n[i] + 0.5 * inv_m_n[i] * acc
    return W


class LPS(Model):
    """Linear peridynamic solid (ordinary state-based), 2D and 3D. See module docstring.

    Parameters
    ----------
    E, nu : float
        Young's modulus (Pa) and Poisson ratio; or give ``K`` and ``G`` (3D moduli,
        LAMMPS ``pair_coeff`` values).
    s0 / Gc : float, optional
        Critical stretch or fracture energy (J/m^2); neither: no failure.
    influence : {"inverse", "constant"}
        omega = 1/|xi| (LAMMPS) or 1.
    """

    name = "lps"
    force_kind = "density"

    def __init__(self, E: float | None = None, nu: float | None = None, *, K: float | None = None,
                 G: float | None = None, s0: float | None = None, Gc: float | None = None,
                 influence: str = "inverse", surface_correction: bool = False):
        if (E is None or nu is None) and (K is None or G is None):
            raise ValueError("LPS needs E and nu, or K and G")
        if E is not None and K is not None:
            raise ValueError("give E and nu, or K and G, not both")
        _check_positive(E=E, K=K, G=G, s0=s0, Gc=Gc)
        if nu is not None and not (-1.0 < nu < 0.5):
            raise ValueError(f"Poisson ratio must be in (-1, 0.5), got {nu!r}")
        if influence not in ("inverse", "constant"):
            raise ValueError(f"unknown influence function {influence!r}; valid: 'inverse', 'constant'")
        if s0 is not None and Gc is not None:
            raise ValueError("give the critical stretch s0 or the fracture energy Gc, not both")
        if E is not None:
            K = E / (3.0 * (1.0 - 2.0 * nu))
            G = E / (2.0 * (1.0 + nu))
        else:
            E = 9.0 * K * G / (3.0 * K + G)
            nu = (3.0 * K - 2.0 * G) / (2.0 * (3.0 * K + G))
        self.E, self.nu, self.K, self.G = float(E), float(nu), float(K), float(G)
        self.influence = influence
        self.s0_given, self.Gc = s0, Gc
        self.s0 = s0 if s0 is not None else np.inf
        self.surface_correction = bool(surface_correction)
        self.needs = Needs(pairs=True, failure=(s0 is not None or Gc is not None), energy=True)

    def prepare(self, system, family, **kw) -> None:
        super().prepare(system, family, **kw)
        d = system.dim
        if d not in (2, 3):
            raise ValueError(f"LPS is implemented in 2D and 3D, not dim={d}")
        E, nu, G = self.E, self.nu, self.G
        if d == 3:
            self.kprime, self.alpha = self.K, 15.0 * G
        else:
            self.kprime = E / (2 * (1 - nu)) if system.plane == "stress" else \
                E / (2 * (1 + nu) * (1 - 2 * nu))
            self.alpha = 8.0 * G
        self.dimf = float(d)
        self.A = d * self.kprime - self.alpha / d
        self._gdev_n = None
        L = family.length
        w = self.bond_weights(deviatoric=False)
        m = np.bincount(family.owner, weights=self._omega(L) * L * L * w, minlength=family.n)
        del L, w
        self.m = m
        with np.errstate(divide="ignore"):
            self.inv_m = np.where(m > 0, 1.0 / np.where(m > 0, m, 1.0), 0.0)
        self.dm = self.dimf * self.inv_m
        self._theta = np.zeros(family.n)
        if self.Gc is not None:
            dl = family.horizon
            if d == 3:
                self.s0 = float(np.sqrt(self.Gc / ((3 * G + (0.75 ** 4) * (self.K - 5 * G / 3)) * dl)))
            else:
                self.s0 = float(np.sqrt(self.Gc / ((6 * G / np.pi + 16 / (9 * np.pi ** 2) *
                                                    (self.kprime - 2 * G)) * dl)))
        if self.surface_correction:
            self._gdev_n = self._deviatoric_correction()
        self.bonds = BondList(family, system.volume)
        self._pair_tables()

    # ------------------------------------------------------------------ per-bond quantities
    def _omega(self, L) -> np.ndarray:
        return 1.0 / L if self.influence == "inverse" else np.ones_like(L)

    def deviatoric_factors(self, bonds=None) -> np.ndarray | None:
        """The surface correction's bond factor ``(g_i + g_j)/2`` (nb,), or of the directed
        bonds ``bonds``, from the kept per-particle ``g`` (a new array); None without the
        correction."""
        if self._gdev_n is None:
            return None
        fam = self.family
        if bonds is None:
            return 0.5 * (self._gdev_n[fam.owner] + self._gdev_n[fam.neighbors])
        return 0.5 * (self._gdev_n[fam.owner_of(bonds)] + self._gdev_n[fam.neighbors[bonds]])

    def bond_weights(self, deviatoric: bool = False) -> np.ndarray:
        """``w = V_j beta_ij`` of every directed bond (nb,) (m^3), or with ``deviatoric``
        the deviatoric weight ``alpha w`` (times the surface factor when corrected). New
        arrays: the per-bond quantities are recomputed, not kept."""
        fam = self.family
        w = self.system.volume[fam.neighbors] * fam.volume_factor
        if not deviatoric:
            return w
        wd = self.alpha * w
        g = self.deviatoric_factors()
        return wd if g is None else wd * g

    @property
    def omega_b(self) -> np.ndarray:
        """Influence function of every directed bond (nb,) (a new array)."""
        return self._omega(self.family.length)

    @property
    def w_b(self) -> np.ndarray:
        """:meth:`bond_weights` (a new array)."""
        return self.bond_weights()

    @property
    def wd_b(self) -> np.ndarray:
        """``bond_weights(deviatoric=True)`` (a new array)."""
        return self.bond_weights(deviatoric=True)

    def _pair_tables(self) -> None:
        """Per-class coefficients of the pair kernels (see :func:`lps_pair_force_kernel`)."""
        bl = self.bonds
        if self._gdev_n is not None:
            k_p, L_k, bf_k, br_k, gf_k, gr_k = bl.classes(self.deviatoric_factors)
        else:
            k_p, L_k, bf_k, br_k = bl.classes()
            gf_k = gr_k = 1.0
        om_k = 1.0 / L_k if self.influence == "inverse" else np.ones_like(L_k)
        omL = om_k * L_k
        self._k_p = k_p
        c = np.ascontiguousarray
        self._dil_tables = (c(L_k), c(omL * bf_k), c(omL * br_k))
        self._force_tables = (c(L_k), c(self.A * omL * bf_k), c(self.A * omL * br_k),
                              c(self.alpha * om_k * bf_k * gf_k), c(self.alpha * om_k * br_k * gr_k))

    def _deviatoric_correction(self) -> np.ndarray:
        """Per-particle factors g_i = W_bulk / W_i under simple shear (N,) (the bond factor
        is (g_i + g_j)/2)."""
        sysm, fam = self.system, self.family
        gam = 1e-3
        y = sysm.x0.copy()
        y[:, 0] += gam * sysm.x0[:, 1]
        intact = np.ones(fam.nb, dtype=np.bool_)
        theta = np.zeros(fam.n)
        L, om, w = fam.length, self.omega_b, self.bond_weights()
        lps_dilatation_kernel(fam.offsets, fam.neighbors, L, w, om, y, intact, self.dm, theta)
        W = lps_energy_kernel(fam.offsets, fam.neighbors, L, self.alpha * w, om, y,
                              intact, theta, self.inv_m, self.kprime, self.dimf)
        Wb = 0.5 * self.G * gam * gam
        return np.where(W > 0, Wb / np.where(W > 0, W, 1.0), 1.0)

    # ------------------------------------------------------------------ forces
    def dilatation(self, state) -> np.ndarray:
        """theta (N,) on the current state (a new array)."""
        f = self.family
        theta = np.empty(f.n)
        L = f.length
        lps_dilatation_kernel(f.offsets, f.neighbors, L, self.bond_weights(), self._omega(L), state.y,
                              state.intact, self.dm, theta)
        return theta

    def _force(self, state, out, fail):
        bl = self.bonds
        nt = nb.get_num_threads()
        ch = bl.chunks(nt)
        theta = self._theta
        theta[:] = 0.0
        buf, zero = bl.target(theta, nt)
        lps_pair_dilatation_kernel(bl.row_n, bl.j_p, self._k_p, bl.fwd_n, bl.fwd_p, bl.rev_p,
                                   *self._dil_tables, ch, bl.volume, state.y, state.intact,
                                   buf, zero)
        bl.finish(buf, zero, theta)
        theta *= self.dm
        buf, zero = bl.target(out, nt)
        broke = lps_pair_force_kernel(bl.row_n, bl.j_p, self._k_p, bl.fwd_n, bl.fwd_p, bl.rev_p,
                                      *self._force_tables, ch, bl.volume, state.y, state.intact,
                                      theta, self.inv_m, self.s0, fail, buf, zero)
        bl.finish(buf, zero, out)
        return int(broke)

    def stream_bytes(self) -> int:
        """Bytes of one force evaluation (dilatation pass + force pass; see
        :meth:`~upscale.engine.bondlist.BondList.stream_bytes`)."""
        bl = self.bonds
        # dilatation pass: theta (N,) read and written instead of an (N, 3) output;
        # force pass: theta and 1/m read besides
        return (bl.stream_bytes(self._dil_tables, per_particle_bytes=2 * 8 - 2 * 24)
                + bl.stream_bytes(self._force_tables, per_particle_bytes=2 * 8))

    def add_force(self, state, out):
        self._force(state, out, False)

    def step_force(self, state, out, *, failure=True):
        return self._force(state, out, bool(failure and self.needs.failure))

    def break_bonds(self, state):
        from upscale.engine.kernels import break_by_stretch

        if not self.needs.failure:
            return 0
        f = self.family
        return int(break_by_stretch(f.offsets, f.neighbors, f.length, state.y, state.intact,
                                    np.full(f.n, self.s0)))

    def energy_density(self, state):
        f = self.family
        theta = self.dilatation(state)
        L = f.length
        return lps_energy_kernel(f.offsets, f.neighbors, L, self.wd_b, self._omega(L), state.y,
                                 state.intact, theta, self.inv_m, self.kprime, self.dimf)

    def stiffness_bound(self):
        """Gershgorin row bound of the linearised LPS force density (N/m^4)."""
        f = self.family
        i, j = f.owner, f.neighbors
        L = f.length
        om, w = self._omega(L), self.bond_weights()
        Rdev = 2.0 * np.bincount(i, weights=self.wd_b * om * (self.inv_m[i] + self.inv_m[j]),
                                              minlength=f.n)
        T = self.dm * np.bincount(i, weights=om * L * w, minlength=f.n)  # sum |d theta_i / d y| / 2
        q = 2.0 * T * self.inv_m
        Rdil = abs(self.A) * np.bincount(i, weights=w * om * L * (q[i] + q[j]), minlength=f.n)
        return Rdev + Rdil

    def describe(self):
        return {"model": self.name, "E_Pa": self.E, "nu": self.nu, "K_Pa": self.K, "G_Pa": self.G,
                "influence": self.influence, "s0": None if np.isinf(self.s0) else self.s0,
                **({"Gc_J_per_m2": self.Gc} if self.Gc is not None else {})}


register("lps", LPS)
