"""Assembly, residual, matvec, factor and solve times of the SCB tangent (principal criterion,
r_s = 1 mm) for SuperLU's MMD ordering, a geometric nested dissection (separator 1 and 2
horizons) and a single-precision factor, in one process. Usage: lu_orderings.py DX

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import sys
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from upscale.experiments.scenes.scb import SCBScene
from upscale.engine.quasistatic import Equilibrium
dx = float(sys.argv[1])
sc = SCBScene(0.0, dx=dx, r_s=1e-3)
eq = Equilibrium(sc.model, sc.fixed)
st = sc.state()
t = time.perf_counter(); eq._assemble(st); print("n", sc.system.n, "assembly", time.perf_counter() - t, "nnz", eq._K.nnz, flush=True)
K = sp.csc_matrix(eq._K)
b = np.random.default_rng(0).standard_normal(K.shape[0])
# residual timing
sc.model.residual(st)
t = time.perf_counter()
for _ in range(5): sc.model.residual(st)
print("residual", (time.perf_counter()-t)/5, flush=True)
t = time.perf_counter()
for _ in range(5): K @ b
print("matvec", (time.perf_counter()-t)/5, flush=True)
# geometric nested dissection on particle coordinates
x = sc.system.x0[:, :2]
free = eq.free
pid = free // 3
def nd(ids, depth=0):
    if ids.size < 200:
        return ids
    p = x[ids]
    ax = int(np.argmax(p.max(0) - p.min(0)))
    med = np.median(p[:, ax])
    w = sc.model.family.horizon if hasattr(sc.model.family, 'horizon') else 3*dx
    sep = np.abs(p[:, ax] - med) <= 1.01 * w   # stencil reach ~ 2 horizons -> half on each side
    left = ids[(p[:, ax] < med) & ~sep]; right = ids[(p[:, ax] >= med) & ~sep]
    return np.concatenate([nd(left, depth+1), nd(right, depth+1), ids[sep]])
def run(name, lu, Kp=None):
    t = time.perf_counter()
    for _ in range(3): xx = lu.solve(bb if Kp is not None else b)
    ts = (time.perf_counter() - t) / 3
    return ts
opts = dict(diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
t = time.perf_counter(); lu = spla.splu(K, permc_spec="MMD_AT_PLUS_A", **opts); tf = time.perf_counter() - t
t = time.perf_counter()
for _ in range(3): xx = lu.solve(b)
print("MMD sym", f"factor {tf:.2f} solve {(time.perf_counter()-t)/3*1e3:.1f} ms fill {lu.L.nnz + lu.U.nnz}", flush=True)
for sepw in (1.0, 2.0):
    dofs_p = pid
    def nd2(ids):
        if ids.size < 100: return ids
        p = x[ids]; ax = int(np.argmax(p.max(0) - p.min(0))); med = np.median(p[:, ax])
        sep = np.abs(p[:, ax] - med) <= sepw * 3 * dx
        left = ids[(p[:, ax] < med) & ~sep]; right = ids[(p[:, ax] >= med) & ~sep]
        return np.concatenate([nd2(left), nd2(right), ids[sep]])
    pord = nd2(np.unique(pid))
    rank = np.empty(sc.system.n, int); rank[pord] = np.arange(pord.size)
    perm = np.lexsort((free % 3, rank[pid]))
    Kp = sp.csc_matrix(K[perm][:, perm])
    t = time.perf_counter(); lu2 = spla.splu(Kp, permc_spec="NATURAL", **opts); tf = time.perf_counter() - t
    bb = b[perm]
    t = time.perf_counter()
    for _ in range(3): xx = lu2.solve(bb)
    print("ND", sepw, f"factor {tf:.2f} solve {(time.perf_counter()-t)/3*1e3:.1f} ms fill {lu2.L.nnz + lu2.U.nnz}", flush=True)
# float32
t = time.perf_counter(); lu3 = spla.splu(K.astype(np.float32), permc_spec="MMD_AT_PLUS_A", **opts); tf = time.perf_counter() - t
b32 = b.astype(np.float32)
t = time.perf_counter()
for _ in range(3): xx = lu3.solve(b32)
print("MMD f32", f"factor {tf:.2f} solve {(time.perf_counter()-t)/3*1e3:.1f} ms", flush=True)
