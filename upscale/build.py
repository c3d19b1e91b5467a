"""Structures built with ASE: single-wall nanotubes, 7-tube bundles, vacancies, graphene.

Conventions (used by every scene and by the LAMMPS reference runners):

* The tube axis is **z**. A tube is centred on ``(x_c, y_c) = (Lx/2, Ly/2)`` in a full-rank
  orthorhombic cell: periodic along z with the exact length of a whole number of
  translational unit cells, and ``vacuum`` Å of empty space between the wall and each
  lateral face of the cell (``pbc = (False, False, True)``).
* The seed (004, sec. 5.3.1) puts the tube axis along its first coordinate and the vacancy at
  ``(L/2, R, 0)``: half way along the axis, on the wall in the direction of its second axis.
  We map the seed's ``(x_s, y_s, z_s)`` to ours by the cyclic (right-handed) permutation
  ``(x, y, z) = (y_s, z_s, x_s)`` about the tube centre line, so the seed's point is
  ``(x_c + R, y_c, z_0 + L/2)`` here: azimuth ``theta = 0``, mid-length.
* Geometry of an (n, m) tube with C–C bond ``a_cc`` (Saito, Dresselhaus & Dresselhaus,
  *Physical Properties of Carbon Nanotubes*, 1998, ch. 3): lattice constant
  ``a = sqrt(3) a_cc``, chiral vector length ``C_h = a sqrt(n^2 + n m + m^2)``, radius
  ``R = C_h / (2 pi)``, chiral angle ``theta_c = atan(sqrt(3) m / (2 n + m))``,
  ``d_R = gcd(2n + m, 2m + n)``, translation length ``T = sqrt(3) C_h / d_R`` and
  ``N_uc = 4 (n^2 + n m + m^2) / d_R`` atoms per translational unit cell. These are the
  rolled-up (ideal) values; a relaxed tube differs slightly with each potential.

Every builder returns a fresh :class:`ase.Atoms`; structural facts are also kept in
``atoms.info`` (``chirality``, ``radius``, ``axis_xy``, ``length``, ``unit_cell_length``,
``ncells``) so later steps (vacancy placement, stress conversion, damage maps) need no
guessing. Bundles carry a per-atom integer array ``atoms.arrays["mol-id"]`` (1 = central
tube, 2..7 = outer tubes; the name ASE's ``lammps-data`` writer uses) and the same number
in ``atoms.get_tags()``.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from ase import Atoms
from ase.build import nanotube

from upscale.constants import WALL_THICKNESS_A

__all__ = ["Chirality", "chirality", "cells_for_length", "swcnt", "bundle", "vacancy", "graphene",
           "WALL_THICKNESS", "VDW_GAP"]

#: Wall thickness of a graphitic shell used to convert forces to stresses, Å (interlayer
#: spacing of graphite; Yakobson et al., PRL 76, 2511 (1996) discuss the choice).
WALL_THICKNESS = WALL_THICKNESS_A
#: Default wall-to-wall gap between neighbouring tubes of a bundle, Å (graphite interlayer
#: spacing, ~ the equilibrium of the carbon Lennard-Jones pair sigma 2^(1/6) * 3.4 / 2^(1/6)).
VDW_GAP = 3.4


@dataclasses.dataclass(frozen=True)
class Chirality:
    """Rolled-up geometry of an (n, m) single-wall tube (ideal, before relaxation).

    Attributes
    ----------
    n, m : int
        Chiral indices.
    bond : float
        C–C bond length a_cc, Å.
    radius : float
        R = C_h / (2 pi), Å.
    chiral_angle_deg : float
        theta_c = atan(sqrt(3) m / (2n + m)), degrees (0 zigzag, 30 armchair).
    d_R : int
        gcd(2n + m, 2m + n).
    atoms_per_cell : int
        4 (n^2 + nm + m^2) / d_R.
    cell_length : float
        Translation length T = sqrt(3) C_h / d_R, Å.
    """

    n: int
    m: int
    bond: float
    radius: float
    chiral_angle_deg: float
    d_R: int
    atoms_per_cell: int
    cell_length: float

    @property
    def circumference(self) -> float:
        """|C_h| = 2 pi R, Å."""
        return 2.0 * math.pi * self.radius


def _check_nm(n, m):
    for name, v in (("n", n), ("m", m)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ValueError(f"chiral index {name}={v!r} must be an integer >= 0")
        if v < 0:
            raise ValueError(f"chiral index {name}={v} is negative; valid: integers n, m >= 0, "
                             "not both zero")
    if n == 0 and m == 0:
        raise ValueError("chirality (0, 0) is not a tube; valid: integers n, m >= 0, "
                         "not both zero")


def _check_positive(name, v):
    if not (isinstance(v, (int, float, np.integer, np.floating)) and np.isfinite(v) and v > 0):
        raise ValueError(f"{name}={v!r} must be a positive finite number")


def chirality(n: int, m: int, bond: float = 1.42) -> Chirality:
    """Geometry facts of an (n, m) tube (see module docstring for the formulas).

    Raises
    ------
    ValueError
        For negative indices, n = m = 0, or a non-positive bond length.
    """
    _check_nm(n, m)
    _check_positive("bond", bond)
    n, m = int(n), int(m)
    a = math.sqrt(3.0) * bond
    q = n * n + n * m + m * m
    Ch = a * math.sqrt(q)
    dR = math.gcd(2 * n + m, 2 * m + n)
    return Chirality(
        n=n, m=m, bond=float(bond), radius=Ch / (2.0 * math.pi),
        chiral_angle_deg=math.degrees(math.atan2(math.sqrt(3.0) * m, 2 * n + m)),
        d_R=dR, atoms_per_cell=4 * q // dR, cell_length=math.sqrt(3.0) * Ch / dR)


def cells_for_length(ch: Chirality, length: float) -> int:
    _check_positive("length", length)
    if length < 2.0 * ch.cell_length - 1e-9:
        raise ValueError(
            f"length={length:g} Å is shorter than two unit cells of the ({ch.n},{ch.m}) tube; "
            f"valid: length >= {2 * ch.cell_length:.4f} Å (unit cell {ch.cell_length:.4f} Å)")
    return max(2, int(round(length / ch.cell_length)))


def swcnt(n: int, m: int, length: float, bond: float = 1.42, vacuum: float = 10.0,
          symbol: str = "C") -> Atoms:
    """Periodic single-wall (n, m) nanotube along z, centred in a vacuum box.

    Parameters
    ----------
    n, m : int
        Chiral indices (n, m >= 0, not both zero).
    length : float
        Wanted tube length, Å. Rounded to the nearest whole number of translational unit
        cells ``ncells = round(length / T)`` (at least 2), so the periodic cell is exact; the
        actual length ``ncells * T`` is ``atoms.info["length"]``.
    bond : float
        C–C bond length of the rolled-up sheet, Å.
    vacuum : float
        Empty space between the wall and each lateral cell face, Å.

    Returns
    -------
    ase.Atoms
        ``ncells * N_uc`` atoms; cell ``diag(2R + 2 vacuum, 2R + 2 vacuum, ncells T)``,
        ``pbc = (False, False, True)``; every atom has three neighbours at ``bond`` Å across
        the periodic boundary.
    """
    ch = chirality(n, m, bond)
    _check_positive("vacuum", vacuum)
    nc = cells_for_length(ch, length)
    tube = nanotube(ch.n, ch.m, length=nc, bond=bond, symbol=symbol)
    Lz = nc * ch.cell_length
    if abs(tube.cell[2, 2] - Lz) > 1e-6 * Lz or len(tube) != nc * ch.atoms_per_cell:
        raise RuntimeError(f"ase.build.nanotube gave an unexpected cell for ({n},{m})")
    side = 2.0 * ch.radius + 2.0 * vacuum
    pos = tube.get_positions()
    # ase centres the tube on the origin; move it to the middle of the box
    pos[:, 0] += side / 2.0
    pos[:, 1] += side / 2.0
    pos[:, 2] = np.mod(pos[:, 2], Lz)
    pos[pos[:, 2] >= Lz, 2] -= Lz  # np.mod(-1e-16, L) == L
    atoms = Atoms(symbol * len(pos), positions=pos, cell=np.diag([side, side, Lz]),
                  pbc=(False, False, True))
    atoms.info.update(chirality=(ch.n, ch.m), radius=ch.radius, axis_xy=(side / 2, side / 2),
                      length=Lz, unit_cell_length=ch.cell_length, ncells=nc, bond=bond,
                      chiral_angle_deg=ch.chiral_angle_deg)
    return atoms


def bundle(n: int, m: int, length: float, ntubes: int = 7, spacing: str = "vdw",
           gap: float = VDW_GAP, bond: float = 1.42, vacuum: float = 12.0) -> Atoms:
    """Hexagonal bundle: a central (n, m) tube and up to six around it, all along z.

    Parameters
    ----------
    n, m, length, bond
        As in :func:`swcnt` (all tubes identical and in the same orientation).
    ntubes : int
        1 to 7: the central tube plus ``ntubes - 1`` neighbours on the hexagon vertices at
        azimuths 0, 60, ..., 300 degrees.
    spacing : {"vdw", "seed"}
        ``"vdw"``: centre-to-centre distance ``2 R + gap`` (walls ``gap`` Å apart, default
        3.4 Å, the graphite interlayer spacing). ``"seed"``: centre lines on a hexagon of side
        ``2.2 R`` as in seed 004 sec. 5.3.2 (for a (10,10) tube the walls are then only
        0.2 R = 1.36 Å apart, deep in the repulsive part of a carbon Lennard-Jones pair).
    gap : float
        Wall-to-wall gap for ``spacing="vdw"``, Å.
    vacuum : float
        Space between the outermost walls and the lateral cell faces, Å (keep above the LJ
        cutoff for a run with lateral periodicity).

    Returns
    -------
    ase.Atoms
        ``pbc = (False, False, True)``; ``arrays["mol-id"]`` and tags 1..ntubes;
        ``info["tube_centres"]`` (ntubes, 2) in Å; ``info["axis_xy"]`` is the central tube.
    """
    if isinstance(ntubes, bool) or not isinstance(ntubes, (int, np.integer)) or not 1 <= ntubes <= 7:
        raise ValueError(f"ntubes={ntubes!r}; valid: an integer 1..7 (centre + hexagon)")
    if spacing not in ("vdw", "seed"):
        raise ValueError(f"spacing={spacing!r}; valid: 'vdw' (wall gap) or 'seed' (2.2 R)")
    one = swcnt(n, m, length, bond=bond, vacuum=vacuum)
    R = one.info["radius"]
    if spacing == "vdw":
        _check_positive("gap", gap)
        d = 2.0 * R + gap
    else:
        d = 2.2 * R
    centres = [(0.0, 0.0)] + [(d * math.cos(k * math.pi / 3), d * math.sin(k * math.pi / 3))
                              for k in range(ntubes - 1)]
    centres = np.array(centres)
    ext = (np.abs(centres).max(axis=0) if ntubes > 1 else np.zeros(2)) + R + vacuum
    side = 2.0 * ext  # box (2 ext_x) x (2 ext_y), bundle centred
    base = one.get_positions() - [one.info["axis_xy"][0], one.info["axis_xy"][1], 0.0]
    pos, mol = [], []
    for k, c in enumerate(centres):
        p = base.copy()
        p[:, 0] += c[0] + side[0] / 2
        p[:, 1] += c[1] + side[1] / 2
        pos.append(p)
        mol.append(np.full(len(p), k + 1, dtype=int))
    pos = np.vstack(pos)
    mol = np.concatenate(mol)
    Lz = one.cell[2, 2]
    atoms = Atoms("C" * len(pos), positions=pos, cell=np.diag([side[0], side[1], Lz]),
                  pbc=(False, False, True))
    atoms.arrays["mol-id"] = mol
    atoms.set_tags(mol)
    info = dict(one.info)
    info.update(axis_xy=(side[0] / 2, side[1] / 2), ntubes=ntubes, spacing=spacing,
                centre_distance=d, wall_gap=d - 2 * R,
                tube_centres=(centres + side / 2).tolist())
    atoms.info.update(info)
    return atoms


def vacancy(atoms: Atoms, n: int = 4, at=None) -> Atoms:
    """Remove the ``n`` atoms nearest a point (a copy is returned; the input is untouched).

    Parameters
    ----------
    atoms : ase.Atoms
        A tube or bundle from :func:`swcnt` / :func:`bundle` (for the default point) or any
        structure (with ``at`` given).
    n : int
        Number of atoms to remove, 1 <= n < len(atoms).
    at : (3,) array_like, optional
        The point, Å. Default: the seed's ``(L/2, R, 0)`` (seed 004 sec. 5.3.1), i.e.
        ``(x_c + R, y_c, z_0 + L/2)`` on the central tube in our axis-along-z frame (see the
        module docstring), where ``z_0`` is the lowest atom's z.

    Returns
    -------
    ase.Atoms
        With ``info["vacancy"] = {"n", "at", "removed"}`` (indices into the input).
        Distances are minimum-image along periodic directions.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1 or n >= len(atoms):
        raise ValueError(f"vacancy n={n!r} for {len(atoms)} atoms; valid: 1 <= n < {len(atoms)}")
    if at is None:
        if "radius" not in atoms.info or "axis_xy" not in atoms.info:
            raise ValueError("vacancy(at=None) needs a tube from upscale.build (info['radius'], "
                             "info['axis_xy']); pass at=(x, y, z) otherwise")
        xc, yc = atoms.info["axis_xy"]
        z = atoms.positions[:, 2]
        if "mol-id" in atoms.arrays:
            z = z[atoms.arrays["mol-id"] == 1]
        at = (xc + atoms.info["radius"], yc, z.min() + 0.5 * atoms.info["length"])
    at = np.asarray(at, dtype=float)
    if at.shape != (3,) or not np.all(np.isfinite(at)):
        raise ValueError(f"vacancy at={at!r}; valid: three finite coordinates in Å")
    d = atoms.positions - at
    cell = atoms.cell.lengths()
    for k in range(3):
        if atoms.pbc[k] and cell[k] > 0:
            d[:, k] -= cell[k] * np.round(d[:, k] / cell[k])
    r = np.linalg.norm(d, axis=1)
    removed = np.sort(np.argsort(r, kind="stable")[:n])
    out = atoms.copy()
    del out[removed]
    out.info["vacancy"] = {"n": int(n), "at": at.tolist(), "removed": removed.tolist()}
    return out


def graphene(nx: int, ny: int, bond: float = 1.42, vacuum: float = 10.0) -> Atoms:
    """Flat periodic graphene sheet in the xy plane from a 4-atom orthorhombic cell.

    The rectangular cell is ``3 a_cc`` along x (armchair direction: bonds parallel to x) and
    ``sqrt(3) a_cc`` along y (zigzag direction), repeated ``nx`` x ``ny`` times; z carries
    ``2 vacuum`` Å of empty space (full-rank cell, ``pbc = (True, True, False)``).

    Returns
    -------
    ase.Atoms
        ``4 nx ny`` atoms at z = vacuum, each with three neighbours at ``bond`` Å.
    """
    for name, v in (("nx", nx), ("ny", ny)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name}={v!r}; valid: an integer >= 1 (number of 4-atom cells)")
    _check_positive("bond", bond)
    _check_positive("vacuum", vacuum)
    a = bond
    h = math.sqrt(3.0) / 2.0 * a
    basis = np.array([[0.0, 0.0], [a, 0.0], [1.5 * a, h], [2.5 * a, h]])
    Lx, Ly = 3.0 * a, 2.0 * h
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    shifts = np.stack([ii.ravel() * Lx, jj.ravel() * Ly], axis=1)
    xy = (shifts[:, None, :] + basis[None, :, :]).reshape(-1, 2)
    pos = np.column_stack([xy, np.full(len(xy), vacuum)])
    atoms = Atoms("C" * len(pos), positions=pos, cell=np.diag([nx * Lx, ny * Ly, 2 * vacuum]),
                  pbc=(True, True, False))
    atoms.info.update(bond=bond, sheet="graphene", nx=nx, ny=ny)
    return atoms
# Defect builders by (zfrac, angle_deg); upscale.defects imports this module only lazily.
from upscale.defects import (adatom, apply_defects, divacancy, monovacancy,  # noqa: E402,F401
                             parse_defects, stone_wales, vacancy4)
