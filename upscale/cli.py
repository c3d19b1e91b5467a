"""Command line: ``upscale SCENE [options]``.

Scenes live in :mod:`upscale.experiments`; each module there that defines
``register(subparsers)`` adds its sub-command. ``upscale demo`` runs the project's main job
on its embedded default scene (see :data:`DEMO`).
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

#: the sub-command (and its arguments) that ``upscale demo`` runs
DEMO: list[str] = ["tension", "--chirality", "10,10", "--length", "100", "--coarsening", "2",
                   "--compare", "lammps"]


def build_parser() -> argparse.ArgumentParser:
    from upscale import experiments

    parser = argparse.ArgumentParser(
        prog="upscale",
        description="Atomistic-to-continuum mechanics: run a scene and write its results.",
    )
    sub = parser.add_subparsers(dest="scene", metavar="SCENE")
    demo = sub.add_parser("demo", help=f"the main job on the default scene ({' '.join(DEMO)})")
    demo.set_defaults(func=None)
    for mod in pkgutil.iter_modules(experiments.__path__):
        if mod.name.startswith("_"):
            continue
        m = importlib.import_module(f"upscale.experiments.{mod.name}")
        if hasattr(m, "register"):
            m.register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.scene is None:
        parser.print_help()
        return 2
    if args.scene == "demo":
        args = parser.parse_args(DEMO)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as exc:  # bad input: one clear line, no traceback
        print(f"upscale {args.scene}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
