"""Why the bundle's peak sample moves under multiple time stepping: the (10,10) K2 bundle
pulled with several integrator settings on the same thermal seed(s), per-tube stress and
kinetic temperature curves side by side around the peak, against the LAMMPS seeds.

    python validation/results/bundle_respa_peak.py [--seeds 4928459] [--max-strain 0.115]
        [--runs verlet:1,respa:5]

``--runs``: comma-separated ``integrator:vdw_every`` (verlet) or ``respa:inner`` entries.
Writes ``validation/results/bundle_respa_peak.json`` (curves of every run) and prints per
run the samples around the central tube's first drop.
"""
import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from upscale.experiments.scenes.bundle import BundleScene, dynamic_tension, parse_specs

p = argparse.ArgumentParser()
p.add_argument("--chirality", default="10,10")
p.add_argument("--coarsening", type=float, default=2.0)
p.add_argument("--seeds", default="4928459")
p.add_argument("--max-strain", type=float, default=0.115)
p.add_argument("--runs", default="verlet:1,respa:5")
p.add_argument("--out", default="validation/results/bundle_respa_peak.json")
a = p.parse_args()
n, m = (int(v) for v in a.chirality.split(","))
specs = parse_specs(None, 7, a.coarsening)
ratios = None
out = {"chirality": [n, m], "coarsening": a.coarsening, "load_before": list(os.getloadavg()),
       "runs": []}
if Path(a.out).is_file():
    out["runs"] = json.loads(Path(a.out).read_text()).get("runs", [])
for seed in (int(s) for s in a.seeds.split(",")):
    for spec in a.runs.split(","):
        integ, _, k = spec.partition(":")
        opt = {}
        if ":" in k:
            k, _, rest = k.partition(":")
            opt = dict(kv.split("=") for kv in rest.split(";"))
        k = int(k)
        vdw_every = k if integ == "verlet" else 1
        scene = BundleScene.create((n, m), 150.0, specs, vdw_every=vdw_every,
                                   coarse_pairs="sites", ratios=ratios)
        ratios = scene.info["ratios"]
        c0 = time.process_time()
        kw = {"integrator": integ, "inner": k if integ == "respa" else 5,
              "record_readings": True}
        kw.update({key: (float(v) if "." in v else int(v)) if v[0].isdigit() else v
                   for key, v in opt.items()})
        r = dynamic_tension(scene, seed=seed, max_strain=a.max_strain, progress=False, **kw)
        cpu = time.process_time() - c0
        c = r["curve"]
        label = f"{spec} seed {seed}"
        out["runs"] = [q for q in out["runs"] if q["label"] != label]
        out["runs"].append({"label": label, "seed": seed, "integrator": integ, "k": k,
                            "options": opt, "cpu_s": cpu,
                            "strength_GPa": r["strength_GPa"],
                            "strain_at_peak": r["strain_at_peak"],
                            "youngs_modulus_TPa": r["youngs_modulus_TPa"],
                            "tube_failure_strain": r["tube_failure_strain"],
                            "strain": c["strain"], "stress_GPa": c["stress_GPa"],
                            "stress_per_tube_GPa": c["stress_per_tube_GPa"],
                            "temperature_per_tube_K": c["temperature_per_tube_K"],
                            "readings": c["readings"], "radius_A": r["stress_convention"][
                                "radius_A"]})
        print(f"{label}: strength {r['strength_GPa']:.3f} GPa at {r['strain_at_peak']:.4f}, "
              f"E {r['youngs_modulus_TPa']:.4f} TPa, central fails at "
              f"{r['tube_failure_strain'][0]}, cpu {cpu:.1f} s", flush=True)
        e = np.asarray(c["strain"])
        P = np.asarray(c["stress_per_tube_GPa"])
        T = np.asarray(c["temperature_per_tube_K"])
        for j in np.flatnonzero((e > 0.08) & (e < 0.112)):
            print(f"  {e[j]:.4f} {c['stress_GPa'][j]:7.2f} | " + " ".join(
                f"{x:6.1f}" for x in P[j]) + " | Txy " + " ".join(f"{x:5.1f}" for x in T[j, :, 0])
                  + " | Tshift " + " ".join(f"{x:5.1f}" for x in T[j, 1:, 1]), flush=True)
out["load_after"] = list(os.getloadavg())
Path(a.out).write_text(json.dumps(out))
