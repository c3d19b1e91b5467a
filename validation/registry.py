"""The one way into every validation case and benchmark (see DESIGN.md).

A case is a function ``run(args) -> dict`` registered with :func:`case`. It prints its own
readable table (use :func:`table`), may save plots under ``args.outdir``, and returns its key
figures: numbers with units in the key names and ``"pass"`` against the issue's target.
The driver writes them to ``validation/out/CASE.json`` and prints them as one JSON object on
the last line of output.
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import pkgutil
from typing import Callable

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


def table(rows: list[dict], columns: list[str] | None = None, floatfmt: str = ".6g") -> str:
    """Format rows of dicts as a plain aligned text table."""
    if not rows:
        return "(no rows)"
    columns = columns or list(rows[0])

    def fmt(v):
        if isinstance(v, float):
            return format(v, floatfmt)
        return str(v)

    cells = [[fmt(r.get(c, "")) for c in columns] for r in rows]
    widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(columns)]
    line = "  ".join(c.rjust(w) for c, w in zip(columns, widths))
    sep = "  ".join("-" * w for w in widths)
    body = ["  ".join(v.rjust(w) for v, w in zip(row, widths)) for row in cells]
    return "\n".join([line, sep, *body])
