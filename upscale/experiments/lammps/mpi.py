"""Run a LAMMPS runner on several MPI ranks:
``mpiexec -n N python -m upscale.experiments.lammps.mpi``.

The LAMMPS Python module joins ``MPI_COMM_WORLD`` when started under ``mpiexec`` (no mpi4py
needed). :func:`run_mpi` pickles the call (function name, Atoms, keyword arguments) to a
temporary file, starts ``nprocs`` copies of this module with the ``mpiexec`` of the ``mpich``
wheel (next to the Python executable, else on PATH), every rank runs the same runner
(LAMMPS decomposes the box over the ranks; gathers and dumps are collective), and rank 0
writes the JSON result that :func:`run_mpi` returns.
"""
from __future__ import annotations

import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

__all__ = ["run_mpi", "mpiexec_path"]

_FUNCS = ("quasi_static_tension", "quasi_static_torsion", "dynamic_tension")


def mpiexec_path() -> str:
    cand = Path(sys.executable).parent / "mpiexec"
    if cand.is_file():
        return str(cand)
    found = shutil.which("mpiexec")
    if not found:
        raise FileNotFoundError("mpiexec not found (next to the Python executable or on PATH); "
                                "install the mpich wheel or run with nprocs=1")
    return found


def run_mpi(func: str, atoms, nprocs: int, **kwargs) -> dict:
    """Run ``upscale.experiments.lammps.tension.<func>(atoms, **kwargs)`` on ``nprocs``
    MPI ranks."""
    if func not in _FUNCS:
        raise ValueError(f"func={func!r}; valid: {', '.join(_FUNCS)}")
    if isinstance(nprocs, bool) or not isinstance(nprocs, int) or nprocs < 1:
        raise ValueError(f"nprocs={nprocs!r}; valid: an integer >= 1")
    show = kwargs.pop("progress", None) is not None  # a callback does not cross processes:
    # rank 0 prints the load steps instead, to this process's standard output
    with tempfile.TemporaryDirectory(prefix="upscale-mpi-") as d:
        job, out = Path(d) / "job.pkl", Path(d) / "out.json"
        job.write_bytes(pickle.dumps({"func": func, "atoms": atoms, "kwargs": kwargs,
                                      "show": show}))
        repo = Path(__file__).resolve().parents[3]
        cmd = [mpiexec_path(), "-n", str(nprocs), sys.executable, "-m",
               "upscale.experiments.lammps.mpi", str(job), str(out)]
        proc = subprocess.run(cmd, cwd=repo, stdout=None if show else subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
        if proc.returncode != 0 or not out.is_file():
            tail = (proc.stderr or proc.stdout or "").strip().splitlines()[-1:] or ["no output"]
            raise RuntimeError(f"MPI run on {nprocs} ranks failed (exit {proc.returncode}): "
                               f"{tail[0]}")
        res = json.loads(out.read_text())
    return res


def _main(argv) -> int:
    from upscale.io import write_json
    from upscale.experiments.lammps import tension

    job = pickle.loads(Path(argv[0]).read_bytes())
    rank = int(os.environ.get("PMI_RANK", os.environ.get("OMPI_COMM_WORLD_RANK", "0")))
    kw = dict(job["kwargs"])
    if job.get("show") and rank == 0:
        kw["progress"] = lambda x, y: print(f"{job['func']}: load {x:.5g}, response {y:.5g}",
                                            flush=True)
    res = getattr(tension, job["func"])(job["atoms"], **kw)
    if rank == 0:
        res["nprocs"] = int(os.environ.get("PMI_SIZE", "1"))
        write_json(argv[1], res)
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
