"""cProfile of one quasi-static SCB run with the default (principal) criterion: P_c, equilibria,
time split and the top functions. Usage: prof05.py ALPHA DX R_S [MAX_SOLVES]

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import cProfile
import json
import pstats
import sys
import time

from upscale.experiments.scenes.scb import run_scb

al, dx, rs = map(float, sys.argv[1:4])
n = int(sys.argv[4]) if len(sys.argv) > 4 else 600
run_scb(0.0, dx=2e-3, r_s=4e-3, max_equilibria=2)   # numba compilation outside the profile
t = time.perf_counter()
pr = cProfile.Profile()
pr.enable()
r = run_scb(al, dx=dx, r_s=rs, max_equilibria=n, stop_fraction=0.5)
pr.disable()
c = r["curve"]
print(json.dumps({"alpha": al, "dx_mm": dx * 1e3, "r_s_mm": rs * 1e3, "particles": r["scene"]["particles"],
                  "P_c_kN": r["P_c_kN"], "equilibria": len(c["load_N"]), "stop": c["stop_reason"],
                  "wall_s": time.perf_counter() - t, "init_deg": r["initiation_angle_deg"],
                  "split": c["time_split_s"]}, default=float), flush=True)
pstats.Stats(pr).sort_stats("tottime").print_stats(18)
