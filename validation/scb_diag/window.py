"""Williams-fit window and order sensitivity of Y_I, Y_II on the particle field and on the FE
field sampled at the particle positions (block FE, the particle model's boundary conditions).
Usage: window.py DX ALPHA [ALPHA ...]

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import sys

from upscale.experiments.scenes.scb import SCBScene
from validation.fem_scb import solve_scb

dx = float(sys.argv[1])
windows = [(0.2, 0.6), (0.3, 0.7), (0.4, 0.8), (0.5, 0.9), (0.2, 0.9)]
for al in map(float, sys.argv[2:]):
    sc = SCBScene(al, dx=dx)
    st, P = sc.elastic()
    f = solve_scb(al, w=3 * dx, h_tip=4e-5, patch="block", block=(1.5 * dx, 2.5 * dx), probe=sc.system.x0[:, :2])
    s2 = sc.state()
    s2.y[:, :2] = sc.system.x0[:, :2] + f["probe_u_m_per_N"]
    print(f"alpha {al:g}: FE Y_I {f['Y_I']:.4f} Y_II {f['Y_II']:.4f} T* {f['T_star']:.3f}", flush=True)
    for w in windows:
        for nt in (8, 10, 12):
            k = sc.stress_intensity(st, P, window=w, method="williams", n_terms=nt)
            kf = sc.stress_intensity(s2, 1.0, window=w, method="williams", n_terms=nt)
            e = lambda a, b: 100 * (a / b - 1) if abs(b) > 0.1 else float("nan")
            print(f"  window {w} n {nt:2d}: particle Y_I {k['Y_I']:.4f} ({e(k['Y_I'], f['Y_I']):+.2f} %) "
                  f"Y_II {k['Y_II']:.4f} ({e(k['Y_II'], f['Y_II']):+.2f} %) | FE@particles Y_I {kf['Y_I']:.4f} "
                  f"({e(kf['Y_I'], f['Y_I']):+.2f} %) Y_II {kf['Y_II']:.4f} ({e(kf['Y_II'], f['Y_II']):+.2f} %)", flush=True)
