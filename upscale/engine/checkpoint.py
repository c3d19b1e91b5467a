"""Checkpoint / restart: the state as one ``.npz`` written atomically.

A checkpoint holds ``y, v, intact, t, step`` and the models' ``extra`` arrays, plus a
JSON ``meta`` (particle and bond counts, models, anything the scene adds) and the arrays a
driver needs to continue exactly where it stopped (``engine``: e.g. the
:class:`~upscale.engine.simulation.Simulation`'s forces of the last step, which the first
half-kick of the next step uses and which cannot be recomputed once that step's bonds have
broken, or a random generator's state). It is written to
a temporary file and moved into place (:func:`upscale.io.atomic_write_bytes`), so a run
killed at any moment leaves the previous checkpoint intact, and a restart resumes there.
"""
from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from upscale.engine.state import State
from upscale.io import NumpyJSON, atomic_write_bytes

__all__ = ["save_checkpoint", "load_checkpoint", "Checkpoint"]


def save_checkpoint(path, state: State, meta: dict | None = None, *,
                    engine: dict | None = None) -> Path:
    """Atomically write ``state`` (and ``meta``, and the driver's ``engine`` arrays) to
    ``path`` (.npz)."""
    arrays = {"y": state.y, "v": state.v, "intact": state.intact,
              "t": np.float64(state.t), "step": np.int64(state.step)}
    for k, v in state.extra.items():
        arrays[f"extra__{k}"] = np.asarray(v)
    for k, v in state.fields.items():
        arrays[f"field__{k}"] = np.asarray(v)
        arrays[f"fieldv__{k}"] = np.asarray(state.field_v[k])
    for k, v in (engine or {}).items():
        arrays[f"engine__{k}"] = np.asarray(v)
    m = dict(meta or {})
    m.setdefault("n", int(state.y.shape[0]))
    m.setdefault("nb", int(state.intact.shape[0]))
    arrays["meta"] = np.frombuffer(json.dumps(m, cls=NumpyJSON).encode(), dtype=np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return atomic_write_bytes(path, buf.getvalue())


def load_checkpoint(path, x0: np.ndarray | None = None, *, nb: int | None = None,
                    engine: bool = False):
    """Read a checkpoint; returns ``(state, meta)``, or ``(state, meta, engine_arrays)``
    with ``engine=True``.

    With ``x0`` (and ``nb``) the checkpoint is checked against the body it is loaded for.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    with np.load(path) as z:
        meta = json.loads(bytes(z["meta"]).decode())
        y, v, intact = z["y"].copy(), z["v"].copy(), z["intact"].copy()
        extra = {k[len("extra__"):]: z[k].copy() for k in z.files if k.startswith("extra__")}
        eng = {k[len("engine__"):]: z[k].copy() for k in z.files if k.startswith("engine__")}
        t, step = float(z["t"]), int(z["step"])
        fields = {k[len("field__"):]: z[k].copy() for k in z.files if k.startswith("field__")}
        field_v = {k[len("fieldv__"):]: z[k].copy() for k in z.files if k.startswith("fieldv__")}
    if x0 is not None and np.asarray(x0).shape != y.shape:
        raise ValueError(f"checkpoint {path} holds {y.shape[0]} particles, the body has "
                         f"{np.asarray(x0).shape[0]}")
    if nb is not None and intact.shape[0] != nb:
        raise ValueError(f"checkpoint {path} holds {intact.shape[0]} bonds, the family has {nb}")
    ref = np.asarray(x0, dtype=np.float64) if x0 is not None else y.copy()
    st = State(ref, y, v, intact, t, step, extra, fields, field_v)
    return (st, meta, eng) if engine else (st, meta)


class Checkpoint:
    """Write a checkpoint every ``every`` steps to ``path`` (only healthy states)."""

    def __init__(self, path, every: int = 1000):
        if int(every) < 1:
            raise ValueError(f"checkpoint interval must be >= 1 step, got {every!r}")
        self.path = Path(path)
        self.every = int(every)
        self.last_step: int | None = None

    keep_previous = False  # set for one file per MPI rank: see previous_path

    @property
    def previous_path(self) -> Path:
        """``name.prev.npz``: the checkpoint before the last, kept when ``keep_previous``
        (the ranks of a killed run may have written different steps last; the previous
        generation gives a step all of them hold)."""
        return self.path.with_name(f"{self.path.stem}.prev{self.path.suffix}")

    def write(self, state: State, meta: dict | None = None, *, engine: dict | None = None) -> Path:
        if self.keep_previous and self.path.is_file():
            self.path.replace(self.previous_path)
        p = save_checkpoint(self.path, state, meta, engine=engine)
        self.last_step = state.step
        return p
