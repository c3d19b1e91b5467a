"""The seed's hexagon (outer tubes' axes on a hexagon of side 2.2 R around the central tube,
seed 004 sec. 5.3.2) against the equilibrium wall gap: wall gap, nearest atoms of two
tubes, the vdW energy of the all-atomistic bundle at rest and its largest pair term, and
the one-line error the scene gives without ``allow_overlap``.

    python validation/results/bundle_hexagon.py [--chirality 10,10]
"""
import argparse
import json

import numpy as np

from upscale.experiments.scenes.bundle import BundleScene, TubeSpec, zero_stress_ratios

p = argparse.ArgumentParser()
p.add_argument("--chirality", default="10,10")
a = p.parse_args()
n, m = (int(v) for v in a.chirality.split(","))
ratios = zero_stress_ratios(n, m)
out = {"chirality": [n, m]}
for spacing in ("vdw", "seed"):
    try:
        BundleScene.create((n, m), 150.0, [TubeSpec("tersoff")] * 7, spacing=spacing,
                           ratios=ratios)
        out[f"{spacing}_error"] = None
    except ValueError as exc:
        out[f"{spacing}_error"] = str(exc)
    sc = BundleScene.create((n, m), 150.0, [TubeSpec("tersoff")] * 7, spacing=spacing,
                            ratios=ratios, allow_overlap=True)
    st = sc.state_at_rest()
    v = sc.vdw
    e = v.energy(st)
    eb = v.energy_between(st)
    f = np.abs(v.force(st)).max()
    from scipy.spatial import cKDTree

    mol = sc.atoms.arrays["mol-id"]
    y = st.y
    d = cKDTree(y[mol == 1]).query(y[mol == 2], k=1)[0].min()
    sig, eps = v.sigma, v.eps
    phi = 4 * eps * ((sig / d) ** 12 - (sig / d) ** 6)
    out[spacing] = {"wall_gap_A": sc.info["wall_gap_A"], "nearest_atoms_1_2_A": float(d),
                    "lj_pair_energy_at_nearest_eV": float(phi),
                    "vdw_energy_eV": float(e), "vdw_energy_per_atom_eV": float(e / len(y)),
                    "energy_centre_outer_eV": float(eb[0].sum()),
                    "max_abs_vdw_force_eV_per_A": float(f),
                    "centre_distance_A": float(np.hypot(*np.subtract(
                        sc.atoms.info["tube_centres"][1], sc.atoms.info["tube_centres"][0])))}
print(json.dumps(out, indent=1))
json.dump(out, open(f"validation/out/bundle_hexagon_{n}-{m}.json", "w"), indent=1)
