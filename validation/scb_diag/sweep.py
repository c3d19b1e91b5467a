"""One-line elastic SCB checks against the segment FE for scene keyword sets.
Usage: sweep.py 'dx=2e-3,stabilisation=0.1' 'al=30,stabilisation=1.0' ...

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
import sys, time, json, numpy as np
from upscale.experiments.scenes.scb import SCBScene
from validation.fem_scb import solve_scb
import functools
@functools.lru_cache(None)
def fe(al, w): return solve_scb(al, w=w, h_tip=4e-5)
for spec in sys.argv[1:]:
    kw = dict(eval("dict(%s)" % spec))
    al = kw.pop("al", 0.0); dx = kw.get("dx", 1e-3)
    win = kw.pop("win", (0.2, 0.6))
    t = time.time()
    sc = SCBScene(al, **kw)
    st, P = sc.elastic()
    k = sc.stress_intensity(st, P, window=win)
    f = fe(al, 3*dx)
    print(spec, f"n={sc.system.n} Y_I {k['Y_I']:.4f}/{f['Y_I']:.4f} ({100*(k['Y_I']/f['Y_I']-1):+.1f}%) Y_II {k['Y_II']:.4f}/{f['Y_II']:.4f} "
          f"({100*(k['Y_II']/f['Y_II']-1) if abs(f['Y_II'])>0.05 else 0:+.1f}%) C {1e-5/P/f['compliance_m_per_N']*100-100:+.2f}% {time.time()-t:.0f}s", flush=True)
