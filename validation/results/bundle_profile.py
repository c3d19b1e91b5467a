"""Where one MD step of the mixed bundle spends its time: the scene of ``bundle-tension``
((10,10), outer tubes dcbr:K, ``--vdw-every``/``--coarse-pairs`` as given), pulled for
``--steps`` steps under cProfile after its set-up and minimisation; prints the functions
by own time and the per-part totals (atomistic centre, coarse tubes, vdW, integrator).

    python validation/results/bundle_profile.py [--chirality 10,10] [--coarsening 2]
        [--vdw-every 4] [--coarse-pairs sites] [--steps 500]
"""
import argparse
import cProfile
import io
import json
import os
import pstats
import time

from upscale.experiments.bundle import BundleScene, dynamic_tension, parse_specs

p = argparse.ArgumentParser()
p.add_argument("--chirality", default="10,10")
p.add_argument("--coarsening", type=float, default=2.0)
p.add_argument("--vdw-every", type=int, default=4)
p.add_argument("--coarse-pairs", default="sites")
p.add_argument("--steps", type=int, default=500)
p.add_argument("--out", default="validation/out/bundle_profile.json")
a = p.parse_args()
n, m = (int(v) for v in a.chirality.split(","))
specs = parse_specs(None, 7, a.coarsening)
t0 = time.perf_counter()
scene = BundleScene.create((n, m), 150.0, specs, vdw_every=a.vdw_every,
                           coarse_pairs=a.coarse_pairs)
t_scene = time.perf_counter() - t0
# a short run first: the numba kernels compiled/loaded outside the profile
dynamic_tension(scene, max_steps=300, progress=False)
scene = BundleScene.create((n, m), 150.0, specs, vdw_every=a.vdw_every,
                           coarse_pairs=a.coarse_pairs, ratios=scene.info["ratios"])
pr = cProfile.Profile()
c0 = time.process_time()
pr.enable()
res = dynamic_tension(scene, max_steps=a.steps, progress=False)
pr.disable()
cpu = time.process_time() - c0
s = io.StringIO()
st = pstats.Stats(pr, stream=s)
st.sort_stats("tottime").print_stats(25)
st.sort_stats("cumulative").print_stats(45)
print(s.getvalue())
tm = res["timing_s"]
out = {"chirality": [n, m], "coarsening": a.coarsening, "vdw_every": a.vdw_every,
       "coarse_pairs": a.coarse_pairs, "steps": tm["steps"], "cpu_s": cpu,
       "minimisation_s": tm["minimisation"], "dynamics_s": tm["dynamics"],
       "dynamics_ms_per_step": 1e3 * tm["dynamics"] / tm["steps"],
       "scene_s": t_scene, "load": list(os.getloadavg())}
print(json.dumps(out, indent=1))
json.dump(out, open(a.out, "w"), indent=1)
