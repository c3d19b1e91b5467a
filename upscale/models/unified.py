"""The unified gain-matrix model: nonlocal strain, stress and body-based forces (seed 004 ch. 6).

Kinematics (eqs. 6.1-6.6, 6.19, 6.24). For particle c with intact bonds b to neighbours
j(b) within the horizon, the gain coefficients a_b (:func:`upscale.models.gain.
gain_coefficients`, the centred Upsilon of eq. 6.5; weights w_b = kappa(|xi_b|) V_j, quartic
kappa) give the nonlocal deformation gradient

    F_c = I + G_c = sum_b (y_j(b) - y_c) (x) a_b                       (6.1, 6.19)

exact for every affine field at interior and boundary particles. The Green strain and the
second Piola-Kirchhoff stress (symbol phi in the seed, ``S`` here) are

    E_c = (F_c^T F_c - I) / 2                                          (6.24)
    S_c = C : E_c      (Voigt order, tensor shear components, 6.23)

with the stored energy W_c = S_c : E_c / 2 per unit volume (6.26). The chapter writes
xi = (G^T G - I)/2 with G built from displacements; that is -I/2 at rest, so the gain is
used as G = F - I.

Forces (6.16-6.22, 6.32-6.35). The stored energy is U = sum_c V_c W_c(F_c); since F_c is
linear in the positions, the force that is exactly -dU/dy is

    f_i = sum_{b in row i} [ V_i P_i a_b  -  V_j P_j a_b' ],   P = F S     (default)

(b' the reverse bond j -> i): the correspondence-type body-based force kappa F phi
Upsilon gamma. The printed form 6.22, phi F^T Upsilon gamma, replaces P = F S by S F^T
(``force="printed"``); it equals the default to first order in strain and differs at
order strain x stress. It is not the derivative of any energy.

Plane stress / plane strain (``dim = 2``) use the in-plane components only; the z
displacement is not a degree of freedom.

Stabilisation (``stabilisation``, dimensionless c_s, default 0). The gain operator has
the zero-energy modes of correspondence models: in the interior of a regular lattice
the symbol of G vanishes at the lattice wave vectors (pi/h, pi/h), ... . A bond-level
penalty on the non-affine part of every bond (Silling 2017, in its energy form)

    U_s = sum_c V_c (c_s E / 2) sum_b w_b |z_b|^2 / sum_b w_b |xi_b|^2,
    z_b = (y_j - y_c) - F_c xi_b

removes them. z_b vanishes for every affine field (F_c is exact there), so the penalty
changes neither the patch test nor a homogeneous solution; U_s is quadratic in y, so
its force and tangent are a constant sparse matrix (rebuilt when bonds break).

Failure (sec. 6.5). Three dimensionally consistent readings of 6.26-6.29; all use G_c
= K_Ic^2 / E' (E' = E in plane stress, E / (1 - nu^2) in plane strain and 3D) and a length
r_s in metres, and all leave bonds with an end in ``no_fail`` (load and support patches)
intact.

The nonlocal stress of the first two is the stress averaged over the disc (2D) or ball
(3D) of radius r_s about each particle (weights V_j, particles without stress excluded),

    S_bar_c = sum_{|x_j - x_c| <= r_s} V_j S_j / sum V_j.

``criterion="principal"`` (default): the energy density of the largest principal value
s_1 of S_bar_c, e_1 = <s_1>^2 / (2 E'), enters the chapter's structure (energy density x
length against G_c, 6.28-6.29):

    G^{(c)} = 2 r_s e_1 / beta^2 >= G_c      <=>      s_1 >= sigma_c = beta K_Ic / sqrt(r_s),

where beta fixes the one free constant by the mode-I tip field: the disc average of
sigma_yy = K cos(t/2)[1 + sin(t/2) sin(3t/2)] / sqrt(2 pi r) about a centre at distance p
ahead of the tip is (1 / pi r_s^2) int dt f_yy(t) (2/3) r_2(t)^(3/2) / sqrt(2 pi), r_2 =
p cos t + sqrt(r_s^2 - p^2 sin^2 t), largest at p = 0.720 r_s where it is beta K /
sqrt(r_s), beta = 0.50497 (:func:`disc_average_factor`; 0.40636 at p = 0; on the crack
line the averaged shear vanishes and sigma_bar_yy > sigma_bar_xx, so it is s_1 there). In
a K-dominated mode-I field the particle 0.72 r_s ahead of the tip therefore fails exactly
at K_I = K_Ic, whatever r_s (for r_s large against the spacing and small against the
body): r_s is the length over which the material averages its stress, a material length,
not a multiple of the spacing. A failing particle loses every bond (it becomes a void:
no stress, excluded from the averages), so a crack is a chain of voids that advances
toward the largest averaged principal stress, i.e. normal to s_1 as the maximum
tangential stress (MTS) criterion; the averaging adds the T-stress over r_s, like the
critical distance r_c of the generalised MTS criterion (the disc average of the Williams
field with T acts as GMTS with r_c of about r_s / 3). The index (s_1 / sigma_c)^2 (the
larger of the two ends, per bond) is quadratic in the load of a linear body.

The gain's stress is itself a weighted average of the gradient over the horizon, so when
r_s is a few spacings the averaged tip stress of the particle model is lower than the
continuum's disc average. ``tip_factor="lattice"`` (default in 2D) takes beta from the
same operations applied to the exact mode-I tip displacement field on the model's own
lattice (:func:`lattice_tip_factor`; it depends on r_s / spacing and the horizon, and
tends to the continuum value as r_s / spacing grows); ``"continuum"`` uses 0.50497.
``"solved"`` applies them to the model's own equilibrium of a disc driven by that field on
its rim, with the model's bond penalty c_s: the penalty resists the non-affine near-tip
deformation, so the solved front stress is not the imposed one (c_s = 1: +8 % at
r_s = dx, -5 % at r_s = 4 dx), and only the solved factor puts the first failure at
K_I = K_Ic on every grid (SCB at alpha = 0: K_I 1.006 K_Ic at dx = r_s; the SCB scenes'
default).

Crack growth (``growth``, principal criterion). ``"free"`` (default here; the seed's
literal rule): any particle may fail. The disc average of the tip field is largest 0.72
r_s ahead of the tip, so once
r_s spans several spacings the first void opens there, with an intact ligament between
it and the crack; the ligament and the voids ahead keep loading and failing over several
equilibria, so the model has a resistance that rises over a length of order r_s, i.e. of
more spacings the finer the grid at a fixed r_s. ``"front"``: only particles on the crack
front may fail, those with a nearest neighbour (closer than :data:`FRONT_RADIUS`
spacings) to which the bond is cut or broken or which is a void (:func:`crack_front`; a
free edge is not a front). The crack then advances particle by particle from its tip
toward the largest averaged principal stress among the front particles, and beta is the
average at the particles next to the tip: the tip-centred disc (p -> 0), 0.40636
K / sqrt(r_s) in the continuum, from the lattice by :func:`lattice_tip_factor` with
``growth="front"``. Nucleation away from a crack is then impossible; the load and
support patches stay protected by ``no_fail`` either way. The SCB scenes default to
``"front"`` (``upscale.experiments.scenes.scb.default_growth``): with it P_c converges under
refinement at a fixed r_s, with ``"free"`` it drifts upward (``scb-convergence``).

``criterion="normal"``: per bond, the averaged stress resolved on the bond, s_b = n_b .
(S_bar_c + S_bar_j)/2 . n_b (n_b the unit reference bond vector), with the same sigma_c.
A bond crossing a crack at an angle phi to its normal carries only about s_1 cos^2 phi, so
the shallow bonds of the family never reach sigma_c: they bridge the faces, the gain
model keeps the particles' stress and the damage spreads instead of forming a crack
(measured in the SCB; kept as an option).

With every criterion ``break_bonds`` breaks, per round, the bonds over the threshold whose
index is at least ``sequential`` times the largest (1: all of them). The averaged field is
smooth over r_s, so breaking everything over the threshold at once fails a band of width
about r_s; ``sequential`` < 1 breaks the most loaded first and re-equilibrates (the
quasi-static driver calls it until nothing breaks).

``criterion="energy"``: the particle energy densities of 6.28 (the earlier reading).
Silling and Askari's fracture energy of a straight crack in 2D is the work to break every
bond crossing a unit length of it, per unit thickness:

    G = int_0^{r_s} dy int int_{r > y / cos theta, r < r_s} w r dr dtheta = (2/3) r_s^3 w

for a uniform bond energy w (J/m^5: energy per unit thickness, per unit area of each end),
which is the integral of 6.27-6.28 (its r_s^3/3 for each half-plane side). The chapter
puts the particle energy density phi:xi/2 times the thickness in place of w, which gives
J m, not J/m^2. The energy density e_c (J/m^3 = J/m per m^2) of a particle is shared
among its interactions over the disc of radius r_s, so w_c = e_c / (pi r_s^2) and

    G^{nc} = 2 r_s e_c / (3 pi),      G_b = G^{nc} + G^{cn} = 2 r_s (e_c + e_n) / (3 pi)

(6.29 with f_1 = f_2 = 1), G_b >= G_c breaks the bond. By default e is the tensile part
of the energy (principal-stress split, :meth:`UnifiedModel.failure_energy_density`; the
chapter's total phi:xi/2 with ``failure_energy="total"``), and a bond breaks only when it is
stretched (|y_j - y_c| > |xi|). This criterion is not directional (every bond of a
high-energy particle is loaded alike) and, the tip particle's energy density being capped
by the spacing (e ~ K^2 / (E dx)), it acts as a strength reached at the tip particle: r_s
then scales with the spacing.

After bonds break, the Upsilon and the centring of every particle are recomputed from
its remaining bonds; a particle whose remaining bonds do not give a regular Upsilon
(fewer than dim + 1, or collinear) carries no stress (``alive`` False; counted in
:meth:`UnifiedModel.describe`). Damage is eq. 6.41, mu = 1 - R/T.

Array suffixes: ``_n`` per particle, ``_b`` per directed bond, ``_c`` Cartesian.
Units: SI (m, N, Pa, J).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from upscale.models import register
from upscale.models.base import Model, Needs
from upscale.models.gain import gain_coefficients, gain_coefficients_quadratic, kappa
from upscale.models.unified_kernels import (deformation_kernel, failure_index_kernel, normal_index_kernel,
                                            residual_2d, residual_kernel, stress_kernel, tangent_kernel, two_hop_pattern)
from upscale.models.unified_material import (check_positive_definite, critical_energy_release_rate, elastic_tensor,
                                             full_tensor, orthotropic_tensor)
from upscale.models.unified_tip import (LATTICE_TIP_MAX_RATIO, averaging_matrix, crack_front, disc_average_factor,
                                        front_pairs, lattice_tip_factor, tip_disc_stress, williams_angular)

__all__ = ["UnifiedModel", "elastic_tensor", "orthotropic_tensor", "critical_energy_release_rate",
           "disc_average_factor", "lattice_tip_factor", "front_pairs", "crack_front", "tip_disc_stress", "williams_angular"]



# ---------------------------------------------------------------------------- model
class UnifiedModel(Model):
    """Gain-matrix nonlocal continuum with body-based forces (seed 004 ch. 6).

    See the module docstring for the equations. ``force_kind = "particle"`` (N).

    Parameters
    ----------
    E, nu : float
        Isotropic Young's modulus (Pa) and Poisson ratio (used when ``C`` is None; E is
        also the scale of the stabilisation and of G_c).
    C : array, optional
        Voigt stiffness (Pa), (3, 3) for 2D, (6, 6) for 3D, e.g. from
        :func:`orthotropic_tensor`; must be symmetric positive definite.
    dim : {2, 3}
    plane : {"stress", "strain"}
        2D only.
    force : {"energy", "printed"}
        Energy-consistent body-based force (default) or the printed eq. 6.22.
    stabilisation : float
        c_s >= 0 of the bond-level penalty (module docstring); 0 switches it off.
    K_Ic : float, optional
        Mode-I toughness (Pa m^0.5); with ``r_s`` turns failure on.
    r_s : float, optional
        Length of the failure criterion (m), > 0.
    G_c : float, optional
        Critical energy release rate (J/m^2) instead of K_Ic.
    no_fail : (N,) bool, optional
        Particles whose bonds never break (load and support patches).
    criterion : {"principal", "normal", "energy"}
        Failure rule (module docstring): the largest principal stress averaged over r_s
        (default; a failing particle loses all its bonds), the averaged stress resolved on
        each bond, or the particle energy densities of 6.28.
    tip_factor : {"lattice", "solved", "continuum"}
        beta of sigma_c: from the mode-I tip field imposed on this lattice (default, 2D;
        :func:`lattice_tip_factor`; the continuum value above r_s / spacing =
        :data:`LATTICE_TIP_MAX_RATIO`), from the model's own solution of a disc driven by
        that field on its rim (``"solved"``, with this model's ``stabilisation``), or the
        continuum disc average (:func:`disc_average_factor`).
    growth : {"free", "front"}
        Which particles may fail under the principal criterion (module docstring): any
        (default) or only those on the crack front.
    sequential : float
        In (0, 1]: per round only the bonds whose index is at least this fraction of the
        largest break (1: every bond over the threshold).
    failure_energy : {"tensile", "total"}
        Energy density of the ``"energy"`` criterion (:meth:`failure_energy_density`).
    rcond : float
        Regularity threshold of Upsilon (see :func:`gain_coefficients`).
    min_bonds : int
        A particle with fewer intact bonds carries no stress (default: dim + 1, the
        least that gives a regular Upsilon).
    """

    name = "unified"
    force_kind = "particle"

    def __init__(self, E: float = 3.75e9, nu: float = 0.35, *, C=None, dim: int = 2,
                 plane: str = "stress", force: str = "energy", stabilisation: float = 0.0,
                 K_Ic: float | None = None, r_s: float | None = None, G_c: float | None = None,
                 no_fail=None, rcond: float = 1e-6, kernel: str = "quartic",
                 failure_energy: str = "tensile", min_bonds: int = 0, gain_order: int = 1,
                 qcond: float = 1e-8, criterion: str = "principal",
                 sequential: float = 1.0, tip_factor: str = "lattice", growth: str = "free"):
        if dim not in (2, 3):
            raise ValueError(f"dim={dim!r}; valid: 2, 3")
        if force not in ("energy", "printed"):
            raise ValueError(f"force={force!r}; valid: 'energy', 'printed'")
        if not (stabilisation >= 0):
            raise ValueError(f"stabilisation={stabilisation!r}; valid: >= 0")
        if C is None:
            C = elastic_tensor(E, nu, dim=dim, plane=plane)
        C = np.asarray(C, dtype=float)
        m = 3 if dim == 2 else 6
        if C.shape != (m, m):
            raise ValueError(f"C has shape {C.shape}; valid: ({m}, {m}) Voigt matrix for dim={dim}")
        self.C = check_positive_definite(C, "stiffness matrix C")
        self.E, self.nu, self.dim, self.plane = float(E), float(nu), dim, plane
        self.force_form = force
        if failure_energy not in ("tensile", "total"):
            raise ValueError(f"failure_energy={failure_energy!r}; valid: 'tensile', 'total'")
        self.failure_energy = failure_energy
        if criterion not in ("principal", "normal", "energy"):
            raise ValueError(f"criterion={criterion!r}; valid: 'principal' (largest principal averaged stress of a "
                             "particle), 'normal' (the averaged stress resolved on the bond), 'energy' (particle "
                             "energy densities of 6.28)")
        if not (0.0 < sequential <= 1.0):
            raise ValueError(f"sequential={sequential!r}; valid: 0 < sequential <= 1")
        self.sequential = float(sequential)
        if tip_factor not in ("lattice", "solved", "continuum"):
            raise ValueError(f"tip_factor={tip_factor!r}; valid: 'lattice', 'solved', 'continuum'")
        self.tip_factor_kind = tip_factor
        if growth not in ("free", "front"):
            raise ValueError(f"growth={growth!r}; valid: 'free' (any particle may fail), 'front' (only "
                             "particles next to a cut or broken nearest-neighbour bond)")
        if growth == "front" and criterion != "principal":
            raise ValueError(f"growth='front' with criterion={criterion!r}; valid: criterion='principal'")
        self.growth = growth
        self.criterion = criterion
        self.stabilisation = float(stabilisation)
        self.kernel = kernel
        self.rcond = float(rcond)
        self.min_bonds = int(min_bonds)
        if gain_order not in (1, 2):
            raise ValueError(f"gain_order={gain_order!r}; valid: 1 (linear fit), 2 (quadratic fit)")
        self.gain_order = int(gain_order)
        self.qcond = float(qcond)
        if r_s is not None and not (np.isfinite(r_s) and r_s > 0):
            raise ValueError(f"r_s={r_s!r} m; valid: r_s > 0")
        self.r_s = None if r_s is None else float(r_s)
        if G_c is None and K_Ic is not None:
            G_c = critical_energy_release_rate(K_Ic, E, nu, "stress" if (dim == 2 and plane == "stress") else "strain")
        if G_c is not None and not (G_c > 0):
            raise ValueError(f"G_c={G_c!r} J/m^2; valid: > 0")
        self.K_Ic = K_Ic
        self.G_c = G_c
        self.no_fail = None if no_fail is None else np.asarray(no_fail, dtype=bool)
        failure = self.r_s is not None and self.G_c is not None
        self.needs = Needs(pairs=True, failure=failure, energy=True, tangent=True)
        self._C4 = full_tensor(self.C, dim)

    # ------------------------------------------------------------------ set-up
    def prepare(self, system, family, *, triplets=None, quadruplets=None) -> None:
        super().prepare(system, family)
        if system.dim != self.dim:
            raise ValueError(f"system has dim={system.dim}, model dim={self.dim}")
        n = system.n
        self._xi = np.ascontiguousarray(family.xi)
        self._w = np.ascontiguousarray(kappa(family.length, family.horizon, self.kernel)
                                       * system.volume[family.neighbors])
        self._reverse = np.ascontiguousarray(family.reverse)
        self.coef = np.zeros((family.nb, self.dim))
        self.alive = np.zeros(n, dtype=bool)
        if self.no_fail is None:
            self._no_fail = np.zeros(n, dtype=bool)
        else:
            if self.no_fail.shape != (n,):
                raise ValueError(f"no_fail has shape {self.no_fail.shape}; valid: ({n},)")
            self._no_fail = self.no_fail
        self._topology = None
        self._csr_pattern = None
        self._avg = None
        if self.needs.failure and self.criterion in ("normal", "principal"):
            self._avg = averaging_matrix(system.x0[:, :self.dim], system.volume, self.r_s)
        self._no_fail_b = self._no_fail[family.owner] | self._no_fail[family.neighbors]
        self._index_cache = None
        self._front_pairs = None
        if self.needs.failure and self.growth == "front":
            if system.spacing is None:
                raise ValueError("growth='front' needs the particle system's spacing (ParticleSystem(spacing=...)); "
                                 "valid otherwise: growth='free'")
            self._front_pairs = front_pairs(system.x0[:, :self.dim], system.spacing, family.owner,
                                            family.neighbors, n)
        self.update_bonds(np.ones(family.nb, dtype=bool))

    def tip_factor(self) -> float:
        """beta of sigma_c: :func:`disc_average_factor` (``tip_factor="continuum"``) or
        :func:`lattice_tip_factor` on this model's spacing and horizon (``"lattice"``, 2D)."""
        p = 0.0 if self.growth == "front" else None
        if self.tip_factor_kind == "continuum" or self.dim == 3:
            return disc_average_factor(self.dim, p=p)[0]
        if self.system.spacing is not None and self.r_s > LATTICE_TIP_MAX_RATIO * self.system.spacing:
            # the lattice factor has converged to the continuum one (within 1.2 % from
            # r_s / spacing = 4 on), and its lattice would hold ~(8 r_s / spacing)^2 particles
            return disc_average_factor(self.dim, p=p)[0]
        if self.system.spacing is None:
            raise ValueError(f"tip_factor={self.tip_factor_kind!r} needs the particle system's spacing "
                             "(ParticleSystem(spacing=...)); valid otherwise: tip_factor='continuum'")
        return lattice_tip_factor(self.r_s, self.system.spacing, self.family.horizon, E=self.E, nu=self.nu,
                                  plane=self.plane, kernel=self.kernel, rcond=self.rcond,
                                  min_bonds=self.min_bonds, gain_order=self.gain_order, growth=self.growth,
                                  field="solved" if self.tip_factor_kind == "solved" else "imposed",
                                  stabilisation=self.stabilisation)[0]

    def sigma_c(self) -> float:
        """Critical averaged stress beta K_Ic / sqrt(r_s) (Pa) of the ``"principal"`` and
        ``"normal"`` criteria, K_Ic = sqrt(E' G_c)."""
        Ep = self.E if (self.dim == 2 and self.plane == "stress") else self.E / (1 - self.nu ** 2)
        return self.tip_factor() * np.sqrt(Ep * self.G_c) / np.sqrt(self.r_s)

    def _sigma_c(self):
        if getattr(self, "_sc_cache", None) is None:
            self._sc_cache = self.sigma_c()
        return self._sc_cache

    def averaged_stress(self, state) -> np.ndarray:
        """Stress S averaged over the r_s neighbourhood (N, dim, dim), Pa (particles without
        stress excluded from the average)."""
        S = self.continuum_fields(state)[2]
        n, d = self.system.n, self.dim
        wv = self.alive.astype(float)
        num = self._avg @ (wv[:, None] * S.reshape(n, d * d))
        den = self._avg @ wv
        out = np.where(den[:, None] > 0, num / np.where(den > 0, den, 1.0)[:, None], 0.0)
        return out.reshape(n, d, d)

    def update_bonds(self, intact) -> None:
        """Recompute Upsilon, the centring and the gain coefficients of every particle from
        the intact bonds (mutates ``coef``, ``alive``, the cached operators)."""
        intact = np.ascontiguousarray(intact, dtype=np.bool_)
        if self.gain_order == 2:
            self.quadratic = np.zeros(self.system.n, dtype=bool)
            gain_coefficients_quadratic(self._xi, self.family.offsets, self._w, intact, self.dim, self.rcond,
                                        self.qcond, self.coef, self.alive, self.quadratic)
        else:
            gain_coefficients(self._xi, self.family.offsets, self._w, intact, self.dim, self.rcond,
                              self.coef, self.alive)
        if self.min_bonds > self.dim + 1:
            cnt = np.bincount(self.family.owner[intact], minlength=self.system.n)
            few = self.alive & (cnt < self.min_bonds)
            if few.any():
                self.alive[few] = False
                self.coef[np.isin(self.family.owner, np.flatnonzero(few))] = 0.0
        self._intact_key = intact.copy()
        self._pen = None

    def _sync(self, state):
        if not np.array_equal(state.intact, self._intact_key):
            self.update_bonds(state.intact)

    # ------------------------------------------------------------------ continuum fields
    def continuum_fields(self, state):
        """(F, E, S, P, W): deformation gradient, Green strain, PK2 stress (Pa), force
        stress (Pa) as (N, dim, dim) and energy density W (N,) J/m^3."""
        self._sync(state)
        n, d = self.system.n, self.dim
        y = np.ascontiguousarray(state.y)
        F = np.empty((n, d, d))
        deformation_kernel(y, self.family.offsets, self.family.neighbors, self.coef, d, F)
        E = np.empty_like(F)
        S = np.empty_like(F)
        P = np.empty_like(F)
        W = np.empty(n)
        stress_kernel(F, self._C4, self.alive, self.force_form == "printed", d, E, S, P, W)
        return F, E, S, P, W

    def deformation_gradient(self, state) -> np.ndarray:
        """F = I + G per particle (N, dim, dim)."""
        return self.continuum_fields(state)[0]

    # ------------------------------------------------------------------ forces and energy
    def add_force(self, state, out) -> None:
        self._residual(state, out)

    def _residual(self, state, out):
        """Adds the force of the gain model and the penalty to ``out`` (N, 3) by the fused
        :func:`~upscale.models.unified_kernels.residual_kernel`; returns the energy (J)."""
        self._sync(state)
        fam, n, d = self.family, self.system.n, self.dim
        if getattr(self, "_work", None) is None or self._work[-1].shape[0] != fam.nb:
            self._work = ((np.empty((n, 4)), np.empty((n, 2))) if d == 2 else
                          (np.empty((n, d, d)), np.empty((n, d, d)), np.empty((n, d, d)), np.empty((n, d)))) \
                + (np.empty((fam.nb, d)),)
        kv, ok = self._penalty_weights()
        if self.stabilisation <= 0:
            kv = np.zeros(n)
        args = (np.ascontiguousarray(state.y), fam.offsets, fam.neighbors, self._reverse, self.coef, self._xi,
                self._w, ok, kv, self._C4, self.alive, self.system.volume, self.force_form == "printed")
        if d == 2:
            return residual_2d(*args, *self._work, out)
        return residual_kernel(*args, d, *self._work, out)

    def energy_density(self, state) -> np.ndarray:
        """Strain energy density W_c = S:E/2 (J/m^3) of the gain model (penalty excluded)."""
        return self.continuum_fields(state)[4]

    def energy(self, state) -> float:
        """Stored energy (J): sum_c V_c W_c plus the stabilisation energy."""
        return float(self._residual(state, np.zeros((self.system.n, 3))))

    # ------------------------------------------------------------------ tangent
    def _tangent_pattern(self):
        """CSR pattern (indptr, indices) of the (3N, 3N) tangent: the dofs of particles two
        family hops apart (:func:`two_hop_pattern`), fixed for the family, so a sparse
        factorisation keeps its symbolic analysis while bonds break (their entries stay as
        zeros)."""
        if getattr(self, "_csr_pattern", None) is None:
            fam, d, n = self.family, self.dim, self.system.n
            ptr, q_p = two_hop_pattern(fam.offsets, fam.neighbors, n)
            cnt = np.diff(ptr)
            rowlen = np.zeros((n, 3), np.int64)
            rowlen[:, :d] = d * cnt[:, None]
            indptr = np.zeros(3 * n + 1, np.int64)
            np.cumsum(rowlen.ravel(), out=indptr[1:])
            cols = (3 * q_p[:, None] + np.arange(d)[None, :]).ravel()   # row p's: cols[d ptr[p]:d ptr[p+1]]
            owner = np.repeat(np.arange(n), d * cnt)
            within = np.arange(cols.size) - d * ptr[owner]
            itype = np.int32 if indptr[-1] < 2 ** 31 else np.int64
            indices = np.empty(indptr[-1], itype)
            for i in range(d):
                indices[indptr[3 * owner + i] + within] = cols
            self._csr_pattern = (indptr.astype(itype), indices, ptr, q_p)
        return self._csr_pattern

    def _penalty_weights(self):
        """(kv (N,), ok (nb,) bool): kv_c = c_s E V_c / sum_b w_b |xi_b|^2 over the bonds of
        c with ``ok`` (intact, c alive); kv = 0 without bonds."""
        if self._pen is None:
            fam = self.family
            c = fam.owner
            ok = self._intact_key & self.alive[c]
            m = np.bincount(c[ok], self._w[ok] * np.einsum("bk,bk->b", self._xi[ok, :self.dim], self._xi[ok, :self.dim]),
                            minlength=self.system.n)
            kv = np.where(m > 0, self.stabilisation * self.E * self.system.volume / np.where(m > 0, m, 1.0), 0.0)
            self._pen = (kv, np.ascontiguousarray(ok))
        return self._pen

    def tangent(self, state, particles=None):
        """Consistent stiffness K = -dF_int/dy (scipy.sparse CSR (3N, 3N) on the fixed
        pattern of :meth:`_tangent_pattern`): per particle c, V_c g . dP/dF . g of its members
        plus the penalty's constant sum_b kv_c w_b e_b e_b^T (:func:`tangent_kernel`),
        dP_iA/dF_jB = delta_ij S_AB + F_iC C_CAKB F_jK (energy form).

        ``particles`` (int array, optional): only the contributions of these particles c;
        the rows of particle p are then exact when every particle of p's family (p
        included) is listed (a local block for the quasi-static solver)."""
        F, E, S, P, W = self.continuum_fields(state)
        d, n = self.dim, self.system.n
        indptr, indices, ptr, q_p = self._tangent_pattern()
        kv, ok = self._penalty_weights()
        if self.stabilisation <= 0:
            kv = np.zeros(n)
        data = np.zeros(indices.size)
        fam = self.family
        parts = np.arange(n) if particles is None else np.asarray(particles, dtype=np.int64)
        tangent_kernel(F, S, self._C4, self.alive, self.system.volume, fam.offsets, fam.neighbors, self.coef,
                       self._xi, self._w, ok, kv, ptr, q_p, d, parts, data)
        return sp.csr_matrix((data, indices, indptr), shape=(3 * n, 3 * n))

    def residual(self, state) -> np.ndarray:
        return self.particle_force(state).ravel()

    # ------------------------------------------------------------------ failure
    def failure_index(self, state) -> np.ndarray:
        """G_b / G_c per directed bond (nb,) (module docstring); zeros without failure."""
        out = np.zeros(self.family.nb)
        if not self.needs.failure:
            return out
        if self.criterion == "principal":
            c = self._index_cache
            if c is not None and np.array_equal(c[0], state.y) and np.array_equal(c[1], state.intact):
                return c[2].copy()        # the quasi-static driver asks again before breaking
            Sb = self.averaged_stress(state)
            if self.dim == 2:             # the larger eigenvalue of the symmetric 2 x 2 (lower triangle)
                s1 = 0.5 * (Sb[:, 0, 0] + Sb[:, 1, 1]) + np.hypot(0.5 * (Sb[:, 0, 0] - Sb[:, 1, 1]), Sb[:, 1, 0])
            else:
                s1 = np.linalg.eigvalsh(Sb)[:, -1]
            ip = (np.maximum(s1, 0.0) / self._sigma_c()) ** 2
            ip[self._no_fail] = 0.0
            if self._front_pairs is not None:
                ip[~crack_front(self._front_pairs, state.intact, self.alive, self.system.n)] = 0.0
            fam = self.family
            np.maximum(ip[fam.owner], ip[fam.neighbors], out=out)
            out[~state.intact | self._no_fail_b] = 0.0
            self._index_cache = (state.y.copy(), state.intact.copy(), out.copy())
            return out
        if self.criterion == "normal":
            Sb = np.ascontiguousarray(self.averaged_stress(state))
            normal_index_kernel(self._xi, self.family.offsets, self.family.neighbors, Sb, state.intact,
                                self._no_fail, self.dim, 1.0 / self._sigma_c(), out)
            return out
        W = self.failure_energy_density(state)
        factor = 2.0 * self.r_s / (3.0 * np.pi * self.G_c)
        failure_index_kernel(np.ascontiguousarray(state.y), self.system.x0, self.family.offsets,
                             self.family.neighbors, W, state.intact, self._no_fail, factor, out)
        return out

    def failure_energy_density(self, state) -> np.ndarray:
        """Energy density e (J/m^3) that enters the criterion: the total W
        (``failure_energy="total"``, the chapter's phi:xi/2) or its tensile part
        (default ``"tensile"``) e+ = sum_i <s_i> (n_i . E n_i) / 2 over the principal
        stresses s_i and directions n_i of S (e+ = W in uniaxial tension, 0 in any
        compressive state)."""
        F, E, S, P, W = self.continuum_fields(state)
        if self.failure_energy == "total":
            return W
        s, n = np.linalg.eigh(S)
        en = np.einsum("nki,nkl,nli->ni", n, E, n)
        return 0.5 * np.sum(np.maximum(s, 0.0) * en, axis=1)

    def break_bonds(self, state, threshold: float = 1.0) -> int:
        """Mutates ``state.intact``: breaks (both directions of) every bond whose failure
        index is >= ``threshold``, then recomputes Upsilon and the centring. Returns the
        number of directed bonds broken."""
        if not self.needs.failure:
            return 0
        idx = self.failure_index(state)
        hit = idx >= threshold
        if self.sequential < 1.0 and hit.any():
            hit &= idx >= self.sequential * idx.max()
        hit |= hit[self._reverse]
        hit &= state.intact
        k = int(hit.sum())
        if k:
            state.intact[hit] = False
            self.update_bonds(state.intact)
        return k

    def stiffness_bound(self):
        """Gershgorin row bound of the reference tangent (N/m per particle)."""
        from upscale.engine.state import State

        st = State.reference(self.system.x0, self.family.nb)
        st.intact[:] = self._intact_key
        K = self.tangent(st)
        r = np.asarray(abs(K).sum(axis=1)).reshape(-1, 3)
        return r.max(axis=1)

    def describe(self) -> dict:
        d = {"model": self.name, "dim": self.dim, "plane": self.plane, "E_Pa": self.E, "nu": self.nu,
             "C_voigt_Pa": self.C.tolist(), "force": self.force_form,
             "stabilisation": self.stabilisation, "criterion": self.criterion, "growth": self.growth, "failure_energy": self.failure_energy, "r_s_m": self.r_s, "G_c_J_per_m2": self.G_c,
             "K_Ic_Pa_sqrt_m": self.K_Ic}
        if self.system is not None:
            d["particles_without_stress"] = int((~self.alive).sum())
        if self.needs.failure and self.criterion in ("normal", "principal"):
            d["sigma_c_Pa"] = self._sigma_c()
            d["tip_factor"] = self.tip_factor_kind
        return d


register("unified", UnifiedModel)
