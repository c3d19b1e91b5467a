"""Factor and solve times of the SCB tangent for SuperLU orderings (one process). Usage: lu.py DX

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import time, numpy as np, scipy.sparse as sp, scipy.sparse.linalg as spla, sys
from upscale.experiments.scenes.scb import SCBScene
from upscale.engine.quasistatic import Equilibrium
dx = float(sys.argv[1])
sc = SCBScene(0.0, dx=dx, r_s=39.26*dx)
eq = Equilibrium(sc.model, sc.fixed)
st = sc.state()
t = time.perf_counter(); eq._assemble(st); print("n", sc.system.n, "assembly", time.perf_counter() - t, "nnz", eq._K.nnz)
K = sp.csc_matrix(eq._K)
b = np.random.default_rng(0).standard_normal(K.shape[0])
for spec, opts in (("COLAMD", {}), ("MMD_AT_PLUS_A", {}), ("MMD_AT_PLUS_A", dict(diag_pivot_thresh=0.0, options=dict(SymmetricMode=True)))):
    t = time.perf_counter(); lu = spla.splu(K, permc_spec=spec, **opts); tf = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(5): x = lu.solve(b)
    ts = (time.perf_counter() - t) / 5
    print(spec, opts, f"factor {tf:.2f} s solve {ts*1e3:.1f} ms fill {lu.L.nnz + lu.U.nnz} res {np.linalg.norm(K@x-b)/np.linalg.norm(b):.1e}")
try:
    import sksparse; print("sksparse available")
except Exception as e: print("no sksparse", e)
