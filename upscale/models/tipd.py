"""Tensor-involved peridynamics (Ti-PD): a bond-based model whose micromodulus carries the
full elastic tensor (seed 003, Tian; 2D eqs. (33)-(48), 3D eqs. (79)-(83)).

Array suffixes: ``_n`` per particle, ``_b`` per directed bond, ``_c`` Cartesian component.

Bond force
----------
For a bond i->j with reference vector ``xi`` and relative displacement
``eta = u_j - u_i`` the force density is linear in eta (eqs. (33), (79))::

    f_ij = M(xi) eta,   M_pq(xi) = Dhat_pq,ab xi_a xi_b / |xi|^3        (d x d, symmetric)
    b_i  = sum_j f_ij V_j beta_ij                                        (N/m^3)

so the assembled stiffness is symmetric and a static solve is one sparse symmetric solve.
The induced tensor ``Dhat`` is built from the symmetrised elastic tensor
``S_paqb = (C_paqb + C_pbqa)/2`` (C the fourth-order elastic tensor, Pa) in the compact
form that reproduces the paper's Voigt matrix (47) and its 3D analogue::

    2D:  Dhat_pq,ab = (12 S_paqb - 3 delta_ab S_pcqc) / (pi delta^3 h)
    3D:  Dhat_pq,ab = (15 S_paqb - 3 delta_ab S_pcqc) / (pi delta^4)

It makes the second moment exact in the continuum: ``(1/2) int M xi_a xi_b dV = S_paqb``
over the horizon, hence the local limit (55)/(92) ``L u -> div(C : eps)``.

Calibration
-----------
``calibration="continuum"`` uses the integral above (the paper's). ``"discrete"`` solves
``(1/2) sum_j M(xi_j) xi_a xi_b V_j beta_j = S`` on the family of the most complete (bulk)
particle: with the discrete fourth moment ``Q_abcd = sum_j xi_a xi_b xi_c xi_d / |xi|^3
V_j beta_j`` (inverted on symmetric pairs) ``Dhat_pq = 2 S_p.q. Q^-1``. At a fixed ratio
delta/dx the continuum calibration carries the quadrature bias of the lattice (several per
cent at delta = 3 dx) and the error stops decreasing with dx; the discrete one does not.

What a user must know (not in the paper)
----------------------------------------
In the local limit the Ti-PD energy is the elastic energy of C plus
``(D66 - D12)/2 det(grad u)`` (2D; an analogous null Lagrangian in 3D). The bulk
equations are right but free boundaries are not: a free strip in tension shows an apparent
Poisson ratio different from the input unless D12 = D66. Rigid rotations store energy
unless D12 = D66, bond forces are not along the bond, and the free-body stiffness is
indefinite when ``S`` (as a quadratic form on all d x d displacement gradients) has a
negative eigenvalue: isotropic 2D plane stress for nu > 1/3, plane strain and 3D for
nu > 1/4. :class:`TiPD` warns (:class:`IndefiniteWarning`) when that happens without the
surface correction below (with it the free-surface traction is that of C and a body held
at one end is positive definite for these materials too). Ti-PD equals bond-based PD (PMB) when D12 = D66 (nu = 1/3 plane stress, 1/4 plane strain
and 3D; eqs. (50)-(51)).

Surface correction (``surface="correspondence"``, not in the paper; the default without failure)
------------------------------------------------------------------------------------------------
The traction a pair model carries across any cut is ``S : H n``, not ``C : H n``: no
micromodulus, however position-dependent, fixes the free-surface error, because a pair
force cannot carry the part ``(C - S)`` of C that breaks the Cauchy relation. The correction
adds that part as a correspondence energy on the nonlocal gradient
``H_i = sum_j w (u_j - u_i) (x) xi K_i^-1`` (w = V_j beta, ``K_i = sum_j w xi (x) xi``)::

    E = E_TiPD + sum_i V_i (1/2) H_i : Delta_i : H_i,   Delta_i = C - S_i^lat,
    S_i^lat = (1/2) sum_j M_ij xi (x) xi V_j beta      (indexed [p, a, q, b])

``S_i^lat`` is the tensor particle i's own (possibly truncated) family carries, so for
every homogeneous gradient the energy density of every particle, surface ones included,
is exactly ``(1/2) eps : C : eps`` (and a rigid rotation costs none). In the bulk ``Delta``
is uniform and (for the discrete calibration) the null-Lagrangian part ``C - S``, whose
energy vanishes on every plane wave: the bulk equations are Ti-PD's; with the continuum
calibration Delta also removes its lattice bias. Forces are the linear correspondence
force ``b_i = sum_j w (Q_i + Q_j) xi``, ``Q_i = (Delta_i : H_i) K_i^-1``, coupling
particles 2 delta apart; the stiffness stays symmetric. Costs: a correspondence pass per
force evaluation and a denser stiffness. Caveats: the free body is slightly indefinite
(a rotation costs no energy but is not force-free; a body held at one end is positive
definite, also for the materials that make the uncorrected model indefinite); layers of
prescribed displacement must be two horizons wide (or be declared with ``surface_bulk``
and be two horizons wide) for the gradients that reach free particles to be built on full
families, else the error is first order in dx; and the correction is elastic (a failure
criterion leaves it off, since H is built on all bonds).

Default: ``surface=None`` means "correspondence" for an elastic model and "none" (the
paper's model) with a failure criterion. The correction is the default because the pair
model alone carries the wrong traction ``S : H n`` at every free surface (apparent Poisson
ratio (1 + nu)/4 in 2D plane stress, whatever the input nu) and stores energy in rigid
rotations; with it the bulk equations are unchanged (discrete calibration) or freed of the
lattice bias (continuum calibration). ``surface="none"`` is the paper's model, e.g. for
its identity with PMB at D12 = D66.

Failure
-------
Damage (56)-(58): a bond breaks for good when its stretch ``s = (|y_j - y_i| - |xi|)/|xi|``
exceeds s0; ``phi_i = 1 - (sum_intact V_j)/(sum V_j)``. Critical stretch from the
fracture energy G0 (J/m^2), isotropic materials:

=====================  =============================================  ==============================================
``critical``           2D                                             3D
=====================  =============================================  ==============================================
``"tipd"`` (default)   (60) s0 = sqrt(8 pi G0 (1-nu^2)/(3 E delta (5+nu)))  (94) s0 = sqrt(10 G0 (1-2nu)(1+nu)/(3 E delta (3-2nu)))
``"osb"``              (62) s0 = sqrt(G0/((6G/pi + 16/(9pi^2)(k-2G)) delta))  (96) s0 = sqrt(G0/((3G + (3/4)^4 (K-5G/3)) delta))
=====================  =============================================  ==============================================

(61)/(95) are the bond-based limits of (60)/(94). For an anisotropic material (Remark 4:
no criterion in the paper) ``"tipd"`` uses the direction mean of the bond stiffness
``xi.M xi / |xi|`` in the bond-based relation ``G0 = c s0^2 h delta^4 / 4`` (2D) or
``G0 = pi c s0^2 delta^5 / 10`` (3D), which is (60)/(94) for isotropic materials.

Voigt order: 2D ``(11, 22, 12)``; 3D ``(11, 22, 33, 23, 13, 12)`` (``order="standard"``) or
the paper's ``(11, 22, 33, 12, 23, 13)`` (``order="tian"``, its eqs. (8)-(9) and (98)).
"""
from __future__ import annotations

import warnings

import numba as nb
import numpy as np

from upscale.engine.kernels import add_to_row
from upscale.models import register
from upscale.models.base import Model, Needs

__all__ = ["TiPD", "IndefiniteWarning", "voigt_to_tensor", "tensor_to_voigt", "isotropic_voigt",
           "orthotropic_voigt_2d", "rotate_tensor", "symmetrised_tensor", "induced_tensor",
           "paper_induced_voigt_2d", "appendix_a_stiffness", "appendix_b_stiffness", "indefiniteness",
           "tipd_critical_stretch", "surface_stress_kernel", "default_surface"]


class IndefiniteWarning(UserWarning):
    """The material makes the Ti-PD free-body stiffness indefinite."""


# ---------------------------------------------------------------------------- tensors
# pairs (or bonds) per block where per-bond matrices are formed (bounds the temporaries)
_PAIR_BLOCK = 1 << 20

_VOIGT = {2: {"standard": [(0, 0), (1, 1), (0, 1)]},
          3: {"standard": [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)],
              "tian": [(0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (0, 2)]}}
_VOIGT[2]["tian"] = _VOIGT[2]["standard"]


def voigt_to_tensor(D, order: str = "standard") -> np.ndarray:
    """Fourth-order elastic tensor C (d, d, d, d) (Pa) from a Voigt stiffness matrix.

    Parameters
    ----------
    D : array (3, 3) (2D) or (6, 6) (3D)
        Voigt stiffness ``sigma = D eps`` with engineering shear strains.
    order : {"standard", "tian"}
        3D Voigt order: (11, 22, 33, 23, 13, 12) or the paper's (11, 22, 33, 12, 23, 13).

    Raises
    ------
    ValueError
        wrong shape, not symmetric, not positive definite, unknown order.
    """
    D = np.asarray(D, dtype=np.float64)
    if D.shape not in ((3, 3), (6, 6)):
        raise ValueError(f"Voigt stiffness must be 3x3 (2D) or 6x6 (3D), got shape {D.shape}")
    d = 2 if D.shape == (3, 3) else 3
    if order not in _VOIGT[d]:
        raise ValueError(f"unknown Voigt order {order!r}; valid: 'standard', 'tian'")
    if not np.all(np.isfinite(D)):
        raise ValueError("Voigt stiffness has non-finite entries")
    if not np.allclose(D, D.T, rtol=1e-12, atol=1e-12 * np.abs(D).max()):
        raise ValueError("Voigt stiffness must be symmetric (D_ij = D_ji)")
    ev = np.linalg.eigvalsh(D)
    if ev.min() <= 0:
        raise ValueError(f"elastic stiffness matrix is not positive definite (smallest eigenvalue "
                         f"{ev.min():.6g} Pa); a stable material needs all eigenvalues > 0")
    pairs = _VOIGT[d][order]
    C = np.zeros((d,) * 4)
    for I, (i, j) in enumerate(pairs):
        for J, (k, l) in enumerate(pairs):
            for a, b in {(i, j), (j, i)}:
                for c, e in {(k, l), (l, k)}:
                    C[a, b, c, e] = D[I, J]
    return C


def tensor_to_voigt(C, order: str = "standard") -> np.ndarray:
    """Voigt stiffness (3, 3) or (6, 6) of a fourth-order tensor with minor symmetries."""
    C = np.asarray(C, dtype=np.float64)
    d = C.shape[0]
    pairs = _VOIGT[d][order]
    return np.array([[C[i, j, k, l] for (k, l) in pairs] for (i, j) in pairs])


def isotropic_voigt(E: float, nu: float, dim: int, plane: str = "stress") -> np.ndarray:
    """Isotropic Voigt stiffness (Pa): 2D plane stress/strain (3, 3) or 3D (6, 6).

    Raises ``ValueError`` for E <= 0 or nu outside (-1, 1/2) (plane stress: (-1, 1))."""
    if not (np.isfinite(E) and E > 0):
        raise ValueError(f"Young's modulus must be positive, got {E!r}")
    hi = 1.0 if (dim == 2 and plane == "stress") else 0.5
    if not (np.isfinite(nu) and -1.0 < nu < hi):
        raise ValueError(f"Poisson ratio {nu!r} outside the isotropic range (-1, {hi:g})"
                         + ("" if hi == 1.0 else " for plane strain / 3D"))
    G = E / (2 * (1 + nu))
    if dim == 2:
        if plane == "stress":
            a, b = E / (1 - nu * nu), E * nu / (1 - nu * nu)
        else:
            a = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
            b = E * nu / ((1 + nu) * (1 - 2 * nu))
        return np.array([[a, b, 0], [b, a, 0], [0, 0, G]])
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    D = np.zeros((6, 6))
    D[:3, :3] = lam
    D[[0, 1, 2], [0, 1, 2]] = lam + 2 * G
    D[[3, 4, 5], [3, 4, 5]] = G
    return D


def orthotropic_voigt_2d(E1: float, E2: float, G12: float, nu12: float) -> np.ndarray:
    """Plane-stress orthotropic Voigt stiffness (eq. (99)), fibre axis 1 (Pa).

    The reciprocity relation is read the standard way, ``nu21 = nu12 E2 / E1``, so
    ``Q11 = E1/(1 - nu12 nu21)``, ``Q12 = nu12 E2/(1 - nu12 nu21)``, ``Q22 = E2/(1 - nu12
    nu21)``, ``Q66 = G12``. Raises ``ValueError`` when ``nu12^2 >= E1/E2`` (not positive
    definite)."""
    for k, v in (("E1", E1), ("E2", E2), ("G12", G12)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{k} must be positive, got {v!r}")
    nu21 = nu12 * E2 / E1
    den = 1.0 - nu12 * nu21
    if not den > 0:
        raise ValueError(f"Poisson ratio nu12 = {nu12!r} outside the material's range: "
                         f"|nu12| < sqrt(E1/E2) = {np.sqrt(E1 / E2):.6g}")
    return np.array([[E1 / den, nu12 * E2 / den, 0], [nu12 * E2 / den, E2 / den, 0], [0, 0, G12]])


def rotation_matrix(angle=None, axes=None, dim: int = 2) -> np.ndarray:
    """Rotation R (d, d) from material to global axes: 2D ``angle`` (rad, counter-clockwise
    from x to the material axis 1), 3D ``axes`` (3, 3) with the material axes as columns
    (orthonormalised check) or ``angle`` about z. Raises ``ValueError`` for a non-finite
    angle or axes that are not a rotation."""
    if axes is not None:
        R = np.asarray(axes, dtype=np.float64)
        if R.shape != (dim, dim) or not np.all(np.isfinite(R)):
            raise ValueError(f"material axes must be a finite ({dim}, {dim}) matrix, got {R.shape}")
        if not np.allclose(R.T @ R, np.eye(dim), atol=1e-10) or np.linalg.det(R) < 0:
            raise ValueError("material axes must be orthonormal and right-handed (a rotation)")
        return R
    a = 0.0 if angle is None else angle
    if not np.isfinite(a):
        raise ValueError(f"material-axis angle must be finite (radians), got {angle!r}")
    c, s = np.cos(a), np.sin(a)
    if dim == 2:
        return np.array([[c, -s], [s, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rotate_tensor(C, R) -> np.ndarray:
    """C'_ijkl = R_ia R_jb R_kc R_ld C_abcd (material -> global axes)."""
    return np.einsum("ia,jb,kc,ld,abcd->ijkl", R, R, R, R, C)


def symmetrised_tensor(C) -> np.ndarray:
    """S_paqb = (C_paqb + C_pbqa)/2 (the part of C that a pair potential can carry)."""
    return 0.5 * (C + C.transpose(0, 3, 2, 1))


def induced_tensor(C) -> np.ndarray:
    """Continuum-calibrated induced tensor without its normalisation (Pa):
    ``12 S_paqb - 3 delta_ab S_pcqc`` (2D) or ``15 S - 3 delta S_pcqc`` (3D), shape
    (d, d, d, d) indexed ``[p, q, a, b]``; divide by ``pi delta^3 h`` (2D) or
    ``pi delta^4`` (3D)."""
    d = C.shape[0]
    S = symmetrised_tensor(C)
    Sqq = np.einsum("pcqc->pq", S)
    k = 12.0 if d == 2 else 15.0
    return k * S.transpose(0, 2, 1, 3) - 3.0 * np.einsum("ab,pq->pqab", np.eye(d), Sqq)


def paper_induced_voigt_2d(D) -> np.ndarray:
    """The paper's Voigt form (47) of the 2D induced tensor, rows kappa_11, kappa_22,
    kappa_12 and columns lambda_11, lambda_22, 2 lambda_12 (as printed; Pa)."""
    D11, D12, D16 = D[0, 0], D[0, 1], D[0, 2]
    D22, D26, D66 = D[1, 1], D[1, 2], D[2, 2]
    return np.array([[9 * D11 - 3 * D66, 9 * D66 - 3 * D11, 12 * D16],
                     [9 * D66 - 3 * D22, 9 * D22 - 3 * D66, 12 * D26],
                     [9 * D16 - 3 * D26, 9 * D26 - 3 * D16, 6 * (D12 + D66)]])


def indefiniteness(C) -> dict:
    """Eigenvalues of the symmetrised tensor S as a quadratic form on all d x d
    displacement gradients H (``W = H_pa S_paqb H_qb / 2``, the local-limit Ti-PD energy
    density of a homogeneous body). A negative eigenvalue makes the free-body stiffness
    indefinite; zero ones are modes that store no energy (rigid rotation when
    D12 = D66). Returns ``{"eigenvalues": ..., "min": ..., "indefinite": bool}``."""
    d = C.shape[0]
    S = symmetrised_tensor(C).reshape(d * d, d * d)
    ev = np.linalg.eigvalsh(0.5 * (S + S.T))
    scale = np.abs(ev).max()
    return {"eigenvalues": ev, "min": float(ev.min()),
            "indefinite": bool(ev.min() < -1e-12 * scale)}


def tipd_critical_stretch(G0: float, E: float, nu: float, horizon: float, dim: int, *,
                          rule: str = "tipd", plane: str = "stress") -> float:
    """Critical stretch of an isotropic material: (60)/(94) (``rule="tipd"``) or the
    ordinary state-based (62)/(96) (``"osb"``); G0 in J/m^2, E in Pa, horizon in m."""
    d = float(horizon)
    if rule == "tipd":
        if dim == 2:
            return float(np.sqrt(8 * np.pi * G0 * (1 - nu * nu) / (3 * E * d * (5 + nu))))
        return float(np.sqrt(10 * G0 * (1 - 2 * nu) * (1 + nu) / (3 * E * d * (3 - 2 * nu))))
    if rule == "osb":
        G = E / (2 * (1 + nu))
        if dim == 2:
            k = E / (2 * (1 - nu)) if plane == "stress" else E / (2 * (1 + nu) * (1 - 2 * nu))
            return float(np.sqrt(G0 / ((6 * G / np.pi + 16 / (9 * np.pi ** 2) * (k - 2 * G)) * d)))
        K = E / (3 * (1 - 2 * nu))
        return float(np.sqrt(G0 / ((3 * G + 0.75 ** 4 * (K - 5 * G / 3)) * d)))
    raise ValueError(f"unknown critical-stretch rule {rule!r}; valid: 'tipd', 'osb'")


# ---------------------------------------------------------------------------- kernels
@nb.njit(parallel=True, cache=True)
def tipd_force_kernel_2d(offsets, neighbors, q_bc, A, u_nc, y_nc, intact_b, rc2_b, fail, out_nc):
    """Adds Ti-PD force densities (2D) to ``out_nc``: ``b_i = sum_j M_b eta_b`` with
    ``eta_b = u_j - u_i`` (``u_nc = y - x0``), ``M_pq = A[p,q,a,b] q_a q_b``,
    ``q_b = xi sqrt(V_j beta / |xi|^3)`` and ``A`` the normalised induced tensor (4, 4)
    flattened ``[2p+q, 2a+b]``. If ``fail``, mutates ``intact_b``: a bond whose squared
    current length (from ``y_nc``) exceeds ``rc2_b`` breaks after its force is counted.
    Returns the number of directed bonds broken."""
    n = offsets.shape[0] - 1
    broke = np.zeros(n, dtype=np.int64)
    # M11 = A00 qx^2 + 2 A01 qx qy + A03 qy^2, etc. (A[pq, ab], symmetric in ab)
    m11a, m11b, m11c = A[0, 0], 2.0 * A[0, 1], A[0, 3]
    m12a, m12b, m12c = A[1, 0], 2.0 * A[1, 1], A[1, 3]
    m22a, m22b, m22c = A[3, 0], 2.0 * A[3, 1], A[3, 3]
    for i in nb.prange(n):
        f0 = 0.0
        f1 = 0.0
        ui0 = u_nc[i, 0]
        ui1 = u_nc[i, 1]
        k = 0
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            j = neighbors[b]
            e0 = u_nc[j, 0] - ui0
            e1 = u_nc[j, 1] - ui1
            qx = q_bc[b, 0]
            qy = q_bc[b, 1]
            xx = qx * qx
            xy = qx * qy
            yy = qy * qy
            M11 = m11a * xx + m11b * xy + m11c * yy
            M12 = m12a * xx + m12b * xy + m12c * yy
            M22 = m22a * xx + m22b * xy + m22c * yy
            f0 += M11 * e0 + M12 * e1
            f1 += M12 * e0 + M22 * e1
            if fail:
                d0 = y_nc[j, 0] - y_nc[i, 0]
                d1 = y_nc[j, 1] - y_nc[i, 1]
                d2 = y_nc[j, 2] - y_nc[i, 2]
                if d0 * d0 + d1 * d1 + d2 * d2 > rc2_b[b]:
                    intact_b[b] = False
                    k += 1
        add_to_row(out_nc, i, f0, f1, 0.0)
        broke[i] = k
    return broke.sum()


@nb.njit(parallel=True, cache=True)
def tipd_force_kernel_3d(offsets, neighbors, q_bc, A, u_nc, y_nc, intact_b, rc2_b, fail, out_nc):
    """3D analogue of :func:`tipd_force_kernel_2d`; ``A`` (9, 9) flattened
    ``[3p+q, 3a+b]``."""
    n = offsets.shape[0] - 1
    broke = np.zeros(n, dtype=np.int64)
    for i in nb.prange(n):
        f = np.zeros(3)
        e = np.zeros(3)
        qq = np.zeros(9)
        k = 0
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            j = neighbors[b]
            rsq = 0.0
            for c in range(3):
                e[c] = u_nc[j, c] - u_nc[i, c]
                if fail:
                    dc = y_nc[j, c] - y_nc[i, c]
                    rsq += dc * dc
            for a in range(3):
                for c in range(3):
                    qq[3 * a + c] = q_bc[b, a] * q_bc[b, c]
            for p in range(3):
                acc = 0.0
                for r in range(3):
                    m = 0.0
                    row = 3 * p + r
                    for ab in range(9):
                        m += A[row, ab] * qq[ab]
                    acc += m * e[r]
                f[p] += acc
            if fail and rsq > rc2_b[b]:
                intact_b[b] = False
                k += 1
        add_to_row(out_nc, i, f[0], f[1], f[2])
        broke[i] = k
    return broke.sum()


@nb.njit(cache=True)
def _tipd_pair_chunk(i0, i1, poff, pj, pb, prb, K_p, u_nc, y_nc, intact_b, rc2_p, fail, check,
                     buf, d):
    """Pairs of the particles i0 <= i < i1 (as first end) of :func:`tipd_pair_force` into
    one thread's buffer (zeroed here; i's sum kept in registers, j's scattered); returns
    the bonds broken. ``check`` False: every bond is intact (the bond state is not read)."""
    buf[:, :] = 0.0
    k = 0
    for i in range(i0, i1):
        ui0 = u_nc[i, 0]
        ui1 = u_nc[i, 1]
        ui2 = u_nc[i, 2]
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for p in range(poff[i], poff[i + 1]):
            fi = True
            fj = True
            if check:
                b = pb[p]
                rb = prb[p]
                fi = intact_b[b]
                fj = intact_b[rb]
                if not (fi or fj):
                    continue
            j = pj[p]
            e0 = u_nc[j, 0] - ui0
            e1 = u_nc[j, 1] - ui1
            if d == 2:
                k12 = K_p[p, 1]
                g0 = K_p[p, 0] * e0 + k12 * e1
                g1 = k12 * e0 + K_p[p, 2] * e1
                g2 = 0.0
            else:
                e2 = u_nc[j, 2] - ui2
                k23 = K_p[p, 3]
                k13 = K_p[p, 4]
                k12 = K_p[p, 5]
                g0 = K_p[p, 0] * e0 + k12 * e1 + k13 * e2
                g1 = k12 * e0 + K_p[p, 1] * e1 + k23 * e2
                g2 = k13 * e0 + k23 * e1 + K_p[p, 2] * e2
            if fi:
                s0 += g0
                s1 += g1
                s2 += g2
            if fj:
                buf[j, 0] -= g0
                buf[j, 1] -= g1
                if d == 3:
                    buf[j, 2] -= g2
            if fail:
                d0 = y_nc[j, 0] - y_nc[i, 0]
                d1 = y_nc[j, 1] - y_nc[i, 1]
                d2 = y_nc[j, 2] - y_nc[i, 2]
                if d0 * d0 + d1 * d1 + d2 * d2 > rc2_p[p]:
                    if fi:
                        intact_b[pb[p]] = False
                        k += 1
                    if fj:
                        intact_b[prb[p]] = False
                        k += 1
        buf[i, 0] += s0
        buf[i, 1] += s1
        if d == 3:
            buf[i, 2] += s2
    return k


@nb.njit(parallel=True, cache=True)
def tipd_pair_force(bounds, poff, pj, pb, prb, K_p, u_nc, y_nc, intact_b, rc2_p, fail, check,
                    buf_tnc, d):
    """Pair form of the Ti-PD force: for each pair i < j with ``eta = u_j - u_i``,
    ``g = K_p eta`` (``K_p = V_i M_ij = V_j M_ji``, N/m, symmetric d x d stored as
    (K11, K12, K22) in 2D, (K11, K22, K33, K23, K13, K12) in 3D) is added to ``buf[t, i]``
    if the bond i->j is intact and subtracted from ``buf[t, j]`` if j->i is; thread t takes
    the particles ``bounds[t] <= i < bounds[t+1]`` into its private buffer ``buf_tnc[t]``
    (T, N, d), zeroed here (sum them with :func:`upscale.engine.pairs.reduce_buffers`, scale
    1/V for densities). If ``fail``, mutates ``intact_b``: both directions break when the
    squared current length exceeds ``rc2_p``, after the force is counted. ``check`` False
    skips reading the bond state (the caller knows that every bond is intact and ``fail``
    is False). Returns the number of directed bonds broken."""
    nt = buf_tnc.shape[0]
    broke = np.zeros(nt, dtype=np.int64)
    for t in nb.prange(nt):
        broke[t] = _tipd_pair_chunk(bounds[t], bounds[t + 1], poff, pj, pb, prb, K_p, u_nc,
                                    y_nc, intact_b, rc2_p, fail, check, buf_tnc[t], d)
    return broke.sum()


@nb.njit(parallel=True, cache=True)
def tipd_energy_kernel(offsets, neighbors, q_bc, A, x_nc, y_nc, intact_b, d):
    """W_i = (1/4) sum_j eta.M eta (J/m^3), half of each bond's energy to each end."""
    n = offsets.shape[0] - 1
    W = np.zeros(n)
    for i in nb.prange(n):
        acc = 0.0
        e = np.zeros(3)
        for b in range(offsets[i], offsets[i + 1]):
            if not intact_b[b]:
                continue
            j = neighbors[b]
            for c in range(d):
                e[c] = (y_nc[j, c] - y_nc[i, c]) - (x_nc[j, c] - x_nc[i, c])
            for p in range(d):
                for r in range(d):
                    m = 0.0
                    for a in range(d):
                        for c in range(d):
                            m += A[d * p + r, d * a + c] * q_bc[b, a] * q_bc[b, c]
                    acc += e[p] * m * e[r]
        W[i] = 0.25 * acc
    return W


# ---------------------------------------------------------------------------- appendix A
def appendix_a_stiffness(system, family, D, *, literal: bool = False):
    """The 2D stiffness ``A`` of Appendix A (``rho u'' = A u``, (48)) entry by entry as
    printed (``literal=True``) or with its typos corrected (``False``): the coefficients
    of A_{2p-1,2q} are ``3(3 D16 - D26)`` (dx^2) and ``3(3 D26 - D16)`` (dy^2), and of
    A_{2p,2q} ``3(3 D66 - D22)`` (dx^2); the paper prints ``3(D11 - 3 D26)``,
    ``3(D26 - 3 D16)`` and ``3(3 D66 - D26)``. Rows are force densities (N/m^3) per
    displacement (m), dofs (x, y) per particle: scipy.sparse (2N, 2N). For comparison with
    :meth:`TiPD.tangent` (``K = -V A``)."""
    D = np.asarray(D, dtype=np.float64)
    D11, D12, D16 = D[0, 0], D[0, 1], D[0, 2]
    D22, D26, D66 = D[1, 1], D[1, 2], D[2, 2]
    h = system.thickness
    dx, dy = family.xi[:, 0], family.xi[:, 1]
    w = system.volume[family.neighbors] * family.volume_factor
    den = np.pi * family.horizon ** 3 * h * family.length ** 3
    a11 = (3 * (3 * D11 - D66) * dx ** 2 + 3 * (3 * D66 - D11) * dy ** 2 + 24 * D16 * dx * dy)
    if literal:
        a12 = 3 * (D11 - 3 * D26) * dx ** 2 + 12 * (D12 + D66) * dx * dy + 3 * (D26 - 3 * D16) * dy ** 2
        a22 = 3 * (3 * D66 - D26) * dx ** 2 + 3 * (3 * D22 - D66) * dy ** 2 + 24 * D26 * dx * dy
    else:
        a12 = 3 * (3 * D16 - D26) * dx ** 2 + 12 * (D12 + D66) * dx * dy + 3 * (3 * D26 - D16) * dy ** 2
        a22 = 3 * (3 * D66 - D22) * dx ** 2 + 3 * (3 * D22 - D66) * dy ** 2 + 24 * D26 * dx * dy
    return _assemble_pair_blocks(system, family, {(0, 0): a11, (0, 1): a12, (1, 1): a22}, w / den, 2)


def _assemble_pair_blocks(system, family, blocks, scale, d):
    """scipy.sparse (dN, dN) of a pair stiffness given per directed bond: block (r, c) of
    the bond's matrix is ``blocks[(r, c)] * scale`` (the lower blocks mirror the upper),
    entered at (i, j) and, negated, at (i, i): ``A u`` is then sum_j M (u_j - u_i)."""
    import scipy.sparse as sp

    i, j = family.owner, family.neighbors
    n = system.n
    rows, cols, vals = [], [], []
    for (r, c), a in blocks.items():
        v = a * scale
        for rr, cc in {(r, c), (c, r)}:
            rows += [d * i + rr, d * i + rr]
            cols += [d * j + cc, d * i + cc]
            vals += [v, -v]
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(d * n, d * n))


# Appendix B's own Voigt order, read off its entries (e.g. the dz^2 coefficient of
# A_{3p-2,3q-2} is 4 D55 - D11 - D44, so 5 is 13): (11, 22, 33, 12, 13, 23), which is
# neither the standard order nor the (11, 22, 33, 12, 23, 13) of the paper's (8)-(9), (98).
_APPENDIX_B_ORDER = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]


def appendix_b_stiffness(system, family, C, *, literal: bool = False):
    """The 3D stiffness ``A`` of Appendix B (``rho u'' = A u``) entry by entry, from the
    elastic tensor ``C`` (3, 3, 3, 3) (Pa; e.g. :func:`voigt_to_tensor`), written in
    Appendix B's Voigt order (11, 22, 33, 12, 13, 23) (``_APPENDIX_B_ORDER``). For p != q

    ``A_{xx} = [3(4D11-D44-D55) dx^2 + 3(4D44-D11-D55) dy^2 + 3(4D55-D11-D44) dz^2
    + 30 D14 dx dy + 30 D15 dx dz + 30 D45 dy dz] V_q / (pi delta^4 |xi|^3)``

    and likewise the five other blocks (xy, xz, yy, yz, zz); the diagonal blocks are minus
    the row sums. As printed (``literal=True``) the dz^2 is missing from the third term of
    every block but A_xx (the term stands alone); corrected (default) it is there, and then
    ``A`` equals the stiffness of :func:`induced_tensor`'s compact form. (The printed p = q
    line of A_{3p,3q} sums A_{3p-1,3q}: a typo not reproduced; both forms use the row sum.)
    Rows are force densities (N/m^3) per displacement (m), dofs (x, y, z) per particle:
    scipy.sparse (3N, 3N). For comparison with :meth:`TiPD.tangent` (``K = -V A``)."""
    C = np.asarray(C, dtype=np.float64)
    if C.shape != (3, 3, 3, 3):
        raise ValueError(f"Appendix B needs the 3D elastic tensor C (3, 3, 3, 3), got shape {C.shape}")
    P = _APPENDIX_B_ORDER
    D = {(I + 1) * 10 + (J + 1): C[P[I] + P[J]] for I in range(6) for J in range(6)}
    dx, dy, dz = family.xi[:, 0], family.xi[:, 1], family.xi[:, 2]
    z2 = np.ones_like(dz) if literal else dz ** 2

    def block(a, b, c, same, xy, xz, yz):
        """3(4a-b-c) dx^2 + 3(4b-a-c) dy^2 + 3(4c-a-b) dz^2 + cross terms."""
        return (3 * (4 * a - b - c) * dx ** 2 + 3 * (4 * b - a - c) * dy ** 2 + 3 * (4 * c - a - b) * same
                + xy * dx * dy + xz * dx * dz + yz * dy * dz)

    a_xx = block(D[11], D[44], D[55], dz ** 2, 30 * D[14], 30 * D[15], 30 * D[45])
    a_xz = block(D[15], D[46], D[35], z2, 15 * (D[16] + D[45]), 15 * (D[13] + D[55]), 15 * (D[34] + D[56]))
    a_xy = block(D[14], D[24], D[56], z2, 15 * (D[12] + D[44]), 15 * (D[16] + D[45]), 15 * (D[46] + D[25]))
    a_yy = block(D[44], D[22], D[66], z2, 30 * D[24], 30 * D[46], 30 * D[26])
    a_yz = block(D[45], D[26], D[36], z2, 15 * (D[46] + D[25]), 15 * (D[34] + D[56]), 15 * (D[23] + D[66]))
    a_zz = block(D[55], D[66], D[33], z2, 30 * D[56], 30 * D[35], 30 * D[36])
    w = system.volume[family.neighbors] * family.volume_factor
    den = np.pi * family.horizon ** 4 * family.length ** 3
    return _assemble_pair_blocks(system, family, {(0, 0): a_xx, (0, 1): a_xy, (0, 2): a_xz, (1, 1): a_yy,
                                                  (1, 2): a_yz, (2, 2): a_zz}, w / den, 3)


# ---------------------------------------------------------------------------- model
def _sym_pairs_inverse(Q, d):
    """Inverse of the fully symmetric fourth moment Q (d,d,d,d) on symmetric pairs:
    returns P (d,d,d,d) with ``Q_abcd P_cdef = sym_abef`` (identity on symmetric pairs)."""
    Qm = Q.reshape(d * d, d * d)
    return np.linalg.pinv(Qm, rcond=1e-12, hermitian=True).reshape(d, d, d, d)


@nb.njit(parallel=True, cache=True)
def surface_stress_kernel(H_nk, Delta_nkk, Kinv_n, d, Q_nk):
    """Surface correction's ``Q_i = (Delta_i : H_i) K_i^-1`` per particle. ``H_nk``: the
    gradients as rows of d*d (2D) or 9 (3D, a (N, 3, 3) view) entries ``[p, a]``;
    ``Delta_nkk`` (N, d*d, d*d) with row ``p d + a`` and column ``q d + b``; ``Kinv_n``
    (N, 3, 3); ``Q_nk`` laid out as ``H_nk``."""
    n = H_nk.shape[0]
    st = 2 if d == 2 else 3                     # row stride of the (p, a) layout
    for i in nb.prange(n):
        P = np.zeros((3, 3))
        for p in range(d):
            for a in range(d):
                v = 0.0
                for q in range(d):
                    for b in range(d):
                        v += Delta_nkk[i, p * d + a, q * d + b] * H_nk[i, q * st + b]
                P[p, a] = v
        for p in range(d):
            for a in range(d):
                v = 0.0
                for c in range(d):
                    v += P[p, c] * Kinv_n[i, c, a]
                Q_nk[i, p * st + a] = v


def default_surface(failure: bool) -> str:
    """The surface correction :class:`TiPD` uses when none is given: "correspondence" for
    an elastic model, "none" with a failure criterion (the correction is elastic)."""
    return "none" if failure else "correspondence"


class TiPD(Model):
    """Tensor-involved peridynamics (seed 003), 2D (plane stress/strain) and 3D; see the
    module docstring for the equations.

    Parameters
    ----------
    C : array (3, 3) / (6, 6) Voigt, or (d, d, d, d) tensor, optional
        Elastic stiffness in the material axes (Pa). Or give ``E`` and ``nu`` (isotropic).
    E, nu : float, optional
        Isotropic Young's modulus (Pa) and Poisson ratio (the plane of the body decides
        plane stress / strain).
    order : {"standard", "tian"}
        3D Voigt order of ``C`` (module docstring).
    angle : float, optional
        Material axis 1 relative to x (rad, about z). ``axes`` (3, 3): material axes as
        columns (3D).
    calibration : {"continuum", "discrete"}
        Induced tensor from the continuum integral (the paper's) or from the family's own
        fourth moments (second-order convergent at fixed delta/dx).
    s0 : float, optional
        Critical stretch; or ``G0`` (J/m^2) with ``critical`` = "tipd" ((60)/(94)) or "osb"
        ((62)/(96)). Neither: no failure.
    warn : bool
        Emit :class:`IndefiniteWarning` when the material makes the free-body stiffness
        of the uncorrected model (``surface="none"``) indefinite.
    kernel : {"pair", "bond"}
        Force loop over the half-pair list (each pair once, :mod:`upscale.engine.pairs`;
        needs symmetric pair stiffnesses, else falls back to "bond") or over the directed
        bonds (each pair twice). Same forces to round-off.
    surface : {None, "none", "correspondence"}
        "correspondence" adds the per-particle correction energy
        ``sum_i V_i (1/2) H_i : (C - S_i^lat) : H_i`` (module docstring, "Surface
        correction"); elastic only (refused together with a failure criterion). "none":
        the paper's model. None (default): "correspondence" without a failure criterion,
        "none" with one (:func:`default_surface`).
    surface_bulk : callable, optional
        ``surface_bulk(x0) -> bool (N,)``: particles whose correction uses the bulk tensor
        ``C - S^lat`` of the most complete family instead of their own, for layers whose
        outer edge is not a free surface (prescribed-displacement layers that extend the
        body).
    """

    name = "tipd"
    force_kind = "density"

    def __init__(self, C=None, *, E: float | None = None, nu: float | None = None,
                 order: str = "standard", angle: float | None = None, axes=None,
                 calibration: str = "continuum", s0: float | None = None,
                 G0: float | None = None, critical: str = "tipd", warn: bool = True,
                 kernel: str = "pair", surface: str | None = None, surface_bulk=None):
        if (C is None) == (E is None):
            raise ValueError("TiPD needs exactly one of C (elastic stiffness) or E, nu (isotropic)")
        if E is not None and nu is None:
            raise ValueError("isotropic TiPD needs nu with E")
        if calibration not in ("continuum", "discrete"):
            raise ValueError(f"unknown calibration {calibration!r}; valid: 'continuum', 'discrete'")
        if critical not in ("tipd", "osb"):
            raise ValueError(f"unknown critical-stretch rule {critical!r}; valid: 'tipd', 'osb'")
        if kernel not in ("pair", "bond"):
            raise ValueError(f"unknown force kernel {kernel!r}; valid: 'pair', 'bond'")
        self.kernel = kernel
        if surface not in (None, "none", "correspondence"):
            raise ValueError(f"unknown surface correction {surface!r}; valid: None, 'none', 'correspondence'")
        if surface is None:
            surface = default_surface(failure=s0 is not None or G0 is not None)
        if surface != "none" and (s0 is not None or G0 is not None):
            raise ValueError("the surface correction is elastic only: give no s0/G0 with "
                             f"surface={surface!r} (valid: surface='none' with failure)")
        self.surface = surface
        if surface_bulk is not None and not callable(surface_bulk):
            raise ValueError(f"surface_bulk must be a callable x0 -> bool mask, got {surface_bulk!r}")
        self.surface_bulk = surface_bulk
        if s0 is not None and G0 is not None:
            raise ValueError("give the critical stretch s0 or the fracture energy G0, not both")
        for k, v in (("s0", s0), ("G0", G0)):
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"{k} must be positive, got {v!r}")
        if angle is not None and not np.isfinite(angle):
            raise ValueError(f"material-axis angle must be finite (radians), got {angle!r}")
        self.C_in, self.E, self.nu, self.order = C, E, nu, order
        self.angle, self.axes = angle, axes
        self.calibration, self.critical = calibration, critical
        self.s0_given, self.G0, self.warn = s0, G0, bool(warn)
        self.s0 = s0 if s0 is not None else np.inf
        self.needs = Needs(pairs=True, failure=(s0 is not None or G0 is not None), energy=True,
                           tangent=True)
        if C is not None:
            Ca = np.asarray(C, dtype=np.float64)
            if Ca.ndim == 2:
                voigt_to_tensor(Ca, order)     # validates shape, symmetry, definiteness

    # ------------------------------------------------------------------ set-up
    def material_tensor(self, dim: int, plane: str = "stress") -> np.ndarray:
        """The elastic tensor C (d, d, d, d) in the global axes (Pa)."""
        if self.E is not None:
            Cm = voigt_to_tensor(isotropic_voigt(self.E, self.nu, dim, plane))
        else:
            Ca = np.asarray(self.C_in, dtype=np.float64)
            Cm = voigt_to_tensor(Ca, self.order) if Ca.ndim == 2 else Ca
            if Cm.shape != (dim,) * 4:
                raise ValueError(f"elastic stiffness is for dim {Cm.shape[0]}, body has dim {dim}")
        R = rotation_matrix(self.angle, self.axes, dim)
        return rotate_tensor(Cm, R)

    def prepare(self, system, family, **kw) -> None:
        super().prepare(system, family, **kw)
        d = system.dim
        if d not in (2, 3):
            raise ValueError(f"Ti-PD is implemented in 2D and 3D, not dim={d}")
        self.dim = d
        C = self.material_tensor(d, system.plane)
        self.C = C
        self.S = symmetrised_tensor(C)
        info = indefiniteness(C)
        self.indefinite = info
        if info["indefinite"] and self.warn and self.surface == "none":
            Dv = tensor_to_voigt(C)
            cond = ("D12 > D66 (isotropic: nu > 1/3 plane stress, nu > 1/4 plane strain)"
                    if d == 2 else "nu > 1/4 for isotropic materials")
            warnings.warn(f"Ti-PD free-body stiffness is indefinite for this material "
                          f"(D12 = {Dv[0, 1]:.6g} Pa, D66 = {Dv[-1, -1]:.6g} Pa; smallest "
                          f"eigenvalue of S {info['min']:.6g} Pa; condition {cond}): free "
                          "surfaces and rigid rotations are not represented correctly",
                          IndefiniteWarning, stacklevel=2)
        xi = family.xi[:, :d]
        L = family.length
        w = system.volume[family.neighbors] * family.volume_factor
        self.w_b = np.ascontiguousarray(w)
        if self.calibration == "continuum":
            norm = np.pi * family.horizon ** 3 * system.thickness if d == 2 else np.pi * family.horizon ** 4
            A = induced_tensor(C) / norm                       # [p, q, a, b]
        else:
            bulk = int(np.argmax(np.bincount(family.owner, weights=w, minlength=family.n)))
            sl = slice(family.offsets[bulk], family.offsets[bulk + 1])
            xb, Lb, wb = xi[sl], L[sl], w[sl]
            Q = np.einsum("ka,kb,kc,kd,k->abcd", xb, xb, xb, xb, wb / Lb ** 3)
            P = _sym_pairs_inverse(Q, d)
            A = 2.0 * np.einsum("paqb,abcd->pqcd", self.S, P)
            self.bulk_particle = bulk
        self.A4 = A
        self.A = np.ascontiguousarray(A.reshape(d * d, d * d))
        q = np.zeros((family.nb, 3))
        q[:, :d] = xi * np.sqrt(w / L ** 3)[:, None]
        self.q_bc = np.ascontiguousarray(q)
        self._q_kernel_b = None
        if self.G0 is not None:
            self.s0 = self._critical_stretch()
        self.rc2_b = np.ascontiguousarray((L * (1.0 + self.s0)) ** 2) if self.needs.failure \
            else np.zeros(1)
        self._u = np.zeros((system.n, 3))
        self._set_pair_stiffness()
        if self.surface == "correspondence":
            self._prepare_surface()

    def lattice_moments(self) -> np.ndarray:
        """``S_i^lat = (1/2) sum_j M_ij xi_a xi_b V_j beta`` of every particle (N, d, d, d, d),
        indexed ``[i, p, a, q, b]`` (Pa): the tensor that the particle's (possibly
        truncated) family carries for a homogeneous displacement gradient."""
        fam, d = self.family, self.dim
        M = self.bond_matrices()
        xi = fam.xi[:, :d]
        per = 0.5 * np.einsum("kpq,ka,kb->kpaqb", M, xi, xi).reshape(fam.nb, -1)
        out = np.zeros((fam.n, per.shape[1]))
        np.add.at(out, fam.owner, per)
        return out.reshape((fam.n,) + (d,) * 4)

    def _prepare_surface(self) -> None:
        """The correction's per-particle tensors ``Delta_i = C - S_i^lat`` and the
        correspondence gradient (shape tensors on the same family, omega = 1)."""
        from upscale.models.correspondence import shape_tensors

        fam, d = self.family, self.dim
        Sl = self.lattice_moments()
        if self.surface_bulk is not None:
            mask = np.asarray(self.surface_bulk(self.system.x0), dtype=bool)
            if mask.shape != (fam.n,):
                raise ValueError(f"surface_bulk must return a bool mask of shape ({fam.n},), "
                                 f"got {mask.shape}")
            w = self.w_b
            bulk = int(np.argmax(np.bincount(fam.owner, weights=w, minlength=fam.n)))
            Sl[mask] = Sl[bulk]
        self.Delta_n = np.ascontiguousarray(self.C[None] - Sl)
        wv = np.ascontiguousarray(self.system.volume[fam.neighbors] * fam.volume_factor)
        self._cw_b = wv
        self._cK, self._cKinv = shape_tensors(fam, wv, d, fam.horizon)
        self._cxi = np.ascontiguousarray(fam.xi)
        self._cH = np.zeros((fam.n, 3, 3))
        self._cQ = np.zeros((fam.n, 3, 3))
        self._surface_pairs()

    def _surface_pairs(self) -> None:
        """Half-pair form of the correction's gradient and force (the correspondence pair
        kernels of :mod:`upscale.models.correspondence`, fed with u instead of y so that
        they return H directly), when the pair weight ``V_i w_ij = V_j w_ji`` is symmetric."""
        from upscale.engine.pairs import half_pairs

        fam, V, d, n = self.family, self.system.volume, self.dim, self.system.n
        pr = half_pairs(fam)
        ci = self._cw_b[pr.b] * V[pr.i]
        cj = self._cw_b[pr.rb] * V[pr.j]
        self._cpair = self.kernel == "pair" and bool(
            np.abs(ci - cj).max() <= 1e-12 * max(np.abs(ci).max(), 1e-300))
        if not self._cpair:
            return
        self._cpr = pr
        self._cc_p = np.ascontiguousarray(0.5 * (ci + cj))
        self._cinv_vol = np.ascontiguousarray(1.0 / V)
        self._cxi_p = np.ascontiguousarray(fam.xi[pr.b, :d] if d == 2 else fam.xi[pr.b])
        self._cC3 = np.zeros((3, 3, 3, 3))          # the kernels' stress pass is not used
        self._cpsi = np.zeros(n)
        self._cDelta = np.ascontiguousarray(self.Delta_n.reshape(n, d * d, d * d))
        if d == 2:
            self._cH4 = np.zeros((n, 4))
            self._cP4 = np.zeros((n, 4))
            self._cQ4 = np.zeros((n, 4))
            self._cB4 = np.zeros((n, 4))
        else:
            self._cPK = np.zeros((n, 3, 3))
            self._cB = np.zeros((n, 3, 3))
        self._surface_buffers()

    def _surface_buffers(self) -> None:
        n, d = self.system.n, self.dim
        self._cbufA = self._cpr.buffers(n, 4 if d == 2 else 9)
        self._cbufF = self._cpr.buffers(n, d)
        self._cbounds = self._cpr.thread_bounds(self._cbufA.shape[0])

    def surface_gradient(self, state) -> np.ndarray:
        """The correction's displacement gradients ``H_i = sum_j w (u_j - u_i) (x) xi K_i^-1``
        (N, 3, 3; first d x d block) on ``state`` (in an internal buffer)."""
        from upscale.models.correspondence import defgrad_kernel

        f = self.family
        u = self._u
        np.subtract(state.y, self.system.x0, out=u)
        defgrad_kernel(f.offsets, f.neighbors, self._cxi, self._cw_b, self._cKinv, u, self.dim,
                       self._cH)
        return self._cH

    def _add_surface_force(self, state, out) -> None:
        from upscale.models.correspondence import nosb_force_kernel

        d, f = self.dim, self.family
        if self._cpair:
            self._add_surface_force_pairs(state, out)
            return
        H = self.surface_gradient(state)[:, :d, :d]
        P = np.einsum("npaqb,nqb->npa", self.Delta_n, H)
        self._cQ[:, :d, :d] = np.einsum("npc,nca->npa", P, self._cKinv[:, :d, :d])
        nosb_force_kernel(f.offsets, f.neighbors, self._cxi, self._cw_b, self._cQ, self._cH,
                          self._cQ, state.y, d, False, out)

    def _add_surface_force_pairs(self, state, out) -> None:
        from upscale.engine.pairs import reduce_buffers
        from upscale.models.correspondence import (nosb_pair_force, nosb_pair_force_2d, nosb_pair_update,
                                                   nosb_pair_update_2d)

        if self._cbufA.shape[0] != nb.get_num_threads():
            self._surface_buffers()
        u = self._u
        np.subtract(state.y, self.system.x0, out=u)
        pr, d = self._cpr, self.dim
        if d == 2:
            nosb_pair_update_2d(self._cbounds, pr.offsets, pr.j, self._cxi_p, self._cc_p, u, self._cinv_vol,
                                self._cKinv, self._cC3, 0, 0.0, 0.0, self._cbufA, self._cH, self._cH4,
                                self._cP4, self._cpsi)
            surface_stress_kernel(self._cH4, self._cDelta, self._cKinv, 2, self._cQ4)
            nosb_pair_force_2d(self._cbounds, pr.offsets, pr.j, self._cxi_p, self._cc_p, self._cQ4, self._cH4,
                               self._cB4, state.y, False, self._cbufF)
        else:
            nosb_pair_update(self._cbounds, pr.offsets, pr.j, self._cxi_p, self._cc_p, u, self._cinv_vol,
                             self._cKinv, self._cC3, 0, 0.0, 0.0, 3, self._cbufA, self._cH, self._cPK,
                             self._cpsi)
            Q = self._cQ.reshape(-1, 9)
            surface_stress_kernel(self._cH.reshape(-1, 9), self._cDelta, self._cKinv, 3, Q)
            nosb_pair_force(self._cbounds, pr.offsets, pr.j, self._cxi_p, self._cc_p, self._cQ, self._cH,
                            self._cB, state.y, 3, False, self._cbufF)
        reduce_buffers(self._cbufF, self._cinv_vol, out, d)

    def _set_pair_stiffness(self) -> None:
        """The pair form of the force from the bond matrices (:meth:`bond_matrices`): on the
        half-pair list (:mod:`upscale.engine.pairs`) ``K_p = V_i M_ij``, which equals
        ``V_j M_ji`` when the bond weights are symmetric (then each pair is computed once);
        otherwise the directed-bond kernel is used. Evaluated in blocks of pairs, so the
        temporaries stay bounded (the (nb, d, d) matrices of every bond are never held)."""
        from upscale.engine.pairs import half_pairs

        fam, d, V = self.family, self.dim, self.system.volume
        pr = half_pairs(fam)
        comp = [(0, 0), (0, 1), (1, 1)] if d == 2 else [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]
        npair = pr.b.shape[0]
        K_p = np.empty((npair, len(comp)))
        big, asym = 1e-300, 0.0
        for a in range(0, npair, _PAIR_BLOCK):
            blk = slice(a, min(npair, a + _PAIR_BLOCK))
            Ki = self.bond_matrices(pr.b[blk]) * V[pr.i[blk]][:, None, None]
            Kj = self.bond_matrices(pr.rb[blk]) * V[pr.j[blk]][:, None, None]
            big = max(big, np.abs(Ki).max(initial=0.0))
            asym = max(asym, np.abs(Ki - Kj).max(initial=0.0))
            for c, (p, q) in enumerate(comp):
                K_p[blk, c] = 0.5 * (Ki[:, p, q] + Kj[:, p, q])
        self._pair = self.kernel == "pair" and bool(asym <= 1e-12 * big)
        if not self._pair:
            self.pairs = None
            return
        self.pairs = pr
        self.K_p = K_p
        self.rc2_p = np.ascontiguousarray(self.rc2_b[pr.b]) if self.needs.failure else np.zeros(1)
        self._inv_vol = np.ascontiguousarray(1.0 / V)
        self._buf = pr.buffers(self.system.n, d)
        self._bounds = pr.thread_bounds(self._buf.shape[0])

    def _critical_stretch(self) -> float:
        d, fam, sysm = self.dim, self.family, self.system
        if self.E is not None:
            return tipd_critical_stretch(self.G0, self.E, self.nu, fam.horizon, d,
                                         rule=self.critical, plane=sysm.plane)
        if self.critical == "osb":
            raise ValueError("critical='osb' needs an isotropic material (E, nu)")
        # direction mean of c(n) = n.M n |xi| (N/m^6 at |xi| = 1 and unit weight)
        Ac = induced_tensor(self.C)
        norm = np.pi * fam.horizon ** 3 * sysm.thickness if d == 2 else np.pi * fam.horizon ** 4
        if d == 2:
            th = np.linspace(0, 2 * np.pi, 720, endpoint=False)
            n = np.stack([np.cos(th), np.sin(th)], 1)
        else:
            rng = np.random.default_rng(0)
            n = rng.normal(size=(20000, 3))
            n /= np.linalg.norm(n, axis=1)[:, None]
        c = np.einsum("kp,kq,ka,kb,pqab->k", n, n, n, n, Ac).mean() / norm
        if d == 2:
            return float(np.sqrt(4 * self.G0 / (c * sysm.thickness * fam.horizon ** 4)))
        return float(np.sqrt(10 * self.G0 / (np.pi * c * fam.horizon ** 5)))

    # ------------------------------------------------------------------ checks
    def bond_matrices(self, bonds=None) -> np.ndarray:
        """M_b V_j beta (nb, d, d) of every directed bond, or (k, d, d) of the directed bonds
        ``bonds`` (N/m^5 per unit volume weight; ``b_i = sum_b M_b eta_b``)."""
        d = self.dim
        q = self.q_bc[:, :d] if bonds is None else self.q_bc[bonds, :d]
        return np.einsum("pqab,ka,kb->kpq", self.A4, q, q)

    def lattice_moment(self, particle: int | None = None) -> np.ndarray:
        """(1/2) sum_j M(xi_j) xi_a xi_b V_j beta_j (d, d, d, d) ``[p, a, q, b]`` (Pa) at
        ``particle`` (default: the bulk particle); equals S for the discrete calibration."""
        fam = self.family
        if particle is None:
            w = self.w_b
            particle = int(np.argmax(np.bincount(fam.owner, weights=w, minlength=fam.n)))
        sl = slice(fam.offsets[particle], fam.offsets[particle + 1])
        M = self.bond_matrices()[sl]
        xi = fam.xi[sl, :self.dim]
        return 0.5 * np.einsum("kpq,ka,kb->paqb", M, xi, xi)

    # ------------------------------------------------------------------ forces
    def _force(self, state, out, fail):
        f = self.family
        u = self._u
        np.subtract(state.y, self.system.x0, out=u)
        if self._pair:
            from upscale.engine.pairs import reduce_buffers

            pr, buf = self.pairs, self._buf
            if buf.shape[0] != nb.get_num_threads():
                buf = self._buf = pr.buffers(self.system.n, self.dim)
                self._bounds = pr.thread_bounds(buf.shape[0])
            # the bond-state reads cost a fifth of the loop: skipped while every bond is intact
            check = bool(fail or not state.intact.all())
            k = int(tipd_pair_force(self._bounds, pr.offsets, pr.j, pr.b, pr.rb, self.K_p, u,
                                    state.y, state.intact, self.rc2_p, fail, check, buf,
                                    self.dim))
            reduce_buffers(buf, self._inv_vol, out, self.dim)
            return k
        kern = tipd_force_kernel_2d if self.dim == 2 else tipd_force_kernel_3d
        if self._q_kernel_b is None:
            # the 2D kernel reads only (q_x, q_y): a contiguous (nb, 2) copy halves its
            # traffic (made on first use: the pair kernel does not need it)
            self._q_kernel_b = np.ascontiguousarray(self.q_bc[:, :2]) if self.dim == 2 else self.q_bc
        return int(kern(f.offsets, f.neighbors, self._q_kernel_b, self.A, u, state.y,
                        state.intact, self.rc2_b, fail, out))

    def add_force(self, state, out):
        self._force(state, out, False)
        if self.surface != "none":
            self._add_surface_force(state, out)

    def step_force(self, state, out, *, failure=True):
        k = self._force(state, out, bool(failure and self.needs.failure))
        if self.surface != "none":
            self._add_surface_force(state, out)
        return k

    def break_bonds(self, state):
        from upscale.engine.kernels import break_by_stretch

        if not self.needs.failure:
            return 0
        f = self.family
        return int(break_by_stretch(f.offsets, f.neighbors, f.length, state.y, state.intact,
                                    np.full(f.n, self.s0)))

    def energy_density(self, state):
        f = self.family
        W = tipd_energy_kernel(f.offsets, f.neighbors, self.q_bc, self.A, self.system.x0,
                               state.y, state.intact, self.dim)
        if self.surface != "none":
            d = self.dim
            H = self.surface_gradient(state)[:, :d, :d]
            W = W + 0.5 * np.einsum("npa,npaqb,nqb->n", H, self.Delta_n, H)
        return W

    def tangent(self, state=None):
        """Assembled stiffness ``K = -dF_int/dy`` (scipy.sparse CSR (3N, 3N), N/m); the
        model is linear, so K does not depend on the displacement, only on the intact
        bonds. Symmetric: ``V_i M_ij = V_j M_ji``."""
        import scipy.sparse as sp

        fam, d, n = self.family, self.dim, self.system.n
        intact = np.ones(fam.nb, dtype=bool) if state is None else np.asarray(state.intact, bool)
        M = self.bond_matrices() * (self.system.volume[fam.owner] * intact)[:, None, None]
        i, j = fam.owner, fam.neighbors
        rows, cols, vals = [], [], []
        for p in range(d):
            for r in range(d):
                v = M[:, p, r]
                rows += [3 * i + p, 3 * i + p]
                cols += [3 * j + r, 3 * i + r]
                vals += [-v, v]
        K = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(3 * n, 3 * n))
        if self.surface != "none":
            K = K + self._surface_stiffness()
        return K

    def _surface_stiffness(self):
        """``-V Bs Delta G`` of the correction (correspondence factors, Delta block-diagonal)."""
        import scipy.sparse as sp

        from upscale.models.correspondence import gradient_operators

        fam, d, n = self.family, self.dim, self.system.n
        dd = d * d
        G, Bs = gradient_operators(fam, self._cw_b, self._cKinv, d)
        blk = self.Delta_n.reshape(n, dd, dd)
        r = (np.arange(n)[:, None, None] * dd + np.arange(dd)[None, :, None]) + 0 * np.arange(dd)[None, None, :]
        c = (np.arange(n)[:, None, None] * dd + np.arange(dd)[None, None, :]) + 0 * np.arange(dd)[None, :, None]
        Db = sp.csr_matrix((blk.ravel(), (r.ravel(), c.ravel())), shape=(n * dd, n * dd))
        Vd = sp.diags(np.repeat(self.system.volume, 3))
        return (-(Vd @ (Bs @ Db @ G))).tocsr()

    def stiffness_bound(self):
        """Gershgorin row bound (N/m^4): ``2 sum_j max_p sum_r |M_b,pr|`` (plus the surface
        correction's correspondence bound, as in
        :meth:`upscale.models.correspondence.Correspondence.stiffness_bound`)."""
        f = self.family
        M = np.empty(f.nb)
        for a in range(0, f.nb, _PAIR_BLOCK):          # blocks: no (nb, d, d) temporaries
            blk = np.arange(a, min(f.nb, a + _PAIR_BLOCK))
            M[blk] = np.abs(self.bond_matrices(blk)).sum(axis=2).max(axis=1)
        R = 2.0 * np.bincount(f.owner, weights=M, minlength=f.n)
        if self.surface != "none":
            d = self.dim
            i, j = f.owner, f.neighbors
            Kinv = self._cKinv[:, :d, :d]
            xi = f.xi[:, :d]
            g = np.abs(self._cw_b[:, None] * np.einsum("kab,kb->ka", Kinv[i], xi)).sum(1)
            gp = np.abs(self._cw_b[:, None] * np.einsum("kab,kb->ka", Kinv[j], xi)).sum(1)
            Gs = np.bincount(i, weights=g, minlength=f.n)
            c = np.abs(self.Delta_n.reshape(f.n, d * d, d * d)).sum(2).max()
            R = R + c * np.bincount(i, weights=g * 2 * Gs[i] + gp * 2 * Gs[j], minlength=f.n)
        return R

    def describe(self):
        d = {"model": self.name, "calibration": self.calibration, "critical": self.critical,
             "surface": self.surface,
             "kernel": "pair" if getattr(self, "_pair", self.kernel == "pair") else "bond",
             "s0": None if np.isinf(self.s0) else self.s0}
        if self.E is not None:
            d.update(E_Pa=self.E, nu=self.nu)
        if self.system is not None:
            d["C_voigt_Pa"] = tensor_to_voigt(self.C).tolist()
            d["indefinite"] = self.indefinite["indefinite"]
        if self.angle is not None:
            d["angle_rad"] = self.angle
        if self.G0 is not None:
            d["G0_J_per_m2"] = self.G0
        return d


register("tipd", TiPD)
