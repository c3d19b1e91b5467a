"""Seed means (12345, 1, 2, 3) of the bench-dcbr-seed scene (clamped grips, RESPA 5 x 1 fs,
the force split SPLIT, default the scene's, upscale.models.dcbr_engine.MTS_SPLIT) against the
stored LAMMPS seed. Usage: bench_dcbr_seed_means.py N M K R_ATOMISTIC [SPLIT [REGION [GROW
[R_GROW]]]] (SPLIT - for the default; REGION default band; GROW: the region the run grows to
when the crack starts, e.g. band about a disc, of half-width R_GROW, default R_ATOMISTIC; run
from the repository root with PYTHONPATH=$PWD; figures in validation/results/engine.md)."""
import sys
import time

import numpy as np

from upscale.models.dcbr_dynamic import dynamic_tension
from validation.cases.dcbr import lammps_reference_or_run, dynamic_scene
from validation.cases.references import DYN_LENGTH
n, m, K = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
split = sys.argv[5] if len(sys.argv) > 5 and sys.argv[5] != "-" else None
region = sys.argv[6] if len(sys.argv) > 6 else "band"
grow = sys.argv[7] if len(sys.argv) > 7 else None
r_grow = float(sys.argv[8]) if len(sys.argv) > 8 else None
ref = lammps_reference_or_run(n, m, DYN_LENGTH, vacancy=True, protocol="dynamic")
rows = []
for s in (12345, 1, 2, 3):
    t0 = time.perf_counter()
    model, dyn = dynamic_scene(n, m, DYN_LENGTH, K, ref, grips="clamped", region=region,
                               r_atomistic=float(sys.argv[4]), grow=grow, r_grow=r_grow)
    dyn.pop("grips"); dyn.update(integrator="respa", outer_dt=5.0, inner=5, seed=s, split=split)
    r = dynamic_tension(model, **dyn)
    e = [100*(r["strength_GPa"]/ref["strength_GPa"]-1), 100*(r["youngs_modulus_TPa"]/ref["youngs_modulus_TPa"]-1), 100*(r["strain_at_peak"]/ref["strain_at_peak"]-1)]
    rows.append(e)
    sps = r["dynamics_s"] / (r["steps"] * r["dt_fs"] * 1e-3)
    print(s, r["strength_GPa"], r["youngs_modulus_TPa"], r["strain_at_peak"], np.round(e, 3),
          "grown_at", r.get("grown_at"), f"dynamics {sps:.3f} s/ps, whole {time.perf_counter() - t0:.1f} s",
          flush=True)
mean = [float(np.mean([rr[i] for rr in rows])) for i in range(3)]
print("mean err % (strength, modulus, strain at peak):", np.round(mean, 3))
