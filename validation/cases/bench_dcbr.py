"""bench-dcbr-seed: wall time of the coarse model against LAMMPS on the seed 004 large tubes.

Both run in the same session on the same machine, one after the other (LAMMPS on one rank;
the coarse model's kernels are serial numba, one core): the dynamic vacancy tension of the
~150 Å (50,50) and (30,60) tubes (50 Å grips, 1 Å/ps, 10 K). LAMMPS is run with its
minimisation force tolerance ``--lammps-ftol`` (2-norm of the global force vector, default
1e-4 eV/Å: every force component then below 1e-4, at least as tight as the coarse model's
set-up, max component 1e-4); the stored references used 1e-6, which costs most of their
wall time. Reported, per tube: the parts of each run (relaxation, dynamics, steps), the
time per MD step, and the ratios (whole run; dynamics per step; dynamics per simulated
picosecond, ``speedup_per_ps``: LAMMPS at its 1 fs step against the coarse model with
multiple time stepping, ``--integrator respa``, and its atomistic region shaped about the
vacancy, ``--region``), plus the strength, modulus and strain at peak of the coarse run
against the stored reference.
"""
from __future__ import annotations

import time

from validation.registry import case, table


def _args(p):
    p.add_argument("--chirality", action="append", default=None,
                   help="N,M (repeatable; default 50,50 30,60)")
    p.add_argument("--coarsening", type=float, action="append", default=None,
                   help="coarsening factor (default 4); repeatable, then one per --chirality "
                        "in the same order (the coarsest resolution within 5 %% differs by tube)")
    p.add_argument("--grips", choices=("bands", "clamped"), default="clamped",
                   help="the coarse grips (validation.cases.dcbr.dynamic_scene; default clamped;"
                        " bands make these tubes' gauge atomistic)")
    p.add_argument("--lammps-ftol", type=float, default=1e-4,
                   help="LAMMPS minimize force tolerance, eV/Å (default 1e-4)")
    p.add_argument("--integrator", choices=("verlet", "respa"), default="respa",
                   help="the coarse run's time stepping (default respa: multiple time "
                        "stepping, --outer-dt / --inner; verlet: 1 fs)")
    p.add_argument("--outer-dt", type=float, default=5.0,
                   help="respa: outer step of the coarse forces, fs (default 5)")
    p.add_argument("--inner", type=int, default=5,
                   help="respa: 1 fs steps of the atomistic region per outer step (default 5)")
    p.add_argument("--region", choices=("band", "disc", "ellipse"), default="band",
                   help="the coarse model's atomistic region about the vacancy (default band, "
                        "the one whose crack path is atomistic; ellipse: 8 Å along the axis, "
                        "--r-arc around)")
    p.add_argument("--r-arc", type=float, default=30.0,
                   help="ellipse: circumferential semi-axis, Å (default 30)")


@case("bench-dcbr-seed", "coarse vs LAMMPS wall time, seed 004 large vacancy tubes (dynamic)",
      add_arguments=_args)
def _bench(args):
    from upscale.models.dcbr_dynamic import dynamic_tension as coarse_dynamic
    from validation.cases.dcbr import _chirality, lammps_reference_or_run, dynamic_scene
    from validation.cases.references import DYN_LENGTH, _spec, build_structure
    from validation.lammps.tension import dynamic_tension as lammps_dynamic

    if not args.lammps_ftol > 0:
        raise SystemExit(f"--lammps-ftol {args.lammps_ftol}; valid: > 0")
    tubes = [_chirality(c) for c in (args.chirality or ["50,50", "30,60"])]
    ks = args.coarsening or [4.0]
    if len(ks) not in (1, len(tubes)) or not all(k >= 1.0 for k in ks):
        raise SystemExit(f"--coarsening {ks}; valid: one factor >= 1, or one per tube "
                         f"({len(tubes)} tubes)")
    ks = ks * len(tubes) if len(ks) == 1 else ks
    rows = []
    for (n, m), K in zip(tubes, ks):
        ref = lammps_reference_or_run(n, m, DYN_LENGTH, vacancy=True, protocol="dynamic")
        print(f"({n},{m}) K={K:g}: coarse run (build, set-up relaxation, dynamics)...", flush=True)
        t0 = time.perf_counter()
        rkw = {"region": args.region} | ({"r_arc": args.r_arc} if args.region == "ellipse"
                                         else {})
        model, dyn = dynamic_scene(n, m, DYN_LENGTH, K, ref, grips=args.grips, **rkw)
        dyn.pop("grips")
        build = time.perf_counter() - t0
        if args.integrator == "respa":
            dyn.update(integrator="respa", outer_dt=args.outer_dt, inner=args.inner)
        rc = coarse_dynamic(model, **dyn)
        wall_c = time.perf_counter() - t0
        atoms = build_structure(_spec("dynamic", n, m, True, DYN_LENGTH))
        print(f"({n},{m}): coarse {wall_c:.1f} s; LAMMPS run ({len(atoms)} atoms; its set-up "
              "minimisation takes several minutes)...", flush=True)
        t0 = time.perf_counter()
        rl = lammps_dynamic(atoms, "tersoff:BNC.tersoff", cutoff="step", ftol=args.lammps_ftol)
        wall_l = time.perf_counter() - t0
        tl = rl["timing_s"]
        row = {"tube": f"({n},{m})", "K": K, "grips": args.grips,
               "atoms": len(atoms), "dof": model.dof,
               "coarse_build_s": build, "coarse_setup_s": rc["setup_relax_s"],
               "coarse_dynamics_s": rc["dynamics_s"], "coarse_steps": rc["steps"],
               "coarse_wall_s": wall_c,
               "lammps_relax_s": tl["zero_stress_relaxation"] + tl["open_tube_minimisation"],
               "lammps_dynamics_s": tl["dynamics"], "lammps_steps": tl["steps"],
               "lammps_wall_s": wall_l, "lammps_ref_wall_s": ref.get("wall_s"),
               "coarse_ms_per_step": 1e3 * rc["dynamics_s"] / rc["steps"],
               "lammps_ms_per_step": 1e3 * tl["dynamics"] / max(tl["steps"], 1)}
        row["speedup_per_step"] = row["lammps_ms_per_step"] / row["coarse_ms_per_step"]
        # per simulated picosecond (LAMMPS at its 1 fs step, the coarse model at its own:
        # with multiple time stepping one outer step of dt_fs)
        row.update({"coarse_integrator": args.integrator, "coarse_dt_fs": rc["dt_fs"],
                    "coarse_inner_steps": rc.get("inner_steps"), "region": args.region,
                    "free_atoms": model.nf,
                    "coarse_s_per_ps": rc["dynamics_s"] / (rc["steps"] * rc["dt_fs"] * 1e-3),
                    "lammps_s_per_ps": tl["dynamics"] / (max(tl["steps"], 1) * 1e-3)})
        row["speedup_per_ps"] = row["lammps_s_per_ps"] / row["coarse_s_per_ps"]
        row["speedup_whole_run"] = wall_l / wall_c
        row["speedup_vs_stored_reference"] = (ref["wall_s"] / wall_c) if ref.get("wall_s") else None
        row.update({"strength_coarse_GPa": rc["strength_GPa"],
                    "strength_lammps_now_GPa": rl["strength_GPa"],
                    "strength_reference_GPa": ref["strength_GPa"],
                    "strength_err_pct": 100 * abs(rc["strength_GPa"] / ref["strength_GPa"] - 1),
                    "modulus_err_pct": 100 * abs(rc["youngs_modulus_TPa"]
                                                 / ref["youngs_modulus_TPa"] - 1),
                    "strain_at_peak_err_pct": 100 * abs(rc["strain_at_peak"]
                                                        / ref["strain_at_peak"] - 1)})
        rows.append(row)
        print(table([row], floatfmt=".4g"), flush=True)
    print(table(rows, ["tube", "K", "atoms", "dof", "coarse_wall_s", "lammps_wall_s",
                       "speedup_whole_run", "coarse_ms_per_step", "lammps_ms_per_step",
                       "speedup_per_step", "speedup_per_ps", "speedup_vs_stored_reference",
                       "strength_err_pct", "modulus_err_pct", "strain_at_peak_err_pct"],
                floatfmt=".4g"))
    return {"rows": rows, "lammps_ftol": args.lammps_ftol}
