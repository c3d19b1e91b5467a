"""Restart files of the quasi-static LAMMPS runner: a long reference run that is killed
resumes at its last finished load step.

A strain step of :func:`upscale.experiments.lammps.quasistatic.quasi_static_tension` starts
from the previous step's minimum with the cell remapped affinely, and every minimisation
starts afresh (CG keeps no history across ``minimize`` commands), so the state to carry is
the positions (atom-id order), the cell length, the step index and the curve so far. After
the zero-stress relaxation and after every load step, :meth:`RunState.save` writes them to
``DIR/state.npz`` (rank 0, atomically: a killed run never leaves half a file). A resumed run
rebuilds the LAMMPS instance from those positions (the neighbour lists are rebuilt, so the
sums may run in another order: a resumed run agrees with an uninterrupted one to round-off,
not bit for bit) and goes on with the next step. The positions are gathered collectively,
so the number of MPI ranks may differ between segments.

Each rank also keeps its CPU time and peak resident memory over all segments in
``DIR/rank<r>.json``, so a run spread over several processes reports its whole cost.
``DIR/fingerprint`` ties the folder to one structure and protocol: a folder made by another
run is refused, not resumed.
"""
from __future__ import annotations

import io
import json
import os
import resource
import time
from pathlib import Path

import numpy as np

from upscale.io import atomic_write_bytes, write_json

__all__ = ["RunState", "mpi_rank"]


def mpi_rank() -> int:
    """This process's rank in an ``mpiexec`` world (0 outside one)."""
    return int(os.environ.get("PMI_RANK", os.environ.get("OMPI_COMM_WORLD_RANK", "0")))


class RunState:
    """The restart folder ``path`` of one run, tied to ``fingerprint`` (a string naming the
    structure and the protocol)."""

    def __init__(self, path, fingerprint: str):
        self.path = Path(path)
        self.rank = mpi_rank()
        self._cpu0 = time.process_time()
        mark = self.path / "fingerprint"
        if mark.is_file() and mark.read_text() != fingerprint:
            raise ValueError(f"restart={str(self.path)!r} holds another run (fingerprint "
                             f"{mark.read_text()[:16]}...); valid: an empty folder or this "
                             "run's own")
        self.path.mkdir(parents=True, exist_ok=True)
        if self.rank == 0 and not mark.is_file():
            atomic_write_bytes(mark, fingerprint.encode())
        rec = self.path / f"rank{self.rank}.json"
        self._before = json.loads(rec.read_text()) if rec.is_file() else \
            {"cpu_s": 0.0, "peak_rss_GB": 0.0, "segments": 0}

    def load(self) -> dict | None:
        """The last saved state (``positions``, ``Lz``, ``k``, ``curve``, ``relaxation``,
        ``dump_bytes``), or None before the first save."""
        f = self.path / "state.npz"
        if not f.is_file():
            return None
        with np.load(f) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            meta["positions"] = z["positions"].copy()
        return meta

    def save(self, positions, Lz: float, k: int, curve: dict, relaxation: dict,
             dump_bytes: int | None) -> None:
        """Write the state after load step ``k`` (-1: after the zero-stress relaxation)."""
        self.account()
        if self.rank != 0:
            return
        meta = {"Lz": float(Lz), "k": int(k), "curve": curve, "relaxation": relaxation,
                "dump_bytes": dump_bytes}
        buf = io.BytesIO()
        np.savez(buf, positions=np.asarray(positions, float),
                 meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))
        atomic_write_bytes(self.path / "state.npz", buf.getvalue())

    def account(self) -> dict:
        """This rank's CPU time and peak memory over every segment so far (written)."""
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2  # kB -> GB
        rec = {"cpu_s": self._before["cpu_s"] + time.process_time() - self._cpu0,
               "peak_rss_GB": max(self._before["peak_rss_GB"], rss),
               "segments": self._before["segments"] + 1}
        write_json(self.path / f"rank{self.rank}.json", rec)
        return rec

    def cost(self) -> dict:
        """The whole run's cost over the ranks' records: ``cpu_s`` (sum over ranks and
        segments), ``peak_rss_GB_per_rank`` (largest per rank), ``segments``."""
        recs = [json.loads(f.read_text()) for f in sorted(self.path.glob("rank*.json"))]
        return {"cpu_s": float(sum(r["cpu_s"] for r in recs)),
                "peak_rss_GB_per_rank": [float(r["peak_rss_GB"]) for r in recs],
                "segments": int(max((r["segments"] for r in recs), default=0))}
