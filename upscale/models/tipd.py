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
particles 2 delta apart; the stiffness stays symmetric. Costs: a gradient pass per force
evaluation (the pair loops of :mod:`upscale.models.tipd_kernels` fuse the Ti-PD force with
the correction's force pass and run gradient, stress and force as one sweep per thread:
about 1.3 PMB steps on the ``bench-tipd`` plate, against 4.5 for the earlier separate
passes) and a denser stiffness. Caveats: the free body is slightly indefinite
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

from upscale.models import register
from upscale.models.base import Model, Needs
from upscale.models.tipd_kernels import (surface_stress_kernel, tipd_energy_kernel, tipd_force_kernel_2d,
                                         tipd_force_kernel_3d, tipd_pair_energy_kernel, tipd_pair_kernel,
                                         tipd_surface_2d, tipd_surface_3d)

__all__ = ["TiPD", "IndefiniteWarning", "voigt_to_tensor", "tensor_to_voigt", "isotropic_voigt",
           "orthotropic_voigt_2d", "rotate_tensor", "symmetrised_tensor", "induced_tensor",
           "paper_induced_voigt_2d", "appendix_a_stiffness", "appendix_b_stiffness", "indefiniteness",
           "tipd_critical_stretch", "surface_stress_kernel", "default_surface"]


class IndefiniteWarning(UserWarning):
    """The material makes the Ti-PD free-body stiffness indefinite."""


# ---------------------------------------------------------------------------- tensors
# directed bonds per block where per-bond matrices are formed at set-up (bounds the
# temporaries: a few hundred bytes per bond of the block)
_PAIR_BLOCK = 1 << 18
# every bit of a ring-buffer index (the buffer is a full per-particle array)
_FULL_MASK = np.uint64(0xFFFFFFFFFFFFFFFF)

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
        Force loops over the half bond list (each pair once, per-class tables,
        :mod:`upscale.models.tipd_kernels`; any weights, any bond state) or over the
        directed bonds (each pair twice; the reference). Same forces to round-off.
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
        if self.calibration == "continuum":
            norm = np.pi * family.horizon ** 3 * system.thickness if d == 2 else np.pi * family.horizon ** 4
            A = induced_tensor(C) / norm                       # [p, q, a, b]
        else:
            bulk = self._bulk_particle()
            sl = np.arange(family.offsets[bulk], family.offsets[bulk + 1])
            xb, Lb, wb = family.xi_of(sl)[:, :d], family.length_of(sl), self.bond_weights(sl)
            Q = np.einsum("ka,kb,kc,kd,k->abcd", xb, xb, xb, xb, wb / Lb ** 3)
            P = _sym_pairs_inverse(Q, d)
            A = 2.0 * np.einsum("paqb,abcd->pqcd", self.S, P)
            self.bulk_particle = bulk
        self.A4 = A
        self.A = np.ascontiguousarray(A.reshape(d * d, d * d))
        if self.G0 is not None:
            self.s0 = self._critical_stretch()
        self._u = np.zeros((system.n, 3))
        self.bonds = None
        if self.kernel == "pair":
            self._pair_tables()
        else:
            self._bond_tables()
        if self.surface == "correspondence":
            self._prepare_surface()

    # ------------------------------------------------------------------ per-bond quantities
    def bond_weights(self, bonds=None) -> np.ndarray:
        """``w = V_j beta_ij`` (m^3) of every directed bond, or of the directed bonds
        ``bonds`` (computed on each call: not kept per bond)."""
        fam, V = self.family, self.system.volume
        if bonds is None:
            return V[fam.neighbors] * fam.volume_factor
        return V[fam.neighbors[bonds]] * fam.volume_factor_of(bonds)

    def _q(self, bonds=None) -> np.ndarray:
        """``q = xi sqrt(V_j beta / |xi|^3)`` (nb or k, d) (``M_b = A : q (x) q``)."""
        fam, d = self.family, self.dim
        w = self.bond_weights(bonds)
        if bonds is None:
            return fam.xi[:, :d] * np.sqrt(w / fam.length ** 3)[:, None]
        return fam.xi_of(bonds)[:, :d] * np.sqrt(w / fam.length_of(bonds) ** 3)[:, None]

    def _bulk_particle(self) -> int:
        """The particle with the most complete family (largest sum of bond weights)."""
        fam = self.family
        W = np.zeros(fam.n)
        for lo, hi in fam.bond_blocks(_PAIR_BLOCK):      # whole rows: the sums of one pass
            blk = np.arange(lo, hi)
            W += np.bincount(fam.owner_of(blk), weights=self.bond_weights(blk), minlength=fam.n)
        return int(np.argmax(W))

    def _bond_tables(self) -> None:
        """Per-bond arrays of the directed-bond loops (``kernel="bond"``)."""
        fam = self.family
        self._q_b = np.ascontiguousarray(self._q())
        self.rc2_b = np.ascontiguousarray((fam.length * (1.0 + self.s0)) ** 2) if self.needs.failure \
            else np.zeros(1)

    def _pair_tables(self) -> None:
        """The half bond list (:class:`~upscale.engine.bondlist.BondList`: each pair once,
        uint32 partners, one-byte classes on a lattice) and the per-class table of the pair
        kernels (:mod:`upscale.models.tipd_kernels`): the classes are the distinct bit
        patterns of (|xi|, beta of both directions, xi), so that every entry of the table is
        computed from exactly the bond's own reference geometry. With uniform volumes and
        the same beta in both directions of every class the weight ``w = V beta`` is folded
        into the table (``self._uni``: the kernels then multiply by no weight)."""
        from upscale.engine.bondlist import BondList

        fam, d = self.family, self.dim
        bl = BondList(fam, self.system.volume)
        k_p, L_k, bf_k, br_k, *xs = bl.classes(*(lambda b, c=c: fam.xi_of(b)[:, c] for c in range(d)))
        xi_k = np.stack(xs[0::2], axis=1)                  # forward xi of each class
        M = np.einsum("pqab,ka,kb->kpq", self.A4, xi_k, xi_k) / L_k[:, None, None] ** 3
        comp = [(0, 0), (0, 1), (1, 1)] if d == 2 else [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]
        V = bl.volume
        uni = bool(np.all(V == V[0]) and np.array_equal(bf_k, br_k))
        w_k = V[0] * bf_k if uni else np.ones_like(bf_k)
        rc2 = (L_k * (1.0 + self.s0)) ** 2 if self.needs.failure else np.full(L_k.size, np.inf)
        self._tab = np.ascontiguousarray(np.concatenate(
            [xi_k * w_k[:, None], np.stack([M[:, p, q] for p, q in comp], 1) * w_k[:, None],
             bf_k[:, None], br_k[:, None], rc2[:, None]], axis=1))
        self._uni = uni
        self._k_p = k_p
        self.bonds = bl
        # how far ahead of a force row its partners reach (for the sweeps)
        n = fam.n
        reach = np.arange(n, dtype=np.int64)
        has = bl.row_n[1:] > bl.row_n[:-1]
        if has.any():
            last = np.maximum.reduceat(bl.j_p, bl.row_n[:-1][has]).astype(np.int64)
            reach[has] = np.maximum(reach[has], last)
        self._reach_n = reach
        span = int((reach - np.arange(n)).max(initial=0))
        self._span = span
        R = 1 << int(np.ceil(np.log2(2 * span + 2)))
        if R >= n:
            R, self._mask = n, _FULL_MASK
        else:
            self._mask = np.uint64(R - 1)
        self._ring = R
        self._scratch = {}

    # ------------------------------------------------------------------ surface correction
    def lattice_moments(self) -> np.ndarray:
        """``S_i^lat = (1/2) sum_j M_ij xi_a xi_b V_j beta`` of every particle (N, d, d, d, d),
        indexed ``[i, p, a, q, b]`` (Pa): the tensor that the particle's (possibly
        truncated) family carries for a homogeneous displacement gradient. Summed in blocks
        of bonds (no (nb, d^4) temporary)."""
        fam, d = self.family, self.dim
        out = np.zeros((d ** 4, fam.n))
        for a in range(0, fam.nb, _PAIR_BLOCK):
            blk = np.arange(a, min(fam.nb, a + _PAIR_BLOCK))
            xi = fam.xi_of(blk)[:, :d]
            per = 0.5 * np.einsum("kpq,ka,kb->kpaqb", self.bond_matrices(blk), xi, xi).reshape(blk.size, -1)
            own = fam.owner_of(blk)
            for c in range(per.shape[1]):
                out[c] += np.bincount(own, weights=per[:, c], minlength=fam.n)
        return np.ascontiguousarray(out.T).reshape((fam.n,) + (d,) * 4)

    def _prepare_surface(self) -> None:
        """The correction's per-particle tensors ``Delta_i = C - S_i^lat`` and the
        correspondence gradient (shape tensors on the same family, omega = 1); for the pair
        kernels the per-particle map ``T_i: A_i -> Q_i`` (``Q = (Delta : (A K^-1)) K^-1``,
        constant in the reference configuration) stored once per distinct bit pattern
        (classes of particles, a uint16 index per particle on a lattice)."""
        from upscale.models.correspondence import shape_tensors

        fam, d, n = self.family, self.dim, self.family.n
        Sl = self.lattice_moments()
        if self.surface_bulk is not None:
            mask = np.asarray(self.surface_bulk(self.system.x0), dtype=bool)
            if mask.shape != (fam.n,):
                raise ValueError(f"surface_bulk must return a bool mask of shape ({fam.n},), "
                                 f"got {mask.shape}")
            Sl[mask] = Sl[self._bulk_particle()]
        self.Delta_n = np.ascontiguousarray(self.C[None] - Sl)
        self._cK, self._cKinv = shape_tensors(fam, self.bond_weights(), d, fam.horizon)
        self._cH = None                         # made by surface_gradient on first use
        if self.bonds is None:
            self._cQ = np.zeros((n, 3, 3))
            return
        dd = d * d
        Kinv = self._cKinv[:, :d, :d]
        T = np.einsum("nca,npcqb,neb->npaqe", Kinv, self.Delta_n, Kinv).reshape(n, dd, dd)
        T = np.ascontiguousarray(T)
        _, first, cls = np.unique(T.reshape(n, -1).view(np.int64), axis=0, return_index=True,
                                  return_inverse=True)
        ctype = np.uint16 if first.size <= 65536 else np.uint32
        self._tc_n = np.ascontiguousarray(cls.ravel().astype(ctype))
        self._T_ckk = np.ascontiguousarray(T[first])

    def surface_gradient(self, state) -> np.ndarray:
        """The correction's displacement gradients ``H_i = sum_j w (u_j - u_i) (x) xi K_i^-1``
        (N, 3, 3; first d x d block) on ``state`` (in an internal buffer)."""
        from upscale.models.correspondence import defgrad_kernel

        f = self.family
        u = self._u
        np.subtract(state.y, self.system.x0, out=u)
        if self._cH is None:
            self._cH = np.zeros((f.n, 3, 3))
        defgrad_kernel(f.offsets, f.neighbors, np.ascontiguousarray(f.xi), self.bond_weights(),
                       self._cKinv, u, self.dim, self._cH)
        return self._cH

    def _add_surface_force_bonds(self, state, out) -> None:
        """The correction on the directed bonds (``kernel="bond"``): gradient, stress and
        force as three passes (:mod:`upscale.models.correspondence`)."""
        from upscale.models.correspondence import nosb_force_kernel

        d, f = self.dim, self.family
        H = self.surface_gradient(state)[:, :d, :d]
        P = np.einsum("npaqb,nqb->npa", self.Delta_n, H)
        self._cQ[:, :d, :d] = np.einsum("npc,nca->npa", P, self._cKinv[:, :d, :d])
        nosb_force_kernel(f.offsets, f.neighbors, np.ascontiguousarray(f.xi), self.bond_weights(),
                          self._cQ, self._cH, self._cQ, state.y, d, False, out)

    def _surface_scratch(self, nt: int) -> tuple:
        """Scratch of the correction's sweeps: per thread the ring buffers (u, A, Q over
        ``self._ring`` rows) and the halo (the force on the next thread's first ``span``
        rows). Made on first use, kept per thread count."""
        s = self._scratch.get(nt)
        if s is None:
            d, R = self.dim, self._ring
            s = (np.zeros((nt, R, d)), np.zeros((nt, R, d * d)), np.zeros((nt, R, d * d)),
                 np.zeros((nt, max(self._span, 1), d)))
            self._scratch[nt] = s
        return s

    def _pair_surface_force(self, state, out, check: bool) -> None:
        """Ti-PD with the surface correction on the half bond list, added to ``out``: one
        sweep per thread (:func:`~upscale.models.tipd_kernels.tipd_surface_2d`)."""
        bl = self.bonds
        nt = nb.get_num_threads()
        kern = tipd_surface_2d if self.dim == 2 else tipd_surface_3d
        kern(bl.row_n, bl.j_p, self._k_p, bl.fwd_n, bl.fwd_p, bl.rev_p, self._reach_n, bl.chunks(nt),
             self._span, self._tab, self._uni, bl.volume, self.system.x0, state.y, self._tc_n,
             self._T_ckk, state.intact, check, self._mask, *self._surface_scratch(nt), out)

    def _pair_force(self, state, out, fail: bool, check: bool) -> int:
        """Ti-PD without the correction on the half bond list (:func:`tipd_pair_kernel`)."""
        bl = self.bonds
        nt = nb.get_num_threads()
        buf, zero = bl.target(out, nt)
        k = tipd_pair_kernel(bl.row_n, bl.j_p, self._k_p, bl.fwd_n, bl.fwd_p, bl.rev_p, self._tab,
                             self._uni, bl.chunks(nt), bl.volume, self.system.x0, state.y,
                             state.intact, fail, check, self.dim, self._u, buf, zero)
        bl.finish(buf, zero, out)
        return int(k)

    def _bond_force(self, state, out, fail: bool) -> int:
        """Ti-PD on the directed bonds (``kernel="bond"``: each pair twice)."""
        f = self.family
        u = self._u
        np.subtract(state.y, self.system.x0, out=u)
        kern = tipd_force_kernel_2d if self.dim == 2 else tipd_force_kernel_3d
        return int(kern(f.offsets, f.neighbors, self._q_b, self.A, u, state.y, state.intact,
                        self.rc2_b, fail, out))

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
        q = self._q(bonds)
        return np.einsum("pqab,ka,kb->kpq", self.A4, q, q)

    def lattice_moment(self, particle: int | None = None) -> np.ndarray:
        """(1/2) sum_j M(xi_j) xi_a xi_b V_j beta_j (d, d, d, d) ``[p, a, q, b]`` (Pa) at
        ``particle`` (default: the bulk particle); equals S for the discrete calibration."""
        fam = self.family
        if particle is None:
            particle = self._bulk_particle()
        bonds = np.arange(fam.offsets[particle], fam.offsets[particle + 1])
        M = self.bond_matrices(bonds)
        xi = fam.xi_of(bonds)[:, :self.dim]
        return 0.5 * np.einsum("kpq,ka,kb->paqb", M, xi, xi)

    # ------------------------------------------------------------------ forces
    def _force(self, state, out, fail: bool) -> int:
        if self.bonds is None:
            k = self._bond_force(state, out, fail)
            if self.surface != "none":
                self._add_surface_force_bonds(state, out)
            return k
        # the bond state is read only while some bond is broken (or may break)
        check = bool(fail or not state.intact.all())
        if self.surface != "none":               # elastic only: no failure
            self._pair_surface_force(state, out, check)
            return 0
        return self._pair_force(state, out, fail, check)

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
        f, d = self.family, self.dim
        if self.bonds is not None:
            bl = self.bonds
            W = np.zeros(f.n)
            tipd_pair_energy_kernel(bl.row_n, bl.j_p, self._k_p, bl.fwd_n, bl.fwd_p, bl.rev_p,
                                    self._tab, self._uni, bl.volume, self.system.x0, state.y,
                                    state.intact, d, W)
        else:
            W = tipd_energy_kernel(f.offsets, f.neighbors, self._q_b, self.A, self.system.x0,
                                   state.y, state.intact, d)
        if self.surface != "none":
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
        G, Bs = gradient_operators(fam, self.bond_weights(), self._cKinv, d)
        blk = self.Delta_n.reshape(n, dd, dd)
        r = (np.arange(n)[:, None, None] * dd + np.arange(dd)[None, :, None]) + 0 * np.arange(dd)[None, None, :]
        c = (np.arange(n)[:, None, None] * dd + np.arange(dd)[None, None, :]) + 0 * np.arange(dd)[None, :, None]
        Db = sp.csr_matrix((blk.ravel(), (r.ravel(), c.ravel())), shape=(n * dd, n * dd))
        Vd = sp.diags(np.repeat(self.system.volume, 3))
        return (-(Vd @ (Bs @ Db @ G))).tocsr()

    def stiffness_bound(self):
        """Gershgorin row bound (N/m^4): ``2 sum_j max_p sum_r |M_b,pr|`` (plus the surface
        correction's correspondence bound, as in
        :meth:`upscale.models.correspondence.Correspondence.stiffness_bound`). In blocks of
        bonds: no (nb, d, d) temporaries."""
        f, d = self.family, self.dim
        R = np.zeros(f.n)
        for lo, hi in f.bond_blocks(_PAIR_BLOCK):          # whole rows: the sums of one pass
            blk = np.arange(lo, hi)
            M = np.abs(self.bond_matrices(blk)).sum(axis=2).max(axis=1)
            R += np.bincount(f.owner_of(blk), weights=M, minlength=f.n)
        R *= 2.0
        if self.surface != "none":
            i, j = f.owner, f.neighbors
            Kinv = self._cKinv[:, :d, :d]
            w = self.bond_weights()
            g = np.empty(f.nb)
            gp = np.empty(f.nb)
            for a in range(0, f.nb, _PAIR_BLOCK):
                s = slice(a, min(f.nb, a + _PAIR_BLOCK))
                xi = f.xi_of(np.arange(s.start, s.stop))[:, :d]
                g[s] = np.abs(w[s, None] * np.einsum("kab,kb->ka", Kinv[i[s]], xi)).sum(1)
                gp[s] = np.abs(w[s, None] * np.einsum("kab,kb->ka", Kinv[j[s]], xi)).sum(1)
            Gs = np.bincount(i, weights=g, minlength=f.n)
            c = np.abs(self.Delta_n.reshape(f.n, d * d, d * d)).sum(2).max()
            R = R + c * np.bincount(i, weights=g * 2 * Gs[i] + gp * 2 * Gs[j], minlength=f.n)
        return R

    def describe(self):
        d = {"model": self.name, "calibration": self.calibration, "critical": self.critical,
             "surface": self.surface,
             "kernel": self.kernel,
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
