"""A fixed decomposition of the reference configuration: recursive coordinate bisection.

A peridynamic body's partners are fixed in the reference configuration (bonds break, none
form), so the particles are split once, on ``x0``, and never migrate. Recursive coordinate
bisection (Berger & Bokhari 1987) splits a set of particles into ``p`` parts by cutting it
across its longest extent at the weighted median that gives the two halves
``floor(p/2)`` and ``ceil(p/2)`` parts' shares of the weight, then splits each half the same
way. The weight of a particle is its number of bonds (the work of its rows in the force
loops), plus one so that an isolated particle still counts.

The cut is deterministic (a stable sort by the coordinate, ties by particle index), so
every rank computes the same decomposition from the same reference configuration without
communicating.
"""
from __future__ import annotations

import numpy as np

from upscale.engine.parallel.comm import Refused

__all__ = ["rcb", "balance"]


def rcb(x0: np.ndarray, weights: np.ndarray, parts: int) -> np.ndarray:
    """Part (rank) of each particle (N,) int32, by weighted recursive coordinate bisection.

    Parameters
    ----------
    x0 : (N, 3) float
        Reference positions.
    weights : (N,) float
        Work per particle (e.g. bonds per particle + 1); positive.
    parts : int
        Number of parts, 1 <= parts <= N (every part gets at least one particle).
    """
    x0 = np.asarray(x0, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    n = x0.shape[0]
    if int(parts) < 1:
        raise ValueError(f"parts={parts!r}; valid: >= 1")
    if int(parts) > n:
        raise Refused(f"{parts} MPI ranks for {n} particles; valid: at most one rank per "
                      "particle (fewer ranks)")
    part = np.zeros(n, dtype=np.int32)
    stack = [(np.arange(n, dtype=np.int64), 0, int(parts))]
    while stack:
        idx, first, p = stack.pop()
        if p == 1:
            part[idx] = first
            continue
        lo_parts = p // 2
        lo, hi = _bisect(x0[idx], w[idx], lo_parts / p, lo_parts, p - lo_parts)
        stack.append((idx[lo], first, lo_parts))
        stack.append((idx[hi], first + lo_parts, p - lo_parts))
    return part


def _bisect(x: np.ndarray, w: np.ndarray, share: float, n_lo: int, n_hi: int):
    """Indices (into x) of the low and high side of a cut across the longest extent at
    the weighted quantile ``share``, each side keeping at least ``n_lo`` / ``n_hi``
    particles."""
    axis = int(np.argmax(x.max(axis=0) - x.min(axis=0)))
    order = np.argsort(x[:, axis], kind="stable")
    cw = np.cumsum(w[order])
    k = int(np.searchsorted(cw, share * cw[-1], side="left")) + 1  # particles on the low side
    k = min(max(k, n_lo), x.shape[0] - n_hi)
    return order[:k], order[k:]


def balance(part: np.ndarray, weights: np.ndarray, parts: int) -> float:
    """Load imbalance: the heaviest part's weight over the mean part weight (1 = even)."""
    load = np.bincount(part, weights=weights, minlength=parts)
    return float(load.max() / load.mean())
