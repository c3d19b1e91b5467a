"""cProfile of a quasi-static SCB run (alpha = 0, r_s = 39.26 dx). Usage: prof.py DX MAX_SOLVES

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import cProfile, pstats, time, sys
from upscale.experiments.scenes.scb import run_scb
dx = float(sys.argv[1]); n = int(sys.argv[2])
run_scb(0.0, dx=2e-3, r_s=0.0785, max_equilibria=3)   # compile
t = time.perf_counter(); pr = cProfile.Profile(); pr.enable()
r = run_scb(0.0, dx=dx, r_s=39.26 * dx, max_equilibria=n, stop_fraction=0.5)
pr.disable()
c = r["curve"]
print("wall", time.perf_counter() - t, "equilibria", len(c["load_N"]), "P max", r["P_c_kN"], "stop", c["stop_reason"])
print("split", c["time_split_s"])
pstats.Stats(pr).sort_stats("cumulative").print_stats(28)
