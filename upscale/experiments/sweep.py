"""``upscale sweep SPEC``: run a scene over a grid of parameters on ``dask.distributed``.

A *scene* is a plain function of keyword parameters that returns a JSON-able dict (keys
starting with ``_`` are private, e.g. a model state, and are dropped). A *sweep* runs one
scene over

* ``params``: parameters shared by every run,
* ``grid``: lists of values whose Cartesian product gives the parameter points,
* ``seeds`` (a list) or ``repeats`` (a count, seeds ``seed_start``, ``seed_start + 1``, ...):
  each point is repeated once per seed, the seed passed as parameter ``seed_param``
  (default ``"seed"``),
* ``runs``: extra parameter points run as they are (after ``params``), e.g. one odd case
  beside the grid,

and writes everything under one output folder::

    OUTPUT/sweep.json             the spec (its identity) and the scene's full name
    OUTPUT/runs/RUN_ID/result.json one per run: parameters, status, result or error
    OUTPUT/sessions/*.json        one per invocation: what it ran, skipped, and its cluster
    OUTPUT/results.csv            the table, one row per run, parameters as columns
    OUTPUT/results.parquet        the same, if pyarrow is importable
    OUTPUT/plots/METRIC_vs_X.png  summary plots (``plot`` section)

The spec is a TOML or YAML file, or a dict with the same keys::

    scene = "tension"                 # a scene name (upscale.experiments), or "module:function"
    output = "out/sweeps/bar"
    repeats = 1                       # (top-level keys before the first [section])
    [params]
    dim = 2
    [grid]
    ratio = [2.0, 3.0, 4.0]
    [plot]
    x = "ratio"
    metrics = ["displacement_err_pct"]
    [run]                             # how to run it; not part of the sweep's identity
    workers = 2                       # LocalCluster workers (default: one per core)
    scheduler = "tcp://host:8786"     # an existing cluster instead of a LocalCluster

Identity and restarts
    A run's identity is a hash of the scene's full name, its parameters and the code version
    (:func:`code_version`: the package version and, in a git checkout, the commit and a hash
    of uncommitted changes), so a result computed by other code is never taken for this
    code's: after a code change the sweep reruns every run, and the earlier version's
    results stay in their folders, out of the table. Each result is written atomically
    (:func:`upscale.io.write_json`, a temporary file and :func:`os.replace`) by the driver
    as soon as it arrives, so killing the sweep loses only the runs in flight, and a
    restart skips every run whose ``result.json`` exists. A run that raises is recorded with its error and traceback (status
    ``"error"``) and the others go on; a restart does not retry it unless asked
    (``retry_failed``): with the same code and parameters it would fail the same way.
    The output folder belongs to one spec: a different spec there is refused, so nothing
    on disk is overwritten.

Parallelism
    By default a ``LocalCluster`` with one worker process per core and one task thread per
    worker: two tasks in one process would each start their own team of numba threads (and
    numba's ``workqueue`` layer, its fallback without OpenMP or TBB, must not be entered
    from two threads at once), and processes sidestep the GIL in the Python parts of a
    scene. Each worker's numba gets ``cores // workers`` threads
    (``NUMBA_NUM_THREADS`` in the worker's environment and :func:`numba.set_num_threads`
    in the task), so the kernels of all workers together use the cores once, not once per
    worker. On an existing cluster (``scheduler``) the task sets one numba thread unless
    told otherwise: its workers usually run one task thread per core already.
"""
from __future__ import annotations

import csv
import dataclasses
import datetime
import hashlib
import importlib
import inspect
import itertools
import json
import math
import os
import subprocess
import sys
import time
import traceback
import types
import typing
from pathlib import Path

from upscale.experiments import registry as _registry

__all__ = ["SCENES", "Spec", "load_spec", "resolve_scene", "code_version", "run_id",
           "run_sweep", "gather", "plot_summary", "execute", "register"]

#: scene names usable in a spec: every scene of :mod:`upscale.experiments` (the registry);
#: any other importable ``"module:function"`` works too
SCENES: dict[str, str] = _registry.SCENES

SPEC_KEYS = ("scene", "output", "params", "grid", "seeds", "repeats", "seed_start",
             "seed_param", "runs", "plot", "run")
RUN_KEYS = ("workers", "scheduler", "timeout", "numba_threads", "retry_failed", "processes")
_JSON_SCALARS = (str, int, float, bool, type(None))


# ------------------------------------------------------------------------------ spec
@dataclasses.dataclass
class Spec:
    """A validated sweep: the scene, its runs' parameters and where they go.

    Built by :func:`load_spec`; ``runs`` is the expanded list of parameter dicts, in order
    (points of ``grid`` x seeds, then the explicit ``runs``), with the values coerced to
    the scene's annotated types (an int where a float is declared becomes a float, so
    ``2`` and ``2.0`` are the same run).
    """

    scene: str                     #: the name given in the spec
    target: str                    #: "module:function" it resolves to
    output: Path
    identity: dict                 #: what makes two specs the same sweep (hashed)
    runs: list[dict]
    param_names: list[str]         #: table columns, in the spec's order
    seed_param: str | None         #: the parameter that carries the seed, if any
    plot: dict
    run: dict                      #: execution settings, not part of the identity

    @property
    def spec_hash(self) -> str:
        return _hash(self.identity)


def _hash(obj) -> str:
    return hashlib.sha256(_canonical(obj).encode()).hexdigest()[:16]


def _canonical(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True)


def _read_spec_file(path: Path) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"spec {str(path)!r}: no such file; valid: a .toml, .yaml, "
                                ".yml or .json sweep spec")
    suffix = path.suffix.lower()
    text = path.read_text()
    try:
        if suffix == ".toml":
            import tomllib

            return tomllib.loads(text)
        if suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        elif suffix == ".json":
            data = json.loads(text)
        else:
            raise ValueError(f"spec {str(path)!r}: unknown format {suffix!r}; valid: .toml, "
                             ".yaml, .yml, .json")
    except ValueError:
        raise
    except Exception as exc:  # yaml.YAMLError is no ValueError; make it one clear line
        raise ValueError(f"spec {str(path)!r}: cannot parse: {str(exc).splitlines()[0]}") \
            from None
    if not isinstance(data, dict):
        raise ValueError(f"spec {str(path)!r}: a {type(data).__name__}; valid: a mapping of "
                         f"{', '.join(SPEC_KEYS)}")
    return data


def resolve_scene(scene) -> tuple[str, typing.Callable]:
    """The full name ``"module:function"`` and the function of a scene.

    ``scene`` is a name of :data:`SCENES`, a ``"module:function"`` path, or a function
    importable by that path (a lambda or a nested function has no stable name, and a run's
    identity needs one).
    """
    if callable(scene):
        target = f"{scene.__module__}:{scene.__qualname__}"
        if "<" in target or scene.__module__ == "__main__":
            raise ValueError(f"scene {target!r}: not importable by name; valid: a module-level "
                             "function of an importable module, or a name of SCENES")
    elif isinstance(scene, str):
        target = SCENES.get(scene, scene)
    else:
        raise ValueError(f"scene {scene!r}: a {type(scene).__name__}; valid: a name of "
                         f"SCENES ({', '.join(sorted(SCENES))}) or 'module:function'")
    if ":" not in target:
        raise ValueError(f"scene {scene!r}: unknown; valid: {', '.join(sorted(SCENES))} or "
                         "'module:function'")
    mod, _, name = target.partition(":")
    try:
        fn = importlib.import_module(mod)
        for part in name.split("."):
            fn = getattr(fn, part)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"scene {scene!r}: cannot import {target!r} ({exc}); valid: "
                         f"{', '.join(sorted(SCENES))} or an importable 'module:function'") \
            from None
    if not callable(fn):
        raise ValueError(f"scene {scene!r}: {target!r} is not a function")
    return target, fn


def _allowed_types(hint) -> tuple | None:
    """The JSON types a type hint admits, or None when it says nothing checkable."""
    if hint is inspect.Parameter.empty or hint is typing.Any:
        return None
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        out = []
        for a in typing.get_args(hint):
            t = _allowed_types(a)
            if t is None:
                return None
            out.extend(t)
        return tuple(out)
    if hint is type(None) or hint is None:
        return (type(None),)
    if origin in (list, tuple) or hint in (list, tuple):
        return (list,)
    if hint in (int, float, str, bool):
        return (hint,)
    return None


def _check_value(name, value, allowed, scene):
    """Check a parameter value against the allowed types; return it coerced (int -> float)."""
    if isinstance(value, tuple):
        value = list(value)
    if isinstance(value, float) and not math.isfinite(value):
        pass
    elif not isinstance(value, _JSON_SCALARS + (list,)) or (
            isinstance(value, list) and not all(isinstance(v, _JSON_SCALARS) for v in value)):
        raise ValueError(f"parameter {name}={value!r}: a {type(value).__name__}; valid: a "
                         "number, string, boolean, null or a list of those")
    if allowed is None:
        return value
    if isinstance(value, bool):  # bool is an int subclass; accept it only where declared
        ok = bool in allowed
    elif isinstance(value, int) and int not in allowed and float in allowed:
        return float(value)
    else:
        ok = isinstance(value, allowed)
    if not ok:
        names = " or ".join(sorted({t.__name__.replace("NoneType", "None") for t in allowed}))
        raise ValueError(f"parameter {name}={value!r} ({type(value).__name__}) of scene "
                         f"{scene!r}; valid: {names}")
    return value


def _signature_checker(fn, target):
    """A function checking one run's parameters against the scene's signature."""
    sig = inspect.signature(fn)
    try:
        hints = typing.get_type_hints(fn)
    except Exception:  # an annotation naming something not importable here: no type checks
        hints = {}
    params = {n: p for n, p in sig.parameters.items()
              if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    var_kw = any(p.kind == p.VAR_KEYWORD for p in sig.parameters.values())
    allowed = {}
    for n, p in params.items():
        a = _allowed_types(hints.get(n, p.annotation if not isinstance(p.annotation, str)
                                     else inspect.Parameter.empty))
        if a is None and p.default is not p.empty and isinstance(p.default,
                                                                 (bool, int, float, str)):
            a = (float,) if type(p.default) is float else (type(p.default),)
        allowed[n] = a
    required = [n for n, p in params.items() if p.default is p.empty]

    def check(point: dict) -> dict:
        out = {}
        for k, v in point.items():
            if k not in params and not var_kw:
                raise ValueError(f"parameter {k!r}: unknown to scene {target!r}; valid: "
                                 f"{', '.join(params) or '(none)'}")
            out[k] = _check_value(k, v, allowed.get(k), target)
        missing = [n for n in required if n not in out]
        if missing:
            raise ValueError(f"scene {target!r} needs parameter(s) {', '.join(missing)}; "
                             "give them in params, grid or runs")
        return out

    return check


def load_spec(source, output=None) -> Spec:
    """Read and validate a sweep spec.

    Parameters
    ----------
    source : str, Path or dict
        A ``.toml``, ``.yaml``/``.yml`` or ``.json`` file, or a dict with the keys of the
        module docstring. A relative ``output`` in a file is taken relative to the current
        directory (where the command runs), as every other path of the command line.
    output : str or Path, optional
        Overrides the spec's ``output``.

    Raises
    ------
    ValueError
        One line naming the offending key or value and what is valid: unknown keys, an
        unknown scene or parameter, a value of the wrong type, an empty grid.
    """
    if isinstance(source, dict):
        data, where = dict(source), "spec"
    else:
        data, where = _read_spec_file(Path(source)), f"spec {str(source)!r}"
    unknown = sorted(set(data) - set(SPEC_KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {', '.join(unknown)}; valid: "
                         f"{', '.join(SPEC_KEYS)}")
    if "scene" not in data:
        raise ValueError(f"{where}: no 'scene'; valid: a name of SCENES "
                         f"({', '.join(sorted(SCENES))}) or 'module:function'")
    target, fn = resolve_scene(data["scene"])
    out = output if output is not None else data.get("output")
    if out is None:
        raise ValueError(f"{where}: no 'output' folder")

    def mapping(key):
        v = data.get(key) or {}
        if not isinstance(v, dict):
            raise ValueError(f"{where}: {key} = {v!r}; valid: a mapping of names to values")
        return v

    fixed, grid, plot, run = mapping("params"), mapping("grid"), mapping("plot"), mapping("run")
    bad = sorted(set(run) - set(RUN_KEYS))
    if bad:
        raise ValueError(f"{where}: unknown run setting(s) {', '.join(bad)}; valid: "
                         f"{', '.join(RUN_KEYS)}")
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            raise ValueError(f"{where}: grid {k} = {v!r}; valid: a non-empty list of values")
    seed_param = data.get("seed_param", "seed")
    if not isinstance(seed_param, str):
        raise ValueError(f"{where}: seed_param = {seed_param!r}; valid: a parameter name")
    if "seeds" in data and "repeats" in data:
        raise ValueError(f"{where}: both 'seeds' and 'repeats'; valid: one of them")
    seeds = data.get("seeds")
    if "repeats" in data:
        rep, start = data["repeats"], data.get("seed_start", 0)
        if isinstance(rep, bool) or not isinstance(rep, int) or rep < 1:
            raise ValueError(f"{where}: repeats = {rep!r}; valid: an integer >= 1")
        if isinstance(start, bool) or not isinstance(start, int):
            raise ValueError(f"{where}: seed_start = {start!r}; valid: an integer")
        seeds = list(range(start, start + rep))
    if seeds is not None and (not isinstance(seeds, list) or not seeds or any(
            isinstance(s, bool) or not isinstance(s, int) for s in seeds)):
        raise ValueError(f"{where}: seeds = {seeds!r}; valid: a non-empty list of integers")
    if seeds is not None and len(set(seeds)) != len(seeds):
        raise ValueError(f"{where}: seeds = {seeds!r} repeat a seed; valid: distinct integers")
    extra = data.get("runs") or []
    if not isinstance(extra, list) or not all(isinstance(r, dict) for r in extra):
        raise ValueError(f"{where}: runs = {extra!r}; valid: a list of parameter mappings")
    clash = sorted(set(fixed) & set(grid)) + (
        [seed_param] if seeds is not None and seed_param in set(fixed) | set(grid) else [])
    if clash:
        raise ValueError(f"{where}: parameter(s) {', '.join(clash)} given twice (params, grid, "
                         "seeds); valid: each in one place")

    check = _signature_checker(fn, target)
    points = []
    if grid or seeds is not None or not extra:
        keys = list(grid)
        for combo in itertools.product(*(grid[k] for k in keys)):
            base = {**fixed, **dict(zip(keys, combo))}
            for s in (seeds if seeds is not None else [None]):
                points.append(base if s is None else {**base, seed_param: s})
    points += [{**fixed, **r} for r in extra]
    runs = [check(p) for p in points]
    ids = [_canonical(r) for r in runs]
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise ValueError(f"{where}: the run {dup} appears twice; valid: distinct parameter "
                         "points")
    names = list(dict.fromkeys(
        [*fixed, *grid, *([seed_param] if seeds is not None else []),
         *(k for r in extra for k in r)]))
    identity = {"scene": target, "runs": runs}
    if plot:
        x = plot.get("x")
        if x is not None and x not in names:
            raise ValueError(f"{where}: plot x = {x!r}; valid: a parameter ({', '.join(names)})")
        ms = plot.get("metrics", [])
        if not isinstance(ms, list) or not all(isinstance(m, str) for m in ms):
            raise ValueError(f"{where}: plot metrics = {ms!r}; valid: a list of result keys")
    return Spec(scene=str(data["scene"]) if not callable(data["scene"]) else target,
                target=target, output=Path(out), identity=identity, runs=runs,
                param_names=names, seed_param=seed_param if seeds is not None else None,
                plot=dict(plot), run=dict(run))


# ------------------------------------------------------------------ identity of runs
def code_version() -> str:
    """The version of the code a result comes from.

    The installed package version, and in a git checkout the commit and, when tracked files
    differ from it, a hash of ``git diff HEAD`` (untracked files are not seen). Computed by
    the driver once per sweep: the workers are assumed to run the same code.
    """
    from importlib.metadata import PackageNotFoundError, version

    try:
        v = version("upscale")
    except PackageNotFoundError:
        v = "unknown"
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return v
    try:
        def git(*a):
            return subprocess.run(["git", "-C", str(root), *a], capture_output=True,
                                  check=True, timeout=30).stdout

        commit = git("rev-parse", "HEAD").decode().strip()
        diff = git("diff", "HEAD", "--no-ext-diff", "--binary")
    except (OSError, subprocess.SubprocessError):
        return v
    out = f"{v}+g{commit[:12]}"
    if diff:
        out += f".dirty{hashlib.sha256(diff).hexdigest()[:8]}"
    return out


def run_id(target: str, params: dict, code: str) -> str:
    """The identity of one run: a hash of the scene's full name, parameters and code."""
    return _hash({"scene": target, "params": params, "code": code})


# ------------------------------------------------------------------------- execution
def execute(target: str, params: dict, numba_threads: int | None = None) -> dict:
    """Run one scene and return its record; never raises for the scene's own errors.

    This is the task a dask worker runs. The scene is imported by name on the worker (the
    same code must be importable there). The record has ``status`` ``"ok"`` with the
    ``result`` (the scene's dict without its ``_private`` keys, made JSON-able), or
    ``"error"`` with ``error`` (one line) and ``traceback``; and ``wall_s``, ``host``,
    ``pid``, ``numba_threads``, ``started_utc``.
    """
    import socket

    from upscale.io import NumpyJSON

    rec = {"status": "ok", "host": socket.gethostname(), "pid": os.getpid(),
           "started_utc": _now()}
    if numba_threads is not None:
        import numba

        numba.set_num_threads(max(1, min(int(numba_threads), numba.config.NUMBA_NUM_THREADS)))
        rec["numba_threads"] = numba.get_num_threads()
    t0 = time.perf_counter()
    try:
        _, fn = resolve_scene(target)
        res = fn(**params)
        if hasattr(res, "figures") and hasattr(res, "meta"):  # a Result: its figures
            res = {**res.figures, "wall_s": res.meta.get("wall_s"),
                   "command": res.meta.get("command")}
        if not isinstance(res, dict):
            raise TypeError(f"scene {target!r} returned a {type(res).__name__}; a scene "
                            "returns a dict")
        res = {k: v for k, v in res.items() if not str(k).startswith("_")}
        rec["result"] = json.loads(json.dumps(res, cls=NumpyJSON))
    except Exception as exc:  # recorded, and the sweep goes on
        rec.update(status="error", error=f"{type(exc).__name__}: {exc}".splitlines()[0],
                   traceback=traceback.format_exc())
    rec["wall_s"] = time.perf_counter() - t0
    return rec


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _check_folder(spec: Spec) -> bool:
    """Check that the output folder is this spec's (True) or new or empty (False)."""
    out = spec.output
    f = out / "sweep.json"
    if f.is_file():
        try:
            held = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"output {str(out)!r}: unreadable sweep.json ({exc}); valid: a "
                             "new folder, or one of this sweep") from None
        if held.get("spec_hash") != spec.spec_hash:
            raise ValueError(
                f"output {str(out)!r} holds a different sweep (scene {held.get('target')!r}, "
                f"{len(held.get('identity', {}).get('runs', []))} runs, spec "
                f"{held.get('spec_hash')}; this spec {spec.spec_hash}); valid: the same spec "
                "or a new output folder")
        return True
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"output {str(out)!r} exists and is not a sweep's folder (no "
                         "sweep.json); valid: a new or empty folder")
    return False


def _claim_folder(spec: Spec) -> None:
    """Write ``sweep.json``, which makes the folder this spec's."""
    from upscale.io import write_json

    write_json(spec.output / "sweep.json", {
        "scene": spec.scene, "target": spec.target, "spec_hash": spec.spec_hash,
        "identity": spec.identity, "param_names": spec.param_names, "plot": spec.plot,
        "created_utc": _now()})


def _result_path(out: Path, rid: str) -> Path:
    return out / "runs" / rid / "result.json"


def _read_record(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):  # absent (or not ours): the run is to do
        return None


def _connect(spec: Spec, workers, scheduler, timeout, numba_threads, processes):
    """A dask client and the numba threads per task: an existing scheduler or a new
    LocalCluster (one worker per core, one task thread each)."""
    from distributed import Client, LocalCluster

    if scheduler:
        if not isinstance(scheduler, str):
            raise ValueError(f"scheduler {scheduler!r}; valid: an address like "
                             "'tcp://host:8786'")
        try:
            client = Client(scheduler, timeout=f"{float(timeout)}s")
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"scheduler {scheduler!r} unreachable within {float(timeout):g} s "
                             f"({type(exc).__name__}); valid: the address of a running dask "
                             "scheduler, or none for a LocalCluster") from None
        return client, None, (1 if numba_threads is None else int(numba_threads))
    cores = os.cpu_count() or 1
    n = cores if workers is None else workers
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"workers={workers!r}; valid: an integer >= 1")
    nt = max(1, cores // n) if numba_threads is None else int(numba_threads)
    env = {k: str(nt) for k in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                "MKL_NUM_THREADS")}
    # no dashboard, and the scheduler's small HTTP server on a free loopback port: several
    # sweeps (or other dask users) on one machine must not compete for port 8787
    kw = {"env": env} if processes else {}
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=processes,
                           dashboard_address="127.0.0.1:0", scheduler_kwargs={"dashboard": False},
                           silence_logs=40, **kw)
    return Client(cluster), cluster, nt


def run_sweep(spec, *, output=None, workers=None, scheduler=None, timeout=None,
              numba_threads=None, retry_failed=None, processes=None, progress=True) -> dict:
    """Run every run of a sweep not yet on disk; gather the table and the plots.

    Parameters
    ----------
    spec : Spec, dict, str or Path
        The sweep (:func:`load_spec`).
    output : str or Path, optional
        Overrides the spec's output folder.
    workers, scheduler, timeout, numba_threads, retry_failed, processes
        Override the spec's ``run`` section: LocalCluster workers (default one per core);
        an existing scheduler's address instead; seconds to wait for it (default 10);
        numba threads per task (default cores // workers locally, 1 on a cluster); rerun
        the runs recorded as failed; LocalCluster worker processes (default True) or
        threads.
    progress : bool
        A tqdm bar over the runs (on stderr).

    Returns
    -------
    dict
        ``planned``, ``skipped`` (already on disk), ``executed`` (run ids of this
        invocation), ``failed`` (run ids whose record is an error), ``wall_s``,
        ``compute_s`` (first submission to last result), ``workers``, ``numba_threads``,
        ``table`` (the CSV path) and ``plots``.

    Raises
    ------
    ValueError
        Bad spec, a folder holding another sweep, an unreachable scheduler: one line.
    """
    from upscale.io import write_json

    t_start = time.perf_counter()
    if not isinstance(spec, Spec):
        spec = load_spec(spec, output=output)
    elif output is not None:
        spec = dataclasses.replace(spec, output=Path(output))
    cfg = dict(spec.run)
    for k, v in (("workers", workers), ("scheduler", scheduler), ("timeout", timeout),
                 ("numba_threads", numba_threads), ("retry_failed", retry_failed),
                 ("processes", processes)):
        if v is not None:
            cfg[k] = v
    timeout = cfg.get("timeout", 10.0)
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not timeout > 0:
        raise ValueError(f"timeout={timeout!r}; valid: seconds > 0")
    ours = _check_folder(spec)
    code = code_version()
    out = spec.output
    ids = [run_id(spec.target, p, code) for p in spec.runs]
    todo, skipped = [], []
    for rid, p in zip(ids, spec.runs):
        rec = _read_record(_result_path(out, rid))
        if rec is None or (cfg.get("retry_failed") and rec.get("status") != "ok"):
            todo.append((rid, p))
        else:
            skipped.append(rid)
    session = {"started_utc": _now(), "pid": os.getpid(), "code_version": code,
               "planned": len(ids), "skipped": skipped, "executed": [], "failed": []}
    sess_file = out / "sessions" / f"{session['started_utc'].replace(':', '')}-{os.getpid()}.json"
    nworkers, nt, t_compute = 0, None, 0.0
    client = cluster = None
    if todo:  # connect before writing anything: an unreachable scheduler leaves no trace
        client, cluster, nt = _connect(spec, cfg.get("workers"), cfg.get("scheduler"),
                                       timeout, cfg.get("numba_threads"),
                                       bool(cfg.get("processes", True)))
    try:
        if not ours:
            _claim_folder(spec)
        write_json(sess_file, session)
        if todo:
            from distributed import as_completed
            from tqdm import tqdm

            nworkers = len(client.scheduler_info(n_workers=-1)["workers"]) \
                if "n_workers" in inspect.signature(client.scheduler_info).parameters \
                else len(client.scheduler_info()["workers"])
            session.update(workers=nworkers, numba_threads=nt,
                           scheduler=cfg.get("scheduler") or "LocalCluster")
            t0 = time.perf_counter()
            futures = {client.submit(execute, spec.target, p, nt, pure=False,
                                     key=f"run-{rid}"): (rid, p) for rid, p in todo}
            bar = tqdm(total=len(ids), initial=len(skipped), unit="run", disable=not progress,
                       desc=f"sweep {out.name}", file=sys.stderr)
            for fut in as_completed(futures):
                rid, p = futures[fut]
                try:
                    rec = fut.result()
                except Exception as exc:  # the worker died (KilledWorker) or similar
                    rec = {"status": "error", "error": f"{type(exc).__name__}: {exc}"
                           .splitlines()[0], "traceback": traceback.format_exc()}
                rec = {"run_id": rid, "scene": spec.target, "params": p, "code_version": code,
                       **rec, "finished_utc": _now()}
                write_json(_result_path(out, rid), rec)
                session["executed"].append(rid)
                if rec["status"] != "ok":
                    session["failed"].append(rid)
                    bar.write(f"run {rid} {_short(p)} failed: {rec['error']}")
                bar.update(1)
                fut.release()
            bar.close()
            t_compute = time.perf_counter() - t0
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    table = gather(spec, code=code)
    plots = plot_summary(spec, table) if spec.plot else []
    failed = [r["run_id"] for r in table["rows"] if r["status"] == "error"]
    session.update(finished_utc=_now(), wall_s=time.perf_counter() - t_start,
                   compute_s=t_compute)
    write_json(sess_file, session)
    return {"output": str(out), "planned": len(ids), "skipped": skipped,
            "executed": session["executed"], "failed": failed, "wall_s": session["wall_s"],
            "compute_s": t_compute, "workers": nworkers, "numba_threads": nt,
            "code_version": code, "table": table["csv"], "parquet": table.get("parquet"),
            "plots": [str(p) for p in plots]}


def _short(p: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in p.items())


# -------------------------------------------------------------------------- results
def _flatten(d: dict, prefix: str = "") -> dict:
    """Scalars of a nested result dict as ``a.b`` columns (lists are left out)."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        elif isinstance(v, _JSON_SCALARS):
            out[key] = v
    return out


def gather(spec, code: str | None = None) -> dict:
    """Collect the runs of ``spec`` (this code version) into one table on disk.

    One row per planned run, in the spec's order: ``run_id``, ``status`` (``ok``,
    ``error`` or ``missing``), the parameters (a column each), the result's scalars (nested
    keys as ``a.b``), ``wall_s`` and ``error``. Written atomically to ``results.csv``, and
    to ``results.parquet`` when pyarrow is importable. Returns ``{"rows", "columns",
    "csv"[, "parquet"]}``.
    """
    import io

    from upscale.io import atomic_write_text

    if not isinstance(spec, Spec):
        spec = load_spec(spec)
    code = code or code_version()
    rows, metrics = [], {}
    for p in spec.runs:
        rid = run_id(spec.target, p, code)
        rec = _read_record(_result_path(spec.output, rid)) or {"status": "missing"}
        row = {"run_id": rid, "status": rec.get("status", "missing"), **p}
        res = _flatten(rec.get("result") or {})
        for k in res:
            metrics.setdefault(k, None)
        row.update({k: v for k, v in res.items() if k not in p})
        row["wall_s"] = rec.get("wall_s")
        row["error"] = rec.get("error", "")
        rows.append(row)
    columns = ["run_id", "status", *spec.param_names,
               *(k for k in metrics if k not in spec.param_names), "wall_s", "error"]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (_canonical(v) if isinstance(v, list) else
                        repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    csv_path = atomic_write_text(spec.output / "results.csv", buf.getvalue())
    out = {"rows": rows, "columns": columns, "csv": str(csv_path)}
    try:
        import pyarrow
        import pyarrow.parquet as pq
    except ImportError:
        return out
    from upscale.io import atomic_write_bytes

    tab = pyarrow.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows])
    sink = pyarrow.BufferOutputStream()
    pq.write_table(tab, sink)
    out["parquet"] = str(atomic_write_bytes(spec.output / "results.parquet",
                                            sink.getvalue().to_pybytes()))
    return out


def plot_summary(spec: Spec, table: dict) -> list[Path]:
    """Plots of each ``plot.metrics`` result against parameter ``plot.x``.

    Every finished run is a faint dot; the seed mean at each x is a line with error bars of
    one standard deviation over the seeds (``ddof=1``). Runs differing in any parameter
    other than ``x`` and the seed are separate lines. Written to
    ``OUTPUT/plots/METRIC_vs_X.png``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from upscale.io import atomic_write_bytes

    x = spec.plot.get("x")
    metrics = spec.plot.get("metrics", [])
    if x is None or not metrics:
        return []
    others = [n for n in spec.param_names if n not in (x, spec.seed_param)]
    ok = [r for r in table["rows"] if r["status"] == "ok"]
    paths = []
    for m in metrics:
        fig, ax = plt.subplots(figsize=(5.5, 4))
        groups: dict = {}
        for r in ok:
            if isinstance(r.get(m), (int, float)) and isinstance(r.get(x), (int, float)):
                key = tuple(_canonical(r.get(o)) for o in others)
                groups.setdefault(key, []).append((r[x], r[m]))
        for key, pts in groups.items():
            label = ", ".join(f"{o}={json.loads(v)}" for o, v in zip(others, key)) or None
            xs = np.array([p[0] for p in pts], float)
            ys = np.array([p[1] for p in pts], float)
            line = ax.plot(xs, ys, "o", alpha=0.3, ms=3)[0]
            ux = np.unique(xs)
            mean = np.array([ys[xs == u].mean() for u in ux])
            sd = np.array([ys[xs == u].std(ddof=1) if (xs == u).sum() > 1 else 0.0 for u in ux])
            ax.errorbar(ux, mean, yerr=sd, color=line.get_color(), marker="s", capsize=3,
                        label=label)
        ax.set_xlabel(x)
        ax.set_ylabel(m)
        ax.set_title(f"{spec.scene}: {m} (seed mean ± sd)", fontsize=9)
        if any(k for k in groups) and len(groups) > 1:
            ax.legend(fontsize=7)
        fig.tight_layout()
        import io

        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=120)
        plt.close(fig)
        paths.append(atomic_write_bytes(spec.output / "plots" / f"{m}_vs_{x}.png",
                                        buf.getvalue()))
    return paths


# ---------------------------------------------------------------------- command line
def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep", help="run a scene over a grid of parameters on dask.distributed",
        description="Run a sweep declared in SPEC (TOML, YAML or JSON; see "
                    "upscale.experiments.sweep): each run in OUTPUT/runs/ID/result.json, "
                    "finished runs skipped on restart, the table in OUTPUT/results.csv.")
    p.add_argument("spec", type=Path, nargs="?", help="the sweep spec file")
    p.add_argument("--output", type=Path, default=None, help="output folder (default: spec's)")
    p.add_argument("--workers", type=int, default=None,
                   help="LocalCluster workers (default: spec's run.workers, else one per core)")
    p.add_argument("--scheduler", default=None,
                   help="address of a running dask scheduler instead of a LocalCluster")
    p.add_argument("--timeout", type=float, default=None,
                   help="seconds to wait for the scheduler (default 10)")
    p.add_argument("--numba-threads", type=int, default=None,
                   help="numba threads per run (default: cores // workers; 1 on a cluster)")
    p.add_argument("--retry-failed", action="store_true", default=None,
                   help="rerun the runs recorded as failed")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--list-scenes", action="store_true", help="print the scene names and exit")
    p.set_defaults(func=_cli)


def _cli(args) -> int:
    if args.list_scenes:
        for k, v in sorted(SCENES.items()):
            print(f"{k}  {v}")
        return 0
    if args.spec is None:
        raise ValueError("no SPEC; valid: a .toml, .yaml, .yml or .json sweep spec file")
    rep = run_sweep(args.spec, output=args.output, workers=args.workers,
                    scheduler=args.scheduler, timeout=args.timeout,
                    numba_threads=args.numba_threads, retry_failed=args.retry_failed,
                    progress=not args.no_progress)
    print(f"{rep['planned']} runs: {len(rep['skipped'])} already done, "
          f"{len(rep['executed'])} run now, {len(rep['failed'])} failed; table {rep['table']}")
    for rid in rep["failed"]:
        rec = _read_record(_result_path(Path(rep["output"]), rid)) or {}
        print(f"  failed {rid} {_short(rec.get('params', {}))}: {rec.get('error')}")
    return 0
