"""Bond networks, the damage index, and crack position/angle on the unrolled tube surface.

Damage index (seed 004 eq. 5.16): ``mu_i = 1 - R_i / T_i`` with ``T_i`` the number of bonds
of atom i in the reference (initial) network and ``R_i`` the number of those still intact;
``mu = 0`` for an intact atom, 1 for an atom that lost all its bonds. Atoms next to a vacancy
have fewer bonds in the reference network but are not damaged by that. A bond is in the
reference network if its length is below ``bond_cutoff`` (default 2.0 Å, well above the
1.42-1.46 Å C–C bond and below the 2.46 Å second-neighbour distance) and counts as broken
once longer than ``break_cutoff`` (default 2.1 Å, the outer cutoff R + D of the C–C
Tersoff interaction: beyond it the pair no longer interacts).

Unrolled surface: azimuth ``theta = atan2(y - y_c, x - x_c)`` in (-pi, pi] about the tube
axis, arc coordinate ``s = R theta``, and ``z``. The seed's vacancy point ``(L/2, R, 0)`` is
at theta = 0 (see :mod:`upscale.build`).

Crack line: total-least-squares line (principal axis) through the damaged atoms on the
(s, z) plane; its angle to the tube axis is reported in [0, 90] degrees (90: a
circumferential crack, perpendicular to the axis).

Array suffix convention: ``_n`` per atom, ``_b`` per bond.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

__all__ = ["bond_network", "damage_index", "unroll", "crack_line", "read_dump",
           "DumpDamage", "dump_damage", "split_along_axis", "dump_box_lows"]


def _box(box):
    if box is None:
        return None
    b = np.asarray(box, dtype=np.float64)
    if b.shape == (3,):
        b = np.concatenate([b, [90.0, 90.0, 90.0]])
    if b.shape != (6,):
        raise ValueError(f"box must be (3,) lengths or (6,) [lx ly lz alpha beta gamma], "
                         f"got shape {b.shape}")
    return b.astype(np.float32)


def bond_network(x_nc, bond_cutoff: float = 2.0, box=None) -> np.ndarray:
    """Pairs of atoms closer than ``bond_cutoff`` Å (minimum image if ``box`` is given).

    Parameters
    ----------
    x_nc : (N, 3) float
        Positions, Å.
    box : (3,) or (6,) array_like, optional
        Orthorhombic periodic box lengths (MDAnalysis ``dimensions``). Periodic in all three
        directions when given; pass a large length for a non-periodic direction.

    Returns
    -------
    (nb, 2) int64
        Bond pairs ``i < j``, sorted.
    """
    from MDAnalysis.lib.distances import self_capped_distance  # noqa: PLC0415

    x = np.ascontiguousarray(x_nc, dtype=np.float32)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"positions must have shape (N, 3), got {x.shape}")
    if not bond_cutoff > 0:
        raise ValueError(f"bond_cutoff={bond_cutoff}; valid: > 0 Å")
    pairs, _ = self_capped_distance(x, bond_cutoff, box=_box(box))
    pairs = np.sort(np.asarray(pairs, dtype=np.int64), axis=1)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order]


def bond_lengths(x_nc, pairs_b, box=None) -> np.ndarray:
    """Lengths (Å) of bonds ``pairs_b`` (nb, 2) at positions ``x_nc`` (minimum image)."""
    from MDAnalysis.lib.distances import calc_bonds  # noqa: PLC0415

    x = np.ascontiguousarray(x_nc, dtype=np.float64)
    p = np.asarray(pairs_b, dtype=np.int64)
    if len(p) == 0:
        return np.zeros(0)
    return calc_bonds(x[p[:, 0]], x[p[:, 1]], box=_box(box))


def damage_index(pairs_b, x_nc, break_cutoff: float = 2.1, box=None,
                 n_atoms: int | None = None) -> np.ndarray:
    """Per-atom damage ``mu = 1 - R/T`` (seed 004 eq. 5.16).

    Parameters
    ----------
    pairs_b : (nb, 2) int
        Reference bond network (from :func:`bond_network` on the initial state).
    x_nc : (N, 3) float
        Current positions, Å.
    break_cutoff : float
        A bond longer than this (Å) is broken.

    Returns
    -------
    (N,) float
        mu in [0, 1]; 0 for atoms without reference bonds.
    """
    p = np.asarray(pairs_b, dtype=np.int64).reshape(-1, 2)
    n = len(x_nc) if n_atoms is None else int(n_atoms)
    intact_b = bond_lengths(x_nc, p, box) <= break_cutoff
    T_n = np.bincount(p.ravel(), minlength=n).astype(float)
    R_n = (np.bincount(p[intact_b, 0], minlength=n)
           + np.bincount(p[intact_b, 1], minlength=n)).astype(float)
    mu = np.zeros(n)
    has = T_n > 0
    mu[has] = 1.0 - R_n[has] / T_n[has]
    return mu


def unroll(x_nc, axis_xy, radius: float | None = None, theta0: float = 0.0):
    """Unrolled tube surface coordinates.

    Parameters
    ----------
    x_nc : (N, 3) float
        Positions, Å, tube axis along z through ``axis_xy``.
    radius : float, optional
        R for the arc coordinate; default the mean distance from the axis.
    theta0 : float
        Azimuth (rad) mapped to the middle of the map (s = 0).

    Returns
    -------
    s_n, z_n : (N,) float
        Arc coordinate ``R * wrap(theta - theta0)`` in [-pi R, pi R) and z, Å.
    """
    x = np.asarray(x_nc, dtype=float)
    dx, dy = x[:, 0] - axis_xy[0], x[:, 1] - axis_xy[1]
    if radius is None:
        radius = float(np.hypot(dx, dy).mean())
    th = np.arctan2(dy, dx) - theta0
    th = (th + np.pi) % (2.0 * np.pi) - np.pi
    return radius * th, x[:, 2].copy()


def crack_line(s_n, z_n, weights=None) -> dict:
    """Straight line through crack points on the unrolled surface.

    Parameters
    ----------
    s_n, z_n : (k,) float
        Arc and axial coordinates of the damaged atoms, Å (k >= 2).
    weights : (k,) float, optional
        E.g. the damage index; default equal weights.

    Returns
    -------
    dict
        ``centre_s_A``, ``centre_z_A`` (weighted mean), ``angle_to_axis_deg`` in [0, 90]
        (angle between the principal axis of the points and the tube axis z; 90 for a
        circumferential crack), ``extent_s_A`` (spread along the line, 2 x std),
        ``straightness`` (1 - minor/major variance ratio; 1 = perfectly straight).
    """
    s = np.asarray(s_n, dtype=float)
    z = np.asarray(z_n, dtype=float)
    if s.shape != z.shape or s.ndim != 1 or len(s) < 2:
        raise ValueError(f"crack_line needs >= 2 points with equal 1-D shapes, got {s.shape}, "
                         f"{z.shape}")
    w = np.ones_like(s) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != s.shape or np.any(w < 0) or w.sum() <= 0:
        raise ValueError("weights must be non-negative, same shape as s, not all zero")
    w = w / w.sum()
    c = np.array([np.sum(w * s), np.sum(w * z)])
    d = np.column_stack([s, z]) - c
    C = (d * w[:, None]).T @ d
    evals, evecs = np.linalg.eigh(C)
    u = evecs[:, 1]  # major axis (s, z) components
    if u[1] < 0 or (u[1] == 0 and u[0] < 0):
        u = -u
    ang = np.degrees(np.arctan2(abs(u[0]), abs(u[1])))  # angle from the z axis
    straight = 1.0 - (evals[0] / evals[1] if evals[1] > 0 else 1.0)
    return {"centre_s_A": float(c[0]), "centre_z_A": float(c[1]),
            "angle_to_axis_deg": float(ang), "extent_A": float(2.0 * np.sqrt(max(evals[1], 0))),
            "straightness": float(straight), "n_points": int(len(s)),
            "direction_sz": [float(u[0]), float(u[1])]}


def split_along_axis(z_n, gap: float = 5.0) -> list[np.ndarray]:
    """Group points into clusters separated by axial gaps larger than ``gap`` Å.

    Returns a list of index arrays into ``z_n`` (each sorted by z), e.g. the separate
    crack rings of a tube that broke in two places.
    """
    z = np.asarray(z_n, dtype=float)
    if z.size == 0:
        return []
    order = np.argsort(z, kind="stable")
    cuts = np.nonzero(np.diff(z[order]) > gap)[0] + 1
    return [np.asarray(g) for g in np.split(order, cuts)]


def read_dump(path):
    """Open a LAMMPS dump (``id type x y z``) with MDAnalysis.

    Returns
    -------
    MDAnalysis.Universe
        Atoms in id order; ``universe.trajectory`` iterates frames (positions in Å,
        ``ts.dimensions`` the box lengths and angles).
    """
    import warnings  # noqa: PLC0415

    import MDAnalysis as mda  # noqa: PLC0415

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"dump file {str(p)!r} does not exist")
    with warnings.catch_warnings():  # masses and dt are not in a dump; we need neither
        warnings.simplefilter("ignore", UserWarning)
        return mda.Universe(str(p), format="LAMMPSDUMP", topology_format="LAMMPSDUMP",
                            lammps_coordinate_convention="unscaled")


def dump_box_lows(path) -> np.ndarray:
    """Lower box bounds ``(frames, 3)`` of an orthogonal LAMMPS dump, Å.

    MDAnalysis moves every frame's box to the origin (it subtracts these bounds from the
    positions); adding them back restores LAMMPS's absolute coordinates, so frames of a
    growing shrink-wrapped box stay comparable.
    """
    lows = []
    with open(path) as fh:
        for line in fh:
            if line.startswith("ITEM: BOX BOUNDS"):
                lows.append([float(next(fh).split()[0]) for _ in range(3)])
    return np.array(lows, dtype=float).reshape(-1, 3)


@dataclasses.dataclass
class DumpDamage:
    """Damage history of a dump: per-frame mu and the first damaged frame."""

    mu_fn: np.ndarray          # (frames, N)
    x_first_nc: np.ndarray     # (N, 3) positions of the first frame (LAMMPS coordinates)
    x_last_nc: np.ndarray      # (N, 3) positions of the last frame (LAMMPS coordinates)
    n_bonds: int
    first_damage_frame: int | None
    frames: int


def dump_damage(path, bond_cutoff: float = 2.0, break_cutoff: float = 2.1,
                periodic_z: bool = True, frames=None) -> DumpDamage:
    """Damage index of every frame of a LAMMPS dump against the network of its first frame.

    ``periodic_z``: the dump comes from a cell periodic along z (quasi-static runs); the box
    lengths of each frame are then used along z with minimum image (x, y are taken as
    non-periodic). Dynamic runs (``periodic_z=False``) use plain distances.
    """
    u = read_dump(path)
    n = len(u.atoms)
    big = 1e6
    lows = dump_box_lows(path)  # absolute LAMMPS coordinates (see dump_box_lows)

    def box_of(dims):
        if not periodic_z:
            return None
        return np.array([big, big, dims[2]])

    traj = u.trajectory if frames is None else u.trajectory[frames]
    mus = []
    x_first = x_last = None
    pairs = None
    import warnings  # noqa: PLC0415

    with warnings.catch_warnings():  # "no dt information": times are not used
        warnings.simplefilter("ignore", UserWarning)
        frames_list = [(ts.dimensions.copy(), u.atoms.positions.astype(np.float64)
                        + lows[ts.frame]) for ts in traj]
    for dims, x in frames_list:
        if pairs is None:
            pairs = bond_network(x, bond_cutoff, box_of(dims))
            x_first = x.copy()
        mus.append(damage_index(pairs, x, break_cutoff, box_of(dims), n))
        x_last = x.copy()
    mu = np.array(mus)
    first = np.nonzero(mu.max(axis=1) > 0)[0]
    return DumpDamage(mu, x_first, x_last, len(pairs), int(first[0]) if len(first) else None,
                      len(mus))
