"""Where the stored references live, installed or in a source checkout.

The references (LAMMPS runs, FE solutions, calibrations) are the repository's
``data/reference/`` with their provenance (its README). An installed package carries them as
data files in ``<prefix>/share/upscale/reference`` (``pyproject.toml``'s
``[tool.setuptools.data-files]``); a source checkout or an editable install reads the
repository's folder. ``UPSCALE_REFERENCE_DIR`` overrides both.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["reference_dir", "reference_file"]


def reference_dir() -> Path:
    """The folder of the stored references (module docstring)."""
    env = os.environ.get("UPSCALE_REFERENCE_DIR")
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[2] / "data" / "reference"
    if repo.is_dir():
        return repo
    return Path(sys.prefix) / "share" / "upscale" / "reference"


def reference_file(name: str) -> Path:
    """``reference_dir() / name``; a missing file is a one-line FileNotFoundError naming the
    folders looked in."""
    path = reference_dir() / name
    if not path.is_file():
        raise FileNotFoundError(f"stored reference {name!r} not found in {path.parent} "
                                "(set UPSCALE_REFERENCE_DIR to the folder that holds it)")
    return path
