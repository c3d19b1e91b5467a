"""restart-exact: runs killed with SIGKILL and resumed end bit for bit where the uninterrupted
runs end (:mod:`upscale.experiments.kill_resume`).

The runs: the pre-cracked plate (``upscale plate``, PMB, velocity Verlet with bond
failure), the CPD bar's Newton solve (load steps), the periodic DCBR tube's dynamic
tension on the engine (Nose-Hoover chain, links breaking) and the DCBR *vacancy* tube's
dynamic tension on the engine (:func:`upscale.experiments.scenes.dcbr_dynamic.dynamic_tension`,
the (10,10) 150 Å coarsening-2 tube of ``dcbr-seeds`` pulled to failure;
``--quick``: a (6,6) 60 Å tube), ``dcbr_bit_identical``. The reference of each is the same
run uninterrupted, in its own process.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

from upscale.experiments.kill_resume import (cpd_kill_resume, dcbr_kill_resume,
                                             dcbr_vacancy_kill_resume, plate_kill_resume)
from validation.registry import case


def _args(p):
    p.add_argument("--n", type=int, default=None,
                   help="plate particles a side (default 500; --quick 40)")
    p.add_argument("--t-end", type=float, default=None,
                   help="plate end time, s (default 5e-5; --quick 3e-5)")
    p.add_argument("--checkpoint-every", type=int, default=None,
                   help="plate checkpoint interval (default 200; --quick 10)")
    p.add_argument("--kill-at", type=int, default=None,
                   help="plate: the step to kill at (default 1000; --quick: a random step)")
    p.add_argument("--seed", type=int, default=None, help="seed of the random kill steps")
    p.add_argument("--threads", type=int, default=1, help="numba threads of every run")


@case("restart-exact", "SIGKILL a run at a step, resume it: plate, CPD Newton and DCBR bit "
      "for bit against the uninterrupted runs", add_arguments=_args,
      target="plate, CPD Newton and DCBR (periodic and vacancy) resumed bit for bit")
def _restart_exact(args):
    q = args.quick
    n = args.n or (40 if q else 500)
    t_end = args.t_end or (3e-5 if q else 5e-5)
    every = args.checkpoint_every or (10 if q else 200)
    kill = args.kill_at if args.kill_at is not None else (None if q else 1000)
    work = Path(tempfile.mkdtemp(prefix="restart-exact-", dir=args.outdir))
    print(f"plate {n} x {n}, t_end {t_end:g} s, checkpoint every {every} steps "
          f"(runs in {work})", flush=True)
    plate = plate_kill_resume(work / "plate", n=n, t_end=t_end, every=every, kill_at=kill,
                              threads=args.threads, seed=args.seed)
    print("CPD bar, 8 Newton load steps", flush=True)
    cpd = cpd_kill_resume(work / "cpd", threads=args.threads, seed=args.seed)
    print("DCBR periodic (10,10) K2 tube, dynamic tension on the engine", flush=True)
    dcbr = dcbr_kill_resume(work / "dcbr", steps=150, every=20, strain_rate=2e-3,
                            threads=args.threads, seed=args.seed)
    tube = "small" if q else "scene"
    print(f"DCBR vacancy tube ({'(6,6) 60 Å' if q else '(10,10) 150 Å K2'}), dynamic tension on "
          "the engine", flush=True)
    vac = dcbr_vacancy_kill_resume(work / "dcbr-vacancy", tube=tube, every=50 if q else 200,
                                   threads=args.threads, seed=args.seed)
    return {"plate_bit_identical": plate["bit_identical"], "cpd_bit_identical": cpd["bit_identical"],
            "dcbr_bit_identical": vac["bit_identical"], "dcbr_vacancy": vac,
            "dcbr_periodic_engine_bit_identical": dcbr["bit_identical"], "dcbr_periodic": dcbr,
            "plate": plate, "cpd": cpd,
            "pass": bool(plate["bit_identical"] and cpd["bit_identical"] and dcbr["bit_identical"]
                         and vac["bit_identical"])}
