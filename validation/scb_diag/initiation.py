"""Where the first failures sit about the tip, against the initiation angle's fit.

Runs the scene (defaults, r_s = 1 mm) to the peak before the load first falls below
STOP (0.95) of it and prints, for the first ROUNDS breaking rounds, the particles that lost
bonds in that round (distance from the tip in spacings, angle in the tip frame, positive
toward +y' as ``SCBScene.initiation_angle``), then the fitted initiation angle with its
default selection (bonds within 3 delta of the tip) and with the first k broken bonds.
Usage: initiation.py ALPHA DX [ROUNDS [STOP]]

Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import sys

import numpy as np

from upscale.experiments.scenes.scb import SCBScene

alpha, dx = float(sys.argv[1]), float(sys.argv[2])
rounds = int(sys.argv[3]) if len(sys.argv) > 3 else 6
stop = float(sys.argv[4]) if len(sys.argv) > 4 else 0.95
sc = SCBScene(alpha, dx=dx, r_s=1e-3)
st, c = sc.fracture(stop_fraction=stop)
fam, x = sc.family, sc.system.x0[:, :2]
print(f"alpha {alpha:g} deg, dx {dx * 1e3:g} mm: P_c {c.peak[0] / 1e3:.4f} kN, {c.first_broken.size} directed bonds broken")
for r in np.unique(c.first_broken_round)[:rounds]:
    b = c.first_broken[c.first_broken_round == r]
    lost = np.unique(np.concatenate([fam.owner[b], fam.neighbors[b]]))
    # the particles that failed: those that lost most of their bonds this round
    cnt = np.bincount(np.concatenate([fam.owner[b], fam.neighbors[b]]), minlength=sc.system.n)
    failed = np.flatnonzero(cnt >= 0.5 * cnt.max())
    d = x[failed] - sc.tip
    ang = np.degrees(np.arctan2(d @ sc.ey, d @ sc.ex))
    dist = np.linalg.norm(d, axis=1) / dx
    print(f"round {r}: {b.size} bonds, {lost.size} particles touched; failed at "
          + ", ".join(f"({dd:.2f} dx, {aa:+.1f} deg)" for dd, aa in zip(dist, ang)))
print(f"initiation angle, default (bonds within 3 delta): {sc.initiation_angle(c):+.1f} deg")
for k in (2, 10, 50, 200):
    print(f"initiation angle, first {k} bonds: {sc.initiation_angle(c, n_first=k):+.1f} deg")
b = c.first_broken
d = 0.5 * (x[fam.owner[b]] + x[fam.neighbors[b]]) - sc.tip
dist = np.linalg.norm(d, axis=1)
for w in (1.5e-3, 2.25e-3, 3e-3, 4.5e-3):
    v = d[dist <= w].mean(axis=0)
    print(f"initiation angle, bonds within {w * 1e3:g} mm: {np.degrees(np.arctan2(v @ sc.ey, v @ sc.ex)):+.1f} deg")
