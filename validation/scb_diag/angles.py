"""Elastic SCB at the eight angles: Williams and face-jump factors, FE with the patch blocks, the
Williams fit on the FE field at the particles, compliance. Usage: angles.py DX 'stabilisation=1.0' ['gain_order=2' ...]

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import sys, time, numpy as np
from upscale.experiments.scenes.scb import SCBScene
from validation.fem_scb import solve_scb
dx = float(sys.argv[1]); specs = sys.argv[2:]
als = (0.0, 10.0, 20.0, 30.0, 40.0, 43.0, 47.0, 50.0)
for spec in specs:
    kw = eval(f"dict({spec})")
    for al in als:
        t = time.time()
        sc = SCBScene(al, dx=dx, **kw); st, P = sc.elastic()
        kj = sc.stress_intensity(st, P); kw_ = sc.stress_intensity(st, P, method="williams", n_terms=10)
        f = solve_scb(al, w=3*dx, h_tip=4e-5, patch="block", block=(1.5*dx, 2.5*dx), probe=sc.system.x0[:, :2])
        s2 = sc.state(); s2.y[:, :2] = sc.system.x0[:, :2] + f["probe_u_m_per_N"]
        kf = sc.stress_intensity(s2, 1.0, method="williams", n_terms=10)
        e = lambda a, b: 100 * (a / b - 1) if abs(b) > 0.1 else float("nan")
        C = 1e-5 / P
        print(f"{spec} al {al:4.1f} | W Y_I {kw_['Y_I']:.4f} ({e(kw_['Y_I'], f['Y_I']):+.1f}%) Y_II {kw_['Y_II']:.4f} ({e(kw_['Y_II'], f['Y_II']):+.1f}%) "
              f"| jump {kj['Y_I']:.4f} ({e(kj['Y_I'], f['Y_I']):+.1f}%) {kj['Y_II']:.4f} ({e(kj['Y_II'], f['Y_II']):+.1f}%) "
              f"| FE {f['Y_I']:.4f} {f['Y_II']:.4f} W(FE@part) {kf['Y_I']:.4f} {kf['Y_II']:.4f} | T* {kw_['T_star']:.3f} FE {f['T_star']:.3f} "
              f"| C {100*(C/f['compliance_m_per_N']-1):+.2f}% {time.time()-t:.0f}s", flush=True)
