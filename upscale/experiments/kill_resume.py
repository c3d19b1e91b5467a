"""Kill a run with SIGKILL at a chosen step, resume it, and compare it bit for bit with the
uninterrupted run.

Each run is a fresh Python process. The killed one patches, from outside the project's
code, the place where a step ends (velocity Verlet's ``step`` for the plate, the sparse
factorisation of each Newton iteration for the CPD solve) to send itself SIGKILL at step
``K``: no ``finally`` block, no buffered write survives, as when the machine kills a job.
The resumed process is the ordinary command (``upscale plate --workdir DIR --resume``, or the CPD bar
solve with ``resume=True``).

    python -m upscale.experiments.kill_resume plate OUT [--kill-at K] [--resume] [--n 40 ...]
    python -m upscale.experiments.kill_resume cpd OUT [--kill-at K] [--resume] [--steps 8 ...]
    python -m upscale.experiments.kill_resume dcbr OUT [--kill-at K] [--resume] [--steps 300 ...]
    python -m upscale.experiments.kill_resume dcbr-vacancy OUT [--kill-at K] [--resume] [--tube small]

The ``dcbr`` run is the periodic coarse tube on the engine
(:class:`upscale.models.dcbr.DCBRTubeModel`): (10,10), 25 Å, coarsening 2, its cell
stretched at a constant strain rate, velocity Verlet with a Nose-Hoover chain at 10 K,
links breaking by the tube's failure rules. The ``dcbr-vacancy`` run is the dynamic
tension of the open vacancy tube on the engine
(:func:`upscale.experiments.scenes.dcbr_dynamic.dynamic_tension` with ``engine=True``): ``--tube
scene``, the (10,10) 150 Å coarsening-2 tube of ``dcbr-seeds`` (clamped grips on LAMMPS's
planes, 10 K, seed 1000) pulled to failure; ``--tube small``, a (6,6) 60 Å tube with 10 Å
grips at 10 Å/ps, to failure (the atomistic region's bonds break, the ghost-force
correction is refreshed every sample); ``--tube small-grow``, the same tube starting with a
disc about the vacancy that grows to the band when the crack starts (``grow``: the run
moves to a second simulation, which a checkpoint after the switch resumes).
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

__all__ = ["plate_kill_resume", "cpd_kill_resume", "dcbr_kill_resume",
           "dcbr_vacancy_kill_resume", "main"]


def _die_at(k: int):
    """A counter that SIGKILLs this process when it reaches ``k``."""
    count = {"n": 0}

    def tick():
        count["n"] += 1
        if count["n"] >= k:
            os.kill(os.getpid(), signal.SIGKILL)
    return tick


def _plate(args) -> int:
    from upscale.cli import main as cli

    if args.kill_at:
        _patch_vv_kill(args.kill_at)
    argv = ["plate", "--n", str(args.n), "--t-end", repr(args.t_end), "--out", str(args.out),
            "--workdir", str(args.out), "--checkpoint-every", str(args.checkpoint_every),
            "--threads", str(args.threads), "--quiet", "--model", args.model]
    if args.resume:
        argv.append("--resume")
    return cli(argv)


def _cpd(args) -> int:
    import upscale.engine.newton as newton
    from upscale.engine.kernels import set_threads
    from upscale.experiments.scenes.cpd_bar import bar_tension
    from upscale.io import atomic_write_bytes

    set_threads(args.threads)
    tick = _die_at(args.kill_at) if args.kill_at else None
    factor = newton.solvers.Factor.factor
    here = {"n": 0}  # factorisations done by this process

    def counting_factor(self, *a, **kw):  # the engine's factorisation, counting (and dying)
        here["n"] += 1
        if tick is not None:
            tick()
        return factor(self, *a, **kw)

    newton.solvers.Factor.factor = counting_factor
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    r = bar_tension(dim=2, dx=args.dx, strain=args.strain, steps=args.steps, tol=1e-12,
                    checkpoint=out / "newton.npz", resume=args.resume)
    _, st = r["_state"]
    import io

    buf = io.BytesIO()
    np.save(buf, st.y)
    atomic_write_bytes(out / "final_y.npy", buf.getvalue())
    print(r["newton"]["n_tangent"], "tangents,", here["n"], "here", flush=True)
    return 0


def _patch_vv_kill(k: int) -> None:
    from upscale.engine.integrators import VelocityVerlet

    step = VelocityVerlet.step

    def dying_step(self, sim, _orig=step):
        out = _orig(self, sim)
        if sim.state.step >= k:
            os.kill(os.getpid(), signal.SIGKILL)
        return out

    VelocityVerlet.step = dying_step


def _dcbr(args) -> int:
    from upscale.constants import ASE_TIME_FS, CARBON_MASS_AMU, K_B_EV
    from upscale.engine.checkpoint import Checkpoint
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import ParticleSystem
    from upscale.engine.thermostats import NoseHooverChain
    from upscale.models.dcbr import DCBRTube, DCBRTubeModel

    if args.kill_at:
        _patch_vv_kill(args.kill_at)
    tube = DCBRTube(10, 10, 25.0, coarsening=2.0)
    r0 = tube.minimise(tube.x0, tube.delta, tube.L, relax_box=True, gtol=1e-8)
    y, d, L0 = r0.y, r0.delta, r0.Lz
    tube.delta = d
    dt = 1.0 / ASE_TIME_FS                 # 1 fs
    rate = args.strain_rate * ASE_TIME_FS  # per fs -> per time unit
    model = DCBRTubeModel(tube, cell=lambda t: L0 * (1.0 + rate * t))
    system = ParticleSystem(tube.x0, tube.natoms_n, CARBON_MASS_AMU,
                            spacing=float(min(tube.spacing)))
    th = NoseHooverChain(10.0, tau=100.0 * dt, k_B=K_B_EV)
    sim = Simulation(system, None, model, integrator=VelocityVerlet(dt=dt, thermostat=th))
    sim.state.y[...] = y
    rng = np.random.default_rng(1)
    sim.state.v[...] = rng.standard_normal(y.shape) * np.sqrt(K_B_EV * 10.0 / system.mass)[:, None]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ck = Checkpoint(out / "checkpoint.npz", every=args.checkpoint_every)
    if args.resume and sim.resume(ck.path):
        sim.prepare()
        ck.last_step = sim.state.step
    sim.run(max(0, args.steps - sim.state.step), checkpoint=ck)
    print(int((~tube.intact).sum()), "broken links", flush=True)
    return 0


def _dcbr_vacancy(args) -> int:
    import json

    from upscale.engine.kernels import set_threads
    from upscale.io import NumpyJSON, atomic_write_bytes
    from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension

    set_threads(args.threads)
    if args.kill_at:
        _patch_vv_kill(args.kill_at)
    if args.tube in ("small", "small-grow"):
        from upscale.models.dcbr_defect import DCBRDefectTube

        if args.tube == "small":
            model = DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)
            dyn = {}
        else:
            model = DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4, r_atomistic=4.0,
                                   region="disc")
            dyn = {"grow": DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4,
                                          r_atomistic=5.0)}
        dyn |= dict(grip=10.0, speed=10.0, max_strain=0.3, sample=20, seed=7)
    else:
        from upscale.experiments.lammps.cache import cache_dir
        from upscale.experiments.scenes.tube_tension import dynamic_scene, lammps_reference

        ref = lammps_reference(10, 10, 150.0, protocol="dynamic", vacancy=True, progress=False,
                               cache_dir=cache_dir("references"))
        model, dyn = dynamic_scene(10, 10, 150.0, 2.0, ref)
        dyn.pop("grips")
        dyn["seed"] = 1000
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    r = dynamic_tension(model, checkpoint=out / "checkpoint.npz",
                        checkpoint_every=args.checkpoint_every, resume=args.resume, **dyn)
    keep = {k: r[k] for k in ("steps", "strength_GPa", "youngs_modulus_TPa", "strain_at_peak",
                              "first_damage", "curve", "grown_at", "region_free_atoms")}
    keep["broken_links"] = int((~dyn.get("grow", model).intact).sum())
    atomic_write_bytes(out / "result.json", json.dumps(keep, cls=NumpyJSON).encode())
    print(keep["broken_links"], "broken links", r["steps"], "steps", flush=True)
    return 0


def _run(cmd: list[str], env_threads: int = 1) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               NUMBA_NUM_THREADS=str(max(1, env_threads)))
    return subprocess.run([sys.executable, "-m", "upscale.experiments.kill_resume", *cmd], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=6 * 3600)


def _check(p: subprocess.CompletedProcess, killed: bool = False) -> None:
    if killed:
        if p.returncode != -signal.SIGKILL:
            raise RuntimeError(f"the run was to be killed but ended with {p.returncode}: "
                               f"{p.stderr[-2000:]}")
    elif p.returncode != 0:
        raise RuntimeError(f"run failed ({p.returncode}): {p.stderr[-2000:]}")


def plate_kill_resume(workdir, *, n: int = 40, t_end: float = 3e-5, every: int = 10,
                      kill_at: int | None = None, model: str = "pmb", threads: int = 1,
                      seed=None) -> dict:
    """The pre-cracked plate (``upscale plate``) uninterrupted, killed at step ``kill_at``
    (default: a random step of the run) and resumed; returns the comparison."""
    from upscale.engine.checkpoint import load_checkpoint

    w = Path(workdir)
    common = ["--n", str(n), "--t-end", repr(t_end), "--checkpoint-every", str(every),
              "--threads", str(threads), "--model", model]
    a = _run(["plate", str(w / "full"), *common], threads)
    _check(a)
    steps = int(load_checkpoint(w / "full" / "checkpoint.npz")[0].step)
    if kill_at is None:
        kill_at = int(np.random.default_rng(seed).integers(1, steps))
    if not 1 <= kill_at < steps:
        raise ValueError(f"kill_at={kill_at}; valid: 1 <= kill_at < {steps} (the run's steps)")
    _check(_run(["plate", str(w / "cut"), *common, "--kill-at", str(kill_at)], threads),
           killed=True)
    ck_step = int(load_checkpoint(w / "cut" / "checkpoint.npz")[0].step)
    _check(_run(["plate", str(w / "cut"), *common, "--resume"], threads))
    sa, _ = load_checkpoint(w / "full" / "checkpoint.npz")
    sb, _ = load_checkpoint(w / "cut" / "checkpoint.npz")
    from upscale.experiments.result import Result

    ja = Result.from_json(w / "full" / "plate.json").figures
    jb = Result.from_json(w / "cut" / "plate.json").figures
    same = (sa.step == sb.step and np.array_equal(sa.y, sb.y) and np.array_equal(sa.v, sb.v)
            and np.array_equal(sa.intact, sb.intact) and sa.t == sb.t)
    return {"steps": steps, "killed_at_step": kill_at, "resumed_from_step": ck_step,
            "broken_bonds_uninterrupted": ja["broken_bonds"],
            "broken_bonds_resumed": jb["broken_bonds"], "resumed": jb["resumed"],
            "max_abs_dy_m": float(np.abs(sa.y - sb.y).max()),
            "max_abs_dv_m_s": float(np.abs(sa.v - sb.v).max()), "bit_identical": bool(same)}


def cpd_kill_resume(workdir, *, steps: int = 8, dx: float = 2e-3, strain: float = 0.05,
                    kill_at: int | None = None, threads: int = 1, seed=None) -> dict:
    """The CPD bar's Newton solve (``steps`` load steps) uninterrupted, killed at the
    ``kill_at``-th Newton iteration (default: a random one) and resumed."""
    import re

    w = Path(workdir)
    common = ["--steps", str(steps), "--dx", repr(dx), "--strain", repr(strain),
              "--threads", str(threads)]
    a = _run(["cpd", str(w / "full"), *common], threads)
    _check(a)
    iters = int(re.search(r"(\d+) tangents", a.stdout).group(1))
    if kill_at is None:
        kill_at = int(np.random.default_rng(seed).integers(1, iters))
    if not 1 <= kill_at < iters:
        raise ValueError(f"kill_at={kill_at}; valid: 1 <= kill_at < {iters} (the solve's "
                         "Newton iterations)")
    _check(_run(["cpd", str(w / "cut"), *common, "--kill-at", str(kill_at)], threads),
           killed=True)
    had_ck = (w / "cut" / "newton.npz").is_file()
    b = _run(["cpd", str(w / "cut"), *common, "--resume"], threads)
    _check(b)
    m = re.search(r"(\d+) tangents, (\d+) here", b.stdout)
    ya, yb = np.load(w / "full" / "final_y.npy"), np.load(w / "cut" / "final_y.npy")
    return {"newton_iterations": iters, "killed_at_iteration": kill_at,
            "checkpoint_before_kill": had_ck,
            "newton_iterations_resumed_total": int(m.group(1)),
            "newton_iterations_after_resume": int(m.group(2)),
            "max_abs_dy_m": float(np.abs(ya - yb).max()),
            "bit_identical": bool(np.array_equal(ya, yb))}


def dcbr_kill_resume(workdir, *, steps: int = 300, every: int = 20, strain_rate: float = 1e-3,
                     kill_at: int | None = None, threads: int = 1, seed=None) -> dict:
    """The periodic DCBR tube's dynamic tension on the engine (module docstring)
    uninterrupted, killed at step ``kill_at`` (default: a random step after the first
    checkpoint) and resumed."""
    import re

    from upscale.engine.checkpoint import load_checkpoint

    w = Path(workdir)
    common = ["--steps", str(steps), "--checkpoint-every", str(every), "--strain-rate",
              repr(strain_rate), "--threads", str(threads)]
    a = _run(["dcbr", str(w / "full"), *common], threads)
    _check(a)
    if kill_at is None:
        kill_at = int(np.random.default_rng(seed).integers(every + 1, steps))
    if not 1 <= kill_at < steps:
        raise ValueError(f"kill_at={kill_at}; valid: 1 <= kill_at < {steps}")
    _check(_run(["dcbr", str(w / "cut"), *common, "--kill-at", str(kill_at)], threads),
           killed=True)
    ck_step = int(load_checkpoint(w / "cut" / "checkpoint.npz")[0].step)
    b = _run(["dcbr", str(w / "cut"), *common, "--resume"], threads)
    _check(b)
    sa, _ = load_checkpoint(w / "full" / "checkpoint.npz")
    sb, _ = load_checkpoint(w / "cut" / "checkpoint.npz")
    same = (sa.step == sb.step and np.array_equal(sa.y, sb.y) and np.array_equal(sa.v, sb.v)
            and all(np.array_equal(sa.extra[k], sb.extra[k]) for k in sa.extra))
    la = int(re.search(r"(\d+) broken links", a.stdout).group(1))
    lb = int(re.search(r"(\d+) broken links", b.stdout).group(1))
    return {"steps": steps, "killed_at_step": kill_at, "resumed_from_step": ck_step,
            "broken_links_uninterrupted": la, "broken_links_resumed": lb,
            "max_abs_dy_A": float(np.abs(sa.y - sb.y).max()), "bit_identical": bool(same)}


def dcbr_vacancy_kill_resume(workdir, *, tube: str = "small", every: int = 50,
                             kill_at: int | None = None, threads: int = 1, seed=None,
                             after_growth: bool = False) -> dict:
    """The open vacancy tube's dynamic tension on the engine (module docstring)
    uninterrupted, killed at step ``kill_at`` (default: a random step after the first
    checkpoint) and resumed; compares the final states (positions, velocities, shifts and
    their rates, every extra: links, last maps, ghost dead load, the scene's records) and
    the result (stress curve, strength, first damage)."""
    import json

    from upscale.engine.checkpoint import load_checkpoint

    w = Path(workdir)
    common = ["--tube", tube, "--checkpoint-every", str(every), "--threads", str(threads)]
    _check(_run(["dcbr-vacancy", str(w / "full"), *common], threads))
    ja = json.loads((w / "full" / "result.json").read_text())
    steps = int(ja["steps"])
    if kill_at is None:  # (after_growth: after the step at which the region grew)
        lo = int(ja["grown_at"]["step"]) + 1 if after_growth else every + 1
        kill_at = int(np.random.default_rng(seed).integers(lo, steps))
    if not 1 <= kill_at < steps:
        raise ValueError(f"kill_at={kill_at}; valid: 1 <= kill_at < {steps} (the run's steps)")
    _check(_run(["dcbr-vacancy", str(w / "cut"), *common, "--kill-at", str(kill_at)],
                threads), killed=True)
    ck_step = int(load_checkpoint(w / "cut" / "checkpoint.npz")[0].step)
    _check(_run(["dcbr-vacancy", str(w / "cut"), *common, "--resume"], threads))
    jb = json.loads((w / "cut" / "result.json").read_text())
    sa, _ = load_checkpoint(w / "full" / "checkpoint.npz")
    sb, _ = load_checkpoint(w / "cut" / "checkpoint.npz")
    same_state = (sa.step == sb.step and np.array_equal(sa.y, sb.y)
                  and np.array_equal(sa.v, sb.v) and sa.extra.keys() == sb.extra.keys()
                  and all(np.array_equal(sa.extra[k], sb.extra[k], equal_nan=sa.extra[k].dtype.kind == "f")
                          for k in sa.extra)
                  and all(np.array_equal(sa.fields[k], sb.fields[k]) and
                          np.array_equal(sa.field_v[k], sb.field_v[k]) for k in sa.fields))
    return {"tube": tube, "steps": steps, "killed_at_step": kill_at,
            "grown_at_step": (ja.get("grown_at") or {}).get("step"),
            "resumed_from_step": ck_step,
            "broken_links_uninterrupted": ja["broken_links"],
            "broken_links_resumed": jb["broken_links"],
            "strength_GPa_uninterrupted": ja["strength_GPa"],
            "strength_GPa_resumed": jb["strength_GPa"],
            "max_abs_dy_A": float(np.abs(sa.y - sb.y).max()),
            "max_abs_dstress_GPa": float(np.abs(np.subtract(ja["curve"]["stress_GPa"],
                                                            jb["curve"]["stress_GPa"])).max())
            if len(ja["curve"]["stress_GPa"]) == len(jb["curve"]["stress_GPa"]) else None,
            "bit_identical": bool(same_state and ja == jb)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m upscale.experiments.kill_resume", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", choices=("plate", "cpd", "dcbr", "dcbr-vacancy"))
    p.add_argument("out", type=Path)
    p.add_argument("--kill-at", type=int, default=0, help="SIGKILL at this step (0: never)")
    p.add_argument("--resume", action="store_true")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--n", type=int, default=40, help="plate: particles a side")
    p.add_argument("--t-end", type=float, default=3e-5, help="plate: end time (s)")
    p.add_argument("--checkpoint-every", type=int, default=10, help="plate: steps")
    p.add_argument("--model", default="pmb", help="plate: pmb or lps")
    p.add_argument("--steps", type=int, default=None, help="cpd: load steps (8); dcbr: MD steps (300)")
    p.add_argument("--strain-rate", type=float, default=1e-3, help="dcbr: per fs")
    p.add_argument("--dx", type=float, default=2e-3, help="cpd: spacing (m)")
    p.add_argument("--strain", type=float, default=0.05, help="cpd: nominal strain of the load")
    p.add_argument("--tube", choices=("small", "small-grow", "scene"), default="small",
                   help="dcbr-vacancy: a (6,6) 60 Å tube (small-grow: its disc region "
                        "grows to the band when the crack starts) or the (10,10) 150 Å K2 "
                        "seed scene")
    args = p.parse_args(argv)
    if args.steps is None:
        args.steps = 8 if args.scene == "cpd" else 300
    if args.scene == "dcbr" and args.checkpoint_every == 10:
        args.checkpoint_every = 20
    return {"plate": _plate, "cpd": _cpd, "dcbr": _dcbr,
            "dcbr-vacancy": _dcbr_vacancy}[args.scene](args)


if __name__ == "__main__":
    sys.exit(main())
