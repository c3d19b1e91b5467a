"""The bundle's inter-tube vdW, old and new code paths in one process: the pair kernel
over (i, j) int64 pairs (``lj_cut_pairs``) against the compressed-row kernel
(``lj_cut_csr``) on the same pair list, and one vdW evaluation with the coarse tubes
unchanged (a minimisation with them held) with and without the reconstruction kept.

    python validation/results/bundle_vdw_bench.py [--chirality 10,10] [--coarse-pairs sites]
"""
import argparse
import json
import os
import time

import numpy as np

from upscale.experiments.bundle import BundleScene, parse_specs, zero_stress_ratios
from upscale.models.tube_vdw import lj_cut_csr, lj_cut_pairs

p = argparse.ArgumentParser()
p.add_argument("--chirality", default="10,10")
p.add_argument("--coarsening", type=float, default=2.0)
p.add_argument("--coarse-pairs", default="sites")
p.add_argument("--repeat", type=int, default=20)
a = p.parse_args()
n, m = (int(v) for v in a.chirality.split(","))
ratios = zero_stress_ratios(n, m)
sc = BundleScene.create((n, m), 150.0, parse_specs(None, 7, a.coarsening), ratios=ratios,
                        coarse_pairs=a.coarse_pairs)
st = sc.state_at_rest()
v = sc.vdw
e_ref = v.energy(st)
x = v.atoms(st)
pl = v.pair_list(x)
off, nbr, pi, pj = pl["offsets"], pl["partners"], pl["i"], pl["j"]
w = v.weights


def best(fn, r=a.repeat):
    t = []
    for _ in range(r):
        t0 = time.process_time()
        out = fn()
        t.append(time.process_time() - t0)
    return min(t), float(np.median(t)), out


f1, f2 = np.zeros_like(x), np.zeros_like(x)
lj_cut_pairs(x, w, pi, pj, v.eps, v.sigma, v.rc, f1)
lj_cut_csr(x, w, off, nbr, v.eps, v.sigma, v.rc, f2)
t_old = best(lambda: lj_cut_pairs(x, w, pi, pj, v.eps, v.sigma, v.rc, np.zeros_like(x)))
t_new = best(lambda: lj_cut_csr(x, w, off, nbr, v.eps, v.sigma, v.rc,
                                np.zeros_like(x)))
e1 = lj_cut_pairs(x, w, pi, pj, v.eps, v.sigma, v.rc, np.zeros_like(x))
e2 = lj_cut_csr(x, w, off, nbr, v.eps, v.sigma, v.rc, np.zeros_like(x))


# one evaluation after the central tube moved (the coarse tubes held)
rows0 = sc.assembly.rows(sc.bodies[0].name)
rng = np.random.default_rng(0)


def moved_eval(keep):
    st.y[rows0] += rng.normal(scale=1e-4, size=(rows0.stop - rows0.start, 3))
    if not keep:
        for mp in v.maps:
            if hasattr(mp, "forget"):
                mp.forget()
    return v.energy(st)


t_nokeep = best(lambda: moved_eval(False))
t_keep = best(lambda: moved_eval(True))
# the rebuild of the pair list
t_build = best(lambda: (v.rebuild(), v.pair_list(x)), r=3)
out = {"chirality": [n, m], "coarsening": a.coarsening, "coarse_pairs": a.coarse_pairs,
       "points": len(x), "pairs": int(len(pj)),
       "pairs_within_rc": int(np.sum(np.sum((x[pi] - x[pj]) ** 2, axis=1) < v.rc ** 2)),
       "kernel_pairs_cpu_ms": 1e3 * t_old[0], "kernel_csr_cpu_ms": 1e3 * t_new[0],
       "kernel_speedup": t_old[0] / t_new[0],
       "energy_rel_diff": abs(e1 - e2) / abs(e1), "force_max_abs_diff": float(np.abs(f1 - f2).max()),
       "eval_held_coarse_rebuild_atoms_cpu_ms": 1e3 * t_nokeep[0],
       "eval_held_coarse_kept_atoms_cpu_ms": 1e3 * t_keep[0],
       "pair_build_cpu_ms": 1e3 * t_build[0], "load": list(os.getloadavg())}
print(json.dumps(out, indent=1))
json.dump(out, open(f"validation/out/bundle_vdw_bench_{n}-{m}.json", "w"), indent=1)
