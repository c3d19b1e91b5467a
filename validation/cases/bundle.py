"""The 7-tube bundle: van der Waals between tubes at rest, and dynamic tension, against LAMMPS.

Cases
-----
``bundle-vdw``      the inter-tube Lennard-Jones energy and forces of the bundle at rest:
                    all-atomistic on the engine (Tersoff bodies + ``tube-vdw``) against
                    LAMMPS (``pair_style hybrid tersoff lj/cut``, the references' pair,
                    cutoff and parameters), and the mixed bundle (coarse outer tubes, atoms
                    reconstructed from their particles) against the all-atomistic one.
``bundle-tension``  the bundle scene (:mod:`upscale.experiments.scenes.bundle`) against the
                    full-atomistic LAMMPS bundle in dynamic tension (stored reference, or
                    computed on the fly with the same protocol).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from upscale.experiments.scenes.tube_tension import REFERENCE_DIR as REF_DIR
from upscale.experiments.scenes.tube_tension import ROOT as REPO
from upscale.experiments.scenes.tube_tension import parse_chirality
from validation.registry import case


def _rel(a, b):
    return float(abs(a - b) / max(abs(b), 1e-300))


def _frel(fa, fb):
    return float(np.abs(fa - fb).max() / max(np.abs(fb).max(), 1e-300))


def _args_vdw(p):
    p.add_argument("--chirality", type=parse_chirality, default=(10, 10), help="N,M")
    p.add_argument("--length", type=float, default=150.0, help="tube length, Å")
    p.add_argument("--coarsening", type=float, default=2.0,
                   help="coarsening of the outer tubes of the mixed bundle (default 2)")
    p.add_argument("--spacing", choices=("vdw", "seed"), default="vdw")


@case("bundle-vdw", "van der Waals between the tubes of a bundle at rest: engine vs LAMMPS "
      "(all-atomistic), mixed vs all-atomistic", add_arguments=_args_vdw,
      target="all-atomistic vdW energy and forces within 1e-10 of LAMMPS; the mixed bundle's "
             "inter-tube energy within 1 % of the all-atomistic one, on the default setting")
def run_bundle_vdw(args):
    from potentials.lammps_runtime import lammps_potential_path
    from potentials.tersoff import write_step_cutoff_file
    from upscale.experiments.lammps import bundle_pair_lines as lammps_pair_lines
    from upscale.experiments.lammps import evaluate as lammps_evaluate
    from upscale.experiments.lammps.potential import LJ_CUTOFF, LJ_EPSILON_EV, LJ_SIGMA
    from upscale.experiments.scenes.bundle import COARSE_PAIRS, BundleScene, TubeSpec
    from upscale.models.tube_vdw import TubeVdW

    n, m = args.chirality
    t0 = time.perf_counter()
    atomistic = BundleScene.create((n, m), args.length, [TubeSpec("tersoff")] * 7,
                                   spacing=args.spacing, vacancy_tube=0)
    if (atomistic.vdw.eps, atomistic.vdw.sigma, atomistic.vdw.rc) != \
            (LJ_EPSILON_EV, LJ_SIGMA, LJ_CUTOFF):
        raise SystemExit("bundle-vdw: the scene's LJ parameters differ from the references'")
    st = atomistic.state_at_rest()
    e_vdw = atomistic.vdw.energy(st)
    f_vdw = atomistic.vdw.force(st)
    e_tot = e_vdw + sum(mm.energy(st) for mm in atomistic.body_models)
    f_tot = f_vdw + sum(mm.force(st) for mm in atomistic.body_models)
    t_ours = time.perf_counter() - t0
    # LAMMPS: the same atoms (types = tubes), the LJ part alone and the whole pair
    atoms = atomistic.atoms_at_rest()
    types = atoms.arrays["mol-id"]
    step = write_step_cutoff_file(lammps_potential_path("BNC.tersoff"),
                                  Path(args.outdir) / "BNC.step.tersoff")
    t1 = time.perf_counter()
    ref_lj = lammps_evaluate(atoms, lammps_pair_lines(7, step, lj_only=True), types=types)
    ref_all = lammps_evaluate(atoms, lammps_pair_lines(7, step), types=types)
    t_lmp = time.perf_counter() - t1
    out = {"chirality": [n, m], "length_A": args.length, "spacing": args.spacing,
           "n_atoms": len(atoms),
           "energy_rel_err_all_atomistic": _rel(e_vdw, ref_lj["energy"]),
           "force_rel_err_all_atomistic": _frel(f_vdw, ref_lj["forces"]),
           "total_energy_rel_err_all_atomistic": _rel(e_tot, ref_all["energy"]),
           "total_force_rel_err_all_atomistic": _frel(f_tot, ref_all["forces"]),
           "vdw_energy_eV": e_vdw, "wall_s_engine": t_ours, "wall_s_lammps": t_lmp}
    # the mixed bundle: the outer tubes coarse, atoms reconstructed from their particles
    # on the validated setting the bundle's tension runs use (COARSE_PAIRS)
    mixed = BundleScene.create((n, m), args.length,
                               [TubeSpec("tersoff")] + [TubeSpec("dcbr", args.coarsening)] * 6,
                               spacing=args.spacing, vacancy_tube=0, coarse_pairs=COARSE_PAIRS)
    sm = mixed.state_at_rest()
    e_mixed = mixed.vdw.energy(sm)
    between_mixed = mixed.vdw.energy_between(sm)
    between_atom = atomistic.vdw.energy_between(st)
    lumped = mixed.lumped_vdw()
    e_lumped = lumped.energy(sm)
    # the tension runs' cheaper variant: coarse-coarse pairs through lumped sites only
    sv = mixed.vdw
    sites = [lumped.maps[k] if mixed.specs[k].model != "tersoff" else None
             for k in range(len(mixed.specs))]
    half = TubeVdW(sv.maps, sv.eps, sv.sigma, rc=sv.rc, sites=sites)
    half.prepare(mixed.assembly.system)
    e_half = half.energy(sm)
    out.update({"energy_rel_err_mixed": _rel(e_mixed, e_vdw),
                "energy_rel_err_lumped": _rel(e_lumped, e_vdw),
                "vdw_energy_mixed_eV": e_mixed, "vdw_energy_lumped_eV": e_lumped,
                "energy_rel_err_coarse_pairs_sites": _rel(e_half, e_vdw),
                "vdw_energy_coarse_pairs_sites_eV": e_half,
                "central_outer_energy_rel_err_mixed": _rel(between_mixed[0].sum(),
                                                           between_atom[0].sum()),
                "outer_outer_energy_rel_err_mixed": _rel(between_mixed[1:].sum(),
                                                         between_atom[1:].sum()),
                "coarsening": args.coarsening, "coarse_pairs": COARSE_PAIRS})
    pairs = between_atom != 0
    out["pair_energy_max_rel_err_mixed"] = float(np.max(np.abs(
        between_mixed[pairs] - between_atom[pairs]) / np.abs(between_atom[pairs])))
    out["dof_mixed"], out["dof_all_atomistic"] = mixed.dof, atomistic.dof
    # issue 21: all-atomistic vdW = LAMMPS to 1e-10, mixed within 1 % on the default setting
    out["pass"] = bool(out["energy_rel_err_all_atomistic"] < 1e-10
                       and out["force_rel_err_all_atomistic"] < 1e-10
                       and out["energy_rel_err_mixed"] < 0.01)
    return out


# ---------------------------------------------------------------------- bundle tension
def _args_tension(p):
    p.add_argument("--chirality", type=parse_chirality, default=(10, 10), help="N,M")
    p.add_argument("--length", type=float, default=150.0, help="tube length, Å (default 150)")
    p.add_argument("--coarsening", type=float, default=2.0,
                   help="coarsening K of the six outer tubes (default 2)")
    p.add_argument("--tubes", default=None,
                   help="model of each tube, centre first (default tersoff,dcbr:K x6)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--gap", type=float, default=None, help="wall gap, Å (default 3.4)")
    g.add_argument("--hexagon", action="store_true",
                   help="the seed's hexagon: centres 2.2 R apart")
    p.add_argument("--seeds", type=int, default=3,
                   help="thermal seeds of the engine run (the mean is compared with the mean "
                   "of the LAMMPS seeds stored; default 3, the bundle issue's seed means)")
    p.add_argument("--seed-start", type=int, default=4928459,
                   help="first thermal seed; the runs use seed-start, seed-start + 1, ... "
                   "(default 4928459, the references' default seed number)")
    from upscale.experiments.scenes.bundle import add_run_options

    add_run_options(p)


def lammps_bundle_references(n, m, length, spacing, gap):
    """The LAMMPS bundle references of this geometry: every stored seed (the default seed's
    file and ``_s<seed>`` variants), else one in the user cache folder
    (``cache_dir("references")``); none: a one-line error naming the command that makes it."""
    import json

    from upscale.experiments.lammps.cache import cache_dir
    from upscale.experiments.scenes.bundle import reference_name

    base = reference_name((n, m), spacing, True, 7)
    if gap is not None and abs(gap - 3.4) > 1e-9:
        base += f"_gap{gap:g}"
    found = sorted(REF_DIR.glob(f"{base}.json")) + sorted(REF_DIR.glob(f"{base}_s*.json"))
    cache = cache_dir("references")
    found += sorted(cache.glob(f"{base}.json")) if not found else []
    refs = [json.loads(p.read_text()) for p in found]
    rerun = REF_DIR / f"{base}_rerun.json"  # the kept run again, with per-tube reactions
    if refs and "stress_per_tube_GPa" not in refs[0]["curve"] and rerun.is_file():
        refs[0]["curve"]["stress_per_tube_GPa"] = json.loads(rerun.read_text())["curve"][
            "stress_per_tube_GPa"]
        refs[0]["curve"]["_per_tube_from"] = str(rerun.relative_to(REPO))
    if refs:
        return refs, [str(p.relative_to(REPO)) if p.is_relative_to(REPO) else str(p)
                      for p in found]
    raise SystemExit(f"bundle-tension: no LAMMPS reference {base}.json in {REF_DIR} or {cache}; "
                     f"compute it with python -m validation reference-tension --chirality {n},{m} "
                     f"--length {length:g} --vacancy --dynamic --bundle 7 --save-reference")


def _mean(rs, key):
    v = [r[key] for r in rs if r.get(key) is not None]
    return float(np.mean(v)) if v else None


def _pct(a, b):
    return None if a is None or b is None else float(100.0 * (a - b) / b)


@case("bundle-tension", "the bundle (atomistic centre, coarse outer tubes) in dynamic "
      "tension against the full-atomistic LAMMPS bundle", add_arguments=_args_tension)
def run_bundle_tension(args):
    import os

    from upscale.experiments.scenes.bundle import BundleScene, parse_specs
    from upscale.experiments.scenes.bundle_plots import plot_curves, plot_damage_maps
    from upscale.experiments.scenes.bundle_pull import dynamic_tension, tube_failures
    from upscale.io import write_json

    n, m = args.chirality
    spacing = "seed" if args.hexagon else "vdw"
    gap = 3.4 if args.gap is None else args.gap
    if args.seeds < 1:
        raise SystemExit(f"bundle-tension: --seeds {args.seeds}; valid: an integer >= 1")
    if args.quick:  # one seed: the quick run checks the pipeline, not the seed mean
        args.seeds = 1
    load0 = os.getloadavg()
    c_case0 = time.process_time()
    try:
        specs = parse_specs(args.tubes, 7, args.coarsening)
        scene = BundleScene.create((n, m), args.length, specs, spacing=spacing, gap=gap,
                                   vacancy_tube=0, allow_overlap=args.allow_overlap,
                                   vdw_every=args.vdw_every, coarse_pairs=args.coarse_pairs)
    except ValueError as exc:
        raise SystemExit(f"bundle-tension: {exc}") from None
    c_scene = time.process_time() - c_case0
    refs, ref_files = lammps_bundle_references(n, m, args.length, spacing, args.gap)
    runs = []
    t0 = time.perf_counter()
    for k in range(args.seeds):
        seed = args.seed_start + k
        if k:
            scene = BundleScene.create((n, m), args.length, specs, spacing=spacing, gap=gap,
                                       vacancy_tube=0, allow_overlap=args.allow_overlap,
                                       ratios=scene.info["ratios"], vdw_every=args.vdw_every,
                                       coarse_pairs=args.coarse_pairs)
        try:
            runs.append(dynamic_tension(scene, seed=seed, progress=not args.quick,
                                        max_strain=args.max_strain,
                                        integrator=args.integrator, inner=args.inner,
                                        thermostat=args.thermostat, chain=args.chain,
                                        settle_ps=args.settle))
        except ValueError as exc:
            raise SystemExit(f"bundle-tension: {exc}") from None
    wall = (time.perf_counter() - t0) / args.seeds
    lam_order = [tube_failures(r["curve"]["strain"], r["curve"]["stress_per_tube_GPa"])
                 for r in refs if "stress_per_tube_GPa" in r["curve"]]
    out = {"chirality": [n, m], "coarsening": args.coarsening, "spacing": spacing,
           "wall_gap_A": scene.info["wall_gap_A"], "tubes": [s.model for s in specs],
           "seeds": args.seeds, "engine_seeds": [args.seed_start + k for k in range(args.seeds)],
           "lammps_seeds": len(refs), "lammps_files": ref_files}
    for key, name in (("strength_GPa", "strength"), ("youngs_modulus_TPa", "modulus"),
                      ("strain_at_peak", "strain_at_peak")):
        ours, theirs = _mean(runs, key), _mean(refs, key)
        out[f"{name}_engine"] = ours
        out[f"{name}_lammps"] = theirs
        out[f"{name}_err_pct"] = _pct(ours, theirs)
        if len(runs) > 1:
            out[f"{name}_engine_sd"] = float(np.std([r[key] for r in runs], ddof=1))
        if len(refs) > 1:
            out[f"{name}_lammps_sd"] = float(np.std([r[key] for r in refs], ddof=1))
    dof_atoms = 3 * scene.info["n_atoms"]
    out.update({"dof": scene.dof, "dof_atoms": dof_atoms,
                "dof_reduction_pct": float(100.0 * (scene.dof - dof_atoms) / dof_atoms),
                "wall_s": wall, "lammps_wall_s": _mean(refs, "wall_s"),
                "cpu_s": _mean(runs, "cpu_s"), "lammps_cpu_s": _mean(refs, "cpu_s"),
                "vdw_every": args.vdw_every, "coarse_pairs": args.coarse_pairs,
                "integrator": args.integrator, "thermostat": args.thermostat,
                "chain": args.chain, "settle_ps": args.settle,
                "inner": args.inner if args.integrator == "respa" else 1,
                "failure_order": [r["failure_order"] for r in runs],
                "tube_failure_strain": [r["tube_failure_strain"] for r in runs],
                "lammps_failure_order": [o["failure_order"] for o in lam_order],
                "lammps_tube_failure_strain": [o["tube_failure_strain"] for o in lam_order],
                "central_tube_fails_first": bool(all(r["central_tube_fails_first"]
                                                     for r in runs)),
                "lammps_central_tube_fails_first": [o["central_tube_fails_first"]
                                                    for o in lam_order],
                "timing_s": [r["timing_s"] for r in runs],
                "scene_cpu_s": c_scene, "case_cpu_s": time.process_time() - c_case0,
                "per_seed": [{"seed": args.seed_start + k, **{q: r[q] for q in (
                    "strength_GPa", "youngs_modulus_TPa", "strain_at_peak", "failure_order",
                    "tube_failure_strain", "wall_s", "cpu_s")}}
                    for k, r in enumerate(runs)],
                "lammps_per_seed": [{"file": f, **{q: r.get(q) for q in (
                    "strength_GPa", "youngs_modulus_TPa", "strain_at_peak", "wall_s")},
                    "steps": r.get("timing_s", {}).get("steps"),
                    "dynamics_s": r.get("timing_s", {}).get("dynamics")}
                    for f, r in zip(ref_files, refs)],
                "load_before": list(load0), "load_after": list(os.getloadavg())})
    out["speedup"] = (out["lammps_wall_s"] / wall) if out["lammps_wall_s"] else None
    out["speedup_cpu"] = (out["lammps_cpu_s"] / out["cpu_s"]) if out["lammps_cpu_s"] else None
    # the runs themselves (without their arrays), and plots
    tagj = f"{n}-{m}_K{args.coarsening:g}_{spacing}"
    if args.seeds > 1 or args.seed_start != 4928459:
        tagj += f"_s{args.seed_start}x{args.seeds}"
    write_json(Path(args.outdir) / f"bundle_run_{tagj}.json",
               {"runs": [{k: v for k, v in r.items() if not k.startswith("_")
                          and k != "damage"} for r in runs],
                "damage": [[{"tube": d["tube"], "model": d["model"],
                             "damaged_fraction": d["damaged_fraction"],
                             "max_mu": d["max_mu"]} for d in r["damage"]] for r in runs]})
    tag = f"{n}-{m}_K{args.coarsening:g}_{spacing}"
    plot_curves(runs[0], Path(args.outdir) / f"bundle_{tag}.png", refs[0] if refs else None,
                title=f"({n},{m}) 7-tube bundle, outer tubes K={args.coarsening:g}: engine "
                      "(solid) vs LAMMPS (dashed)")
    plot_damage_maps(runs[0], Path(args.outdir) / f"bundle_damage_{tag}.png",
                     title=f"({n},{m}) bundle K={args.coarsening:g}: damage, last state")
    ok = [out[k] is not None for k in ("strength_err_pct", "modulus_err_pct",
                                       "strain_at_peak_err_pct")]
    out["pass"] = bool(all(ok) and abs(out["strength_err_pct"]) <= 5.0
                       and abs(out["modulus_err_pct"]) <= 3.0
                       and abs(out["strain_at_peak_err_pct"]) <= 10.0
                       and out["central_tube_fails_first"]
                       and (out["speedup"] or 0) >= 5.0)
    return out
