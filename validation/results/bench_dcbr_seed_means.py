"""Seed means (12345, 1, 2, 3) of the bench-dcbr-seed scene (clamped grips, RESPA 5 x 1 fs)
against the stored LAMMPS seed, printed per seed and as means.

    PYTHONPATH=$PWD python validation/results/bench_dcbr_seed_means.py N M K [R_ATOMISTIC]
        [--split S] [--region band|disc|ellipse] [--grow band] [--r-grow R]
        [--no-grow-thermal] [--outer-dt FS --inner N]

``--split``: the force split (default the scene's, upscale.models.dcbr_engine.MTS_SPLIT);
``--region`` (default band) the atomistic region at the start, of half-width R_ATOMISTIC
(default 8 Å); ``--grow`` the region the run grows to when the crack starts, of half-width
``--r-grow`` (default R_ATOMISTIC); ``--no-grow-thermal``: the atoms that become free keep
their carried velocities only; ``--outer-dt`` / ``--inner``: the RESPA outer step (fs) and
the 1 fs inner steps per outer step (default 5 / 5, the bench's). Figures in validation/results/engine.md."""
import argparse
import time

import numpy as np

from upscale.models.dcbr_dynamic import dynamic_tension
from validation.cases.dcbr import lammps_reference_or_run, dynamic_scene
from validation.cases.references import DYN_LENGTH

p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
p.add_argument("n", type=int)
p.add_argument("m", type=int)
p.add_argument("K", type=float)
p.add_argument("r_atomistic", type=float, nargs="?", default=8.0)
p.add_argument("--split", default=None)
p.add_argument("--region", default="band")
p.add_argument("--grow", default=None)
p.add_argument("--r-grow", type=float, default=None)
p.add_argument("--outer-dt", type=float, default=5.0)
p.add_argument("--inner", type=int, default=5)
p.add_argument("--no-grow-thermal", action="store_true")
a = p.parse_args()
ref = lammps_reference_or_run(a.n, a.m, DYN_LENGTH, vacancy=True, protocol="dynamic")
rows = []
for s in (12345, 1, 2, 3):
    t0 = time.perf_counter()
    model, dyn = dynamic_scene(a.n, a.m, DYN_LENGTH, a.K, ref, grips="clamped", region=a.region,
                               r_atomistic=a.r_atomistic, grow=a.grow, r_grow=a.r_grow)
    dyn.pop("grips")
    dyn.update(integrator="respa", outer_dt=a.outer_dt, inner=a.inner, seed=s, split=a.split)
    if a.grow is not None:
        dyn["grow_thermal"] = not a.no_grow_thermal
    r = dynamic_tension(model, **dyn)
    e = [100 * (r["strength_GPa"] / ref["strength_GPa"] - 1),
         100 * (r["youngs_modulus_TPa"] / ref["youngs_modulus_TPa"] - 1),
         100 * (r["strain_at_peak"] / ref["strain_at_peak"] - 1)]
    rows.append(e)
    sps = r["dynamics_s"] / (r["steps"] * r["dt_fs"] * 1e-3)
    print(s, r["strength_GPa"], r["youngs_modulus_TPa"], r["strain_at_peak"], np.round(e, 3),
          "grown_at", r.get("grown_at"), f"dynamics {sps:.3f} s/ps, whole "
          f"{time.perf_counter() - t0:.1f} s", flush=True)
mean = [float(np.mean([rr[i] for rr in rows])) for i in range(3)]
print("mean err % (strength, modulus, strain at peak):", np.round(mean, 3))
