"""``python -m validation report``: every case on one page, against its target and baseline.

``--run none`` reads the baselines (:mod:`validation.baseline`) and runs nothing; ``quick``
runs each case's ``--quick`` variant where it has one (a case without one shows its
baseline); ``full`` runs every case. Each run is its own process (``python -m validation
CASE``, its output in ``OUT/logs/CASE.log``), so a case that raises is shown as raised and
the others still run.

Written to ``--outdir`` (default ``validation/out/report/``): ``report.html``, one
self-contained page (inline CSS, the PNG plots of each case's output folder
``validation/out/CASE/`` embedded as base64), and ``report.md``, the same table in Markdown.
``validation/README.md`` is regenerated from the baselines on every call. The last line of
output is one JSON object: ``cases``, ``passed``, ``failed``, ``stale``, ``wall_s`` (and
``no_baseline``, ``raised``).

A case's verdict is its fresh run's ``pass`` when it ran, else its baseline's; a case with
neither has no verdict and counts in neither ``passed`` nor ``failed``.
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

from upscale.io import atomic_write_text
from validation import baseline as bl
from validation.report_html import markdown, page, readme

OUT = bl.ROOT / "validation" / "out"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", choices=("none", "quick", "full"), default="none",
                   help="none: read the baselines only; quick: run each case's --quick variant "
                        "where it has one; full: run every case (default: %(default)s)")
    p.add_argument("--cases", default=None,
                   help="comma list of case names (default: every registered case)")
    p.add_argument("--outdir", type=Path, default=OUT / "report",
                   help="where the page and the summary go (default: %(default)s)")


def select(cases: dict, spec: str | None) -> list[str]:
    """Case names from the ``--cases`` list; ValueError naming an unknown one."""
    if not spec:
        return sorted(cases)
    names = [s.strip() for s in spec.split(",") if s.strip()]
    unknown = [n for n in names if n not in cases]
    if unknown:
        raise ValueError(f"unknown case {unknown[0]!r} in --cases (see python -m validation --list)")
    return names


def run_one(name: str, quick: bool, logs: Path) -> dict:
    """Run one case in its own process; ``{"figures", "pass", "wall_s", "status"}``."""
    cmd = [sys.executable, "-m", "validation", name] + (["--quick"] if quick else [])
    result_file = OUT / name / f"{name}.json"
    t0 = time.time()
    with open(logs / f"{name}.log", "w") as log:
        rc = subprocess.run(cmd, cwd=bl.ROOT, stdout=log, stderr=subprocess.STDOUT).returncode
    wall = time.time() - t0
    fresh = result_file.is_file() and result_file.stat().st_mtime >= t0
    if rc not in (0, 1) or not fresh:
        return {"status": f"raised (exit {rc}, see logs/{name}.log)", "wall_s": wall,
                "figures": {}, "pass": None, "command": " ".join(["python", *cmd[1:]])}
    figures = json.loads(result_file.read_text())["result"]
    return {"status": "ran" + (" --quick" if quick else ""), "wall_s": wall, "figures": figures,
            "pass": figures.get("pass"), "command": " ".join(["python", *cmd[1:]])}


def plots(name: str) -> list[Path]:
    """PNG files in the case's output folder (newest first, at most 12)."""
    folder = OUT / name
    found = sorted(folder.glob("*.png"), key=lambda p: -p.stat().st_mtime) if folder.is_dir() else []
    return found[:12]


def target(c) -> str | None:
    """The case's stated target: as registered, else a ``(target: ...)`` in its summary."""
    if c.target:
        return c.target
    m = re.search(r"\(target:\s*([^)]*)\)", c.summary)
    return m.group(1) if m else None


def entry(c, base: dict | None, fresh: dict | None, stale_cache: dict) -> dict:
    """Everything the page shows of one case."""
    e = {"name": c.name, "summary": c.summary, "target": target(c), "module": c.module,
         "quick": c.has_quick(), "baseline": base, "run": fresh, "plots": plots(c.name),
         "stale": None}
    if base:
        deps = bl.dependencies(c.module)
        e["stale"] = bl.stale_files(deps, str(base["provenance"]["commit"]), stale_cache)
    src = fresh if fresh and fresh["status"].startswith("ran") else base
    e["pass"] = src.get("pass") if src else None
    e["raised"] = bool(fresh) and not fresh["status"].startswith("ran")
    return e


def counts(entries: list[dict], wall: float) -> dict:
    is_stale = [e for e in entries if e["baseline"] and (e["stale"] is None or e["stale"])]
    return {"cases": len(entries), "passed": sum(e["pass"] is True for e in entries),
            "failed": sum(e["pass"] is False for e in entries), "stale": len(is_stale),
            "no_baseline": sum(e["baseline"] is None for e in entries),
            "raised": sum(e["raised"] for e in entries), "wall_s": round(wall, 1)}


def main(args, cases: dict) -> int:
    t0 = time.perf_counter()
    try:
        names = select(cases, args.cases)
        baselines = bl.load_all(set(cases))
    except ValueError as e:  # BaselineError is a ValueError
        print(f"python -m validation report: {e}", file=sys.stderr)
        return 2
    logs = args.outdir / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    entries, stale_cache = [], {}
    for name in names:
        c = cases[name]
        fresh = None
        if args.run == "full" or (args.run == "quick" and c.has_quick()):
            print(f"[report] {name} ...", file=sys.stderr, flush=True)
            fresh = run_one(name, args.run == "quick", logs)
            print(f"[report] {name}: {fresh['status']}, {fresh['wall_s']:.0f} s", file=sys.stderr)
        entries.append(entry(c, baselines.get(name), fresh, stale_cache))
    summary = counts(entries, time.perf_counter() - t0)
    head = {"run": args.run, "commit": bl.git("rev-parse", "--short", "HEAD"),
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), **summary}
    html = page(head, entries)
    atomic_write_text(args.outdir / "report.html", html)
    atomic_write_text(args.outdir / "report.md", markdown(head, entries))
    from_baselines = [entry(cases[n], baselines.get(n), None, stale_cache) for n in sorted(cases)]
    atomic_write_text(bl.ROOT / "validation" / "README.md", readme(from_baselines))
    print(f"wrote {args.outdir / 'report.html'}, {args.outdir / 'report.md'}, validation/README.md",
          file=sys.stderr)
    print(json.dumps(summary))
    return 0
