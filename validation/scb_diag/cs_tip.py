"""Y_I, Y_II of the elastic SCB (Williams fit, 10 terms) against the block FE at a few angles for
several model options, the FE solved once per angle. Usage: cs_tip.py DX ALPHAS 'stabilisation=1.0' ['stabilisation=3.0' ...]

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import sys, time
from upscale.experiments.scenes.scb import SCBScene
from validation.fem_scb import solve_scb
dx = float(sys.argv[1]); als = [float(v) for v in sys.argv[2].split(",")]; specs = sys.argv[3:]
for al in als:
    sc0 = SCBScene(al, dx=dx)
    f = solve_scb(al, w=3 * dx, h_tip=4e-5, patch="block", block=(1.5 * dx, 2.5 * dx), probe=sc0.system.x0[:, :2])
    for spec in specs:
        t = time.time()
        kw = eval(f"dict({spec})")
        sc = SCBScene(al, dx=dx, **kw); st, P = sc.elastic()
        k = sc.stress_intensity(st, P, method="williams", n_terms=10)
        e = lambda a, b: 100 * (a / b - 1) if abs(b) > 0.1 else float("nan")
        print(f"al {al:4.1f} {spec:28s} Y_I {k['Y_I']:.4f} ({e(k['Y_I'], f['Y_I']):+.1f}%) Y_II {k['Y_II']:.4f} "
              f"({e(k['Y_II'], f['Y_II']):+.1f}%) FE {f['Y_I']:.4f} {f['Y_II']:.4f} "
              f"C {100 * (1e-5 / P / f['compliance_m_per_N'] - 1):+.2f}% {time.time() - t:.0f}s", flush=True)
