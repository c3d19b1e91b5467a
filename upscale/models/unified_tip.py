"""Crack-tip fields and the crack front of the unified model's failure criterion
(:mod:`upscale.models.unified`, whose module docstring gives the equations): the Williams
tip stress, its disc average beta (continuum and on the model's own lattice), the
nearest-neighbour crack front, and the r_s averaging matrix. Units: SI."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["williams_angular", "disc_average_factor", "tip_disc_stress", "FRONT_RADIUS", "front_pairs",
           "crack_front", "averaging_matrix", "LATTICE_TIP_MAX_RATIO", "lattice_tip_factor"]


def williams_angular(K_I, K_II, t):
    """Angular part of the near-tip stress: (f_xx, f_yy, f_xy) with sigma_ij = f_ij /
    sqrt(2 pi r) (Pa m^0.5 per K), t the polar angle from the crack line ahead of the tip
    (crack faces at t = +-pi), x ahead and y normal to the crack; T adds to sigma_xx."""
    c2, s2, c32, s32 = np.cos(t / 2), np.sin(t / 2), np.cos(1.5 * t), np.sin(1.5 * t)
    fxx = K_I * c2 * (1 - s2 * s32) - K_II * s2 * (2 + c2 * c32)
    fyy = K_I * c2 * (1 + s2 * s32) + K_II * s2 * c2 * c32
    fxy = K_I * c2 * s2 * c32 + K_II * c2 * (1 - s2 * s32)
    return fxx, fyy, fxy


def disc_average_factor(dim: int = 2, n_quad: int = 400, p: float | None = None) -> tuple[float, float]:
    """(beta, p): the largest average of the mode-I tip stress sigma_yy over a disc (dim 2)
    or ball (dim 3, the plane-strain field constant along z) of radius r_s, in units K /
    sqrt(r_s), and the distance p / r_s of its centre ahead of the tip (module docstring).
    With ``p`` given, the average about the centre p r_s ahead of the tip instead of the
    largest (p = 0: the tip-centred disc, 0.40636 in 2D; the factor of ``growth="front"``).

    2D: sigma_bar_yy(p) = int_{-pi}^{pi} f_yy(t) (2/3) r_2^(3/2) dt / (pi sqrt(2 pi)),
    r_2 = p cos t + sqrt(1 - p^2 sin^2 t), Gauss-Legendre in t, maximised over p in [0, 1).
    3D: the ball's slices z = const are discs of radius sqrt(1 - z^2) (weights pi (1 - z^2)
    of the ball's volume 4 pi / 3), each averaged by the 2D formula (rays from a tip outside
    a slice meet it between r_1 and r_2, the integrand then (2/3)(r_2^(3/2) - r_1^(3/2))).
    """
    from scipy.optimize import minimize_scalar

    if dim not in (2, 3):
        raise ValueError(f"dim={dim!r}; valid: 2, 3")
    x, w = np.polynomial.legendre.leggauss(n_quad)
    t, w = np.pi * x, np.pi * w
    fyy = williams_angular(1.0, 0.0, t)[1]

    def disc(p, rho):
        # disc of radius rho centred at p ahead of the tip, average in units K / sqrt(rho)
        # (the tip outside the disc, q > 1: rays meet it between r_1 and r_2)
        q = p / rho
        disc_ = 1 - (q * np.sin(t)) ** 2
        hit = (disc_ > 0) & ((q < 1) | (np.cos(t) > 0))
        sq = np.sqrt(np.where(hit, disc_, 0.0))
        r2 = np.where(hit, q * np.cos(t) + sq, 0.0)
        r1 = np.where(hit & (q >= 1), np.maximum(q * np.cos(t) - sq, 0.0), 0.0)
        g = (2.0 / 3.0) * (r2 ** 1.5 - r1 ** 1.5)
        return np.sum(w * fyy * g) / (np.pi * np.sqrt(2 * np.pi)) / np.sqrt(rho)

    if dim == 2:
        f = lambda p: -disc(p, 1.0)
    else:
        zq, wq = np.polynomial.legendre.leggauss(64)
        rho = np.sqrt(1 - zq ** 2)

        def f(p):
            return -np.sum(wq * np.pi * rho ** 2 * np.array([disc(p, r) for r in rho])) / (4 * np.pi / 3)
    if p is not None:
        if not (0.0 <= p < 1.0):
            raise ValueError(f"p={p!r}; valid: 0 <= p < 1 (the centre's distance ahead of the tip / r_s)")
        return float(-f(p)), float(p)
    r = minimize_scalar(f, bounds=(0.0, 0.99), method="bounded", options={"xatol": 1e-9})
    return float(-r.fun), float(r.x)


def tip_disc_stress(K_I, K_II, T, r_s):
    """The near-tip field K_I, K_II (Pa m^0.5), T (Pa) averaged over the disc of radius
    r_s (m) centred at the tip, in the crack frame (x ahead of the tip, y normal): the
    continuum limit of what ``growth="front"`` compares with sigma_c as the spacing falls.
    Returns (s_xx, s_yy, s_xy, s_1): the averaged components and their largest principal
    value (Pa). (The direction of growth is not the principal direction of this average:
    the front particle that fails first is the one whose disc, centred a fraction of a
    spacing from the tip, has the largest s_1, i.e. it follows the gradient of s_1 with
    the disc's centre.)

    With sigma_ij = K f_ij(t) / sqrt(2 pi r) the average is (2/3) int_{-pi}^{pi} f_ij dt /
    (pi sqrt(2 pi r_s)); the integrals are 4.8 (mode I, yy), 3.2 (mode I, xx), 3.2 (mode II,
    xy) and zero for the odd ones (mode I xy, mode II xx and yy), and T adds to s_xx:

        s_yy = c 4.8 K_I,  s_xx = c 3.2 K_I + T,  s_xy = c 3.2 K_II,  c = (2/3) / (pi sqrt(2 pi r_s)),

    so in pure mode I s_1 = s_yy = 0.40636 K_I / sqrt(r_s) (:func:`disc_average_factor` at
    p = 0), the criterion then met at K_I = K_Ic for every r_s; T and K_II enter over r_s,
    like the critical distance of the generalised MTS criterion. Higher Williams terms are
    left out (r_s small against the crack and the ligament)."""
    if not (np.all(np.asarray(r_s) > 0)):
        raise ValueError(f"r_s={r_s!r} m; valid: r_s > 0")
    c = (2.0 / 3.0) / (np.pi * np.sqrt(2 * np.pi * np.asarray(r_s, float)))
    sxx = c * 3.2 * np.asarray(K_I, float) + np.asarray(T, float)
    syy = c * 4.8 * np.asarray(K_I, float)
    sxy = c * 3.2 * np.asarray(K_II, float)
    s1 = 0.5 * (sxx + syy) + np.sqrt(0.25 * (syy - sxx) ** 2 + sxy ** 2)
    return sxx, syy, sxy, s1


#: nearest-neighbour radius of the crack front, in spacings (the 8 / 18 lattice neighbours
#: of a square / cubic lattice in 2D / 3D)
FRONT_RADIUS = 1.5


def front_pairs(x, spacing, owner, neighbors, n):
    """Nearest-neighbour pairs of the crack-front rule: (i, j, b) for every pair closer
    than :data:`FRONT_RADIUS` spacings in the reference positions ``x`` (N, dim), b the
    directed bond i -> j of the family (``owner``, ``neighbors``) or -1 when the family has
    no such bond (a bond cut by a pre-crack)."""
    from scipy.spatial import cKDTree

    pr = cKDTree(x).query_pairs(FRONT_RADIUS * spacing, output_type="ndarray")
    keys = owner.astype(np.int64) * n + neighbors
    o = np.argsort(keys)
    want = pr[:, 0].astype(np.int64) * n + pr[:, 1]
    k = np.minimum(np.searchsorted(keys[o], want), keys.size - 1)
    b = np.where(keys[o][k] == want, o[k], -1)
    return pr[:, 0], pr[:, 1], b


def crack_front(pairs, intact, alive, n):
    """(N,) bool: particles next to a crack, i.e. with a nearest neighbour (:func:`front_pairs`)
    to which the bond is cut or broken, or which carries no stress (a void)."""
    i, j, b = pairs
    cut = (b < 0) | ~intact[np.maximum(b, 0)] | ~alive[i] | ~alive[j]
    return (np.bincount(i[cut], minlength=n) + np.bincount(j[cut], minlength=n)) > 0


def averaging_matrix(x, volume, radius):
    """Sparse (N, N) matrix of V_j over the pairs |x_j - x_c| <= radius (self included)."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(x).query_pairs(radius * (1 + 1e-9), output_type="ndarray")
    n = x.shape[0]
    i = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n)])
    j = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(n)])
    return sp.csr_matrix((volume[j], (i, j)), shape=(n, n))


#: above this r_s / spacing, ``tip_factor="lattice"`` takes the continuum factor
LATTICE_TIP_MAX_RATIO = 16.0


def lattice_tip_factor(r_s: float, spacing: float, horizon: float, *, E: float = 3.75e9, nu: float = 0.35,
                       plane: str = "stress", kernel: str = "quartic", rcond: float = 1e-6,
                       min_bonds: int = 0, gain_order: int = 1, growth: str = "free", field: str = "imposed",
                       stabilisation: float = 0.0, radius: float | None = None) -> tuple[float, float]:
    """(beta, p): :func:`disc_average_factor` on the model's own lattice. The exact mode-I
    tip displacement field (K = 1, isotropic E, nu; plane stress kappa = (3 - nu)/(1 + nu),
    plane strain 3 - 4 nu) is imposed on a square lattice of ``spacing`` (a disc of radius
    4 (r_s + horizon + spacing) about a tip at a cell corner, the crack a cut along -x
    between two rows); the gain's stress (which is itself a weighted average of the
    gradient over the horizon) is averaged over r_s as in the criterion, and beta is the
    largest principal value times sqrt(r_s) within r_s + horizon of the tip, p / r_s its
    distance ahead. With this beta the criterion reaches sigma_c exactly at K_I = K_Ic in
    a K-dominated field at this spacing and horizon, for any r_s / spacing (2D only).
    ``growth="front"``: the largest over the crack-front particles only (:func:`crack_front`,
    the particles next to the cut), as the criterion then allows failure only there.

    ``field="imposed"``: the exact field on every particle. ``field="solved"``: the exact
    field on the outer ring (one horizon thick) only, the rest relaxed to equilibrium with
    the model's bond penalty ``stabilisation``: the field the criterion meets in a fracture
    run, where the penalty resists the non-affine part of the near-tip deformation. With
    c_s = 1 the solved front stress is 8 % above the imposed one at r_s = spacing and 5 %
    below it at r_s = 4 spacings (so the imposed beta puts the first failure at K_I = 0.92
    to 1.06 K_Ic). ``radius``: the lattice disc's
    radius (default 4 (r_s + horizon + spacing); a larger disc changes beta by up to 0.35 %,
    through the one bond that passes exactly through the tip, cut or kept by rounding)."""
    from upscale.engine import ParticleSystem, bonds_crossing_segment, build_family
    from upscale.engine.quasistatic import Equilibrium
    from upscale.engine.state import State
    from upscale.models.unified import UnifiedModel

    if growth not in ("free", "front"):
        raise ValueError(f"growth={growth!r}; valid: 'free', 'front'")
    if field not in ("imposed", "solved"):
        raise ValueError(f"field={field!r}; valid: 'imposed', 'solved'")
    L = 4.0 * (r_s + horizon + spacing) if radius is None else float(radius)
    if not L > r_s + 2 * horizon:
        raise ValueError(f"radius={radius!r} m; valid: > r_s + 2 horizon = {r_s + 2 * horizon:g} m")
    n = int(np.ceil(L / spacing))
    g = (np.arange(-n, n) + 0.5) * spacing
    X, Y = np.meshgrid(g, g, indexing="ij")
    keep = X ** 2 + Y ** 2 <= L * L
    x0 = np.column_stack([X[keep], Y[keep], np.zeros(keep.sum())])
    sysm = ParticleSystem(x0, spacing * spacing, 1.0, dim=2, thickness=1.0, plane=plane, spacing=spacing)
    fam = build_family(sysm, horizon)
    cut = bonds_crossing_segment(x0, (-2 * L, 0.0), (0.0, 0.0))(fam.owner, fam.neighbors, fam.xi)
    fam = fam.remove_bonds(cut | cut[fam.reverse])
    model = UnifiedModel(E=E, nu=nu, plane=plane, kernel=kernel, rcond=rcond, min_bonds=min_bonds,
                         gain_order=gain_order, stabilisation=stabilisation if field == "solved" else 0.0)
    model.prepare(sysm, fam)
    mu = E / (2 * (1 + nu))
    kap = (3 - nu) / (1 + nu) if plane == "stress" else 3 - 4 * nu
    K = 1e-6 * E * np.sqrt(spacing)            # small: the Green strain stays linear
    r = np.hypot(x0[:, 0], x0[:, 1])
    th = np.arctan2(x0[:, 1], x0[:, 0])
    f = K / (2 * mu) * np.sqrt(r / (2 * np.pi))
    u = np.zeros_like(x0)
    u[:, 0] = f * np.cos(th / 2) * (kap - 1 + 2 * np.sin(th / 2) ** 2)
    u[:, 1] = f * np.sin(th / 2) * (kap + 1 - 2 * np.cos(th / 2) ** 2)
    st = State.reference(x0, fam.nb)
    if field == "solved":        # from the reference, so the tolerance is relative to the full load
        ring = np.zeros((sysm.n, 3), bool)
        ring[r > L - horizon, :2] = True
        Equilibrium(model, ring, preconditioner="cholmod", tol=1e-8, max_iter=60).solve(st, u)
    else:
        st.y += u
    S = model.continuum_fields(st)[2]
    A = averaging_matrix(x0[:, :2], sysm.volume, r_s)
    wv = model.alive.astype(float)
    Sb = (A @ (wv[:, None] * S.reshape(-1, 4))) / np.maximum(A @ wv, 1e-300)[:, None]
    s1 = np.linalg.eigvalsh(Sb.reshape(-1, 2, 2))[:, -1]
    near = r <= r_s + horizon
    if growth == "front":
        near &= crack_front(front_pairs(x0[:, :2], spacing, fam.owner, fam.neighbors, sysm.n),
                            np.ones(fam.nb, bool), model.alive, sysm.n)
    i = np.flatnonzero(near)[np.argmax(s1[near])]
    return float(s1[i] * np.sqrt(r_s) / K), float(x0[i, 0] / r_s)
