r"""Continuum-kinematics-inspired peridynamics (CPD; Javili, McBride & Steinmann 2019, JMPS).

One-, two- and three-neighbour interactions (seed 000, "Constitutive laws" and Table 2;
seed 002 for the same model written as force densities b_1, b_2, b_3):

.. math::

    \psi_1 = \tfrac12 C_1 L (l/L - 1)^2,\qquad
    \psi_2 = \tfrac12 C_2 A (a/A - 1)^2,\qquad
    \psi_3 = \tfrac12 C_3 V (v/V - 1)^2

with the length ``l = |xi'|``, the area ``a = |xi' x xi''|`` and the volume
``v = |xi' . (xi'' x xi''')|`` of the relative positions ``xi = y_j - y_i`` (capitals: the
same in the reference configuration). The point-wise stored energy density is (seed 000)

.. math::

    \psi(x) = \int_{H_0} \tfrac12\psi_1\,dV' + \iint_{H_0^2} \tfrac13\psi_2\,dV''dV'
              + \iiint_{H_0^3} \tfrac14\psi_3\,dV'''dV''dV'.

Units (SI)
----------
``psi_1, psi_2, psi_3`` are energies per volume^2, ^3, ^4 (J/m^6, J/m^9, J/m^12), so
``C1`` is in J/m^7 (= N/m^6), ``C2`` in J/m^11, ``C3`` in J/m^15, and ``psi`` in J/m^3.
In 2D every particle volume is its area times the plate thickness ``h`` (engine
convention), the neighbourhood volume is ``V_H = beta pi delta^2 h`` and the constants keep
the 3D units above; the area measure ``a`` is the in-plane area (m^2). There is no
three-neighbour interaction in 2D (every neighbour triple is coplanar).

Discretisation and counting convention
--------------------------------------
Two quadratures of the neighbourhood integrals (``quadrature=``):

``"uniform"`` -- seed 000 ("Discretization of the integrals"): every admissible set gets the
    same effective volume, ``V_1 = V_H/N_1``, ``V_2 = V_H^2/N_2``, ``V_3 = V_H^3/N_3`` with
    ``N_k`` the numbers of *ordered* admissible neighbour sets of the point,
    ``V_H^i = beta^i V_ball`` (seed 002), completeness
    ``beta^i = min(1, sum_j V_j beta_ij / V_ball)`` (``beta_ij`` the family's partial-volume
    factor), ``V_ball = 4/3 pi delta^3`` (3D) or ``pi delta^2 h`` (2D). Note the powers:
    ``V_k`` carries ``V_H^k`` (m^3k), which is what makes ``psi`` come out in J/m^3.
``"volume"`` (default) -- product quadrature with the neighbours' own volumes
    ``omega_j = V_j beta_ij``: ``dV' dV'' -> omega_j omega_k`` etc. (units m^3k as above).
    Collinear / coplanar sets need no renormalisation here: their integrands vanish
    (``A = 0`` or ``V = 0``), so dropping them is exact. With the engine's ``"linear"``
    partial volumes it is the accurate choice (see ``cpd-calibration``).

Because every ``psi_k`` is symmetric in its neighbours, a sum over ordered sets equals
``2!`` (pairs of neighbours) or ``3!`` (triples) times the sum over *unordered* sets; the
code stores unordered sets (``slot_j < slot_k [< slot_l]``, :mod:`upscale.engine.multibody`)
and uses the equivalent weights per centre ``i`` and unordered set:

* one-neighbour  ``w_1^i = 1/2 V^i V_H^i / N_1^i``   (volume: ``1/2 V^i omega_j``)
* two-neighbour  ``w_2^i = 1/3 V^i (V_H^i)^2 / n_2^i``   (``n_2 = N_2/2`` unordered pairs;
  volume: ``2/3 V^i omega_j omega_k``)
* three-neighbour ``w_3^i = 1/4 V^i (V_H^i)^3 / n_3^i``  (``n_3 = N_3/6`` unordered triples;
  volume: ``3/2 V^i omega_j omega_k omega_l``)

so that the stored energy of particle ``i`` is ``W_i = sum_k sum_sets w psi_k``
(J) and its energy density ``W_i / V^i`` is the discrete ``psi(x_i)``. A set is owned by
its centre: the geometric triangle ``{i, j, k}`` appears again (with the weight of that
centre) if it is also in the family of ``j`` or ``k``; this is exactly the
``1/2, 1/3, 1/4`` bookkeeping of the continuum energy, where every point of a set plays the
centre once.

Forces and tangent are exact derivatives of the total energy ``W = sum_i W_i``:
``F_int = -dW/dy`` (N per particle) and ``K = d^2W/dy^2`` (symmetric). Where every set is
in the family of each of its members and ``V^i V_k^i`` is uniform -- the bulk of a uniform
grid with ``|x_j - x_k| <= delta`` -- this reduces to seed 000's point-wise residual
``R^a = R_1^a + R_2^a + R_3^a`` (times ``V^a``), e.g.
``R_2^a = sum_{i != j} 2 xi^j x dpsi_2/da V_2``. Sets whose members are farther than
``delta`` apart are seen by fewer centres; the energy-consistent form weights them by the
number of centres that own them, whereas the point-wise form of the paper is not the
gradient of any energy there. We use the energy-consistent form so that the tangent is
symmetric, the Newton solve minimises an energy, and linear and angular momentum are
conserved exactly (each set's forces sum to zero and have zero moment).

Calibration (isotropic linear elasticity)
-----------------------------------------
Linearise about the reference with ``F = I + H``, ``eps = sym H``, ``n = Xi/|Xi|``:
``l/L - 1 = n.eps.n``; ``a/A - 1 = tr eps - N.eps.N`` in 3D (``a = |cof F . A_vec|`` with
``cof F ~ (1 + tr H) I - H^T``, ``N`` the unit normal) and ``a/A - 1 = tr eps`` in 2D
(``a/A = |det F|``); ``v/V - 1 = tr eps``. Replace the sums by integrals over the ball
(``x', x'', x'''`` independent and uniform) and use the isotropic moments
``int_{S^2} n_i n_j n_k n_l dOmega = 4pi/15 (d_ij d_kl + d_ik d_jl + d_il d_jk)``,
``int_0^{2pi} n_i n_j n_k n_l dtheta = pi/4 (...)``, ``E[sin angle(n', n'')] = pi/4``
(3D, normal independent of the angle by rotational invariance), ``E|n'.(n'' x n''')| = pi/8``,
``E|sin(theta' - theta'')| = 2/pi`` (2D). With ``psi = 1/2 lambda (tr eps)^2 + mu eps:eps``:

3D::

    one-neighbour   psi = C1 pi delta^4/60 [(tr eps)^2 + 2 eps:eps]
                    -> lambda_1 = mu_1 = pi delta^4 C1 / 30               (nu = 1/4)
    two-neighbour   psi = C2 pi^3 delta^8/24 [2/5 (tr eps)^2 + 2/15 eps:eps]
                    -> lambda_2 = pi^3 delta^8 C2 / 30, mu_2 = pi^3 delta^8 C2 / 180
    three-neighbour psi = C3 pi^4 delta^12/64 (tr eps)^2
                    -> lambda_3 = pi^4 delta^12 C3 / 32, mu_3 = 0

2D (thickness h; in-plane Lame constants: plane strain lambda, mu; plane stress
lambda* = 2 lambda mu/(lambda + 2 mu) = E nu/(1 - nu^2), mu)::

    one-neighbour   lambda_1 = mu_1 = pi h delta^3 C1 / 24   (nu = 1/3 plane stress, 1/4 strain)
    two-neighbour   lambda_2 = 8 pi h^2 delta^6 C2 / 27, mu_2 = 0

Dimensions check: J/m^7 * m^4 = J/m^11 * m^8 = J/m^15 * m^12 = Pa (2D: the thickness
supplies the missing length powers). The C1/C3 pair agrees with the published calibration
of Ekiz, Steinmann & Javili (2022, Mech. Mater. 104417): ``C1 = 30 mu/(pi delta^4)``,
``C3 = 32 (lambda - mu)/(pi^4 delta^12)`` (mode ``"C1C3"``, tested).

Reachable Poisson ratio with non-negative constants: every term has ``lambda_k >= mu_k``, so
``lambda >= mu``: 3D ``nu in [1/4, 1/2)``; 2D plane stress ``nu in [1/3, 1)``, plane strain
``[1/4, 1/2)``. With C1 and C2 only (no quadruplets) 3D needs ``lambda <= 6 mu``, i.e.
``nu in [1/4, 3/7]``. The calibration (:func:`calibrate`) is unique in 2D; in 3D it has one
free choice, fixed by ``mode``: ``"C1C2"`` (cheapest beyond bonds: ``C3 = 0``),
``"C1C3"`` (``C2 = 0``), ``"C2C3"`` (``C1 = 0``), ``"auto"`` (``C1C2`` up to 3/7, then
``C2C3``).

The continuum coefficients above are the ``delta/dx -> infinity`` limit. On a lattice the
neighbourhood sums differ from the integrals by several per cent at ``delta/dx = 2-4``
(lattice anisotropy and the radial distribution of the points). ``calibration="discrete"``
(default) therefore solves the same two equations with the coefficients ``l_k, m_k``
*measured* on the model's own most interior particle (isotropic least-squares fit of its
energy density over small strains, :meth:`CPD.discrete_coefficients`); ``"continuum"`` uses
the formulas. ``surface_correction=True`` (default off) additionally gives every set a
constant weight factor built from direction-wise ratios of bulk to local energy density
under uniaxial strains (PD energy-method surface correction,
:meth:`CPD._apply_surface_correction`; constants of the reference, so forces stay energy
gradients). Measured in ``cpd-newton [--surface-correction]``: it cuts the cantilever
error (2D, delta/dx = 2-3) from +16..+26 % to -4..-6 % but over-stiffens the bar in tension
(+0.6..+6 % -> -6..-7 %; 3D -11..-13 %), so it stays an option.

Damage
------
Optional critical stretches, one per interaction type, tension only, irreversible:
a bond breaks when ``l/L - 1 > s1c``; a two-neighbour set when ``a/A - 1 > s2c`` or one of
its two bonds (centre-j, centre-k) is broken; a three-neighbour set when ``v/V - 1 > s3c`` or
one of its three bonds is broken. Defaults ``s2c = 2 s1c`` and ``s3c = 3 s1c`` (an isotropic
expansion with bond stretch ``s`` stretches areas by ~``2s`` and volumes by ~``3s``).
Broken sets stop contributing; the effective volumes keep their reference counts ``N_k``.
Damage per particle ``mu = 1 - R/T`` (seed 004 eq. 5.16) is reported per type.

Array suffixes: ``_n`` per particle, ``_b`` per directed bond, ``_t`` per triplet,
``_q`` per quadruplet, ``_c`` Cartesian.
"""
from __future__ import annotations

import math
import types

import numba
import numpy as np

from upscale.engine import multibody
from upscale.engine.kernels import bond_length
from upscale.models.base import Model, Needs

__all__ = ["CPD", "calibrate", "lame", "modulus_coefficients", "poisson_range",
           "energy_forces", "tangent_bsr"]

MODES = ("auto", "C1C2", "C1C3", "C2C3")
QUADRATURES = ("uniform", "volume")


# =========================================================================== calibration
def lame(E: float, nu: float, dim: int = 3, plane: str = "stress") -> tuple[float, float]:
    """Lame constants (lambda, mu) in Pa seen by a ``dim``-D model (2D: in-plane constants
    of plane stress ``lambda* = E nu/(1 - nu^2)`` or plane strain)."""
    mu = E / (2.0 * (1.0 + nu))
    if dim == 2 and plane == "stress":
        return E * nu / (1.0 - nu * nu), mu
    return E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), mu


def modulus_coefficients(horizon: float, dim: int = 3, thickness: float = 1.0) -> dict:
    """Coefficients of ``lambda = l1 C1 + l2 C2 + l3 C3`` and ``mu = m1 C1 + m2 C2``
    (see the module docstring for the derivation). Units: Pa per unit of each constant."""
    d = float(horizon)
    if dim == 3:
        return {"l1": math.pi * d ** 4 / 30, "m1": math.pi * d ** 4 / 30,
                "l2": math.pi ** 3 * d ** 8 / 30, "m2": math.pi ** 3 * d ** 8 / 180,
                "l3": math.pi ** 4 * d ** 12 / 32, "m3": 0.0}
    if dim == 2:
        h = float(thickness)
        return {"l1": math.pi * h * d ** 3 / 24, "m1": math.pi * h * d ** 3 / 24,
                "l2": 8 * math.pi * h * h * d ** 6 / 27, "m2": 0.0, "l3": 0.0, "m3": 0.0}
    raise ValueError(f"CPD is defined in 2D and 3D, got dim={dim!r}")


def poisson_range(dim: int = 3, plane: str = "stress", mode: str = "auto") -> tuple[float, float, bool]:
    """Range ``(lo, hi, hi_included)`` of Poisson's ratio reachable with non-negative
    constants (derived in the module docstring)."""
    if dim == 3:
        if mode == "C1C2":
            return 0.25, 3.0 / 7.0, True
        if mode == "C2C3":
            return 3.0 / 7.0, 0.5, False
        return 0.25, 0.5, False
    if plane == "stress":
        return 1.0 / 3.0, 1.0, False
    return 0.25, 0.5, False


def _check_nu(nu, dim, plane, mode):
    lo, hi, inc = poisson_range(dim, plane, mode)
    ok = (nu >= lo - 1e-12) and (nu <= hi + 1e-12 if inc else nu < hi)
    if not ok:
        where = f"{dim}D" + (f" plane {plane}" if dim == 2 else "") + (f", mode {mode}" if mode != "auto" else "")
        raise ValueError(f"nu={nu!r} outside the range CPD reaches with non-negative constants in "
                         f"{where}: [{lo:.6g}, {hi:.6g}{']' if inc else ')'}")


def calibrate(E: float, nu: float, horizon: float, dim: int = 3, *, plane: str = "stress",
              thickness: float = 1.0, mode: str = "auto",
              coefficients: dict | None = None) -> tuple[float, float, float]:
    """CPD constants ``(C1, C2, C3)`` (J/m^7, J/m^11, J/m^15) for Young's modulus ``E`` (Pa)
    and Poisson's ratio ``nu`` with horizon ``delta`` (m); 2D needs the ``plane`` and the
    ``thickness`` (m).

    Raises
    ------
    ValueError
        ``nu`` outside :func:`poisson_range`, non-positive ``E`` or ``horizon``, bad ``mode``.

    ``coefficients`` replaces the continuum coefficients of :func:`modulus_coefficients`
    (e.g. by the discrete ones of an interior point, :meth:`CPD.discrete_coefficients`).
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if not (E > 0 and np.isfinite(E)):
        raise ValueError(f"E must be positive, got {E!r}")
    if not (horizon > 0 and np.isfinite(horizon)):
        raise ValueError(f"horizon must be positive, got {horizon!r}")
    if dim not in (2, 3):
        raise ValueError(f"CPD is defined in 2D and 3D, got dim={dim!r}")
    if dim == 2 and mode not in ("auto",):
        mode = "auto"
    _check_nu(nu, dim, plane, mode)
    lam, mu = lame(E, nu, dim, plane)
    k = modulus_coefficients(horizon, dim, thickness) if coefficients is None else coefficients
    # (with discrete coefficients a constant that would come out slightly negative at the
    # very ends of the range is clipped to zero)
    if dim == 2:
        C1 = mu / k["m1"]
        return C1, max(lam - k["l1"] * C1, 0.0) / k["l2"], 0.0
    if mode == "auto":
        mode = "C1C2" if lam <= 6 * mu * (1 + 1e-12) else "C2C3"
    # general 2x2 solves (the discrete coefficients need not have l1 == m1)
    if mode == "C1C2":
        a, b, c, d = k["l1"], k["l2"], k["m1"], k["m2"]
        det = a * d - b * c
        C1, C2 = (d * lam - b * mu) / det, (a * mu - c * lam) / det
        if abs(nu - 0.25) < 1e-12 and dim == 3 and coefficients is None:
            C1, C2 = mu / k["m1"], 0.0
        return max(C1, 0.0), max(C2, 0.0), 0.0
    if mode == "C1C3":
        C1 = mu / k["m1"]
        return C1, 0.0, max(lam - k["l1"] * C1, 0.0) / k["l3"]
    C2 = mu / k["m2"]
    return 0.0, C2, max(lam - k["l2"] * C2, 0.0) / k["l3"]


def effective_moduli(C1, C2, C3, horizon, dim=3, thickness=1.0) -> tuple[float, float]:
    """Continuum (lambda, mu) (Pa) of given constants (inverse of :func:`calibrate`)."""
    k = modulus_coefficients(horizon, dim, thickness)
    return (k["l1"] * C1 + k["l2"] * C2 + k["l3"] * C3, k["m1"] * C1 + k["m2"] * C2)


# =========================================================================== kernels
@numba.njit(cache=True, inline="always")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True)
def _pair_energy_force(y, offsets, neighbors, ref_nc, q_b, w_n, g_s, C1, intact_b, f, e_n):
    """Adds -dW1/dy to ``f`` (N, 3) and W1 per centre to ``e_n`` (N,); the reference
    lengths ``L = |ref_j - ref_c|`` are recomputed from the reference positions."""
    n = offsets.shape[0] - 1
    for c in range(n):
        w = w_n[c]
        if w == 0.0:
            continue
        for p in range(offsets[c], offsets[c + 1]):
            if not intact_b[p]:
                continue
            j = neighbors[p]
            x0 = y[j, 0] - y[c, 0]
            x1 = y[j, 1] - y[c, 1]
            x2 = y[j, 2] - y[c, 2]
            l = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            L = bond_length(ref_nc, c, j)
            s = l / L - 1.0
            ww = w * q_b[p] * g_s[p]
            e_n[c] += ww * 0.5 * C1 * L * s * s
            g = ww * C1 * s / l
            f[j, 0] -= g * x0
            f[j, 1] -= g * x1
            f[j, 2] -= g * x2
            f[c, 0] += g * x0
            f[c, 1] += g * x1
            f[c, 2] += g * x2


@numba.njit(cache=True)
def _triplet_energy_force(y, offsets, neighbors, q_b, t_off, sj, sk, A_t, w_n, g_s, C2, intact_t, f, e_n):
    """Adds -dW2/dy to ``f`` and W2 per centre to ``e_n``."""
    n = offsets.shape[0] - 1
    for c in range(n):
        w = w_n[c]
        if w == 0.0:
            continue
        base = offsets[c]
        for t in range(t_off[c], t_off[c + 1]):
            if not intact_t[t]:
                continue
            j = neighbors[base + sj[t]]
            k = neighbors[base + sk[t]]
            u0 = y[j, 0] - y[c, 0]
            u1 = y[j, 1] - y[c, 1]
            u2 = y[j, 2] - y[c, 2]
            v0 = y[k, 0] - y[c, 0]
            v1 = y[k, 1] - y[c, 1]
            v2 = y[k, 2] - y[c, 2]
            a0, a1, a2 = _cross(u0, u1, u2, v0, v1, v2)
            m = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            A = A_t[t]
            s = m / A - 1.0
            ww = w * q_b[base + sj[t]] * q_b[base + sk[t]] * g_s[t]
            e_n[c] += ww * 0.5 * C2 * A * s * s
            if m == 0.0:
                continue
            g = ww * C2 * s / m         # w dpsi/da = g * a
            g0, g1, g2 = g * a0, g * a1, g * a2
            dj0, dj1, dj2 = _cross(v0, v1, v2, g0, g1, g2)    # dpsi/dxi_j = xi_k x g
            dk0, dk1, dk2 = _cross(g0, g1, g2, u0, u1, u2)    # dpsi/dxi_k = g x xi_j
            f[j, 0] -= dj0
            f[j, 1] -= dj1
            f[j, 2] -= dj2
            f[k, 0] -= dk0
            f[k, 1] -= dk1
            f[k, 2] -= dk2
            f[c, 0] += dj0 + dk0
            f[c, 1] += dj1 + dk1
            f[c, 2] += dj2 + dk2


@numba.njit(cache=True)
def _quad_energy_force(y, offsets, neighbors, q_b, q_off, sj, sk, sl, V_q, w_n, g_s, C3, intact_q, f, e_n):
    """Adds -dW3/dy to ``f`` and W3 per centre to ``e_n``."""
    n = offsets.shape[0] - 1
    xi = np.empty((0, 3))
    for c in range(n):
        w = w_n[c]
        if w == 0.0:
            continue
        base = offsets[c]
        m_c = offsets[c + 1] - base
        if xi.shape[0] < m_c:
            xi = np.empty((m_c, 3))
        for p in range(m_c):
            jj = neighbors[base + p]
            xi[p, 0] = y[jj, 0] - y[c, 0]
            xi[p, 1] = y[jj, 1] - y[c, 1]
            xi[p, 2] = y[jj, 2] - y[c, 2]
        for t in range(q_off[c], q_off[c + 1]):
            if not intact_q[t]:
                continue
            p, q, r = sj[t], sk[t], sl[t]
            kl0, kl1, kl2 = _cross(xi[q, 0], xi[q, 1], xi[q, 2], xi[r, 0], xi[r, 1], xi[r, 2])
            v = xi[p, 0] * kl0 + xi[p, 1] * kl1 + xi[p, 2] * kl2
            m = abs(v)
            V = V_q[t]
            s = m / V - 1.0
            ww = w * q_b[base + p] * q_b[base + q] * q_b[base + r] * g_s[t]
            e_n[c] += ww * 0.5 * C3 * V * s * s
            if m == 0.0:
                continue
            g = ww * C3 * s * (1.0 if v > 0 else -1.0)   # w dpsi/dv
            lj0, lj1, lj2 = _cross(xi[r, 0], xi[r, 1], xi[r, 2], xi[p, 0], xi[p, 1], xi[p, 2])
            jk0, jk1, jk2 = _cross(xi[p, 0], xi[p, 1], xi[p, 2], xi[q, 0], xi[q, 1], xi[q, 2])
            j = neighbors[base + p]
            k = neighbors[base + q]
            l = neighbors[base + r]
            f[j, 0] -= g * kl0
            f[j, 1] -= g * kl1
            f[j, 2] -= g * kl2
            f[k, 0] -= g * lj0
            f[k, 1] -= g * lj1
            f[k, 2] -= g * lj2
            f[l, 0] -= g * jk0
            f[l, 1] -= g * jk1
            f[l, 2] -= g * jk2
            f[c, 0] += g * (kl0 + lj0 + jk0)
            f[c, 1] += g * (kl1 + lj1 + jk1)
            f[c, 2] += g * (kl2 + lj2 + jk2)


# ---------------------------------------------------------------- tangent (block CSR)
@numba.njit(cache=True)
def _local_table(c, offsets, neighbors, indptr, indices, loc, star=False):
    """loc[r * M + s] = block index of (member r, member s) in the block-CSR pattern, where
    member 0 is the centre and member p + 1 is slot p of its row (M = slots + 1). With
    ``star`` only the entries a pair interaction touches (centre row and column, diagonal)
    are filled."""
    base = offsets[c]
    M = offsets[c + 1] - base + 1
    for r in range(M):
        gr = c if r == 0 else neighbors[base + r - 1]
        lo0, hi0 = indptr[gr], indptr[gr + 1]
        for s in range(M):
            if star and r != 0 and s != 0 and s != r:
                continue
            gs = c if s == 0 else neighbors[base + s - 1]
            lo, hi = lo0, hi0
            while lo < hi:
                mid = (lo + hi) // 2
                if indices[mid] < gs:
                    lo = mid + 1
                else:
                    hi = mid
            if lo >= hi0 or indices[lo] != gs:
                loc[r * M + s] = -1     # cannot happen with a 2*horizon pattern
            else:
                loc[r * M + s] = lo
    return M


@numba.njit(cache=True)
def _scatter(data, loc, M, ids, nv, H, dim):
    """Add the member-vector Hessian ``H`` (3nv, 3nv) of one set to the point blocks:
    rows/cols of the neighbours are those of H, the centre's are minus the sums."""
    # neighbour-neighbour blocks and centre rows/cols
    for a in range(nv):
        for b in range(nv):
            blk = data[loc[ids[a] * M + ids[b]]]
            for s in range(dim):
                for t in range(dim):
                    blk[s, t] += H[3 * a + s, 3 * b + t]
    for b in range(nv):
        bcb = data[loc[ids[b]]]          # (centre, member b)
        bbc = data[loc[ids[b] * M]]      # (member b, centre)
        for s in range(dim):
            for t in range(dim):
                acc1 = 0.0
                acc2 = 0.0
                for a in range(nv):
                    acc1 += H[3 * a + s, 3 * b + t]
                    acc2 += H[3 * b + s, 3 * a + t]
                bcb[s, t] -= acc1
                bbc[s, t] -= acc2
    bcc = data[loc[0]]
    for s in range(dim):
        for t in range(dim):
            acc = 0.0
            for a in range(nv):
                for b in range(nv):
                    acc += H[3 * a + s, 3 * b + t]
            bcc[s, t] += acc


@numba.njit(cache=True)
def _flush(data, loc, Lb, M, dim):
    """Add the per-centre block buffer ``Lb`` (M*M, 3, 3) to the global block data."""
    for k in range(M * M):
        blk = data[loc[k]]
        src = Lb[k]
        for s in range(dim):
            for t in range(dim):
                blk[s, t] += src[s, t]


@numba.njit(cache=True)
def _pair_tangent(y, offsets, neighbors, ref_nc, q_b, w_n, g_s, C1, intact_b, indptr, indices, data, dim):
    n = offsets.shape[0] - 1
    loc = np.empty(0, np.int64)
    H = np.zeros((3, 3))
    ids = np.zeros(1, np.int64)
    x = np.empty(3)
    for c in range(n):
        w = w_n[c]
        if w == 0.0:
            continue
        M = offsets[c + 1] - offsets[c] + 1
        if loc.shape[0] < M * M:
            loc = np.empty(M * M, np.int64)
        _local_table(c, offsets, neighbors, indptr, indices, loc, True)
        for p in range(offsets[c], offsets[c + 1]):
            if not intact_b[p]:
                continue
            j = neighbors[p]
            for s in range(3):
                x[s] = y[j, s] - y[c, s]
            l = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
            L = bond_length(ref_nc, c, j)
            ww = w * q_b[p] * g_s[p]
            d = ww * C1 * (1.0 / L - 1.0 / l)
            e = ww * C1 / (l * l * l)
            for s in range(3):
                for t in range(3):
                    H[s, t] = e * x[s] * x[t]
                H[s, s] += d
            ids[0] = p - offsets[c] + 1
            _scatter(data, loc, M, ids, 1, H, dim)


@numba.njit(cache=True, inline="always")
def _E(w, out, r0, c0, sign):
    """out[r0:r0+3, c0:c0+3] += sign * E(w), E(w)_ab = eps_abc w_c."""
    out[r0 + 0, c0 + 1] += sign * w[2]
    out[r0 + 0, c0 + 2] -= sign * w[1]
    out[r0 + 1, c0 + 0] -= sign * w[2]
    out[r0 + 1, c0 + 2] += sign * w[0]
    out[r0 + 2, c0 + 0] += sign * w[1]
    out[r0 + 2, c0 + 1] -= sign * w[0]


@numba.njit(cache=True)
def _triplet_tangent(y, offsets, neighbors, q_b, t_off, sj, sk, A_t, w_n, g_s, C2, intact_t,
                     indptr, indices, data, dim):
    n = offsets.shape[0] - 1
    loc = np.empty(0, np.int64)
    Lb = np.zeros((0, 3, 3))          # per-centre dense block buffer (cache friendly)
    ident = np.arange(0)
    H = np.zeros((6, 6))
    J = np.zeros((3, 6))     # da/d(xi_j, xi_k)
    PJ = np.zeros((3, 6))
    g = np.zeros(6)
    ids = np.zeros(2, np.int64)
    u = np.empty(3)
    v = np.empty(3)
    nrm = np.empty(3)
    for c in range(n):
        w = w_n[c]
        if w == 0.0 or t_off[c + 1] == t_off[c]:
            continue
        base = offsets[c]
        M = offsets[c + 1] - base + 1
        if loc.shape[0] < M * M:
            loc = np.empty(M * M, np.int64)
        _local_table(c, offsets, neighbors, indptr, indices, loc)
        if Lb.shape[0] < M * M:
            Lb = np.zeros((M * M, 3, 3))
            ident = np.arange(M * M)
        else:
            Lb[:M * M] = 0.0
        for t in range(t_off[c], t_off[c + 1]):
            if not intact_t[t]:
                continue
            j = neighbors[base + sj[t]]
            k = neighbors[base + sk[t]]
            for s in range(3):
                u[s] = y[j, s] - y[c, s]
                v[s] = y[k, s] - y[c, s]
            a0, a1, a2 = _cross(u[0], u[1], u[2], v[0], v[1], v[2])
            m = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            if m == 0.0:
                continue
            A = A_t[t]
            nrm[0], nrm[1], nrm[2] = a0 / m, a1 / m, a2 / m
            ww = w * q_b[base + sj[t]] * q_b[base + sk[t]] * g_s[t]
            dpsi = ww * C2 * (m / A - 1.0)
            d2psi = ww * C2 / A
            # J = [E(xi_k), -E(xi_j)]  (a = xi_j x xi_k)
            J[:, :] = 0.0
            _E(v, J, 0, 0, 1.0)
            _E(u, J, 0, 3, -1.0)
            # g = J^T n ; P J = J - n (n^T J)
            for b in range(6):
                acc = nrm[0] * J[0, b] + nrm[1] * J[1, b] + nrm[2] * J[2, b]
                g[b] = acc
                for r in range(3):
                    PJ[r, b] = J[r, b] - nrm[r] * acc
            for a in range(6):
                for b in range(6):
                    acc = 0.0
                    for r in range(3):
                        acc += J[r, a] * PJ[r, b]
                    H[a, b] = d2psi * g[a] * g[b] + dpsi * acc / m
            _E(nrm, H, 0, 3, dpsi)          # d2a/dxi_j dxi_k . n = E(n)
            for a in range(3):
                for b in range(3):
                    H[3 + a, b] = H[b, 3 + a]
            ids[0] = sj[t] + 1
            ids[1] = sk[t] + 1
            _scatter(Lb, ident, M, ids, 2, H, dim)
        _flush(data, loc, Lb, M, dim)


@numba.njit(cache=True)
def _quad_tangent(y, offsets, neighbors, q_b, q_off, sj, sk, sl, V_q, w_n, g_s, C3, intact_q,
                  indptr, indices, data, dim):
    n = offsets.shape[0] - 1
    loc = np.empty(0, np.int64)
    Lb = np.zeros((0, 3, 3))
    ident = np.arange(0)
    H = np.zeros((9, 9))
    g = np.zeros(9)
    ids = np.zeros(3, np.int64)
    xi = np.empty((0, 3))
    wj = np.empty(3)
    wk = np.empty(3)
    wl = np.empty(3)
    for c in range(n):
        w = w_n[c]
        if w == 0.0 or q_off[c + 1] == q_off[c]:
            continue
        base = offsets[c]
        mc = offsets[c + 1] - base
        M = mc + 1
        if loc.shape[0] < M * M:
            loc = np.empty(M * M, np.int64)
        _local_table(c, offsets, neighbors, indptr, indices, loc)
        if Lb.shape[0] < M * M:
            Lb = np.zeros((M * M, 3, 3))
            ident = np.arange(M * M)
        else:
            Lb[:M * M] = 0.0
        if xi.shape[0] < mc:
            xi = np.empty((mc, 3))
        for p in range(mc):
            jj = neighbors[base + p]
            for s in range(3):
                xi[p, s] = y[jj, s] - y[c, s]
        for t in range(q_off[c], q_off[c + 1]):
            if not intact_q[t]:
                continue
            p, q, r = sj[t], sk[t], sl[t]
            for s in range(3):
                wj[s] = xi[p, s]
                wk[s] = xi[q, s]
                wl[s] = xi[r, s]
            g[0], g[1], g[2] = _cross(wk[0], wk[1], wk[2], wl[0], wl[1], wl[2])
            g[3], g[4], g[5] = _cross(wl[0], wl[1], wl[2], wj[0], wj[1], wj[2])
            g[6], g[7], g[8] = _cross(wj[0], wj[1], wj[2], wk[0], wk[1], wk[2])
            vv = wj[0] * g[0] + wj[1] * g[1] + wj[2] * g[2]
            m = abs(vv)
            if m == 0.0:
                continue
            sg = 1.0 if vv > 0 else -1.0
            V = V_q[t]
            ww = w * q_b[base + p] * q_b[base + q] * q_b[base + r] * g_s[t]
            dpsi = ww * C3 * (m / V - 1.0) * sg    # times d2v (sign of |v| folded in)
            d2psi = ww * C3 / V                    # times (dm)(dm) = (dv)(dv)
            for a in range(9):
                for b in range(9):
                    H[a, b] = d2psi * g[a] * g[b]
            _E(wl, H, 0, 3, dpsi)      # (j,k) = E(xi_l)
            _E(wk, H, 0, 6, -dpsi)     # (j,l) = -E(xi_k)
            _E(wj, H, 3, 6, dpsi)      # (k,l) = E(xi_j)
            for a in range(3):
                for b in range(3):
                    H[3 + a, b] = H[b, 3 + a]
                    H[6 + a, b] = H[b, 6 + a]
                    H[6 + a, 3 + b] = H[3 + b, 6 + a]
            ids[0] = p + 1
            ids[1] = q + 1
            ids[2] = r + 1
            _scatter(Lb, ident, M, ids, 3, H, dim)
        _flush(data, loc, Lb, M, dim)


# ---------------------------------------------------------------- failure
@numba.njit(cache=True)
def _break_pairs(y, offsets, neighbors, ref_nc, s1c, intact_b):
    n = offsets.shape[0] - 1
    nbroken = 0
    for c in range(n):
        for p in range(offsets[c], offsets[c + 1]):
            if not intact_b[p]:
                continue
            j = neighbors[p]
            l = math.sqrt((y[j, 0] - y[c, 0]) ** 2 + (y[j, 1] - y[c, 1]) ** 2 + (y[j, 2] - y[c, 2]) ** 2)
            if l / bond_length(ref_nc, c, j) - 1.0 > s1c:
                intact_b[p] = False
                nbroken += 1
    return nbroken


@numba.njit(cache=True)
def _break_triplets(y, offsets, neighbors, t_off, sj, sk, A_t, s2c, intact_b, intact_t):
    n = offsets.shape[0] - 1
    nbroken = 0
    for c in range(n):
        base = offsets[c]
        for t in range(t_off[c], t_off[c + 1]):
            if not intact_t[t]:
                continue
            pj, pk = base + sj[t], base + sk[t]
            brk = (not intact_b[pj]) or (not intact_b[pk])
            if not brk:
                j, k = neighbors[pj], neighbors[pk]
                a0, a1, a2 = _cross(y[j, 0] - y[c, 0], y[j, 1] - y[c, 1], y[j, 2] - y[c, 2],
                                    y[k, 0] - y[c, 0], y[k, 1] - y[c, 1], y[k, 2] - y[c, 2])
                brk = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) / A_t[t] - 1.0 > s2c
            if brk:
                intact_t[t] = False
                nbroken += 1
    return nbroken


@numba.njit(cache=True)
def _break_quads(y, offsets, neighbors, q_off, sj, sk, sl, V_q, s3c, intact_b, intact_q):
    n = offsets.shape[0] - 1
    nbroken = 0
    for c in range(n):
        base = offsets[c]
        for t in range(q_off[c], q_off[c + 1]):
            if not intact_q[t]:
                continue
            pj, pk, pl = base + sj[t], base + sk[t], base + sl[t]
            brk = (not intact_b[pj]) or (not intact_b[pk]) or (not intact_b[pl])
            if not brk:
                j, k, l = neighbors[pj], neighbors[pk], neighbors[pl]
                a0, a1, a2 = _cross(y[k, 0] - y[c, 0], y[k, 1] - y[c, 1], y[k, 2] - y[c, 2],
                                    y[l, 0] - y[c, 0], y[l, 1] - y[c, 1], y[l, 2] - y[c, 2])
                v = (y[j, 0] - y[c, 0]) * a0 + (y[j, 1] - y[c, 1]) * a1 + (y[j, 2] - y[c, 2]) * a2
                brk = abs(v) / V_q[t] - 1.0 > s3c
            if brk:
                intact_q[t] = False
                nbroken += 1
    return nbroken


# =========================================================================== flat API
_EMPTY_I32 = np.zeros(0, np.int32)
_EMPTY_I64 = np.zeros(1, np.int64)


def _factors(g, fam, tri, quad):
    ones = lambda k: np.ones(max(k, 1))  # noqa: E731
    nb = fam.neighbors.shape[0]
    nt = 0 if tri is None else tri.size
    nq = 0 if quad is None else quad.size
    if g is None:
        return ones(nb), ones(nt), ones(nq)
    return tuple(ones(k) if a is None else np.ascontiguousarray(a, dtype=np.float64)
                 for a, k in zip(g, (nb, nt, nq)))


def energy_forces(y, fam, tri, quad, w, C, intact, *, types=(1, 2, 3), g=None):
    """Energy per centre (N,) (J) and internal force per particle (N, 3) (N) on flat
    arrays. ``fam``: object with ``offsets``, ``neighbors``, ``x0`` (reference positions, from
    which the kernels recompute the bond lengths) and ``q`` (per-bond quadrature weight);
    ``tri``/``quad``:
    :class:`~upscale.engine.multibody.TripletFamily` / ``QuadrupletFamily`` or None;
    ``w = (w1_n, w2_n, w3_n)`` per-centre weights (module docstring); ``C = (C1, C2, C3)``;
    ``intact = (intact_b, intact_t, intact_q)``; ``g = (g_b, g_t, g_q)`` optional per-set
    weight factors (surface correction; default 1)."""
    y = np.ascontiguousarray(y, dtype=np.float64)
    n = y.shape[0]
    f = np.zeros((n, 3))
    e = np.zeros(n)
    g = _factors(g, fam, tri, quad)
    if 1 in types and C[0] != 0.0:
        _pair_energy_force(y, fam.offsets, fam.neighbors, fam.x0, fam.q, w[0], g[0], float(C[0]),
                           intact[0], f, e)
    if 2 in types and C[1] != 0.0 and tri is not None:
        _triplet_energy_force(y, fam.offsets, fam.neighbors, fam.q, tri.offsets, tri.slot_j,
                              tri.slot_k, tri.area, w[1], g[1], float(C[1]), intact[1], f, e)
    if 3 in types and C[2] != 0.0 and quad is not None:
        _quad_energy_force(y, fam.offsets, fam.neighbors, fam.q, quad.offsets, quad.slot_j,
                           quad.slot_k, quad.slot_l, quad.volume, w[2], g[2], float(C[2]),
                           intact[2], f, e)
    return e, f


def tangent_bsr(y, fam, tri, quad, w, C, intact, pattern, dim, *, types=(1, 2, 3), g=None):
    """Stiffness ``K = d^2W/dy^2`` as ``scipy.sparse.bsr_matrix`` (3N, 3N) with 3x3 blocks
    on ``pattern = (indptr, indices)`` (:func:`upscale.engine.multibody.block_pattern`).
    In 2D only the in-plane (x, y) entries are filled."""
    import scipy.sparse as sp

    y = np.ascontiguousarray(y, dtype=np.float64)
    n = y.shape[0]
    indptr, indices = pattern
    data = np.zeros((indices.shape[0], 3, 3))
    g = _factors(g, fam, tri, quad)
    if 1 in types and C[0] != 0.0:
        _pair_tangent(y, fam.offsets, fam.neighbors, fam.x0, fam.q, w[0], g[0], float(C[0]), intact[0],
                      indptr, indices, data, dim)
    if 2 in types and C[1] != 0.0 and tri is not None:
        _triplet_tangent(y, fam.offsets, fam.neighbors, fam.q, tri.offsets, tri.slot_j, tri.slot_k,
                         tri.area, w[1], g[1], float(C[1]), intact[1], indptr, indices, data, dim)
    if 3 in types and C[2] != 0.0 and quad is not None:
        _quad_tangent(y, fam.offsets, fam.neighbors, fam.q, quad.offsets, quad.slot_j, quad.slot_k,
                      quad.slot_l, quad.volume, w[2], g[2], float(C[2]), intact[2], indptr, indices,
                      data, dim)
    return sp.bsr_matrix((data, indices, indptr), shape=(3 * n, 3 * n))


# =========================================================================== model
def _fmt(v) -> str:
    return f"{v:.6g}"


class CPD(Model):
    """Continuum-kinematics-inspired peridynamics on the engine (see the module docstring
    for the equations, units, counting convention, calibration and damage rules).

    Parameters
    ----------
    horizon : float
        Horizon delta (m); must equal the family's horizon.
    dim : {2, 3}
    E, nu : float, optional
        Young's modulus (Pa) and Poisson's ratio: the constants are calibrated
        (:func:`calibrate`, ``mode``). Mutually exclusive with ``C1, C2, C3``.
    C1, C2, C3 : float, optional
        Constants in J/m^7, J/m^11, J/m^15 (non-negative; C3 = 0 in 2D).
    mode : {"auto", "C1C2", "C1C3", "C2C3"}
        3D calibration choice (module docstring).
    plane : {"stress", "strain"}, optional
        2D idealisation for the calibration; default: the system's ``plane`` (a different
        explicit value is an error in ``prepare``).
    s1c, s2c, s3c : float, optional
        Critical stretches of bonds, areas and volumes (failure only if ``s1c`` is given;
        defaults ``2 s1c`` and ``3 s1c``).
    tol : float
        Non-collinearity / non-coplanarity tolerance of the multi-neighbour families.
    max_sets : int
        Largest number of triplets or quadruplets the model agrees to store.

    Notes
    -----
    ``needs.triplets`` is False when ``C2 == 0`` and ``needs.quadruplets`` is False when
    ``C3 == 0``: no such family is built and no such kernel runs.
    """

    name = "cpd"
    force_kind = "density"

    def __init__(self, *, horizon: float, dim: int = 3, E: float | None = None,
                 nu: float | None = None, C1: float | None = None, C2: float | None = None,
                 C3: float | None = None, mode: str = "auto", plane: str | None = None,
                 s1c: float | None = None, s2c: float | None = None, s3c: float | None = None,
                 quadrature: str = "volume", calibration: str = "discrete",
                 surface_correction: bool = False,
                 tol: float = multibody.DEFAULT_TOL, max_sets: int = multibody.DEFAULT_MAX_SETS):
        if quadrature not in QUADRATURES:
            raise ValueError(f"quadrature must be one of {QUADRATURES}, got {quadrature!r}")
        self.quadrature = quadrature
        if calibration not in ("discrete", "continuum"):
            raise ValueError(f"calibration must be 'discrete' or 'continuum', got {calibration!r}")
        self.calibration = calibration
        self.surface_correction = bool(surface_correction)
        self.g = None
        self.coefficients = None
        if dim not in (2, 3):
            raise ValueError(f"CPD is defined in 2D and 3D, got dim={dim!r}")
        if not (horizon is not None and np.isfinite(horizon) and horizon > 0):
            raise ValueError(f"horizon must be positive, got {horizon!r}")
        if plane not in (None, "stress", "strain"):
            raise ValueError(f"plane must be 'stress' or 'strain', got {plane!r}")
        self.horizon = float(horizon)
        self.dim = int(dim)
        self.plane = plane
        self.mode = mode
        self.tol = float(tol)
        self.max_sets = int(max_sets)
        given = [c is not None for c in (C1, C2, C3)]
        if (E is not None or nu is not None) and any(given):
            raise ValueError("give either E and nu (calibration) or C1, C2, C3, not both")
        if E is not None or nu is not None:
            if E is None or nu is None:
                raise ValueError("calibration needs both E and nu")
            self.E, self.nu = float(E), float(nu)
            if dim == 2 and plane is None:   # plane comes from the system in prepare
                p_try = "stress" if self.nu >= 1.0 / 3.0 else "strain"
                if self.nu >= 0.5 and self.nu < 1.0:
                    p_try = "stress"
                try:
                    self.C = calibrate(self.E, self.nu, self.horizon, 2, plane=p_try, mode=mode)
                except ValueError:
                    raise ValueError(f"nu={nu!r} outside the range CPD reaches with non-negative "
                                     "constants in 2D: [0.25, 0.5) plane strain, "
                                     "[0.333333, 1) plane stress") from None
            else:
                self.C = calibrate(self.E, self.nu, self.horizon, self.dim,
                                   plane=plane or "stress", thickness=1.0, mode=mode)
        else:
            if not any(given):
                raise ValueError("give E and nu, or at least one of C1, C2, C3")
            units = ("J/m^7", "J/m^11", "J/m^15")
            C = []
            for k, (c, u) in enumerate(zip((C1, C2, C3), units)):
                c = 0.0 if c is None else float(c)
                if not (np.isfinite(c) and c >= 0.0):
                    raise ValueError(f"C{k + 1}={c!r} is negative or not finite; valid range "
                                     f"[0, inf) {u}")
                C.append(c)
            if dim == 2 and C[2] != 0.0:
                raise ValueError(f"C3={C[2]!r}: there is no three-neighbour interaction in 2D "
                                 "(all neighbour triples are coplanar); valid C3 = 0 in 2D")
            if sum(C) == 0.0:
                raise ValueError("all constants are zero; valid: C1, C2, C3 >= 0, not all zero")
            self.E = self.nu = None
            self.C = tuple(C)
        for name, s in (("s1c", s1c), ("s2c", s2c), ("s3c", s3c)):
            if s is not None and not (np.isfinite(s) and s > 0):
                raise ValueError(f"{name}={s!r} must be a positive critical stretch")
        self.s1c = None if s1c is None else float(s1c)
        self.s2c = None if self.s1c is None else float(2 * self.s1c if s2c is None else s2c)
        self.s3c = None if self.s1c is None else float(3 * self.s1c if s3c is None else s3c)
        self._pattern = None

    # ------------------------------------------------------------------ needs
    @property
    def needs(self) -> Needs:
        return Needs(pairs=True, triplets=self.C[1] > 0.0, quadruplets=self.C[2] > 0.0,
                     failure=self.s1c is not None, energy=True, tangent=True)

    # ------------------------------------------------------------------ set-up
    def prepare(self, system, family, *, triplets=None, quadruplets=None, centres=None) -> None:
        """Build the triplet/quadruplet families the constants need, the neighbourhood
        volumes ``V_H`` and the per-centre weights ``w_k``.

        ``centres`` (int array, optional) restricts *all* interactions to the sets owned by
        these particles (the others own none: weight 0); for measurements of the point-wise
        energy density and of the cost per point in large neighbourhoods.

        Raises
        ------
        ValueError
            dimension or horizon mismatch; a particle without bonds, or (when C2 > 0 /
            C3 > 0) without a non-collinear pair / non-coplanar triple of neighbours.
        """
        if system.dim != self.dim:
            raise ValueError(f"model dim={self.dim} but system dim={system.dim}")
        if abs(family.horizon - self.horizon) > 1e-9 * self.horizon:
            raise ValueError(f"family horizon {family.horizon!r} != model horizon {self.horizon!r}")
        super().prepare(system, family)
        self.thickness = float(getattr(system, "thickness", 1.0) or 1.0) if self.dim == 2 else 1.0
        if self.dim == 2:
            sp_ = getattr(system, "plane", None) or "stress"
            if self.plane is not None and self.plane != sp_:
                raise ValueError(f"model plane {self.plane!r} but system plane {sp_!r}")
            self.plane = sp_
        if self.E is not None:
            self.C = calibrate(self.E, self.nu, self.horizon, self.dim, plane=self.plane,
                               thickness=self.thickness, mode=self.mode)
        x0 = system.x0
        n = system.n
        N1 = np.diff(family.offsets)
        own = np.ones(n, bool)
        if centres is not None:
            own[:] = False
            own[np.asarray(centres, dtype=np.int64)] = True
        self.centres = None if centres is None else np.flatnonzero(own)
        partial = getattr(family, "partial_rows", None)  # rows missing bonds: not checked
        chk = own if partial is None else own & ~partial
        if (N1[chk] == 0).any():
            i = int(np.flatnonzero(chk & (N1 == 0))[0])
            raise ValueError(f"horizon {_fmt(self.horizon)} too small: particle {i} has no "
                             f"neighbour (spacing {_fmt(system.spacing)}; need horizon >= spacing)")
        if self.needs.triplets:
            tri = triplets if triplets is not None else multibody.build_triplets(
                x0, family, centres=self.centres, tol=self.tol, max_sets=self.max_sets)
            n2 = tri.counts
            if (n2[chk] == 0).any():
                i = int(np.flatnonzero(chk & (n2 == 0))[0])
                raise ValueError(
                    f"horizon {_fmt(self.horizon)} too small for two-neighbour interactions: "
                    f"particle {i} has no non-collinear pair of neighbours ({int(N1[i])} "
                    f"neighbours); need horizon >= spacing in 2D/3D lattices, or C2 = 0")
        else:
            tri, n2 = None, np.zeros(n, np.int64)
        if self.needs.quadruplets:
            quad = quadruplets if quadruplets is not None else multibody.build_quadruplets(
                x0, family, centres=self.centres, tol=self.tol, max_sets=self.max_sets)
            n3 = quad.counts
            if (n3[chk] == 0).any():
                i = int(np.flatnonzero(chk & (n3 == 0))[0])
                raise ValueError(
                    f"horizon {_fmt(self.horizon)} too small for three-neighbour interactions: "
                    f"particle {i} has no non-coplanar triple of neighbours ({int(N1[i])} "
                    f"neighbours); need horizon >= spacing on a cubic lattice, or C3 = 0")
        else:
            quad, n3 = None, np.zeros(n, np.int64)
        self.triplets, self.quadruplets = tri, quad
        d = self.horizon
        V_ball = 4.0 / 3.0 * math.pi * d ** 3 if self.dim == 3 else math.pi * d * d * self.thickness
        owner = family.owner
        vsum = np.bincount(owner, weights=system.volume[family.neighbors] * family.volume_factor,
                           minlength=n)
        self.beta = np.minimum(1.0, vsum / V_ball)
        self.V_H = self.beta * V_ball
        V = system.volume
        if self.quadrature == "uniform":
            w1 = np.where(own, 0.5 * V * self.V_H / np.maximum(N1, 1), 0.0)
            w2 = np.where(n2 > 0, V * self.V_H ** 2 / (3.0 * np.maximum(n2, 1)), 0.0)
            w3 = np.where(n3 > 0, V * self.V_H ** 3 / (4.0 * np.maximum(n3, 1)), 0.0)
            self._q_b = np.ones(family.nb)
        else:
            w1 = np.where(own, 0.5 * V, 0.0)
            w2 = np.where(n2 > 0, 2.0 / 3.0 * V, 0.0)
            w3 = np.where(n3 > 0, 1.5 * V, 0.0)
            self._q_b = np.ascontiguousarray(system.volume[family.neighbors] * family.volume_factor)
        if hasattr(self, "_fam_arrays"):
            del self._fam_arrays
        self.w = (np.ascontiguousarray(w1), np.ascontiguousarray(w2), np.ascontiguousarray(w3))
        self.counts = {"pairs": N1, "triplets": n2, "quadruplets": n3}
        self.coefficients = modulus_coefficients(self.horizon, self.dim, self.thickness)
        self.correction = None
        self.g = None
        if self.surface_correction:
            self._apply_surface_correction()
        if self.E is not None and self.calibration == "discrete":
            self.coefficients = self.discrete_coefficients()
            self.C = calibrate(self.E, self.nu, self.horizon, self.dim, plane=self.plane,
                               thickness=self.thickness, mode=self.mode,
                               coefficients=self.coefficients)
        self._pattern = None

    def _apply_surface_correction(self) -> None:
        """Directional surface correction (PD energy method, Madenci & Oterkus): for every
        centre ``i``, interaction type and axis ``a < dim`` the factor
        ``g_a^i = S_a(bulk) / S_a(i)`` of the energy densities under the uniaxial strain
        ``e_a (x) e_a`` (bulk: the most interior particle). Each set then gets a constant
        weight factor from its own geometry: a bond with unit vector ``n`` gets
        ``(sum_a n_a^2 / g_a^2)^(-1/2)`` (the ellipse of Madenci & Oterkus); a 3D area
        set with unit normal ``N`` the in-plane average ``sum_a (1 - N_a^2) g_a / 2``; 2D
        area and volume sets (purely volumetric) the mean of ``g_a``. The factors are
        constants of the reference configuration, so forces stay energy gradients."""
        from upscale.engine.state import State

        c0 = self.interior_particle()
        st = State.reference(self.system.x0, self.family.nb)
        ints = self._intact(st)
        amp = 1e-6
        n, d = self.system.n, self.dim
        x0 = self.system.x0
        fam = self._fam()
        self.correction = [None, None, None]
        g_out = [None, None, None]
        for t in (1, 2, 3):
            if not np.any(self.w[t - 1]):
                continue
            C = [0.0, 0.0, 0.0]; C[t - 1] = 1.0
            ga = np.ones((n, d))
            for a in range(d):
                e = np.zeros((3, 3)); e[a, a] = amp
                y = x0 + x0 @ e.T
                S = energy_forces(y, fam, self.triplets, self.quadruplets, self.w, C, ints,
                                  types=(t,))[0] / self.system.volume
                with np.errstate(divide="ignore", invalid="ignore"):
                    ga[:, a] = np.where(S > 0, S[c0] / S, 1.0)
            self.correction[t - 1] = ga
            if t == 1:
                nvec = self.family.xi[:, :d] / self.family.length[:, None]
                gi = ga[self.family.owner]
                g_out[0] = 1.0 / np.sqrt(np.sum(nvec ** 2 / gi ** 2, axis=1))
            elif t == 2:
                m = self.triplets.members(self.family)
                if d == 3:
                    N = np.cross(x0[m[:, 1]] - x0[m[:, 0]], x0[m[:, 2]] - x0[m[:, 0]])
                    N /= np.linalg.norm(N, axis=1)[:, None]
                    g_out[1] = np.sum((1.0 - N ** 2) * ga[m[:, 0]], axis=1) / 2.0
                else:
                    g_out[1] = ga[m[:, 0]].mean(axis=1)
            else:
                own = np.repeat(np.arange(n), self.quadruplets.counts)
                g_out[2] = ga[own].mean(axis=1)
        self.g = tuple(g_out)

    def interior_particle(self) -> int:
        """The particle with the most complete neighbourhood among the owners of sets
        (ties: closest to the centroid)."""
        own = np.ones(self.system.n, bool) if self.centres is None else np.isin(
            np.arange(self.system.n), self.centres)
        N1 = np.where(own, self.counts["pairs"], -1)
        cand = np.flatnonzero(N1 == N1.max())
        x = self.system.x0
        return int(cand[np.argmin(np.linalg.norm(x[cand] - x.mean(axis=0), axis=1))])

    def discrete_coefficients(self, centre: int | None = None) -> dict:
        """Coefficients ``l_k, m_k`` (Pa per unit C_k) of the discrete energy density of one
        interior particle: ``psi = sum_k C_k [l_k/2 (tr eps)^2 + m_k eps:eps]``, least-squares
        fit of the isotropic part over uniaxial, shear, dilatational and 24 random
        (rotation-invariant distribution) strains of amplitude 1e-6.
        Types without a family keep their continuum coefficients."""
        from upscale.engine.state import State

        c = self.interior_particle() if centre is None else int(centre)
        k = dict(modulus_coefficients(self.horizon, self.dim, self.thickness))
        d = self.dim
        strains = []
        for a in range(d):
            e = np.zeros((3, 3)); e[a, a] = 1.0; strains.append(e)
        for a in range(d):
            for b in range(a + 1, d):
                e = np.zeros((3, 3)); e[a, b] = e[b, a] = 0.5; strains.append(e)
        e = np.zeros((3, 3)); e[:d, :d] = np.eye(d); strains.append(e)
        rng = np.random.default_rng(12345)       # rotation-invariant (GOE) sample: the fit
        for _ in range(24):                        # approximates the isotropic projection
            g = np.zeros((3, 3)); g[:d, :d] = rng.standard_normal((d, d))
            strains.append(0.5 * (g + g.T))
        amp = 1e-6
        X = np.array([[0.5 * np.trace(e) ** 2, np.sum(e * e)] for e in strains]) * amp * amp
        wc = tuple(np.where(np.arange(self.system.n) == c, w, 0.0) for w in self.w)
        st = State.reference(self.system.x0, self.family.nb)
        ints = self._intact(st)
        fams = (True, self.triplets is not None, self.quadruplets is not None)
        for t in (1, 2, 3):
            if not fams[t - 1]:
                continue
            C = [0.0, 0.0, 0.0]; C[t - 1] = 1.0
            q = []
            for e in strains:
                y = self.system.x0 + amp * self.system.x0 @ e.T
                q.append(energy_forces(y, self._fam(), self.triplets, self.quadruplets, wc, C,
                                       ints, types=(t,), g=self.g)[0][c] / self.system.volume[c])
            if t == 3 or (t == 2 and d == 2):      # purely volumetric term: fit lambda only
                lt = float(np.linalg.lstsq(X[:, :1], np.array(q), rcond=None)[0][0])
                mt = 0.0
            else:
                lt, mt = (float(v) for v in np.linalg.lstsq(X, np.array(q), rcond=None)[0])
            k[f"l{t}"], k[f"m{t}"] = lt, mt
        return k

    def _fam(self):
        fam = self.family
        if not hasattr(self, "_fam_arrays"):
            f = types.SimpleNamespace()  # the family's own arrays (no copies) for the kernels
            f.offsets = fam.offsets
            f.neighbors = fam.neighbors
            f.x0 = np.ascontiguousarray(fam.x0, dtype=np.float64)
            f.q = self._q_b
            self._fam_arrays = f
        return self._fam_arrays

    @property
    def pattern(self):
        """Block-CSR sparsity pattern of the tangent (indptr, indices): all pairs within
        the reach of the interactions (twice the longest bond with multi-neighbour sets),
        or the exact member pattern when only some ``centres`` own interactions."""
        if self._pattern is None and self.centres is not None:
            self._pattern = multibody.member_pattern(self.family, self.centres)
        if self._pattern is None:
            reach = float(self.family.length.max()) * (1.0 + 1e-9)
            if self.needs.triplets or self.needs.quadruplets:
                reach *= 2.0
            self._pattern = multibody.block_pattern(self.system.x0, reach, dim=3)
        return self._pattern

    def init_state(self, state) -> None:
        state.extra["cpd_intact_t"] = np.ones(0 if self.triplets is None else self.triplets.size, bool)
        state.extra["cpd_intact_q"] = np.ones(0 if self.quadruplets is None else self.quadruplets.size, bool)

    def _intact(self, state):
        if "cpd_intact_t" not in state.extra:
            self.init_state(state)
        nt = 0 if self.triplets is None else self.triplets.size
        nq = 0 if self.quadruplets is None else self.quadruplets.size
        if state.extra["cpd_intact_t"].shape != (nt,) or state.extra["cpd_intact_q"].shape != (nq,):
            raise ValueError(f"state holds the set states of another CPD model "
                             f"({state.extra['cpd_intact_t'].size} triplets, "
                             f"{state.extra['cpd_intact_q'].size} quadruplets; this model has "
                             f"{nt}, {nq}): use one state per model or call init_state")
        if state.intact.shape != (self.family.nb,):
            raise ValueError(f"state.intact has {state.intact.size} bonds, the family {self.family.nb}")
        return (np.ascontiguousarray(state.intact, dtype=np.bool_), state.extra["cpd_intact_t"],
                state.extra["cpd_intact_q"])

    # ------------------------------------------------------------------ physics
    def energy_and_force(self, state):
        """(W_n (N,) in J per particle, F_int (N, 3) in N) on the current positions."""
        return energy_forces(state.y, self._fam(), self.triplets, self.quadruplets, self.w,
                             self.C, self._intact(state), g=self.g)

    def particle_force(self, state) -> np.ndarray:
        """Internal force per particle ``-dW/dy`` (N, 3) (N)."""
        return self.energy_and_force(state)[1]

    def add_force(self, state, out: np.ndarray) -> None:
        """Adds the force density ``F_int / V`` (N/m^3) to ``out`` (N, 3)."""
        out += self.particle_force(state) / self.system.volume[:, None]

    def energy_density(self, state) -> np.ndarray:
        """Point-wise stored energy density psi(x_i) (J/m^3), (N,)."""
        return self.energy_and_force(state)[0] / self.system.volume

    def energy(self, state) -> float:
        """Total stored energy W (J)."""
        return float(self.energy_and_force(state)[0].sum())

    def residual(self, state) -> np.ndarray:
        """``F_int`` flattened (3N,) (N)."""
        return self.particle_force(state).ravel()

    def tangent(self, state, *, types=(1, 2, 3), fmt: str = "csr"):
        """Consistent stiffness ``K = -dF_int/dy = d^2W/dy^2`` as scipy.sparse (3N, 3N)
        (N/m), CSR (``fmt="bsr"``: the 3x3 block matrix the kernels fill, no conversion);
        in 2D the out-of-plane rows and columns are zero."""
        K = tangent_bsr(state.y, self._fam(), self.triplets, self.quadruplets, self.w, self.C,
                        self._intact(state), self.pattern, self.dim, types=types, g=self.g)
        return K if fmt == "bsr" else K.tocsr()

    # ------------------------------------------------------------------ failure
    def break_bonds(self, state) -> int:
        """Mutates ``state.intact`` and the triplet/quadruplet states in ``state.extra``:
        applies the three critical stretches. Returns the number of bonds broken."""
        if self.s1c is None:
            return 0
        ib, it, iq = self._intact(state)
        f = self._fam()
        y = np.ascontiguousarray(state.y)
        nb = _break_pairs(y, f.offsets, f.neighbors, f.x0, self.s1c, ib)
        if self.triplets is not None:
            _break_triplets(y, f.offsets, f.neighbors, self.triplets.offsets, self.triplets.slot_j,
                            self.triplets.slot_k, self.triplets.area, self.s2c, ib, it)
        if self.quadruplets is not None:
            q = self.quadruplets
            _break_quads(y, f.offsets, f.neighbors, q.offsets, q.slot_j, q.slot_k, q.slot_l,
                         q.volume, self.s3c, ib, iq)
        if ib is not state.intact:
            state.intact[...] = ib
        return int(nb)

    def damage(self, state) -> dict:
        """Damage ``mu = 1 - R/T`` per particle (N,) for each interaction type."""
        ib, it, iq = self._intact(state)
        n = self.system.n
        out = {"pairs": 1.0 - np.bincount(self.family.owner, weights=ib, minlength=n)
               / np.maximum(self.counts["pairs"], 1)}
        for key, fam, st in (("triplets", self.triplets, it), ("quadruplets", self.quadruplets, iq)):
            if fam is not None:
                own = np.repeat(np.arange(n), fam.counts)
                out[key] = 1.0 - np.bincount(own, weights=st, minlength=n) / np.maximum(fam.counts, 1)
        return out

    # ------------------------------------------------------------------ stability
    def stiffness_bound(self) -> np.ndarray:
        """Gershgorin row bound per particle (N,) of ``|dF/dy| / V`` at the reference state
        (N/m^4, force-density units): the engine's stable step is ``2 sqrt(rho_i / R_i)``.
        Computed from the assembled consistent tangent, so it is exact as a bound."""
        from upscale.engine.state import State

        st = State.reference(self.system.x0, self.family.nb)
        K = self.tangent(st)
        rows = np.asarray(abs(K).sum(axis=1)).ravel().reshape(-1, 3).max(axis=1)
        return rows / self.system.volume

    def describe(self) -> dict:
        d = {"model": self.name, "horizon_m": self.horizon, "dim": self.dim,
             "C1_J_per_m7": self.C[0], "C2_J_per_m11": self.C[1], "C3_J_per_m15": self.C[2]}
        if self.E is not None:
            d.update(E_Pa=self.E, nu=self.nu, mode=self.mode, plane=self.plane if self.dim == 2 else None)
        if self.s1c is not None:
            d.update(s1c=self.s1c, s2c=self.s2c, s3c=self.s3c)
        return d


def _register():
    from upscale.models import register

    register("cpd", CPD)


_register()
