"""Where the crack of a (50,50) K3 seed whose stress plateaus stops: damaged atoms and broken
coarse links every 400 steps of the seed-scale vacancy scene (validation/results/engine.md).

    python validation/results/dcbr_plateau_probe.py SEED
"""
import sys
import numpy as np
from upscale.models.dcbr_dynamic import dynamic_tension
from validation.cases.dcbr import lammps_reference_or_run, dynamic_scene

seed = int(sys.argv[1])
ref = lammps_reference_or_run(50, 50, 150.0, protocol="dynamic", vacancy=True, progress=False)
model, dyn = dynamic_scene(50, 50, 150.0, 3.0, ref, vacancy=True, grips=None)
dyn.pop("grips")
dyn["max_strain"] = 0.14
rows = []

def mon(step, y, v, d, s):
    if step % 400:
        return
    xf, _ = model.atom_positions(y, d, model.L)
    dmg = model.atom_damage(y, d, model.L)
    z = xf[:, 2]
    hit = dmg > 0.3
    nl = int((~model.intact).sum())
    g = model.gain
    zl = model.x0[g.pair_i[~model.intact], 2] if nl else np.array([])
    rows.append((step, s, int(hit.sum()), (z.min(), z.max()),
                 (z[hit].min(), z[hit].max()) if hit.any() else None, nl,
                 (zl.min(), zl.max()) if nl else None))
    print(f"step {step} stress {s:.2f} damaged atoms {hit.sum()} band z {z.min():.1f}..{z.max():.1f} "
          f"damaged z {rows[-1][4]} coarse links broken {nl} at z {rows[-1][6]}", flush=True)

r = dynamic_tension(model, seed=seed, temperature=10.0, engine=True, monitor=mon, **dyn)
print("strength", r["strength_GPa"], "at", r["strain_at_peak"])
