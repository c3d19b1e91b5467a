"""LAMMPS tension references of tubes and bundles, their analysis and plots.

Cases
-----
``reference-tension``  one LAMMPS tension run (quasi-static or dynamic), analysed.
``references``         regenerates every kept reference in ``data/reference/`` and its plots.
``reference-extensometer``  reruns the kept small dynamic references and, where the rerun
                       reproduces the stored curve exactly, adds its extensometer strain.
``tersoff-chain``      the project's Tersoff calculator + an ASE optimiser against the LAMMPS
                       quasi-static curve of the same short (10,10) tube.

The kept reference set (``REFERENCE_SET``), all with ``BNC.tersoff`` and the step cutoff:

* quasi-static, periodic tubes of ~100 Å (rounded to whole unit cells): (10,10), (17,0),
  (12,6), pristine and with the 4-atom vacancy, strain steps of 0.5 %;
* dynamic, open tubes of ~150 Å with 50 Å grips (free length ~50 Å), 1 Å/ps per grip,
  10 K: the same six tubes;
* dynamic, 7-tube (10,10) bundle of ~150 Å (walls 3.4 Å apart, LJ between tubes), vacancy in
  the central tube;
* quasi-static pristine (10,10) of ~20 Å with the standard switching function, 2 % steps to
  60 % strain (with 1 % steps the damped-dynamics fallback found the broken state at 27 %
  instead of the stretched metastable branch: the artefact branch is path dependent): shows the cutoff artefact (plateau, then a rise), flagged
  ``rise_after_plateau`` (a 100 Å tube spent > 10 min in one step of the plateau here);
* the seed 004 large tubes (> 10,000 atoms dynamic), both with the 4-atom vacancy:
  dynamic (50,50) and (30,60) of ~150 Å (same protocol as the other dynamic tubes;
  ``dyn_50-50_vac4``, ``dyn_30-60_vac4``) and a quasi-static periodic (50,50) of ~100 Å with
  0.5 % steps (``qs_50-50_vac4``; the (30,60) one takes ~1.5 h on one core and is not kept yet).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from validation.registry import case, table

REPO = Path(__file__).resolve().parents[2]
REF_DIR = REPO / "data" / "reference"
PLOT_DIR = REF_DIR / "plots"

QS_LENGTH = 100.0
LOCALISED_FRACTION = 0.2  # damaged atoms of tube 1 below this fraction: a crack, not diffuse
DYN_LENGTH = 150.0
TUBES = [(10, 10), (17, 0), (12, 6)]
LARGE_TUBES = [(50, 50), (30, 60)]  # the seed 004 cases, vacancy only


def _spec(protocol, n, m, vac, length, ntubes=1):
    tag = f"{'qs' if protocol == 'quasi-static' else 'dyn'}_{n}-{m}_{'vac4' if vac else 'pristine'}"
    if ntubes > 1:
        tag += f"_bundle{ntubes}"
    return {"name": tag, "protocol": protocol, "chirality": (n, m), "vacancy": vac,
            "length": length, "ntubes": ntubes}


REFERENCE_SET = (
    [_spec("quasi-static", n, m, v, QS_LENGTH) for (n, m) in TUBES for v in (False, True)]
    + [_spec("dynamic", n, m, v, DYN_LENGTH) for (n, m) in TUBES for v in (False, True)]
    + [_spec("dynamic", 10, 10, True, DYN_LENGTH, ntubes=7)]
    # the standard switching function, to show (and flag) the cutoff artefact
    + [dict(_spec("quasi-static", 10, 10, False, 20.0), name="qs_10-10_pristine_stdcut",
            cutoff="standard", max_strain=0.6, strain_step=0.02)]
    # the seed 004 large tubes (dynamic first: they have priority when run one by one)
    + [_spec("dynamic", n, m, True, DYN_LENGTH) for (n, m) in LARGE_TUBES]
    # quasi-static (50,50) only: (30,60) was started but not finished (~1.5 h on one core)
    + [_spec("quasi-static", 50, 50, True, QS_LENGTH)]
)


def parse_chirality(text):
    try:
        n, m = (int(v) for v in str(text).split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--chirality {text!r}; valid: two integers N,M (e.g. 10,10)") from None
    from upscale.build import chirality  # noqa: PLC0415

    try:
        chirality(n, m)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return n, m


def build_structure(spec):
    """The ase.Atoms of a reference spec (tube or bundle, vacancy as the seed places it)."""
    from upscale.build import bundle, swcnt, vacancy  # noqa: PLC0415

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
    from tqdm import tqdm  # noqa: PLC0415

    from upscale.experiments.lammps.tension import (default_dump_dir, dynamic_tension,  # noqa: PLC0415
                                           quasi_static_tension)

    from upscale.experiments.lammps.potential import resolve_potential  # noqa: PLC0415

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
    from upscale.analysis.damage import (crack_line, dump_damage,  # noqa: PLC0415
                                         split_along_axis, unroll)
    from upscale.analysis.plots import plot_damage_map  # noqa: PLC0415

    from upscale.analysis.stress import curve_metrics  # noqa: PLC0415

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
    from upscale.analysis.damage import read_dump  # noqa: PLC0415

    types = np.asarray(read_dump(dump).atoms.types).astype(int)
    sel = np.nonzero(types == 1)[0]  # tube 1 (the central tube of a bundle)
    # reference network on tube 1 to find the vacancy neighbours (under-coordinated atoms)
    from upscale.analysis.damage import bond_network  # noqa: PLC0415

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
    from upscale.analysis.damage import read_dump  # noqa: PLC0415

    u = read_dump(dump)
    return float(u.trajectory[0].dimensions[2])


def _frame_positions(dump, k):
    import warnings  # noqa: PLC0415

    from upscale.analysis.damage import dump_box_lows, read_dump  # noqa: PLC0415

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


def _summary_row(res):
    d = res.get("damage", {})
    return {"name": res["name"], "atoms": res["structure"]["n_atoms"],
            "strength_GPa": res["strength_GPa"],
            "strain_at_peak": res["strain_at_peak"],
            "failure_strain": res["failure_strain"] if res["failure_strain"] is not None else "-",
            "E_TPa": res["youngs_modulus_TPa"],
            "max_GPa": res.get("max_stress_overall_GPa", "-"),
            "crack_deg": d.get("crack_angle_to_axis_deg", "-"),
            "start_to_vac_A": d.get("crack_start_distance_to_vacancy_A", "-"),
            "ejected": d.get("n_ejected_atoms", "-"),
            "wall_s": res["wall_s"]}


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
    from potentials.lammps_runtime import LammpsUnavailable  # noqa: PLC0415

    try:
        return _reference_tension(args)
    except (ValueError, FileNotFoundError, LammpsUnavailable) as exc:
        raise SystemExit(f"reference-tension: {exc}") from None


def _reference_tension(args):
    from upscale.io import write_json  # noqa: PLC0415

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
    plot = (PLOT_DIR if keep else args.outdir) / f"damage_{spec['name']}.png"
    res = analyse(res, plot_path=plot)
    write_json(Path(outdir) / f"{spec['name']}.json", res)
    print(table([_summary_row(res)]))
    out = _key_figures(res)
    out["pass"] = bool(abs(out["zero_strain_stress_GPa"]) < 0.05 and res["strength_GPa"] > 0)
    return out


def _args_refs(p):
    p.add_argument("--only", default=None, help="comma-separated names (e.g. qs_10-10_vac4)")
    p.add_argument("--skip-existing", action="store_true",
                   help="keep JSONs already in data/reference/ (only redo plots)")
    p.add_argument("--plots-only", action="store_true", help="no LAMMPS runs, replot only")
    _add_common(p)


def write_readme(results):
    from upscale.io import atomic_write_text  # noqa: PLC0415

    rows = [_summary_row(r) for r in results]
    lines = [
        "# LAMMPS tension references",
        "",
        "Generated by `python -m validation references` (validation/cases/references.py,",
        "runners in upscale/experiments/lammps/). Do not edit by hand: rerun the command.",
        "",
        "* Source: LAMMPS through its Python module (`potentials.lammps_runtime`); version, ",
        "  potential file name and sha256, protocol and date are inside every JSON.",
        "* Potential: `BNC.tersoff` (Lindsay & Broido C-C parameters) with the step cutoff",
        "  (switching region narrowed to D = 1e-5 Å at the outer cutoff R + D = 2.1 Å, written",
        "  by `potentials.tersoff.write_step_cutoff_file`).",
        "* Stress: wall-thickness convention, area ntubes * 2 pi R t, t = 3.4 Å, R the mean",
        "  radius of the relaxed tube; quasi-static stress = -pzz V / (2 pi R t L); dynamic",
        "  stress = mean grip reaction force / area.",
        "* Every test starts from the structure relaxed to zero axial stress (atoms and axial",
        "  cell length, `fix box/relax z 0`); strain is measured from that length.",
        "* Quasi-static: periodic tubes of ~100 Å (whole unit cells), 0.5 % strain steps, CG",
        "  minimisation at fixed cell after each step.",
        "* Dynamic: open tubes of ~150 Å, 50 Å end grips moved apart at 1 Å/ps each, 1 fs",
        "  time step, Nose-Hoover 10 K on the free part (temperature from vx, vy), strain =",
        "  grip separation change / initial free length. Bundle: 7 (10,10) tubes, walls 3.4 Å",
        "  apart, Tersoff within tubes + LJ (epsilon 2.84 meV, sigma 3.4 Å, cut 10.2 Å;",
        "  Girifalco, Hodak & Lee PRB 62, 13104 (2000)) between tubes, vacancy in the centre.",
        "* Young's modulus: least-squares slope over 0-2 % strain. Strength: maximum stress",
        "  before the first drop of more than 5 %. Damage index mu = 1 - R/T (seed 004",
        "  eq. 5.16): bonds < 2.0 Å in the first frame, broken beyond 2.1 Å. Crack angle:",
        "  principal axis of the damaged atoms of tube 1 on the unrolled surface (R theta, z)",
        "  in the last frame, 90 deg = perpendicular to the axis; reported only when the",
        "  damage is localised (< 20 % of the tube's atoms damaged; a pristine periodic tube",
        "  can fail everywhere at once). Crack start: centre of the first damaged atoms vs the",
        "  centre of the vacancy's under-coordinated atoms, on the unrolled surface.",
        "* The 4-atom vacancy removes the 4 atoms nearest the seed's point (L/2, R, 0) (our",
        "  (x_c + R, y_c, L/2), axis along z); which 4 (a compact cluster or a short chain)",
        "  depends on where that point falls in the lattice, so strengths with a vacancy",
        "  depend on the tube length; the removed indices are in each JSON.",
        "* Quasi-static minimisation with the step cutoff: CG, then damped dynamics",
        "  (LAMMPS quickmin) and CG again while a force component exceeds 1e-4 eV/Å (a bond",
        "  held at the step stops CG line searches); residual forces per step are in the",
        "  JSON (`curve.fmax_eV_per_A`).",
        "* With the step cutoff, an MD step that lands inside the 2e-5 Å switching window gives",
        "  an atom a huge kick (energy is not conserved there): after fracture a few atoms can",
        "  be thrown off; they are counted (`damage.n_ejected_atoms`, column `ejected`) and",
        "  left out of the damage maps and crack fits. Such an atom drags the shrink-wrapped",
        "  box (and LAMMPS's neighbour bins) with it: since the (50,50)/(30,60) references a",
        "  dynamic run stops when the box volume exceeds 1e8 A^3 (`aborted` in the JSON; the",
        "  earlier references ran without that stop, the bundle's box reached 2.6e5 A in z).",
        "* Extensometer (dynamic; `python -m validation reference-extensometer`, the seed-scale",
        "  tubes with `--only`; recorded in `extensometer_added`): the grip strain includes",
        "  the compliance of the material next to the grips, so the dynamic references also",
        "  carry `curve.extensometer_strain`, the least-squares slope of the atoms' axial",
        "  displacement against their axial position at the start of the pull over the atoms",
        "  between two marks a quarter of the gauge inside each grip plane (each sample the",
        "  mean over its 100 steps, every 10 steps, as the stress; window and atom count in",
        "  `protocol_detail.extensometer`), `youngs_modulus_ext_TPa` (the same 0-2 % fit on",
        "  it) and `strain_at_peak_ext` (its value at the strength sample). The runs were",
        "  repeated with it and kept only where strain and stress reproduce bit for bit. A",
        "  least-squares slope weighs the local strain most at the window's centre, where",
        "  the vacancy sits: the vacancy tubes' `youngs_modulus_ext_TPa` is 4-5 % below",
        "  their grip modulus (pristine: 2-4 % above: next to the rigid grips, which also",
        "  hold the radius, the tube is stiffer than in the middle),",
        "  and a crack opening inside the strength sample's 100 steps enters",
        "  `strain_at_peak_ext` ((17,0) seed 3 in `seed_spread.json`: 0.230, the other",
        "  seeds 0.123).",
        "* Trajectories (LAMMPS dumps) are kept outside the repository",
        "  (~/.cache/upscale/dumps/).",
        "",
        "## Results",
        "",
        "```",
        table(rows),
        "```",
        "",
        "Plots: `plots/stress_strain_*.png` (overlays), `plots/damage_*.png` (damage maps).",
        "",
        "Seed spread: `seed_spread.json` (`python -m validation reference-seeds --seeds 8",
        "--save`, then `--seeds 16 --save --chirality 10,10`) reruns the three small dynamic",
        "vacancy references with 8 thermal seeds, 16 for (10,10) (the kept one",
        "first; it reproduces the stored run exactly, and so does every seed stored before,",
        "`reproduces_stored`); its `stats` give how far one dynamic run's strength, strain at",
        "peak and modulus move with the thermal start (also on the extensometer). The (10,10)",
        "tube's vacancy makes its strength a matter of when the thermal motion breaks its",
        "first bond: over 16 seeds 62.4-75.9 GPa (mean 69.8, sd 3.6) at strains at peak",
        "0.077-0.101, while (17,0) and (12,6) keep an sd of 0.1 and 0.3 GPa. The temperature",
        "moves it likewise (one run each, `reference-seeds --seeds 1 --chirality 10,10",
        "--temperature T`, printed, not stored): 82.5 GPa at 0.113 at 0 K, 78.0 at 0.105 at 0.01 K, 67.2 at",
        "0.085 at 1 K. (50,50): 3 seeds (`--seeds 3 --chirality 50,50 --reuse-kept`).",
        "`seed_spread_pristine.json` (`python -m validation reference-seeds --pristine",
        "--seeds 4 --save`, 2026-11-22) does the same for the three pristine dynamic",
        "references (the kept seed reproduces `dyn_*_pristine.json` exactly). These fail next",
        "to a grip plane and hardly move with the seed (strength sd 0.01-0.05 GPa, strain at",
        "peak the same sample in 11 of 12 runs), but the modulus, fitted over the first 2 % of",
        "strain at 10 K, moves by 1.0-1.6 % (sd 0.4-0.7 %) between seeds.",
        "",
        'Grip stiffness: `grip_stiffness.json` (`python -m validation dcbr-grip-stiffness',
        '--save`) holds the static stiffness k = F / separation of each small vacancy tube',
        "held by the dynamic protocol's grips (same set-up, grips moved apart by 0.25 % of",
        'the gauge, free atoms minimised), a number free of gauge conventions to set the',
        "coarse model's grips against.",
        '',
        'Quasi-static protocol sensitivity: `qs_protocol_sensitivity.json` (`python -m',
        'validation reference-qs-sensitivity --save`) reruns the quasi-static vacancy references',
        'with the minimisation varied (strain step 0.25 %, quickmin dmax 0.005 Å or 0.5 fs, CG',
        'only, FIRE (it lost atoms), backtracking line search); the converged variants move the strength by',
        '<= 2.2 % ((10,10)) and 1.7 % ((17,0), (12,6)); CG alone stalls at the step cutoff with',
        'residual forces up to 196 eV/Å and is not a quasi-static result.',
        '',
        "Cross-check of the chain: `python -m validation tersoff-chain` relaxes and stretches",
        "a short periodic (10,10) tube with the project's Tersoff calculator",
        "(`potentials.tersoff.Tersoff.from_lammps('BNC.tersoff', step_cutoff=True)`) and ASE's",
        "LBFGS, and compares its stress with this LAMMPS runner at every strain up to the peak",
        "(key `max_stress_rel_err`).",
        "",
    ]
    atomic_write_text(REF_DIR / "README.md", "\n".join(lines))


def make_overlays(results):
    from upscale.analysis.plots import plot_stress_strain  # noqa: PLC0415

    paths = []
    for proto, tag in (("quasi-static", "qs"), ("dynamic", "dyn")):
        sel = [dict(r, label=r["name"]) for r in results
               if r["protocol"] == proto and r["structure"]["ntubes"] == 1]
        if sel:
            p = PLOT_DIR / f"stress_strain_{tag}.png"
            plot_stress_strain(sel, p, title=f"LAMMPS BNC.tersoff, {proto} "
                               "(step cutoff; _stdcut: standard)")
            paths.append(p)
    b = [dict(r, label=r["name"]) for r in results
         if r["structure"]["chirality"] == [10, 10] and r["protocol"] == "dynamic"]
    if any(r["structure"]["ntubes"] > 1 for r in b):
        p = PLOT_DIR / "stress_strain_bundle.png"
        plot_stress_strain(b, p, title="(10,10): 7-tube bundle vs single tube, dynamic")
        paths.append(p)
    return paths


@case("references", "regenerate every kept LAMMPS tension reference in data/reference/ "
      "with damage maps and stress-strain overlays", add_arguments=_args_refs)
def run_references(args):
    from tqdm import tqdm  # noqa: PLC0415

    from upscale.io import write_json  # noqa: PLC0415

    specs = REFERENCE_SET
    if args.quick:  # a reduced set: one short quasi-static tube, into the outdir
        res = run_spec(_spec("quasi-static", 10, 10, True, 30.0), args.potential, args.cutoff,
                       args.dump_dir, dump_name="case_references_quick", strain_step=0.02)
        res = analyse(res, plot_path=Path(args.outdir) / "damage_quick.png")
        write_json(Path(args.outdir) / "quick.json", res)
        print(table([_summary_row(res)]))
        return {"n_runs": 1, "pass": bool(res["strength_GPa"] > 0)}
    if args.only:
        names = set(args.only.split(","))
        unknown = names - {s["name"] for s in specs}
        if unknown:
            raise SystemExit(f"--only: unknown {sorted(unknown)}; valid: "
                             f"{', '.join(s['name'] for s in specs)}")
        specs = [s for s in specs if s["name"] in names]
    results = []
    for spec in tqdm(specs, desc="references", unit="run"):
        path = REF_DIR / f"{spec['name']}.json"
        if (args.skip_existing or args.plots_only) and path.is_file():
            res = json.loads(path.read_text())
            if args.plots_only:
                res = analyse(res, plot_path=PLOT_DIR / f"damage_{spec['name']}.png")
                write_json(path, res)
            results.append(res)
            continue
        if args.plots_only:
            continue
        res = run_spec(spec, args.potential, args.cutoff, args.dump_dir)
        res = analyse(res, plot_path=PLOT_DIR / f"damage_{spec['name']}.png")
        write_json(path, res)
        results.append(res)
    # overlays and README over everything kept (not only this invocation's runs)
    kept = [json.loads((REF_DIR / f"{s['name']}.json").read_text()) for s in REFERENCE_SET
            if (REF_DIR / f"{s['name']}.json").is_file()]
    make_overlays(kept)
    write_readme(kept)
    print(table([_summary_row(r) for r in kept]))
    return {"n_runs": len(results), "n_kept": len(kept),
            "total_wall_s": float(sum(r["wall_s"] for r in kept)),
            "pass": len(kept) == len(REFERENCE_SET)}


EXT_KEYS = ("youngs_modulus_ext_TPa", "strain_at_peak_ext")


def _args_ext(p):
    p.add_argument("--only", default=None,
                   help="comma-separated names (default: the small tubes' dyn_*_vac4 and "
                        "dyn_*_pristine)")
    _add_common(p)


@case("reference-extensometer", "rerun the kept small dynamic LAMMPS references and add the "
      "extensometer strain where the rerun reproduces them exactly", add_arguments=_args_ext)
def run_reference_extensometer(args):
    """Adds the extensometer fields to kept dynamic references without replacing them.

    Each reference is rerun with :func:`upscale.experiments.lammps.tension.dynamic_tension` as it was
    made (its spec, default seed, one rank, no dump, and no box-volume stop if it predates
    it); the new fields (``curve.
    extensometer_strain``, ``protocol_detail.extensometer``, ``youngs_modulus_ext_TPa``,
    ``strain_at_peak_ext``) are written into the stored JSON only if the rerun's strain and
    stress curves equal the stored ones exactly (the extensometer is measured inside LAMMPS
    and does not touch the dynamics); otherwise the case stops with the largest difference.
    """
    from upscale.io import write_json  # noqa: PLC0415
    from upscale.experiments.lammps.tension import dynamic_tension  # noqa: PLC0415

    names = (args.only.split(",") if args.only else
             [f"dyn_{n}-{m}_{k}" for n, m in TUBES for k in ("vac4", "pristine")])
    rows = []
    for name in names:
        path = REF_DIR / f"{name}.json"
        if not path.is_file():
            raise SystemExit(f"--only {name}: no {path.name} in data/reference/; valid: "
                             "names of kept dyn_* references")
        old = json.loads(path.read_text())
        if old["protocol"] != "dynamic" or old.get("nprocs", 1) != 1:
            raise SystemExit(f"{name}: protocol {old['protocol']!r}, nprocs "
                             f"{old.get('nprocs')}; valid: a dynamic reference run on 1 rank")
        spec = old["spec"]
        pd = old["protocol_detail"]
        t0 = time.perf_counter()
        new = dynamic_tension(build_structure(spec), args.potential,
                              cutoff=spec.get("cutoff", args.cutoff), grip=pd["grip_A"],
                              speed=pd["speed_A_per_ps_each_grip"],
                              temperature=pd["temperature_K"], timestep=pd["timestep_ps"],
                              # references made before the box-volume stop ran without it
                              max_box_volume=pd.get("max_box_volume_A3", 1e300))
        wall = time.perf_counter() - t0
        same = all(new["curve"][k] == old["curve"][k] for k in ("strain", "stress_GPa")) and \
            all(new[k] == old[k] for k in ("strength_GPa", "youngs_modulus_TPa",
                                           "strain_at_peak"))
        if not same:
            n = min(len(new["curve"]["stress_GPa"]), len(old["curve"]["stress_GPa"]))
            d = np.abs(np.subtract(new["curve"]["stress_GPa"][:n],
                                   old["curve"]["stress_GPa"][:n])).max()
            raise SystemExit(f"{name}: the rerun does not reproduce the stored curve ("
                             f"{len(new['curve']['strain'])} vs {len(old['curve']['strain'])} "
                             f"samples, max stress difference {d:.3g} GPa); not stored")
        old["curve"]["extensometer_strain"] = new["curve"]["extensometer_strain"]
        old["protocol_detail"]["extensometer"] = new["protocol_detail"]["extensometer"]
        old.update({k: new[k] for k in EXT_KEYS})
        old["extensometer_added"] = {
            "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "command": f"python -m validation reference-extensometer --only {name}",
            "reproduced": "the rerun's strain and stress curves equal the stored ones bit for "
                          "bit (same seed, one rank)",
            "rerun_wall_s": wall, "rerun_dynamics_s": new["timing_s"]["dynamics"]}
        write_json(path, old)
        rows.append({"name": name, "E_TPa": old["youngs_modulus_TPa"],
                     "E_ext_TPa": old["youngs_modulus_ext_TPa"],
                     "strain_at_peak": old["strain_at_peak"],
                     "strain_at_peak_ext": old["strain_at_peak_ext"],
                     "strength_GPa": old["strength_GPa"], "wall_s": wall,
                     "dynamics_s": new["timing_s"]["dynamics"]})
        print(table(rows[-1:], floatfmt=".5g"), flush=True)
    kept = [json.loads((REF_DIR / f"{s['name']}.json").read_text()) for s in REFERENCE_SET
            if (REF_DIR / f"{s['name']}.json").is_file()]
    write_readme(kept)
    print(table(rows, floatfmt=".5g"))
    return {"runs": rows, "pass": True}


# --------------------------------------------------------------------------------------
# tersoff-chain: the project's Tersoff calculator + ASE optimiser vs the LAMMPS curve
# --------------------------------------------------------------------------------------
def _args_chain(p):
    p.add_argument("--length", type=float, default=10.0,
                   help="(10,10) tube length, Å (rounded to whole cells; default %(default)s)")
    p.add_argument("--strain-step", type=float, default=0.01)
    p.add_argument("--fmax", type=float, default=1e-5,
                   help="ASE optimiser force tolerance, eV/Å (default %(default)s)")


def ase_quasi_static(atoms, calc, strains, fmax=1e-5, progress=None):
    """Quasi-static tension with an ASE calculator, the same protocol as LAMMPS's runner.

    Zero-stress relaxation of atoms and the axial cell length (``FrechetCellFilter`` with
    only the zz strain free, LBFGS to ``fmax``), then for each strain the cell is set to
    ``L0 (1 + eps)`` with the atoms scaled affinely and the positions are relaxed (LBFGS,
    ``fmax``). Stress: ``sigma_zz V / (2 pi R t L)`` with R the mean radius after the
    zero-stress relaxation (ASE's stress is the positive-in-tension ``(1/V) dE/d eps``).

    Returns
    -------
    dict with ``L0_A``, ``radius_A``, ``strain``, ``stress_GPa``, ``steps``.
    """
    from ase.filters import FrechetCellFilter  # noqa: PLC0415
    from ase.optimize import LBFGS  # noqa: PLC0415

    from upscale.analysis.stress import EV_PER_A3_IN_GPA, wall_area  # noqa: PLC0415

    a = atoms.copy()
    a.calc = calc
    mask = [False, False, True, False, False, False]
    opt = LBFGS(FrechetCellFilter(a, mask=mask), logfile=None)
    opt.run(fmax=fmax, steps=20000)
    for _ in range(3):  # box and atoms again from the new reference
        opt = LBFGS(FrechetCellFilter(a, mask=mask), logfile=None)
        if opt.run(fmax=fmax, steps=20000) and opt.nsteps == 0:
            break
    L0 = float(a.cell[2, 2])
    xc = a.positions[:, :2].mean(axis=0)
    R = float(np.hypot(*(a.positions[:, :2] - xc).T).mean())
    A = wall_area(R)
    out = {"L0_A": L0, "radius_A": R, "strain": [], "stress_GPa": [], "steps": []}
    cell0 = a.cell.array.copy()
    for eps in strains:
        c = cell0.copy()
        c[2, 2] = L0 * (1.0 + eps)
        a.set_cell(c, scale_atoms=True)
        opt = LBFGS(a, logfile=None)
        opt.run(fmax=fmax, steps=20000)
        sig = a.get_stress(voigt=True)[2]  # eV/Å^3, tension positive
        V = a.get_volume()
        s = sig * V / (A * a.cell[2, 2]) * EV_PER_A3_IN_GPA
        out["strain"].append(float(eps))
        out["stress_GPa"].append(float(s))
        out["steps"].append(int(opt.nsteps))
        if progress is not None:
            progress(eps, s)
    return out


@case("tersoff-chain", "project Tersoff calculator + ASE optimiser vs LAMMPS quasi-static "
      "curve of a (10,10) tube (stress within 0.1% up to the peak)", add_arguments=_args_chain,
      target="stress within 0.1 % of LAMMPS up to the peak")
def run_tersoff_chain(args):
    from tqdm import tqdm  # noqa: PLC0415

    from potentials.tersoff import Tersoff  # noqa: PLC0415
    from upscale.analysis.plots import plot_stress_strain  # noqa: PLC0415
    from upscale.build import swcnt  # noqa: PLC0415
    from upscale.experiments.lammps.tension import quasi_static_tension  # noqa: PLC0415

    step = args.strain_step if not args.quick else 0.02
    tube = swcnt(10, 10, args.length)
    t0 = time.perf_counter()
    bar = tqdm(desc="LAMMPS", unit="step", leave=False)
    lmp = quasi_static_tension(tube, "tersoff:BNC.tersoff", cutoff="step", strain_step=step,
                               max_strain=0.40, ftol=1e-10, relax_ftol=1e-10, fmax_tol=1e-6,
                               after_failure=1,
                               progress=lambda e, s: (bar.update(1),
                                                      bar.set_postfix_str(f"{s:.1f} GPa")))
    bar.close()
    t_lmp = time.perf_counter() - t0
    e_l = np.array(lmp["curve"]["strain"])
    s_l = np.array(lmp["curve"]["stress_GPa"])
    ipk = int(np.argmax(s_l))
    strains = e_l[: ipk + 1]
    calc = Tersoff.from_lammps("BNC.tersoff", step_cutoff=True)
    bar = tqdm(total=len(strains), desc="ASE", unit="step", leave=False)
    t0 = time.perf_counter()
    ase_res = ase_quasi_static(tube, calc, strains, fmax=args.fmax,
                               progress=lambda e, s: bar.update(1))
    bar.close()
    t_ase = time.perf_counter() - t0
    s_a = np.array(ase_res["stress_GPa"])
    ref = s_l[: ipk + 1]
    nz = strains > 0
    rel = np.abs(s_a[nz] - ref[nz]) / np.abs(ref[nz])
    rows = [{"strain": float(e), "lammps_GPa": float(r), "ase_GPa": float(a),
             "rel_err": float(abs(a - r) / abs(r)) if e > 0 else float("nan")}
            for e, r, a in zip(strains, ref, s_a)]
    print(table(rows))
    plot_stress_strain([("LAMMPS tersoff (step cutoff)", e_l, s_l),
                        ("project Tersoff + ASE LBFGS", strains, s_a)],
                       Path(args.outdir) / "tersoff_chain.png",
                       title=f"(10,10), L = {tube.cell[2, 2]:.2f} Å periodic, BNC.tersoff")
    out = {"max_stress_rel_err": float(rel.max()), "n_strains_compared": int(nz.sum()),
           "peak_strain": float(strains[-1]), "lammps_strength_GPa": float(ref[-1]),
           "ase_stress_at_peak_GPa": float(s_a[-1]),
           "L0_lammps_A": lmp["relaxation"]["L0_A"], "L0_ase_A": ase_res["L0_A"],
           "L0_rel_diff": abs(ase_res["L0_A"] - lmp["relaxation"]["L0_A"])
           / lmp["relaxation"]["L0_A"],
           "radius_lammps_A": lmp["relaxation"]["radius_relaxed_A"],
           "radius_ase_A": ase_res["radius_A"],
           "n_atoms": len(tube), "lammps_wall_s": t_lmp, "ase_wall_s": t_ase,
           "potential_sha256": lmp["potential"]["file_sha256"]}
    out["pass"] = bool(out["max_stress_rel_err"] < 1e-3)
    return out
