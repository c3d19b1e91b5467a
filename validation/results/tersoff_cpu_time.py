"""bench-tersoff's one-thread race timed by process CPU time instead of wall time.

Usage: ``PYTHONPATH=$PWD python validation/results/tersoff_cpu_time.py [repeats]``.
Uses the case's own timers (``validation.cases.tersoff``) on its structures (diamond and
graphite, ~8,000 and ~100,000 atoms), alternating ours and LAMMPS ``repeats`` times and
keeping each side's best, exactly as ``bench-tersoff`` does, but with the clock replaced
by ``time.process_time``: on a loaded machine this is what each code costs while it runs.
"""
import sys
import time
import types

import numpy as np

import validation.cases.tersoff as T


def main(repeats: int = 3):
    T.time = types.SimpleNamespace(perf_counter=time.process_time)
    rows = []
    for kind in ("diamond", "graphite"):
        for n_target in (8000, 100000):
            atoms = T.bench_structure(kind, n_target)
            nsteps = max(5, int(1e6 / len(atoms)))
            r = T._race(atoms, nsteps, repeats, 1)
            rows.append((kind, len(atoms), 1e6 * r["calculator"], 1e6 * r["kernel"], 1e6 * r["lammps"]))
            k, n, c, kk, lm = rows[-1]
            print(f"{k:9s} {n:7d} atoms: ours {c:.3f} us (kernel {kk:.3f}), LAMMPS {lm:.3f} us per atom-step "
                  f"(CPU time) -> ratio {c / lm:.3f} (kernel {kk / lm:.3f})", flush=True)
    print("max ratio", max(c / lm for _, _, c, _, lm in rows))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
