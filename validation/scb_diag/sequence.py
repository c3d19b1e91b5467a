"""Failure sequence of one quasi-static SCB run: per breaking round, the load before and after it
and the particles that became voids (every bond broken), as (distance ahead of the initial tip,
offset across the crack) in spacings.
Usage: sequence.py ALPHA,DX,R_S [M [GROWTH]]   (GROWTH: free (default) or front)

Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import sys

import numpy as np

from upscale.experiments.scenes.scb import SCBScene

al, dx, rs = map(float, sys.argv[1].split(","))
m = float(sys.argv[2]) if len(sys.argv) > 2 else 3.0
growth = sys.argv[3] if len(sys.argv) > 3 else "free"
sc = SCBScene(al, dx=dx, m=m, r_s=rs, growth=growth)
print(f"sigma_c {sc.model.sigma_c() / 1e6:.4f} MPa, beta {sc.model.tip_factor():.5f}")
st, curve = sc.fracture(stop_fraction=0.5, max_equilibria=400)
fam = sc.family
P = curve.load
x0 = sc.system.x0[:, :2]
deg = np.bincount(fam.owner, minlength=sc.system.n)
lost = np.zeros(sc.system.n, int)
ipk = int(np.argmax(P))
print(f"alpha {al:g} dx {dx * 1e3:g} mm r_s {rs * 1e3:g} mm m {m:g} {growth}: P_c {P.max() / 1e3:.4f} kN "
      f"at equilibrium {ipk}; {len(P)} equilibria")
for r in np.unique(curve.first_broken_round):
    b = curve.first_broken[curve.first_broken_round == r]
    before = lost.copy()
    np.add.at(lost, fam.owner[b], 1)
    dead = np.flatnonzero((lost >= deg) & (before < deg))
    rel = x0[dead] - sc.tip[:2]
    a_, c_ = rel @ sc.ex[:2] / dx, rel @ sc.ey[:2] / dx
    tag = " <- peak" if r - 1 == ipk else ""
    print(f"round at equilibrium {r:4d}: P before {P[r - 1] / 1e3:.4f} kN, after {P[r] / 1e3:.4f}; bonds {b.size}; "
          f"voids {dead.size}: " + " ".join(f"({u:+.1f},{v:+.1f})" for u, v in zip(a_[:8], c_[:8])) + tag)
    if P[r] < 0.5 * P.max():
        break
