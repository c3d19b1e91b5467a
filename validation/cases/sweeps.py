"""Sweeps on Dask (``upscale.experiments.sweep``) checked on real ensembles.

``sweep-check``: the (10,10) 4-atom-vacancy tube's coarse thermal seeds at coarsening 2
(``dcbr-seeds``' scene, seeds 1000, 1001, ...) (1) on two LocalCluster workers, plus one run
that raises (a negative temperature), listed with its error while the others complete; (2)
called one after another in this process (a fresh run of the current code, not a stored
one): every seed's five figures equal, and the two-worker speed-up over it, judged only when
the machine was quiet at the start; (3) through ``upscale sweep``, killed with SIGKILL (its
whole process group) once half the runs are written, then restarted: runs redone, runs lost,
and the final table against the uninterrupted one (wall times aside); (4) with
``--lammps-seeds``, LAMMPS reference seeds as sweep tasks against
``data/reference/seed_spread.json``.
"""
from __future__ import annotations

import csv
import datetime
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from validation.registry import case

ROOT = Path(__file__).resolve().parents[2]
KEYS = ("strength_GPa", "strain_at_peak", "youngs_modulus_TPa", "strain_at_peak_ext",
        "youngs_modulus_ext_TPa")
SEED0 = 1000  # dcbr-seeds' first seed


# ----------------------------------------------------------------------------- scenes
def coarse_vacancy_seed(n: int = 10, m: int = 10, coarsening: float = 2.0, seed: int = SEED0,
                        temperature: float = 10.0) -> dict:
    """One thermal seed of the coarse dynamic tension of the (n, m) 4-atom-vacancy tube.

    The single-seed run of ``dcbr-seeds`` (its scene, :func:`upscale.experiments.
    tube_tension.dynamic_scene`, and protocol, LAMMPS's grips and gauge from the dynamic reference),
    reached through this one function so that the sweep follows the scene wherever it is
    kept. Returns the five figures ``dcbr-seeds`` stores, the grips and the DOF.
    """
    from upscale.experiments.lammps.cache import cache_dir
    from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension
    from upscale.experiments.scenes.tube_tension import dynamic_scene, lammps_reference

    ref = lammps_reference(n, m, 150.0, protocol="dynamic", vacancy=True, progress=False,
                           cache_dir=cache_dir("references"))
    model, dyn = dynamic_scene(n, m, 150.0, coarsening, ref, vacancy=True)
    grips = dyn.pop("grips")
    r = dynamic_tension(model, seed=seed, temperature=temperature, **dyn)
    return {**{k: r[k] for k in KEYS}, "grips": grips, "dof": r.get("dof")}


def lammps_vacancy_seed(n: int = 10, m: int = 10, seed: int = 4928459, nprocs: int = 1) -> dict:
    """One thermal seed of the LAMMPS dynamic reference of the (n, m) vacancy tube, the
    protocol of ``reference-seeds`` (:func:`upscale.experiments.lammps.tension.dynamic_tension`), on
    ``nprocs`` MPI ranks (1: in the worker's process; more: through the mpich wheel's
    ``mpiexec``)."""
    from upscale.build import swcnt, vacancy
    from upscale.experiments.lammps.tension import dynamic_tension

    atoms = vacancy(swcnt(n, m, 150.0), n=4)
    r = dynamic_tension(atoms, "tersoff:BNC.tersoff", cutoff="step", seed=seed, nprocs=nprocs)
    return {k: r[k] for k in KEYS}


# ------------------------------------------------------------------------------ check
def _ensemble_spec(seeds, out: Path) -> dict:
    return {"scene": f"{__name__}:coarse_vacancy_seed", "output": str(out),
            "params": {"n": 10, "m": 10, "coarsening": 2.0}, "seeds": list(seeds),
            "runs": [{"seed": SEED0, "temperature": -1.0}],  # raises: a deliberate failure
            "plot": {"x": "coarsening", "metrics": ["strength_GPa", "youngs_modulus_TPa",
                                                    "strain_at_peak"]}}


def _toml(spec: dict) -> str:
    """The ensemble spec as TOML (the command line reads files; its values are simple)."""
    val = json.dumps
    lines = [f"scene = {val(spec['scene'])}", f"output = {val(spec['output'])}",
             f"seeds = {val(spec['seeds'])}"]
    for sec in ("params", "plot"):
        lines.append(f"[{sec}]")
        lines += [f"{k} = {val(v)}" for k, v in spec[sec].items()]
    for r in spec["runs"]:
        lines.append("[[runs]]")
        lines += [f"{k} = {val(v)}" for k, v in r.items()]
    return "\n".join(lines) + "\n"


def _csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def _no_wall(rows):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


def _cli(spec_file: Path, workers: int) -> list[str]:
    return [sys.executable, "-m", "upscale.cli", "sweep", str(spec_file), "--workers",
            str(workers), "--no-progress"]


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def _kill_and_resume(spec: dict, workers: int, kill_after: int) -> dict:
    """Run the sweep through ``upscale sweep``, SIGKILL its process group after
    ``kill_after`` results are on disk, restart it to the end; count what was redone/lost."""
    from upscale.experiments import sweep

    out = Path(spec["output"])
    f = out.parent / f"{out.name}.toml"
    f.write_text(_toml(spec))
    runs = out / "runs"
    t0 = time.perf_counter()
    proc = subprocess.Popen(_cli(f, workers), env=_env(), start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    while proc.poll() is None and len(list(runs.glob("*/result.json"))) < kill_after:
        time.sleep(0.1)
    if proc.poll() is not None:
        raise RuntimeError(f"the sweep ended (exit {proc.returncode}) before {kill_after} runs "
                           f"were written; run {' '.join(_cli(f, workers))} to see why")
    os.killpg(proc.pid, signal.SIGKILL)  # the driver, its nannies and workers
    proc.wait()
    t_kill = time.perf_counter() - t0
    survivors = True
    for _ in range(50):
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            survivors = False
            break
        time.sleep(0.1)
    before = {p.parent.name: (p.stat().st_ino, p.stat().st_mtime_ns)
              for p in runs.glob("*/result.json")}
    partial = list(runs.glob("*/.result.json.*.tmp"))
    res = subprocess.run(_cli(f, workers), env=_env(), capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"restart failed (exit {res.returncode}): "
                           f"{res.stderr.strip().splitlines()[-1:]}")
    sessions = sorted((out / "sessions").glob("*.json"), key=lambda p: p.stat().st_mtime_ns)
    restart = json.loads(sessions[-1].read_text())
    after = {p.parent.name: (p.stat().st_ino, p.stat().st_mtime_ns)
             for p in runs.glob("*/result.json")}
    redone = {r for r in restart["executed"] if r in before} | {
        r for r, st in before.items() if after.get(r) != st}
    rows = sweep.gather(sweep.load_spec(spec))["rows"]
    done = {r["run_id"] for r in rows if r["status"] in ("ok", "error")}
    lost = (set(before) - done) | {r["run_id"] for r in rows if r["status"] == "missing"}
    return {"finished_before_kill": len(before), "killed_after_s": t_kill,
            "processes_left_after_kill": survivors, "temporary_files_left": len(partial),
            "restart_executed": len(restart["executed"]), "restart_skipped":
            len(restart["skipped"]), "redone": sorted(redone), "lost": sorted(lost),
            "table": str(out / "results.csv")}


def _args(p):
    p.add_argument("--seeds", type=int, default=None,
                   help="coarse seeds in the ensemble (default 16, --quick 4)")
    p.add_argument("--lammps-seeds", type=int, default=None,
                   help="LAMMPS reference seeds run as a sweep of their own and compared "
                        "with data/reference/seed_spread.json (default 2, --quick 0)")


@case("sweep-check", "sweeps on Dask: the (10,10) vacancy K=2 seed ensemble as a sweep "
      "against a fresh serial run of the same seeds, speed-up of 2 workers, SIGKILL + restart, "
      "a failing run",
      add_arguments=_args,
      target="every seed's five figures equal to a fresh serial run; the failing run listed; the killed sweep resumes with nothing redone or lost and the same table; speed-up >= 1.7x when the machine was quiet")
def _sweep_check(args):
    from upscale.experiments import sweep

    nseeds = args.seeds or (4 if args.quick else 16)
    if nseeds < 1:
        raise SystemExit(f"--seeds {nseeds}; must be at least 1")
    nlammps = args.lammps_seeds if args.lammps_seeds is not None else (0 if args.quick else 2)
    seeds = [SEED0 + i for i in range(nseeds)]
    base = Path(args.outdir) / datetime.datetime.now(datetime.timezone.utc).strftime(
        "run-%Y%m%dT%H%M%SZ")
    load0 = os.getloadavg()
    print(f"sweep-check: {nseeds} coarse seeds + 1 failing run; load average {load0[0]:.2f} "
          f"(1 min), {os.cpu_count()} cores; folders under {base}", flush=True)

    # 1. two workers, uninterrupted
    spec_a = _ensemble_spec(seeds, base / "two_workers")
    rep_a = sweep.run_sweep(spec_a, workers=2)
    rows_a = sweep.gather(sweep.load_spec(spec_a))["rows"]
    ens = [r for r in rows_a if r.get("temperature") is None]

    # 2. the same seeds called one after another in this process: the fresh run of the
    # current code the sweep must reproduce, and the serial time the speed-up is taken on
    load1 = os.getloadavg()
    t0 = time.perf_counter()
    fresh = {s: coarse_vacancy_seed(seed=s) for s in seeds}
    serial_s = time.perf_counter() - t0
    per_seed = [{"seed": r["seed"], "status": r["status"], "strength_GPa": r.get("strength_GPa"),
                 "fresh_strength_GPa": fresh[r["seed"]]["strength_GPa"],
                 "all_5_equal": r["status"] == "ok"
                 and all(r[k] == fresh[r["seed"]][k] for k in KEYS)} for r in ens]
    reproduces = len(per_seed) == nseeds and all(p["all_5_equal"] for p in per_seed)
    bad = [r for r in rows_a if r["status"] == "error"]
    rec = json.loads((base / "two_workers" / "runs" / bad[0]["run_id"] / "result.json")
                     .read_text()) if bad else {}
    failed_recorded = (len(bad) == 1 and bad[0].get("temperature") == -1.0
                       and "temperature=-1.0" in bad[0]["error"]
                       and "Traceback" in rec.get("traceback", "")
                       and all(r["status"] == "ok" for r in ens))
    # Quiet means nothing else ran when the check started: the later load averages include
    # this check's own workers, so they are reported, not judged.
    quiet = load0[0] < 0.5
    speed = {"speedup_2workers": serial_s / rep_a["wall_s"], "serial_s": serial_s,
             "wall_2workers_s": rep_a["wall_s"],
             "load_avg_1min_at_start": [load0[0], load1[0], os.getloadavg()[0]],
             "speedup_pass": None}
    speed["speedup_pass"] = speed["speedup_2workers"] >= 1.7 if quiet else None

    # 3. SIGKILL midway, restart
    spec_c = _ensemble_spec(seeds, base / "killed")
    kr = _kill_and_resume(spec_c, 2, max(1, (nseeds + 1) // 2))
    same_table = _no_wall(_csv(kr["table"])) == _no_wall(_csv(rep_a["table"]))

    # 4. LAMMPS reference seeds as tasks
    lam = {}
    if nlammps:
        from upscale.experiments.scenes.tube_tension import REFERENCE_DIR

        ref = json.loads((REFERENCE_DIR / "seed_spread.json").read_text())
        ref = {r["seed"]: r for r in ref.get("result", ref)["tubes"]["10,10"]["runs"]}
        lseeds = list(ref)[:nlammps]  # the stored seeds in their order, the kept one first
        spec_d = {"scene": f"{__name__}:lammps_vacancy_seed", "output": str(base / "lammps"),
                  "seeds": lseeds}
        rep_d = sweep.run_sweep(spec_d, workers=min(2, len(lseeds)))
        rows_d = sweep.gather(sweep.load_spec(spec_d))["rows"]
        eq = [r["status"] == "ok" and all(r[k] == ref[r["seed"]][k] for k in KEYS)
              for r in rows_d]
        lam = {"lammps_seeds": lseeds, "lammps_reproduces_stored": all(eq),
               "lammps_wall_s": rep_d["wall_s"]}

    out = {"reproduces_fresh_run": reproduces, "seeds": nseeds,
           "compared": "every seed's 5 figures against the scene called directly",
           "speedup_2workers": speed.get("speedup_2workers"),
           "resumed_redone_runs": len(kr["redone"]), "resumed_lost_runs": len(kr["lost"]),
           "failed_run_recorded": failed_recorded,
           "resumed_table_equals_uninterrupted": same_table,
           "processes_left_after_kill": kr["processes_left_after_kill"],
           "killed_after_runs": kr["finished_before_kill"],
           **{k: v for k, v in speed.items() if k != "speedup_2workers"}, **lam,
           "per_seed": per_seed, "folders": str(base),
           "code_version": rep_a["code_version"]}
    checks = [reproduces, failed_recorded, same_table, not kr["redone"], not kr["lost"],
              not kr["processes_left_after_kill"], lam.get("lammps_reproduces_stored", True),
              speed.get("speedup_pass") is not False]
    out["pass"] = all(checks)
    return out


# ----------------------------------------------------------------------------- sweep-tube
#: the tube scene by name over chirality x defects x seed: the engine's atomistic tube in the
#: dynamic pull (the scene's parameters; 10 Å grips on 60 Å tubes keep it to seconds a run)
TUBE_SWEEP = {"scene": "tension", "repeats": 2, "seed_start": 1,
              "params": {"model": "atomistic", "protocol": "dynamic", "length": 60.0,
                         "grip": 10.0, "maximum": 0.3, "progress": False},
              "grid": {"chirality": [[5, 5], [8, 0]], "defects": ["", "v1@0.5@0"]},
              "plot": {"x": "defects", "metrics": ["strength_GPa"]}}


@case("sweep-tube", "the tube scene swept by name over chirality x defects x seed on Dask "
      "(every run finishes; each point's seed mean; a run equals the scene called directly)",
      target="all 8 runs finish, 4 points x 2 seeds, a run's strength equals the scene "
             "called directly", quick=False)
def _sweep_tube(args):
    from upscale import experiments
    from upscale.experiments import sweep

    import numba

    spec = dict(TUBE_SWEEP, output=str(Path(args.outdir) / "sweep"))
    # one numba thread in each task and in the direct call below: the thread count changes
    # the reductions' order, and a 10 K pull carries that round-off into its figures
    sweep.run_sweep(spec, workers=2, numba_threads=1, progress=False)
    rows = sweep.gather(sweep.load_spec(spec))["rows"]
    ok = [r for r in rows if r["status"] == "ok"]
    points = {}
    for r in ok:
        points.setdefault((str(r["chirality"]), r["defects"]), []).append(r["strength_GPa"])
    summary = [{"chirality": c, "defects": d or "-", "seeds": len(v),
                "strength_GPa_mean": sum(v) / len(v)} for (c, d), v in sorted(points.items())]
    one = rows[0]
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        direct = experiments.tension(chirality=tuple(json.loads(str(one["chirality"]))),
                                     defects=one["defects"], seed=int(one["seed"]),
                                     **TUBE_SWEEP["params"])
    finally:
        numba.set_num_threads(threads)
    same = direct.figures["strength_GPa"] == one["strength_GPa"]
    return {"runs": len(rows), "runs_ok": len(ok), "points": len(points),
            "direct_equals_sweep": bool(same), "points_table": summary,
            "pass": len(ok) == len(rows) == 8 and len(points) == 4 and bool(same)}
