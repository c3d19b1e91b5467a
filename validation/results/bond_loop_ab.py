"""Before/after of the PMB and LPS bond loops in one process, interleaved with LAMMPS.

Usage (from the repository root of the branch with the half bond list)::

    git archive <before-commit> | tar -x -C /tmp/before
    PYTHONPATH=$PWD python validation/results/bond_loop_ab.py /tmp/before [rounds]

Loads ``upscale/models/bond_based.py`` and ``state_based.py`` of the *before* tree under
other module names (they import only the engine's unchanged kernels), prepares both
versions of PMB and LPS on the bench-pmb block (31^3 particles, LAMMPS's example
material, partial volumes as LAMMPS), and times one ``step_force`` of each and ``run 20``
of LAMMPS peri/pmb and peri/lps in interleaved rounds on one thread. Prints the best wall
and CPU (process) time of each and the ratios; CPU time is the steadier figure on a
loaded machine.
"""
import importlib.util
import os
import sys
import tempfile
import time

import numpy as np

from upscale.engine import ParticleSystem, State, build_family
from upscale.engine.kernels import set_threads
from upscale.engine.lammps_peri import LAMMPS_EXAMPLE as P, LammpsPeri
from upscale.models.bond_based import PMB
from upscale.models.state_based import LPS
from validation.cases.peridynamics import _engine_force_time, _LammpsPairTimer


def _load_module(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(before: str, rounds: int = 5, cells: int = 30):
    old_bb = _load_module(os.path.join(before, "upscale/models/bond_based.py"), "before_bond_based")
    old_sb = _load_module(os.path.join(before, "upscale/models/state_based.py"), "before_state_based")
    lp = LammpsPeri("pmb", (cells,) * 3, P["lc"], P["horizon"], P["density"], {"c": P["c"], "s00": P["s00"]})
    x = lp.positions()
    lp.close()
    sysm = ParticleSystem(x, P["lc"] ** 3, P["density"], spacing=P["lc"])
    fam = build_family(sysm, P["horizon"], partial_volume="lammps")
    models = {"pmb_before": old_bb.PMB(c=P["c"], s0=P["s00"]), "pmb_after": PMB(c=P["c"], s0=P["s00"]),
              "lps_before": old_sb.LPS(K=P["K"], G=P["G"], s0=P["s00"]),
              "lps_after": LPS(K=P["K"], G=P["G"], s0=P["s00"])}
    for m in models.values():
        m.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    set_threads(1)
    best = {}
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as d:
        lmp = {s: _LammpsPairTimer(s, cells, os.path.join(d, f"log.{s}")) for s in ("pmb", "lps")}
        try:
            for _ in range(rounds):
                for s in ("pmb", "lps"):
                    for tag in ("before", "after"):
                        w, c = _engine_force_time(models[f"{s}_{tag}"], st, 10)
                        best[f"{s}_{tag}_wall"] = min(best.get(f"{s}_{tag}_wall", np.inf), w)
                        best[f"{s}_{tag}_cpu"] = min(best.get(f"{s}_{tag}_cpu", np.inf), c)
                    pair, loop, cpu = lmp[s].time(20)
                    best[f"{s}_lammps_wall"] = min(best.get(f"{s}_lammps_wall", np.inf), pair)
                    best[f"{s}_lammps_cpu"] = min(best.get(f"{s}_lammps_cpu", np.inf), cpu)
        finally:
            for t in lmp.values():
                t.close()
    load1 = os.getloadavg()[0]
    print(f"{sysm.n} particles, {fam.nb} directed bonds, best of {rounds} interleaved rounds, "
          f"one thread, load average {load0:.2f} -> {load1:.2f}")
    print(f"{'':12s} {'wall s':>9s} {'cpu s':>9s} {'x LAMMPS wall':>14s} {'x LAMMPS cpu':>13s}")
    for s in ("pmb", "lps"):
        for tag in ("lammps", "before", "after"):
            w, c = best[f"{s}_{tag}_wall"], best[f"{s}_{tag}_cpu"]
            print(f"{s + ' ' + tag:12s} {w:9.4f} {c:9.4f} {best[f'{s}_lammps_wall'] / w:14.2f} "
                  f"{best[f'{s}_lammps_cpu'] / c:13.2f}")
        print(f"{s} after/before speed-up: wall {best[f'{s}_before_wall'] / best[f'{s}_after_wall']:.2f}, "
              f"cpu {best[f'{s}_before_cpu'] / best[f'{s}_after_cpu']:.2f}")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 5)
