"""Baselines: each case's last accepted figures with their provenance.

``validation/baselines/CASE.json`` is written by ``python -m validation CASE --record`` and
holds ``{"case", "figures", "pass", "provenance"}``; the provenance says where the figures
come from (commit, date, machine, load average, the exact command, wall time, versions), so
a reader can tell which figure is current. A run that raised is never recorded (a baseline
records a run that finished); a finished run that misses its target is recorded as it is,
with ``pass: false``, so the report shows the miss.

A file holding several cases (``{"provenance": ..., "CASE": {...}, ...}``, as main's table
``main-99b82f2.json``) is read too: each key that names a registered case is a baseline of
that case, under the file's provenance; a ``CASE.json`` of the case itself takes precedence.

Staleness: a baseline is stale when a file its case imports (the case's module and every
module of ``upscale``, ``potentials`` and ``validation`` it reaches, imports inside functions
included; the driver's own modules aside) changed in git between the baseline's commit and
``HEAD``. Uncommitted changes do not count (a baseline is judged against commits); those of
the case's files at recording time are listed in its provenance.
"""
from __future__ import annotations

import ast
import functools
import json
import os
import platform
import subprocess
import time
from pathlib import Path

from upscale.io import versions, write_json

ROOT = Path(__file__).resolve().parents[1]
BASELINES = ROOT / "validation" / "baselines"
PACKAGES = ("upscale", "potentials", "validation")
#: the driver: imported by every case, computes none of their figures, so not a staleness cause
DRIVER = {"validation/__init__.py", "validation/__main__.py", "validation/registry.py",
          "validation/baseline.py", "validation/report.py", "validation/report_html.py",
          "validation/cases/__init__.py"}
REQUIRED = ("commit", "date", "machine", "command")  # provenance a baseline must carry
ALIASES = {"date": ("date", "date_utc"), "command": ("command", "commands")}


class BaselineError(ValueError):
    """A baseline file that does not parse or lacks provenance (one-line message)."""


def git(*args: str) -> str:
    """Output of ``git ARGS`` in the repository ('' when git fails)."""
    try:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return out.stdout.strip() if out.returncode == 0 else ""


def provenance(command: list[str], wall_s: float, module: str | None = None) -> dict:
    """Where a run's figures come from: commit, the files the case imports that differ from
    it (``uncommitted``), UTC date, machine (``uname``), 1/5/15-minute load average,
    command, wall time, versions."""
    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    changed = {line[3:] for line in git("status", "--porcelain", "--untracked-files=all")
               .splitlines()}
    deps = dependencies(module) if module else frozenset()
    return {"commit": commit, "uncommitted": sorted(deps & changed),
            "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "machine": " ".join(platform.uname()),
            "load": [round(x, 2) for x in os.getloadavg()],
            "command": " ".join(command), "wall_s": round(float(wall_s), 3),
            "versions": versions()}


def record(case: str, result: dict, command: list[str], wall_s: float,
           module: str | None = None) -> Path:
    """Write ``validation/baselines/CASE.json`` atomically from a finished run's ``result``
    (``module``: the case's module, whose imports' uncommitted changes are listed)."""
    body = {"case": case, "figures": result, "pass": result.get("pass"),
            "provenance": provenance(command, wall_s, module)}
    return write_json(BASELINES / f"{case}.json", body)


def _check_provenance(path: Path, prov) -> dict:
    if not isinstance(prov, dict):
        raise BaselineError(f"baseline {path.name}: no 'provenance' object")
    out = dict(prov)
    for key in REQUIRED:
        found = [prov[k] for k in ALIASES.get(key, (key,)) if prov.get(k)]
        if not found:
            raise BaselineError(f"baseline {path.name}: provenance lacks {key!r}")
        out[key] = found[0] if not isinstance(found[0], list) else "; ".join(map(str, found[0]))
    return out


def read(path: Path, names) -> dict[str, dict]:
    """Baselines in one file, ``{case: {"figures", "pass", "provenance", "file"}}``, for the
    registered case ``names``. Raises :class:`BaselineError` naming the file."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as e:
        raise BaselineError(f"baseline {Path(path).name} does not parse: {e}") from None
    if not isinstance(data, dict):
        raise BaselineError(f"baseline {Path(path).name}: not a JSON object")
    prov = _check_provenance(Path(path), data.get("provenance"))
    rel = str(Path(path).resolve().relative_to(ROOT))
    if "case" in data:
        if not isinstance(data.get("figures"), dict):
            raise BaselineError(f"baseline {Path(path).name}: no 'figures' object")
        return {data["case"]: {"figures": data["figures"], "pass": data.get("pass"),
                               "provenance": prov, "file": rel}}
    return {k: {"figures": v, "pass": v.get("pass"), "provenance": prov, "file": rel}
            for k, v in data.items() if k in names and isinstance(v, dict)}


def load_all(names) -> dict[str, dict]:
    """Every baseline of the registered cases ``names``; ``CASE.json`` before shared files."""
    files = sorted(BASELINES.glob("*.json"))
    own = [p for p in files if p.stem in names]
    shared = [p for p in files if p.stem not in names]
    out: dict[str, dict] = {}
    for p in shared + own:  # later files win: a case's own file over a shared table
        out.update(read(p, names))
    return out


# ------------------------------------------------------------------------ staleness
def module_file(name: str) -> Path | None:
    """Source file of project module ``name`` (a package's ``__init__.py``), or None."""
    base = ROOT.joinpath(*name.split("."))
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if p.is_file():
            return p
    return None


@functools.lru_cache(maxsize=None)
def _imports(path: Path, name: str) -> frozenset[str]:
    """Project modules imported anywhere in ``path`` (module ``name``), relative ones resolved."""
    tree = ast.parse(path.read_text(), str(path))
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                base = ".".join(p for p in [*parts, base] if p)
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names)
    return frozenset(m for m in found if m.split(".")[0] in PACKAGES)


@functools.lru_cache(maxsize=None)
def dependencies(module: str) -> frozenset[str]:
    """Repository paths of ``module`` and every project module it reaches by import
    (parent packages' ``__init__`` included, as Python runs them), the driver's aside."""
    seen: dict[str, Path] = {}
    todo = [module]
    while todo:
        name = todo.pop()
        parts = name.split(".")
        for i in range(1, len(parts) + 1):
            sub = ".".join(parts[:i])
            if sub in seen:
                continue
            path = module_file(sub)
            if path is None:
                continue
            seen[sub] = path
            todo.extend(_imports(path, sub))
    return frozenset(str(p.relative_to(ROOT)) for p in seen.values()) - DRIVER


def changed_since(commit: str) -> set[str] | None:
    """Paths changed in git between ``commit`` and HEAD, or None when git does not know it."""
    if not git("rev-parse", "--verify", "--quiet", f"{commit.split('-')[0]}^{{commit}}"):
        return None
    return set(git("diff", "--name-only", commit.split("-")[0], "HEAD").splitlines())


def stale_files(deps: set[str], commit: str, cache: dict) -> list[str] | None:
    """Files of ``deps`` changed after ``commit`` (sorted); None when the commit is unknown."""
    if commit not in cache:
        cache[commit] = changed_since(commit)
    changed = cache[commit]
    return None if changed is None else sorted(deps & changed)
