"""The communicator the engine runs on: MPI's world under ``mpiexec``/``srun``, else one
process.

MPI comes through ``mpi4py``. Its binary wheel finds the MPI library at run time: in a
virtual environment with the ``mpich`` wheel (a dependency of this project) it loads the
wheel's ``libmpi.so.12`` from ``<venv>/lib`` without any setting; on a cluster the
cluster's MPICH-ABI library (Cray MPICH, Intel MPI, MVAPICH) is chosen with
``MPI4PY_LIBMPI=/path/to/libmpi.so.12`` (or found on ``LD_LIBRARY_PATH``), and the ranks
must be started by the launcher that belongs to that library.

``mpi4py`` is imported only when the process was started by an MPI launcher (one of the
environment variables :data:`LAUNCHER_VARS` is set): a serial run never initialises MPI.
Every collective here is called by all ranks in the same order; the serial communicator
implements the same methods as identities, so the engine has one code path.
"""
from __future__ import annotations

import contextlib
import os
import sys

import numpy as np

__all__ = ["world", "launched_by_mpi", "SerialComm", "MPIComm", "LAUNCHER_VARS", "Refused",
           "one_process", "serial"]

# set by Hydra (MPICH, Intel MPI), PMIx launchers, Open MPI and SLURM's srun
LAUNCHER_VARS = ("PMI_SIZE", "PMI_RANK", "PMIX_RANK", "OMPI_COMM_WORLD_SIZE", "MPI_LOCALNRANKS")
_RANK_VARS = ("PMI_RANK", "PMIX_RANK", "OMPI_COMM_WORLD_RANK", "SLURM_PROCID")

_WORLD = None
_SERIAL_DEPTH = 0  # inside serial(): world() is one process


class Refused(ValueError):
    """A run refused on several MPI ranks for a reason every rank meets at the same point
    (a model, an integrator, a solver or an input that cannot run distributed). Uncaught,
    it ends the run with its one line on rank 0 (``error: ...``) and every rank exits
    (code 1), without an abort."""


def one_process(what: str) -> None:
    """:class:`Refused` when the world has several ranks: ``what`` runs on one process
    in this version (e.g. ``newton.solve``); nothing on one process."""
    comm = world()
    if comm.size > 1:
        raise Refused(f"{what} runs on one process in this version; this run has {comm.size} "
                      "MPI ranks: run it without mpiexec (valid on several ranks: velocity "
                      "Verlet and adaptive dynamic relaxation of a Simulation)")


@contextlib.contextmanager
def serial():
    """Inside, :func:`world` is one process: a simulation built there is whole on this
    rank (a reference to compare a distributed run with, in the same processes)."""
    global _SERIAL_DEPTH
    _SERIAL_DEPTH += 1
    try:
        yield
    finally:
        _SERIAL_DEPTH -= 1


def _env_rank() -> int:
    """This process's rank as the launcher's environment says (0 if it does not)."""
    for k in _RANK_VARS:
        if os.environ.get(k, "").isdigit():
            return int(os.environ[k])
    return 0


def launched_by_mpi() -> bool:
    """True when an MPI launcher started this process (its environment says so)."""
    return any(k in os.environ for k in LAUNCHER_VARS)


def world():
    """The world communicator (cached): :class:`MPIComm` when launched by MPI with more
    than one rank, else :class:`SerialComm`. MPI launch without ``mpi4py`` installed:
    one-line ``RuntimeError`` saying what to install."""
    global _WORLD
    if _SERIAL_DEPTH:
        return _SERIAL
    if _WORLD is None:
        if launched_by_mpi():
            try:
                from mpi4py import MPI
            except Exception as exc:  # not installed, or its MPI library not loadable
                _one_line_on_rank0()
                raise RuntimeError("started by an MPI launcher but mpi4py is not importable "
                                   f"({type(exc).__name__}: {exc}); install it (pip install "
                                   "mpi4py mpich) or point MPI4PY_LIBMPI at the MPI library"
                                   ) from None
            _WORLD = SerialComm()
            if MPI.COMM_WORLD.Get_size() > 1:
                _WORLD = MPIComm(MPI.COMM_WORLD)
                _abort_on_uncaught(MPI.COMM_WORLD)
        else:
            _WORLD = SerialComm()
    return _WORLD


def _one_line_on_rank0() -> None:
    """Without MPI the ranks cannot agree: an uncaught error prints one line on the
    process the launcher calls rank 0 and nothing on the others."""
    rank = _env_rank()

    def hook(kind, value, tb):
        if rank == 0:
            sys.stderr.write(f"error: {value}\n")
            sys.stderr.flush()

    sys.excepthook = hook


def _abort_on_uncaught(comm) -> None:
    """An exception nobody catches on one rank ends every rank (``MPI_Abort``) instead of
    leaving the others waiting in a collective; the rank prints it first. A
    :class:`Refused` (met by every rank alike): one line on rank 0, every rank exits."""
    previous = sys.excepthook

    def hook(kind, value, tb):
        if isinstance(value, Refused):
            if comm.Get_rank() == 0:
                sys.stderr.write(f"error: {value}\n")
                sys.stderr.flush()
            return
        sys.stderr.write(f"[rank {comm.Get_rank()} of {comm.Get_size()}] ")
        previous(kind, value, tb)
        sys.stderr.flush()
        comm.Abort(1)

    sys.excepthook = hook


class SerialComm:
    """One process: every collective is the identity."""

    rank, size = 0, 1

    def allreduce_sum(self, x):
        return x

    def allreduce_max(self, x):
        return x

    def allgather(self, obj) -> list:
        return [obj]

    def alltoall(self, objs: list) -> list:
        return list(objs)

    def bcast(self, obj):
        return obj

    def barrier(self) -> None:
        pass

    def exchange(self, sends, recvs) -> None:
        """Nothing to exchange on one process."""


class MPIComm:
    """An mpi4py communicator with the few collectives the engine uses."""

    def __init__(self, comm):
        self.comm = comm
        self.rank = comm.Get_rank()
        self.size = comm.Get_size()

    def allreduce_sum(self, x):
        """Sum over ranks of a float or a float64 array (rank order: the same on every
        rank, not the serial order of the terms)."""
        from mpi4py import MPI

        if np.ndim(x) == 0:
            return self.comm.allreduce(x, op=MPI.SUM)
        a = np.ascontiguousarray(x, dtype=np.float64)
        out = np.empty_like(a)
        self.comm.Allreduce(a, out, op=MPI.SUM)
        return out

    def allreduce_max(self, x):
        from mpi4py import MPI

        return self.comm.allreduce(x, op=MPI.MAX)

    def allgather(self, obj) -> list:
        return self.comm.allgather(obj)

    def alltoall(self, objs: list) -> list:
        return self.comm.alltoall(objs)

    def bcast(self, obj):
        return self.comm.bcast(obj, root=0)

    def barrier(self) -> None:
        self.comm.Barrier()

    def exchange(self, sends, recvs) -> None:
        """Point-to-point exchange: ``sends`` and ``recvs`` are lists of ``(peer, buffer)``
        (contiguous arrays); receives are posted first, then sends, then all complete
        (nonblocking ``Irecv``/``Isend``, one message per peer and direction)."""
        from mpi4py import MPI

        reqs = [self.comm.Irecv(buf, source=peer, tag=17) for peer, buf in recvs]
        reqs += [self.comm.Isend(buf, dest=peer, tag=17) for peer, buf in sends]
        MPI.Request.Waitall(reqs)


_SERIAL = SerialComm()
