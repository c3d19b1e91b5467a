"""Material tensors of the unified gain-matrix model (:mod:`upscale.models.unified`):
isotropic and orthotropic Voigt stiffnesses (Pa, engineering shear order), the full
C_ijkl with tensor shear, and G_c from K_Ic. Units: SI."""
from __future__ import annotations

import numpy as np

__all__ = ["elastic_tensor", "orthotropic_tensor", "critical_energy_release_rate", "check_positive_definite",
           "full_tensor"]


def _voigt_pairs(dim):
    return [(0, 0), (1, 1), (0, 1)] if dim == 2 else [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]


def check_positive_definite(C, what):
    C = np.asarray(C, dtype=float)
    if not np.allclose(C, C.T, rtol=1e-10, atol=1e-12 * np.abs(C).max()):
        raise ValueError(f"{what} is not symmetric; valid: a symmetric positive definite Voigt matrix")
    ev = np.linalg.eigvalsh(C)
    if ev[0] <= 0:
        raise ValueError(f"{what} is not positive definite (smallest eigenvalue {ev[0]:.4g} Pa); "
                         "valid: a positive definite Voigt matrix")
    return C


def elastic_tensor(E: float, nu: float, *, dim: int = 2, plane: str = "stress") -> np.ndarray:
    """Isotropic Voigt stiffness (Pa), engineering shear strain order.

    ``dim = 2``: (3, 3) in order (11, 22, 12), plane stress ``E/(1-nu^2) [[1, nu, 0], [nu,
    1, 0], [0, 0, (1-nu)/2]]`` or plane strain (lambda, mu). ``dim = 3``: (6, 6) in order
    (11, 22, 33, 23, 13, 12).

    Raises
    ------
    ValueError
        E <= 0, or nu outside (-1, 1/2) (the isotropic solid's range).
    """
    if not (np.isfinite(E) and E > 0):
        raise ValueError(f"Young's modulus E={E!r} Pa; valid: E > 0")
    if not (-1.0 < nu < 0.5):
        raise ValueError(f"Poisson ratio nu={nu!r}; valid for an isotropic solid: -1 < nu < 0.5")
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    if dim == 2:
        if plane == "stress":
            f = E / (1 - nu * nu)
            return f * np.array([[1, nu, 0], [nu, 1, 0], [0, 0, (1 - nu) / 2]])
        if plane == "strain":
            return np.array([[lam + 2 * mu, lam, 0], [lam, lam + 2 * mu, 0], [0, 0, mu]])
        raise ValueError(f"plane={plane!r}; valid: 'stress', 'strain'")
    if dim != 3:
        raise ValueError(f"dim={dim!r}; valid: 2, 3")
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[np.arange(3), np.arange(3)] = lam + 2 * mu
    C[np.arange(3, 6), np.arange(3, 6)] = mu
    return C


def _rotation_voigt(R, dim):
    """Voigt (engineering shear) transformation of a stiffness: C' = T C T^T."""
    pairs = _voigt_pairs(dim)
    m = len(pairs)
    T = np.zeros((m, m))
    for I, (i, j) in enumerate(pairs):
        for J, (k, l) in enumerate(pairs):
            v = R[i, k] * R[j, l]
            if k != l:
                v += R[i, l] * R[j, k]
            T[I, J] = v
    return T


def orthotropic_tensor(E1, E2, nu12, G12, *, E3=None, nu13=None, nu23=None, G13=None, G23=None,
                       dim: int = 2, plane: str = "stress", angle_deg: float = 0.0,
                       rotation=None) -> np.ndarray:
    """Orthotropic Voigt stiffness (Pa) with material axes rotated.

    Compliance in material axes (order 11, 22, [33, 23, 13,] 12), inverted; plane stress
    takes the in-plane block of the compliance, plane strain the in-plane block of the
    stiffness. The material axes are rotated by ``angle_deg`` about z (2D/3D) or by the
    3x3 ``rotation`` (3D): C_global = T C_material T^T (engineering shear order).

    Raises
    ------
    ValueError
        A non-positive modulus, or constants whose stiffness is not positive definite.
    """
    for name, v in (("E1", E1), ("E2", E2), ("G12", G12)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name}={v!r} Pa; valid: > 0")
    E3 = E2 if E3 is None else E3
    nu13 = nu12 if nu13 is None else nu13
    nu23 = nu12 if nu23 is None else nu23
    G13 = G12 if G13 is None else G13
    G23 = E2 / (2 * (1 + nu23)) if G23 is None else G23
    S = np.zeros((6, 6))
    S[0, 0], S[1, 1], S[2, 2] = 1 / E1, 1 / E2, 1 / E3
    S[0, 1] = S[1, 0] = -nu12 / E1
    S[0, 2] = S[2, 0] = -nu13 / E1
    S[1, 2] = S[2, 1] = -nu23 / E2
    S[3, 3], S[4, 4], S[5, 5] = 1 / G23, 1 / G13, 1 / G12
    check_positive_definite(S, f"orthotropic compliance (E1={E1}, E2={E2}, nu12={nu12}, G12={G12})")
    C3 = np.linalg.inv(S)
    if dim == 2:
        idx = [0, 1, 5]
        if plane == "stress":
            C = np.linalg.inv(S[np.ix_(idx, idx)])
        elif plane == "strain":
            C = C3[np.ix_(idx, idx)]
        else:
            raise ValueError(f"plane={plane!r}; valid: 'stress', 'strain'")
        t = np.radians(angle_deg)
        R = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
        T = _rotation_voigt(R, 2)
        return T @ C @ T.T
    if rotation is None:
        t = np.radians(angle_deg)
        rotation = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
    T = _rotation_voigt(np.asarray(rotation, float), 3)
    return T @ C3 @ T.T


def critical_energy_release_rate(K_Ic: float, E: float, nu: float = 0.0, plane: str = "stress") -> float:
    """G_c = K_Ic^2 / E (plane stress) or K_Ic^2 (1 - nu^2) / E (plane strain, 3D), J/m^2."""
    if not (K_Ic > 0):
        raise ValueError(f"K_Ic={K_Ic!r} Pa m^0.5; valid: > 0")
    return K_Ic ** 2 / E if plane == "stress" else K_Ic ** 2 * (1 - nu * nu) / E


def full_tensor(Cv, dim):
    """Full C_ijkl (tensor shear) from the Voigt matrix (engineering shear)."""
    pairs = _voigt_pairs(dim)
    C4 = np.zeros((dim,) * 4)
    for I, (i, j) in enumerate(pairs):
        for J, (k, l) in enumerate(pairs):
            for a, b in {(i, j), (j, i)}:
                for c, d in {(k, l), (l, k)}:
                    C4[a, b, c, d] = Cv[I, J]
    return C4
