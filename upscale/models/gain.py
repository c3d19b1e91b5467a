"""The stochastic-projection gain matrix G (seed 004, eqs. 5.9 and 6.1-6.6).

For a central particle c with neighbours n inside the influence radius (horizon) delta,
weights w_n = kappa(|x_n - x_c|) v_n (kappa: smoothing function, v_n: particle volume),

    beta_n  = x_n - x_c                 reference relative position
    alpha_n = u_n - u_c                 relative displacement          (eq. 6.10)
    Theta   = sum_n w_n alpha_n beta_n^T                               (eq. 6.3)
    Lambda  = (1/W) (sum_n w_n alpha_n)(sum_n w_n beta_n)^T            (eq. 6.4)
    Upsilon = [sum_n w_n beta_n beta_n^T - (1/W)(sum w beta)(sum w beta)^T]^-1   (eq. 6.5)
    G       = (Theta - Lambda) Upsilon                                 (eq. 6.1)

with W = sum_n w_n. This is the sample form of eq. 5.9,
G = (pi((y-x) h^T) - pi(y-x) pi(h)^T) Var(h)^-1: a weighted covariance of displacement and
position differences times the inverse weighted variance of the positions.

Two deliberate choices, both reducing to the printed equations on a symmetric (interior)
neighbourhood where sum_n w_n beta_n = 0:

* Lambda and the centring of Upsilon use W = sum kappa v (eq. 6.4 prints sum v) and Upsilon
  is the *centred* variance (eq. 6.5 prints the raw second moment; eq. 5.9 has Var(h)).
  With these G equals the displacement gradient H *exactly* for every affine field
  u = H x + c, at every particle, interior or not (appendix B.1 states it in the local limit).
* The stabilised displacement of eq. 6.6, u_bar_c = sum_n s_cn u_n with partition-of-unity
  weights s_cn = kappa_cn v_n / sum kappa v over the family including c, is optional
  (``stabilised=True``). When on, the same smoothing is applied to the reference positions
  (beta uses x_bar) so affine exactness is kept; the stencil of G then reaches neighbours
  of neighbours.

G is linear in the displacements: G_c = sum_e u_{j(e)} (x) a_e over the entries e of row c,
with coefficient vectors a_e (precomputed once, CSR per particle). Its derivative with
respect to u_j is therefore the fixed set {a_e}, and for any energy E = sum_c W_c(F_c) the
force is f_j = - sum_{e: j(e)=j} P_{c(e)} a_e with P_c = dW_c/dF_c (chain rule).
Since sum_e a_e = 0 in each row, the same coefficients applied to *positions* give the
deformation map F_c = F0_c + G_c, and rigid translations never enter.

Surfaces (a tube wall, a plate's mid-surface): points on a curved 2D manifold make the 3x3
Upsilon singular (flat patch) or ill-conditioned in the normal direction (curved patch).
With ``surface=True`` each particle gets a tangent frame T_c = [t1 t2] (3x2): the normal is
the eigenvector of the smallest eigenvalue of the weighted covariance of its family
(local PCA), oriented away from ``axis`` when given (tubes) and t2 is the projection of the
axis direction (the tube axis; any fixed direction otherwise), t1 = t2 x n. The reference
differences are replaced by their tangent coordinates s_n = T_c^T beta_n (2-vectors), so
Upsilon is 2x2 and G is the 3x2 *surface gain*: it maps reference tangent vectors to
deformed 3D vectors. For an affine field, G = H F0 exactly (F0 = fit of the reference
chords, equal to T on a symmetric neighbourhood); on a cylinder with a symmetric (theta, z)
grid, uniform radial/axial stretch is recovered exactly and a twist to O((h/R)^2).

Array suffix convention: ``_n`` per particle, ``_e`` per CSR entry, ``_c`` Cartesian.
"""
from __future__ import annotations

import dataclasses

import numba
import numpy as np
from scipy.spatial import cKDTree

__all__ = ["kappa", "GainOperator", "build_gain", "gain_coefficients", "gain_coefficients_quadratic"]


def kappa(r, horizon, kind: str = "quartic"):
    """Smoothing (influence) function kappa(r) of the gain matrix, kappa(0) = 1.

    Parameters
    ----------
    r : array_like
        Reference distances (same unit as ``horizon``).
    horizon : float
        Influence radius delta; kappa = 0 for r >= delta.
    kind : {"quartic", "constant", "gaussian"}
        ``quartic``: (1 - (r/delta)^2)^2; ``constant``: 1 (the seed's phi of eq. 5.14);
        ``gaussian``: exp(-4 (r/delta)^2) truncated at delta.
    """
    q = np.asarray(r, dtype=float) / horizon
    inside = q < 1.0
    if kind == "quartic":
        k = (1.0 - q * q) ** 2
    elif kind == "constant":
        k = np.ones_like(q)
    elif kind == "gaussian":
        k = np.exp(-4.0 * q * q)
    else:
        raise ValueError(f"unknown smoothing function kind={kind!r}; valid: quartic, constant, gaussian")
    return np.where(inside, k, 0.0)


@numba.njit(cache=True)
def _deformation_kernel(y_nc, offsets, neighbors, image_ed, cell_d, coef_ek, out):
    """out[c] = sum_e (y[j_e] + image_e * cell) (x) a_e (image_e: the periodic image of j_e,
    integer multiples of the cell lengths ``cell``; the shift formed per entry, not as an
    (nnz, 3) array per call)."""
    n = offsets.shape[0] - 1
    k = coef_ek.shape[1]
    for c in range(n):
        for i in range(3):
            for a in range(k):
                out[c, i, a] = 0.0
        for e in range(offsets[c], offsets[c + 1]):
            j = neighbors[e]
            for i in range(3):
                d = y_nc[j, i] + image_ed[e, i] * cell_d[i]
                for a in range(k):
                    out[c, i, a] += d * coef_ek[e, a]
    return out


@numba.njit(cache=True)
def _force_kernel(P_nck, offsets, neighbors, coef_ek, out):
    """out[j] = -sum_{e: j_e = j} P[c_e] a_e (serial: entries of different rows share j)."""
    n = offsets.shape[0] - 1
    k = coef_ek.shape[1]
    for i in range(out.shape[0]):
        for d in range(3):
            out[i, d] = 0.0
    for c in range(n):
        for e in range(offsets[c], offsets[c + 1]):
            j = neighbors[e]
            for i in range(3):
                s = 0.0
                for a in range(k):
                    s += P_nck[c, i, a] * coef_ek[e, a]
                out[j, i] -= s
    return out


@numba.njit(cache=True)
def _cell_derivative_kernel(P_nck, offsets, image_ed, coef_ek, out):
    """out[d] = sum_c sum_e (P[c] a_e)_d image_e[d]: dE/dL_d of E = sum_c W_c(F_c)."""
    n = offsets.shape[0] - 1
    k = coef_ek.shape[1]
    for c in range(n):
        for e in range(offsets[c], offsets[c + 1]):
            for i in range(3):
                if image_ed[e, i] == 0:
                    continue
                s = 0.0
                for a in range(k):
                    s += P_nck[c, i, a] * coef_ek[e, a]
                out[i] += s * image_ed[e, i]
    return out


@dataclasses.dataclass
class GainOperator:
    """Precomputed linear map u -> G (seed 004 eq. 6.1) for every particle.

    Attributes
    ----------
    offsets : (N+1,) int64
        CSR row pointers (row c holds the entries of particle c's G).
    neighbors : (nnz,) int64
        Particle j of each entry.
    image : (nnz, 3) int64
        Periodic image of j as seen from c (integer multiples of the cell lengths).
    coef : (nnz, k) float64
        Coefficient vectors a_e, unit 1/length; k = 3 (volume) or 2 (surface).
    F0 : (N, 3, k) float64
        Reference map: identity (k = 3) or the fitted reference chords ~ T (k = 2).
    frame : (N, 3, k) float64
        Identity (k = 3) or the tangent frame T_c = [t1 t2] (k = 2, surface).
    normal : (N, 3) float64 or None
        Unit normal of each particle (surface only).
    n_family : (N,) int64
        Number of neighbours within the horizon (the particle itself excluded).
    cell : (3,) float64
        Reference cell lengths (only used along periodic directions).
    pbc : (3,) bool
    horizon : float
    alive : (N,) bool
        False for particles dropped with ``on_singular="drop"`` (G undefined, row empty).
    pair_i, pair_j, pair_image : (npairs,) int64, (npairs,) int64, (npairs, 3) int64
        The full family (before any ``intact`` mask): the links between particles.
    offset : (N, 3, k) float64 or None
        Constant added to G (clamped grips, :func:`build_gain`'s ``clamp``), else None.
    fit_beta : (nnz, 3) float64 or None
        The reference link vectors of the entries that G was fitted against (the real
        ones, or with the axial coordinate clamped at the grip planes).
    """

    offsets: np.ndarray
    neighbors: np.ndarray
    image: np.ndarray
    coef: np.ndarray
    F0: np.ndarray
    frame: np.ndarray
    normal: np.ndarray | None
    n_family: np.ndarray
    cell: np.ndarray
    pbc: np.ndarray
    horizon: float
    alive: np.ndarray | None = None
    pair_i: np.ndarray | None = None
    pair_j: np.ndarray | None = None
    pair_image: np.ndarray | None = None
    offset: np.ndarray | None = None
    fit_beta: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.offsets.shape[0] - 1

    @property
    def k(self) -> int:
        return self.coef.shape[1]

    def gain(self, u, cell=None):
        """G of every particle for displacements ``u`` (N, 3) [length] -> (N, 3, k).

        ``cell`` is the deformed cell (periodic directions); the image displacement
        n (cell - cell0) enters the relative displacement of periodic neighbours.
        """
        u = np.ascontiguousarray(u, dtype=float)
        dcell = np.zeros(3) if cell is None else np.asarray(cell, dtype=float) - self.cell
        out = np.empty((self.n, 3, self.k))
        return _deformation_kernel(u, self.offsets, self.neighbors, self.image, dcell,
                                   self.coef, out)

    def deformation(self, y, cell=None, out=None):
        """F_c = F0_c + G_c from deformed positions ``y`` (N, 3) and deformed ``cell``.

        Uses sum_e a_e = 0 per row: sum_e (y_j + n_e L) (x) a_e = sum_e (u_j + n_e dL) (x) a_e + F0.
        """
        y = np.ascontiguousarray(y, dtype=float)
        if out is None:
            out = np.empty((self.n, 3, self.k))
        cell = self.cell if cell is None else cell
        _deformation_kernel(y, self.offsets, self.neighbors, self.image,
                            np.ascontiguousarray(cell, dtype=float), self.coef, out)
        if self.offset is not None:  # clamped grips (build_gain's ``clamp``)
            out += self.offset
        return out

    def forces(self, P, out=None):
        """Forces -dE/dy (N, 3) for E = sum_c W_c(F_c), given P_c = dW_c/dF_c (N, 3, k)."""
        P = np.ascontiguousarray(P, dtype=float)
        if out is None:
            out = np.empty((self.n, 3))
        return _force_kernel(P, self.offsets, self.neighbors, self.coef, out)

    def cell_derivative(self, P):
        """dE/dL_d (3,) for E = sum_c W_c(F_c): derivative w.r.t. the cell lengths."""
        P = np.ascontiguousarray(P, dtype=float)
        return _cell_derivative_kernel(P, self.offsets, self.image, self.coef, np.zeros(3))


def _family(x, horizon, cell, pbc):
    """Neighbour pairs within the horizon with periodic images: (i, j, image (m,3) int)."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    reps = []
    for d in range(3):
        if pbc[d]:
            nrep = int(np.ceil(horizon / cell[d]))
            reps.append(np.arange(-nrep, nrep + 1))
        else:
            reps.append(np.array([0]))
    images = np.array(np.meshgrid(*reps, indexing="ij")).reshape(3, -1).T
    tree = cKDTree(x)
    ii, jj, im = [], [], []
    for img in images:
        shifted = x + img * cell
        pairs = tree.query_ball_point(shifted, r=horizon * (1 - 1e-12), return_sorted=False)
        for j, lst in enumerate(pairs):  # x_i near x_j + img
            for i in lst:
                if i == j and not img.any():
                    continue
                ii.append(i)
                jj.append(j)
                im.append(img)
    ii = np.array(ii, dtype=np.int64)
    jj = np.array(jj, dtype=np.int64)
    im = np.array(im, dtype=np.int64).reshape(-1, 3)
    order = np.lexsort((jj, ii))
    return ii[order], jj[order], im[order], n


def build_gain(x, horizon, volume=None, *, surface: bool = False, axis=None, axis_point=None,
               cell=None, pbc=(False, False, False), kind: str = "quartic",
               stabilised: bool = False, rcond: float = 1e-10, intact=None,
               on_singular: str = "raise", clamp=None) -> GainOperator:
    """Precompute the gain operator of every particle (seed 004 eqs. 6.1-6.6).

    Parameters
    ----------
    x : (N, 3) float
        Reference positions [length].
    horizon : float
        Influence radius delta [length], > 0.
    volume : (N,) float, optional
        Particle volumes v_n (areas for a surface); 1 when omitted.
    surface : bool
        Build the 3x2 surface gain on tangent frames (see module docstring).
    axis, axis_point : (3,) float, optional
        Surface only: direction used for t2 (tube axis) and a point on that axis; the
        normal is oriented away from the axis line.
    cell : (3,) float, optional
        Lengths of an orthorhombic periodic cell (origin at 0); needed where ``pbc``.
    pbc : (3,) bool
    kind : str
        Smoothing function, see :func:`kappa`.
    stabilised : bool
        Use the stabilised displacement of eq. 6.6 (see module docstring).
    rcond : float
        A particle whose Upsilon^-1 has smallest/largest eigenvalue below ``rcond`` is
        rejected as having too few (or degenerate) neighbours.
    intact : (npairs,) bool, optional
        Mask over the family pairs (``op.pair_i``, ``op.pair_j``, ``op.pair_image`` of an
        operator built with the same arguments): broken links are left out of G.
    on_singular : {"raise", "drop"}
        What to do with a particle whose G is singular: raise (default; bad input), or
        drop it (``op.alive[c] = False``, empty row; used after links break).
    clamp : (z_lo, z_hi, rigid[, x_ref]) or None
        Rigid grips along z (open directions only, no ``stabilised``): the material beyond
        the planes z_lo < z_hi does not deform, and ``rigid`` (N,) bool marks the particles
        held there. G is then fitted against the *stretchable* axial coordinate
        phi(z) = clip(z, z_lo, z_hi) instead of z (the part of a link beyond a plane has no
        strain to give), G_c = G_ref,c + sum_n a_cn (x) (y_n - x_ref,n) (``op.offset`` holds
        the constant; x_ref: the state the grips take hold of, default x; G_ref: the plain
        G there), for the particles whose family reaches past a plane (the others keep the
        plain G and ``op.offset`` is zero for them). A rigid particle whose family reaches
        the gauge stands for the material between its plane and the gauge: its G is fitted
        about the plane (its clamped coordinate), so it sees the strain of that gap; a
        rigid particle deeper in has G = G_ref,c. So a gauge stretched uniformly between
        rigid grips gives every particle exactly its strain, however the rows fall about
        the planes; with the plain stencil the particles next to a plane mix the grip's
        zero strain into theirs and the grips' own particles take strain from the gauge,
        which lengthens the effective gauge by about a row spacing per grip.

    Raises
    ------
    ValueError
        One line naming the first particle whose neighbours within the horizon give a
        singular Upsilon, and the number of neighbours it has.
    """
    x = np.ascontiguousarray(x, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or not np.all(np.isfinite(x)):
        raise ValueError(f"positions must be a finite (N, 3) array, got shape {x.shape}")
    if not (horizon > 0 and np.isfinite(horizon)):
        raise ValueError(f"influence radius must be a positive number, got {horizon!r}")
    n = len(x)
    v = np.ones(n) if volume is None else np.asarray(volume, dtype=float)
    if v.shape != (n,) or np.any(v <= 0):
        raise ValueError("volume must be (N,) and positive")
    pbc = np.asarray(pbc, dtype=bool)
    cellv = np.zeros(3) if cell is None else np.asarray(cell, dtype=float)
    if np.any(pbc & ~(cellv > 0)):
        raise ValueError(f"periodic directions need positive cell lengths, got cell={cellv.tolist()}")
    if on_singular not in ("raise", "drop"):
        raise ValueError(f"on_singular={on_singular!r}; valid: 'raise', 'drop'")
    ii, jj, im, _ = _family(x, horizon, cellv, pbc)
    pairs = (ii.copy(), jj.copy(), im.copy())
    if intact is not None:
        intact = np.asarray(intact, dtype=bool)
        if intact.shape != ii.shape:
            raise ValueError(f"intact mask has shape {intact.shape}, the family has {len(ii)} pairs")
        ii, jj, im = ii[intact], jj[intact], im[intact]
    beta = x[jj] + im * cellv - x[ii]
    w = kappa(np.linalg.norm(beta, axis=1), horizon, kind) * v[jj]
    rigid = None
    if clamp is not None:
        z_lo, z_hi, rigid = float(clamp[0]), float(clamp[1]), np.asarray(clamp[2], dtype=bool)
        x_ref = np.asarray(clamp[3], dtype=float) if len(clamp) > 3 else x
        if pbc[2] or stabilised or rigid.shape != (n,) or not z_lo < z_hi:
            raise ValueError(f"clamp=({z_lo}, {z_hi}, rigid {rigid.shape}) with pbc={pbc.tolist()}"
                             f", stabilised={stabilised}; valid: z_lo < z_hi, rigid (N,) bool, "
                             "z not periodic, stabilised False")
        xs = x.copy()
        xs[:, 2] = np.clip(x[:, 2], z_lo, z_hi)  # the stretchable axial coordinate
        low = x[:, 2] < 0.5 * (z_lo + z_hi)  # a held particle sits at its grip's plane
        xs[rigid & low, 2], xs[rigid & ~low, 2] = z_lo, z_hi
    alive = np.ones(n, dtype=bool)
    fam_off = np.zeros(n + 1, dtype=np.int64)
    np.add.at(fam_off, ii + 1, 1)
    fam_off = np.cumsum(fam_off)
    n_family = np.diff(fam_off)

    if stabilised:
        # smoothing rows s_cn over the family including c itself (kappa(0) = 1)
        s_i = np.concatenate([np.arange(n), ii])
        s_j = np.concatenate([np.arange(n), jj])
        s_im = np.concatenate([np.zeros((n, 3), np.int64), im])
        s_w = np.concatenate([v, w])
        order = np.lexsort((s_j, s_i))
        s_i, s_j, s_im, s_w = s_i[order], s_j[order], s_im[order], s_w[order]
        tot = np.zeros(n)
        np.add.at(tot, s_i, s_w)
        s_w = s_w / tot[s_i]
        s_off = np.zeros(n + 1, dtype=np.int64)
        np.add.at(s_off, s_i + 1, 1)
        s_off = np.cumsum(s_off)
        xbar = np.zeros((n, 3))
        np.add.at(xbar, s_i, s_w[:, None] * (x[s_j] + s_im * cellv))
        beta_fit = xbar[jj] + im * cellv - xbar[ii]
    else:
        beta_fit = beta if clamp is None else xs[jj] + im * cellv - xs[ii]

    k = 2 if surface else 3
    frame = np.zeros((n, 3, k))
    normal = None
    if surface:
        normal = np.zeros((n, 3))
        ax = np.array([0.0, 0.0, 1.0]) if axis is None else np.asarray(axis, float)
        ax = ax / np.linalg.norm(ax)
        ap = np.zeros(3) if axis_point is None else np.asarray(axis_point, float)
    coef = np.zeros((len(ii), k))
    F0 = np.zeros((n, 3, k))
    own_rows = []  # (c, coefficient of y_c) of the families fitted about c (``clamp``)
    touched = np.zeros(n, bool)  # particles whose G the grips change (``clamp``)
    F0_std = np.zeros((n, 3, k))
    G_ref = np.zeros((n, 3, k))
    for c in range(n):
        sl = slice(fam_off[c], fam_off[c + 1])
        b, wc = beta_fit[sl], w[sl]
        W = wc.sum()
        if (len(wc) < k + 1 or W <= 0) and on_singular == "drop":
            alive[c] = False
            continue
        if len(wc) < k + 1 or W <= 0:
            raise ValueError(
                f"particle {c} has {len(wc)} neighbours with nonzero weight within influence radius "
                f"{horizon:g}; G needs at least {k + 1} non-{'collinear' if k == 2 else 'coplanar'} ones "
                "(increase the influence radius)")
        if surface:
            bb = beta[sl]  # local PCA of the (unsmoothed) family: smallest axis = normal
            mean = (wc[:, None] * bb).sum(0) / W
            d = bb - mean
            cov = (wc[:, None, None] * d[:, :, None] * d[:, None, :]).sum(0)
            evals, evecs = np.linalg.eigh(cov)
            nrm = evecs[:, 0]
            if axis is not None:
                radial = x[c] - ap - np.dot(x[c] - ap, ax) * ax
                if np.dot(nrm, radial) < 0:
                    nrm = -nrm
            elif nrm[np.argmax(np.abs(nrm))] < 0:
                nrm = -nrm
            t2 = ax - np.dot(ax, nrm) * nrm
            if np.linalg.norm(t2) < 1e-8:  # axis along the normal: pick any tangent
                t2 = np.cross(nrm, [1.0, 0.0, 0.0])
                if np.linalg.norm(t2) < 1e-8:
                    t2 = np.cross(nrm, [0.0, 1.0, 0.0])
            t2 /= np.linalg.norm(t2)
            t1 = np.cross(t2, nrm)
            T = np.column_stack([t1, t2])
            normal[c] = nrm
            frame[c] = T
            s = b @ T
        else:
            frame[c] = np.eye(3)
            s = b
        own = False
        if rigid is not None and (rigid[c] or np.any(beta_fit[sl] != beta[sl])):
            # a particle the grips touch: its plain fit (real coordinates, centred) gives the
            # reference chords F0 and G at x_ref, about which its clamped G is linearised
            sr = beta[sl] @ frame[c] if surface else beta[sl]
            dr = sr - (wc[:, None] * sr).sum(0) / W
            Mr = (wc[:, None, None] * dr[:, :, None] * dr[:, None, :]).sum(0)
            ar = wc[:, None] * (dr @ np.linalg.inv(Mr))
            nb = jj[sl]
            shift = im[sl] * cellv
            touched[c] = True
            F0_std[c] = np.einsum("ei,ea->ia", x[nb] + shift, ar)
            G_ref[c] = np.einsum("ei,ea->ia", x_ref[nb] + shift, ar)
            if rigid[c] and rigid[nb].all():  # held, deep in a grip: G = G_ref
                continue
            # a family that reaches past a grip plane is not symmetric in the clamped
            # coordinate: its fit is taken about c itself (eta_n = y_n - y_c, the uncentred
            # form of eq. 6.5), which gives y_c a coefficient; centred, the row next to a
            # plane would not feel its own position and one of the two row parities would
            # end free at the grip
            own = True
        sbar = np.zeros(k) if own else (wc[:, None] * s).sum(0) / W
        ds = s - sbar
        M = (wc[:, None, None] * ds[:, :, None] * ds[:, None, :]).sum(0)  # Upsilon^-1
        ev = np.linalg.eigvalsh(M)
        if ev[0] <= rcond * max(ev[-1], 1e-300) and on_singular == "drop":
            alive[c] = False
            continue
        if ev[0] <= rcond * max(ev[-1], 1e-300):
            raise ValueError(
                f"particle {c}: its {len(wc)} neighbours within influence radius {horizon:g} give a "
                f"singular Upsilon (need {k + 1} non-{'collinear' if k == 2 else 'coplanar'} ones); "
                "increase the influence radius")
        Ups = np.linalg.inv(M)  # eq. 6.5 (centred)
        a = wc[:, None] * (ds @ Ups)  # a_n = w_n Upsilon (s_n - s_bar)
        coef[sl] = a
        if own:
            own_rows.append((c, -a.sum(0)))

    coef[~alive[ii]] = 0.0
    if stabilised:
        # compose: G_c = sum_n a_cn (x) u_bar_n, u_bar_n = sum_j s_nj u_j (images add up)
        rows_i, rows_j, rows_im, rows_a = [], [], [], []
        for c in range(n):
            sl = slice(fam_off[c], fam_off[c + 1])
            nn, imn, an = jj[sl], im[sl], coef[sl]
            cnt = s_off[nn + 1] - s_off[nn]
            idx = np.concatenate([np.arange(s_off[q], s_off[q + 1]) for q in nn])
            rep = np.repeat(np.arange(len(nn)), cnt)
            rows_i.append(np.full(len(idx), c, np.int64))
            rows_j.append(s_j[idx])
            rows_im.append(imn[rep] + s_im[idx])
            rows_a.append(an[rep] * s_w[idx][:, None])
            # the smoothing of the centre, u_bar_c, is cancelled by the centring: no term
        ii = np.concatenate(rows_i)
        jj = np.concatenate(rows_j)
        im = np.concatenate(rows_im)
        coef = np.concatenate(rows_a)
        # merge duplicate (j, image) entries of a row
        key = np.column_stack([ii, jj, im])
        uniq, inv = np.unique(key, axis=0, return_inverse=True)
        inv = inv.ravel()
        merged = np.zeros((len(uniq), k))
        np.add.at(merged, inv, coef)
        ii, jj, im, coef = uniq[:, 0], uniq[:, 1], uniq[:, 2:5], merged
        fam_off2 = np.zeros(n + 1, dtype=np.int64)
        np.add.at(fam_off2, ii + 1, 1)
        offsets = np.cumsum(fam_off2)
    else:
        offsets = fam_off
    if own_rows:  # add the entries of y_c to their rows (CSR order kept by a stable sort)
        oc = np.array([r[0] for r in own_rows], np.int64)
        ii = np.concatenate([ii, oc])
        jj = np.concatenate([jj, oc])
        im = np.concatenate([im, np.zeros((len(oc), 3), im.dtype)])
        coef = np.concatenate([coef, np.array([r[1] for r in own_rows])])
        beta_fit = np.concatenate([beta_fit, np.zeros((len(oc), 3))])
        order = np.argsort(ii, kind="stable")
        ii, jj, im, coef, beta_fit = ii[order], jj[order], im[order], coef[order], beta_fit[order]
        offsets = np.zeros(n + 1, dtype=np.int64)
        np.add.at(offsets, ii + 1, 1)
        offsets = np.cumsum(offsets)
    op = GainOperator(offsets=np.ascontiguousarray(offsets, np.int64),
                      neighbors=np.ascontiguousarray(jj, np.int64),
                      image=np.ascontiguousarray(im, np.int64),
                      coef=np.ascontiguousarray(coef, float), F0=F0, frame=frame, normal=normal,
                      n_family=n_family, cell=cellv, pbc=pbc, horizon=float(horizon),
                      alive=alive, pair_i=pairs[0], pair_j=pairs[1], pair_image=pairs[2])
    if not surface:
        op.F0 = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    else:
        op.F0 = op.deformation(x)  # the fitted reference chords (== T on symmetric families)
        op.F0[~alive] = frame[~alive]
    if clamp is not None:  # G_c = G_ref,c + sum a (x) (y - x_ref) where the grips touch
        op.offset = np.zeros((n, 3, k))
        t = touched & alive
        op.offset[t] = G_ref[t] - op.deformation(x_ref)[t]
        if surface:
            op.F0[t] = F0_std[t]
    op.fit_beta = beta_fit  # the reference link vectors G was fitted against (by family)
    return op


# ---------------------------------------------------------------------------- flat CSR form
@numba.njit(parallel=True, cache=True)
def gain_coefficients(xi_bc, offsets, weight_b, intact_b, dim, rcond, coef_bk, alive_n):
    """Centred gain coefficients a_b of every particle on an engine pair family (CSR).

    The same G as :func:`build_gain` without smoothing (eqs. 6.1-6.5, centred Upsilon),
    for volumes (``dim = 3``) or in-plane bodies (``dim = 2``: the in-plane components
    of the bond vectors, frame ``[e_x, e_y]``), evaluated on the family's flat arrays so
    that it can be recomputed cheaply whenever bonds break:

        beta_bar_c = sum_b w_b beta_b / sum_b w_b,    M_c = sum_b w_b d_b d_b^T,
        d_b = beta_b - beta_bar_c,  Upsilon_c = M_c^-1,  a_b = w_b Upsilon_c d_b,

    sums over the intact bonds b of row c. Then G_c = sum_b (u_j(b) - u_c) (x) a_b and,
    since sum_b a_b = 0, F_c = sum_b (y_j(b) - y_c) (x) a_b.

    Parameters
    ----------
    xi_bc : (nb, 3) float64
        Reference bond vectors x_j - x_c.
    offsets : (N+1,) int64
        CSR row pointers of the family (``Family.offsets``).
    weight_b : (nb,) float64
        w_b = kappa(|xi_b|) V_j (any positive unit; it cancels in G).
    intact_b : (nb,) bool
        Bonds that take part.
    dim : int
        2 or 3.
    rcond : float
        A row whose M has ``det(M) <= rcond * (tr(M)/dim)^dim`` (nearly singular, e.g.
        fewer than dim + 1 non-collinear/coplanar intact bonds) gets ``alive = False``
        and zero coefficients.
    coef_bk : (nb, dim) float64
        Output, mutated: a_b (unit 1/length); zero for broken bonds and dead rows.
    alive_n : (N,) bool
        Output, mutated: rows with a regular Upsilon.
    """
    n = offsets.shape[0] - 1
    for c in numba.prange(n):
        s0 = offsets[c]
        s1 = offsets[c + 1]
        W = 0.0
        bb = np.zeros(3)
        cnt = 0
        for b in range(s0, s1):
            for a in range(dim):
                coef_bk[b, a] = 0.0
            if intact_b[b]:
                W += weight_b[b]
                cnt += 1
                for a in range(dim):
                    bb[a] += weight_b[b] * xi_bc[b, a]
        alive_n[c] = False
        if cnt < dim + 1 or W <= 0.0:
            continue
        for a in range(dim):
            bb[a] /= W
        M = np.zeros((3, 3))
        for b in range(s0, s1):
            if intact_b[b]:
                for p in range(dim):
                    dp = xi_bc[b, p] - bb[p]
                    for q in range(dim):
                        M[p, q] += weight_b[b] * dp * (xi_bc[b, q] - bb[q])
        U = np.zeros((3, 3))
        tr = 0.0
        for a in range(dim):
            tr += M[a, a]
        if dim == 2:
            det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
            if not det > rcond * (tr / 2.0) ** 2:
                continue
            U[0, 0] = M[1, 1] / det
            U[1, 1] = M[0, 0] / det
            U[0, 1] = -M[0, 1] / det
            U[1, 0] = -M[1, 0] / det
        else:
            det = (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
                   - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
                   + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))
            if not det > rcond * (tr / 3.0) ** 3:
                continue
            for p in range(3):
                for q in range(3):
                    p1, p2 = (p + 1) % 3, (p + 2) % 3
                    q1, q2 = (q + 1) % 3, (q + 2) % 3
                    U[q, p] = (M[p1, q1] * M[p2, q2] - M[p1, q2] * M[p2, q1]) / det
        alive_n[c] = True
        for b in range(s0, s1):
            if intact_b[b]:
                for a in range(dim):
                    s = 0.0
                    for q in range(dim):
                        s += U[a, q] * (xi_bc[b, q] - bb[q])
                    coef_bk[b, a] = weight_b[b] * s
    return coef_bk, alive_n


@numba.njit(cache=True)
def _quadratic_basis(xi_bc, b, dim, L, p):
    """The basis of the quadratic fit at bond ``b`` into ``p`` (1 + dim + dim (dim + 1) / 2,):
    1, xi_a / L, xi_a xi_q / L^2 (a <= q), L the family's largest bond length."""
    p[0] = 1.0
    for a in range(dim):
        p[1 + a] = xi_bc[b, a] / L
    k = 1 + dim
    for a in range(dim):
        for q in range(a, dim):
            p[k] = xi_bc[b, a] * xi_bc[b, q] / (L * L)
            k += 1


@numba.njit(parallel=True, cache=True)
def gain_coefficients_quadratic(xi_bc, offsets, weight_b, intact_b, dim, rcond, qcond, coef_bk, alive_n,
                                quadratic_n):
    """Second-order gain coefficients: the gradient of a weighted least-squares quadratic fit.

    The centred gain of :func:`gain_coefficients` is the gradient part of the weighted
    least-squares fit of u_j - u_c over the family by the basis p(beta) = [1, beta]; here
    the basis is p(beta) = [1, beta, quadratic monomials of beta / L] (L = the row's
    longest bond, for conditioning: 6 functions in 2D, 10 in 3D):

        A_c = sum_b w_b p_b p_b^T,   a_b = w_b [A_c^-1 p_b]_(gradient part),
        F_c = sum_b (y_j(b) - y_c) (x) a_b.

    A is exact for every quadratic field, at boundary and crack-face particles too, where
    the linear fit of a one-sided family picks up an error of order delta x (second
    gradient). On a point-symmetric family the odd moments vanish, the gradient decouples
    from the constant and the quadratic terms and the coefficients equal the linear ones
    exactly (interior particles of a regular grid are unchanged). Still linear in y, still
    sum_b a_b = 0 (the constant of the basis), so forces and tangents built from a_b are
    unchanged in form.

    Rows whose A has ``lambda_min / lambda_max <= qcond`` (too few or too flat intact
    bonds for a quadratic fit) keep the linear coefficients (``quadratic_n`` False);
    rows that fail the linear test of :func:`gain_coefficients` (``rcond``) are dead.
    Arguments and outputs as :func:`gain_coefficients`; ``quadratic_n`` (N,) bool is
    mutated.
    """
    gain_coefficients(xi_bc, offsets, weight_b, intact_b, dim, rcond, coef_bk, alive_n)
    n = offsets.shape[0] - 1
    nq = dim * (dim + 1) // 2
    nbas = 1 + dim + nq
    for c in numba.prange(n):
        quadratic_n[c] = False
        if not alive_n[c]:
            continue
        s0 = offsets[c]
        s1 = offsets[c + 1]
        L = 0.0
        for b in range(s0, s1):
            if intact_b[b]:
                l2 = 0.0
                for a in range(dim):
                    l2 += xi_bc[b, a] * xi_bc[b, a]
                if l2 > L:
                    L = l2
        L = np.sqrt(L)
        A = np.zeros((nbas, nbas))
        p = np.zeros(nbas)
        for b in range(s0, s1):
            if not intact_b[b]:
                continue
            _quadratic_basis(xi_bc, b, dim, L, p)
            for r in range(nbas):
                for q in range(nbas):
                    A[r, q] += weight_b[b] * p[r] * p[q]
        ev, V = np.linalg.eigh(A)
        if not ev[0] > qcond * ev[nbas - 1]:
            continue
        Ainv = np.zeros((nbas, nbas))
        for r in range(nbas):
            for q in range(nbas):
                s = 0.0
                for e in range(nbas):
                    s += V[r, e] * V[q, e] / ev[e]
                Ainv[r, q] = s
        quadratic_n[c] = True
        for b in range(s0, s1):
            if not intact_b[b]:
                continue
            _quadratic_basis(xi_bc, b, dim, L, p)
            for a in range(dim):
                s = 0.0
                for q in range(nbas):
                    s += Ainv[1 + a, q] * p[q]
                coef_bk[b, a] = weight_b[b] * s / L
    return coef_bk, alive_n
