"""Profile and CPU time of the bench-dcbr-seed coarse run (clamped grips, 8 Å band, RESPA
5 x 1 fs, seed 12345, one process). Usage:
  dcbr_seed_profile.py N M K run|prof|groups OUT [SPLIT [REGION]]
(from the repository root with PYTHONPATH=$PWD NUMBA_NUM_THREADS=1). ``run`` prints the
dynamics' wall and CPU time per simulated ps (CPU: the engine loop, Simulation.run) and
the strength, modulus and strain at peak to 15 digits (the force split ``SPLIT``, a key of
``upscale.models.dcbr_engine.SPLITS``, default ``default``), and saves the final positions,
shifts and stress curve to OUT.npz (compare two trees' files with np.array_equal);
``prof`` also writes a cProfile of the whole run to OUT.prof and prints the engine loop's
parts (figures in validation/results/engine.md); ``groups`` prints the time of one evaluation
of each force group under each of the splits (``SPLITS``). ``REGION``: ``band`` (default, the
band from the start) or ``disc`` (bench-dcbr-seed's default: a disc that grows to the band when
the crack starts); the profile then also gives each phase's wall time per ps."""
import sys
import time

import numpy as np

import upscale.engine.simulation as S
from upscale.models.dcbr_dynamic import dynamic_tension
from validation.cases.dcbr import dynamic_scene, lammps_reference_or_run
from validation.cases.references import DYN_LENGTH

n, m, K = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
mode, out = sys.argv[4], sys.argv[5]
split = sys.argv[6] if len(sys.argv) > 6 else "coarse"
region = sys.argv[7] if len(sys.argv) > 7 else "band"
ref = lammps_reference_or_run(n, m, DYN_LENGTH, vacancy=True, protocol="dynamic")
model, dyn = dynamic_scene(n, m, DYN_LENGTH, K, ref, grips="clamped", region=region,
                           r_atomistic=8.0, grow=None if region == "band" else "band")
dyn.pop("grips")
if mode == "groups":
    # median wall time of one evaluation of each force group, coarse split and atoms-free
    # split (fast_interface, fast_ghost), at the reference lattice moved by 1e-4 Å noise, without the
    # transfer of prepare_split
    from upscale.engine.respa import RESPA
    from upscale.engine.simulation import Simulation
    from upscale.models.dcbr_engine import SPLITS, DCBRDefectTubeModel

    for split in SPLITS:
        em = DCBRDefectTubeModel(model, split=split)
        st = Simulation(em.system(), None, em, em.conditions(), RESPA(5.0, 5, force=True)).state
        rng = np.random.default_rng(0)
        em._group(st, "fast"), em._group(st, "slow")  # (compilation)
        for g in ("fast", "slow"):
            ts = []
            for _ in range(50):
                st.y[em.y_rows] += 1e-4 * rng.standard_normal((len(em.y_rows), 3))
                t0 = time.perf_counter()
                em._group(st, g)
                ts.append(time.perf_counter() - t0)
            print(f"| {split} | {g} | {1e3 * np.median(ts):.3f} ms |")
    sys.exit(0)
dyn.update(integrator="respa", outer_dt=5.0, inner=5, split=split)
_run, CPU = S.Simulation.run, [0.0]


def run(self, *a, **k):
    c0 = time.process_time()
    try:
        return _run(self, *a, **k)
    finally:
        CPU[0] += time.process_time() - c0


S.Simulation.run = run
if mode == "prof":
    import cProfile
    import pstats
    pr = cProfile.Profile()
    pr.enable()
rc = dynamic_tension(model, **dyn)
if mode == "prof":
    pr.disable()
    pr.dump_stats(out + ".prof")
    st = pstats.Stats(pr).stats

    def cum(key):
        mod, fn = key.split(":")
        hits = [(v[1], v[3]) for (f, _, name), v in st.items() if name == fn and mod in f]
        return sum(h[0] for h in hits), sum(h[1] for h in hits)

    for label, key in (("engine loop", "simulation.py:run"), ("RESPA.step", "respa.py:step"),
                       ("group forces", "respa.py:_group_forces"),
                       ("fast group", "dcbr_engine.py:_fast_eval"),
                       ("slow group", "dcbr_engine.py:_slow_eval"),
                       ("conditions", "simulation.py:apply_displacement"),
                       ("kicks", "respa.py:_kick"),
                       ("samples", "dcbr_dynamic.py:bookkeeping"),
                       ("ghost refresh", "dcbr_dynamic.py:refresh_ghost"),
                       ("split refresh", "dcbr_dynamic.py:refresh"),
                       ("Tersoff kernel (whole run)", "tersoff_kernels.py:tersoff_range"),
                       ("ghost load (whole run)", "dcbr_defect.py:apply_ghost_load")):
        calls, t = cum(key)
        print(f"| {label} | {calls} | {t:.2f} |")
ps = rc["steps"] * rc["dt_fs"] * 1e-3
print(f"dynamics wall {rc['dynamics_s']:.2f} s, {rc['dynamics_s'] / ps:.3f} s/ps; engine loop "
      f"CPU {CPU[0]:.2f} s, {CPU[0] / ps:.3f} s/ps; set-up {rc['setup_relax_s']:.2f} s; "
      f"{rc['steps']} outer steps")
g = rc["grown_at"]
if g is not None:
    tb = rc["dynamics_before_growth_s"]
    print(f"grown at {g['time_ps']:.3f} ps: {tb / g['time_ps']:.3f} s/ps before, "
          f"{(rc['dynamics_s'] - tb) / (ps - g['time_ps']):.3f} s/ps after")
print(f"strength {rc['strength_GPa']:.15g} modulus {rc['youngs_modulus_TPa']:.15g} "
      f"strain at peak {rc['strain_at_peak']:.15g}")
np.savez(out + ".npz", pos=rc["positions"], delta=rc["delta"],
         stress=np.asarray(rc["curve"]["stress_GPa"]))
