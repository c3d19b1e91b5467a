"""The scenes: plain functions of their parameters returning a :class:`Result`.

>>> from upscale import experiments
>>> run = experiments.tension(tube, model="dcbr", coarsening=2)      # doctest: +SKIP
>>> run.figures["strength_GPa"]; run.plot("tension.png"); run.to_json("tension.json")

``experiments.NAME`` is the scene registered under ``NAME`` in
:data:`upscale.experiments.registry.SCENES` (``plate_bending`` for ``plate-bending``),
imported on first use; :func:`names` lists them. Loading protocols are
:mod:`upscale.experiments.protocols`, the result type :mod:`upscale.experiments.result`,
the LAMMPS reference backend :mod:`upscale.experiments.lammps`, the implementations
:mod:`upscale.experiments.scenes`.
"""
from __future__ import annotations

from upscale.experiments.result import Comparison, Result

__all__ = ["Result", "Comparison", "names"]


def names() -> list[str]:
    """The scene names (as on the command line)."""
    from upscale.experiments.registry import names as _names

    return _names()


def __getattr__(name: str):
    import importlib

    registry = importlib.import_module("upscale.experiments.registry")
    key = name.replace("_", "-")
    if key in registry.SCENES:
        return registry.get(key)
    raise AttributeError(f"module 'upscale.experiments' has no attribute {name!r}; "
                         f"scenes: {', '.join(registry.names())}")
