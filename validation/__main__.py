"""``python -m validation --list`` | ``python -m validation CASE [--quick] [--record] [options]``
| ``python -m validation report [--run none|quick|full] [--cases a,b,...]``."""
from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

from validation.registry import discover, is_rows, table

PROG = "python -m validation"


def _parser(cases) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__)
    parser.add_argument("--list", action="store_true", help="list the cases, one a line")
    sub = parser.add_subparsers(dest="case", metavar="CASE")
    for name, c in sorted(cases.items()):
        p = sub.add_parser(name, help=c.summary.replace("%", "%%"), description=c.summary)
        p.add_argument("--quick", action="store_true", help="reduced version, about a minute")
        p.add_argument("--record", action="store_true",
                       help="write the figures as the case's baseline, validation/baselines/"
                            f"{name}.json, with their provenance (refused if the run raises)")
        p.add_argument("--outdir", type=Path, default=Path("validation/out") / name,
                       help="where plots and the JSON result go (default: %(default)s)")
        if c.add_arguments:
            c.add_arguments(p)
    from validation.report import add_arguments

    add_arguments(sub.add_parser("report", help="one HTML page (and a Markdown summary) of "
                                 "every case against its target and baseline"))
    return parser


def run_case(c, args, argv) -> int:
    """Run case ``c``; write its JSON, print it on the last line; record it with ``--record``."""
    from upscale.io import versions, write_json

    args.outdir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        result = dict(c.run(args))
    except Exception as e:
        if not args.record:
            raise
        traceback.print_exc()
        print(f"{PROG}: {c.name} raised {type(e).__name__}; not recorded (a baseline records a "
              "run that finished)", file=sys.stderr)
        return 2
    result.setdefault("case", c.name)
    result.setdefault("quick", bool(args.quick))
    result["case_wall_s"] = round(time.perf_counter() - t0, 3)
    for key, rows in result.items():  # every table the case returns, its scalar columns
        if is_rows(rows):
            cols = [k for k in dict.fromkeys(k for r in rows for k in r)
                    if not isinstance(rows[0].get(k), (list, dict))]
            print(f"{key}:\n{table(rows, cols, floatfmt='.4g')}")
    write_json(args.outdir / f"{c.name}.json", {"result": result, "versions": versions()})
    if args.record:
        from validation.baseline import record

        path = record(c.name, result, [PROG, *argv], result["case_wall_s"], c.module)
        print(f"recorded {path}", file=sys.stderr)
    print(json.dumps(result, default=float))
    return 0 if result.get("pass", True) is not False else 1


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    cases = discover()
    if argv and not argv[0].startswith("-") and argv[0] not in cases and argv[0] != "report":
        print(f"{PROG}: unknown case {argv[0]!r} (see {PROG} --list)", file=sys.stderr)
        return 2
    args = _parser(cases).parse_args(argv)
    if args.list or not args.case:
        width = max(len(n) for n in cases) if cases else 0
        for name, c in sorted(cases.items()):
            print(f"{name.ljust(width)}  {c.summary}")
        return 0
    if args.case == "report":
        from validation.report import main as report

        return report(args, cases)
    if args.record and args.quick:
        print(f"{PROG}: --record with --quick refused: a baseline records the case's full run",
              file=sys.stderr)
        return 2
    return run_case(cases[args.case], args, argv)


if __name__ == "__main__":
    sys.exit(main())
