"""bench-scb: the SCB fracture table's run time against main's, and the memory of the
elastic solve at dx = 0.25 mm (the issue on heavy scenes).

Every angle is driven by the library's quasi-static fracture until the load has fallen below
``--stop-fraction`` (0.1) of its peak ("full crack"), against main's recorded run of the
same table (``main-99b82f2.json``, key ``bench-scb``: dx = 0.5 mm, r_s = 1 mm, one core).
``--elastic-025`` runs the elastic solve at dx = 0.25 mm alone in a fresh process, so that
its peak resident memory is its own.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from validation.registry import case

#: the eight crack angles of the SCB table (seed 004 Table 6.2), degrees, in main's order
ALPHAS = (0.0, 30.0, 50.0, 10.0, 20.0, 40.0, 43.0, 47.0)
MAIN = Path(__file__).resolve().parents[1] / "baselines" / "main-99b82f2.json"
TARGET_SPEEDUP, TARGET_P_C_PCT, TARGET_ELASTIC_GB = 10.0, 0.5, 4.0

_ELASTIC = """
import json, resource, sys, time
from upscale.experiments.scenes.scb import SCBScene
t = time.perf_counter()
sc = SCBScene(0.0, dx=2.5e-4)
st, P = sc.elastic()
k = sc.stress_intensity(st, P, method="williams", n_terms=10)
print(json.dumps({"particles": sc.system.n, "wall_s": time.perf_counter() - t, "Y_I": k["Y_I"],
                  "peak_GB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6}))
"""


def _args(p):
    p.add_argument("--dx", type=float, default=None, help="spacing in m (default 5e-4; quick 1e-3)")
    p.add_argument("--alphas", default=None, help="comma list of angles (default the eight; quick 0,30)")
    p.add_argument("--r-s", type=float, default=1e-3, help="r_s in m (default %(default)s)")
    p.add_argument("--stop-fraction", type=float, default=0.1,
                   help="full crack: the run ends when the load falls below this fraction of its peak")
    p.add_argument("--u-max", type=float, default=1e-2, help="largest load-point displacement, m")
    p.add_argument("--max-equilibria", type=int, default=3000, help="cap on the solves of one run")
    p.add_argument("--elastic-025", action="store_true",
                   help="also the elastic solve at dx = 0.25 mm alone: its peak memory")


def main_figures(dx, r_s, stop_fraction, alphas):
    """main's recorded (wall s, CPU s, P_c kN) per angle in ``alphas``, or None where that
    run is not comparable (another dx, r_s or stop fraction, or an angle it did not run)."""
    r = json.loads(MAIN.read_text())["bench-scb"]
    same = (np.isclose(r["dx_m"], dx) and np.isclose(r["r_s_m"], r_s)
            and np.isclose(r["stop_fraction"], stop_fraction))
    if not same or not all(np.isclose(r["alpha_deg"], a).any() for a in alphas):
        return None
    k = [int(np.flatnonzero(np.isclose(r["alpha_deg"], a))[0]) for a in alphas]
    return {key: [r[src][i] for i in k] for key, src in
            (("wall_s", "wall_s_per_angle"), ("cpu_s", "cpu_s_per_angle"), ("P_c_kN", "P_c_kN"))}


def _angle(al, dx, args) -> dict:
    from upscale.experiments.scenes.scb import SCBScene

    w0, c0 = time.perf_counter(), time.process_time()
    sc = SCBScene(al, dx=dx, r_s=args.r_s)
    t_scene = time.perf_counter() - w0
    st, curve = sc.fracture(stop_fraction=args.stop_fraction, max_equilibria=args.max_equilibria,
                            u_max=args.u_max)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    sv = curve.time_split_s["solver"]
    split = {"scene": t_scene, "assembly": sv["assembly_s"], "factorisation": sv["factor_s"],
             "cg": sv["cg_s"], "residual": sv["residual_s"], "failure": curve.time_split_s["failure"]}
    split["other"] = wall - sum(split.values())
    P_c = curve.peak[0]
    return {"alpha": al, "particles": sc.system.n, "wall s": wall, "cpu s": cpu,
            "equilibria": len(curve.load), "stop": curve.stop_reason,
            "final/peak": float(curve.load[-1] / P_c), "P_c kN": P_c / 1e3,
            **{f"{k} %": 100 * v / wall for k, v in split.items()}}


def _elastic_025() -> dict:
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", _ELASTIC], capture_output=True, text=True,
                         env=env, check=True).stdout.strip().splitlines()[-1]
    return json.loads(out)


@case("bench-scb", "SCB speed: the eight angles to full crack at dx = 0.5 mm against main's recorded "
      "run; the elastic solve's memory at 0.25 mm", _args)
def bench_scb(args):
    import cvxopt.cholmod  # noqa: F401  (its BLAS loaded before the limit, so the limit holds)
    from threadpoolctl import threadpool_limits
    from tqdm import tqdm

    from upscale.engine.kernels import set_threads

    set_threads(1)
    quick = args.quick
    dx = args.dx or (1e-3 if quick else 5e-4)
    alphas = [float(a) for a in args.alphas.split(",")] if args.alphas else \
        ([0.0, 30.0] if quick else list(ALPHAS))
    load0 = os.getloadavg()[0]
    with threadpool_limits(limits=1):
        rows = [_angle(al, dx, args) for al in tqdm(alphas, desc="bench-scb", unit="angle")]
    base = main_figures(dx, args.r_s, args.stop_fraction, alphas)
    for i, r in enumerate(rows):
        r["main wall s"] = base["wall_s"][i] if base else None
        r["speed-up"] = base["wall_s"][i] / r["wall s"] if base else None
        r["P_c change %"] = 100 * (r["P_c kN"] / base["P_c_kN"][i] - 1) if base else None
    total, total_cpu = sum(r["wall s"] for r in rows), sum(r["cpu s"] for r in rows)
    res = {"dx_m": dx, "r_s_m": args.r_s, "stop_fraction": args.stop_fraction, "alpha_deg": alphas,
           "table_wall_s": total, "table_cpu_s": total_cpu,
           "wall_s_per_angle": [r["wall s"] for r in rows], "P_c_kN": [r["P_c kN"] for r in rows],
           "equilibria": [r["equilibria"] for r in rows],
           "full_crack": all(r["stop"] == "load dropped" for r in rows),
           "loadavg_start": load0, "loadavg_end": os.getloadavg()[0],
           "speedup_vs_main": sum(base["wall_s"]) / total if base else None,
           "cpu_speedup_vs_main": sum(base["cpu_s"]) / total_cpu if base else None,
           "P_c_change_pct_max": max(abs(r["P_c change %"]) for r in rows) if base else None,
           "rows": rows}
    res["pass"] = res["full_crack"]
    if base:
        res["pass"] = bool(res["full_crack"] and res["speedup_vs_main"] >= TARGET_SPEEDUP
                           and res["P_c_change_pct_max"] <= TARGET_P_C_PCT)
    if args.elastic_025:
        el = _elastic_025()
        res.update(elastic_025mm_peak_GB=el["peak_GB"], elastic_025mm_wall_s=el["wall_s"],
                   elastic_025mm_Y_I=el["Y_I"])
        res["pass"] = bool(res["pass"] and el["peak_GB"] <= TARGET_ELASTIC_GB)
    return res
