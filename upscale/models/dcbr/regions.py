"""Atomistic regions: the atoms the coarse model keeps, around every defect and where asked.

The atomistic region of a tube is every atom of it within ``r_atomistic`` Å of a defect's
core (its defective atoms and empty sites, :mod:`.defects`), plus any atoms a user
selects. Distances are straight lines in the tube's frame with its axis coordinate periodic
on a periodic tube, so a region crosses the periodic boundary whole. Region atoms closer
than ``1.3 a_cc`` (bonded, with room for strain; loose atoms of an adatom included) are one
region: regions merge where they meet. A region never spans two tubes (each tube is its own
body; the tubes of a bundle meet only through their van der Waals forces).
"""
from __future__ import annotations

import dataclasses
import numbers

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from upscale.models.dcbr.defects import frame_tree

__all__ = ["Region", "Regions", "atomistic_regions", "selected_atoms"]

#: Region atoms closer than this many bond lengths belong to one region.
_JOIN_BONDS = 1.3


@dataclasses.dataclass(frozen=True)
class Region:
    """One connected atomistic region.

    Attributes
    ----------
    tube : int
    atoms : (k,) int
        Indices into the structure.
    defects : tuple of int
        Indices into the defect list of the defects whose core lies in it.
    selected : bool
        It holds atoms the user selected.
    """

    tube: int
    atoms: np.ndarray
    defects: tuple
    selected: bool


@dataclasses.dataclass(frozen=True)
class Regions:
    """All regions: ``label`` (N,) region index per atom, -1 for coarse atoms."""

    label: np.ndarray
    regions: list

    @property
    def mask(self) -> np.ndarray:
        """Atoms in an atomistic region, (N,) bool."""
        return self.label >= 0


def selected_atoms(select, positions) -> np.ndarray:
    """Boolean mask (N,) of a user selection.

    ``select`` is a callable ``f(positions (N, 3) Å) -> bool mask (N,) or indices``, a bool
    mask (N,), or an index array. Selecting nothing is an error.
    """
    n = len(positions)
    what = select(np.array(positions, copy=True)) if callable(select) else select
    arr = np.asarray(what)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise ValueError(f"region selector gave a mask of shape {arr.shape}; valid: a "
                             f"bool mask of shape ({n},) or atom indices")
        mask = arr
    elif arr.size == 0 or np.issubdtype(arr.dtype, np.integer):
        idx = arr.astype(np.int64).ravel()
        if idx.size and (idx.min() < -n or idx.max() >= n):
            raise ValueError(f"region selector index {int(idx.max() if idx.max() >= n else idx.min())}"
                             f" is out of range; valid: atom indices -{n}..{n - 1}")
        mask = np.zeros(n, dtype=bool)
        mask[idx] = True
    else:
        raise ValueError(f"region selector gave {arr.dtype} values; valid: a bool mask of "
                         f"shape ({n},) or integer atom indices")
    if not mask.any():
        raise ValueError("region selector selects no atom; valid: a selection of at least "
                         "one atom (or no selector)")
    return mask


def _check_radius(r):
    if isinstance(r, bool) or not isinstance(r, numbers.Real) or not np.isfinite(r) or r < 0:
        raise ValueError(f"r_atomistic={r!r}; valid: a finite distance >= 0 Å")
    return float(r)


def _core(tube, defects):
    """(phi, z, r, defect index) of every core point of the tube's defects."""
    loc = {int(a): k for k, a in enumerate(tube.atoms)}
    phi, z, r, owner = [], [], [], []
    for k, d in defects:
        rows = [loc[int(a)] for a in d.atoms]
        uv = tube.lattice.site_uv(d.sites)
        phi += list(tube.phi[rows]) + list(uv[:, 0] / tube.radius)
        z += list(tube.z[rows]) + list(uv[:, 1])
        r += list(tube.r[rows]) + [tube.radius] * len(d.sites)
        owner += [k] * (len(rows) + len(d.sites))
    return np.array(phi), np.array(z), np.array(r), np.array(owner, dtype=int)


def _tube_regions(tube, t, defects, r_a, chosen):
    """Region atoms of one tube (local indices), grouped, with their defects."""
    tree, pts = frame_tree(tube, tube.phi, tube.z, tube.r)
    inside = chosen[tube.atoms].copy()
    hits = {}
    if defects:
        cphi, cz, cr, owner = _core(tube, defects)
        ctree, cpts = frame_tree(tube, cphi, cz, cr)
        for k, near in enumerate(ctree.query_ball_tree(tree, r_a)):
            inside[near] = True
            hits[k] = near
    rows = np.flatnonzero(inside)
    if len(rows) == 0:
        return []
    sub = frame_tree(tube, tube.phi[rows], tube.z[rows], tube.r[rows])[0]
    pairs = sub.query_pairs(_JOIN_BONDS * tube.bond, output_type="ndarray")
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                     shape=(len(rows), len(rows)))
    lab = connected_components(adj, directed=False)[1]
    where = np.full(len(tube.atoms), -1)
    where[rows] = lab
    out = []
    for c in range(lab.max() + 1):
        atoms = tube.atoms[rows[lab == c]]
        mine = sorted({owner[k] for k, near in hits.items() if near and where[near[0]] == c})
        out.append(Region(t, np.sort(atoms), tuple(int(i) for i in mine),
                          bool(chosen[atoms].any())))
    return out


def atomistic_regions(structure, defects, r_atomistic: float, select=None) -> Regions:
    """The atomistic regions of a registered structure.

    Parameters
    ----------
    structure : Structure
    defects : list of Defect
        From :func:`~upscale.models.dcbr.defects.find_defects`.
    r_atomistic : float
        Radius about each defect core kept atomistic, Å (0: the core atoms only).
    select : callable, bool mask or index array, optional
        Atoms to keep atomistic besides (see :func:`selected_atoms`).

    Returns
    -------
    Regions
    """
    r_a = _check_radius(r_atomistic)
    n = len(structure.positions)
    chosen = np.zeros(n, dtype=bool) if select is None \
        else selected_atoms(select, structure.positions)
    regions = []
    for t, tube in enumerate(structure.tubes):
        mine = [(k, d) for k, d in enumerate(defects) if d.tube == t]
        regions += _tube_regions(tube, t, mine, r_a, chosen)
    label = np.full(n, -1)
    for k, reg in enumerate(regions):
        label[reg.atoms] = k
    return Regions(label, regions)
