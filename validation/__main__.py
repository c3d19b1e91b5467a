"""``python -m validation --list`` | ``python -m validation CASE [--quick] [options]``."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from validation.registry import discover


def main(argv=None) -> int:
    cases = discover()
    parser = argparse.ArgumentParser(prog="python -m validation", description=__doc__)
    parser.add_argument("--list", action="store_true", help="list the cases, one a line")
    sub = parser.add_subparsers(dest="case", metavar="CASE")
    for name, c in sorted(cases.items()):
        p = sub.add_parser(name, help=c.summary.replace("%", "%%"), description=c.summary)
        p.add_argument("--quick", action="store_true", help="reduced version, about a minute")
        p.add_argument("--outdir", type=Path, default=Path("validation/out") / name,
                       help="where plots and the JSON result go (default: %(default)s)")
        if c.add_arguments:
            c.add_arguments(p)
    args = parser.parse_args(argv)
    if args.list or not args.case:
        width = max(len(n) for n in cases) if cases else 0
        for name, c in sorted(cases.items()):
            print(f"{name.ljust(width)}  {c.summary}")
        return 0
    from upscale.io import versions, write_json

    args.outdir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    result = cases[args.case].run(args)
    result = dict(result)
    result.setdefault("case", args.case)
    result.setdefault("quick", bool(args.quick))
    result["case_wall_s"] = round(time.perf_counter() - t0, 3)
    write_json(args.outdir / f"{args.case}.json", {"result": result, "versions": versions()})
    print(json.dumps(result, default=float))
    return 0 if result.get("pass", True) is not False else 1


if __name__ == "__main__":
    sys.exit(main())
