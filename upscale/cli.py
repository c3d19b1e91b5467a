"""Command line: ``upscale SCENE [options]``.

Every scene of :data:`upscale.experiments.registry.SCENES` is a sub-command whose options
come from the scene function's signature (:func:`upscale.experiments.registry.add_scene_parser`);
a module of :mod:`upscale.experiments.scenes` that still defines ``register(subparsers)``
adds its own sub-command for a scene not yet in the registry. ``upscale demo`` runs the
project's main job on its embedded default scene (see :data:`DEMO`).
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

#: the scenes that run on several MPI ranks (``mpiexec -n N upscale SCENE``); others refuse
MPI_SCENES = ("plate",)

#: the sub-command (and its arguments) that ``upscale demo`` runs
DEMO: list[str] = ["tension", "--chirality", "10,10", "--length", "100", "--coarsening", "2",
                   "--compare", "lammps"]


def build_parser() -> argparse.ArgumentParser:
    from upscale.experiments import registry, scenes

    parser = argparse.ArgumentParser(
        prog="upscale",
        description="Atomistic-to-continuum mechanics: run a scene and write its results.",
    )
    sub = parser.add_subparsers(dest="_command", metavar="SCENE")
    demo = sub.add_parser("demo", help=f"the main job on the default scene ({' '.join(DEMO)})")
    demo.set_defaults(func=None)
    done = set()
    for name in registry.names():
        if _scene_ready(registry, name):
            registry.add_scene_parser(sub, name)
            done.add(name)
    for mod in pkgutil.iter_modules(scenes.__path__):
        if mod.name.startswith("_"):
            continue
        m = importlib.import_module(f"upscale.experiments.scenes.{mod.name}")
        if hasattr(m, "register"):
            m.register(_Skip(sub, done))
    from upscale.experiments import sweep

    sweep.register(sub)
    return parser


def _scene_ready(registry, name: str) -> bool:
    try:
        registry.get(name)
    except (AttributeError, ImportError):  # a registered scene not written yet
        return False
    return True


class _Skip:
    """Sub-parser collection that ignores the old sub-commands the registry already made."""

    def __init__(self, sub, done):
        self._sub, self._done = sub, done

    def add_parser(self, name, **kw):
        if name in self._done:
            return argparse.ArgumentParser(add_help=False)  # discarded
        return self._sub.add_parser(name, **kw)


def main(argv=None) -> int:
    from upscale.experiments.registry import REMOVED_FLAGS

    argv = list(sys.argv[1:] if argv is None else argv)
    for word in argv:
        flag = word.split("=")[0]
        if flag in REMOVED_FLAGS:
            print(f"upscale: error: {flag} was removed: {REMOVED_FLAGS[flag]}", file=sys.stderr)
            return 2
    parser = build_parser()
    args = parser.parse_args(argv)
    if args._command is None:
        parser.print_help()
        return 2
    if args._command == "demo":
        args = parser.parse_args(DEMO)
    try:
        rank = _mpi_rank(args)
    except RuntimeError as exc:  # started by an MPI launcher without a usable mpi4py
        print(f"upscale {args._command}: error: {exc}", file=sys.stderr)
        return 2
    try:
        if hasattr(args, "_scene"):
            from upscale.experiments.registry import run_from_args

            run_from_args(args)
            return 0
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as exc:  # bad input: one clear line, no traceback
        if rank == 0:  # under mpiexec every rank meets the same bad input: one line
            print(f"upscale {args._command}: error: {exc}", file=sys.stderr)
        return 2


def _refuse_ranks(comm, command: str) -> int:
    """One line on rank 0 for a scene that runs on one process only; exit code 2."""
    if comm.rank == 0:
        print(f"upscale {command}: error: runs on one MPI rank in this version, started on "
              f"{comm.size}; valid under mpiexec: {', '.join(MPI_SCENES)}", file=sys.stderr)
    return 2


def _mpi_rank(args) -> int:
    """Under an MPI launcher with several ranks: rank 0 writes the results and prints; the
    others run the same scene (their part of the body) and write into a scratch folder
    removed at exit, with stdout silenced. Returns this process's rank (0 on one)."""
    from upscale.engine.parallel.comm import world

    comm = world()
    if comm.size > 1 and args._command not in MPI_SCENES:
        raise SystemExit(_refuse_ranks(comm, args._command))
    if comm.rank == 0 or not hasattr(args, "out"):
        return comm.rank
    import atexit
    import os
    import shutil
    import tempfile

    scratch = tempfile.mkdtemp(prefix=f"upscale-rank{comm.rank}-")
    atexit.register(shutil.rmtree, scratch, ignore_errors=True)
    args.out = scratch
    args.quiet = True
    sys.stdout = open(os.devnull, "w")
    return comm.rank


if __name__ == "__main__":
    sys.exit(main())
