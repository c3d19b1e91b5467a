"""The bundle's inter-tube vdW, code paths in one process: the pair kernel over (i, j)
int64 pairs (``lj_cut_pairs``, the model's) against a compressed-row kernel (int32
partners, the row's force in registers; defined here, measured no faster) on the same
pair list, and one vdW evaluation with the coarse tubes
unchanged (a minimisation with them held) with and without the reconstruction kept.

    python validation/results/bundle_vdw_bench.py [--chirality 10,10] [--coarse-pairs sites]
"""
import argparse
import json
import os
import time

import numpy as np
from numba import njit

from upscale.experiments.scenes.bundle import BundleScene, parse_specs, zero_stress_ratios
from upscale.models.tube_vdw import lj_cut_pairs


@njit(cache=True)
def lj_cut_csr(x, w, offsets, nbr, eps, sigma, rc, f):
    """Eq. (1) over a half pair list in compressed rows: atom ``a``'s partners are
    ``nbr[offsets[a]:offsets[a + 1]]`` (int32, each pair once). Returns the energy (eV) and
    adds the forces (eV/Å) to ``f`` (n, 3); the same sums as :func:`lj_cut_pairs` over
    the same pairs, with one division per pair and the row's own force kept in
    registers (4 bytes of index per pair instead of 16)."""
    rc2 = rc * rc
    s2 = sigma * sigma
    c4 = 4.0 * eps
    c24 = 24.0 * eps
    e = 0.0
    for a in range(offsets.shape[0] - 1):
        p0 = offsets[a]
        p1 = offsets[a + 1]
        if p0 == p1:
            continue
        xa = x[a, 0]
        ya = x[a, 1]
        za = x[a, 2]
        wa = w[a]
        fx = 0.0
        fy = 0.0
        fz = 0.0
        for p in range(p0, p1):
            b = nbr[p]
            dx = xa - x[b, 0]
            dy = ya - x[b, 1]
            dz = za - x[b, 2]
            r2 = dx * dx + dy * dy + dz * dz
            if r2 >= rc2:
                continue
            ir2 = 1.0 / r2
            q = s2 * ir2
            q6 = q * q * q
            ww = wa * w[b]
            e += ww * c4 * (q6 * q6 - q6)
            g = ww * c24 * (2.0 * q6 * q6 - q6) * ir2   # -dphi/dr / r
            fx += g * dx
            fy += g * dy
            fz += g * dz
            f[b, 0] -= g * dx
            f[b, 1] -= g * dy
            f[b, 2] -= g * dz
        f[a, 0] += fx
        f[a, 1] += fy
        f[a, 2] += fz
    return e


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
pi, pj = pl["i"], pl["j"]
off = np.zeros(len(x) + 1, np.int64)  # the same pairs in compressed rows, int32 partners
np.cumsum(np.bincount(pi, minlength=len(x)), out=off[1:])
nbr = pj.astype(np.int32)
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
# interleaved (the load changes during the measurement): best of each over 3 x repeat
t_o, t_n = [], []
for _ in range(3 * a.repeat):
    t0 = time.process_time()
    lj_cut_pairs(x, w, pi, pj, v.eps, v.sigma, v.rc, np.zeros_like(x))
    t1 = time.process_time()
    lj_cut_csr(x, w, off, nbr, v.eps, v.sigma, v.rc, np.zeros_like(x))
    t_o.append(t1 - t0)
    t_n.append(time.process_time() - t1)
t_old, t_new = (min(t_o), float(np.median(t_o))), (min(t_n), float(np.median(t_n)))
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
       "kernel_pairs_cpu_ms_median": 1e3 * t_old[1], "kernel_csr_cpu_ms_median": 1e3 * t_new[1],
       "energy_rel_diff": abs(e1 - e2) / abs(e1), "force_max_abs_diff": float(np.abs(f1 - f2).max()),
       "eval_held_coarse_rebuild_atoms_cpu_ms": 1e3 * t_nokeep[0],
       "eval_held_coarse_kept_atoms_cpu_ms": 1e3 * t_keep[0],
       "pair_build_cpu_ms": 1e3 * t_build[0], "load": list(os.getloadavg())}
print(json.dumps(out, indent=1))
json.dump(out, open(f"validation/out/bundle_vdw_bench_{n}-{m}.json", "w"), indent=1)
