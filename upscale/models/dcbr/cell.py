"""The lattice a coarse particle carries: a patch of the ideal (n, m) tube around a bond.

Seed 004 sec. 5.3.1, eq. 5.13 (discrete Cauchy-Born rule): a particle's energy per atom is
the Tersoff energy of its lattice with the bonds mapped by its gain. On a closed tube the
uniform maps are

    s' = lam_t s + gam z,   z' = lam_z z,   radius' = lam_t R0        (s = R0 theta, arc)

(M = [[lam_t, gam], [0, lam_z]] with M^T M = C, the particle's surface metric), and the
second sublattice B is shifted by (d_rho, d_s, d_z). :class:`TubeCell` holds the patch of
the tube's own atoms around a bonded pair A0-B0 in reference cylinder coordinates (s, z)
and sublattice flags, and evaluates the energy per atom e(q) = (E_A0 + E_B0) / 2 of the
patch mapped by q = (lam_t, gam, lam_z, d_rho, d_s, d_z) (:func:`.kernels.cell_energy_grad`).

The patch is built from :func:`upscale.build.swcnt` exactly as the validated coarse tube
(``upscale.models.dcbr.TubeLattice``, the old module) builds it, so the two give the same
numbers: A0 is the atom nearest (theta = 0, z = L/2), B0 its most axial bonded neighbour,
the patch every atom within ``r_patch`` (chord) of A0 or B0.

Units: Å, eV. Suffixes: ``_p`` per patch atom.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from potentials.tersoff import read_tersoff_file
from upscale.models.dcbr import kernels as K

__all__ = ["TubeCell", "tersoff_row"]


def tersoff_row(potential: str = "BNC.tersoff", element: str = "C",
                step_cutoff: bool = True) -> np.ndarray:
    """The ``element element element`` row (24,) of the project's Tersoff parameter table
    (:attr:`potentials.tersoff.TersoffParameters.table`, columns
    ``potentials.tersoff_kernels.IDX_*``); with ``step_cutoff`` f_C is a step at R + D
    (2.1 Å for C-C in BNC.tersoff), as the atomistic model and the LAMMPS references."""
    name = potential.split(":", 1)[1] if potential.lower().startswith("tersoff:") else potential
    par = read_tersoff_file(name, [element]).with_step_cutoff(bool(step_cutoff))
    return np.ascontiguousarray(par.table[par.e2p[0, 0, 0]])


def _two_colour(pairs: np.ndarray, start: int) -> np.ndarray:
    """Sublattice flag 0/1 of each patch atom by breadth-first 2-colouring of the bonds."""
    sub = -np.ones(len(pairs))
    sub[start] = 0
    front = [start]
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
    return sub


@dataclasses.dataclass
class TubeCell:
    """Patch of the ideal rolled (n, m) tube around the bonded pair A0-B0.

    Attributes
    ----------
    s_p, z_p : (P,) float
        Reference arc R0 (theta - theta_A0) and axial z - z_A0, Å.
    sub_p : (P,) float
        Sublattice flag, 0 (A) or 1 (B).
    R0 : float
        Radius of the ideal tube, Å.
    iA, iB : int
        Patch indices of A0 and B0.
    candA, candB : (k,) int64
        Patch atoms within ``r_patch`` of A0 / B0 (Tersoff neighbour candidates).
    bondsA : (3,) int64
        The three bonded neighbours of A0.
    n, m : int
    bond : float
        a_cc of the reference tube, Å.
    """

    s_p: np.ndarray
    z_p: np.ndarray
    sub_p: np.ndarray
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
    def build(cls, n: int, m: int, bond: float = 1.42, r_patch: float = 3.2) -> "TubeCell":
        """The patch of the ideal (n, m) tube of C-C bond ``bond`` (Å)."""
        from upscale.build import chirality, swcnt  # noqa: PLC0415

        ch = chirality(n, m, bond)
        length = max(3 * ch.cell_length, 4 * r_patch + 2.0)
        atoms = swcnt(n, m, length=length, bond=bond, vacuum=5.0)
        cx, cy = atoms.info["axis_xy"]
        Lz = atoms.cell[2, 2]
        x = atoms.get_positions() - [cx, cy, 0.0]
        rho = np.hypot(x[:, 0], x[:, 1])
        R0 = float(rho.mean())
        th = np.arctan2(x[:, 1], x[:, 0])
        iA0 = int(np.argmin(np.abs(x[:, 2] - Lz / 2) + np.abs(th)))

        def rel(i0):
            dth = (th - th[i0] + np.pi) % (2 * np.pi) - np.pi
            dz = x[:, 2] - x[i0, 2]
            return dth, dz - Lz * np.round(dz / Lz)

        def chord(i0):
            dth, dz = rel(i0)
            return np.sqrt((2 * R0 * np.sin(dth / 2)) ** 2 + dz ** 2)

        dA = chord(iA0)
        nb = np.nonzero((dA > 0.1) & (dA < 1.1 * bond))[0]
        if len(nb) != 3:
            raise RuntimeError(f"atom A0 has {len(nb)} bonded neighbours, expected 3")
        iB0 = int(nb[np.argmax(np.abs(rel(iA0)[1][nb]))])  # the most axial bond
        dB = chord(iB0)
        inp = np.nonzero((dA < r_patch) | (dB < r_patch))[0]
        dth, dz = rel(iA0)
        s, zz = R0 * dth[inp], dz[inp]
        P = len(inp)
        pairs = np.zeros((P, P), dtype=bool)
        for a in range(P):
            da = np.sqrt((2 * R0 * np.sin((dth[inp] - dth[inp][a]) / 2)) ** 2 + (zz - zz[a]) ** 2)
            pairs[a] = (da > 0.1) & (da < 1.1 * bond)
        iA = int(np.nonzero(inp == iA0)[0][0])
        iB = int(np.nonzero(inp == iB0)[0][0])
        sub = _two_colour(pairs, iA)
        candA = np.nonzero((dA[inp] < r_patch) & (np.arange(P) != iA))[0]
        candB = np.nonzero((dB[inp] < r_patch) & (np.arange(P) != iB))[0]
        return cls(s_p=np.ascontiguousarray(s), z_p=np.ascontiguousarray(zz), sub_p=sub,
                   R0=R0, iA=iA, iB=iB, candA=candA.astype(np.int64),
                   candB=candB.astype(np.int64), bondsA=np.nonzero(pairs[iA])[0].astype(np.int64),
                   n=int(n), m=int(m), bond=float(bond))

    def args(self) -> tuple:
        """The patch arrays in the order the kernels take them (s, z, sub, R0, iA, iB,
        candA, candB)."""
        return (self.s_p, self.z_p, self.sub_p, self.R0, self.iA, self.iB, self.candA,
                self.candB)

    def energy(self, q, P_f) -> tuple:
        """Energy per atom e(q) (eV) and de/dq (6,) of the patch mapped by q (6,)."""
        g = np.empty(6)
        e = K.cell_energy_grad(np.asarray(q, dtype=float), *self.args(), P_f, g)
        return float(e), g

    def relaxed(self, lam_t: float, gam: float, lam_z: float, P_f) -> tuple:
        """min over the sublattice shift of e(lam_t, gam, lam_z, shift): (e eV, shift (3,) Å),
        by Newton's method on the three shift components (:func:`.kernels.relax_cell_shift`)."""
        q = np.array([lam_t, gam, lam_z, 0.0, 0.0, 0.0])
        ok = K.relax_cell_shift(q, *self.args(), P_f, 1e-12, 50)
        if not ok:
            raise RuntimeError(f"the sublattice shift did not relax at (lam_t, gam, lam_z) = "
                               f"({lam_t}, {gam}, {lam_z})")
        return self.energy(q, P_f)[0], q[3:].copy()
