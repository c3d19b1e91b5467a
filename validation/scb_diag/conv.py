"""Quasi-static SCB runs: P_c, solves, time split. Usage: conv.py ALPHA,DX,R_S [...]

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import sys, json, time
from upscale.experiments.scenes.scb import run_scb
out = []
for spec in sys.argv[1:]:
    al, dx, rs = map(float, spec.split(","))
    r = run_scb(al, dx=dx, r_s=rs, stop_fraction=0.5, max_equilibria=400)
    c = r["curve"]
    row = {"alpha": al, "dx_mm": dx * 1e3, "r_s_mm": rs * 1e3, "P_c_kN": r["P_c_kN"], "equilibria": len(c["load_N"]),
           "stop": c["stop_reason"], "wall_s": r["wall_s"], "split": c["time_split_s"], "init_deg": r["initiation_angle_deg"]}
    print(json.dumps(row), flush=True)
