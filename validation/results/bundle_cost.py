"""Whole-run cost of the 7-tube vacancy bundle, LAMMPS against the engine, in one process:
LAMMPS's full-atomistic bundle (the references' protocol and default seed) pulled until
its run stops (runaway-atom halt at failure, or ``--max-strain``), then the mixed bundle
on the engine (outer tubes ``dcbr:K``, vdW every 4 steps, lumped sites between coarse
tubes) pulled to the strain LAMMPS reached; wall and CPU time of each whole run (engine:
scene set-up included). ``--integrators verlet,respa``: each engine run with velocity
Verlet at 1 fs (vdW held 4 steps) and with multiple time stepping (``--inner`` 1 fs steps
per outer step, the vdW in the slow group). Figures in
validation/out/bundle_cost_<N>-<M>.json.

    python validation/results/bundle_cost.py [--chirality 10,10] [--coarsening 2,4]
        [--integrators verlet,respa] [--inner 5] [--thermostat per-tube] [--chain 3]
        [--settle 1]
"""
import argparse
import json
import os
import time
from pathlib import Path

from upscale.experiments.scenes.bundle import BundleScene, dynamic_tension, parse_specs
from validation.cases.references import build_structure
from upscale.experiments.lammps.tension import dynamic_tension as lammps_tension

p = argparse.ArgumentParser()
p.add_argument("--chirality", default="10,10")
p.add_argument("--coarsening", default="2,4")
p.add_argument("--max-strain", type=float, default=0.16)
p.add_argument("--integrators", default="verlet")
p.add_argument("--inner", type=int, default=5)
p.add_argument("--thermostat", default="bundle", choices=("bundle", "per-tube"))
p.add_argument("--chain", type=int, default=3)
p.add_argument("--settle", type=float, default=0.0)
a = p.parse_args()
n, m = (int(v) for v in a.chirality.split(","))
out = {"chirality": [n, m], "load_start": list(os.getloadavg()), "runs": []}
atoms = build_structure({"name": f"dyn_{n}-{m}_vac4_bundle7", "protocol": "dynamic",
                         "chirality": (n, m), "vacancy": True, "length": 150.0, "ntubes": 7})
t0, c0 = time.perf_counter(), time.process_time()
lam = lammps_tension(atoms, "tersoff:BNC.tersoff", cutoff="step", max_strain=a.max_strain)
row = {"run": "LAMMPS", "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
       "steps": lam["timing_s"]["steps"], "timing_s": lam["timing_s"],
       "final_strain": (lam.get("aborted") or {}).get("strain", lam["curve"]["strain"][-1]),
       "strength_GPa": lam["strength_GPa"], "load_end": list(os.getloadavg())}
out["runs"].append(row)
print(row, flush=True)
strain_end = row["final_strain"]
runs = [(float(k), i) for k in a.coarsening.split(",") for i in a.integrators.split(",")]
for K, integ in runs:
    t0, c0 = time.perf_counter(), time.process_time()
    scene = BundleScene.create((n, m), 150.0, parse_specs(None, 7, K),
                               vdw_every=1 if integ == "respa" else 4, coarse_pairs="sites")
    r = dynamic_tension(scene, max_strain=strain_end, progress=False, integrator=integ,
                        inner=a.inner, thermostat=a.thermostat, chain=a.chain,
                        settle_ps=a.settle)
    row = {"run": f"engine K={K:g} {integ}" + (f" {a.inner}x1 fs" if integ == "respa" else "")
           + f", thermostat {a.thermostat}, chain {a.chain}, settle {a.settle:g} ps",
           "wall_s": time.perf_counter() - t0,
           "cpu_s": time.process_time() - c0, "steps": r["timing_s"]["steps"],
           "timing_s": r["timing_s"], "final_strain": r["curve"]["strain"][-1],
           "strength_GPa": r["strength_GPa"], "load_end": list(os.getloadavg())}
    out["runs"].append(row)
    print(row, flush=True)
lw, lc = out["runs"][0]["wall_s"], out["runs"][0]["cpu_s"]
for r in out["runs"][1:]:
    r["wall_ratio"] = lw / r["wall_s"]
    r["cpu_ratio"] = lc / r["cpu_s"]
print(json.dumps(out, indent=1))
Path("validation/out").mkdir(parents=True, exist_ok=True)
json.dump(out, open(f"validation/out/bundle_cost_{n}-{m}.json", "w"), indent=1)
