"""``upscale tension``: quasi-static tension of a periodic single-wall tube with the coarse
DCBR model (:mod:`upscale.models.dcbr`), optionally beside its LAMMPS reference.

    upscale tension --chirality 10,10 --length 100 --coarsening 2 [--compare lammps]

Writes ``tension_N_M_K.json`` (curve, modulus, strength, strain at peak, damage, wall time,
versions) and, with ``--compare lammps``, the overlay plot with the damage map, and prints the
comparison table. The LAMMPS side is a LAMMPS run of the same tube, potential file and
protocol, read from ``data/reference/`` (or from ``validation/out/lammps-cache/``, where the
validation cases cache the references they compute); the scene is
:func:`upscale.experiments.scenes.tube_tension.run_tension_comparison`.
"""
from __future__ import annotations

import time
from pathlib import Path

__all__ = ["register", "run"]


def register(subparsers):
    p = subparsers.add_parser("tension", help="quasi-static tension of a tube with the DCBR model",
                              description=__doc__)
    p.add_argument("--chirality", default="10,10", help="N,M (default 10,10)")
    p.add_argument("--length", type=float, default=100.0, help="tube length, Å (default 100)")
    p.add_argument("--coarsening", type=float, default=2.0,
                   help="particle spacing / lattice constant, >= 1 (default 2)")
    p.add_argument("--strain-step", type=float, default=0.005)
    p.add_argument("--max-strain", type=float, default=0.40)
    p.add_argument("--potential", default="tersoff:BNC.tersoff")
    p.add_argument("--compare", choices=["lammps"], default=None,
                   help="load the stored LAMMPS reference and print the comparison")
    p.add_argument("--outdir", type=Path, default=Path("out/tension"))
    p.add_argument("--engine", action="store_true",
                   help="run the load steps on the particle engine (L-BFGS-B on the positions, "
                   "shifts relaxed at every configuration): a checkpoint and an extxyz/VTK "
                   "frame with damage per load step in OUTDIR/engine_N_M_K/")
    p.set_defaults(func=run)


def run(args) -> int:
    from upscale.io import versions, write_json
    from upscale.experiments.scenes.tube_tension import quasi_static_tension
    from upscale.models.dcbr import DCBRTube

    from upscale.experiments.scenes.tube_tension import parse_chirality

    n, m = parse_chirality(args.chirality)
    out = Path(args.outdir)
    tag = f"{n}_{m}_K{args.coarsening:g}"
    if args.compare == "lammps":
        from upscale.experiments.scenes.tube_tension import ROOT, run_tension_comparison
        from upscale.io import text_table as table

        try:
            res = run_tension_comparison(n, m, args.length, args.coarsening, args.strain_step,
                                         outdir=out,
                                         cache_dir=ROOT / "validation" / "out" / "lammps-cache")
        except LookupError as exc:  # no stored reference: say how to compute it
            raise ValueError(str(exc)) from None
        curve = res.pop("_curve")
        rows = [
            {"quantity": "Young's modulus (TPa)", "DCBR": res["modulus_TPa"],
             "LAMMPS": res["modulus_lammps_TPa"], "error (%)": res["modulus_err_pct"]},
            {"quantity": "strength (GPa)", "DCBR": res["strength_GPa"],
             "LAMMPS": res["strength_lammps_GPa"], "error (%)": res["strength_err_pct"]},
            {"quantity": "strain at peak", "DCBR": res["strain_at_peak"],
             "LAMMPS": res["strain_at_peak_lammps"], "error (%)": res["strain_at_peak_err_pct"]},
            {"quantity": "degrees of freedom", "DCBR": res["dof"], "LAMMPS": res["dof_atoms"],
             "error (%)": ""},
            {"quantity": "wall time (s)", "DCBR": res["wall_s"], "LAMMPS": res["lammps_wall_s"],
             "error (%)": ""},
        ]
        print(f"({n},{m}) tube, {res['atoms']} atoms, coarsening {args.coarsening:g} "
              f"({res['particles']} particles); stress on wall thickness 3.4 A")
        print(table(rows, ["quantity", "DCBR", "LAMMPS", "error (%)"], floatfmt=".5g"))
        print(f"speed-up {res['speedup']:.3g}x (LAMMPS: {res['lammps_source']})")
        write_json(out / f"tension_{tag}.json", {"result": res, "curve": curve,
                                                 "versions": versions()})
        print(f"wrote {out / f'tension_{tag}.json'} and {out / f'dcbr_tension_{n}_{m}_K{args.coarsening:g}.png'}")
        return 0
    t0 = time.perf_counter()
    model = DCBRTube(n, m, args.length, coarsening=args.coarsening, potential=args.potential)
    show = lambda e, s: print(f"strain {e:.4f}  stress {s:9.3f} GPa", flush=True)  # noqa: E731
    if args.engine:
        from upscale.engine.checkpoint import Checkpoint
        from upscale.engine.output import Output
        from upscale.experiments.scenes.tube_tension import quasi_static_tension_engine

        frames = out / f"engine_{tag}"
        res = quasi_static_tension_engine(
            model, strain_step=args.strain_step, max_strain=args.max_strain, progress=show,
            checkpoint=Checkpoint(frames / "checkpoint.npz", every=1),
            output=Output(frames, every=1, length_unit=1e-10))
    else:
        res = quasi_static_tension(model, strain_step=args.strain_step,
                                   max_strain=args.max_strain, progress=show)
    res["wall_s"] = time.perf_counter() - t0
    write_json(out / f"tension_{tag}.json", {"result": res, "versions": versions()})
    print(f"({n},{m}) coarsening {args.coarsening:g}: {model.N} particles for {model.n_atoms} atoms; "
          f"E = {res['youngs_modulus_TPa']:.4f} TPa, strength {res['strength_GPa']:.2f} GPa at "
          f"strain {res['strain_at_peak']:.3f}; {res['wall_s']:.1f} s; wrote {out / f'tension_{tag}.json'}")
    return 0
