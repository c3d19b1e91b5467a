"""The one way into every validation case and benchmark (see DESIGN.md).

A case is a function ``run(args) -> dict`` registered with :func:`case`. It prints its own
readable table (use :func:`table`), may save plots under ``args.outdir``, and returns its key
figures: numbers with units in the key names and ``"pass"`` against the case's target.
The driver writes them to ``validation/out/CASE/CASE.json`` and prints them as one JSON object
on the last line of output; ``--record`` also writes them as the case's baseline
(:mod:`validation.baseline`), and ``python -m validation report`` puts every case on one page
(:mod:`validation.report`).
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib
import pkgutil
from pathlib import Path
from typing import Callable

from upscale.io import text_table

__all__ = ["case", "CASES", "Case", "table", "show", "figure", "is_rows", "discover"]


@dataclasses.dataclass
class Case:
    name: str
    summary: str
    run: Callable[[argparse.Namespace], dict]
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None
    target: str | None = None  # the target as stated, shown beside the figures
    quick: bool | None = None  # has a reduced --quick variant (None: the run mentions it)

    @property
    def module(self) -> str:
        return self.run.__module__

    def has_quick(self) -> bool:
        """Whether ``--quick`` changes the run: as declared, else whether the run's source
        reads ``quick`` (a case that ignores it has no reduced variant)."""
        if self.quick is not None:
            return self.quick
        import inspect

        return "quick" in inspect.getsource(self.run)


CASES: dict[str, Case] = {}


def case(name: str, summary: str, add_arguments=None, target: str | None = None,
         quick: bool | None = None):
    """Decorator registering ``run(args) -> dict`` as validation case ``name``; ``target``
    states the pass criterion as the issue gave it, ``quick`` whether ``--quick`` reduces it."""

    def deco(fn):
        if name in CASES:
            raise ValueError(f"validation case {name!r} registered twice")
        CASES[name] = Case(name, summary, fn, add_arguments, target, quick)
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


def is_rows(v) -> bool:
    """Whether a figure is a table: a non-empty list of dicts (the driver prints those)."""
    return isinstance(v, list) and bool(v) and all(isinstance(r, dict) for r in v)


def show(rows: list[dict], title: str | None = None, cols=None, fmt: str = ".4g") -> None:
    """Print ``title`` and ``rows`` as a text table (for tables a case does not return)."""
    if title:
        print(title)
    print(table(rows, cols, fmt), flush=True)


@contextlib.contextmanager
def figure(path, nrows: int = 1, ncols: int = 1, figsize=(6, 4), dpi: int = 130, **kw):
    """``(fig, axes)`` of a matplotlib (Agg) figure, laid out and saved to ``path`` on exit."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(nrows, ncols, figsize=figsize, **kw)
    try:
        yield fig, axes
        fig.tight_layout()
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=dpi)
    finally:
        plt.close(fig)


def threads(n: int | None = 1) -> int:
    """Set the engine's numba threads (None: all); returns the number now in use."""
    from upscale.engine.kernels import set_threads

    return set_threads(n)
