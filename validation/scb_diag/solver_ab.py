"""Same-process before/after timing of the quasi-static solver on one SCB run: P_c, CPU and wall
time, solver counters per configuration. Usage: solver_ab.py ALPHA DX CONF [CONF ...], CONF =
'old' (central differences, fixed inner tolerance, one factorisation), 'new' (the defaults) or
k=v,k=v (Equilibrium options); MAXEQ=n in the environment caps the equilibria (default 600).

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import sys, time, json
import upscale.engine.quasistatic as qs
al, dx = float(sys.argv[1]), float(sys.argv[2])
confs = sys.argv[3:]
orig = qs.Equilibrium.__init__
CUR = {}
def init(self, *a, **k):
    k.update(CUR); orig(self, *a, **k)
qs.Equilibrium.__init__ = init
from upscale.experiments.scenes.scb import run_scb
run_scb(0.0, dx=2e-3, r_s=4e-3, max_equilibria=2)
res = []
for c in confs:
    CUR.clear()
    if c == "old": CUR.update(difference="central", refactor="never", forcing="fixed")
    elif c != "new":
        for kv in c.split(","):
            k, v = kv.split("="); CUR[k] = v
    t = time.perf_counter(); c0 = time.process_time()
    r = run_scb(al, dx=dx, r_s=1e-3, stop_fraction=0.5, max_equilibria=int(__import__("os").environ.get("MAXEQ", "600")))
    cu = r["curve"]
    d = {"conf": c, "P_c_N": r["P_c_N"], "neq": len(cu["load_N"]), "init": r["initiation_angle_deg"], "broken": r["broken_bonds"],
         "wall": time.perf_counter() - t, "cpu": time.process_time() - c0, "solver": cu["time_split_s"]["solver"]}
    res.append(d)
    print(json.dumps(d, default=float), flush=True)
b = res[0]
for d in res[1:]:
    print(f"{d['conf']}: P_c rel diff {d['P_c_N']/b['P_c_N']-1:.2e}, cpu ratio {b['cpu']/d['cpu']:.2f}, wall ratio {b['wall']/d['wall']:.2f}")
