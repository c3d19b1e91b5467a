"""Whole SCB fracture runs (stop at half the peak) with the engine's Equilibrium factor on two
orderings, one after the other in one process: P_c, equilibria, wall / CPU, factor and CG time.
Usage: ordering_ab.py DX ALPHA[,ALPHA...] ORDER[,ORDER...]
ORDER: a SuperLU permc_spec (MMD_AT_PLUS_A, the engine's; COLAMD; ...) or METIS_ND (needs pymetis,
not a project dependency: SuperLU on the natural order of the METIS nested-dissection permutation).

Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import sys
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import upscale.engine.quasistatic as q
from upscale.experiments.scenes.scb import SCBScene


class PermutedLU:
    def __init__(self, A, perm, **opts):
        self.perm = perm
        self.lu = spla.splu(sp.csc_matrix(A[perm][:, perm]), permc_spec="NATURAL", **opts)

    def solve(self, b):
        x = np.empty_like(b)
        x[self.perm] = self.lu.solve(b[self.perm])
        return x


def metis_factor(self, Kff):
    import pymetis

    t = time.perf_counter()
    d = Kff.diagonal()
    shift = 1e-8 * float(np.mean(np.abs(d))) + np.where(d == 0, float(np.mean(np.abs(d))), 0.0)
    A = sp.csr_matrix(Kff + sp.diags(shift))
    if getattr(self, "_perm", None) is None:
        G = A.copy()
        G.data[:] = 1.0
        G.setdiag(0)
        G.eliminate_zeros()
        adj = pymetis.CSRAdjacency(adj_starts=G.indptr.astype(np.int64), adjacent=G.indices.astype(np.int64))
        self._perm = np.asarray(pymetis.nested_dissection(adjacency=adj)[0])
    self._lu = PermutedLU(A, self._perm, diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    self.stats["factor_s"] += time.perf_counter() - t
    self.stats["factorisations"] += 1


dx = float(sys.argv[1])
alphas = [float(a) for a in sys.argv[2].split(",")]
orders = sys.argv[3].split(",")
orig_init, orig_factor = q.Equilibrium.__init__, q.Equilibrium._factor
for al in alphas:
    for o in orders:
        def patched(self, *a, _o=o, **k):
            if _o != "METIS_ND":
                k.setdefault("permc_spec", _o)
            orig_init(self, *a, **k)
        q.Equilibrium.__init__ = patched
        q.Equilibrium._factor = metis_factor if o == "METIS_ND" else orig_factor
        sc = SCBScene(al, dx=dx, r_s=1e-3)
        t = time.perf_counter()
        c0 = time.process_time()
        st, c = sc.fracture(stop_fraction=0.5)
        sv = c.time_split_s["solver"]
        print(f"alpha {al:g} {o:14s} P_c {c.peak[0]:.10g} N eq {len(c.load)} wall {time.perf_counter() - t:.1f} "
              f"cpu {time.process_time() - c0:.1f} factor {sv['factor_s']:.1f} ({sv['factorisations']}) "
              f"cg {sv['cg_s']:.1f} ({sv['cg_iterations']}) asm {sv['assembly_s']:.1f}", flush=True)
