"""Point defects in single-wall nanotubes, placed by axial fraction and azimuth.

A defect is asked for at a point of the wall given by ``(zfrac, angle_deg)``:

* ``zfrac`` in [0, 1]: axial position as a fraction of the tube length
  (``atoms.info["length"]``), measured from the lowest z of the tube;
* ``angle_deg``: azimuth about the tube axis ``atoms.info["axis_xy"]`` in degrees, 0 = +x,
  counter-clockwise seen from +z; any real number (taken mod 360).

The point is ``(x_c + R cos a, y_c + R sin a, z_0 + zfrac L)`` with ``R = info["radius"]``;
the builder acts on the atom (or bond) nearest it. ``(0.5, 0)`` is the point of
:func:`upscale.build.vacancy`'s default (seed 004 sec. 5.3.1). Distances are minimum-image
along every periodic direction of the (orthorhombic) cell, so a defect at ``zfrac`` 0 or 1
straddles the periodic boundary of a :func:`upscale.build.swcnt` tube. In a bundle
(``arrays["mol-id"]``) only the central tube (mol-id 1) is a candidate.

Every builder returns a NEW :class:`ase.Atoms` (the input is untouched), keeps ``info`` and
appends a record to ``info["defects"]``::

    {"kind", "zfrac", "angle_deg" (wrapped to [0, 360)), "target" (the point, Å),
     "at" (defect centre, Å), "atoms" (indices into the output)}

For vacancies ``"atoms"`` lists the under-coordinated neighbours left behind and
``"removed_positions"`` (Å) the deleted atoms; earlier records' ``"atoms"`` are re-indexed
when atoms are deleted. Bonds are C–C distances below :data:`BOND_CUTOFF` = 1.8 Å (between
the first, 1.42 Å, and second, 2.46 Å, neighbour shells of graphene). The structures are
not relaxed.

:func:`parse_defects` / :func:`apply_defects` read the command-line form
``KIND@ZFRAC@ANGLE[,KIND@ZFRAC@ANGLE...]`` with the kinds of :data:`DEFECT_KINDS`.
"""
from __future__ import annotations

import copy
import math
import numbers

import numpy as np
from ase import Atoms

__all__ = ["monovacancy", "divacancy", "vacancy4", "stone_wales", "adatom", "parse_defects",
           "apply_defects", "DEFECT_KINDS", "BOND_CUTOFF", "ADATOM_HEIGHT"]

#: Neighbour (bond) cutoff for C–C, Å.
BOND_CUTOFF = 1.8
#: Height of a bridge adatom above the midpoint of its bond, along the wall normal, Å.
ADATOM_HEIGHT = 1.5

_SPEC_FORM = "KIND@ZFRAC@ANGLE (e.g. 'v1@0.5@0', items separated by commas)"


# ---------------------------------------------------------------- geometry helpers
class _Tube:
    """Axis, radius, length, lowest z and candidate atoms of a tube (validated)."""

    def __init__(self, atoms):
        if not isinstance(atoms, Atoms):
            raise ValueError(f"defect builders take an ase.Atoms tube, got {type(atoms).__name__}; "
                             "valid: a tube from upscale.build.swcnt")
        if "axis_xy" not in atoms.info:
            raise ValueError("structure has no atoms.info['axis_xy'] (tube axis); valid: a tube "
                             "from upscale.build.swcnt or atoms.info['axis_xy'] = (x, y) in Å")
        cell = np.asarray(atoms.cell[:], dtype=float)
        if np.any(atoms.pbc) and not np.allclose(cell, np.diag(np.diag(cell))):
            raise ValueError("defect builders need an orthorhombic cell along periodic "
                             f"directions, got cell {cell.tolist()}; valid: a tube from "
                             "upscale.build.swcnt")
        self.atoms = atoms
        self.xc, self.yc = (float(v) for v in atoms.info["axis_xy"])
        pos = atoms.positions
        cand = np.ones(len(atoms), dtype=bool)
        if "mol-id" in atoms.arrays:
            cand = atoms.arrays["mol-id"] == 1
        if not cand.any():
            raise ValueError("structure has no atom of the central tube (mol-id 1)")
        self.candidates = np.flatnonzero(cand)
        self.periods = np.array([cell[k, k] if atoms.pbc[k] and cell[k, k] > 0 else 0.0
                                 for k in range(3)])
        r = np.hypot(pos[cand, 0] - self.xc, pos[cand, 1] - self.yc)
        self.radius = float(atoms.info.get("radius", np.median(r)))
        z = pos[cand, 2]
        self.z0 = float(z.min())
        if "length" in atoms.info:
            self.length = float(atoms.info["length"])
        elif self.periods[2] > 0:
            self.length = float(self.periods[2])
        else:
            self.length = float(np.ptp(z))

    def mic(self, d):
        """Minimum-image copy of displacement(s) ``d`` (..., 3), Å."""
        d = np.array(d, dtype=float)
        for k in range(3):
            if self.periods[k] > 0:
                d[..., k] -= self.periods[k] * np.round(d[..., k] / self.periods[k])
        return d

    def wrap(self, p):
        """Point ``p`` with its periodic coordinates moved into the cell, Å."""
        p = np.array(p, dtype=float)
        for k in range(3):
            if self.periods[k] > 0:
                p[..., k] = np.mod(p[..., k], self.periods[k])
                p[..., k] = np.where(p[..., k] >= self.periods[k], 0.0, p[..., k])
        return p

    def target(self, zfrac, angle_deg):
        a = math.radians(angle_deg)
        return np.array([self.xc + self.radius * math.cos(a), self.yc + self.radius * math.sin(a),
                         self.z0 + zfrac * self.length])

    def nearest(self, point, k=1):
        """Indices of the ``k`` candidate atoms nearest ``point`` (stable order)."""
        r = np.linalg.norm(self.mic(self.atoms.positions[self.candidates] - point), axis=1)
        return self.candidates[np.argsort(r, kind="stable")[:k]]

    def neighbours(self, i, positions=None):
        """Atoms within :data:`BOND_CUTOFF` of atom ``i`` (sorted indices)."""
        pos = self.atoms.positions if positions is None else positions
        r = np.linalg.norm(self.mic(pos - pos[i]), axis=1)
        r[i] = np.inf
        return np.flatnonzero(r < BOND_CUTOFF)

    def normal(self, p):
        """Outward unit wall normal (radial, perpendicular to the axis) at point ``p``."""
        n = np.array([p[0] - self.xc, p[1] - self.yc, 0.0])
        return n / np.linalg.norm(n)


def _check_place(zfrac, angle_deg):
    if isinstance(zfrac, bool) or not isinstance(zfrac, numbers.Real):
        raise ValueError(f"defect zfrac={zfrac!r} is not a number; valid: 0 <= zfrac <= 1 "
                         "(fraction of the tube length)")
    if not (0.0 <= float(zfrac) <= 1.0):
        raise ValueError(f"defect zfrac={zfrac!r} is outside [0, 1]; valid: 0 <= zfrac <= 1 "
                         "(fraction of the tube length)")
    if isinstance(angle_deg, bool) or not isinstance(angle_deg, numbers.Real) \
            or not math.isfinite(angle_deg):
        raise ValueError(f"defect angle_deg={angle_deg!r} is not a finite number; valid: any "
                         "real number of degrees (taken mod 360)")
    return float(zfrac), float(angle_deg) % 360.0


def _unwrapped(tube, i, j):
    """Positions of atoms ``i`` and ``j`` with ``j`` the minimum image next to ``i``."""
    pi = tube.atoms.positions[i]
    return pi, pi + tube.mic(tube.atoms.positions[j] - pi)


def _pick_bond(tube, i, point, prefer):
    """Neighbour ``j`` of atom ``i`` whose bond is most nearly ``prefer`` ("axial" or
    "circumferential"): largest / smallest |cos| of the bond's angle to the axis (rounded to
    1e-6); ties go to the bond whose midpoint is nearest ``point``, then the lower index."""
    nb = tube.neighbours(i)
    if len(nb) == 0:
        raise ValueError(f"atom {i} nearest the defect point has no neighbour within "
                         f"{BOND_CUTOFF} Å; valid: a tube with an intact wall there")
    keys = []
    for j in nb:
        pi, pj = _unwrapped(tube, i, j)
        d = pj - pi
        c = round(abs(d[2]) / np.linalg.norm(d), 6)
        dist = np.linalg.norm(tube.mic(0.5 * (pi + pj) - point))
        keys.append((-c if prefer == "axial" else c, round(dist, 9), int(j)))
    return min(keys)[2]


def _new_record(kind, zfrac, angle, point, tube, at, atoms_idx, **extra):
    rec = {"kind": kind, "zfrac": zfrac, "angle_deg": angle,
           "target": tube.wrap(point).tolist(), "at": tube.wrap(at).tolist(),
           "atoms": [int(k) for k in atoms_idx]}
    rec.update(extra)
    return rec


def _finish(out, src, rec, removed=()):
    """Give ``out`` a deep copy of ``src.info`` with earlier records re-indexed for the
    ``removed`` (input) indices, plus ``rec``."""
    info = copy.deepcopy(src.info)
    removed = np.sort(np.asarray(removed, dtype=int))
    defects = list(info.get("defects", []))
    if len(removed):
        for old in defects:
            if "atoms" in old:
                idx = np.asarray(old["atoms"], dtype=int)
                keep = idx[~np.isin(idx, removed)]
                old["atoms"] = (keep - np.searchsorted(removed, keep)).tolist()
    defects.append(rec)
    info["defects"] = defects
    out.info = info
    return out


def _remove(tube, removed, kind, zfrac, angle, point):
    """Delete ``removed`` (input indices); record the left-behind neighbours."""
    atoms = tube.atoms
    removed = np.unique(np.asarray(removed, dtype=int))
    border = set()
    for i in removed:
        border.update(int(j) for j in tube.neighbours(i))
    border = np.array(sorted(border - set(removed.tolist())), dtype=int)
    first = atoms.positions[removed[0]]
    rpos = first + tube.mic(atoms.positions[removed] - first)
    out = atoms.copy()
    del out[removed]
    new_border = border - np.searchsorted(removed, border)
    rec = _new_record(kind, zfrac, angle, point, tube, rpos.mean(axis=0), new_border,
                      removed_positions=tube.wrap(rpos).tolist())
    return _finish(out, atoms, rec, removed), rec, removed


# ---------------------------------------------------------------- builders
def _monovacancy(atoms, zfrac, angle_deg):
    zfrac, angle = _check_place(zfrac, angle_deg)
    tube = _Tube(atoms)
    point = tube.target(zfrac, angle)
    return _remove(tube, tube.nearest(point), "v1", zfrac, angle, point)


def monovacancy(atoms: Atoms, zfrac: float = 0.5, angle_deg: float = 0.0) -> Atoms:
    """Single vacancy: remove the atom nearest the point ``(zfrac, angle_deg)``.

    Parameters
    ----------
    atoms : ase.Atoms
        A tube from :func:`upscale.build.swcnt` (needs ``info["axis_xy"]``).
    zfrac : float
        Axial position, fraction 0..1 of the tube length from its lowest z.
    angle_deg : float
        Azimuth about the axis, degrees (0 = +x; mod 360).

    Returns
    -------
    ase.Atoms
        One atom fewer (unrelaxed: the three neighbours stay two-fold); record kind ``"v1"``.
    """
    return _monovacancy(atoms, zfrac, angle_deg)[0]


def _divacancy(atoms, zfrac, angle_deg):
    zfrac, angle = _check_place(zfrac, angle_deg)
    tube = _Tube(atoms)
    point = tube.target(zfrac, angle)
    i = int(tube.nearest(point)[0])
    j = _pick_bond(tube, i, point, "axial")
    return _remove(tube, [i, j], "v2", zfrac, angle, point)


def divacancy(atoms: Atoms, zfrac: float = 0.5, angle_deg: float = 0.0) -> Atoms:
    """Divacancy: remove the atom nearest the point and one bonded neighbour.

    The neighbour is the one whose bond is most nearly axial (largest |cos| of the angle
    between bond and tube axis; ties, e.g. the two inclined bonds of an (n, n) tube, go to the
    bond whose midpoint is nearest the point). Unrelaxed: the V2 (5-8-5) reconstruction of
    e.g. Krasheninnikov et al., Chem. Phys. Lett. 418, 132 (2006) is left to the relaxation.

    Parameters
    ----------
    atoms, zfrac, angle_deg
        As in :func:`monovacancy` (zfrac 0..1 of the length, azimuth in degrees).

    Returns
    -------
    ase.Atoms
        Two atoms fewer, four two-fold neighbours; record kind ``"v2"``.
    """
    return _divacancy(atoms, zfrac, angle_deg)[0]


def _vacancy4(atoms, zfrac, angle_deg):
    from upscale.build import vacancy  # here, not at the top: upscale.build re-exports us

    zfrac, angle = _check_place(zfrac, angle_deg)
    tube = _Tube(atoms)
    point = tube.target(zfrac, angle)
    removed = np.asarray(vacancy(atoms, n=4, at=point).info["vacancy"]["removed"], dtype=int)
    return _remove(tube, removed, "v4", zfrac, angle, point)


def vacancy4(atoms: Atoms, zfrac: float = 0.5, angle_deg: float = 0.0) -> Atoms:
    """Four-atom vacancy of seed 004 sec. 5.3.1: the four atoms nearest the point removed.

    The atoms are chosen by :func:`upscale.build.vacancy` (``n=4``, ``at`` = the point);
    ``(0.5, 0)`` removes the same atoms as ``vacancy(atoms, n=4)``.

    Parameters
    ----------
    atoms, zfrac, angle_deg
        As in :func:`monovacancy` (zfrac 0..1 of the length, azimuth in degrees).

    Returns
    -------
    ase.Atoms
        Four atoms fewer; record kind ``"v4"``.
    """
    return _vacancy4(atoms, zfrac, angle_deg)[0]


def _stone_wales(atoms, zfrac, angle_deg, orientation="circumferential"):
    if orientation not in ("circumferential", "axial"):
        raise ValueError(f"stone_wales orientation={orientation!r}; valid: 'circumferential' "
                         "or 'axial'")
    zfrac, angle = _check_place(zfrac, angle_deg)
    tube = _Tube(atoms)
    point = tube.target(zfrac, angle)
    i = int(tube.nearest(point)[0])
    j = _pick_bond(tube, i, point, orientation)
    pi, pj = _unwrapped(tube, i, j)
    mid = 0.5 * (pi + pj)
    n = tube.normal(mid)
    radius = 0.5 * sum(np.hypot(p[0] - tube.xc, p[1] - tube.yc) for p in (pi, pj))
    pos = atoms.positions.copy()
    for k, p in ((i, pi), (j, pj)):
        v = p - mid
        q = mid + np.cross(n, v) + n * np.dot(n, v)  # Rodrigues, 90 degrees about n
        rho = np.hypot(q[0] - tube.xc, q[1] - tube.yc)
        q[0] = tube.xc + (q[0] - tube.xc) * radius / rho  # back onto the cylinder
        q[1] = tube.yc + (q[1] - tube.yc) * radius / rho
        pos[k] = tube.wrap(q)
    out = atoms.copy()
    out.positions = pos
    border = sorted((set(tube.neighbours(i, pos)) | set(tube.neighbours(j, pos))) - {i, j})
    rec = _new_record("sw", zfrac, angle, point, tube, mid, [i, j] + [int(b) for b in border],
                      orientation=orientation)
    return _finish(out, atoms, rec), rec, np.array([], dtype=int)


def stone_wales(atoms: Atoms, zfrac: float = 0.5, angle_deg: float = 0.0,
                orientation: str = "circumferential") -> Atoms:
    """Stone–Wales (5-7-7-5) defect: a C–C bond rotated by 90 degrees in the wall.

    The bond is one of the three bonds of the atom nearest the point, by default the most
    nearly circumferential one (smallest |cos| of its angle to the axis; in an (n, n) tube the
    bond perpendicular to the axis, which ends up axial; ties go to the bond whose midpoint is
    nearest the point). Both atoms turn by 90 degrees about the local wall normal (radial)
    through the bond midpoint (Stone & Wales, Chem. Phys. Lett. 128, 501 (1986)) and are then
    moved radially back to their mean original radius. Unrelaxed, each rotated atom is also
    1.9 Å from two next-shell atoms (inside the 2.1 Å cutoff of ``BNC.tersoff``): with that
    potential a (10, 10) defect costs ~31 eV as built and ~5.9 eV after relaxation (Tersoff
    and Brenner values in the literature: ~5-10 eV), so relax before measuring anything.

    Parameters
    ----------
    atoms, zfrac, angle_deg
        As in :func:`monovacancy` (zfrac 0..1 of the length, azimuth in degrees).
    orientation : {"circumferential", "axial"}
        Which bond of the nearest atom to rotate.

    Returns
    -------
    ase.Atoms
        Same atoms; two pentagons and two heptagons replace four hexagons; record kind
        ``"sw"`` with ``"atoms"`` = the two rotated atoms, then their four new neighbours.
    """
    return _stone_wales(atoms, zfrac, angle_deg, orientation)[0]


def _adatom(atoms, zfrac, angle_deg, height=ADATOM_HEIGHT):
    if isinstance(height, bool) or not isinstance(height, numbers.Real) \
            or not 0 < height < 10 or not math.isfinite(height):
        raise ValueError(f"adatom height={height!r}; valid: a positive number of Å below 10")
    zfrac, angle = _check_place(zfrac, angle_deg)
    tube = _Tube(atoms)
    point = tube.target(zfrac, angle)
    best = None
    for i in tube.nearest(point, k=min(12, len(tube.candidates))):
        for j in tube.neighbours(int(i)):
            pi, pj = _unwrapped(tube, int(i), int(j))
            d = np.linalg.norm(tube.mic(0.5 * (pi + pj) - point))
            key = (round(d, 9), min(int(i), int(j)), max(int(i), int(j)))
            best = key if best is None or key < best else best
    if best is None:
        raise ValueError("no C–C bond near the adatom point; valid: a tube with an intact wall")
    i, j = best[1], best[2]
    pi, pj = _unwrapped(tube, i, j)
    mid = 0.5 * (pi + pj)
    q = tube.wrap(mid + height * tube.normal(mid))
    new = atoms[[i]]  # carries every per-atom array (mol-id, tags, ...) of a bridge atom
    new.positions[0] = q
    out = atoms.copy()
    out.extend(new)
    k = len(out) - 1
    rec = _new_record("adatom", zfrac, angle, point, tube, q, [k, i, j], height=float(height))
    return _finish(out, atoms, rec), rec, np.array([], dtype=int)


def adatom(atoms: Atoms, zfrac: float = 0.5, angle_deg: float = 0.0,
           height: float = ADATOM_HEIGHT) -> Atoms:
    """Carbon adatom at the bridge site of the C–C bond whose midpoint is nearest the point.

    The adatom sits ``height`` Å above the bond midpoint along the outward wall normal.
    Default 1.5 Å: on graphene DFT puts the relaxed bridge adatom about 1.9 Å above the
    sheet with ~1.5 Å bonds, its two partners pulled out of the plane (Lehtinen et al.,
    PRL 91, 017202 (2003)); on the unrelaxed wall 1.5 Å gives bonds of
    sqrt(1.5^2 + 0.71^2) = 1.66 Å, bonded within 1.8 Å and inside the Tersoff inner cutoff,
    where 1.9 Å would leave them at 2.0 Å.

    Parameters
    ----------
    atoms, zfrac, angle_deg
        As in :func:`monovacancy` (zfrac 0..1 of the length, azimuth in degrees).
    height : float
        Height above the bond midpoint, Å.

    Returns
    -------
    ase.Atoms
        One atom more (appended last, per-atom arrays copied from a bridge atom); record
        kind ``"adatom"`` with ``"atoms"`` = [adatom, bridge atom, bridge atom].
    """
    return _adatom(atoms, zfrac, angle_deg, height)[0]


#: Defect kind -> builder ``f(atoms, zfrac, angle_deg) -> Atoms`` (iterates as the kinds).
DEFECT_KINDS = {"v1": monovacancy, "v2": divacancy, "v4": vacancy4, "sw": stone_wales,
                "adatom": adatom}
_BUILDERS = {"v1": _monovacancy, "v2": _divacancy, "v4": _vacancy4, "sw": _stone_wales,
             "adatom": _adatom}


# ---------------------------------------------------------------- spec
def _item_text(item):
    if isinstance(item, str):
        return item
    return "@".join(str(v) for v in item) if isinstance(item, (tuple, list)) else repr(item)


def _check_kind(kind, text):
    if kind not in DEFECT_KINDS:
        raise ValueError(f"defect kind {kind!r} in {text!r} is unknown; valid kinds: "
                         f"{', '.join(DEFECT_KINDS)}")


def _parse_item(text):
    parts = text.strip().split("@")
    if len(parts) != 3 or not all(p.strip() for p in parts):
        raise ValueError(f"defect item {text!r} is malformed; valid form: {_SPEC_FORM}")
    kind = parts[0].strip().lower()
    _check_kind(kind, text)
    try:
        zfrac = float(parts[1])
    except ValueError:
        raise ValueError(f"defect zfrac {parts[1].strip()!r} in {text!r} is not a number; "
                         f"valid: 0 <= ZFRAC <= 1 in {_SPEC_FORM}") from None
    if not 0.0 <= zfrac <= 1.0:  # also rejects nan
        raise ValueError(f"defect zfrac {parts[1].strip()!r} in {text!r} is outside [0, 1]; "
                         "valid: 0 <= ZFRAC <= 1 (fraction of the tube length)")
    try:
        angle = float(parts[2])
    except ValueError:
        raise ValueError(f"defect angle {parts[2].strip()!r} in {text!r} is not a number; "
                         f"valid: any real number of degrees in {_SPEC_FORM}") from None
    if not math.isfinite(angle):
        raise ValueError(f"defect angle {parts[2].strip()!r} in {text!r} is not finite; "
                         "valid: any real number of degrees (taken mod 360)")
    return kind, zfrac, angle


def parse_defects(spec: str) -> list[tuple[str, float, float]]:
    """Parse ``"KIND@ZFRAC@ANGLE,KIND@ZFRAC@ANGLE,..."``.

    Parameters
    ----------
    spec : str
        Comma-separated items; KIND one of :data:`DEFECT_KINDS` (case-insensitive), ZFRAC in
        [0, 1] (fraction of the tube length), ANGLE in degrees (any real; wrapped mod 360 by
        the builders). Blank around items is ignored; an empty spec means no defect.

    Returns
    -------
    list of (str, float, float)
        ``(kind, zfrac, angle_deg)`` in the order given.

    Raises
    ------
    ValueError
        One line naming the bad value and what is valid.
    """
    if not isinstance(spec, str):
        raise ValueError(f"defect spec {spec!r} is not a string; valid form: {_SPEC_FORM}")
    if not spec.strip():
        return []
    return [_parse_item(item) for item in spec.split(",")]


def _normalise(spec_or_list):
    if isinstance(spec_or_list, str):
        items = parse_defects(spec_or_list)
        return items, [s.strip() for s in spec_or_list.split(",")] if items else []
    if isinstance(spec_or_list, tuple) and len(spec_or_list) == 3 \
            and isinstance(spec_or_list[0], str) and not isinstance(spec_or_list[1], (tuple, list)):
        spec_or_list = [spec_or_list]
    items, texts = [], []
    for item in spec_or_list:
        text = _item_text(item)
        if isinstance(item, str):
            items.append(_parse_item(item))
        elif isinstance(item, (tuple, list)) and len(item) == 3 and isinstance(item[0], str):
            kind = item[0].strip().lower()
            _check_kind(kind, text)
            _check_place(item[1], item[2])
            items.append((kind, float(item[1]), float(item[2])))
        else:
            raise ValueError(f"defect item {text!r} is malformed; valid: a string {_SPEC_FORM} "
                             "or a tuple (kind, zfrac, angle_deg)")
        texts.append(text.strip())
    return items, texts


def apply_defects(atoms: Atoms, spec_or_list) -> Atoms:
    """Apply defects in order and return the new structure (the input is untouched).

    Parameters
    ----------
    atoms : ase.Atoms
        A tube from :func:`upscale.build.swcnt` (needs ``info["axis_xy"]``).
    spec_or_list : str or sequence
        A spec for :func:`parse_defects` or a list of ``(kind, zfrac, angle_deg)`` / spec
        items (zfrac 0..1 of the tube length, angle in degrees).

    Returns
    -------
    ase.Atoms
        With one ``info["defects"]`` record per item.

    Raises
    ------
    ValueError
        For a bad item (see :func:`parse_defects`), a structure without
        ``info["axis_xy"]``, or two items whose removed or affected atoms (the atoms of
        the records' ``"atoms"`` plus the removed ones) overlap.
    """
    items, texts = _normalise(spec_or_list)
    _Tube(atoms)  # the structure check, even for an empty list
    out = atoms
    ids = np.arange(len(atoms))  # identity of each current atom: original index or new id
    next_id = len(atoms)
    seen = []  # (item number, set of identities)
    for num, ((kind, zfrac, angle), text) in enumerate(zip(items, texts), start=1):
        new, rec, removed = _BUILDERS[kind](out, zfrac, angle)
        mine = set(ids[removed].tolist())
        ids = np.delete(ids, removed)
        added = len(new) - len(ids)
        ids = np.concatenate([ids, np.arange(next_id, next_id + added)])
        next_id += added
        mine |= set(ids[rec["atoms"]].tolist())
        for other, theirs in seen:
            if mine & theirs:
                raise ValueError(
                    f"defect items {other} {texts[other - 1]!r} and {num} {text!r} overlap "
                    f"(input atoms {sorted(mine & theirs)[:6]} removed/affected by both); "
                    "valid: defects far enough apart that their atoms are disjoint")
        seen.append((num, mine))
        out = new
    if out is atoms:
        out = atoms.copy()
        out.info = copy.deepcopy(atoms.info)
    return out
