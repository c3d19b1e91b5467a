"""The SCB tangent's factorisation with SuperLU (the engine's: MMD on K + K^T, symmetric mode),
SuperLU on a METIS nested-dissection ordering, and MKL PARDISO (real symmetric positive
definite, LDL^T), in one process: factor time, one solve, fill, relative residual.
Usage: factor_libraries.py DX [REPEATS]

pymetis and pypardiso are not project dependencies; the comparison runs what is importable.
To try them without touching the project's environment:
    .venv/bin/pip install --prefix /tmp/x --no-deps pymetis pypardiso mkl intel-openmp tbb tcmlib umf intel-cmplr-lib-ur
    PYPARDISO_MKL_RT=/tmp/x/lib/libmkl_rt.so.3 MKL_NUM_THREADS=1 \
    PYTHONPATH=$PWD:/tmp/x/lib/python3.11/site-packages .venv/bin/python validation/scb_diag/factor_libraries.py 5e-4

Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import sys
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from upscale.engine.quasistatic import Equilibrium
from upscale.experiments.scenes.scb import SCBScene

dx = float(sys.argv[1])
repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 2
sc = SCBScene(0.0, dx=dx, r_s=1e-3)
K = sc.model.tangent(sc.state()).tocsr()
free = Equilibrium(sc.model, sc.fixed).free
Kff = K[free][:, free].tocsr()
b = np.random.default_rng(0).standard_normal(free.size)
opts = dict(diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
print(f"dx {dx * 1e3:g} mm: {free.size} free dofs, {Kff.nnz} nonzeros")


def report(name, factor, solve, fill=None):
    tf, ts = np.inf, np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        f = factor()
        tf = min(tf, time.perf_counter() - t)
        t = time.perf_counter()
        x = solve(f)
        ts = min(ts, time.perf_counter() - t)
    res = np.linalg.norm(Kff @ x - b) / np.linalg.norm(b)
    fl = f"{fill(f) / 1e6:.1f} M" if fill else "-"
    print(f"{name:28s} factor {tf:7.3f} s  solve {ts * 1e3:7.1f} ms  fill {fl:>8s}  residual {res:.1e}", flush=True)


report("SuperLU MMD symmetric", lambda: spla.splu(Kff.tocsc(), permc_spec="MMD_AT_PLUS_A", **opts),
       lambda lu: lu.solve(b), lambda lu: lu.L.nnz + lu.U.nnz)
try:
    import pymetis
except ImportError:
    print("pymetis not importable: METIS ordering skipped")
else:
    G = Kff.copy()
    G.data[:] = 1.0
    G.setdiag(0)
    G.eliminate_zeros()
    t = time.perf_counter()
    perm = np.asarray(pymetis.nested_dissection(xadj=G.indptr, adjncy=G.indices)[0])
    print(f"METIS ordering {time.perf_counter() - t:.3f} s")
    P = Kff[perm][:, perm].tocsc()

    def solve_nd(lu):
        x = np.empty_like(b)
        x[perm] = lu.solve(b[perm])
        return x

    report("SuperLU METIS-ND symmetric", lambda: spla.splu(P, permc_spec="NATURAL", **opts), solve_nd,
           lambda lu: lu.L.nnz + lu.U.nnz)
try:
    import pypardiso
except ImportError:
    print("pypardiso not importable: PARDISO skipped")
else:
    U = sp.triu(Kff, format="csr")

    def fac():
        ps = pypardiso.PyPardisoSolver(mtype=2)
        ps.factorize(U)
        return ps

    report("MKL PARDISO SPD (pypardiso)", fac, lambda ps: ps.solve(U, b))
