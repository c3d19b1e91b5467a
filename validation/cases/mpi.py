"""MPI cases (issue 50): the pre-cracked plates on several ranks against one, the speed of
two ranks against one and two threads, and an exact restart of a killed 2-rank run.

Each case starts its own ranks (``mpiexec -n K python -m validation.cases.mpi plate ...``,
one thread per rank, the ``mpiexec`` of the mpich wheel), so it is run without ``mpiexec``.
The plate is :class:`upscale.experiments.scenes.plate.PlateScene`'s; on several ranks it is
built by :func:`lean_plate` (each rank builds only its rows of the family). One thread per
rank keeps each particle's sum order, so the runs can be bit-identical (``bit_identical``);
``bench-mpi``'s scaling model (:mod:`upscale.engine.parallel.scaling`) writes its tables to
``scaling_model.json``.
"""
from __future__ import annotations

import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from validation.registry import case, show


def _mpiexec() -> str:
    exe = shutil.which("mpiexec", path=str(Path(sys.executable).parent)) or shutil.which("mpiexec")
    if exe is None:
        raise ValueError("no mpiexec found; install the mpich wheel (pip install mpich)")
    return exe


#: the environment a launcher gives its ranks (MPICH's Hydra, Open MPI, PMIx): left out of
#: the runs a case starts, so that a case run under ``mpiexec`` starts clean worlds
_LAUNCH_PREFIXES = ("PMI_", "PMIX_", "HYDRA_", "MPIR_", "OMPI_", "MPI_LOCAL")


def _env(threads: int = 1) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(_LAUNCH_PREFIXES)}
    env["NUMBA_NUM_THREADS"] = str(threads)
    return env


def _rank0_only() -> None:
    """Under ``mpiexec`` (``mpiexec -n 2 python -m validation mpi-same-answer``): rank 0
    runs the case, which starts its own worlds; the other ranks leave at once."""
    from upscale.engine.parallel.comm import launched_by_mpi

    if launched_by_mpi() and int(os.environ.get("PMI_RANK", os.environ.get(
            "PMIX_RANK", os.environ.get("OMPI_COMM_WORLD_RANK", "0")))) != 0:
        sys.exit(0)


def _refuse_under_mpi() -> None:
    from upscale.engine.parallel.comm import launched_by_mpi

    if launched_by_mpi():
        raise ValueError("run this case without mpiexec: it starts its own ranks")


def _cmd(ranks: int, *args) -> list[str]:
    cmd = [sys.executable, "-m", "validation.cases.mpi", "plate", *map(str, args)]
    return [_mpiexec(), "-n", str(ranks), *cmd] if ranks > 1 else cmd


def run_plate(ranks: int, model: str, n: int, steps: int, out: Path, threads: int = 1,
              workdir=None, every: int = 0) -> dict:
    """One plate run on ``ranks`` ranks; its arrays (npz) and figures (json beside)."""
    extra = [workdir, every] if workdir is not None else []
    r = subprocess.run(_cmd(ranks, model, n, steps, out, *extra), env=_env(threads),
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"plate on {ranks} ranks failed: {r.stderr.strip().splitlines()[-1:]}")
    return json.loads(Path(out).with_suffix(".json").read_text())


def _same_args(p):
    p.add_argument("--ranks", default="1,2,4", help="rank counts (the first is the reference)")
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--n", type=int, default=None, help="particles a side (default 100; quick 40)")


@case("mpi-same-answer", "pre-cracked PMB, LPS and Ti-PD plates on 1, 2 and 4 ranks for "
      "1,000 steps: displacements and broken bonds against the serial run",
      add_arguments=_same_args,
      target="displacements within 1e-12 of the serial run's largest, same broken bonds")
def mpi_same_answer(args):
    _rank0_only()
    ranks = [int(r) for r in args.ranks.split(",")]
    n = args.n or (40 if args.quick else 100)
    rows, out = [], {"ranks": ranks, "plate_n": n, "steps": args.steps}
    worst, same, bits, agree = 0.0, True, True, True
    with tempfile.TemporaryDirectory() as d:
        for model in ("pmb", "lps", "tipd"):
            ref = None
            for k in ranks:
                f = Path(d) / f"{model}{k}.npz"
                fig = run_plate(k, model if k == 1 else f"lean:{model}", n, args.steps, f)
                z = dict(np.load(f))
                if ref is None:
                    ref = z
                umax = float(np.abs(ref["u"]).max())
                rel = float(np.abs(z["u"] - ref["u"]).max()) / umax
                ident = bool(np.array_equal(z["intact"], ref["intact"]))
                worst, same = max(worst, rel), same and ident
                bits &= bool(np.array_equal(z["u"], ref["u"]))
                agree &= bool(z["agree"])
                rows.append({"model": model, "ranks": k, "broken": int(z["broken"]),
                             "max_rel_diff": rel, "same_broken": ident,
                             "wall_s": fig["run_wall_s"]})
    show(rows, fmt=".3g")
    out.update(max_rel_diff=worst, broken_bonds_identical=same, bit_identical=bits,
               bond_states_agree=agree, **{"pass": bool(worst <= 1e-12 and same and agree)})
    return out


def _bench_args(p):
    p.add_argument("--n", type=int, default=None, help="particles a side (default 600; quick 200)")
    p.add_argument("--steps", type=int, default=None, help="steps (default 200; quick 100)")


def _traffic_sums(fig: dict) -> dict:
    t = fig["traffic"]
    return {"rows": sum(x["rows_received"] for x in t), "owned": sum(x["owned"] for x in t),
            "bytes": sum(x["bytes_sent"] for x in t), "peers": max(x["peers"] for x in t),
            "exchange_s": max(x["exchange_alone_s"] for x in t),
            "wait_s": max(x["exchange_s"] for x in t),
            "packing_s": max(x["packing_s"] for x in t),
            "rows_moved": max(x["rows_received"] + x["rows_sent"] for x in t),
            "halo_bonds": sum(x["local_bonds"] - x["owned_bonds"] for x in t)}


@case("bench-mpi", "speed of 2 ranks against 1 and 2 threads on a plate of >= 10 M bonds; "
      "halo volume, bytes and time of the exchange per step at 2 and 4 ranks; a weak- and "
      "strong-scaling model from them to 1,000 ranks",
      add_arguments=_bench_args, target="2 ranks at least 1.7x one rank")
def bench_mpi(args):
    from upscale.engine.parallel import scaling

    _refuse_under_mpi()
    n = args.n or (200 if args.quick else 600)
    steps = args.steps or (100 if args.quick else 200)
    load0 = os.getloadavg()
    rows, runs = [], {}
    with tempfile.TemporaryDirectory() as d:
        for name, ranks, threads in (("1 rank x 1 thread", 1, 1), ("1 rank x 2 threads", 1, 2),
                                     ("2 ranks x 1 thread", 2, 1), ("4 ranks x 1 thread", 4, 1)):
            fig = run_plate(ranks, "lean:pmb", n, steps,
                            Path(d) / f"r{ranks}t{threads}.npz", threads)
            runs[(ranks, threads)] = fig
            tr = _traffic_sums(fig) if fig["traffic"] else {}
            rows.append({"run": name, "bonds": fig["bonds"],
                         "s_per_step": fig["run_wall_s"] / steps,
                         "halo_rows": tr.get("rows", 0), "bytes_per_step": tr.get("bytes", 0),
                         "exchange_us": 1e6 * tr.get("exchange_s", 0.0),
                         "exchange_wait_us": 1e6 * tr.get("wait_s", 0.0),
                         "max_rss_MB": max(fig["max_rss_MB"])})
    load1 = os.getloadavg()
    show(rows)
    t = {k: v["run_wall_s"] / steps for k, v in runs.items()}
    two, four = _traffic_sums(runs[(2, 1)]), _traffic_sums(runs[(4, 1)])
    N, bonds = n * n, runs[(1, 1)]["bonds"]
    assumed = scaling.ASSUMED
    const = scaling.fit(n_particles=N, bonds=bonds, s_per_step_1rank=t[(1, 1)],
                        halo_rows_2ranks=two["rows"] / 2, packing_s_2ranks=two["packing_s"],
                        rows_moved_2ranks=two["rows_moved"],
                        halo_bonds_2ranks=two["halo_bonds"] / 2, dim=2)
    kw = {"a": assumed}
    body3 = {"particles": 1e7, "bonds_per_particle": 100.0}  # the 3D body
    strong2 = scaling.strong(N, const, dim=2, **kw)
    strong3 = scaling.strong(body3["particles"], const, dim=3,
                             bonds_per_particle=body3["bonds_per_particle"], **kw)
    weak2 = scaling.weak(N / 2, const, dim=2, **kw)
    weak3 = scaling.weak(1e5, const, dim=3, bonds_per_particle=body3["bonds_per_particle"], **kw)
    cross2 = scaling.crossover(const, dim=2, **kw)
    cross3 = scaling.crossover(const, dim=3, bonds_per_particle=body3["bonds_per_particle"], **kw)
    at = {r["ranks"]: r for r in strong2}
    out = {"plate_n": n, "particles": N, "bonds": bonds, "steps": steps, "model": "pmb",
           "load_average_1_5_15min_at_start": list(load0),
           "load_average_1_5_15min_at_end": list(load1),
           "s_per_step": {f"{r}r{th}t": v for (r, th), v in t.items()},
           "speedup_2ranks_over_1": t[(1, 1)] / t[(2, 1)],
           "speedup_2threads_over_1": t[(1, 1)] / t[(1, 2)],
           "speedup_2ranks_over_2threads": t[(1, 2)] / t[(2, 1)],
           "halo_fraction": two["rows"] / two["owned"],
           "halo_fraction_4ranks": four["rows"] / four["owned"],
           "bytes_per_step_2ranks": two["bytes"], "bytes_per_step_4ranks": four["bytes"],
           "exchange_us_per_step": 1e6 * two["exchange_s"],
           "exchange_us_per_step_4ranks": 1e6 * four["exchange_s"],
           "exchange_and_wait_us_per_step": 1e6 * two["wait_s"],
           "packing_us_per_step": 1e6 * two["packing_s"],
           "max_rss_MB_per_rank": {f"{r}r{th}t": v["max_rss_MB"] for (r, th), v in runs.items()},
           "model_assumptions": {**assumed, "halo": "cube-like subdomains (RCB) in a shell of "
                                 "the measured halo width, 3^d - 1 peers; the copies of an "
                                 "exchange at their measured cost per row (sent + received); "
                                 "one Allreduce per step (recursive doubling); compute "
                                 "proportional to the bonds held (owned and halo rows'), at "
                                 "the 1-rank time per bond; no load imbalance, no OS noise"},
           "model_constants": const,
           "model_2ranks_s_per_step_vs_measured": [at[2]["total_s"], t[(2, 1)]],
           "strong_2d_plate_speedup_at_1000": at[1000]["speedup"],
           "strong_2d_plate_efficiency_at_1000": at[1000]["efficiency"],
           "strong_3d_1e7x100_efficiency_at_1000": strong3[-1]["efficiency"],
           "strong_3d_1e7x100_s_per_step_at_1000": strong3[-1]["total_s"],
           "weak_2d_efficiency_at_1000": weak2[-1]["efficiency"],
           "weak_3d_1e5_per_rank_efficiency_at_1000": weak3[-1]["efficiency"],
           "exchange_dominates_below_particles_per_rank_2d": cross2,
           "exchange_dominates_below_particles_per_rank_3d_100_bonds": cross3}
    (args.outdir / "scaling_model.json").write_text(json.dumps(
        {"strong_2d_plate": strong2, "strong_3d_1e7x100": strong3, "weak_2d": weak2,
         "weak_3d_1e5_per_rank": weak3, **{k: out[k] for k in ("model_assumptions",
                                                                 "model_constants")}},
        indent=1, default=float))
    out["pass"] = bool(out["speedup_2ranks_over_1"] >= 1.7)
    return out


def _restart_args(p):
    p.add_argument("--n", type=int, default=None, help="particles a side (default 100; quick 40)")
    p.add_argument("--steps", type=int, default=1000)
    p.add_argument("--seed", type=int, default=None, help="seed of the kill moment")


@case("mpi-restart-exact", "the 2-rank PMB plate killed with SIGKILL at a random moment and "
      "resumed from its per-rank checkpoints, against the uninterrupted 2-rank run",
      add_arguments=_restart_args, target="bit-identical")
def mpi_restart_exact(args):
    _refuse_under_mpi()
    n = args.n or (40 if args.quick else 100)
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        run_plate(2, "pmb", n, args.steps, d / "full.npz")
        work = d / "work"
        work.mkdir()
        every = max(args.steps // 20, 1)
        p = subprocess.Popen(_cmd(2, "pmb", n, args.steps, d / "killed.npz", work, every),
                             env=_env(), start_new_session=True,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while not list(work.glob("*.prev.npz")) and p.poll() is None:
            time.sleep(0.02)
        time.sleep(rng.uniform(0.0, 1.0))
        killed = p.poll() is None
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        at = -1  # the newest step of rank 0's files (killed between the rename of the
        for f in work.glob("checkpoint.rank0of2*.npz"):  # last one and the new write,
            with np.load(f) as z:                        # only .prev is there)
                at = max(at, int(z["step"]))
        run_plate(2, "pmb", n, args.steps, d / "resumed.npz", workdir=work, every=every)
        a, b = np.load(d / "full.npz"), np.load(d / "resumed.npz")
        same = bool(np.array_equal(a["u"], b["u"]) and np.array_equal(a["intact"], b["intact"]))
    out = {"ranks": 2, "plate_n": n, "steps": args.steps, "killed_before_the_end": killed,
           "last_checkpoint_step_of_rank0": at, "mpi_bit_identical": same}
    out["pass"] = bool(same and killed)
    return out


def lean_plate(n: int, model: str):
    """The :class:`~upscale.experiments.scenes.plate.PlateScene` plate's simulation, its
    family passed as a :class:`~upscale.engine.families.FamilyRecipe` (the pre-crack as
    its bonds broken at the start): on several ranks no rank builds the whole family. The
    same body, family, state, model and conditions as the scene's (the tests compare)."""
    from upscale import models
    from upscale.engine import Simulation, bonds_crossing_segment, square_lattice
    from upscale.engine.conditions import Velocity, region
    from upscale.engine.families import FamilyRecipe
    from upscale.engine.integrators import VelocityVerlet
    from upscale.experiments.scenes import plate as P

    h = P.L_PLATE / n
    system = square_lattice(n, n, h, thickness=h, density=P.RHO, plane="stress",
                            centered=True)
    cut = bonds_crossing_segment(system.x0, (-P.CRACK / 2, 0.0), (P.CRACK / 2, 0.0))
    recipe = FamilyRecipe(system, 3.015 * h, broken=cut)
    cls = models.get(model)
    mdl = cls(E=P.E_PLATE, s0=P.S0) if model == "pmb" else cls(E=P.E_PLATE, nu=1.0 / 3.0, s0=P.S0)
    L = P.L_PLATE
    top = region(system, "top rows", box=((None, L / 2 - 3 * h, None), (None, None, None)))
    bottom = region(system, "bottom rows", box=((None, None, None), (None, -L / 2 + 3 * h, None)))
    conds = [Velocity(top, (0.0, P.V_EDGE, 0.0), components=(1,)),
             Velocity(bottom, (0.0, -P.V_EDGE, 0.0), components=(1,))]
    sim = Simulation(system, recipe, mdl, conds, integrator=VelocityVerlet())
    sim.prepare()
    return sim


def plate_main(argv: list[str]) -> None:
    """``plate MODEL N STEPS OUT.npz [WORKDIR EVERY]`` (under ``mpiexec`` or alone): run
    the plate (resuming from WORKDIR's checkpoints if there), then rank 0 writes the whole
    body's displacements and bond states (OUT.npz) and the figures (OUT.json)."""
    from upscale.engine.checkpoint import Checkpoint
    from upscale.experiments.scenes.plate import PlateScene

    model, n, steps, out = argv[0], int(argv[1]), int(argv[2]), Path(argv[3])
    lean = model.startswith("lean:")
    sim = lean_plate(n, model[5:]) if lean else PlateScene(n, model=model).sim
    ck = None
    if len(argv) > 4:
        ck = Checkpoint(Path(argv[4]) / "checkpoint.npz", every=int(argv[5]))
        if sim.resume(ck.path):
            sim.prepare()
            ck.last_step = sim.state.step
    info = sim.run(max(0, steps - sim.state.step), checkpoint=ck)
    part = sim.part
    u = sim.gather(sim.state.u)
    intact = sim.state.intact if part is None else part.gather_bonds(sim.state.intact)
    agree, traffic = True, []
    if part is not None:
        from upscale.engine.parallel import bond_states_agree

        agree = bond_states_agree(part.comm, part.local, sim.state.intact)
        t = part.traffic()
        t["exchange_alone_s"] = part.time_exchange(sim.state.y)
        t["packing_s"] = part.time_packing(sim.state.y)
        t.update(local_bonds=int(part.local.offsets[-1]),
                 owned_bonds=int(np.count_nonzero(part.owned_bonds)))
        traffic = part.comm.allgather(t)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    rss = [rss] if part is None else part.comm.allgather(rss)
    desc = sim.describe()  # collective on several ranks
    if part is None or part.rank == 0:
        np.savez(out, u=u, intact=intact, broken=info["broken_bonds"], agree=agree)
        out.with_suffix(".json").write_text(json.dumps(
            {"run_wall_s": info["wall_s"], "bonds": desc["bonds"], "particles": desc["particles"],
             "traffic": traffic, "broken_bonds": info["broken_bonds"], "max_rss_MB": rss},
            default=float))


if __name__ == "__main__":
    if sys.argv[1:2] == ["plate"]:
        plate_main(sys.argv[2:])
