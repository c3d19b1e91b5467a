"""Crack-face opening per newton along the face (alpha = 0, dx = 1 mm): FE with the patch blocks
(centre box and cell box) against the particle model for c_s = 0.1, 1, 3 and both gain orders.

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import sys, numpy as np
from validation.fem_scb import solve_scb
from upscale.experiments.scenes.scb import SCBScene
dx=1e-3
ys = np.arange(0.5, 15, 1.0)*1e-3
def cod(x0,u):
    out=[]
    for y in ys:
        a = np.flatnonzero((np.abs(x0[:,0]-0.5e-3)<1e-6)&(np.abs(x0[:,1]-y)<1e-6))[0]
        b = np.flatnonzero((np.abs(x0[:,0]+0.5e-3)<1e-6)&(np.abs(x0[:,1]-y)<1e-6))[0]
        out.append(u[a,0]-u[b,0])
    return np.array(out)
sc = SCBScene(0.0, dx=dx)
x0 = sc.system.x0[:, :2]
print("y mm  ", " ".join(f"{y*1e3:6.1f}" for y in ys))
for blk in [(1.5e-3,2.5e-3),(2e-3,3e-3)]:
    r = solve_scb(0.0, w=3e-3, h_tip=4e-5, probe=x0, patch="block", block=blk)
    print(f"FE blk{blk}", " ".join(f"{v*1e9:6.2f}" for v in cod(x0, r["probe_u_m_per_N"])), "C", r["compliance_m_per_N"], "Y", r["Y_I"])
for cs in (0.1, 1.0, 3.0):
  for go in (1,2):
    sc = SCBScene(0.0, dx=dx, stabilisation=cs, gain_order=go)
    st, P = sc.elastic()
    u = (st.y - sc.system.x0)[:, :2] / P
    print(f"cs {cs} go {go}", " ".join(f"{v*1e9:6.2f}" for v in cod(x0, u)), "C", 1e-5/P, "Y", sc.stress_intensity(st,P)["Y_I"], flush=True)
