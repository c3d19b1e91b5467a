"""P_c, the first failure load and the initiation angle of quasi-static SCB runs, free or front growth.
Usage: growth.py ALPHA,DX,R_S[,GROWTH[,M]] [...]   (GROWTH: free (default) or front; M = delta / dx, default 3)

Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import json
import sys

from upscale.experiments.scenes.scb import run_scb

for spec in sys.argv[1:]:
    p = spec.split(",")
    al, dx, rs = map(float, p[:3])
    growth = p[3] if len(p) > 3 else "free"
    m = float(p[4]) if len(p) > 4 else 3.0
    r = run_scb(al, dx=dx, r_s=rs, m=m, stop_fraction=0.5, max_equilibria=800, growth=growth)
    c = r["curve"]
    first = next((c["load_N"][i - 1] / 1e3 for i, b in enumerate(c["broken"]) if b > 0), None)
    print(json.dumps({"alpha": al, "dx_mm": dx * 1e3, "r_s_mm": rs * 1e3, "m": m, "growth": growth,
                      "P_c_kN": round(r["P_c_kN"], 4), "first_failure_kN": first and round(first, 4),
                      "initiation_deg": r["initiation_angle_deg"], "equilibria": len(c["load_N"]),
                      "stop": c["stop_reason"], "wall_s": round(r["wall_s"], 1)}), flush=True)
