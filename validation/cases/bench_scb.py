"""bench-scb: run time of the SCB fracture scene (seed 004 ch. 6) per angle, to full crack.

For every angle the scene is built (particles, family, crack cut, gain matrices, the tip
factor's own elastic solve: ``scene``), then driven by :func:`quasi_static_fracture` until
the load has fallen below ``--stop-fraction`` (default 0.1) of its peak: the crack has cut
the ligament up to the load patch's no-fail zone ("full crack", ``crack_reach_y_over_R``
the crack path's highest point over R; P_c is the peak on the way). Past that point the
load rises again on the no-fail zone's hinge, so ``--u-max`` must reach the fall (about
4 mm of load-point displacement at alpha = 0). Reported per angle: wall and CPU
time of each part, the equilibria (Newton solves at a new load or after bonds broke), and
where the time went inside the solves (tangent assembly, sparse Cholesky factorisation,
preconditioned CG with its matrix-free products, residuals at the Newton iterates) and in
the failure checks (failure index, breaking, Upsilon recomputation).

With ``--direct-reference``, measured in the same run per angle: one direct sparse solve
of the intact body's tangent on the free dofs (``scipy.sparse.linalg.spsolve``, SuperLU
with its default column ordering), the cost a plain Newton iteration would pay, and
``equilibrium_over_direct``, the mean wall time of one equilibrium in units of that solve.

Against main: main's recorded run of the same table (``MAIN_RESULT``, the eight angles at
dx = 0.5 mm, r_s = 1 mm, stop fraction 0.1, one core; commit 775b0f2, the code of main
99b82f2's solvers) gives ``speedup_vs_main`` = its table wall time over this run's (for the
angles run, the sum of main's per-angle times over them) and ``P_c_change_pct_max``, the
largest |P_c / P_c,main - 1| over the angles, in percent; ``cpu_speedup_vs_main`` the same
ratio in CPU time (less sensitive to other jobs on the machine). ``pass``: every angle to full
crack and, where the run is comparable to main's (same dx, r_s, stop fraction), at least
10x main's speed with every P_c within 0.5 % (the issue's target).

The whole-table time (``table_wall_s``) is the sum over the angles run. All kernels run on
one thread (the machine has two cores; a second job on the other core is allowed and the
load average is reported: wall / CPU close to 1 means the run had its core).
``--profile`` adds a cProfile of the first angle's fracture (top functions by own time).
"""
from __future__ import annotations

import os
import time

import numpy as np

from validation.cases.scb import ALPHAS
from validation.registry import case, table

#: main's recorded bench-scb run (775b0f2; versions, date and machine in the file)
MAIN_RESULT = "validation/results/bench_scb_dx05mm.json"
TARGET_SPEEDUP = 10.0
TARGET_P_C_PCT = 0.5


def _args(p):
    p.add_argument("--dx", type=float, default=None, help="spacing in m (default 5e-4; quick 1e-3)")
    p.add_argument("--alphas", default=None, help="comma list of angles (default the eight; quick 0,30)")
    p.add_argument("--r-s", type=float, default=1e-3, help="r_s in m (default %(default)s, the calibrated one)")
    p.add_argument("--stop-fraction", type=float, default=0.1,
                   help="full crack: the run ends when the load falls below this fraction of its peak")
    p.add_argument("--u-max", type=float, default=1e-2,
                   help="largest load-point displacement, m (default %(default)s; the crack reaches the "
                        "load patch near 4 mm at dx = 1 mm)")
    p.add_argument("--max-equilibria", type=int, default=3000, help="cap on the solves of one run")
    p.add_argument("--profile", action="store_true", help="cProfile the first angle's fracture")
    p.add_argument("--direct-reference", action="store_true",
                   help="time one SuperLU solve of the intact tangent per angle (outside the wall time)")


def main_baseline(dx, r_s, stop_fraction, alphas):
    """main's recorded (wall s, P_c kN) per angle in ``alphas`` from :data:`MAIN_RESULT`, or
    None when that run is not comparable (another dx, r_s or stop fraction, or an angle it
    did not run)."""
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / MAIN_RESULT
    if not path.is_file():
        return None
    r = json.loads(path.read_text())["result"]
    same = (np.isclose(r["dx_m"], dx) and np.isclose(r["r_s_m"], r_s)
            and np.isclose(r["stop_fraction"], stop_fraction))
    if not same or not all(any(np.isclose(a, b) for b in r["alpha_deg"]) for a in alphas):
        return None
    k = [int(np.flatnonzero(np.isclose(r["alpha_deg"], a))[0]) for a in alphas]
    return {"wall_s": [r["wall_s_per_angle"][i] for i in k], "P_c_kN": [r["P_c_kN"][i] for i in k],
            "cpu_s": [r["cpu_s_per_angle"][i] for i in k],
            "table_wall_s": r["table_wall_s"], "file": MAIN_RESULT}


def direct_solve_time(scene, repeats=2):
    """(seconds, free dofs, nonzeros): best of ``repeats`` direct solves of the intact
    tangent on the free dofs of the run's own :class:`Equilibrium`, the right-hand side
    that of the driven dofs moved by ``u_dir``."""
    import scipy.sparse.linalg as spla

    from upscale.engine.quasistatic import Equilibrium

    free = Equilibrium(scene.model, scene.fixed).free
    K = scene.model.tangent(scene.state()).tocsr()
    Kff = K[free][:, free].tocsc()
    b = -(K[free] @ scene.u_dir.ravel())
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        x = spla.spsolve(Kff, b)
        best = min(best, time.perf_counter() - t)
    rel = float(np.linalg.norm(Kff @ x - b) / np.linalg.norm(b))
    if not rel < 1e-8:
        raise RuntimeError(f"the reference direct solve left a relative residual {rel:.2e} (valid: < 1e-8)")
    return best, int(free.size), int(Kff.nnz)


def _profile_rows(prof, n=12):
    import pstats

    s = pstats.Stats(prof)
    tot = sum(v[2] for v in s.stats.values())
    rows = []
    for (fn, line, name), (cc, nc, tt, ct, _) in sorted(s.stats.items(), key=lambda kv: -kv[1][2])[:n]:
        rows.append({"function": f"{os.path.basename(fn)}:{line}({name})", "calls": nc,
                     "own s": tt, "own %": 100 * tt / tot, "cumulative s": ct})
    return rows


@case("bench-scb", "SCB speed: wall time per angle to full crack at dx = 0.5 mm, the whole table, where the time goes",
      _args)
def bench_scb(args):
    import cvxopt.cholmod  # noqa: F401  (its BLAS loaded before the limit, so the limit holds for it)
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        return _bench(args)


def _bench(args):
    import cProfile

    from tqdm import tqdm

    from upscale.engine.kernels import set_threads
    from upscale.experiments.scenes.scb import SCBScene
    from upscale.io import write_json

    set_threads(1)
    quick = bool(getattr(args, "quick", False))
    dx = args.dx or (1e-3 if quick else 5e-4)
    alphas = [float(a) for a in args.alphas.split(",")] if args.alphas else ([0.0, 30.0] if quick else list(ALPHAS))
    load0 = os.getloadavg()[0]
    rows, prof_rows = [], None
    shares = {k: 0.0 for k in ("scene", "assembly", "factorisation", "cg", "residual", "failure", "other")}
    for i, al in enumerate(tqdm(alphas, desc="bench-scb", unit="angle")):
        w0, c0 = time.perf_counter(), time.process_time()
        sc = SCBScene(al, dx=dx, r_s=args.r_s)
        t_scene = time.perf_counter() - w0
        w_ref, c_ref = time.perf_counter(), time.process_time()
        t_direct = nnz = None
        nfree = int((~sc.fixed[:, :2]).sum())
        if getattr(args, "direct_reference", False):
            t_direct, nfree, nnz = direct_solve_time(sc)
        w_ref = time.perf_counter() - w_ref          # assembly and both repeats: not the scene's
        c_ref = time.process_time() - c_ref
        prof = cProfile.Profile() if (args.profile and i == 0) else None
        w1, c1 = time.perf_counter(), time.process_time()
        if prof is not None:
            prof.enable()
        st, curve = sc.fracture(stop_fraction=args.stop_fraction, max_equilibria=args.max_equilibria,
                                u_max=args.u_max)
        if prof is not None:
            prof.disable()
            prof_rows = _profile_rows(prof)
        t_frac, c_frac = time.perf_counter() - w1, time.process_time() - c1
        pts, _ = sc.crack_path(st)
        reach = float(np.max(pts[:, 1]) / sc.R) if len(pts) else 0.0
        wall = time.perf_counter() - w0 - w_ref
        cpu = time.process_time() - c0 - c_ref
        sv = curve.time_split_s["solver"]
        eqs = len(curve.load)
        split = {"scene": t_scene, "assembly": sv["assembly_s"], "factorisation": sv["factor_s"],
                 "cg": sv["cg_s"], "residual": sv["residual_s"], "failure": curve.time_split_s["failure"]}
        split["other"] = wall - sum(split.values())
        for k, v in split.items():
            shares[k] += v
        P_c = curve.peak[0]
        rows.append({"alpha": al, "particles": sc.system.n, "free dofs": nfree, "K nnz": nnz,
                     "wall s": wall, "cpu s": cpu, "scene s": t_scene, "fracture s": t_frac,
                     "fracture cpu s": c_frac, "equilibria": eqs, "stop": curve.stop_reason,
                     "final/peak": float(curve.load[-1] / P_c), "crack y/R": reach, "P_c kN": P_c / 1e3,
                     "s/equilibrium": t_frac / eqs, "direct solve s": t_direct,
                     "eq/direct": None if t_direct is None else t_frac / eqs / t_direct,
                     "factorisations": sv["factorisations"], "cg iterations": sv["cg_iterations"],
                     "direct fallbacks": sv.get("direct_fallbacks", 0),
                     "newton iterations": sv["outer_iterations"],
                     **{f"{k} %": 100 * v / wall for k, v in split.items()}})
        write_json(args.outdir / "bench-scb_partial.json", {"rows": rows})   # survives a stopped run
    print(f"SCB to full crack (load < {args.stop_fraction:g} of the peak), dx = {dx * 1e3:g} mm, "
          f"delta = 3 dx, r_s = {args.r_s * 1e3:g} mm, one thread; load average at the start {load0:.2f}")
    base = main_baseline(dx, args.r_s, args.stop_fraction, alphas)
    for i, r in enumerate(rows):
        r["main wall s"] = base["wall_s"][i] if base else None
        r["main P_c kN"] = base["P_c_kN"][i] if base else None
        r["speed-up"] = base["wall_s"][i] / r["wall s"] if base else None
        r["P_c change %"] = 100 * (r["P_c kN"] / base["P_c_kN"][i] - 1) if base else None
    print(table(rows, ["alpha", "particles", "free dofs", "wall s", "cpu s", "scene s", "fracture s",
                       "equilibria", "stop", "final/peak", "crack y/R", "P_c kN", "s/equilibrium", "main wall s",
                       "speed-up", "main P_c kN", "P_c change %"]
                + (["direct solve s", "eq/direct"] if getattr(args, "direct_reference", False) else []), ".4g"))
    print("where the time goes (% of each angle's wall time)")
    print(table(rows, ["alpha", "scene %", "assembly %", "factorisation %", "cg %", "residual %", "failure %",
                       "other %", "factorisations", "newton iterations", "cg iterations", "direct fallbacks"],
                ".3g"))
    if prof_rows:
        print(f"cProfile of the fracture at alpha = {alphas[0]:g} deg (own time; numba kernels are one entry each)")
        print(table(prof_rows, floatfmt=".4g"))
    total = sum(r["wall s"] for r in rows)
    res = {"dx_m": dx, "r_s_m": args.r_s, "stop_fraction": args.stop_fraction, "alpha_deg": alphas,
           "particles": [r["particles"] for r in rows],
           "wall_s_per_angle": [r["wall s"] for r in rows], "cpu_s_per_angle": [r["cpu s"] for r in rows],
           "table_wall_s": total, "table_cpu_s": sum(r["cpu s"] for r in rows),
           "equilibria": [r["equilibria"] for r in rows], "stop_reason": [r["stop"] for r in rows],
           "final_over_peak": [r["final/peak"] for r in rows], "crack_reach_y_over_R": [r["crack y/R"] for r in rows], "P_c_kN": [r["P_c kN"] for r in rows],
           "s_per_equilibrium": [r["s/equilibrium"] for r in rows],
           "direct_solve_s": [r["direct solve s"] for r in rows],
           "equilibrium_over_direct": (float(np.mean([r["eq/direct"] for r in rows]))
                                       if getattr(args, "direct_reference", False) else None),
           "factorisations": [r["factorisations"] for r in rows],
           "cg_iterations": [r["cg iterations"] for r in rows],
           "direct_fallbacks": [r["direct fallbacks"] for r in rows],
           "time_share_pct": {k: 100 * v / total for k, v in shares.items()},
           "loadavg_start": load0, "loadavg_end": os.getloadavg()[0], "profile": prof_rows,
           "full_crack": all(r["stop"] == "load dropped" for r in rows),
           "main_result": base["file"] if base else None,
           "main_wall_s_per_angle": base["wall_s"] if base else None,
           "main_P_c_kN": base["P_c_kN"] if base else None,
           "speedup_vs_main": sum(base["wall_s"]) / total if base else None,
           "cpu_speedup_vs_main": (sum(base["cpu_s"]) / sum(r["cpu s"] for r in rows)) if base else None,
           "P_c_change_pct": [r["P_c change %"] for r in rows] if base else None,
           "P_c_change_pct_max": max(abs(r["P_c change %"]) for r in rows) if base else None}
    res["pass"] = res["full_crack"]
    if base:
        res["pass"] = bool(res["full_crack"] and res["speedup_vs_main"] >= TARGET_SPEEDUP
                           and res["P_c_change_pct_max"] <= TARGET_P_C_PCT)
    return res
