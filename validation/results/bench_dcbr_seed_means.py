"""Seed means (12345, 1, 2, 3) of the bench-dcbr-seed scene (clamped grips, band region, RESPA
5 x 1 fs, the force split SPLIT, default the scene's, upscale.models.dcbr_engine.MTS_SPLIT)
against the stored LAMMPS seed. Usage: bench_dcbr_seed_means.py N M K R_ATOMISTIC [SPLIT]
(run from the repository root with PYTHONPATH=$PWD; figures in validation/results/engine.md)."""
import sys

import numpy as np

from upscale.models.dcbr_dynamic import dynamic_tension
from validation.cases.dcbr import lammps_reference_or_run, dynamic_scene
from validation.cases.references import DYN_LENGTH
n, m, K = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
ref = lammps_reference_or_run(n, m, DYN_LENGTH, vacancy=True, protocol="dynamic")
rows = []
for s in (12345, 1, 2, 3):
    model, dyn = dynamic_scene(n, m, DYN_LENGTH, K, ref, grips="clamped", region="band", r_atomistic=float(sys.argv[4]))
    dyn.pop("grips"); dyn.update(integrator="respa", outer_dt=5.0, inner=5, seed=s,
                                 split=sys.argv[5] if len(sys.argv) > 5 else None)
    r = dynamic_tension(model, **dyn)
    e = [100*(r["strength_GPa"]/ref["strength_GPa"]-1), 100*(r["youngs_modulus_TPa"]/ref["youngs_modulus_TPa"]-1), 100*(r["strain_at_peak"]/ref["strain_at_peak"]-1)]
    rows.append(e); print(s, r["strength_GPa"], r["youngs_modulus_TPa"], r["strain_at_peak"], np.round(e, 3), flush=True)
mean = [float(np.mean([rr[i] for rr in rows])) for i in range(3)]
print("mean err % (strength, modulus, strain at peak):", np.round(mean, 3))
