"""Structure recognition: the tubes of an ``ase.Atoms``, each with axis, radius, chirality
and lattice map, registered from the atoms alone.

Steps (reading notes ``adaptive-coupling.md`` sec. 1):

1. Bonds below the cutoff (:mod:`.graph`); the connected pieces are the tubes, unwrapped
   across periodic faces by walking the bonds. A piece that comes back onto itself
   shifted by a cell vector P is periodic along P.
2. Axis: P for a periodic tube; otherwise the eigenvector with the smallest eigenvalue of
   ``sum_i n_i n_i^T`` over the unit normals n_i of the planes through each 3-fold atom's
   neighbours (they are normal to the axis; principal axes of the atoms fail for tubes
   shorter than 2.45 R). A flat sheet has two small eigenvalues: no tube.
3. Radius and axis point: algebraic circle fit (Kasa) of the atoms projected on the plane
   normal to the axis, ``x^2 + y^2 = 2 a x + 2 b y + c``, ``R^2 = c + a^2 + b^2``, refitted
   without atoms more than 1 Å off (adatoms). Frame: e_z the axis (sign: its largest
   Cartesian component positive), e_1 the projection of the Cartesian x (or y) axis,
   e_2 = e_z x e_1; azimuth phi from e_1 towards e_2, so (e_t, e_z, e_r) is right-handed.
4. Chirality, exactly: each bond's angle alpha in the unrolled (t = R phi, z) sheet is
   labelled with the nearest of the six bond directions alpha_0 + k 60 deg (alpha_0 from
   Psi_6 = <exp(6 i alpha)>). Summing the lattice steps of the labels around a closed path
   that winds once round the tube gives the chiral vector C = p a1 + q a2 exactly while no
   bond is 30 deg off (a Burgers circuit). The paths are the fundamental cycles of a
   breadth-first tree (winding from the unwrapped azimuth, none through a periodic face);
   each C is rotated by multiples of 60 deg into [0, 60) deg from a1 and votes; the
   majority wins (a minority marks a path through a 5-7 pair). a_cc is the mean bond
   unrolled onto the sheet (arc R dphi and axial dz; the chord is shorter by ~(a/R)^2/24).
5. The lattice map (:mod:`.lattice`).

Conventions: (n, m) with n > m is the handedness :func:`ase.build.nanotube` builds for
n > m; (m, n) is its mirror image. Lengths Å, angles degrees in the results.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from ase import Atoms

from upscale.models.dcbr.graph import (BOND_CUTOFF, BondGraph, bfs_tree, bond_graph,
                                       components, tree_accumulate)
from upscale.models.dcbr.lattice import LatticeMap, fit_lattice

__all__ = ["Tube", "Structure", "register", "MIN_TUBE_ATOMS"]

#: Pieces with fewer atoms than this are loose atoms, not tubes.
MIN_TUBE_ATOMS = 24
#: A bond more than this off every lattice direction takes no part in a circuit, degrees.
_LABEL_TOLERANCE = 15.0
#: An atom more than this off the fitted radius is not on the wall, Å.
_OFF_WALL = 1.0
#: Loose atoms further than this from every wall belong to no tube, Å.
_LOOSE_REACH = 4.0

# lattice step of each bond label k (direction alpha_0 + k 60 deg) in thirds of (a1, a2),
# a1 at alpha_0 - 30 deg, a2 at alpha_0 + 30 deg: the A->B bonds are
# delta_0 = (a1 + a2)/3, delta_1 = (a2 - 2 a1)/3, delta_2 = (a1 - 2 a2)/3, B->A their negatives
_STEP3 = np.array([[1, 1], [-1, 2], [-2, 1], [-1, -1], [1, -2], [2, -1]], dtype=float)


@dataclasses.dataclass
class Tube:
    """One registered tube.

    Attributes
    ----------
    atoms : (K,) int
        Indices into the structure (its wall atoms, then loose atoms given to it).
    chirality : (int, int)
        (n, m) in :func:`ase.build.nanotube`'s handedness.
    periodic : bool
        Periodic along its axis.
    length : float
        Period (periodic) or axial extent, Å.
    axis, e1, e2 : (3,) float
        Unit frame: axis e_z, azimuth 0 along e1, 90 deg along e2.
    centre : (3,) float
        A point of the axis, Å.
    radius, bond : float
        Fitted R and mean bond a_cc, Å.
    phi, z, r : (K,) float
        Azimuth (rad, [0, 2 pi)), axial coordinate (Å from the origin's projection on the
        axis, continuous along the tube, so on a periodic tube take it mod L) and radial
        distance (Å).
    votes : dict
        Chirality -> number of circuits that gave it.
    psi6 : float
        |Psi_6| of the bond angles (1 for a perfect wall).
    lattice : LatticeMap
    """

    atoms: np.ndarray
    chirality: tuple
    periodic: bool
    length: float
    axis: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    centre: np.ndarray
    radius: float
    bond: float
    phi: np.ndarray
    z: np.ndarray
    r: np.ndarray
    votes: dict
    psi6: float
    lattice: LatticeMap

    def cartesian(self, phi, z, r=None) -> np.ndarray:
        """Points (..., 3) Å at azimuth ``phi`` (rad), axial ``z`` (Å), radius ``r``."""
        phi, z = np.asarray(phi, float), np.asarray(z, float)
        r = self.radius if r is None else np.asarray(r, float)
        rad = np.cos(phi)[..., None] * self.e1 + np.sin(phi)[..., None] * self.e2
        return self.centre + (r[..., None] if np.ndim(r) else r) * rad + z[..., None] * self.axis

    def quality(self) -> dict:
        """Registration quality: lattice fit, |Psi_6|, and the share of circuits agreeing."""
        q = self.lattice.quality()
        total = sum(self.votes.values())
        q.update(psi6=self.psi6, circuits=total,
                 circuit_agreement=(max(self.votes.values()) / total) if total else 0.0)
        return q


@dataclasses.dataclass
class Structure:
    """The registered structure: positions, bond graph and tubes."""

    positions: np.ndarray
    graph: BondGraph
    tubes: list
    tube_of_atom: np.ndarray  # (N,) tube index of each atom


def _fail(msg):
    raise ValueError(msg)


def _check_atoms(atoms):
    if not isinstance(atoms, Atoms):
        _fail(f"structure is a {type(atoms).__name__}; valid: an ase.Atoms of carbon tubes")
    if len(atoms) == 0:
        _fail("structure has no atoms; valid: an ase.Atoms holding at least one carbon tube")
    numbers = np.unique(atoms.numbers)
    if (numbers != 6).any():
        bad = sorted(set(atoms.get_chemical_symbols()) - {"C"})
        _fail(f"structure holds element(s) {', '.join(bad)}; valid: carbon (C) only")


def _period(graph, X, piece):
    """The shortest cell vector along which the piece repeats into itself, or None."""
    src = graph.sources
    e = np.flatnonzero(piece[src])
    mis = X[src[e]] + graph.d_ec[e] - X[graph.indices[e]]
    big = np.linalg.norm(mis, axis=1) > 0.5
    if not big.any():
        return None
    vecs = mis[big]
    P = vecs[np.argmin(np.linalg.norm(vecs, axis=1))]
    off = np.linalg.norm(np.cross(vecs, P), axis=1) / np.linalg.norm(P)
    if (off > 0.5).any():
        _fail(f"a piece of {int(piece.sum())} atoms repeats itself in two periodic directions "
              "(a sheet, not a tube); valid: tubes periodic along their axis only")
    return P


def _normals(graph, X, members):
    """Unit normals of the planes through the neighbours of each 3-fold atom."""
    three = members[graph.coordination[members] == 3]
    e0 = graph.indptr[three]
    nb = np.stack([X[three] + graph.d_ec[e0 + k] for k in range(3)], axis=1)
    nrm = np.cross(nb[:, 1] - nb[:, 0], nb[:, 2] - nb[:, 0])
    return nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def _axis(graph, X, members, P):
    n = _normals(graph, X, members)
    if len(n) < 3:
        _fail(f"a piece of {len(members)} atoms has fewer than three 3-fold atoms; valid: a "
              "tube wall (atoms with three bonds)")
    w, v = np.linalg.eigh(n.T @ n)
    if w[1] < 0.2 * w[2]:
        _fail(f"a piece of {len(members)} atoms is flat (bond-plane normals all parallel), "
              "no nanotube; valid: a closed cylindrical wall")
    axis = v[:, 0] if P is None else P / np.linalg.norm(P)
    if P is not None and np.sqrt(np.mean((n @ axis) ** 2)) > 0.3:
        _fail(f"a piece of {len(members)} atoms is periodic along {np.round(P, 3).tolist()} "
              "but its wall is not parallel to it; valid: tubes periodic along their axis")
    return axis if axis[np.argmax(np.abs(axis))] > 0 else -axis


def _frame(axis):
    ref = np.eye(3)[0] if abs(axis[0]) < 0.9 else np.eye(3)[1]
    e1 = ref - np.dot(ref, axis) * axis
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _circle(xy):
    """Kasa circle fit, refitted without points more than _OFF_WALL from the first fit."""
    keep = np.ones(len(xy), dtype=bool)
    for _ in range(2):
        p = xy[keep]
        A = np.column_stack([2 * p[:, 0], 2 * p[:, 1], np.ones(len(p))])
        (a, b, c), *_ = np.linalg.lstsq(A, (p ** 2).sum(axis=1), rcond=None)
        R = math.sqrt(max(c + a * a + b * b, 0.0))
        keep = np.abs(np.hypot(xy[:, 0] - a, xy[:, 1] - b) - R) < _OFF_WALL
    return np.array([a, b]), R


def _geometry(X, members, axis):
    e1, e2 = _frame(axis)
    xy = np.stack([X[members] @ e1, X[members] @ e2], axis=1)
    c2, R = _circle(xy)
    d = xy - c2
    r = np.hypot(d[:, 0], d[:, 1])
    off = np.abs(r - R) > _OFF_WALL
    if R < 1.0 or off.mean() > 0.05:
        _fail(f"a piece of {len(members)} atoms is not one cylinder ({100 * off.mean():.0f} % "
              f"of its atoms more than {_OFF_WALL} Å off the fitted radius {R:.2f} Å): tubes "
              "that overlap, or no nanotube; valid: separate tubes, walls over "
              f"{BOND_CUTOFF} Å apart")
    phi = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi)
    centre = c2[0] * e1 + c2[1] * e2
    return e1, e2, centre, R, phi, r


def _labels(alpha, ok):
    """Bond labels k (0..5), |Psi_6| and the mask of bonds within _LABEL_TOLERANCE."""
    psi = np.mean(np.exp(6j * alpha[ok]))
    a0 = np.angle(psi) / 6.0
    x = (alpha - a0) / (np.pi / 3)
    k = np.round(x)
    good = np.abs(x - k) * 60.0 < _LABEL_TOLERANCE
    return np.mod(k, 6).astype(int), float(abs(psi)), good


def _reduce(p, q):
    """Rotate C = p a1 + q a2 by multiples of 60 deg into [0, 60) deg from a1."""
    for _ in range(6):
        if p > 0 and q >= 0:
            return int(p), int(q)
        p, q = -q, p + q
    return None


def _votes(graph, order, parent_edge, X, step_e, P, axis):
    """Chiral vectors (internal (p, q)) of the winding fundamental cycles, counted.

    ``step_e`` (E, 4) per edge: azimuth step (rad), lattice step in thirds (2), and 1 for a
    bond too far off every lattice direction (its cycles do not vote)."""
    acc = tree_accumulate(graph, order, parent_edge, step_e, np.zeros(4))
    src, dst = graph.sources, graph.indices
    inside = ~np.isnan(acc[src, 0]) & ~np.isnan(acc[dst, 0])
    nt = np.flatnonzero(inside & (parent_edge[dst] != np.arange(len(dst))) & (src < dst))
    s, d = src[nt], dst[nt]
    cyc = acc[s] + step_e[nt] - acc[d]
    wind = cyc[:, 0] / (2 * np.pi)
    B = cyc[:, 1:3]
    through = np.zeros(len(nt), dtype=bool)
    if P is not None:
        through = np.abs((X[s] + graph.d_ec[nt] - X[d]) @ axis) > 0.5
    use = (np.abs(np.abs(wind) - 1) < 0.25) & ~through & (acc[s, 3] + step_e[nt, 3]
                                                          + acc[d, 3] == 0) \
        & np.all(np.abs(B / 3 - np.round(B / 3)) < 1e-6, axis=1)
    C = np.round(B[use] / 3).astype(int) * np.sign(np.round(wind[use])).astype(int)[:, None]
    votes = {}
    for p, q in C:
        key = _reduce(p, q)
        if key is not None:
            votes[key] = votes.get(key, 0) + 1
    return votes


def _to_ase(pq):
    """Internal (p, q) (a1 -> a2 counter-clockwise) in ASE's handedness: (q, p); a zigzag
    tube is its own mirror image and keeps (p, 0)."""
    p, q = pq
    return (p, 0) if q == 0 else (q, p)


def _from_ase(nm):
    n, m = int(nm[0]), int(nm[1])
    return (n + m, 0) if n == 0 or m == 0 else (m, n)


def _choose(votes, hint, size):
    """Majority chirality (internal (p, q)); the hint decides only where the circuits give
    no majority, and is refused where they contradict it."""
    total = sum(votes.values())
    best = max(votes, key=votes.get) if total else None
    if hint is not None:
        want = _from_ase(hint)
        if best is not None and votes[best] > total / 2 and want != best:
            n, m = _to_ase(best)
            _fail(f"chirality hint {tuple(hint)} disagrees with the ({n},{m}) registered from "
                  f"{votes[best]} of {total} lattice circuits; valid: the tube's own "
                  "chirality, or no hint")
        return want
    if best is None:
        _fail(f"a piece of {size} atoms has no lattice circuit winding round it, no "
              "nanotube; valid: a closed honeycomb cylinder")
    return best


def _check_hint(chirality, ntubes):
    if chirality is None:
        return [None] * ntubes
    single = len(chirality) == 2 and all(isinstance(v, (int, np.integer)) for v in chirality)
    hints = [chirality] * ntubes if single else list(chirality)
    if len(hints) != ntubes or not all(
            len(h) == 2 and all(isinstance(v, (int, np.integer)) and v >= 0 for v in h)
            and h[0] + h[1] > 0 for h in hints):
        _fail(f"chirality hint {chirality!r}; valid: (n, m) integers >= 0 for every tube, or "
              f"a list of {ntubes} of them")
    return hints


def _wall(graph, pos, piece):
    """Unwrapped positions, period, tree and frame of one piece."""
    members = np.flatnonzero(piece)
    coord = graph.coordination[members]
    root = int(members[np.argmax(coord == 3)])
    order, parent_edge = bfs_tree(graph, root, piece)
    X = tree_accumulate(graph, order, parent_edge, graph.d_ec, pos[root])
    P = _period(graph, X, piece)
    axis = _axis(graph, X, members, P)
    extent = float(np.linalg.norm(P)) if P is not None else float(np.ptp(X[members] @ axis))
    if extent < 2 * graph.cutoff:
        _fail(f"a tube of {len(members)} atoms is {extent:.2f} Å long; valid: at least two "
              f"bond cutoffs ({2 * graph.cutoff:.2f} Å)")
    return members, order, parent_edge, X, P, axis


def _steps(graph, piece, phi_n, R, axis):
    """Per-edge (E, 4) circuit steps of the piece (zeros elsewhere), |Psi_6| and the mean
    bond unrolled onto the sheet, sqrt((R dphi)^2 + dz^2), Å (the chord is shorter)."""
    e = np.flatnonzero(piece[graph.sources])
    src, dst = graph.sources[e], graph.indices[e]
    dphi = phi_n[dst] - phi_n[src]
    dphi = (dphi + np.pi) % (2 * np.pi) - np.pi
    dz = graph.d_ec[e] @ axis
    alpha = np.arctan2(dz, R * dphi)
    three = graph.coordination == 3
    labels, psi6, good = _labels(alpha, three[src] & three[dst])
    step = np.zeros((len(graph.indices), 4))
    step[e, 0] = dphi
    step[e, 1:3] = _STEP3[labels]
    step[e, 3] = ~good
    return step, psi6, float(np.mean(np.hypot(R * dphi, dz)))


def _tube(graph, pos, piece, hint, loose, wall, geometry):
    members, order, parent_edge, X, P, axis = wall
    e1, e2, centre, R, phi, r = geometry
    phi_n = np.zeros(graph.n_atoms)
    phi_n[members] = phi
    step, psi6, bond = _steps(graph, piece, phi_n, R, axis)
    votes = _votes(graph, order, parent_edge, X, step, P, axis)
    pq = _choose(votes, hint, len(members))
    z = X[members] @ axis
    if len(loose):
        members, z, phi, r = _add_loose(members, z, phi, r, pos[loose], loose, centre, axis,
                                        e1, e2, P)
    L = float(np.linalg.norm(P)) if P is not None else float(np.ptp(z))
    seed = int(np.argmin(np.abs(z - np.median(z)) + 100.0 * (graph.coordination[members] != 3)))
    lat = fit_lattice(pq[0], pq[1], bond, R, R * phi, z, r,
                      period=L if P is not None else None, seed=seed)
    return Tube(members, _to_ase(pq), P is not None, L, axis, e1, e2, centre, R, bond, phi, z,
                r, {_to_ase(k): v for k, v in votes.items()}, psi6, lat)


def _add_loose(members, z, phi, r, lpos, loose, centre, axis, e1, e2, P):
    """Loose atoms in the tube's frame (axial coordinate moved next to the tube's)."""
    d = lpos - centre
    lz = d @ axis
    if P is not None:
        L = np.linalg.norm(P)
        lz = lz - L * np.floor((lz - z.min()) / L)
    x, y = d @ e1, d @ e2
    return (np.concatenate([members, loose]), np.concatenate([z, lz]),
            np.concatenate([phi, np.mod(np.arctan2(y, x), 2 * np.pi)]),
            np.concatenate([r, np.hypot(x, y)]))


def _loose_owner(pos, loose, walls):
    """Tube index of each loose atom: the nearest wall, within _LOOSE_REACH Å."""
    owner = np.empty(len(loose), dtype=int)
    for k, i in enumerate(loose):
        gap = []
        for axis, centre, R in walls:
            d = pos[i] - centre
            gap.append(abs(np.linalg.norm(d - np.dot(d, axis) * axis) - R))
        owner[k] = int(np.argmin(gap))
        if gap[owner[k]] > _LOOSE_REACH:
            _fail(f"atom {int(i)} is {gap[owner[k]]:.2f} Å from the nearest tube wall; valid: "
                  f"loose atoms within {_LOOSE_REACH} Å of a wall")
    return owner


def register(atoms, chirality=None, cutoff: float = BOND_CUTOFF) -> Structure:
    """Find the tubes of a carbon structure and register each one's lattice.

    Parameters
    ----------
    atoms : ase.Atoms
        One tube or several (bundles, multi-wall), periodic along the axis or finite, any
        cell (zero-length vectors allowed where not periodic).
    chirality : (n, m) or list of (n, m), optional
        A hint (for all tubes, or one per tube in the order of their lowest atom index);
        used only where the lattice circuits give no majority, refused where one
        contradicts it.
    cutoff : float
        Bond cutoff, Å.

    Returns
    -------
    Structure

    Raises
    ------
    ValueError
        One line: not an ase.Atoms, an element other than carbon, no nanotube, tubes
        that overlap, a periodic length below two cutoffs, a hint that contradicts the
        atoms.
    """
    _check_atoms(atoms)
    if not (isinstance(cutoff, (int, float)) and 1.6 <= cutoff <= 2.2):
        _fail(f"bond cutoff={cutoff!r} Å; valid: 1.6 to 2.2 Å (between the first and second "
              "neighbour shells)")
    pos = atoms.get_positions()
    graph = bond_graph(pos, atoms.cell[:], atoms.pbc, cutoff)
    count, label = components(graph)
    sizes = np.bincount(label, minlength=count)
    walls = [k for k in range(count) if sizes[k] >= MIN_TUBE_ATOMS]
    if not walls:
        _fail(f"no nanotube: the largest bonded piece has {sizes.max()} atoms; valid: a "
              f"structure with a tube of at least {MIN_TUBE_ATOMS} bonded atoms")
    loose = np.flatnonzero(np.isin(label, walls, invert=True))
    hints = _check_hint(chirality, len(walls))
    wall = [_wall(graph, pos, label == k) for k in walls]
    geometry = [_geometry(w[3], w[0], w[5]) for w in wall]
    owner = _loose_owner(pos, loose, [(w[5], g[2], g[3]) for w, g in zip(wall, geometry)])
    tubes = [_tube(graph, pos, label == k, hints[t], loose[owner == t], wall[t], geometry[t])
             for t, k in enumerate(walls)]
    tube_of = np.full(len(atoms), -1)
    for t, tube in enumerate(tubes):
        tube_of[tube.atoms] = t
    return Structure(pos, graph, tubes, tube_of)
