"""The one way into every validation case and benchmark (see DESIGN.md).

A case is a function ``run(args) -> dict`` registered with :func:`case`. It prints its own
readable table (use :func:`table`), may save plots under ``args.outdir``, and returns its key
figures: numbers with units in the key names and ``"pass"`` against the case's target.
The driver writes them to ``validation/out/CASE.json`` and prints them as one JSON object on
the last line of output.
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import pkgutil
from typing import Callable

from upscale.io import text_table

__all__ = ["case", "CASES", "Case", "table", "discover"]


@dataclasses.dataclass
class Case:
    name: str
    summary: str
    run: Callable[[argparse.Namespace], dict]
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None


CASES: dict[str, Case] = {}


def case(name: str, summary: str, add_arguments=None):
    """Decorator registering ``run(args) -> dict`` as validation case ``name``."""

    def deco(fn):
        if name in CASES:
            raise ValueError(f"validation case {name!r} registered twice")
        CASES[name] = Case(name, summary, fn, add_arguments)
        return fn

    return deco


def discover() -> dict[str, Case]:
    """Import every module of :mod:`validation.cases` so their cases register."""
    from validation import cases

    for mod in pkgutil.iter_modules(cases.__path__):
        if not mod.name.startswith("_"):
            importlib.import_module(f"validation.cases.{mod.name}")
    return CASES


table = text_table  # one formatter for the cases and the commands (upscale.io)
