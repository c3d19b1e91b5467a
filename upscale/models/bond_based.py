"""Bond-based peridynamics: the prototype microelastic brittle (PMB) model.

Silling, J. Mech. Phys. Solids 48 (2000) 175; Silling & Askari, Comput. Struct. 83 (2005)
1526. Pairwise force density on particle i (N/m^3)::

    b_i = sum_j c s_ij V_j beta_ij (y_j - y_i)/|y_j - y_i|,   s = (|y_j - y_i| - |xi|)/|xi|

with the micromodulus c calibrated by matching the strain energy density of an isotropic
stretch in the bulk (beta = 1, constant influence function):

==========================  ======================================  =====================
dimension                   c                                       implied Poisson ratio
==========================  ======================================  =====================
3D                          18 K / (pi delta^4),  K = E/(3(1-2nu))  1/4
2D plane stress (thick. t)  6 E / ((1-nu) pi t delta^3)             1/3
2D plane strain             6 E / ((1+nu)(1-2nu) pi t delta^3)      1/4
1D (area A)                 2 E / (A delta^2)                       -
==========================  ======================================  =====================

(for the implied nu these are the classical 12E/(pi delta^4), 9E/(pi t delta^3) and
48E/(5 pi t delta^3)). Another ``nu`` keeps the dilatational modulus and is recorded as
such: bond-based PD cannot represent it.

Critical stretch from the fracture energy G_c (energy to break every bond crossing a unit
area): 3D ``G_c = pi c s0^2 delta^5 / 10``; 2D ``G_c = c s0^2 t delta^4 / 4``;
1D ``G_c = c s0^2 A delta^3 / 6`` (Silling & Askari 2005; Ha & Bobaru 2010).
A bond breaks when s > s0; it breaks after its force of that evaluation is counted
(the LAMMPS order).

``calibration="lattice"`` rescales c by the ratio of the continuum integral of |xi| over
the horizon to its discrete sum at a bulk particle (the quadrature error of the family,
several per cent for delta = 3h), so the bulk energy of an isotropic stretch is exact.

Surface correction (``surface_correction=True``): per-particle factors
``g_i = W_bulk / W_i`` from an isotropic stretch, bond factor ``(g_i + g_j)/2``
(the energy method of Madenci & Oterkus 2014, isotropic test).

Force loop: each pair once, over the half bond list of :mod:`upscale.engine.bondlist`
(int32 partners, a one-byte reference-geometry class per pair, the coefficients per
class), both ends updated from one evaluation (:func:`pmb_pair_kernel`).

LAMMPS conventions: ``PMB(c=..., s0=...)`` on a family built with
``partial_volume="lammps"`` is pair_style peri/pmb with ``alpha = 0``;
:class:`LammpsContact` is its short-range repulsive contact force.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from upscale.engine.bondlist import BondList
from upscale.engine.kernels import bond_length, bond_vector
from upscale.models import register
from upscale.models.base import Model, Needs, check_positive

__all__ = ["PMB", "LammpsContact", "pmb_micromodulus", "pmb_critical_stretch"]



# ---------------------------------------------------------------------------- kernels
@nb.njit(parallel=True, cache=True, error_model="numpy")
def pmb_pair_kernel(row_n, j_p, k_p, fwd_n, fwd_p, rev_p, invL_k, cf_k, cr_k, rc2_k, chunk_t,
                    vol_n, y_nc, intact_b, fail, buf_tnc, zero):
    """PMB force densities over the half bond list (:mod:`upscale.engine.bondlist`).

    Per pair (i, j > i) of class k, with d = y_j - y_i and r = |d|::

        g = 1/L_k - 1/r                      (= s / r, s the stretch)
        b_i += g c beta_ij V_j d             if i->j is intact
        b_j -= g c beta_ji V_i d             if j->i is intact

    ``invL_k = 1/L``, ``cf_k = c beta_ij (g_ij)``, ``cr_k = c beta_ji (g_ji)`` per class
    (g: the optional surface-correction factor), ``rc2_k = (L (1 + s0))^2``. With
    ``fail`` a direction that is intact breaks when ``r^2 > rc2`` (after its force is
    counted: LAMMPS's order); mutates ``intact_b``. Thread t adds into ``buf_tnc[t]``
    (zeroed first if ``zero``) over the particles ``chunk_t[t]:chunk_t[t+1]``. One sqrt
    and one division per pair. Returns the number of directed bonds broken."""
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
            yi0 = y_nc[i, 0]
            yi1 = y_nc[i, 1]
            yi2 = y_nc[i, 2]
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
                d0 = y_nc[j, 0] - yi0
                d1 = y_nc[j, 1] - yi1
                d2 = y_nc[j, 2] - yi2
                rsq = d0 * d0 + d1 * d1 + d2 * d2
                k = k_p[p]
                g = invL_k[k] - 1.0 / np.sqrt(rsq)
                if ii:
                    gi = g * (cf_k[k] * vol_n[j])
                    f0 += gi * d0
                    f1 += gi * d1
                    f2 += gi * d2
                if ij:
                    gj = g * (cr_k[k] * vi)
                    buf[j, 0] -= gj * d0
                    buf[j, 1] -= gj * d1
                    buf[j, 2] -= gj * d2
                if fail and rsq > rc2_k[k]:
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
def pmb_energy_kernel(offsets, neighbors, length_b, w_b, y_nc, intact_b, c):
    """W_i = 1/4 sum_j c s^2 |xi| w_b (J/m^3), half of each bond's energy to each end."""
    n = offsets.shape[0] - 1
    W = np.zeros(n)
    for i in nb.prange(n):
        acc = 0.0
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            r = bond_length(y_nc, i, neighbors[b])
            s = (r - length_b[b]) / length_b[b]
            acc += s * s * length_b[b] * w_b[b]
        W[i] = 0.25 * c * acc
    return W


@nb.njit(parallel=True, cache=True, error_model="numpy")
def contact_pair_kernel(row_n, j_p, k_p, dc_k, chunk_t, vol_n, y_nc, k15_over_delta, buf_tnc, zero):
    """LAMMPS peri short-range contact over the half bond list: for a pair closer than
    ``dc_k = min(0.9 |xi|, 1.35 lc)`` (per class) adds ``k (r - d) V_j / r (y_j - y_i)``
    to i and the opposite with ``V_i`` to j (repulsive: r < d), intact or not. Thread t
    adds into ``buf_tnc[t]``. Returns the number of active directed contacts."""
    nt = chunk_t.shape[0] - 1
    active = np.zeros(nt, dtype=np.int64)
    for t in nb.prange(nt):
        buf = buf_tnc[t]
        if zero:
            buf[:, :] = 0.0
        a = 0
        for i in range(chunk_t[t], chunk_t[t + 1]):
            vi = vol_n[i]
            f0 = 0.0
            f1 = 0.0
            f2 = 0.0
            for p in range(np.uint64(row_n[i]), np.uint64(row_n[i + 1])):
                j = j_p[p]
                d0, d1, d2, r = bond_vector(y_nc, i, j)
                dij = dc_k[k_p[p]]
                if r < dij:
                    fp = k15_over_delta * (r - dij) / r if r > 0.0 else 0.0
                    gi = fp * vol_n[j]
                    gj = fp * vi
                    f0 += gi * d0
                    f1 += gi * d1
                    f2 += gi * d2
                    buf[j, 0] -= gj * d0
                    buf[j, 1] -= gj * d1
                    buf[j, 2] -= gj * d2
                    a += 2
            buf[i, 0] += f0
            buf[i, 1] += f1
            buf[i, 2] += f2
        active[t] = a
    return active.sum()


# ---------------------------------------------------------------------------- calibration
def pmb_micromodulus(E: float, nu: float | None, horizon: float, dim: int, *,
                     thickness: float | None = None, plane: str = "stress",
                     area: float = 1.0) -> float:
    """Micromodulus c (N/m^6) matching the bulk energy of an isotropic stretch."""
    d = float(horizon)
    if dim == 3:
        nu = 0.25 if nu is None else nu
        K = E / (3.0 * (1.0 - 2.0 * nu))
        return 18.0 * K / (np.pi * d ** 4)
    if dim == 2:
        t = 1.0 if thickness is None else float(thickness)
        if plane == "stress":
            nu = 1.0 / 3.0 if nu is None else nu
            return 6.0 * E / ((1.0 - nu) * np.pi * t * d ** 3)
        nu = 0.25 if nu is None else nu
        return 6.0 * E / ((1.0 + nu) * (1.0 - 2.0 * nu) * np.pi * t * d ** 3)
    if dim == 1:
        return 2.0 * E / (area * d ** 2)
    raise ValueError(f"dim must be 1, 2 or 3, got {dim!r}")


def pmb_critical_stretch(Gc: float, c: float, horizon: float, dim: int, *,
                         thickness: float | None = None, area: float = 1.0) -> float:
    """Critical stretch s0 such that breaking all bonds across a unit area costs G_c."""
    d = float(horizon)
    if dim == 3:
        return float(np.sqrt(10.0 * Gc / (np.pi * c * d ** 5)))
    if dim == 2:
        t = 1.0 if thickness is None else float(thickness)
        return float(np.sqrt(4.0 * Gc / (c * t * d ** 4)))
    return float(np.sqrt(6.0 * Gc / (c * area * d ** 3)))


def _natural_nu(dim, plane):
    return {3: 0.25, 1: None}.get(dim, 1.0 / 3.0 if plane == "stress" else 0.25)


_check_positive = check_positive


class PMB(Model):
    """Prototype microelastic brittle bond-based model (see module docstring).

    Parameters
    ----------
    E : float, optional
        Young's modulus (Pa). Either ``E`` or ``c``.
    nu : float, optional
        Poisson ratio; default the value bond-based PD implies (1/4 in 3D and plane
        strain, 1/3 in plane stress). Another value keeps the dilatational modulus.
    c : float, optional
        Micromodulus (N/m^6) given directly (LAMMPS ``pair_coeff`` c).
    s0 : float, optional
        Critical stretch. Or give ``Gc`` (J/m^2). Neither: no failure (the engine then
        never checks bonds).
    surface_correction : bool
        Energy-method surface correction (isotropic stretch test).
    """

    name = "pmb"
    force_kind = "density"

    def __init__(self, E: float | None = None, nu: float | None = None, *, c: float | None = None,
                 s0: float | None = None, Gc: float | None = None,
                 surface_correction: bool = False, calibration: str = "continuum"):
        if (E is None) == (c is None):
            raise ValueError("PMB needs exactly one of E (Young's modulus) or c (micromodulus)")
        _check_positive(E=E, c=c, s0=s0, Gc=Gc)
        if nu is not None and not (-1.0 < nu < 0.5):
            raise ValueError(f"Poisson ratio must be in (-1, 0.5), got {nu!r}")
        if s0 is not None and Gc is not None:
            raise ValueError("give the critical stretch s0 or the fracture energy Gc, not both")
        self.E, self.nu, self.c_given, self.s0_given, self.Gc = E, nu, c, s0, Gc
        self.surface_correction = bool(surface_correction)
        if calibration not in ("continuum", "lattice"):
            raise ValueError(f"unknown calibration {calibration!r}; valid: 'continuum', 'lattice'")
        self.calibration = calibration
        self.needs = Needs(pairs=True, failure=(s0 is not None or Gc is not None), energy=True)
        self.c = c
        self.s0 = s0 if s0 is not None else np.inf

    # ------------------------------------------------------------------ set-up
    def prepare(self, system, family, **kw) -> None:
        super().prepare(system, family, **kw)
        area = float(np.mean(system.volume) / system.spacing) if system.dim == 1 else 1.0
        self._area = area
        self._g_n = None
        w = self.bond_weights()
        if self.c_given is None:
            self.c = pmb_micromodulus(self.E, self.nu, family.horizon, system.dim,
                                      thickness=system.thickness, plane=system.plane, area=area)
            if self.calibration == "lattice":
                self.c *= self._lattice_factor(w)
        if self.Gc is not None:
            self.s0 = pmb_critical_stretch(self.Gc, self.c, family.horizon, system.dim,
                                           thickness=system.thickness, area=area)
        if self.surface_correction:
            self._g_n = self._surface_factors(w)
        del w
        self.bonds = BondList(family, system.volume)
        self._pair_tables()

    # ------------------------------------------------------------------ per-bond quantities
    def surface_factors(self, bonds=None) -> np.ndarray | None:
        """The surface-correction factor ``(g_i + g_j)/2`` of every directed bond (nb,), or
        of the directed bonds ``bonds``, from the kept per-particle ``g`` (a new array);
        None without the correction."""
        if self._g_n is None:
            return None
        fam = self.family
        if bonds is None:
            return 0.5 * (self._g_n[fam.owner] + self._g_n[fam.neighbors])
        return 0.5 * (self._g_n[fam.owner_of(bonds)] + self._g_n[fam.neighbors[bonds]])

    def bond_weights(self) -> np.ndarray:
        """``w = V_j beta_ij`` (times the surface factor when corrected) of every directed
        bond (nb,) (m^3; a new array: the weights are not kept per bond)."""
        fam = self.family
        w = self.system.volume[fam.neighbors] * fam.volume_factor
        g = self.surface_factors()
        return w if g is None else w * g

    @property
    def w_b(self) -> np.ndarray:
        """:meth:`bond_weights` (a new array)."""
        return self.bond_weights()

    def _pair_tables(self) -> None:
        """Per-class coefficients of the pair kernel (see :func:`pmb_pair_kernel`)."""
        bl = self.bonds
        if self.surface_correction:
            k_p, L_k, bf_k, br_k, gf_k, gr_k = bl.classes(self.surface_factors)
        else:
            k_p, L_k, bf_k, br_k = bl.classes()
            gf_k = gr_k = 1.0
        rc2 = (L_k * (1.0 + self.s0)) ** 2 if self.needs.failure else np.full(L_k.size, np.inf)
        self._k_p = k_p
        self._tables = tuple(np.ascontiguousarray(a) for a in (
            1.0 / L_k, self.c * (bf_k * gf_k), self.c * (br_k * gr_k), rc2))

    def _lattice_factor(self, w) -> float:
        """Continuum integral of |xi| over the horizon divided by its discrete value
        ``sum_j |xi_ij| V_j beta_ij`` at the most complete (bulk) particle, so that the
        bulk energy of an isotropic stretch is exact on this discretisation."""
        sysm, fam = self.system, self.family
        S = np.bincount(fam.owner, weights=fam.length * w, minlength=fam.n).max()
        d = fam.horizon
        if sysm.dim == 3:
            integral = np.pi * d ** 4
        elif sysm.dim == 2:
            integral = 2.0 * np.pi * d ** 3 * sysm.thickness / 3.0
        else:
            integral = d * d * self._area
        return float(integral / S)

    def _surface_factors(self, w) -> np.ndarray:
        """Per-particle factors g_i = W_bulk / W_i under an isotropic stretch (N,) (the bond
        factor is (g_i + g_j)/2); ``w`` the uncorrected bond weights."""
        sysm, fam = self.system, self.family
        s = 1e-3
        y = sysm.x0 * (1.0 + s)
        W = pmb_energy_kernel(fam.offsets, fam.neighbors, fam.length, w, y,
                              np.ones(fam.nb, dtype=np.bool_), self.c)
        d = fam.horizon
        if sysm.dim == 3:
            Wb = np.pi * self.c * d ** 4 * s * s / 4.0
        elif sysm.dim == 2:
            Wb = np.pi * self.c * sysm.thickness * d ** 3 * s * s / 6.0
        else:
            Wb = self.c * self._area * d ** 2 * s * s / 2.0
        return np.where(W > 0, Wb / np.where(W > 0, W, 1.0), 1.0)

    # ------------------------------------------------------------------ forces
    def _pair_force(self, state, out, fail: bool) -> int:
        bl = self.bonds
        nt = nb.get_num_threads()
        buf, zero = bl.target(out, nt)
        invL, cf, cr, rc2 = self._tables
        broke = pmb_pair_kernel(bl.row_n, bl.j_p, self._k_p, bl.fwd_n, bl.fwd_p, bl.rev_p,
                                invL, cf, cr, rc2, bl.chunks(nt), bl.volume, state.y,
                                state.intact, fail, buf, zero)
        bl.finish(buf, zero, out)
        return int(broke)

    def add_force(self, state, out):
        self._pair_force(state, out, False)

    def step_force(self, state, out, *, failure=True):
        return self._pair_force(state, out, bool(failure and self.needs.failure))

    def stream_bytes(self) -> int:
        """Bytes one force evaluation reads and writes (see
        :meth:`~upscale.engine.bondlist.BondList.stream_bytes`)."""
        return self.bonds.stream_bytes(self._tables)

    def break_bonds(self, state):
        from upscale.engine.kernels import break_by_stretch

        if not self.needs.failure:
            return 0
        f = self.family
        s0 = np.full(f.n, self.s0)
        return int(break_by_stretch(f.offsets, f.neighbors, f.length, state.y, state.intact, s0))

    def energy_density(self, state):
        f = self.family
        return pmb_energy_kernel(f.offsets, f.neighbors, f.length, self.bond_weights(), state.y,
                                 state.intact, self.c)

    def stiffness_bound(self):
        """Silling-Askari: R_i = 2 sum_j c beta V_j / |xi| (N/m^4)."""
        f = self.family
        return 2.0 * np.bincount(f.owner, weights=self.c * self.bond_weights() / f.length, minlength=f.n)

    def describe(self):
        d = {"model": self.name, "c_N_per_m6": self.c, "s0": None if np.isinf(self.s0) else self.s0,
             "surface_correction": self.surface_correction, "calibration": self.calibration}
        if self.E is not None:
            d["E_Pa"] = self.E
            d["nu"] = self.nu if self.nu is not None else (
                _natural_nu(self.system.dim, self.system.plane) if self.system else None)
        if self.Gc is not None:
            d["Gc_J_per_m2"] = self.Gc
        return d


class LammpsContact(Model):
    """The short-range repulsive contact force of LAMMPS pair peri/pmb and peri/lps.

    For a pair closer than ``d_ij = min(0.9 |xi_ij|, 1.35 lc)`` LAMMPS adds the force
    density ``-k (r - d_ij) V_j`` along the pair (repulsive), with
    ``k = 15 c / delta`` (peri/pmb) or ``k = 15 * 18 K / (pi delta^4) / delta``
    (peri/lps). LAMMPS applies it over its ordinary neighbour list (any particles within
    the cut-off in the *current* configuration); here it runs over the pair family
    (broken bonds included), which is the same set as long as no two particles that
    started farther apart than the horizon come within 1.35 lc; each pair once, over the
    half bond list of that family. ``last_active`` counts
    the active directed contacts of the last evaluation.
    """

    name = "lammps-contact"
    needs = Needs(pairs=True)

    def __init__(self, k: float, lc: float, *, family=None):
        _check_positive(k=k, lc=lc)
        self.k = float(k)
        self.lc = float(lc)
        self.contact_family = family
        self.last_active = 0
        self.max_active = 0

    @classmethod
    def for_pmb(cls, c: float, horizon: float, lc: float, **kw) -> "LammpsContact":
        return cls(15.0 * c / horizon, lc, **kw)

    @classmethod
    def for_lps(cls, K: float, horizon: float, lc: float, **kw) -> "LammpsContact":
        return cls((15.0 * 18.0 * K) / (np.pi * horizon ** 4) / horizon, lc, **kw)

    def prepare(self, system, family, **kw) -> None:
        """``family`` given at construction (e.g. the family before a pre-crack was
        removed, as LAMMPS's neighbour list still holds those pairs) takes precedence."""
        super().prepare(system, self.contact_family if self.contact_family is not None else family, **kw)
        self.bonds = BondList(self.family, system.volume)
        self._k_p, L_k = self.bonds.classes()[:2]
        self._dc_k = np.ascontiguousarray(np.minimum(0.9 * L_k, 1.35 * self.lc))

    def stiffness_bound(self):
        """No contact is active in the reference state: zero."""
        return np.zeros(self.system.n)

    def add_force(self, state, out):
        bl = self.bonds
        nt = nb.get_num_threads()
        buf, zero = bl.target(out, nt)
        self.last_active = int(contact_pair_kernel(bl.row_n, bl.j_p, self._k_p, self._dc_k,
                                                   bl.chunks(nt), bl.volume, state.y, self.k,
                                                   buf, zero))
        bl.finish(buf, zero, out)
        self.max_active = max(self.max_active, self.last_active)

    def describe(self):
        return {"model": self.name, "k": self.k, "lc": self.lc}


register("pmb", PMB)
