"""Where one MD step of the mixed bundle spends its time: the scene of ``bundle-tension``
((10,10), outer tubes dcbr:K, ``--vdw-every``/``--coarse-pairs`` as given), pulled for
``--steps`` steps under cProfile after its set-up and minimisation; prints the functions
by own time and the per-part totals (atomistic centre, coarse tubes, vdW, integrator).

    python validation/results/bundle_profile.py [--chirality 10,10] [--coarsening 2]
        [--vdw-every 4] [--coarse-pairs sites] [--steps 500] [--integrator respa --inner 5]
"""
import argparse
import cProfile
import io
import json
import os
import pstats
import time

from upscale.experiments.scenes.bundle import BundleScene, dynamic_tension, parse_specs

p = argparse.ArgumentParser()
p.add_argument("--chirality", default="10,10")
p.add_argument("--coarsening", type=float, default=2.0)
p.add_argument("--vdw-every", type=int, default=4)
p.add_argument("--coarse-pairs", default="sites")
p.add_argument("--steps", type=int, default=500)
p.add_argument("--integrator", default="verlet", choices=("verlet", "respa"))
p.add_argument("--inner", type=int, default=5)
p.add_argument("--out", default="validation/out/bundle_profile.json")
a = p.parse_args()
n, m = (int(v) for v in a.chirality.split(","))
specs = parse_specs(None, 7, a.coarsening)
t0 = time.perf_counter()
scene = BundleScene.create((n, m), 150.0, specs, vdw_every=a.vdw_every,
                           coarse_pairs=a.coarse_pairs)
t_scene = time.perf_counter() - t0
# a short run first: the numba kernels compiled/loaded outside the profile
dynamic_tension(scene, max_steps=300, progress=False, integrator=a.integrator, inner=a.inner)
scene = BundleScene.create((n, m), 150.0, specs, vdw_every=a.vdw_every,
                           coarse_pairs=a.coarse_pairs, ratios=scene.info["ratios"])
pr = cProfile.Profile()
c0 = time.process_time()
pr.enable()
res = dynamic_tension(scene, max_steps=a.steps, progress=False, integrator=a.integrator,
                      inner=a.inner)
pr.disable()
cpu = time.process_time() - c0
s = io.StringIO()
st = pstats.Stats(pr, stream=s)
st.sort_stats("tottime").print_stats(25)
st.sort_stats("cumulative").print_stats(45)
print(s.getvalue())
# per part: cumulative time of the function that does the part (calls, seconds)
PARTS = (("coarse tubes: own forces", "dcbr_engine.py", "_evaluate"),
         ("coarse tubes: link rules", "dcbr_engine.py", "break_links"),
         ("vdW: coarse atoms reconstructed", "tube_vdw.py", "positions"),
         ("vdW: forces pulled back", "tube_vdw.py", "pull_back"),
         ("vdW: pair kernel", "tube_vdw.py", "lj_cut_csr"),
         ("vdW: pair kernel (pairs)", "tube_vdw.py", "lj_cut_pairs"),
         ("vdW: pair list check/rebuild", "tube_vdw.py", "_pairs"),
         ("vdW: state comparison", "tube_vdw.py", "_same_state"),
         ("atomistic centre (Tersoff)", "tersoff.py", "evaluate"),
         ("thermostat (Nose-Hoover halves)", "thermostats.py", "_half"),
         ("field forces (engine)", "fields.py", "add_field_forces"),
         ("field kicks (engine)", "integrators.py", "_kick_fields"),
         ("body views (engine)", "bodies.py", "sub"),
         ("conditions apply (grips, ties)", "conditions.py", "apply"),
         ("minimisation (whole)", "simulation.py", "minimise"),
         ("field kicks (r-RESPA)", "respa.py", "_kick"),
         ("group forces (r-RESPA)", "respa.py", "_group_forces"),
         ("MD steps (whole)", "integrators.py", "step"),
         ("MD steps (whole, r-RESPA)", "respa.py", "step"))
parts = []
for label, fname, func in PARTS:
    nc = ct = 0.0
    for (f, _, fn), (_, ncalls, _, cum, _) in st.stats.items():
        if f.endswith(fname) and fn == func:
            nc += ncalls
            ct += cum
    parts.append({"part": label, "calls": int(nc), "cum_s": ct})
for r in parts:
    print(f"{r['part']:<36s} {r['calls']:>7d} {r['cum_s']:8.2f} s")
tm = res["timing_s"]
out = {"chirality": [n, m], "coarsening": a.coarsening, "vdw_every": a.vdw_every,
       "integrator": a.integrator, "inner": a.inner if a.integrator == "respa" else 1,
       "coarse_pairs": a.coarse_pairs, "steps": tm["steps"], "cpu_s": cpu,
       "minimisation_s": tm["minimisation"], "dynamics_s": tm["dynamics"],
       "dynamics_ms_per_step": 1e3 * tm["dynamics"] / tm["steps"],
       "scene_s": t_scene, "load": list(os.getloadavg()), "parts": parts,
       "profile_total_s": st.total_tt}
print(json.dumps(out, indent=1))
json.dump(out, open(a.out, "w"), indent=1)
