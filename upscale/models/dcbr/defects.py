"""Defects of the registered tubes: where the atoms leave the perfect honeycomb.

An atom is defective when it has other than three bonds, sits off every free site of its
tube's lattice map (further than :data:`~upscale.models.dcbr.lattice.OFF_SITE` = 0.7 Å,
radial offset included: adatoms, interstitials, the rotated pair of a Stone–Wales defect),
or has a bond angle whose shortest ring is not a hexagon (:mod:`.rings`: this catches the
Stone–Wales 55-77 and the reconstructed 5-8-5 / 555-777 divacancies whose atoms are all
3-fold). A site is defective when it lies inside the tube and no atom occupies it
(vacancies). Defective atoms and empty sites closer than ``1.45 a_cc`` (one bond with room
for strain, below the 2.46 Å second neighbours) form one defect, across the periodic
boundary too (distances in the tube's frame, the axis coordinate periodic).

Kind guess from the atoms added, ``extra = (off-site atoms) - (empty sites)``, and the rings:

* the end of a finite tube (a defect reaching within 1.5 Å of either end): ``"edge"``;
* ``extra < 0``: ``"v<k>"``, k = -extra missing atoms (``"v1"``, ``"v2"``, ``"v4"``);
* ``extra = 0`` with pentagons and heptagons: ``"sw"`` (Stone–Wales), otherwise
  ``"distortion"`` (bonds or rings changed, no atom missing or added);
* ``extra = 1``: ``"adatom"``; ``extra > 1``: ``"interstitial<k>"``.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from upscale.models.dcbr.rings import angle_rings, ring_limit

__all__ = ["Defect", "find_defects", "frame_points", "frame_tree"]

#: Defective atoms and empty sites closer than this many bond lengths are one defect.
_LINK_BONDS = 1.45
#: A defect reaching this close to either end of a finite tube is its edge, Å.
_EDGE_REACH = 1.5


@dataclasses.dataclass(frozen=True)
class Defect:
    """One defect of one tube.

    Attributes
    ----------
    tube : int
        Index into ``Structure.tubes``.
    kind : str
        Guess: ``"v1"``, ``"v2"``, ``"v4"`` (``"v<k>"``), ``"sw"``, ``"adatom"``,
        ``"interstitial<k>"``, ``"distortion"`` or ``"edge"``.
    atoms : (k,) int
        Defective atoms (indices into the structure).
    sites : (e,) int
        Empty lattice sites (ids of the tube's lattice map).
    site_positions : (e, 3) float
        Their ideal positions, Å.
    z : float
        Axial position of the defect's centre, Å (in [0, L) on a periodic tube).
    azimuth_deg : float
        Its azimuth about the axis, degrees in [0, 360) (0 along the tube's e1).
    position : (3,) float
        The centre on the wall, Å.
    rings : dict
        Non-hexagonal ring size -> count among its atoms' bond angles.
    extra : int
        Off-site atoms minus empty sites (negative: atoms missing).
    """

    tube: int
    kind: str
    atoms: np.ndarray
    sites: np.ndarray
    site_positions: np.ndarray
    z: float
    azimuth_deg: float
    position: np.ndarray
    rings: dict
    extra: int


def frame_points(tube, phi, z, r):
    """Points in the tube's own frame (x = r cos phi, y = r sin phi, z; z wrapped to [0, L)
    on a periodic tube), shifted to be non-negative, and the k-d tree box (or None)."""
    z = np.mod(z, tube.length) if tube.periodic else z - tube.z.min() + 10.0
    off = tube.radius + 20.0
    pts = np.stack([r * np.cos(phi) + off, r * np.sin(phi) + off, z], axis=1)
    box = np.array([4 * off, 4 * off, tube.length]) if tube.periodic else None
    if box is not None:
        pts[:, 2] = np.where(pts[:, 2] >= box[2], 0.0, pts[:, 2])
    return np.clip(pts, 0.0, None), box


def frame_tree(tube, phi, z, r):
    """k-d tree of points in the tube frame (periodic along a periodic tube's axis)."""
    pts, box = frame_points(tube, phi, z, r)
    return cKDTree(pts, boxsize=box), pts


def _flags(structure, tube):
    """Defective atoms (local indices into tube.atoms) and the ring sizes of all atoms."""
    g = structure.graph
    coord = g.coordination[tube.atoms]
    rings = angle_rings(g, tube.atoms, ring_limit(tube.radius, tube.bond))
    odd_ring = ((rings != 6) & (rings != -1)).any(axis=1)
    bad = (coord != 3) | (tube.lattice.site < 0) | odd_ring
    return np.flatnonzero(bad), rings


def _site_points(tube, ids):
    uv = tube.lattice.site_uv(ids)
    return uv[:, 0] / tube.radius, uv[:, 1]


def _clusters(tube, bad, ids):
    """Defect label of each defective atom and each empty site."""
    sphi, sz = _site_points(tube, ids)
    phi = np.concatenate([tube.phi[bad], sphi])
    z = np.concatenate([tube.z[bad], sz])
    r = np.concatenate([tube.r[bad], np.full(len(ids), tube.radius)])
    tree, _ = frame_tree(tube, phi, z, r)
    pairs = tree.query_pairs(_LINK_BONDS * tube.bond, output_type="ndarray")
    n = len(phi)
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(adj, directed=False)[1], phi, z


def _centre(tube, phi, z):
    a = np.angle(np.mean(np.exp(1j * phi)))
    if tube.periodic:
        L = tube.length
        zc = np.mod(np.angle(np.mean(np.exp(2j * np.pi * z / L))) * L / (2 * np.pi), L)
    else:
        zc = float(np.mean(z))
    return float(np.mod(a, 2 * np.pi)), float(zc)


def _ring_counts(rings):
    sizes, counts = np.unique(rings[(rings > 0) & (rings != 6)], return_counts=True)
    return {int(k): max(1, int(round(c / k))) for k, c in zip(sizes, counts)}


def _kind(tube, extra, rings, z):
    if not tube.periodic and (np.min(z) - tube.z.min() < _EDGE_REACH
                              or tube.z.max() - np.max(z) < _EDGE_REACH):
        return "edge"
    if extra < 0:
        return f"v{-extra}"
    if extra == 0:
        return "sw" if 5 in rings and 7 in rings else "distortion"
    return "adatom" if extra == 1 else f"interstitial{extra}"


def _tube_defects(structure, t):
    tube = structure.tubes[t]
    bad, rings = _flags(structure, tube)
    empty = tube.lattice.empty_sites
    if len(bad) + len(empty) == 0:
        return []
    label, phi, z = _clusters(tube, bad, empty)
    out = []
    for c in range(label.max() + 1):
        mine = np.flatnonzero(label == c)
        a_loc = bad[mine[mine < len(bad)]]
        s_ids = empty[mine[mine >= len(bad)] - len(bad)]
        extra = int((tube.lattice.site[a_loc] < 0).sum()) - len(s_ids)
        ring = _ring_counts(rings[a_loc])
        ph, zc = _centre(tube, phi[mine], z[mine])
        sphi, sz = _site_points(tube, s_ids)
        out.append(Defect(
            t, _kind(tube, extra, ring, z[mine]), tube.atoms[a_loc], s_ids,
            tube.cartesian(sphi, np.mod(sz, tube.length) if tube.periodic else sz),
            zc, float(np.degrees(ph)), tube.cartesian(ph, zc), ring, extra))
    return sorted(out, key=lambda d: (d.z, d.azimuth_deg))


def find_defects(structure) -> list[Defect]:
    """Every defect of every tube of a registered :class:`Structure` (tube by tube, each
    tube's sorted by axial position)."""
    return [d for t in range(len(structure.tubes)) for d in _tube_defects(structure, t)]
