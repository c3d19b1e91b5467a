"""One result type for every scene.

A scene (a plain function of its parameters, :mod:`upscale.experiments`) returns a
:class:`Result`:

``figures``
    scalar numbers, the unit in the name (``strength_GPa``, ``youngs_TPa``,
    ``strain_at_peak``, ``P_c_kN``); a dimensionless figure has no suffix.
``curves``
    named 1-D arrays. Arrays of one table share a prefix before ``/``
    (``"curve/strain"``, ``"curve/stress_GPa"``); a name without ``/`` belongs to the table
    ``"curve"``. :meth:`Result.to_csv` writes one CSV per table.
``fields``
    per-particle arrays, first axis the particle (``damage`` (N,), ``x0`` (N, 3), ...).
``meta``
    what is needed to read and rerun the numbers: ``scene``, ``params`` (every argument of
    the scene call), ``conventions`` (stress area, sign of compression, ...), ``versions``
    (packages, machine), ``commit``, ``seeds``, ``wall_s``, ``cpu_s``, ``command`` (the
    ``upscale`` command line that reruns it), ``schema`` (:data:`SCHEMA`), and
    ``plot`` (what :meth:`Result.plot` draws: ``{"x": name, "y": [names]}`` per table),
    ``peak_rss_GB`` (the process's peak resident memory when the result was made), and
    for a scene on a peridynamic family ``memory``
    (:func:`upscale.engine.memory.run_memory`: bonds, bytes kept per bond).

Everything written goes through :func:`upscale.io.atomic_write_bytes`: a reader never sees
half a file.
"""
from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import os
import subprocess
import time
from pathlib import Path

import numpy as np

from upscale.io import NumpyJSON, atomic_write_bytes, atomic_write_text, text_table, versions
from upscale.engine.memory import peak_rss_gb

__all__ = ["Result", "Comparison", "SCHEMA", "make_meta", "command_line", "Timer"]

#: version of the JSON layout written by :meth:`Result.to_json`
SCHEMA = 1


@dataclasses.dataclass
class Result:
    """What a scene returns (module docstring): ``figures``, ``curves``, ``fields``, ``meta``."""

    figures: dict = dataclasses.field(default_factory=dict)
    curves: dict = dataclasses.field(default_factory=dict)
    fields: dict = dataclasses.field(default_factory=dict)
    meta: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        self.figures = {str(k): _scalar(k, v) for k, v in self.figures.items()}
        self.curves = {str(k): np.asarray(v) for k, v in self.curves.items()}
        for k, v in self.curves.items():
            if v.ndim != 1:
                raise ValueError(f"curve {k!r} has shape {v.shape}; valid: a 1-D array")
        self.fields = {str(k): np.asarray(v) for k, v in self.fields.items()}

    @property
    def scene(self) -> str:
        return str(self.meta.get("scene", "scene"))

    def __repr__(self) -> str:
        figs = ", ".join(f"{k}={_fmt(v)}" for k, v in self.figures.items())
        return f"Result({self.scene}: {figs})"

    # ----------------------------------------------------------------- tables and files
    def tables(self) -> dict[str, dict[str, np.ndarray]]:
        """The curves grouped by table: ``{table: {column: array}}`` (module docstring)."""
        out: dict[str, dict[str, np.ndarray]] = {}
        for name, arr in self.curves.items():
            table, _, col = name.rpartition("/")
            out.setdefault(table or "curve", {})[col] = arr
        return out

    def to_dict(self) -> dict:
        """A JSON-able dict (arrays as lists); :meth:`from_dict` inverts it."""
        return {"schema": SCHEMA, "figures": self.figures,
                "curves": {k: v for k, v in self.curves.items()},
                "fields": {k: v for k, v in self.fields.items()}, "meta": self.meta}

    @classmethod
    def from_dict(cls, d: dict) -> "Result":
        schema = d.get("schema")
        if schema != SCHEMA:
            raise ValueError(f"result schema {schema!r}; valid: {SCHEMA}")
        return cls(figures=d.get("figures", {}), curves=d.get("curves", {}),
                   fields=d.get("fields", {}), meta=d.get("meta", {}))

    def to_json(self, path, fields: bool = True) -> Path:
        """Write the result as JSON atomically (``fields=False`` leaves the per-particle
        arrays out: a small file for tables and sweeps)."""
        d = self.to_dict()
        if not fields:
            d["fields"] = {}
        return atomic_write_text(path, json.dumps(d, cls=NumpyJSON, indent=1) + "\n")

    @classmethod
    def from_json(cls, path) -> "Result":
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"result file {path}: {exc}") from None
        return cls.from_dict(d)

    def to_csv(self, folder) -> list[Path]:
        """One CSV per curve table, ``folder/<scene>_<table>.csv``; columns padded with NaN
        where a table's arrays differ in length."""
        folder = Path(folder)
        paths = []
        for table, cols in self.tables().items():
            n = max(len(a) for a in cols.values())
            data = np.full((n, len(cols)), np.nan)
            for j, a in enumerate(cols.values()):
                data[: len(a), j] = a
            buf = io.StringIO()
            np.savetxt(buf, data, delimiter=",", header=",".join(cols), comments="", fmt="%.10g")
            name = f"{self.scene}_{table}.csv".replace("/", "_")
            paths.append(atomic_write_text(folder / name, buf.getvalue()))
        return paths

    # ----------------------------------------------------------------- comparison
    def compare(self, other: "Result", figures=None) -> "Comparison":
        """Relative errors of this result's figures against ``other`` (the reference):
        ``100 (self - other) / |other|`` per cent, for every figure both have (or those
        named in ``figures``)."""
        names = figures or [k for k in self.figures if k in other.figures]
        rows = []
        for k in names:
            a, b = self.figures.get(k, math.nan), other.figures.get(k, math.nan)
            err = 100.0 * (a - b) / abs(b) if (b and math.isfinite(b)) else math.nan
            rows.append({"figure": k, "this": a, "reference": b, "error_pct": err})
        return Comparison(rows, this=_label(self), reference=_label(other))

    # ----------------------------------------------------------------- pictures
    def plot(self, path, other: "Result | None" = None) -> Path:
        """The scene's standard figure as a PNG: every curve table (``meta["plot"]`` names
        its axes; else the first column against the others) and, where ``fields`` has
        ``damage`` and ``x0``, the particles in the reference configuration coloured by
        damage. With ``other``, both results on the same axes and the same colour scale."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        runs = [self] if other is None else [self, other]
        panels = [t for t in self.tables()]
        maps = [r for r in runs if "damage" in r.fields and "x0" in r.fields]
        ncol = max(1, len(panels)) + len(maps)
        fig, axes = plt.subplots(1, ncol, figsize=(4.6 * ncol, 3.8), dpi=110, squeeze=False)
        for ax, table in zip(axes[0], panels):
            for r, style in zip(runs, ("-", "--")):
                _plot_table(ax, r, table, style)
        vmax = max([1e-12] + [float(np.nanmax(r.fields["damage"])) for r in maps])
        for ax, r in zip(axes[0][len(panels):], maps):
            _damage_map(ax, r, vmax)
        fig.suptitle(_label(self) if other is None else f"{_label(self)} vs {_label(other)}",
                     fontsize=9)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        plt.close(fig)
        return atomic_write_bytes(path, buf.getvalue())


@dataclasses.dataclass
class Comparison:
    """Rows ``{figure, this, reference, error_pct}``; ``str()`` is a text table."""

    rows: list
    this: str = "this"
    reference: str = "reference"

    def __str__(self) -> str:
        return text_table(self.rows, ["figure", "this", "reference", "error_pct"], ".6g")

    def __getitem__(self, figure: str) -> float:
        for r in self.rows:
            if r["figure"] == figure:
                return r["error_pct"]
        raise KeyError(figure)

    def max_abs_error_pct(self) -> float:
        errs = [abs(r["error_pct"]) for r in self.rows if math.isfinite(r["error_pct"])]
        return max(errs) if errs else math.nan


class Timer:
    """Wall and CPU time of a block: ``with Timer() as t: ...; t.wall_s, t.cpu_s``. CPU time
    is the process's (all threads)."""

    def __enter__(self):
        self._w, self._c = time.perf_counter(), time.process_time()
        self.wall_s = self.cpu_s = 0.0
        return self

    def __exit__(self, *exc):
        self.wall_s = time.perf_counter() - self._w
        self.cpu_s = time.process_time() - self._c
        return False


def make_meta(scene: str, params: dict, *, timer: Timer | None = None, seeds=None,
              conventions: dict | None = None, plot: dict | None = None, **extra) -> dict:
    """The ``meta`` of a scene's :class:`Result` (module docstring)."""
    meta = {"scene": scene, "schema": SCHEMA, "params": _jsonable(params),
            "conventions": conventions or {}, "versions": versions(), "commit": _commit(),
            "seeds": list(seeds) if seeds is not None else [],
            "command": command_line(scene, params)}
    if timer is not None:
        meta.update(wall_s=timer.wall_s, cpu_s=timer.cpu_s)
    meta["peak_rss_GB"] = peak_rss_gb()
    if plot:
        meta["plot"] = plot
    meta.update(extra)
    return meta


def command_line(scene: str, params: dict) -> str:
    """The ``upscale`` command that reruns ``scene`` with ``params`` (options named as in
    :mod:`upscale.experiments.scenes`: ``foo_bar`` -> ``--foo-bar``; booleans as
    ``--foo-bar`` / ``--no-foo-bar``; sequences comma-joined; strings quoted for the shell;
    ``None`` and objects left out)."""
    import shlex

    words = ["upscale", scene.replace("_", "-")]
    for k, v in params.items():
        if v is None or k in ("progress", "structure"):
            continue
        opt = "--" + k.replace("_", "-")
        if isinstance(v, (bool, np.bool_)):
            words.append(opt if v else "--no-" + k.replace("_", "-"))
        elif isinstance(v, (list, tuple)):
            words += [opt, ",".join(str(x) for x in v)]
        elif isinstance(v, (int, float, str, Path)):
            words += [opt, shlex.quote(str(v))]
    return " ".join(words)


# --------------------------------------------------------------------- private helpers
def _scalar(name, v):
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    try:
        return float(v)
    except (TypeError, ValueError):
        raise ValueError(f"figure {name!r} = {v!r}; valid: a number") from None


def _fmt(v) -> str:
    return format(v, ".5g") if isinstance(v, float) else str(v)


def _label(r: Result) -> str:
    model = r.meta.get("params", {}).get("model")
    return f"{r.scene} ({model})" if model else r.scene


def _jsonable(params: dict) -> dict:
    out = {}
    for k, v in params.items():
        try:
            json.dumps(v, cls=NumpyJSON)
            out[k] = v
        except TypeError:
            out[k] = repr(v) if not hasattr(v, "get_chemical_formula") else \
                f"Atoms({v.get_chemical_formula()})"
    return out


def _commit() -> str | None:
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return None
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, timeout=5,
                             env={**os.environ, "GIT_OPTIONAL_LOCKS": "0"})
        if out.returncode == 0:
            return out.stdout.strip()
    return None


def _plot_table(ax, r: Result, table: str, style: str) -> None:
    cols = r.tables().get(table)
    if not cols:
        return
    spec = r.meta.get("plot", {}).get(table, {})
    names = list(cols)
    x = spec.get("x", names[0])
    ys = spec.get("y", [n for n in names if n != x][:3])
    for y in ys:
        if y in cols and x in cols:
            n = min(len(cols[x]), len(cols[y]))
            ax.plot(cols[x][:n], cols[y][:n], style, marker=".", ms=3,
                    label=f"{_label(r)}: {y}")
    ax.set_xlabel(x)
    ax.set_title(table, fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)


def _damage_map(ax, r: Result, vmax: float) -> None:
    """Particles in the reference configuration, coloured by damage on [0, vmax]; a tube
    (``meta["conventions"]["unroll"]``: its axis) is unrolled to (azimuth, z)."""
    x0 = np.asarray(r.fields["x0"], dtype=float)
    mu = np.asarray(r.fields["damage"], dtype=float)
    axis = r.meta.get("conventions", {}).get("unroll")
    if axis is not None:
        u = np.degrees(np.arctan2(x0[:, 1] - axis[1], x0[:, 0] - axis[0]))
        v, labels = x0[:, 2], ("azimuth (deg)", "z")
    else:
        u, v, labels = x0[:, 0], x0[:, 1], ("x", "y")
    sc = ax.scatter(u, v, c=mu, s=4, cmap="inferno_r", vmin=0.0, vmax=vmax)
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(f"damage: {_label(r)}", fontsize=9)
    ax.figure.colorbar(sc, ax=ax, shrink=0.8)
