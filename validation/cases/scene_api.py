"""``scene-api``: every scene through Python and through the command line, and the tube
scene's figures against main's recorded ones.

1. Each scene's quick variant (:data:`upscale.experiments.registry.QUICK`) run as
   ``experiments.NAME(**kw)`` and as ``upscale NAME ...`` in-process (``cli.main``): the
   figures must agree (to 1e-8 relative; the quasi-static SCB solver refactors on a
   wall-time budget, so it agrees to its tolerance, not to round-off).
2. The coarse tube's quasi-static table (pristine (10,10), (17,0), (12,6), 100 Å; with
   ``--vacancy`` the seed's 4-atom-vacancy tubes; coarsening 1-4; ``--quick``: (10,10)
   K = 2) through ``experiments.tension(model="dcbr")`` against main's figures recorded in
   ``validation/baselines/main-99b82f2.json`` (main's ``dcbr-table`` rows): strength within
   1e-4 relative, the modulus's error against the stored LAMMPS reference within 1e-2
   percentage points (main kept that error, not the modulus: 1e-4 relative of the modulus
   moves it by at most 1e-2), the same strain at peak.

The timing of the old load-step loop against the engine's quasi-static path
(``qs_engine_over_old_wall``: the (10,10) K = 2 tube; ``qs_engine_over_old_wall_rows_max``:
the largest over the rows of the table timed alternately, wall and CPU time) was measured
before the old loop was deleted and is read from the same baseline.
"""
from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

from upscale import experiments
from upscale.cli import main as cli_main
from upscale.experiments import registry
from upscale.experiments.result import Result
from validation.registry import case, table

BASELINE = Path(__file__).resolve().parents[1] / "baselines" / "main-99b82f2.json"
#: strength compared with main: tolerance (relative)
TOL = {"strength_GPa": 1e-4}


def _args(p):
    p.add_argument("--vacancy", action="store_true", help="the 4-atom-vacancy tubes' table")
    p.add_argument("--scenes", default=None, help="comma list (default: every quick variant)")


def _same(a, b, rel=1e-8) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b or abs(a - b) <= rel * max(abs(a), abs(b))


def api_equals_cli(names) -> list[dict]:
    from upscale.engine.kernels import set_threads

    rows = []
    set_threads(1)
    for name in names:
        kw = registry.QUICK[name]
        if "progress" in kw or name == "tension":
            kw = {**kw, "progress": False}
        api = getattr(experiments, name.replace("-", "_"))(**kw)
        with tempfile.TemporaryDirectory() as tmp:
            argv = [*registry.argv_of(name, {k: v for k, v in kw.items() if k != "progress"}),
                    "--out", tmp, "--threads", "1", "--quiet"]
            rc = cli_main(argv)
            cli = Result.from_json(Path(tmp) / f"{name.replace('-', '_')}.json") if rc == 0 \
                else None
        keys = [k for k in api.figures if k != "wall_s"]
        ok = cli is not None and all(_same(api.figures[k], cli.figures.get(k, math.nan))
                                     for k in keys)
        rows.append({"scene": name, "figures": len(keys), "cli_rc": rc, "equal": ok})
    return rows


def change_vs_main(vacancy: bool, quick: bool) -> list[dict]:
    base = json.loads(BASELINE.read_text())
    table_rows = base["dcbr-table-vacancy" if vacancy else "dcbr-table"]["rows"]
    rows = []
    for r in table_rows:
        n, m = (int(v) for v in r["tube"].split()[0].strip("()").split(","))
        if quick and ((n, m) != (10, 10) or r["K"] != 2):
            continue
        defects = "v4@0.5@0" if vacancy else ""
        res = experiments.tension(chirality=(n, m), length=100.0, model="dcbr",
                                  coarsening=r["K"], progress=False,
                                  **({"structure": _seed_vacancy_tube(n, m)} if vacancy
                                     else {"defects": defects}))

        kw = {"structure": _seed_vacancy_tube(n, m)} if vacancy else \
            {"chirality": (n, m), "length": 100.0}
        ref = experiments.tension(model="lammps", progress=False, **kw)
        d_s = 100 * (res.figures["strength_GPa"] / r["strength_GPa"] - 1)
        e_mod = 100 * abs(res.figures["youngs_TPa"] / ref.figures["youngs_TPa"] - 1)
        rows.append({"tube": r["tube"], "K": r["K"], "strength_GPa": res.figures["strength_GPa"],
                     "main": r["strength_GPa"], "change_pct": d_s,
                     "modulus_err_pct": e_mod, "main_modulus_err_pct": r["modulus_err_%"],
                     "strain_at_peak": res.figures["strain_at_peak"],
                     "main_strain_at_peak": r["strain_at_peak"],
                     "wall_s": res.meta["wall_s"], "main_wall_s": r["wall_s"]})
    return rows


def _seed_vacancy_tube(n, m):
    from upscale.build import swcnt, vacancy

    return vacancy(swcnt(n, m, length=100.0), n=4)


@case("scene-api", "every scene through Python and the command line (same figures); the "
      "coarse tube's quasi-static table against main's recorded figures", _args)
def scene_api(args) -> dict:
    names = args.scenes.split(",") if args.scenes else list(registry.QUICK)
    rows = api_equals_cli(names)
    print(table(rows))
    changes = change_vs_main(args.vacancy, args.quick)
    print(table(changes, floatfmt=".8g"))
    base = json.loads(BASELINE.read_text())
    ok = sum(r["equal"] for r in rows)
    worst = max(abs(r["change_pct"]) for r in changes)
    worst_mod = max(abs(r["modulus_err_pct"] - r["main_modulus_err_pct"]) for r in changes)
    same_peak = all(r["strain_at_peak"] == r["main_strain_at_peak"] for r in changes)
    res = {"scenes_ok": ok, "scenes": len(rows), "cli_equals_api": ok == len(rows),
           "max_change_vs_main_pct": worst, "modulus_err_change_points_max": worst_mod,
           "strain_at_peak_same": same_peak,
           "qs_engine_over_old_wall": base.get("qs_engine_over_old_wall", {}).get("ratio"),
           **{f"qs_engine_over_old_{k}_rows_max": base.get("qs_engine_over_old_wall_rows",
                                                           {}).get(f"{k}_ratio_max")
              for k in ("wall", "cpu")}}
    res["pass"] = bool(ok == len(rows) and worst <= 100 * TOL["strength_GPa"] and same_peak
                       and worst_mod <= 1e-2 and not args.quick)
    return res
