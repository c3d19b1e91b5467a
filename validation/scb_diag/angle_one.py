"""Elastic SCB at one angle, as validation/scb_diag/angles.py: Williams factors of the particle
model against FE with the patch blocks, and the same fit on the FE field at the particles.
Usage: angle_one.py DX ALPHA 'm=6.0' (scene keywords). Run from the repository root with PYTHONPATH=$PWD."""
import sys, time
from upscale.experiments.scenes.scb import SCBScene
from validation.fem_scb import solve_scb
dx = float(sys.argv[1]); al = float(sys.argv[2]); kw = eval(f"dict({sys.argv[3]})")
t = time.time()
sc = SCBScene(al, dx=dx, **kw); st, P = sc.elastic()
kw_ = sc.stress_intensity(st, P, method="williams", n_terms=10)
f = solve_scb(al, w=3*dx, h_tip=4e-5, patch="block", block=(1.5*dx, 2.5*dx), probe=sc.system.x0[:, :2])
s2 = sc.state(); s2.y[:, :2] = sc.system.x0[:, :2] + f["probe_u_m_per_N"]
kf = sc.stress_intensity(s2, 1.0, method="williams", n_terms=10)
e = lambda a, b: 100 * (a / b - 1) if abs(b) > 0.1 else float("nan")
print(f"dx {dx} al {al} {kw} | Y_I {kw_['Y_I']:.4f} ({e(kw_['Y_I'], f['Y_I']):+.2f}%) Y_II {kw_['Y_II']:.4f} ({e(kw_['Y_II'], f['Y_II']):+.2f}%) "
      f"| FE {f['Y_I']:.4f} {f['Y_II']:.4f} | est(FE) {kf['Y_I']:.4f} {kf['Y_II']:.4f} | {time.time()-t:.0f}s", flush=True)
