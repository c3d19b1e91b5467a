"""A scaling model of one distributed run, on paper, from the figures measured on a few
ranks of one machine (``python -m validation bench-mpi``).

Time of one step on P ranks, each holding n particles of b bonds:

    T(P) = t_bond * (b * n + b_h * h)                the force loops: the owned rows'
                                                     bonds and the halo rows' (b_h per
                                                     halo row, measured: the bonds a
                                                     rank holds beyond its owned rows)
         + peers * alpha + 24 h / beta + t_row * h   the halo exchange: one message per
                                                     peer, h halo rows of 3 float64,
                                                     and their packing (measured)
         + 2 log2(P) * alpha                         the one Allreduce of a step (the
                                                     blow-up guard), recursive doubling

``t_bond`` is the single-rank, single-thread time per bond and step; ``alpha`` and
``beta`` are the interconnect's latency and bandwidth (assumed: stated in the result);
``t_row`` is the measured cost of an exchange's copies per halo row received (its rows
gathered into the send buffers and scattered from the receive buffers, on one rank,
without messages: ``Partition.time_packing``). The
halo of a subdomain is the shell of the halo width w (rows, measured at 2 ranks)
around it: h = (s + 2 w)^d - s^d for a cube-like subdomain of side s = n^(1/d) in d
dimensions, with 3^d - 1 peers (at most P - 1). A rank of a 2-rank run of a square plate
has one cut: h = w sqrt(N).

Strong scaling: N fixed, n = N/P. Weak scaling: n fixed. The particle count per rank
below which the exchange takes longer than the owned rows' force loops solves
``t_bond b n = exchange(n) + allreduce``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["fit", "step_time", "strong", "weak", "crossover", "ASSUMED"]

#: interconnect assumed for the model (a typical HPC network: InfiniBand HDR/NDR class)
ASSUMED = {"latency_s": 1.5e-6, "bandwidth_B_per_s": 12e9, "bytes_per_halo_row": 24}


def fit(*, n_particles: int, bonds: int, s_per_step_1rank: float, halo_rows_2ranks: float,
        packing_s_2ranks: float, rows_moved_2ranks: float, halo_bonds_2ranks: float,
        dim: int = 2) -> dict:
    """The model's measured constants from one body of ``n_particles`` (a square plate
    for ``dim`` 2) on 1 and 2 ranks: seconds per bond and step, the halo width in rows
    (``w``: the rows one rank of two receives over the cut's length in particles), the
    cost per halo row of an exchange's copies (``packing_s_2ranks`` for
    ``rows_moved_2ranks`` rows sent and received: per received row, twice that) and the
    bonds per halo row a rank holds beyond its owned rows' (``halo_bonds_2ranks`` of one
    rank over its halo rows)."""
    side = n_particles ** (1.0 / dim)
    cut = side ** (dim - 1)
    return {"t_bond_s": s_per_step_1rank / bonds, "bonds_per_particle": bonds / n_particles,
            "halo_width_rows": halo_rows_2ranks / cut,
            "t_row_s": 2.0 * packing_s_2ranks / max(rows_moved_2ranks, 1.0),
            "halo_bonds_per_row": halo_bonds_2ranks / max(halo_rows_2ranks, 1.0)}


def _halo(n: float, dim: int, w: float) -> tuple[float, int]:
    """(halo rows, peers) of a cube-like subdomain of n particles."""
    side = n ** (1.0 / dim)
    return (side + 2 * w) ** dim - side ** dim, 3 ** dim - 1


def step_time(n: float, P: int, const: dict, *, dim: int, bonds_per_particle=None,
              a: dict = ASSUMED) -> dict:
    """Seconds per step on P ranks of n particles each: compute, exchange, allreduce."""
    b = bonds_per_particle or const["bonds_per_particle"]
    own = const["t_bond_s"] * b * n
    if P == 1:
        return {"compute_s": own, "compute_owned_s": own, "exchange_s": 0.0,
                "allreduce_s": 0.0, "total_s": own}
    h, peers = _halo(n, dim, const["halo_width_rows"])
    bh = const["halo_bonds_per_row"] * b / const["bonds_per_particle"]
    comp = own + const["t_bond_s"] * bh * h
    peers = min(peers, P - 1)
    ex = peers * a["latency_s"] + a["bytes_per_halo_row"] * h / a["bandwidth_B_per_s"] \
        + const["t_row_s"] * h
    ar = 2 * np.log2(P) * a["latency_s"]
    return {"compute_s": comp, "compute_owned_s": own, "exchange_s": ex, "allreduce_s": ar,
            "total_s": comp + ex + ar}


def _ranks(pmax: int) -> list[int]:
    return sorted({1, *[2 ** k for k in range(int(np.log2(pmax)) + 1)], pmax})


def strong(N: float, const: dict, *, dim: int, pmax: int = 1000, **kw) -> list[dict]:
    """Rows (P, n per rank, seconds per step and its parts, speedup, efficiency) for N
    particles on 1..pmax ranks."""
    t1 = step_time(N, 1, const, dim=dim, **kw)["total_s"]
    rows = []
    for P in _ranks(pmax):
        t = step_time(N / P, P, const, dim=dim, **kw)
        rows.append({"ranks": P, "particles_per_rank": N / P, **t,
                     "speedup": t1 / t["total_s"], "efficiency": t1 / t["total_s"] / P})
    return rows


def weak(n: float, const: dict, *, dim: int, pmax: int = 1000, **kw) -> list[dict]:
    """Rows (P, seconds per step and its parts, efficiency T(1)/T(P)) for n particles per
    rank on 1..pmax ranks."""
    t1 = step_time(n, 1, const, dim=dim, **kw)["total_s"]
    return [{"ranks": P, "particles": n * P, **(t := step_time(n, P, const, dim=dim, **kw)),
             "efficiency": t1 / t["total_s"]} for P in _ranks(pmax)]


def crossover(const: dict, *, dim: int, P: int = 1000, **kw) -> float:
    """Particles per rank below which the exchange (and the Allreduce) take longer than
    the force loops on the owned rows, at P ranks (bisection in log n)."""
    lo, hi = 1.0, 1e12

    def excess(n):
        t = step_time(n, P, const, dim=dim, **kw)
        return t["exchange_s"] + t["allreduce_s"] - t["compute_owned_s"]

    if excess(hi) > 0:
        return float("inf")
    if excess(lo) < 0:
        return lo
    for _ in range(200):
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if excess(mid) > 0 else (lo, mid)
    return float(hi)
