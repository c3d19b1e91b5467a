"""The bundle's start and its thermostat: the (10,10) K2 bundle pulled on one thermal seed
with given set-up and thermostat settings, the breathing of each tube's cross-section and
each tube's kinetic temperature before failure, and the run's metrics.

    python validation/results/bundle_settle.py [--seed 4928459] [--max-strain 0.40]
        [--runs "settle_ps=0;chain=1,settle_ps=1.0;chain=3"] [--integrator respa] [--inner 5]

``--runs``: comma-separated settings, each ``key=value[;key=value]`` of
:func:`upscale.experiments.scenes.bundle.dynamic_tension` (``settle_ps``: the quench of every tube
before the pull, 0 = the coarse tubes as set up; ``chain``: Nose-Hoover chain length).
Window for the breathing and temperatures: strain 0.01-0.08 (after the first 0.1 ps of
ramp-in, before any tube fails). Breathing amplitude: the standard deviation over the
window of each tube's mean radius (Å, ``curve.radius_per_tube_A``) after removing its
linear trend (the Poisson contraction of the pull). Appends to ``--out`` (JSON).
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
p.add_argument("--seed", type=int, default=4928459)
p.add_argument("--max-strain", type=float, default=0.40)
p.add_argument("--integrator", default="respa")
p.add_argument("--inner", type=int, default=5)
p.add_argument("--runs", default="settle_ps=0;chain=1,settle_ps=1.0;chain=1,settle_ps=1.0;chain=3")
p.add_argument("--out", default="validation/results/bundle_settle.json")
a = p.parse_args()
n, m = (int(v) for v in a.chirality.split(","))
specs = parse_specs(None, 7, a.coarsening)
out = {"runs": []}
if Path(a.out).is_file():
    out = json.loads(Path(a.out).read_text())
ratios = None
for spec in a.runs.split(","):
    opt = {k: (float(v) if "." in v else int(v)) if v[0].isdigit() else v
           for k, v in (kv.split("=") for kv in spec.split(";"))}
    scene = BundleScene.create((n, m), 150.0, specs, coarse_pairs="sites", ratios=ratios)
    ratios = scene.info["ratios"]
    load0 = os.getloadavg()
    c0 = time.process_time()
    r = dynamic_tension(scene, seed=a.seed, max_strain=a.max_strain, progress=False,
                        integrator=a.integrator, inner=a.inner, **opt)
    cpu = time.process_time() - c0
    c = r["curve"]
    e = np.asarray(c["strain"])
    w = (e > 0.01) & (e < 0.08)
    R = np.asarray(c["radius_per_tube_A"])[w]
    T = np.asarray(c["temperature_per_tube_K"], dtype=float)[w]
    ew = e[w]
    breath = [float(np.std(R[:, k] - np.polyval(np.polyfit(ew, R[:, k], 1), ew)))
              for k in range(R.shape[1])]
    row = {"label": f"{a.chirality} K{a.coarsening:g} {a.integrator}{a.inner} seed {a.seed} "
                    f"{spec}",
           "options": opt, "seed": a.seed, "cpu_s": cpu, "load_before": list(load0),
           "load_after": list(os.getloadavg()),
           "settle": r["protocol_detail"]["settle"],
           "strength_GPa": r["strength_GPa"], "strain_at_peak": r["strain_at_peak"],
           "youngs_modulus_TPa": r["youngs_modulus_TPa"],
           "failure_order": r["failure_order"],
           "breathing_sd_A": breath,
           "Txy_mean_K": T[:, :, 0].mean(axis=0).tolist(),
           "Txy_sd_K": T[:, :, 0].std(axis=0).tolist(),
           "Tshift_mean_K": np.nanmean(T[:, 1:, 1], axis=0).tolist(),
           "curve": {k: c[k] for k in ("strain", "stress_GPa", "stress_per_tube_GPa",
                                        "temperature_per_tube_K", "radius_per_tube_A")}}
    out["runs"] = [q for q in out["runs"] if q["label"] != row["label"]] + [row]
    Path(a.out).write_text(json.dumps(out))
    f = " ".join
    print(f"{row['label']}: strength {r['strength_GPa']:.3f} GPa at {r['strain_at_peak']:.4f}, "
          f"E {r['youngs_modulus_TPa']:.4f} TPa, order {r['failure_order']}, cpu {cpu:.1f} s, "
          f"load {load0[0]:.1f}\n  settle {row['settle']}\n"
          f"  breathing sd (Å) {f(f'{x:.4f}' for x in breath)}\n"
          f"  Txy mean (K) {f(f'{x:.2f}' for x in row['Txy_mean_K'])}\n"
          f"  Txy sd (K) {f(f'{x:.2f}' for x in row['Txy_sd_K'])}\n"
          f"  Tshift mean (K) {f(f'{x:.2f}' for x in row['Tshift_mean_K'])}", flush=True)
