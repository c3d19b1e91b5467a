"""The bond graph of a carbon structure: neighbours, connected pieces, unwrapped positions.

Two carbon atoms are bonded when they are closer than ``cutoff`` (default
:data:`BOND_CUTOFF` = 1.85 Å): in the gap between the first neighbour shell of a graphitic
wall (a_cc = 1.42-1.46 Å) and the second (sqrt(3) a_cc = 2.46-2.53 Å), and below the
3.4 Å between the walls of a bundle or a multi-wall tube, so the connected pieces of the
graph are the tubes.

Periodic cells of any shape are handled by images: every atom is wrapped into the cell
along its periodic directions and copied across each periodic face it lies within
``cutoff`` of; one k-d tree (:class:`scipy.spatial.cKDTree`) then finds all pairs. This
needs each periodic height of the cell to exceed ``2 cutoff`` (a bond never reaches two
images of one atom). A zero-length or non-periodic cell vector (e.g. the cell
``diag(0, 0, T)`` of :func:`ase.build.nanotube`) is a direction without images.

Arrays (suffixes: ``_e`` per directed edge, ``_n`` per atom): the graph is CSR,
``indptr`` (N+1,), ``indices`` (E,), and ``d_ec`` (E, 3) the bond vector
``x_j - x_i`` of edge i -> j in Å with the image taken into account; every bond is stored in
both directions. ``unwrap`` walks a breadth-first tree of the bonds, so a piece that
crosses a periodic face comes out whole: ``X_child = X_parent + d_e``.
"""
from __future__ import annotations

import dataclasses

import numba as nb
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["BOND_CUTOFF", "BondGraph", "bond_graph", "components", "bfs_tree",
           "tree_accumulate"]

#: C-C bond cutoff, Å: between the first (1.42-1.46 Å) and second (2.46-2.53 Å) shells.
BOND_CUTOFF = 1.85


@dataclasses.dataclass(frozen=True)
class BondGraph:
    """Directed CSR bond graph (each bond in both directions).

    Attributes
    ----------
    indptr : (N+1,) int64
    indices : (E,) int64
        Neighbour j of each edge i -> j.
    d_ec : (E, 3) float64
        Bond vector x_j - x_i, Å (minimum image through the periodic faces).
    cutoff : float
        Bond cutoff, Å.
    """

    indptr: np.ndarray
    indices: np.ndarray
    d_ec: np.ndarray
    cutoff: float

    @property
    def n_atoms(self) -> int:
        return len(self.indptr) - 1

    @property
    def coordination(self) -> np.ndarray:
        """Number of bonds of each atom, (N,) int."""
        return np.diff(self.indptr)

    @property
    def sources(self) -> np.ndarray:
        """Atom i of each edge i -> j, (E,) int64."""
        return np.repeat(np.arange(self.n_atoms), self.coordination)


def _periodic_cell(cell, pbc):
    """Completed cell (3, 3) and the periodic directions (bool (3,)); zero vectors have no
    images whatever ``pbc`` says."""
    cell = np.asarray(cell, dtype=float)
    lengths = np.linalg.norm(cell, axis=1)
    periodic = np.asarray(pbc, dtype=bool) & (lengths > 1e-9)
    full = cell.copy()
    for k in range(3):
        if not periodic[k]:
            full[k] = 0.0
    # fill the missing directions with unit vectors orthogonal to the periodic ones
    ortho = []
    for k in np.flatnonzero(periodic):
        v = full[k] - sum(np.dot(full[k], o) * o for o in ortho)
        ortho.append(v / np.linalg.norm(v))
    for k in np.flatnonzero(~periodic):
        for trial in np.eye(3):
            v = trial - sum(np.dot(trial, o) * o for o in ortho)
            if np.linalg.norm(v) > 1e-6:
                full[k] = v / np.linalg.norm(v)
                ortho.append(full[k])
                break
    return full, periodic


def _heights(full):
    """Distance between opposite faces along each cell vector, Å."""
    vol = abs(np.linalg.det(full))
    return np.array([vol / np.linalg.norm(np.cross(full[(k + 1) % 3], full[(k + 2) % 3]))
                     for k in range(3)])


def bond_graph(positions, cell, pbc, cutoff: float = BOND_CUTOFF) -> BondGraph:
    """Bonds closer than ``cutoff`` Å, through the periodic faces of any cell.

    Parameters
    ----------
    positions : (N, 3) float, Å
    cell : (3, 3) float, Å (rows are cell vectors; zero rows allowed where not periodic)
    pbc : (3,) bool
    cutoff : float, Å

    Raises
    ------
    ValueError
        A periodic height below ``2 cutoff`` (one-line, naming the height).
    """
    pos = np.asarray(positions, dtype=float)
    full, periodic = _periodic_cell(cell, pbc)
    h = _heights(full)
    for k in np.flatnonzero(periodic):
        if h[k] < 2.0 * cutoff:
            raise ValueError(f"periodic cell height {h[k]:.3f} Å along cell vector {k} is "
                             f"shorter than two bond cutoffs ({2 * cutoff:.2f} Å); valid: a "
                             "periodic length of at least two cutoffs")
    frac = pos @ np.linalg.inv(full)
    shift = np.zeros_like(frac)
    shift[:, periodic] = -np.floor(frac[:, periodic])
    ext_pos = pos + shift @ full
    ext_frac = frac + shift
    owner = np.arange(len(pos))
    img = np.zeros((len(pos), 3))
    for k in np.flatnonzero(periodic):
        f = cutoff / h[k]
        lo = ext_frac[:, k] < f
        hi = ext_frac[:, k] > 1.0 - f
        add = np.concatenate([np.flatnonzero(lo), np.flatnonzero(hi)])
        sgn = np.concatenate([np.ones(lo.sum()), -np.ones(hi.sum())])
        ext_pos = np.vstack([ext_pos, ext_pos[add] + sgn[:, None] * full[k]])
        ext_frac = np.vstack([ext_frac, ext_frac[add] + sgn[:, None] * np.eye(3)[k]])
        owner = np.concatenate([owner, owner[add]])
        img = np.vstack([img, img[add] + sgn[:, None] * np.eye(3)[k]])
    pairs = cKDTree(ext_pos).query_pairs(cutoff, output_type="ndarray")
    return _directed(pairs, ext_pos, owner, len(pos), cutoff)


def _directed(pairs, ext_pos, owner, n, cutoff):
    """CSR of the pairs with at least one real (un-imaged) end, in both directions."""
    a, b = pairs[:, 0], pairs[:, 1]
    ra, rb = a < n, b < n
    src = np.concatenate([a[ra], b[rb]])
    dst = np.concatenate([owner[b[ra]], owner[a[rb]]])
    d = np.vstack([ext_pos[b[ra]] - ext_pos[a[ra]], ext_pos[a[rb]] - ext_pos[b[rb]]])
    order = np.lexsort((dst, src))
    src, dst, d = src[order], dst[order], d[order]
    keep = np.ones(len(src), dtype=bool)  # a bond found through two faces is kept once
    keep[1:] = (src[1:] != src[:-1]) | (dst[1:] != dst[:-1]) \
        | (np.abs(d[1:] - d[:-1]).max(axis=1) > 1e-9)
    src, dst, d = src[keep], dst[keep], d[keep]
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=indptr[1:])
    return BondGraph(indptr, dst.astype(np.int64), np.ascontiguousarray(d), float(cutoff))


def components(graph: BondGraph) -> tuple[int, np.ndarray]:
    """Connected pieces: ``(count, label per atom)`` (labels ordered by lowest atom index)."""
    n = graph.n_atoms
    adj = csr_matrix((np.ones(len(graph.indices)), graph.indices, graph.indptr), shape=(n, n))
    return connected_components(adj, directed=False)


@nb.njit(cache=True)
def _bfs(indptr, indices, root, member):
    """Breadth-first order from ``root`` over atoms with ``member`` true; the parent edge of
    each visited atom (-1 for the root and unvisited atoms)."""
    n = len(indptr) - 1
    order = np.empty(n, dtype=np.int64)
    parent_edge = np.full(n, -1, dtype=np.int64)
    seen = np.zeros(n, dtype=np.bool_)
    order[0] = root
    seen[root] = True
    head, tail = 0, 1
    while head < tail:
        i = order[head]
        head += 1
        for e in range(indptr[i], indptr[i + 1]):
            j = indices[e]
            if member[j] and not seen[j]:
                seen[j] = True
                parent_edge[j] = e
                order[tail] = j
                tail += 1
    return order[:tail], parent_edge


def bfs_tree(graph: BondGraph, root: int, member=None):
    """Breadth-first tree of the piece holding ``root``.

    Returns
    -------
    order : (K,) int64
        Atoms in visiting order (root first).
    parent_edge : (N,) int64
        Edge index (into ``graph.indices``) from each atom's parent to it; -1 for the root
        and atoms outside the tree.
    """
    if member is None:
        member = np.ones(graph.n_atoms, dtype=np.bool_)
    return _bfs(graph.indptr, graph.indices, int(root), np.asarray(member, dtype=np.bool_))


@nb.njit(cache=True)
def _accumulate(order, parent_edge, sources, value_e, out):
    for k in range(1, len(order)):
        c = order[k]
        e = parent_edge[c]
        p = sources[e]
        for q in range(out.shape[1]):
            out[c, q] = out[p, q] + value_e[e, q]


def tree_accumulate(graph: BondGraph, order, parent_edge, value_e, start):
    """Sum an edge quantity down the tree: ``out[child] = out[parent] + value_e[edge]``.

    Parameters
    ----------
    value_e : (E, k) float
        Per directed edge (e.g. ``graph.d_ec`` for unwrapped positions, Å).
    start : (k,) float
        Value at the root.

    Returns
    -------
    (N, k) float64; rows outside the tree are NaN.
    """
    value_e = np.ascontiguousarray(value_e, dtype=np.float64)
    out = np.full((graph.n_atoms, value_e.shape[1]), np.nan)
    out[order[0]] = start
    _accumulate(np.asarray(order), np.asarray(parent_edge), graph.sources, value_e, out)
    return out
