"""Convert the per-rank checkpoints of a run over K MPI ranks into one whole-body
checkpoint, which a run on any rank count (one included) resumes.

``python -m upscale.engine.parallel.convert DIR/checkpoint.npz --ranks K`` reads
``DIR/checkpoint.rank<r>of<K>.npz`` (or their previous generation, the newest step every
rank holds) and writes ``DIR/checkpoint.npz``. Each rank file carries the global indices
of its particles and bonds (``mpi_gid``, ``mpi_bond_gid``) and which of them it owns, so
the conversion needs neither the scene nor MPI. A resumed run continues bit for bit when
it keeps one thread per rank (the forces of the last step are the owners' values).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from upscale.engine.parallel.partition import rank_path

__all__ = ["merge_checkpoints", "main"]

_ROWS = ("F", "F_ext", "reactions")  # per-particle engine arrays


def _step(path: Path) -> int:
    with np.load(path) as z:
        return int(z["step"])


def _files(path: Path, ranks: int) -> list[Path]:
    """Each rank's file of the newest step all ranks hold (current or previous generation)."""
    per = []
    for r in range(ranks):
        cur = rank_path(path, r, ranks)
        prev = cur.with_name(f"{cur.stem}.prev{cur.suffix}")
        per.append({_step(f): f for f in (prev, cur) if f.is_file()})
    if not all(per):
        missing = [r for r, d in enumerate(per) if not d]
        raise ValueError(f"no checkpoint of ranks {missing} of {ranks} next to {path}")
    common = set(per[0]).intersection(*per[1:])
    if not common:
        raise ValueError(f"the {ranks} ranks' checkpoints of {path} hold no common step")
    s = max(common)
    return [d[s] for d in per]


def merge_checkpoints(path, ranks: int, out=None) -> Path:
    """Write the whole-body checkpoint (``out``, default ``path``) of the per-rank files
    of ``ranks`` ranks; returns its path."""
    from upscale.engine.checkpoint import load_checkpoint, save_checkpoint
    from upscale.engine.state import State

    path = Path(path)
    loaded = [load_checkpoint(f, engine=True) for f in _files(path, int(ranks))]
    st0, meta, eng0 = loaded[0]
    if "mpi_gid" not in eng0:
        raise ValueError(f"{path}: these rank files carry no global indices (written before "
                         "they did); resume them on the same rank count")
    n, nb = int(eng0["mpi_n"]), int(eng0["mpi_nb"])
    y, v = np.empty((n, 3)), np.empty((n, 3))
    intact = np.empty(nb, dtype=bool)
    rows = {k: np.empty((n, 3)) for k in _ROWS if k in eng0}
    for st, _, eng in loaded:
        if st.extra or st.fields:
            raise ValueError("checkpoints with model extras or fields cannot be merged yet")
        own, g = eng["mpi_owned"], eng["mpi_gid"]
        y[g[own]], v[g[own]] = st.y[own], st.v[own]
        ob = eng["mpi_bond_owned"]
        intact[eng["mpi_bond_gid"][ob]] = st.intact[ob]
        for k, a in rows.items():
            a[g[own]] = eng[k][own]
    engine = {k: a for k, a in eng0.items() if not k.startswith("mpi_") and k not in rows}
    engine.update(rows)
    meta = {**meta, "n": n, "nb": nb, "merged_from_ranks": int(ranks)}
    return save_checkpoint(out or path, State(y.copy(), y, v, intact, st0.t, st0.step),
                           meta, engine=engine)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m upscale.engine.parallel.convert",
                                description="merge per-rank checkpoints into one")
    p.add_argument("checkpoint", type=Path,
                   help="the run's checkpoint path (e.g. DIR/checkpoint.npz)")
    p.add_argument("--ranks", type=int, required=True, help="the rank count that wrote them")
    p.add_argument("--out", type=Path, default=None, help="output (default: the checkpoint path)")
    args = p.parse_args(argv)
    try:
        out = merge_checkpoints(args.checkpoint, args.ranks, args.out)
    except (ValueError, FileNotFoundError) as exc:
        print(f"convert: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
