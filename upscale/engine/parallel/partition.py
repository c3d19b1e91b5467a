"""A simulation's body split over MPI ranks: what each rank holds and the global sums.

:func:`localize` turns the global body (system, family, conditions, state) into one
rank's part, before the models are prepared: the models are then prepared on, and run on,
the rank's owned particles plus halo (:mod:`~upscale.engine.parallel.halo`) as if that
were the whole body, and never learn of ranks. The halo particles are held (all their
dofs constrained, velocity zero): their positions come from their owners at every force
evaluation (:meth:`Partition.exchange_positions`), and the forces the models compute on
them are not used.

Halo layers per model (:func:`halo_depth`): a model may declare ``halo_depth``; else PMB
without surface correction and Ti-PD without its surface correction need one (a bond's
force depends on the two positions and the bond only) and PMB with surface correction,
LPS, correspondence (NOSB), CPD and the unified model two (a bond's force also depends on
per-particle quantities of the partner summed over the partner's row: the surface factor,
the dilatation, the deformation gradient and stress, the partner's sets, the gain and
stress). The outer halo layer's rows are partial: the local family marks them
(``Family.partial_rows``) so that a model's checks of every family skip them. Other
models, and the variants named in :func:`halo_depth`, are refused with the reason.
"""
from __future__ import annotations

import copy
import glob
import time
from pathlib import Path

import numpy as np

from upscale.engine.parallel.comm import Refused
from upscale.engine.parallel.decomposition import rcb
from upscale.engine.parallel.halo import Local, build_local, build_local_rows

__all__ = ["Partition", "localize", "halo_depth", "rank_path"]

_CONDITIONS = ("Displacement", "Fixed", "Velocity", "Force", "BodyForce")
# why the models whose force is a sum over families do not run distributed yet
_TUBE = ("the coarse tube runs on one process in this version (its links, atomistic "
         "regions and minimisers are not split over ranks)")
_NOT_YET = {
    "dcbr": _TUBE, "tube": _TUBE, "tersoff": "an atomistic model: run LAMMPS on ranks instead",
    "lj": "a model between bodies: not split over ranks yet",
    "tridyn": "its rotations are fields per particle, and the halo exchange carries "
              "positions only",
}
_THERMOSTATS = ("NoneType", "Langevin", "NoseHoover", "NoseHooverChain")


def halo_depth(model) -> int:
    """Halo layers ``model``'s forces need (module docstring); one-line ``ValueError``
    for a model that cannot run distributed yet."""
    d = getattr(model, "halo_depth", None)
    if d is not None:
        return int(d)
    if model.name == "pmb":
        return 2 if getattr(model, "surface_correction", False) else 1
    if model.name == "lps":
        return 2
    if model.name == "nosb":  # per-particle F, P, K^-1 of the partners: two layers
        if getattr(model, "bond_associated", False):
            raise Refused("bond-associated correspondence cannot run on several MPI ranks "
                          "yet (its forces come from a stiffness assembled on the whole "
                          "family); run it on one rank")
        return 2
    if model.name == "cpd":  # sets centred at the partners hold i: two layers
        if getattr(model, "surface_correction", False):
            raise Refused("CPD with surface correction cannot run on several MPI ranks yet "
                          "(its correction is computed from every particle's family); run it "
                          "on one rank")
        if getattr(model, "E", None) is not None and model.calibration == "discrete":
            raise Refused("CPD with calibration='discrete' cannot run on several MPI ranks "
                          "yet (it fits its constants on one interior particle of the whole "
                          "body, which a rank does not hold); use calibration='continuum' or "
                          "give C1, C2, C3, or run it on one rank")
        return 2
    if model.name == "unified":  # the partners' stress and gain: two layers
        if model.needs.failure:
            raise Refused("the unified model with bond failure cannot run on several MPI "
                          "ranks yet (a bond's failure depends on the stress at both ends, so "
                          "the halo's copies of a bond need the owner's decision: an exchange "
                          "of bond states, not done yet); run it on one rank")
        return 2
    why = _NOT_YET.get(model.name) or _NOT_YET.get(model.name.split("-")[0])
    if why:
        raise Refused(f"model {model.name!r} cannot run on several MPI ranks yet: {why}; "
                      "run it on one rank")
    if model.name == "tipd":  # a pair force from the two positions and the bond alone
        if getattr(model, "surface", "none") in (None, "none"):
            return 1
        raise Refused("Ti-PD with surface correction cannot run on several MPI ranks yet "
                      "(its prepare checks every particle's family, and the halo's outer "
                      "rows are partial); run it with surface='none' or on one rank")
    raise Refused(f"model {model.name!r} cannot run on several MPI ranks yet (the engine "
                  "does not know the halo its forces need); valid there: 'pmb', 'lps', "
                  "'tipd'; run it on one rank")


class Partition:
    """The communicator, the decomposition ``part`` (N,) and this rank's :class:`Local`."""

    def __init__(self, comm, local: Local, part: np.ndarray):
        self.comm, self.local, self.part = comm, local, part
        self.rank, self.size = comm.rank, comm.size
        self.owned = local.owned
        self.halo = ~local.owned
        self.owned_bonds = local.owned_bonds
        self.exchanges = 0        # position exchanges done, and the wall time in them (s)
        self.exchange_s = 0.0
        self._counts = comm.allgather((local.n_owned, local.halo_rows()))  # for describe

    def exchange_positions(self, y: np.ndarray) -> None:
        """Mutates ``y``: halo rows <- their owners' current positions."""
        t0 = time.perf_counter()
        self.local.exchange(self.comm, y)
        self.exchange_s += time.perf_counter() - t0
        self.exchanges += 1

    def time_exchange(self, y: np.ndarray, repeats: int = 50) -> float:
        """Mean wall time (s) of one halo exchange of ``y`` with the ranks synchronised
        before each (collective): the exchange alone, without the wait for a slower rank
        that the in-run timing includes. ``y`` is left as it was (halo rows are copies)."""
        total = 0.0
        for _ in range(int(repeats)):
            self.comm.barrier()
            t0 = time.perf_counter()
            self.local.exchange(self.comm, y)
            total += time.perf_counter() - t0
        return float(self.comm.allreduce_max(total / max(int(repeats), 1)))

    def time_packing(self, y: np.ndarray, repeats: int = 50) -> float:
        """Mean wall time (s) of the copies of one halo exchange of ``y`` on this rank
        alone: the send rows gathered into buffers and the received buffers scattered
        into the halo rows, without any message (the part of an exchange that grows with
        the halo on any interconnect). ``y`` is left as it was."""
        loc = self.local
        bufs = [np.ascontiguousarray(y[rows]) for _, rows in loc.recv]
        t0 = time.perf_counter()
        for _ in range(int(repeats)):
            for _, rows in loc.send:
                np.ascontiguousarray(y[rows])
            for (_, rows), buf in zip(loc.recv, bufs):
                y[rows] = buf
        return (time.perf_counter() - t0) / max(int(repeats), 1)

    def traffic(self) -> dict:
        """This rank's halo traffic per position exchange: peers, rows and bytes sent and
        received (float64 x 3 per row), and the mean wall time of an exchange (s)."""
        loc = self.local
        sent = sum(r.shape[0] for _, r in loc.send)
        got = sum(r.shape[0] for _, r in loc.recv)
        return {"peers": len(loc.recv), "rows_sent": sent, "rows_received": got,
                "bytes_sent": 24 * sent, "bytes_received": 24 * got, "owned": loc.n_owned,
                "local": loc.n, "exchange_s": self.exchange_s / max(self.exchanges, 1)}

    def gather(self, a: np.ndarray) -> np.ndarray:
        """Global per-particle array (N, ...) on every rank from the owned rows."""
        return self.local.gather(self.comm, a)

    def localize_checkpoint(self, st, eng: dict, x0: np.ndarray):
        """This rank's part ``(state, engine arrays)`` of a whole-body checkpoint (the
        per-particle forces of the halo rows zeroed: the halo is held)."""
        from upscale.engine.state import State

        loc = self.local
        if st.y.shape[0] != loc.n_global or st.intact.shape[0] != loc.nb_global:
            raise Refused(f"checkpoint holds {st.y.shape[0]} particles and "
                          f"{st.intact.shape[0]} bonds, the body {loc.n_global} and "
                          f"{loc.nb_global}")
        if st.extra or st.fields:
            raise Refused("a checkpoint with model extras or fields cannot be split over "
                          "MPI ranks yet")
        g = loc.gid
        out = State(x0, st.y[g].copy(), st.v[g].copy(), st.intact[loc.bond_gid].copy(),
                    st.t, st.step)
        out.v[self.halo] = 0.0
        eng = dict(eng)
        for k in ("F", "F_ext", "reactions"):
            if k in eng:
                a = eng[k][g].copy()
                a[self.halo] = 0.0
                eng[k] = a
        return out, eng

    def gather_bonds(self, a: np.ndarray) -> np.ndarray:
        """Global per-bond array (nb, ...) on every rank from the owned rows' bonds."""
        return self.local.gather_bonds(self.comm, a)

    def sum(self, x):
        return self.comm.allreduce_sum(x)

    def broken_bonds(self, intact: np.ndarray) -> int:
        """Broken directed bonds of the whole body (each counted on its owner's rank)."""
        mine = int(np.count_nonzero(self.owned_bonds & ~intact))
        return int(self.comm.allreduce_sum(mine))

    def describe(self) -> dict:
        loc, counts = self.local, self._counts
        return {"ranks": self.size, "decomposition": "recursive coordinate bisection, "
                "weighted by bonds per particle + 1", "halo_layers": loc.depth,
                "owned_per_rank": [c[0] for c in counts], "halo_per_rank": [c[1] for c in counts]}


def rank_path(path, rank: int, size: int) -> Path:
    """``dir/name.npz`` -> ``dir/name.rank<r>of<n>.npz`` (one checkpoint file per rank)."""
    p = Path(path)
    return p.with_name(f"{p.stem}.rank{rank}of{size}{p.suffix}")


def refuse_other_ranks(path, size: int) -> None:
    """One-line ``ValueError`` when per-rank checkpoints of ``path`` written by another
    rank count are there (saying how to convert them); nothing otherwise."""
    p = Path(path)
    found = sorted(glob.glob(str(p.with_name(f"{p.stem}.rank0of*{p.suffix}"))))
    counts = sorted({int(f[len(str(p.with_name(f"{p.stem}.rank0of"))):].split(".")[0])
                     for f in found} - {size})
    if counts:
        k = counts[0]
        raise Refused(f"checkpoint {p} was written on {k} MPI ranks, this run has {size}: "
                      f"resume on {k} ranks, or merge it first (python -m "
                      f"upscale.engine.parallel.convert {p} --ranks {k}), which any rank "
                      "count resumes")


def localize(comm, system, family, models, conditions, state, integrator):
    """This rank's ``(system, family, conditions, state, Partition)`` of the global body
    (collective). Refuses, with one line, what cannot run distributed yet."""
    from upscale.engine.families import Family, FamilyRecipe, candidate_counts
    from upscale.engine.system import ParticleSystem

    depth = max(halo_depth(m) for m in models)  # first: it names a model that cannot
    if family is None:
        raise Refused("several MPI ranks need a pair family to split the body by")
    th = type(getattr(integrator, "thermostat", None)).__name__
    if type(integrator).__name__ != "VelocityVerlet" or th not in _THERMOSTATS:
        name = getattr(integrator, "name", type(integrator).__name__)
        raise Refused(f"integrator {name!r}{'' if th == 'NoneType' else ' with ' + th} runs on "
                      "one rank in this version; valid on several ranks: VelocityVerlet "
                      f"without a thermostat or with {', '.join(_THERMOSTATS[1:])}")
    recipe = family if isinstance(family, FamilyRecipe) else None
    if recipe is not None:  # each rank builds its rows only (weights: candidates in range)
        cuts = np.linspace(0, system.n, comm.size + 1).astype(np.int64)  # a slice each
        mine = candidate_counts(system, recipe.horizon, partial_volume=recipe.partial_volume,
                                spacing=recipe.spacing,
                                rows=np.arange(cuts[comm.rank], cuts[comm.rank + 1]))
        w = np.concatenate(comm.allgather(mine))
        del mine
        part = rcb(system.x0, w + 1.0, comm.size)
        del w
        loc = build_local_rows(comm, recipe, part, depth)
        horizon, h = float(recipe.horizon), float(recipe.spacing or system.spacing)
        pv, beta = recipe.partial_volume, None
    else:
        part = rcb(system.x0, family.counts + 1.0, comm.size)
        loc = build_local(comm, family.offsets, family.neighbors, part, depth)
        horizon, h, pv = family.horizon, family.spacing, family.partial_volume
        beta = None if family.beta is None else family.beta[loc.bond_gid]
    g = loc.gid
    lsys = ParticleSystem(system.x0[g], system.volume[g], system.density[g], system.material[g],
                          dim=system.dim, thickness=system.thickness, plane=system.plane,
                          spacing=system.spacing, units=system.units)
    lfam = Family(loc.offsets, loc.neighbors, lsys.x0, horizon, h, pv, beta,
                  partial_rows=~loc.complete)
    lstate = _local_state(state, lsys, loc)
    if recipe is not None and state is None:
        lstate.intact[...] = recipe.initial_intact(loc.offsets, loc.neighbors, gid=g)
    lconds = [c for c in (_local_condition(c, loc) for c in conditions) if c is not None]
    return lsys, lfam, lconds, lstate, Partition(comm, loc, part)


def _local_state(state, lsys, loc: Local):
    from upscale.engine.state import State

    if state is None:
        st = State.reference(lsys.x0, loc.bond_gid.shape[0])
    else:
        if state.extra or state.fields:
            raise Refused("a state with model extras or fields cannot be split over MPI "
                          "ranks yet; start from positions, velocities and bond states")
        if state.y.shape != (loc.n_global, 3) or state.intact.shape != (loc.nb_global,):
            raise Refused(f"state has {state.y.shape[0]} particles and {state.intact.shape[0]}"
                          f" bonds, the body {loc.n_global} and {loc.nb_global}")
        g = loc.gid
        st = State(lsys.x0, state.y[g].copy(), state.v[g].copy(),
                   state.intact[loc.bond_gid].copy(), state.t, state.step)
    st.v[~loc.owned] = 0.0
    return st


def _local_condition(cond, loc: Local):
    """``cond`` restricted to this rank's owned particles of its region (None if it has
    none there)."""
    from upscale.engine.conditions import Region

    kind = type(cond).__name__
    if kind not in _CONDITIONS:
        raise Refused(f"condition {kind} runs on one rank in this version; valid on several"
                      f" ranks: {', '.join(_CONDITIONS)}")
    reg = cond.region
    mask = reg.mask[loc.gid] & loc.owned
    if not mask.any():
        return None
    rows = np.searchsorted(reg.index, loc.gid[mask])   # the rows of the region's values
    r = object.__new__(Region)                         # a region may be empty on a rank
    r.name, r.mask, r.index = reg.name, mask, np.flatnonzero(mask)
    c = copy.copy(cond)
    c.region = r
    v = cond.value
    c.value = (lambda t, f=v: _rows(f(t), rows)) if callable(v) else _rows(v, rows)
    return c


def _rows(v, rows):
    a = np.asarray(v, dtype=np.float64)
    return a[rows] if a.ndim == 2 else a
