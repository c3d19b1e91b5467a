"""Upscaled (DCBR) nanotube: coarse particles carrying the Tersoff lattice through G.

Seed 004, sec. 5.3.1, eqs. 5.13-5.16. Coarse particles sit on the tube wall in a regular
(theta, z) arrangement whose spacing is ``coarsening`` times the graphene lattice constant
a = sqrt(3) a_cc; each carries ``N_c = N_atoms / N_particles`` atoms and the tube's own
lattice. Its energy is N_c times the Tersoff energy per atom of that lattice with the bonds
mapped by its gain (eq. 5.13), bond-order angular terms included, the shift between the two
sublattices relaxed; the total is the discrete eq. 5.15 with V_I = N_c.

**How the bonds are mapped (curvature).** The 3x2 surface gain F_c of particle c (module
:mod:`upscale.models.gain`) maps reference tangent vectors (e_theta, e_z) to deformed 3D
vectors; its frame-invariant content is the surface metric C = S F^T F S (S = (F0^T F0)^-1/2,
identity on the regular grid). Mapping flat graphene bonds with F (eq. 5.13 literally,
r = F delta) ignores the wall curvature: for a (10,10) tube the chord of a bond differs from
its arc by ~0.1 % and the bond angles by ~1 degree, and the Tersoff angular term sees that
(the flat-cell energy misses the curvature energy). We therefore map the *tube's own atoms*:
a closed tube admits exactly the uniform maps

    s' = lam_t s + gam z,  z' = lam_z z,  radius' = lam_t R0      (s = R0 theta, arc)

(M = [[lam_t, gam], [0, lam_z]] upper triangular: the chiral vector must close on itself),
and M^T M = C fixes (lam_t, gam, lam_z) uniquely (Cholesky). The mapped bonds are chords of
the deformed cylinder; in the flat limit R0 -> inf this is r = F delta again. The two-atom
basis gets a shift (d_rho, d_s, d_z) of sublattice B; e(C) = min over the shift. Then for a
uniformly strained periodic tube the coarse energy per atom equals the atomistic one (the
uniformly strained tube *is* this two-atom helical cell), which ``python -m validation
dcbr-energy`` checks against LAMMPS (1 % of the strain energy per atom).

**Forces.** dW/dF = 2 N_c F S (de/dC) S by the chain rule through (lam_t, gam, lam_z), then
through G (linear in positions) to particle forces (:meth:`GainOperator.forces`). The
sublattice shifts are extra per-particle unknowns minimised together with the positions
(quasi-static scenes), so de/d shift = 0 at every solution (envelope theorem).

**Failure rules** (no fitted parameter; both are properties of the molecular potential).

1. Lattice stability (the rule that decides the strength of a perfect tube): after each
   load step the most loaded particle's lattice, mapped uniformly onto the smallest
   periodic piece of the real tube at least twice the cutoff long, is tested for a negative
   eigenvalue of its atomistic Hessian (:class:`LatticeStability`; the phonon instability by
   which a perfect lattice fails). An unstable particle fails: it loses all its links. The
   uniform coarse branch alone keeps rising well past the atomistic failure (its stress
   peak lies several % of strain beyond LAMMPS's), while the periodic piece's Hessian turns
   negative close to LAMMPS's failure strain (``dcbr-stability``).
2. Bond cutoff: a link (c, n) of G's family breaks when, in the mapped lattice of c or of
   n, the C-C bond most aligned with the link's reference direction is longer than the
   outer cutoff R + D of the potential file (2.1 Å for C-C in BNC.tersoff), i.e. the bond
   it stands for has no energy left.

Broken links leave G's family (Upsilon is rebuilt); a particle left with fewer than 3
non-collinear links drops out. Damage index mu = 1 - R/T per particle (eq. 5.16).

**Zero-energy-mode (hourglass) control** (``hourglass``, default 0.1; 0 switches it off).
G_c does not see u_c itself, so checkerboard-like patterns of the regular grid leave every
G unchanged (on the curved wall: combinations of them) and cost nothing (``python -m
validation dcbr-stability`` counts the zero-energy modes beyond the 4 rigid ones: several
without this control, none with it). A penalty on the non-affine part of each link (Silling 2017;
Breitenfeld et al. 2014: hourglass control for correspondence peridynamics) restores its
stiffness,

    W_stab = 1/2 k_s sum_c sum_{n in family(c), intact} |rt_cn|^2 / |beta_cn|^2,

where p_cn is the link predicted by c's own *uniform cylindrical map* (the same map the
energy uses): with M_c = chol(C_c) = [[lam_t, gam], [0, lam_z]], Q_c = F_c S_c M_c^-1 (3x2,
orthonormal columns: the deformed e_theta, e_z), n'_c = q1 x q2 and the link's reference arc
and axial offsets (ds, dz),

    p_cn = Q_c (R' sin phi, lam_z dz)^T - n'_c R' (1 - cos phi) + Q3_c r0_cn,
    R' = lam_t R0,  phi = (lam_t ds + gam dz) / R',   Q3_c = [q1 q2 n'_c],

i.e. the chord of the deformed cylinder; the residual r_cn = y_n - y_c - p_cn then has the
part G can see, its own linear fit, removed: rt_cn = r_cn - (sum_m r_cm (x) a_cm) s_cn (a:
G's coefficients, s: tangent coordinates, sum_m a_cm (x) s_cm = I), and W_stab uses rt.
r0_cn (local frame, computed once per family) is
the residual at the reference configuration: zero on a full symmetric family, nonzero only
next to broken links, so the reference state costs nothing for any family. Consequences:
W_stab = 0 for every rigid motion and for uniform radial/axial stretch (F recovers M
exactly there); under a uniform twist the chord fit of G recovers gam only to O((h/R)^2)
(gain-affine), p_cn then misses the links by a nearly linear field that the projection
removes; what is left is measured by the tests. Its gradient is exact:
dp/dF_c by the chain rule through the frame and the Cholesky factor (each particle's map
evaluated once per call, the links' gradients pulled back to it in one reverse pass:
:mod:`upscale.models.dcbr_coupling_kernels`; ``method="numpy"`` keeps the reference
implementation, complex-step differentiation, error ~1e-30, no truncation), then through
G's fixed coefficients like the lattice energy, plus the direct terms in y_n, y_c and the
cell.

Stiffness (from the lattice's own elastic constant, not fitted): k_s = hourglass * N_c *
c_zz / 8, c_zz = d^2 e / d lam_z^2 (eV/atom, shift relaxed, central difference of
:meth:`TubeLattice.relaxed`); a non-affine link strain eps on all 8 links of the 3x3 stencil
then costs ``hourglass`` times the uniaxial energy N_c c_zz eps^2 / 2 of the particle.
The lattice-stability rule reads the lattice energy per atom only (``_e_lat_n``);
``_e_n`` (per-atom energies, used by the ASE calculator) adds each particle's share of
W_stab (its own links) divided by N_c, so the per-particle energies sum to the total.

Scope (what is and is not here): periodic pristine tubes of any chirality, uniform
(theta, z) arrangement (quasi-static tension:
:func:`upscale.experiments.scenes.tube_tension.quasi_static_tension_engine`) and an ASE
calculator (:mod:`upscale.calculators`). Defects are in :mod:`upscale.models.dcbr_defect`
(an atomistic region around the vacancy coupled to these particles) and dynamic tension of
open tubes with grips in :mod:`upscale.experiments.scenes.dcbr_dynamic`. The tube supplies energy and
gradient; its minimisations run on the engine's array-level minimisers
(:func:`upscale.engine.array_minimisers.lbfgs_b`, :meth:`DCBRTube.minimise`), and
:class:`DCBRTubeModel` is the same tube as an engine model (shifts relaxed at every
configuration) for the engine's integrators and minimisers.

Units: eV, Å; stress in GPa with the wall area 2 pi R t, t = 3.4 Å.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from potentials.tersoff import INDEX as TI
from upscale.constants import EV_PER_A3_IN_GPA, WALL_THICKNESS_A
from upscale.engine.array_minimisers import bfgs, lbfgs_b, one_blas_thread

from upscale.models import dcbr_coupling_kernels as CK
from upscale.models import dcbr_kernels as K
from upscale.models.gain import GainOperator, build_gain

__all__ = ["tersoff_params", "TubeLattice", "LatticeStability", "DCBRTube",
           "DCBRTubeModel", "TubeMinimum", "EV_PER_A3_IN_GPA", "WALL_THICKNESS"]

# The new model package's files (upscale/models/dcbr/, issue 51) sit beside this module until
# it is deleted; this path makes them importable as upscale.models.dcbr.<name> meanwhile.
__path__ = [__file__[:-len(".py")]]

# Each component of a particle's sublattice shift is held within +-SHIFT_BOUND_FRACTION
# times the bond length (0.355 Å for 1.42 Å) by the minimiser's bounds. The relaxed lattice
# shifts by at most 0.2 Å up to 30 % axial strain ((17,0), (12,6); 0.04 Å for (10,10)), but
# the lattice energy of BNC.tersoff with the step cutoff has a second, spurious basin half a
# bond away: B moved 0.7 Å along the arc of an armchair tube shortens two bonds to 1.23 Å and
# takes the third out of the cutoff, and these two-coordinated chains come out at -8.8 to
# -9.1 eV/atom, below graphene's -7.91, past a barrier of +3 eV/atom. No atomistic tube goes
# there (every atom would have to move at once), but an L-BFGS line search, which samples
# energies, can step over the barrier and the stress then jumps
# (tests/test_dcbr.py::test_sublattice_shift_stays_in_graphenes_basin).
SHIFT_BOUND_FRACTION = 0.25


WALL_THICKNESS = WALL_THICKNESS_A


def tersoff_params(potential: str = "tersoff:BNC.tersoff", cutoff: str = "step",
                   element: str = "C") -> np.ndarray:
    """Parameters of the ``element element element`` entry of a LAMMPS tersoff file.

    Returns the 14 numbers m, gamma, lambda3, c, d, costheta0 (h), n, beta, lambda2, B, R, D,
    lambda1, A (:data:`potentials.tersoff.NAMES`; ``p[INDEX[name]]``), read by
    :func:`potentials.tersoff.read_tersoff_file`. With
    ``cutoff="step"`` they are those of the file LAMMPS is given
    (:func:`potentials.tersoff.write_step_cutoff_file`): R' = R + D - 1e-5, D' = 1e-5 Å.
    """
    from potentials.tersoff import NAMES, STEP_CUTOFF_D, read_tersoff_file  # noqa: PLC0415

    if cutoff not in ("step", "standard"):
        raise ValueError(f"cutoff={cutoff!r}; valid: 'step' or 'standard'")
    name = potential.split(":", 1)[1] if potential.lower().startswith("tersoff:") else potential
    entry = read_tersoff_file(name, [element]).entry(element, element, element)
    v = np.array([entry[k] for k in NAMES], dtype=float)
    if cutoff == "step":
        outer = v[TI["R"]] + v[TI["D"]]
        v[TI["R"]], v[TI["D"]] = outer - STEP_CUTOFF_D, STEP_CUTOFF_D
    return v


@dataclasses.dataclass
class TubeLattice:
    """A patch of the ideal (n, m) tube around a bonded pair A0-B0, in cylinder coordinates.

    Attributes
    ----------
    s, z : (P,) float
        Reference arc coordinate R0 (theta - theta_A0) and axial z - z_A0, Å.
    sub : (P,) float
        Sublattice flag, 0 (A) or 1 (B).
    R0 : float
        Radius of the ideal rolled tube, Å.
    iA, iB : int
        Indices of A0 and B0 in the patch.
    candA, candB : (k,) int64
        Patch atoms within ``r_patch`` of A0 / B0 (Tersoff neighbour candidates).
    bondsA : (3,) int64
        The three bonded neighbours of A0.
    """

    s: np.ndarray
    z: np.ndarray
    sub: np.ndarray
    R0: float
    iA: int
    iB: int
    candA: np.ndarray
    candB: np.ndarray
    bondsA: np.ndarray
    n: int
    m: int
    bond: float

    @classmethod
    def build(cls, n: int, m: int, bond: float = 1.42, r_patch: float = 3.2) -> "TubeLattice":
        from upscale.build import chirality, swcnt  # noqa: PLC0415

        ch = chirality(n, m, bond)
        length = max(3 * ch.cell_length, 4 * r_patch + 2.0)
        atoms = swcnt(n, m, length=length, bond=bond, vacuum=5.0)
        cx, cy = atoms.info["axis_xy"]
        Lz = atoms.cell[2, 2]
        x = atoms.get_positions() - [cx, cy, 0.0]
        rho = np.hypot(x[:, 0], x[:, 1])
        R0 = float(rho.mean())
        if np.abs(rho - R0).max() > 1e-6:
            raise RuntimeError("swcnt atoms are not on one cylinder")
        th = np.arctan2(x[:, 1], x[:, 0])
        iA0 = int(np.argmin(np.abs(x[:, 2] - Lz / 2) + np.abs(th)))

        def rel(i0):
            dth = (th - th[i0] + np.pi) % (2 * np.pi) - np.pi
            dz = x[:, 2] - x[i0, 2]
            dz -= Lz * np.round(dz / Lz)
            return dth, dz

        def chord(i0):
            dth, dz = rel(i0)
            return np.sqrt((2 * R0 * np.sin(dth / 2)) ** 2 + dz ** 2)

        dA = chord(iA0)
        nb = np.nonzero((dA > 0.1) & (dA < 1.1 * bond))[0]
        if len(nb) != 3:
            raise RuntimeError(f"atom A0 has {len(nb)} bonded neighbours, expected 3")
        iB0 = int(nb[np.argmax(np.abs(rel(iA0)[1][nb]))])  # the most axial bond
        dB = chord(iB0)
        in_patch = np.nonzero((dA < r_patch) | (dB < r_patch))[0]
        # sublattice by 2-colouring the bond graph restricted to the patch (it is connected)
        dth, dz = rel(iA0)
        s = R0 * dth[in_patch]
        zz = dz[in_patch]
        P = len(in_patch)
        pairs = np.zeros((P, P), dtype=bool)
        for a in range(P):
            da = np.sqrt((2 * R0 * np.sin((dth[in_patch] - dth[in_patch][a]) / 2)) ** 2
                         + (zz - zz[a]) ** 2)
            pairs[a] = (da > 0.1) & (da < 1.1 * bond)
        sub = -np.ones(P)
        iA = int(np.nonzero(in_patch == iA0)[0][0])
        iB = int(np.nonzero(in_patch == iB0)[0][0])
        sub[iA] = 0
        front = [iA]
        while front:
            nxt = []
            for a in front:
                for b in np.nonzero(pairs[a])[0]:
                    if sub[b] < 0:
                        sub[b] = 1 - sub[a]
                        nxt.append(b)
            front = nxt
        if np.any(sub < 0):
            raise RuntimeError("tube patch is not connected; enlarge r_patch")
        candA = np.nonzero((dA[in_patch] < r_patch) & (np.arange(P) != iA))[0]
        candB = np.nonzero((dB[in_patch] < r_patch) & (np.arange(P) != iB))[0]
        bondsA = np.nonzero(pairs[iA])[0]
        return cls(s=np.ascontiguousarray(s), z=np.ascontiguousarray(zz), sub=sub, R0=R0,
                   iA=iA, iB=iB, candA=candA.astype(np.int64), candB=candB.astype(np.int64),
                   bondsA=bondsA.astype(np.int64), n=int(n), m=int(m), bond=float(bond))

    def energy(self, q, p):
        """Energy per atom (eV) and its gradient (6,) for lattice parameters q (6,)."""
        P = len(self.s)
        g = np.empty(6)
        e = K.cell_energy_grad(np.asarray(q, float), self.s, self.z, self.sub, self.R0, self.iA,
                               self.iB, self.candA, self.candB, p, np.empty((P, 3)),
                               np.empty((P, 3)), g)
        return e, g

    def relaxed(self, lam_t, gam, lam_z, p, shift0=(0.0, 0.0, 0.0), relax_shift=True):
        """min over the sublattice shift of e(lam_t, gam, lam_z, shift): (e, shift (3,))."""
        fixed = np.array([lam_t, gam, lam_z], float)
        if not relax_shift:
            return self.energy(np.r_[fixed, 0, 0, 0], p)[0], np.zeros(3)

        def fun(d):
            e, g = self.energy(np.r_[fixed, d], p)
            return e, g[3:]

        res = bfgs(fun, np.asarray(shift0, float), gtol=1e-11, max_iter=200)
        return res.energy, res.x


class LatticeStability:
    """Is the tube lattice, uniformly mapped by q, stable against atomic displacements?

    The smallest periodic piece of the ideal (n, m) tube whose length is at least twice the
    potential's outer cutoff (no atom meets its own image twice) is mapped by the
    cylindrical map of q = (lam_t, gam, lam_z, d_rho, d_s, d_z) (gam is set to 0: a twist is
    not periodic); its Hessian at fixed cell (central differences of the forces of
    :mod:`potentials.tersoff`, step 1e-4 Å) is projected off the four zero modes (three
    translations, rotation about the axis). The lattice is unstable when the smallest
    eigenvalue is negative (below -1e-3 eV/Å^2, far above the finite-difference noise).
    This is the phonon (lattice) instability by which a perfect lattice fails under load,
    tested on the modes commensurate with that piece; no parameter is fitted.
    """

    def __init__(self, n, m, potential="tersoff:BNC.tersoff", cutoff="step", bond=1.42):
        from ase.build import nanotube  # noqa: PLC0415

        from upscale.build import chirality  # noqa: PLC0415

        self.p = tersoff_params(potential, cutoff)
        self.cut = float(self.p[TI['R']] + self.p[TI['D']])
        ch = chirality(n, m, bond)
        ncell = max(1, int(math.ceil(2 * self.cut / ch.cell_length)))
        t = nanotube(n, m, length=ncell, bond=bond)
        x = t.get_positions()
        self.Lz = ncell * ch.cell_length
        self.R0 = float(np.hypot(x[:, 0], x[:, 1]).mean())
        self.theta = np.arctan2(x[:, 1], x[:, 0])
        self.z = x[:, 2]
        # sublattice: 2-colour the bond graph
        d = x[:, None, :] - x[None, :, :]
        d[..., 2] -= self.Lz * np.round(d[..., 2] / self.Lz)
        nb = (np.linalg.norm(d, axis=2) > 0.1) & (np.linalg.norm(d, axis=2) < 1.1 * bond)
        sub = -np.ones(len(x))
        sub[0], front = 0, [0]
        while front:
            nxt = []
            for a in front:
                for b in np.nonzero(nb[a])[0]:
                    if sub[b] < 0:
                        sub[b] = 1 - sub[a]
                        nxt.append(b)
            front = nxt
        self.sub = sub
        self.natoms = len(x)
        self.ncell = ncell
        # image copies at z -/+ Lz and Tersoff candidates within 1.6 x cutoff (reference)
        nat = len(x)
        self.owner = np.concatenate([np.arange(nat)] * 3).astype(np.int64)
        self.img = np.concatenate([np.zeros(nat), -np.ones(nat), np.ones(nat)])
        xe = x[self.owner] + np.outer(self.img, [0.0, 0.0, self.Lz])
        dd = np.linalg.norm(x[:, None, :] - xe[None, :, :], axis=2)
        off, idx = [0], []
        for i in range(nat):
            js = np.nonzero((dd[i] < 1.6 * self.cut) & (np.arange(len(xe)) != i))[0]
            idx.extend(js)
            off.append(len(idx))
        self.cand_off = np.array(off, np.int64)
        self.cand_idx = np.array(idx, np.int64)
        deps = [{i} for i in range(nat)]  # sites whose energy depends on atom i
        for j in range(nat):
            for e in self.cand_idx[self.cand_off[j]:self.cand_off[j + 1]]:
                deps[self.owner[e]].add(j)
        self.dep_off = np.cumsum([0] + [len(d) for d in deps]).astype(np.int64)
        self.dep_idx = np.array([j for d in deps for j in sorted(d)], np.int64)
        self._cache: dict = {}

    def positions(self, q):
        lt, _gm, lz, drho, ds, dz = q
        rho = lt * self.R0 + self.sub * drho
        th = self.theta + self.sub * ds / (lt * self.R0)
        return np.column_stack([rho * np.cos(th), rho * np.sin(th), lz * self.z + self.sub * dz])

    def hessian(self, q, h=1e-4):
        """(H, U): Hessian (3n, 3n) of the mapped piece, eV/Å^2, and its four zero modes U
        (orthonormal columns: translations, rotation about the axis)."""
        x = self.positions(q)
        n = len(x)
        H = K.piece_hessian(x, q[2] * self.Lz, self.owner, self.img, self.cand_off,
                            self.cand_idx, self.p, h, self.dep_off, self.dep_idx)
        U = np.zeros((3 * n, 4))
        for c in range(3):
            U[c::3, c] = 1.0
        U[0::3, 3] = -x[:, 1]
        U[1::3, 3] = x[:, 0]
        U, _ = np.linalg.qr(U)
        return H, U

    def min_eigenvalue(self, q, h=1e-4) -> float:
        """Smallest eigenvalue (eV/Å^2) of the Hessian projected off the zero modes."""
        H, U = self.hessian(q, h)
        Pj = np.eye(len(H)) - U @ U.T
        w = np.linalg.eigvalsh(Pj @ H @ Pj)
        w = np.delete(w, np.argsort(np.abs(w))[:4])  # the four projected zero modes
        return float(w.min())

    def stable(self, q, tol=1e-3) -> bool:
        """True when H + U U^T + tol I is positive definite (Cholesky), i.e. no eigenvalue
        of the Hessian off the zero modes is below -tol (eV/Å^2; the finite-difference
        noise is ~1e-8). BLAS on one thread (:func:`~upscale.engine.array_minimisers.one_blas_thread`):
        a few hundred unknowns, where OpenBLAS's threads on a busy machine made this
        Cholesky factorisation take 0.2 s instead of 0.5 ms."""
        key = tuple(np.round(np.asarray(q, float), 7))
        if key not in self._cache:
            with one_blas_thread():
                H, U = self.hessian(q)
                A = H + U @ U.T + tol * np.eye(len(H))
                try:
                    np.linalg.cholesky(A)
                    ok = True
                except np.linalg.LinAlgError:
                    ok = False
            self._cache[key] = ok
        return self._cache[key]


def uniform_map_frame(FS):
    """(lam_t, gam, lam_z, Q3) of surface maps FS (n,3,2), real or complex: M = chol(FS^T FS)
    (upper triangular, theta first) and the deformed frame Q3 = [q1 q2 q1 x q2] (n,3,3)."""
    C = np.einsum("nia,nib->nab", FS, FS)  # transpose, no conjugate (complex step)
    lt = np.sqrt(C[:, 0, 0])
    gm = C[:, 0, 1] / lt
    lz = np.sqrt(C[:, 1, 1] - gm * gm)
    q1 = FS[:, :, 0] / lt[:, None]
    q2 = (FS[:, :, 1] - gm[:, None] * q1) / lz[:, None]
    n = np.stack([q1[:, 1] * q2[:, 2] - q1[:, 2] * q2[:, 1],
                  q1[:, 2] * q2[:, 0] - q1[:, 0] * q2[:, 2],
                  q1[:, 0] * q2[:, 1] - q1[:, 1] * q2[:, 0]], axis=1)
    return lt, gm, lz, np.stack([q1, q2, n], axis=2)


@dataclasses.dataclass
class TubeMinimum:
    """A minimum of the coarse tube (:meth:`DCBRTube.minimise`).

    Attributes
    ----------
    y : (Ny, 3) float
        The unknown positions (particles, then any free atoms), Å.
    delta : (N, 3) float
        Sublattice shifts (d_s, d_z, d_rho), Å.
    Lz : float
        Cell length, Å.
    energy : float
        Energy at the minimum, eV.
    info : dict
        ``nit``, ``nfev``, ``success``, ``max_force_eV_A`` (largest position gradient
        component), ``message``, and what a subclass adds (``damped_cycles``,
        ``step_crossings``, ``zero_stress_iterations``).
    cell_force : float
        dE/dLz at the minimum, eV/Å (the axial force on the cell).
    """

    y: np.ndarray
    delta: np.ndarray
    Lz: float
    energy: float
    info: dict
    cell_force: float

    @property
    def max_force(self) -> float:
        """Largest position gradient component, eV/Å."""
        return self.info["max_force_eV_A"]


class DCBRTube:
    """Coarse (DCBR) model of a periodic single-wall (n, m) tube along z.

    Parameters
    ----------
    n, m : int
        Chiral indices.
    length : float
        Wanted length, Å; rounded like :func:`upscale.build.swcnt` to whole unit cells so the
        coarse and atomistic tubes have the same length and number of atoms.
    coarsening : float
        Particle spacing / lattice constant a = sqrt(3) a_cc (>= 1).
    horizon_factor : float
        Influence radius / largest particle spacing (default 1.5: the 3x3 stencil).
    potential, cutoff : str
        Tersoff file and ``"step"`` or ``"standard"`` cutoff (see :func:`tersoff_params`).
    bond : float
        a_cc of the rolled-up reference tube, Å (as in :func:`upscale.build.swcnt`).
    relax_shift : bool
        Relax the sublattice shift (False: the B sublattice follows the map rigidly).
    stability : bool
        Apply the lattice-stability failure rule (:class:`LatticeStability`) after each
        load step (:meth:`check_stability`).
    hourglass : float
        Zero-energy-mode control: k_s as a fraction of the lattice stiffness (module
        docstring); 0 switches it off. Default 0.1.
    method : str
        ``"numba"`` (default): the hourglass term (and a subclass's terms through the
        particles' maps) by the kernels of :mod:`upscale.models.dcbr_coupling_kernels`;
        ``"numpy"``: the straightforward array implementation with complex-step
        derivatives, kept as the reference the kernels are tested against. Same results
        to round-off. May be changed on the instance (attribute ``method``).
    """

    def __init__(self, n: int, m: int, length: float, coarsening: float = 2.0,
                 horizon_factor: float = 1.5, potential: str = "tersoff:BNC.tersoff",
                 cutoff: str = "step", bond: float = 1.42, kind: str = "quartic",
                 relax_shift: bool = True, stability: bool = True, hourglass: float = 0.1,
                 method: str = "numba"):
        from upscale.build import cells_for_length, chirality  # noqa: PLC0415

        if not (coarsening >= 1.0 and np.isfinite(coarsening)):
            raise ValueError(f"coarsening factor {coarsening!r} is below 1; valid: a number >= 1 "
                             "(1 = one particle per lattice constant)")
        if not horizon_factor > 1.0:
            raise ValueError(f"horizon_factor={horizon_factor!r}; valid: > 1")
        if not (hourglass >= 0.0 and np.isfinite(hourglass)):
            raise ValueError(f"hourglass={hourglass!r}; valid: a number >= 0 (0 = off)")
        self.method = method
        self.p = tersoff_params(potential, cutoff)
        self.p_standard = tersoff_params(potential, "standard")
        self.potential, self.cutoff = potential, cutoff
        self.lattice = TubeLattice.build(n, m, bond)
        ch = chirality(n, m, bond)
        nc = cells_for_length(ch, length)
        self.L = nc * ch.cell_length
        self.n_atoms = nc * ch.atoms_per_cell
        R0 = self.lattice.R0
        a = math.sqrt(3.0) * bond
        self.n_theta = max(3, int(round(2 * math.pi * R0 / (coarsening * a))))
        self.n_z = max(3, int(round(self.L / (coarsening * a))))
        th = 2 * math.pi * (np.arange(self.n_theta) + 0.5) / self.n_theta
        zz = self.L * (np.arange(self.n_z) + 0.5) / self.n_z
        T, Z = np.meshgrid(th, zz, indexing="ij")
        self.theta = T.ravel()
        self.x0 = np.column_stack([R0 * np.cos(self.theta), R0 * np.sin(self.theta), Z.ravel()])
        self.N = len(self.x0)
        self.natoms_n = np.full(self.N, self.n_atoms / self.N)
        ds, dz = 2 * math.pi * R0 / self.n_theta, self.L / self.n_z
        self.spacing = (ds, dz)
        self.horizon = horizon_factor * max(ds, dz)
        self.kind = kind
        self.coarsening = float(coarsening)
        self.relax_shift = relax_shift
        self.shift_bound = SHIFT_BOUND_FRACTION * float(self.lattice.bond)
        self.periodic = True  # along the axis; False for an open tube (dynamic tension)
        self.area0 = ds * dz
        self.hourglass = float(hourglass)
        self.k_stab = 0.0
        self._build_gain(None)
        self.e0 = self.lattice.energy(np.array([1.0, 0, 1.0, 0, 0, 0]), self.p)[0]
        if self.hourglass > 0:
            h = 1e-3
            ez = [self.lattice.relaxed(1.0, 0.0, 1.0 + t, self.p)[0] for t in (-h, 0.0, h)]
            self.c_zz = (ez[0] - 2 * ez[1] + ez[2]) / h ** 2  # eV/atom
            self.k_stab = self.hourglass * float(self.natoms_n[0]) * self.c_zz / 8.0
        self.delta = np.zeros((self.N, 3))
        self.stability = LatticeStability(n, m, potential, cutoff, bond) if stability else None

    @property
    def method(self) -> str:
        """``"numba"`` or ``"numpy"``: the implementation of the terms through the
        particles' maps (class docstring)."""
        return self._method

    @method.setter
    def method(self, value: str):
        if value not in ("numba", "numpy"):
            raise ValueError(f"method={value!r}; valid: 'numba' (kernels) or 'numpy' "
                             "(reference implementation)")
        self._method = value

    # ------------------------------------------------------------------ gain and links
    def _build_gain(self, intact):
        self.gain: GainOperator = build_gain(
            self.x0, self.horizon, np.full(self.N, 1.0), surface=True, axis=[0, 0, 1],
            cell=[0, 0, self.L], pbc=(False, False, self.periodic), kind=self.kind, intact=intact,
            on_singular="raise" if intact is None else "drop",
            clamp=None if self.periodic else getattr(self, "clamp", None))
        g = self.gain
        A0 = np.einsum("nia,nib->nab", g.F0, g.F0)
        A0[~g.alive] = np.eye(2)
        w, V = np.linalg.eigh(A0)
        self.S = np.ascontiguousarray(np.einsum("nab,nb,ncb->nac", V, w ** -0.5, V))
        if intact is None:
            self.intact = np.ones(len(g.pair_i), dtype=bool)
            self.n_links0 = np.bincount(g.pair_i, minlength=self.N)
            # the lattice bond each link stands for: best aligned in reference tangent coords
            lat = self.lattice
            bdir = np.column_stack([lat.s[lat.bondsA], lat.z[lat.bondsA]])
            bdir /= np.linalg.norm(bdir, axis=1)[:, None]
            beta = self.x0[g.pair_j] + g.pair_image * g.cell - self.x0[g.pair_i]
            t = np.einsum("eia,ei->ea", g.frame[g.pair_i], beta)
            # a link through the axis (few particles around) has no tangent direction: it
            # is mapped to the first bond; it carries no weight in G anyway (s = 0)
            t /= np.maximum(np.linalg.norm(t, axis=1), 1e-12)[:, None]
            self.link_bond = np.argmax(np.abs(t @ bdir.T), axis=1)
        self.alive = g.alive.copy()
        self._build_stab()

    # ------------------------------------------------------------------ hourglass control
    def _build_stab(self):
        """Link data of W_stab over the entries of G (module docstring): owner c, j, image,
        1/|beta|^2, reference arc and axial offsets, and the reference residual r0 (local)."""
        g = self.gain
        ce = np.repeat(np.arange(self.N), np.diff(g.offsets))
        keep = g.alive[ce]
        clamp = None if self.periodic else getattr(self, "clamp", None)
        if clamp is not None:  # a rigid grip particle owns no link (its G is T), and the
            # entries of y_c itself (families fitted about c) are not links
            keep &= ~np.asarray(clamp[2], bool)[ce] & (g.neighbors != ce)
        fit = g.fit_beta[keep] if g.fit_beta is not None else None
        ce, je, im = ce[keep], g.neighbors[keep], g.image[keep]
        beta = self.x0[je] + im * g.cell - self.x0[ce]
        if fit is None:
            fit = beta
        R0 = self.lattice.R0
        T = g.frame[ce]
        nrm = np.cross(T[:, :, 0], T[:, :, 1])
        tang = np.einsum("ei,ei->e", beta, T[:, :, 0])
        norm_c = np.einsum("ei,ei->e", beta, nrm)
        dth = np.arctan2(tang, R0 + norm_c)
        self._st = {"c": ce.astype(np.int64), "j": je.astype(np.int64), "im": im.astype(float),
                    "imz": np.ascontiguousarray(im[:, 2], dtype=float),
                    "w": 1.0 / np.einsum("ei,ei->e", beta, beta),
                    "ds": R0 * dth, "dz": np.einsum("ei,ei->e", fit, T[:, :, 1]),
                    "r0": np.zeros((len(ce), 3)),
                    "a": np.ascontiguousarray(g.coef[keep], dtype=float),
                    "s": np.ascontiguousarray(np.einsum("eia,ei->ea", T, fit))}
        x_ref = self.x0 if clamp is None or len(clamp) < 4 else clamp[3]
        if x_ref is not self.x0:  # the residual is zero at the state the grips hold
            beta = x_ref[je] + im * g.cell - x_ref[ce]
        F0 = g.deformation(x_ref, g.cell)
        Q3, h = self._stab_local(F0)
        self._st["r0"] = np.ascontiguousarray(np.einsum("eia,ei->ea", Q3, beta) - h)

    def _stab_local(self, F):
        """Per link: Q3_c (e,3,3) and h (e,3), the local chord of c's uniform map (real or
        complex F, for the complex-step derivative)."""
        st, S, R0 = self._st, self.S, self.lattice.R0
        dead = ~self.gain.alive
        if dead.any():  # empty rows (no links, frame unset): any regular F, they own no link
            F = F.copy()
            F[dead] = np.eye(3, 2)
        FS = np.einsum("nia,nab->nib", F, S)
        lt, gm, lz, Q3n = uniform_map_frame(FS)
        c = st["c"]
        Q3 = Q3n[c]
        Rp = lt[c] * R0
        phi = (lt[c] * st["ds"] + gm[c] * st["dz"]) / Rp
        h = np.stack([Rp * np.sin(phi), lz[c] * st["dz"], -Rp * (1.0 - np.cos(phi))], axis=1)
        return Q3, h

    def _map_frames(self, F):
        """Each particle's uniform map at F (N,3,2): (FS (N,3,2), (lam_t, gam, lam_z) (N,3),
        Q3 (N,3,3), flag (N,) int8), see :func:`dcbr_coupling_kernels.map_frames`."""
        N = self.N
        FS = np.empty((N, 3, 2))
        par = np.empty((N, 3))
        Q3 = np.empty((N, 3, 3))
        flag = np.empty(N, np.int8)
        CK.map_frames(np.ascontiguousarray(F, dtype=float), self.S, self.gain.alive,
                      self.alive, FS, par, Q3, flag)
        return FS, par, Q3, flag

    def stab_energy_and_gradient(self, y, F, Lz, frames=None):
        """W_stab (eV), its P = dW/dF (N,3,2), direct dW/dy (N,3) and direct dW/dLz.

        Also sets ``_w_stab_n`` (N,): each particle's share (the links it owns), eV.
        ``frames``: the particles' maps at F (:meth:`_map_frames`), if already computed."""
        if self.method == "numpy":
            return self._stab_energy_and_gradient_numpy(y, F, Lz)
        N = self.N
        P = np.zeros((N, 3, 2))
        gy = np.zeros((N, 3))
        self._w_stab_n = np.zeros(N)
        st = self._st
        if self.k_stab == 0.0 or len(st["c"]) == 0:
            return 0.0, P, gy, 0.0
        if frames is None:
            frames = self._map_frames(F)
        _, par, Q3, _ = frames
        gQ3 = np.zeros((N, 3, 3))
        gpar = np.zeros((N, 3))
        E, dL = CK.stab_links(np.ascontiguousarray(y, dtype=float), float(Lz), st["c"], st["j"],
                              st["imz"], st["w"], st["ds"], st["dz"], st["r0"], st["a"],
                              st["s"], self.k_stab, self.lattice.R0, par, Q3, gy,
                              self._w_stab_n, gQ3, gpar)
        CK.frame_adjoint(np.ascontiguousarray(F, dtype=float), self.S, self.gain.alive, par, Q3,
                         gQ3, gpar, P)
        return float(E), P, gy, float(dL)

    def _stab_energy_and_gradient_numpy(self, y, F, Lz):
        """Reference implementation of :meth:`stab_energy_and_gradient` (numpy arrays,
        complex-step dp/dF)."""
        N = self.N
        P = np.zeros((N, 3, 2))
        gy = np.zeros((N, 3))
        st = self._st
        self._w_stab_n = np.zeros(N)
        if self.k_stab == 0.0 or len(st["c"]) == 0:
            return 0.0, P, gy, 0.0
        c, j = st["c"], st["j"]
        link = y[j] - y[c] + st["im"] * np.array([0.0, 0.0, Lz])
        Q3, h = self._stab_local(F)
        r = link - np.einsum("eia,ea->ei", Q3, h + st["r0"])
        # project out the part of r that G can see (its own linear fit): rt = r - Fr_c s_e,
        # Fr_c = sum_e r_e (x) a_e (sum_e a_e (x) s_e = I, so the fit of rt is zero)
        a, sv = st["a"], st["s"]
        Fr = np.zeros((N, 3, 2))
        np.add.at(Fr, c, r[:, :, None] * a[:, None, :])
        rt = r - np.einsum("eia,ea->ei", Fr[c], sv)
        kw = self.k_stab * st["w"]
        we = 0.5 * kw * np.einsum("ei,ei->e", rt, rt)
        self._w_stab_n = np.bincount(c, weights=we, minlength=N)  # each particle's own links
        E = float(np.sum(we))
        krt = kw[:, None] * rt
        B = np.zeros((N, 3, 2))
        np.add.at(B, c, krt[:, :, None] * sv[:, None, :])
        kr = krt - np.einsum("eia,ea->ei", B[c], a)  # dW/dr_e (transpose of the projection)
        np.add.at(gy, j, kr)
        np.subtract.at(gy, c, kr)
        dL = float(np.sum(kr[:, 2] * st["im"][:, 2]))
        eps = 1e-30
        Fc = F.astype(complex)
        for i in range(3):
            for a in range(2):
                Fc.real[:] = F
                Fc.imag[:] = 0.0
                Fc.imag[:, i, a] = eps
                Q3c, hc = self._stab_local(Fc)
                dp = np.einsum("eia,ea->ei", Q3c, hc + st["r0"]).imag / eps
                np.add.at(P[:, i, a], c, -np.einsum("ei,ei->e", kr, dp))
        return E, P, gy, dL

    @property
    def damage(self) -> np.ndarray:
        """mu = 1 - R/T per particle (seed 004 eq. 5.16)."""
        R = np.bincount(self.gain.pair_i[self.intact], minlength=self.N)
        return 1.0 - R / self.n_links0

    # ------------------------------------------------------------------ energy
    def _coarse_part(self, y, delta, Lz):
        """The particles' lattice energy and hourglass term at particle positions ``y``:
        (E, F, P = dE/dF, dE/d delta, direct dE/dy, direct dE/dLz); sets ``_e_lat_n``,
        ``_q_n``, ``_w_stab_n`` and ``_frames`` (the particles' maps, :meth:`_map_frames`;
        None with ``method="numpy"``)."""
        F = self.gain.deformation(y, np.array([0.0, 0.0, Lz]))
        P = np.empty_like(F)
        gd = np.empty((self.N, 3))
        self._e_lat_n = np.empty(self.N)
        self._q_n = np.zeros((self.N, 6))
        lat = self.lattice
        E = K.coarse_energy(F, self.S, np.ascontiguousarray(delta), self.natoms_n, self.alive,
                            lat.s, lat.z, lat.sub, lat.R0, lat.iA, lat.iB, lat.candA, lat.candB,
                            self.p, self.e0, P, gd, self._e_lat_n, self._q_n)
        if not self.relax_shift:
            gd[:] = 0.0
        self._frames = self._map_frames(F) if self.method == "numba" else None
        Es, Ps, gys, dLs = self.stab_energy_and_gradient(np.asarray(y, float), F, Lz,
                                                         frames=self._frames)
        P += Ps
        return E + Es, F, P, gd, gys, dLs

    def energy_and_gradient(self, y, delta, Lz):
        """Total energy E - N e0 + W_stab (eV) and dE/dy (N,3), dE/d delta (N,3), dE/dLz (eV/Å)."""
        g = self.gain
        E, F, P, gd, gys, dLs = self._coarse_part(y, delta, Lz)
        self._e_n = self._e_lat_n + self._w_stab_n / self.natoms_n
        fy = g.forces(P)
        dL = g.cell_derivative(P)[2] + dLs
        return E, gys - fy, gd, dL

    def condensed_hessian(self, y, delta, Lz, h: float = 1e-5) -> np.ndarray:
        """Stiffness of the particle positions with the massless sublattice shifts condensed.

        Central differences (step ``h``) of the analytic gradient give the Hessian in
        (y, delta); the Schur complement K = K_yy - K_yd K_dd^-1 K_dy eliminates the shifts.

        Returns
        -------
        (3N, 3N) ndarray, eV/Å^2.
        """
        N = self.N
        z0 = np.concatenate([y.ravel(), delta.ravel()])

        def grad(z):
            _, gy, gd, _ = self.energy_and_gradient(z[:3 * N].reshape(N, 3),
                                                    z[3 * N:].reshape(N, 3), Lz)
            return np.concatenate([gy.ravel(), gd.ravel()])

        H = np.empty((6 * N, 6 * N))
        for i in range(6 * N):
            zp, zm = z0.copy(), z0.copy()
            zp[i] += h
            zm[i] -= h
            H[i] = (grad(zp) - grad(zm)) / (2 * h)
        H = 0.5 * (H + H.T)
        a, b = slice(0, 3 * N), slice(3 * N, 6 * N)
        return H[a, a] - H[a, b] @ np.linalg.solve(H[b, b], H[b, a])

    def _pack(self, y, delta, Lz=None):
        parts = [y.ravel(), delta.ravel()]
        if Lz is not None:
            parts.append([Lz])
        return np.concatenate(parts)

    def minimise(self, y, delta, Lz, relax_box=False, gtol=1e-6, maxiter=5000,
                 fixed=None) -> "TubeMinimum":
        """Minimise the energy over positions and shifts (and Lz if ``relax_box``) by the
        engine's L-BFGS-B (:func:`upscale.engine.array_minimisers.lbfgs_b`, 30 correction pairs).

        ``gtol``: max |gradient component| in eV/Å. ``fixed``: optional boolean mask shaped
        like ``y``; those position components stay. With ``relax_box`` the positions scale
        with the cell along z (affine in z) and the cell length, in units of L/10 so that
        its step matches the particle steps, is one more unknown. Each sublattice shift
        component stays within +-``shift_bound`` (graphene's basin; see
        SHIFT_BOUND_FRACTION). Returns a :class:`TubeMinimum`.
        """
        N = self.N
        Ny = len(y)  # the unknown positions (a subclass may add rows, e.g. atoms)
        Lscale = self.L / 10.0

        def fun(xv):
            yy = xv[:3 * Ny].reshape(Ny, 3)
            dd = xv[3 * Ny:3 * Ny + 3 * N].reshape(N, 3)
            L = xv[-1] * Lscale if relax_box else Lz
            if relax_box:
                yy = yy.copy()
                yy[:, 2] *= L / self.L
            E, gy, gd, gL = self.energy_and_gradient(yy, dd, L)
            if relax_box:
                gL_tot = gL + np.dot(gy[:, 2], xv[:3 * Ny].reshape(Ny, 3)[:, 2]) / self.L
                gy = gy.copy()
                gy[:, 2] *= L / self.L
                return E, np.concatenate([gy.ravel(), gd.ravel(), [gL_tot * Lscale]])
            return E, np.concatenate([gy.ravel(), gd.ravel()])

        if relax_box:
            ys = y.copy()
            ys[:, 2] *= self.L / Lz
            x0 = self._pack(ys, delta, Lz / Lscale)
        else:
            x0 = self._pack(y, delta)
        b = self.shift_bound
        lo = np.full(len(x0), -np.inf)
        hi = np.full(len(x0), np.inf)
        lo[3 * Ny:3 * Ny + 3 * N], hi[3 * Ny:3 * Ny + 3 * N] = -b, b
        x0[3 * Ny:3 * Ny + 3 * N] = np.clip(x0[3 * Ny:3 * Ny + 3 * N], -b, b)
        if fixed is not None:
            fixed = np.asarray(fixed, bool)
            if fixed.shape != y.shape:
                raise ValueError(f"fixed has shape {fixed.shape}; valid: that of y {y.shape}")
            fx = np.nonzero(fixed.ravel())[0]
            lo[fx] = hi[fx] = x0[fx]
        res = lbfgs_b(fun, x0, lo, hi, gtol=gtol, max_iter=maxiter, memory=30, ftol=1e-15,
                      maxfun=4 * maxiter)
        xv = res.x
        y = xv[:3 * Ny].reshape(Ny, 3).copy()
        delta = xv[3 * Ny:3 * Ny + 3 * N].reshape(N, 3).copy()
        if relax_box:
            Lz = xv[-1] * Lscale
            y[:, 2] *= Lz / self.L
        E, gy, gd, gL = self.energy_and_gradient(y, delta, Lz)
        info = {"nit": res.iterations, "nfev": res.n_force, "success": res.converged,
                "max_force_eV_A": float(np.abs(gy).max()), "message": res.message}
        return TubeMinimum(y, delta, Lz, E, info, gL)

    # ------------------------------------------------------------------ links and failure
    def set_links(self, intact, alive) -> None:
        """Put back a link state (``intact`` over the links, ``alive`` (N,)), e.g. a resumed
        run's: G is rebuilt on the intact links and the particles failed by the stability
        rule stay failed."""
        self.intact[...] = np.asarray(intact, bool)
        self._build_gain(self.intact)
        self.alive &= np.asarray(alive, bool)

    def update_links(self):
        """Break links per the failure rule (module docstring); return the number broken."""
        q = self._q_n
        lat = self.lattice
        L = K.mapped_bond_lengths(np.ascontiguousarray(q), lat.s, lat.z, lat.sub, lat.R0,
                                  lat.iA, lat.bondsA)
        rcut = self.p_standard[TI['R']] + self.p_standard[TI['D']]  # outer cutoff R + D
        g = self.gain
        over = np.zeros(len(g.pair_i), dtype=bool)
        li = L[g.pair_i, self.link_bond]
        lj = L[g.pair_j, self.link_bond]
        alive_i = self.alive[g.pair_i]
        alive_j = self.alive[g.pair_j]
        over = ((li > rcut) & alive_i) | ((lj > rcut) & alive_j)
        newly = over & self.intact
        nb = int(newly.sum())
        if nb:
            self.intact &= ~over
            self._build_gain(self.intact)
        return nb

    def check_stability(self, all_equal: bool = False):
        """Lattice-stability rule: fail the most loaded particle if its lattice is unstable.

        The alive particle with the largest lattice energy per atom (of the last
        :meth:`energy_and_gradient`) is tested; if its mapped lattice is unstable it fails
        (loses all its links) and 1 is returned, else 0 (less loaded particles are taken as
        stable). One particle per call: the caller re-minimises, so the load the failed
        particle carried moves to its neighbours and the failure can run on as a crack. With
        ``all_equal`` every particle in the same lattice state (to 1e-7) fails at once.
        """
        if self.stability is None or not self.alive.any():
            return 0
        e = np.where(self.alive, self._e_lat_n, -np.inf)
        c = int(np.argmax(e))
        q = self._q_n[c]
        if self.stability.stable(q):
            return 0
        failed = np.zeros(self.N, dtype=bool)
        failed[c] = True
        if all_equal:
            failed |= np.all(np.abs(self._q_n - q) < 1e-7, axis=1) & self.alive
        g = self.gain
        self.intact &= ~(failed[g.pair_i] | failed[g.pair_j])
        self._build_gain(self.intact)
        self.alive &= ~failed
        return int(failed.sum())

    def radius(self, y, delta):
        """Mean wall radius (Å): particles sit on sublattice A, B is d_rho further out."""
        rho = np.hypot(y[:, 0], y[:, 1])
        return float(np.mean(rho + 0.5 * delta[:, 0]))


def _bits_equal(a, b) -> bool:
    """The same array bit for bit (the model's cache key: the same input gives the same
    evaluation); a byte compare is several times faster than ``np.array_equal`` for arrays
    of up to a few thousand numbers, and it is made at every evaluation."""
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _same(a, b) -> bool:
    """``np.array_equal`` of two link masks, by their bytes first (:func:`_bits_equal`)."""
    return _bits_equal(a, b) or np.array_equal(a, b)


class DCBRTubeModel:
    """The periodic coarse tube (:class:`DCBRTube`) as an engine model, by composition.

    The engine's state holds the particle positions ``y`` (Å); the model holds the cell
    length ``Lz`` (Å, set by the scene with :meth:`set_cell`: the load of a tension scene)
    and relaxes the massless sublattice shifts delta at every configuration,

        E*(y) = min_{|delta_c| <= b} E(y, delta; Lz),     F = -dE*/dy = -dE/dy |_{delta*},

    (the envelope theorem; ``b`` = :data:`SHIFT_BOUND_FRACTION` a_cc, as
    :meth:`DCBRTube.minimise`), by Newton's method on the shifts alone at fixed gains (the
    shift energy is local to each particle's lattice, eq. 5.13, so the gains F_c stay fixed
    and its Hessian is block diagonal; L-BFGS-B where a Newton step is not clean:
    :meth:`_relaxed`), warm started from the last shifts, which live in
    ``state.extra["dcbr.delta"]`` (N, 3) and so are checkpointed. Forces are per particle
    (eV/Å, ``force_kind = "particle"``); masses are the scene's (``natoms_n`` x the carbon
    mass, amu). The failure rules
    (:meth:`DCBRTube.update_links`, then :meth:`DCBRTube.check_stability` if no link broke)
    are :meth:`break_bonds`; the links live in the tube (``tube.intact``), not in the
    engine's pair family (``needs.pairs`` is False).

    Parameters
    ----------
    tube : DCBRTube
        Periodic (``tube.periodic``); the model mutates its links on failure.
    shift_gtol : float
        Tolerance of the shift relaxation (max |dE/d delta| component, eV/Å).
    failure : bool
        Apply the failure rules in the engine's force evaluations (False: links never
        break, e.g. for an NVE stability run).
    cell : callable, optional
        ``cell(t) -> Lz`` (Å): a cell length prescribed in time (dynamic tension of the
        periodic tube, strain controlled); else the length of :meth:`set_cell`.

    The tube's link state (``tube.intact``, ``tube.alive``) is mirrored in
    ``state.extra["dcbr.intact"]`` / ``["dcbr.alive"]``, so a checkpoint carries it; a
    state whose links differ from the tube's (a resumed one) is given to the tube, and its
    gains rebuilt, at the next evaluation.
    """

    name = "dcbr-tube"
    force_kind = "particle"

    def __init__(self, tube: DCBRTube, *, shift_gtol: float = 1e-10, failure: bool = True,
                 cell=None):
        from upscale.models.base import Needs

        if not isinstance(tube, DCBRTube) or not getattr(tube, "periodic", True):
            raise ValueError(f"DCBRTubeModel takes a periodic DCBRTube, got {type(tube).__name__}")
        if not (np.isfinite(shift_gtol) and shift_gtol > 0):
            raise ValueError(f"shift_gtol must be positive, got {shift_gtol!r}")
        self.tube = tube
        self.Lz = float(tube.L)
        self.shift_gtol = float(shift_gtol)
        if cell is not None and not callable(cell):
            raise ValueError(f"cell must be a callable cell(t) -> Lz, got {cell!r}")
        self.cell = cell
        self.needs = Needs(pairs=False, failure=bool(failure), energy=True)
        self._cache = None
        self._held = False
        self.system = None

    def prepare(self, system, family=None, **kw) -> None:
        if system.n != self.tube.N:
            raise ValueError(f"the body has {system.n} particles, the tube {self.tube.N}; valid: "
                             "the tube's own particles (DCBRTube.x0)")
        if system.dim != 3:
            raise ValueError(f"the tube model needs a 3D body, got dim={system.dim}")
        self.system = system

    def init_state(self, state) -> None:
        state.extra.setdefault("dcbr.delta", np.array(self.tube.delta, dtype=np.float64))
        state.extra.setdefault("dcbr.intact", self.tube.intact.copy())
        state.extra.setdefault("dcbr.alive", self.tube.alive.copy())

    def _sync_links(self, state) -> None:
        """Give the tube the state's links if they differ (a resumed state)."""
        t = self.tube
        li, la = state.extra.get("dcbr.intact"), state.extra.get("dcbr.alive")
        if li is None:
            return
        if not (_same(li, t.intact) and _same(la, t.alive)):
            t.intact[...] = li
            t._build_gain(t.intact)
            t.alive &= la  # particles failed by the stability rule keep no link either
            self._cache = None

    def set_cell(self, Lz: float) -> None:
        """The periodic cell length (Å), the load of a tension scene."""
        if not (np.isfinite(Lz) and Lz > 0):
            raise ValueError(f"cell length must be positive, got {Lz!r}")
        self.Lz = float(Lz)
        self._cache = None

    def relax_shifts(self, y, delta) -> np.ndarray:
        """Mutates ``delta`` (N, 3) to the shifts minimising the energy at positions ``y``
        (max |dE/d delta| component <= ``shift_gtol``; :meth:`_relaxed`)."""
        self._relaxed(np.ascontiguousarray(y), delta)
        return delta

    #: Newton steps of the shift relaxation before it falls back to L-BFGS-B
    NEWTON_ITERATIONS = 10
    #: largest shift component change (Å) of one Newton step; a larger one falls back
    NEWTON_MAX_STEP = 0.02
    #: particles whose lattice parameters (lam_t, gam, lam_z, shift) agree to this share
    #: their Hessian block (Å, and dimensionless for the stretches): the block then errs by
    #: ~1e-5 relative, and a Newton step still divides the gradient by ~1e5 (a joint
    #: minimisation leaves the particles of a pristine tube 1e-10 to 1e-8 apart)
    HESSIAN_GROUP_TOL = 1e-6
    #: at most this many distinct lattice states get their blocks from the lattice cell
    #: (four cell evaluations each); more take three evaluations of the whole tube
    HESSIAN_MAX_GROUPS = 8

    def _relaxed(self, y, d, start=None, q=None):
        """Relax the shifts ``d`` (mutated) at positions ``y``; returns the tube's
        ``energy_and_gradient`` at (y, d) (``start``: that of the unrelaxed (y, d), if known,
        with ``q`` the lattice states (N, 6) it left in ``tube._q_n``).

        The shift energy is a sum of per-particle terms, each of its own shift alone (the
        gains fixed), so its Hessian is block diagonal: Newton's method on the (3, 3) blocks,
        each by forward differences of the gradient (step 1e-5 Å). A block depends only on
        the particle's lattice state q = (lam_t, gam, lam_z, shift): particles in the same
        state (to :attr:`HESSIAN_GROUP_TOL`; a pristine periodic tube under uniform strain
        has one) share it, computed on the lattice cell (four cell evaluations);
        with more than :attr:`HESSIAN_MAX_GROUPS` states all particles' component k is
        perturbed at once (three lattice-energy evaluations of the tube). Each step is
        checked by the lattice energy's gradient alone far from the minimum and, near it
        (gradient below 1e-5 eV/Å, where one step lands below ``shift_gtol``), by the tube's
        full evaluation, which the caller needs at the relaxed shifts anyway: from the
        shifts of a converged joint minimisation one step and one evaluation, where
        L-BFGS-B, whose line search compares energies, mostly ended on a failed line search
        after ~20 evaluations with the gradient unchanged (the energy changes by
        ~gradient^2 / stiffness, below its round-off). A step that is not a clean Newton
        step (a block not positive definite, a shift moving more than
        :attr:`NEWTON_MAX_STEP` Å or to its bound, a shift starting on its bound, a gradient
        that does not fall, a non-finite value) or no convergence in
        :attr:`NEWTON_ITERATIONS` steps falls back to L-BFGS-B
        (:func:`~upscale.engine.array_minimisers.lbfgs_b`, memory 10, shifts bounded by +-b) from
        the start."""
        t = self.tube
        if not t.relax_shift:
            return t.energy_and_gradient(y, d, self.Lz)
        b = t.shift_bound
        if np.any(np.abs(d) > b):
            np.clip(d, -b, b, out=d)
            start = None
        d0 = d.copy()
        out = self._newton_shifts(y, d, start, q, b)
        if out is not None:
            d[...], res = out
            return res
        Fg = t.gain.deformation(y, np.array([0.0, 0.0, self.Lz]))
        lat = t.lattice
        P = np.empty_like(Fg)
        e_n = np.empty(t.N)
        q_n = np.zeros((t.N, 6))
        gd = np.empty((t.N, 3))

        def fun(dv):
            dd = dv.reshape(t.N, 3)
            E = K.coarse_energy(Fg, t.S, np.ascontiguousarray(dd), t.natoms_n, t.alive, lat.s,
                                lat.z, lat.sub, lat.R0, lat.iA, lat.iB, lat.candA, lat.candB,
                                t.p, t.e0, P, gd, e_n, q_n)
            if not (np.isfinite(E) and np.all(np.isfinite(gd))):
                return np.inf, np.zeros_like(dv)
            return E, gd.ravel().copy()

        r = lbfgs_b(fun, d0.ravel(), -b, b, gtol=self.shift_gtol, max_iter=1000, memory=10,
                    ftol=1e-15, maxfun=15000)
        d[...] = r.x.reshape(t.N, 3)
        return t.energy_and_gradient(y, d, self.Lz)

    def _newton_shifts(self, y, d, res, q, b, h: float = 1e-5):
        """Block-diagonal Newton on the shifts from ``d`` (:meth:`_relaxed`; ``res``, ``q``:
        the tube's evaluation there and its lattice states, or None): ``(relaxed shifts,
        their evaluation)``, or None where it must fall back."""
        t = self.tube
        lat = t.lattice
        alive = t.alive
        work = {}

        def lattice_grad(dd):  # the lattice energy alone: (E, dE/d delta, q), no side effect
            if not work:
                Fg = t.gain.deformation(y, np.array([0.0, 0.0, self.Lz]))
                work.update(F=Fg, P=np.empty_like(Fg), e=np.empty(t.N))
            gk, qk = np.empty((t.N, 3)), np.zeros((t.N, 6))
            E = K.coarse_energy(work["F"], t.S, np.ascontiguousarray(dd), t.natoms_n, t.alive,
                                lat.s, lat.z, lat.sub, lat.R0, lat.iA, lat.iB, lat.candA,
                                lat.candB, t.p, t.e0, work["P"], gk, work["e"], qk)
            return E, gk, qk

        def full(dd):
            return t.energy_and_gradient(y, dd, self.Lz)

        if not alive.any():
            return d, res if res is not None else full(d)
        if res is not None and q is not None:
            E, gd = res[0], res[2]
        else:
            res = None
            E, gd, q = lattice_grad(d)
        if not (np.isfinite(E) and np.all(np.isfinite(gd))):
            return None
        gmax = float(np.abs(gd[alive]).max())
        if gmax <= self.shift_gtol:
            return d, res if res is not None else full(d)
        if np.any(np.abs(d[alive]) >= b):  # a shift on its bound: the bounded method decides
            return None
        for _ in range(self.NEWTON_ITERATIONS):
            step = self._newton_step(q, d, gd, lattice_grad, h)
            if step is None or not (np.all(np.isfinite(step))
                                    and np.abs(step).max() <= self.NEWTON_MAX_STEP):
                return None
            dn = d.copy()
            dn[alive] += step
            if np.any(np.abs(dn[alive]) >= b):
                return None
            if gmax <= 1e-5:
                res = full(dn)
                En, gn, qn = res[0], res[2], t._q_n
            else:
                res = None
                En, gn, qn = lattice_grad(dn)
            if not (np.isfinite(En) and np.all(np.isfinite(gn))):
                return None
            gn_max = float(np.abs(gn[alive]).max())
            if not gn_max < gmax:
                return None
            d, gd, gmax, q = dn, gn, gn_max, qn
            if gmax <= self.shift_gtol:
                return d, res if res is not None else full(d)
        return None

    def _newton_step(self, q, d, gd, lattice_grad, h):
        """The alive particles' Newton steps -H_c^-1 g_c (n, 3) on their shifts ``d``
        (gradient ``gd``, lattice states ``q`` (N, 6) as the energy kernel left them), the
        blocks H_c = d^2E/d delta_c^2 by forward differences (:meth:`_relaxed`: per lattice
        state on the lattice cell, or by three evaluations of the tube's lattice energy);
        None if a block is not positive definite."""
        t = self.tube
        lat = t.lattice
        alive = t.alive
        ga = gd[alive]
        qa = q[alive]
        tol = self.HESSIAN_GROUP_TOL
        if np.abs(qa - qa[0]).max() <= tol:  # one state (a pristine tube under uniform load)
            first, inverse = np.zeros(1, np.int64), np.zeros(len(qa), np.int64)
        else:
            _, first, inverse = np.unique(np.round(qa / tol), axis=0, return_index=True,
                                          return_inverse=True)
            inverse = inverse.ravel()
        if len(first) <= self.HESSIAN_MAX_GROUPS:
            P = len(lat.s)
            pos, gpos, g0, gk = np.empty((P, 3)), np.empty((P, 3)), np.empty(6), np.empty(6)
            Hg = np.empty((len(first), 3, 3))  # per atom: x N_c per particle
            for i, r in enumerate(first):
                qr = np.array(qa[r], dtype=float)
                K.cell_energy_grad(qr, lat.s, lat.z, lat.sub, lat.R0, lat.iA, lat.iB,
                                   lat.candA, lat.candB, t.p, pos, gpos, g0)
                for k in range(3):
                    qk = qr.copy()
                    qk[3 + k] += h
                    K.cell_energy_grad(qk, lat.s, lat.z, lat.sub, lat.R0, lat.iA, lat.iB,
                                       lat.candA, lat.candB, t.p, pos, gpos, gk)
                    Hg[i, :, k] = (gk[3:] - g0[3:]) / h
            Hg = 0.5 * (Hg + np.transpose(Hg, (0, 2, 1)))
            try:
                np.linalg.cholesky(Hg)
            except np.linalg.LinAlgError:
                return None
            Hinv = np.linalg.inv(Hg)
            return -np.einsum("nij,nj->ni", Hinv[inverse], ga) / t.natoms_n[alive][:, None]
        H = np.empty((len(qa), 3, 3))
        for k in range(3):
            dk = d.copy()
            dk[:, k] += h
            H[:, :, k] = (lattice_grad(dk)[1][alive] - ga) / h
        try:
            Lc = np.linalg.cholesky(0.5 * (H + np.transpose(H, (0, 2, 1))))
        except np.linalg.LinAlgError:
            return None
        return -np.linalg.solve(np.transpose(Lc, (0, 2, 1)),
                                np.linalg.solve(Lc, ga[:, :, None]))[:, :, 0]

    # the shifts as a massless internal field minimised with the positions (engine L-BFGS-B)
    @property
    def internal_fields(self) -> dict:
        """``{"dcbr.delta": (-b, b)}`` (the shifts and their bounds), empty without shift
        relaxation."""
        b = self.tube.shift_bound
        return {"dcbr.delta": (-b, b)} if self.tube.relax_shift else {}

    def hold_internal(self, flag: bool) -> None:
        """While held, the shifts are taken as they are in ``state.extra`` (a minimiser
        moves them); else they are relaxed at every configuration. The last evaluation is
        kept: at the same positions and shifts it is the held one, and the start of the
        relaxation when the hold ends (a minimiser's last iterate)."""
        self._held = bool(flag)

    def internal_gradient(self, state) -> dict:
        """``{"dcbr.delta": dE/d delta (N, 3)}`` (eV/Å) at the state's shifts."""
        return {"dcbr.delta": self._evaluate(state)[3]}

    def _evaluate(self, state):
        self._sync_links(state)
        if self.cell is not None:
            Lz = float(self.cell(state.t))
            if Lz != self.Lz:
                self.set_cell(Lz)
        y = np.ascontiguousarray(state.y)
        d = state.extra["dcbr.delta"]
        c = self._cache
        start = q = None
        # cache: (Lz, y, E, dE/dy, dE/dLz, dE/d delta, delta, shifts relaxed there, the
        # lattice states (N, 6) of that evaluation)
        if c is not None and c[0] == self.Lz and _bits_equal(c[1], y):
            if c[7] and not self._held:
                return c[2], c[3], c[4], c[5]
            if _bits_equal(c[6], d):
                if self._held:
                    return c[2], c[3], c[4], c[5]
                start, q = (c[2], c[3], c[5], c[4]), c[8]  # held there: the relaxation's start
        if self._held:
            E, gy, gd, gL = self.tube.energy_and_gradient(y, d, self.Lz)
        else:
            E, gy, gd, gL = self._relaxed(y, d, start, q)
        self._cache = (self.Lz, y.copy(), E, gy, gL, gd, d.copy(), not self._held,
                       self.tube._q_n)
        return E, gy, gL, gd

    # ------------------------------------------------------------------ the contract
    def add_force(self, state, out) -> None:
        out -= self._evaluate(state)[1]

    def step_force(self, state, out, *, failure=True) -> int:
        self.add_force(state, out)
        return self.break_bonds(state) if failure else 0

    def break_bonds(self, state) -> int:
        """The tube's failure rules at the current state (links first, then stability)."""
        self._evaluate(state)  # the rules read the lattice state of this configuration
        nb = self.tube.update_links()
        if nb == 0:
            nb = self.tube.check_stability(all_equal=True)
        if nb:
            self._cache = None
            if "dcbr.intact" in state.extra:
                state.extra["dcbr.intact"][...] = self.tube.intact
                state.extra["dcbr.alive"][...] = self.tube.alive
        return int(nb)

    def force(self, state):
        out = np.zeros_like(state.y)
        self.add_force(state, out)
        return out

    def energy(self, state) -> float:
        return float(self._evaluate(state)[0])

    def particle_damage(self, state) -> np.ndarray:
        """mu = 1 - R/T of the tube's links per particle (seed 004 eq. 5.16)."""
        self._sync_links(state)
        return self.tube.damage

    def cell_force(self, state) -> float:
        """dE/dLz (eV/Å): the axial force the periodic tube carries."""
        return float(self._evaluate(state)[2])

    def stiffness_bound(self):
        return None

    def describe(self) -> dict:
        t = self.tube
        return {"model": self.name, "chirality": [t.lattice.n, t.lattice.m],
                "coarsening": t.coarsening, "particles": t.N, "atoms": t.n_atoms,
                "potential": t.potential, "cutoff": t.cutoff, "hourglass": t.hourglass,
                "cell_length_A": self.Lz}
