"""Shortest rings through each bond angle (a local Franzblau search), numba on the CSR graph.

For an atom i with bonded neighbours j and k, the shortest ring through the angle j-i-k has
``2 + d(j, k)`` atoms, d the shortest path from j to k that avoids i (breadth first, at most
``max_ring - 2`` steps). In a perfect wall every angle lies in a hexagon; a Stone–Wales
defect shows 5 and 7, a reconstructed divacancy 5 and 8 (5-8-5) or 5 and 7 (555-777), a
reconstructed monovacancy 5 and 9, a bridge adatom a 3-ring (Banhart, Kotakoski &
Krasheninnikov, ACS Nano 5, 26 (2011)). The search limit must stay below the tube's girth
(the shortest path winding round it), else the winding path would count as a ring:
:func:`ring_limit` gives ``min(10, floor(2 pi R / a_cc) - 1)`` (no bond advances more than
a_cc round the circumference).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["MAX_SLOTS", "ring_limit", "angle_rings"]

#: Angles kept per atom (all pairs of up to four neighbours).
MAX_SLOTS = 6


def ring_limit(radius: float, bond: float, limit: int = 10) -> int:
    """Largest ring size to search on a tube of radius R and bond a_cc, both Å."""
    return int(min(limit, math.floor(2.0 * math.pi * radius / bond) - 1))


@nb.njit(cache=True)
def _path(indptr, indices, start, goal, avoid, maxd, mark, dist, queue, stamp):
    """Shortest path length start -> goal avoiding ``avoid`` (0 if above ``maxd``)."""
    mark[start] = stamp
    dist[start] = 0
    queue[0] = start
    head, tail = 0, 1
    while head < tail:
        a = queue[head]
        head += 1
        if dist[a] >= maxd:
            continue
        for e in range(indptr[a], indptr[a + 1]):
            b = indices[e]
            if b == avoid or mark[b] == stamp:
                continue
            if b == goal:
                return dist[a] + 1
            mark[b] = stamp
            dist[b] = dist[a] + 1
            queue[tail] = b
            tail += 1
    return 0


@nb.njit(cache=True)
def _angle_rings(indptr, indices, atoms, max_ring):
    n = len(indptr) - 1
    out = np.full((len(atoms), MAX_SLOTS), -1, dtype=np.int64)
    mark = np.zeros(n, dtype=np.int64)
    dist = np.zeros(n, dtype=np.int64)
    queue = np.empty(n, dtype=np.int64)
    stamp = 0
    for q in range(len(atoms)):
        i = atoms[q]
        slot = 0
        for e1 in range(indptr[i], indptr[i + 1]):
            for e2 in range(e1 + 1, indptr[i + 1]):
                if slot >= MAX_SLOTS:
                    break
                stamp += 1
                d = _path(indptr, indices, indices[e1], indices[e2], i, max_ring - 2, mark,
                          dist, queue, stamp)
                out[q, slot] = d + 2 if d > 0 else 0
                slot += 1
    return out


def angle_rings(graph, atoms, max_ring: int) -> np.ndarray:
    """Shortest ring through each angle of the given atoms.

    Parameters
    ----------
    graph : BondGraph
    atoms : (K,) int
    max_ring : int
        Largest ring searched (atoms).

    Returns
    -------
    (K, MAX_SLOTS) int64: ring size per angle, 0 where none within ``max_ring``, -1 for
    unused slots (fewer than two bonds, or fewer angles).
    """
    return _angle_rings(graph.indptr, graph.indices, np.asarray(atoms, dtype=np.int64),
                        int(max_ring))
