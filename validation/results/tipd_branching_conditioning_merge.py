"""The dx / dx/2 verdict over the traction ensemble from ``tipd-branching-conditioning`` runs
made one grid at a time: ``python validation/results/tipd_branching_conditioning_merge.py
COARSE.json FINE.json``. Each argument is the JSON of a ``--grids coarse`` or ``--grids fine``
run (or ``both``) at the same ``--dx``; the runs present on both grids are compared as the
case does with ``--grids both`` (median branching position within two horizons, median peak
speed within 10 %, beside the nominal runs alone)."""
import json
import sys

from validation.cases.tipd import _ensemble_verdict


def load(paths):
    per, dx = {}, set()
    for p in paths:
        res = json.load(open(p))["result"]
        dx.add(res["dx_m"])
        for key, bg in res["runs"].items():
            for grid, by_f in bg.items():
                per.setdefault(key, {}).setdefault(grid, {}).update({float(f): v for f, v in by_f.items()})
    if len(dx) != 1:
        raise SystemExit(f"the runs must share one --dx; got {sorted(dx)}")
    return per, dx.pop()


if __name__ == "__main__":
    per, dx = load(sys.argv[1:])
    verdict = _ensemble_verdict(per, 3 * dx)
    for key, e in verdict.items():
        bx = ["none" if v is None else f"{v * 1e3:.2f}" for v in e["median_branching_x_m"]]
        print(f"{key}: median x_b {bx[0]} / {bx[1]} mm, apart {e['median_apart_over_delta']} delta, "
              f"branching fraction {e['branching_fraction']}, median v_max/cR "
              f"{e['median_v_max_over_cR'][0]:.4f} / {e['median_v_max_over_cR'][1]:.4f}, "
              f"agree {e['agree']} (with the mean speed {e['agree_mean_speed']}), nominal runs agree "
              f"{e['agree_nominal']}, paired {e['paired_agree']} (position {e['paired_agree_position']})")
    print(json.dumps({"dx_m": dx, "ensemble": verdict}, default=float))
