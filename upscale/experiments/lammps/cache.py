"""Where the LAMMPS backend keeps what it computes: a user folder, never the source tree.

:func:`cache_dir` is ``$UPSCALE_CACHE`` when that is set, else ``$XDG_CACHE_HOME/upscale``,
else ``~/.cache/upscale``. Its sub-folders: ``potentials/`` (the step-cutoff Tersoff files
LAMMPS reads), ``dumps/`` (LAMMPS dumps of the runs) and ``references/`` (reference runs
computed on demand by the validation cases, keyed by the runner's checksum).
"""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir"]


def cache_dir(sub: str | None = None) -> Path:
    """The cache folder (module docstring), or its sub-folder ``sub``; not created here."""
    env = os.environ.get("UPSCALE_CACHE", "").strip()
    if env:
        base = Path(env).expanduser()
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "upscale"
    return base / sub if sub else base
