"""The nanotube: the coarse (DCBR) tube and the engine's atomistic tube against LAMMPS and
against main's recorded figures.

The scenes are :mod:`upscale.experiments.scenes.tube_tension`'s; these cases compare them.
References: closed-form affine fields (``gain-affine``) and LAMMPS through the runners of
:mod:`upscale.experiments.lammps.tension` (same potential file, tube and protocol), taken from
``data/reference/*.json`` when a record matches, else computed and cached in
``cache_dir("references")`` (never the source tree), keyed by the runners' source checksum.

``protocol-atomistic``: the engine's atomistic Tersoff tube against LAMMPS, both through
:func:`upscale.experiments.tension` with the same protocol object; the potential is exact
against LAMMPS (``tersoff-vs-lammps``), so any difference is the protocol's. Quasi-static
tension of a periodic (10,10), 100 Å; compression of a periodic (10,10), 120 Å, with a
divacancy in the middle (it picks the buckling mode), past buckling, strain step 0.001;
torsion of a free (10,10), 100 Å, 10 Å rigid grips, past buckling, 1 degree per step.
Target (issue "One way to run a scene"): curves within 1 % (max |d sigma| / |sigma_peak| up
to the first drop of either), buckling strain and twist angle within 2 %. Beside it (not in
``pass``): the dynamic pull of a free (10,10) of 100 Å, 10 Å grips at 1 Å/ps each, 10 K, the
seed means over :data:`DYNAMIC_SEEDS` each side. ``--quick``: a (5,5), never a pass.

``tube-regression``: ``experiments.tension(model="dcbr")`` on main's quasi-static table
(``validation/baselines/main-99b82f2.json``, recorded before the old tube paths were
replaced by the scene): strength within 1e-4 relative, the modulus's error against LAMMPS
within 1e-2 points (main kept that error, not the modulus), the same strain at peak.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from upscale import experiments
from upscale.constants import ACC_EV_A_AMU_IN_A_FS2, ASE_TIME_FS, CARBON_MASS_AMU, K_B_EV
from upscale.experiments.lammps.cache import cache_dir
from upscale.experiments.scenes.tube_tension import (GRIPS, REFERENCE_DIR, dynamic_scene,
                                                     lammps_reference, parse_chirality)
from upscale.experiments.scenes.tube_tension import run_tension_comparison as _run_tension
from validation.registry import case, figure, show

CACHE = cache_dir("references")
RUNNER = Path(__file__).resolve().parents[2] / "upscale" / "experiments" / "lammps"  # the runners


def _run_lammps(protocol, atoms, potential, cutoff, strain_step, progress):
    """The LAMMPS tension runner (:mod:`upscale.experiments.lammps.tension`) for a missing reference."""
    from upscale.experiments.lammps.tension import dynamic_tension, quasi_static_tension

    if protocol == "quasi-static":
        return quasi_static_tension(atoms, potential, cutoff=cutoff, strain_step=strain_step,
                                    progress=progress)
    return dynamic_tension(atoms, potential, cutoff=cutoff, progress=progress)


def _runner_tag() -> str:
    import hashlib

    h = hashlib.sha256()
    for f in sorted(RUNNER.glob("*.py")):  # a changed runner = new run
        h.update(f.read_bytes())
    return h.hexdigest()[:10]


def lammps_reference_or_run(n, m, length, **kw) -> dict:
    """:func:`upscale.experiments.scenes.tube_tension.lammps_reference`, computing a missing record
    with the LAMMPS runner and caching it in ``cache_dir("references")`` (the user cache
    folder), keyed by the runners' source checksum."""
    return lammps_reference(n, m, length, cache_dir=CACHE, cache_tag=_runner_tag(),
                            runner=_run_lammps, **kw)


def run_tension_comparison(*args, **kw) -> dict:
    """:func:`upscale.experiments.scenes.tube_tension.run_tension_comparison` with references
    stored, cached or computed now (see :func:`lammps_reference_or_run`)."""
    return _run_tension(*args, cache_dir=CACHE, runner=_run_lammps, **kw)


def _err_pct(a, b):
    return 100.0 * abs(a - b) / abs(b)


# ---------------------------------------------------------------------------- gain-affine
def _gain_affine(args):
    from upscale.models.dcbr import DCBRTube
    from upscale.models.gain import build_gain

    rng = np.random.default_rng(11)
    m = 6 if args.quick else 9
    g = (np.arange(m) + 0.5) * 1.0
    x = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    x = x + rng.uniform(-0.3, 0.3, x.shape)
    horizon = 2.2
    inner = np.all((x > horizon) & (x < m - horizon), axis=1)

    def rot(axis, ang):
        a = np.asarray(axis, float) / np.linalg.norm(axis)
        K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K

    fields = {"stretch": np.diag([1.1, 0.95, 1.02]),
              "shear": np.array([[1, 0.2, 0], [0, 1, -0.1], [0.05, 0, 1.0]]),
              "rotation": rot([1, 2, 3], 0.7),
              "rotation+stretch": rot([0, 1, 1], -0.4) @ np.diag([1.05, 1.0, 0.9])}
    rows = []
    worst_inner, worst_all = 0.0, 0.0
    for stab in (False, True):
        op = build_gain(x, horizon, volume=rng.uniform(0.8, 1.2, len(x)), stabilised=stab)
        for name, F in fields.items():
            u = x @ (F - np.eye(3)).T + [0.1, 0.2, -0.3]
            err = np.abs(op.gain(u) - (F - np.eye(3))).max(axis=(1, 2))
            worst_inner = max(worst_inner, err[inner].max())
            worst_all = max(worst_all, err.max())
            rows.append({"field": name, "eq6.6_stabilised": stab, "particles": len(x),
                         "max|G-H| interior": float(err[inner].max()), "max|G-H| all": float(err.max())})
    show(rows, fmt=".6g")
    # cylinder: uniform radial + axial stretch (exact) and twist (O(h^2))
    R, nt, nz, dz = 6.0, 24, 40, 1.3
    th = 2 * np.pi * np.arange(nt) / nt
    z = dz * (np.arange(nz) + 0.5)
    T, Z = np.meshgrid(th, z, indexing="ij")
    th, z = T.ravel(), Z.ravel()
    xc = np.column_stack([R * np.cos(th), R * np.sin(th), z])
    L = nz * dz
    op = build_gain(xc, 3.2, surface=True, axis=[0, 0, 1], cell=[0, 0, L], pbc=(False, False, True))
    lt, lz = 0.97, 1.08
    F = op.deformation(xc * [lt, lt, lz], [0, 0, lz * L])
    C = np.einsum("nia,nib->nab", F, F)
    stretch_err = float(np.abs(C - np.diag([lt ** 2, lz ** 2])).max())
    op2 = build_gain(xc, 3.2, surface=True, axis=[0, 0, 1])
    kt = 0.01
    F2 = op2.deformation(np.column_stack([R * np.cos(th + kt * z), R * np.sin(th + kt * z), z]))
    inn = (z > 4) & (z < L - 4)
    C2 = np.einsum("nia,nib->nab", F2, F2)[inn]
    twist_err = float(np.abs(C2[:, 0, 1] / (R * kt) - 1).max())
    # rigid motion of the coarse tube: energy change
    tube = DCBRTube(10, 10, 30.0, coarsening=2)
    y = tube.x0 + 0.02 * rng.standard_normal(tube.x0.shape)
    d = 0.005 * rng.standard_normal((tube.N, 3))
    E1 = tube.energy_and_gradient(y, d, tube.L)[0]
    Q = rot([0, 0, 1], 0.9)
    E2 = tube.energy_and_gradient(y @ Q.T + [1.0, -2.0, 0.7], d, tube.L)[0]
    rigid = abs(E2 - E1)
    return {"gain_err_interior_max": float(worst_inner), "gain_err_all_max": float(worst_all),
            "cylinder_stretch_err_max": stretch_err, "cylinder_twist_rel_err_max": twist_err,
            "rigid_motion_energy_eV": float(rigid),
            "pass": bool(worst_inner < 1e-12 and stretch_err < 1e-12 and twist_err < 0.02
                         and rigid < 1e-9)}


case("gain-affine", "gain matrix G on affine fields (3D cloud), cylinder stretch/twist, rigid motions")(_gain_affine)


# ---------------------------------------------------------------------------- dcbr-energy
def _energy_args(p):
    p.add_argument("--chirality", action="append", default=None,
                   help="N,M (repeatable; default 10,10 17,0 12,6; --quick: 10,10)")
    p.add_argument("--length", type=float, default=None, help="tube length, Å (default: max(10, two unit cells))")
    p.add_argument("--coarsening", type=float, default=1.0)


def _dcbr_energy(args):
    from upscale.experiments.scenes.tube_tension import quasi_static_tension_engine
    from upscale.models.dcbr import DCBRTube

    from upscale.build import chirality

    chis = [parse_chirality(c) for c in (args.chirality or (["10,10"] if args.quick else
                                                              ["10,10", "17,0", "12,6"]))]
    step = 0.02 if args.quick else 0.01
    rows, worst, worst_ns = [], 0.0, 0.0
    for n, m in chis:
        length = args.length or max(10.0, 2 * chirality(n, m).cell_length)
        ref = lammps_reference_or_run(n, m, length, strain_step=step, progress=False)
        eps_peak = ref["strain_at_peak"]
        e_ref = np.array(ref["curve"]["energy_eV"])
        s_ref = np.array(ref["curve"]["strain"])
        out = {}
        for shift in (True, False):
            t = DCBRTube(n, m, length, coarsening=args.coarsening, relax_shift=shift,
                         stability=False)  # the uniform branch: no failure rule needed
            r = quasi_static_tension_engine(t, strain_step=step, max_strain=eps_peak + 1e-9,
                                            fit_max_strain=0.02 if step <= 0.01 else 0.04)
            out[shift] = np.array(r["curve"]["energy_eV"])
        natoms = ref["structure"]["n_atoms"]
        k = min(len(out[True]), len(e_ref))
        for i in range(1, k):
            if s_ref[i] > eps_peak + 1e-12:
                break
            d_ref = (e_ref[i] - e_ref[0]) / natoms
            d_cg = (out[True][i] - out[True][0]) / natoms
            d_ns = (out[False][i] - out[False][0]) / natoms
            err, err_ns = _err_pct(d_cg, d_ref), _err_pct(d_ns, d_ref)
            worst, worst_ns = max(worst, err), max(worst_ns, err_ns)
            rows.append({"tube": f"({n},{m})", "strain": float(s_ref[i]),
                         "dE_lammps_meV/atom": 1e3 * d_ref, "dE_dcbr_meV/atom": 1e3 * d_cg,
                         "err_%": err, "dE_no_shift_meV/atom": 1e3 * d_ns, "err_no_shift_%": err_ns})
        print(f"({n},{m}): LAMMPS reference from {ref['_source']}, peak at strain {eps_peak}")
    show(rows, fmt=".5g")
    return {"energy_err_pct_max": worst, "energy_err_pct_max_without_shift_relaxation": worst_ns,
            "tubes": [f"{n},{m}" for n, m in chis], "coarsening": args.coarsening,
            "strain_step": step, "pass": bool(worst < 1.0)}


case("dcbr-energy", "DCBR vs LAMMPS strain energy per atom of uniformly strained periodic tubes",
     add_arguments=_energy_args)(_dcbr_energy)


# ---------------------------------------------------------------------------- dcbr-tension
def _tension_args(p):
    p.add_argument("--chirality", default="10,10", help="N,M (default 10,10)")
    p.add_argument("--length", type=float, default=None, help="Å (default 100; --quick 25)")
    p.add_argument("--coarsening", type=float, default=2.0)
    _variant_args(p)
    p.add_argument("--r-atomistic", type=float, default=8.0,
                   help="with --vacancy: half-width (band) or radius (disc) of the atomistic region, Å")
    p.add_argument("--region", choices=("band", "disc"), default="band", help="with --vacancy")
    p.add_argument("--step-crossing", choices=("damped", "energy", "force", "always"), default="damped",
                   help="with --vacancy: how a pair held at the step cutoff goes across "
                   "(run_tension_comparison)")
    p.add_argument("--strain-step", type=float, default=0.005)
    p.add_argument("--hourglass", type=float, default=0.1,
                   help="zero-energy-mode control, fraction of the lattice stiffness (0 = off)")


def _variant_args(p):
    """--vacancy, --dynamic, --grips, --temperature: the tube and protocol of a comparison."""
    p.add_argument("--vacancy", action="store_true", help="the 4-atom vacancy tubes (DCBRDefectTube)")
    p.add_argument("--dynamic", action="store_true",
                   help="dynamic tension of the open tube with grips (150 Å, the dynamic references)")
    p.add_argument("--grips", choices=GRIPS, default=None,
                   help="dynamic: 'bands' (atomistic bands across the grip planes; the default "
                   "without --vacancy) or 'clamped' (coarse rows clamped rigid; with --vacancy)")
    p.add_argument("--temperature", type=float, default=10.0,
                   help="dynamic: thermostat K (default 10, as LAMMPS; 0 = NVE from rest)")


def _dcbr_tension(args):
    n, m = parse_chirality(args.chirality)
    # the dynamic scene needs the stored 150 Å references (50 Å grips); --quick keeps them
    length = args.length or (150.0 if args.dynamic else (25.0 if args.quick else 100.0))
    out = run_tension_comparison(n, m, length, args.coarsening, args.strain_step,
                                 args.vacancy, args.dynamic, outdir=args.outdir,
                                 hourglass=args.hourglass, r_atomistic=args.r_atomistic,
                                 region=args.region, step_crossing=args.step_crossing,
                                 temperature=args.temperature, grips=args.grips)
    out.pop("_curve")
    out["pass"] = bool(out["modulus_err_pct"] < 3 and out["strength_err_pct"] < 5
                       and out["strain_at_peak_err_pct"] < 10)
    return out


case("dcbr-tension", "DCBR vs LAMMPS quasi-static tension of a periodic tube (--chirality N,M)",
     add_arguments=_tension_args)(_dcbr_tension)


# ---------------------------------------------------------------------------- dcbr-table
def _table_args(p):
    p.add_argument("--chirality", action="append", default=None,
                   help="N,M (repeatable; default 10,10 17,0 12,6; --quick: 10,10)")
    p.add_argument("--length", type=float, default=None, help="Å (default 100; --quick 25)")
    p.add_argument("--coarsening", type=float, action="append", default=None,
                   help="repeatable (default 1 2 3 4)")
    _variant_args(p)


#: dcbr-table's columns and the keys of run_tension_comparison they show (the extensometer's
#: figures where the run has them: dynamic)
TABLE_COLUMNS = {"atoms": "atoms", "dof": "dof", "wall_s": "wall_s", "lammps_wall_s": "lammps_wall_s",
                 "speedup": "speedup", "strength_err_%": "strength_err_pct", "modulus_err_%": "modulus_err_pct",
                 "strain_at_peak_err_%": "strain_at_peak_err_pct", "strength_GPa": "strength_GPa",
                 "strength_lammps_GPa": "strength_lammps_GPa", "strain_at_peak": "strain_at_peak",
                 "strain_at_peak_lammps": "strain_at_peak_lammps", "modulus_ext_err_%": "modulus_ext_err_pct",
                 "strain_at_peak_ext_err_%": "strain_at_peak_ext_err_pct"}
CRACK_COLUMNS = {"crack_deg": "crack_angle_deg", "crack_lammps_deg": "crack_angle_lammps_deg",
                 "ejected": "ejected_atoms"}


def _dcbr_table(args):
    chis = [parse_chirality(c) for c in (args.chirality or (["10,10"] if args.quick else
                                                         ["10,10", "17,0", "12,6"]))]
    length = args.length or (150.0 if args.dynamic else (25.0 if args.quick else 100.0))
    ks = args.coarsening or [1.0, 2.0, 3.0, 4.0]
    rows = []
    for n, m in chis:
        for k in ks:
            o = run_tension_comparison(n, m, length, k, outdir=args.outdir, verbose=False,
                                       plot=(k == ks[-1]), vacancy=args.vacancy,
                                       dynamic=args.dynamic, temperature=args.temperature,
                                       grips=args.grips)
            row = {"tube": f"({n},{m}){' vac4' if args.vacancy else ''}", "K": k,
                   **{col: o[key] for col, key in TABLE_COLUMNS.items() if key in o}}
            if args.dynamic and not args.vacancy:  # where the pristine tube failed
                row.update({c: o.get(c) for c in ("first_damage_strain", "first_damage_to_grip_plane_A",
                                                  "first_damage_halves")})
            if args.vacancy or args.dynamic:
                row.update({col: o.get(key) for col, key in CRACK_COLUMNS.items()})
            if args.vacancy:
                row["first_damage_to_vacancy_A"] = o.get("crack_start_to_vacancy_A")
            rows.append(row)
            print(f"({n},{m}) K={k:g}: done in {o['wall_s']:.1f} s", flush=True)
    out = {"rows": rows, "strength_err_pct_max": max(r["strength_err_%"] for r in rows),
           "modulus_err_pct_max": max(r["modulus_err_%"] for r in rows),
           "strain_at_peak_err_pct_max": max(r["strain_at_peak_err_%"] for r in rows)}
    # issue 5's target as stated, quasi-static and dynamic alike: every row within the
    # budgets in this one run (a dynamic row is one thermal draw against the kept reference)
    out["pass"] = all(r["strength_err_%"] < BUDGET_PCT["strength"]
                      and r["modulus_err_%"] < BUDGET_PCT["modulus"]
                      and r["strain_at_peak_err_%"] < BUDGET_PCT["strain_at_peak"]
                      for r in rows)
    return out


#: the error budgets against LAMMPS (issue 5), per cent: every row of the table, one run
BUDGET_PCT = {"strength": 5.0, "modulus": 3.0, "strain_at_peak": 10.0}


case("dcbr-table", "run-time vs error table of the DCBR tube against LAMMPS (coarsening 1-4)",
     add_arguments=_table_args,
     target="every row: strength within 5 %, modulus 3 %, strain at peak 10 % of LAMMPS (one run)")(_dcbr_table)


# ---------------------------------------------------------------------------- dcbr-seeds
SEED_KEYS = ("strength_GPa", "youngs_modulus_TPa", "strain_at_peak")
SEED_BUDGET = dict(zip(SEED_KEYS, BUDGET_PCT.values()))


def _seeds_args(p):
    p.add_argument("--chirality", action="append", default=None,
                   help="N,M (repeatable; default 10,10 17,0 12,6)")
    p.add_argument("--seeds", type=int, default=4, help="thermal seeds 1000, 1001, ... (default 4)")
    p.add_argument("--coarsening", type=float, default=2.0, help="default 2")
    p.add_argument("--pristine", action="store_true",
                   help="pristine tubes (atomistic bands across the grip planes) instead of "
                        "the 4-atom vacancy tubes")
    p.add_argument("--grips", choices=GRIPS, default=None,
                   help="'bands' (default with --pristine) or 'clamped' (default otherwise)")


@case("dcbr-seeds", "the coarse model's dynamic tension over thermal seeds: its seed means "
      "against LAMMPS's (data/reference/seed_spread.json; --pristine: pristine tubes)",
      add_arguments=_seeds_args,
      target="seed means within 5 % (strength), 3 % (modulus), 10 % (strain at peak) of "
             "LAMMPS's seed means (issue 17), 4 seeds, every tube")
def _dcbr_seeds(args):
    """The coarse scene of ``dcbr-tension --dynamic`` (:func:`dynamic_scene`), seeds 1000,
    1001, ..., against the LAMMPS seed spread of the same tubes (``reference-seeds``)."""
    import json  # noqa: PLC0415

    from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension  # noqa: PLC0415

    if not args.coarsening >= 1.0 or args.seeds < 1:
        raise SystemExit(f"--coarsening {args.coarsening} --seeds {args.seeds}; valid: "
                         "coarsening >= 1, seeds >= 1")
    spread = json.loads((REFERENCE_DIR / ("seed_spread_pristine.json" if args.pristine
                                          else "seed_spread.json")).read_text())
    spread = spread.get("result", spread)["tubes"]
    rows, tubes, ok = [], {}, True
    for n, m in (parse_chirality(c) for c in (args.chirality or ["10,10", "17,0", "12,6"])):
        ref = lammps_reference_or_run(n, m, 150.0, protocol="dynamic",
                                      vacancy=not args.pristine, progress=False)
        runs = []
        for s in range(args.seeds):
            model, dyn = dynamic_scene(n, m, 150.0, args.coarsening, ref,
                                       vacancy=not args.pristine, grips=args.grips)
            dyn.pop("grips")
            r = dynamic_tension(model, seed=1000 + s, **dyn)
            runs.append({"seed": 1000 + s, **{k: r[k] for k in SEED_KEYS}})
            print(f"({n},{m}) K={args.coarsening:g} seed {1000 + s}: {r['strength_GPa']:.2f} "
                  f"GPa at {r['strain_at_peak']:.4f}", flush=True)
        lruns = spread[f"{n},{m}"]["runs"]
        row = {"tube": f"({n},{m})", "K": args.coarsening, "seeds": len(runs),
               "seeds_lammps": len(lruns)}
        for k in SEED_KEYS:
            c = float(np.mean([x[k] for x in runs]))
            lm = float(np.mean([x[k] for x in lruns]))
            row[f"{k}_mean"], row[f"{k}_lammps_mean"] = c, lm
            row[f"{k}_err_%"] = 100.0 * abs(c / lm - 1)
            ok &= row[f"{k}_err_%"] < SEED_BUDGET[k]
        rows.append(row)
        tubes[f"{n},{m}"] = runs
    return {"rows": rows, "runs": tubes, "pristine": bool(args.pristine),
            "strength_err_pct_max": max(r["strength_GPa_err_%"] for r in rows),
            "modulus_err_pct_max": max(r["youngs_modulus_TPa_err_%"] for r in rows),
            "strain_at_peak_err_pct_max": max(r["strain_at_peak_err_%"] for r in rows),
            "pass": bool(ok)}


# ---------------------------------------------------------------------------- dcbr-stability


def _stability_args(p):
    from upscale.models.dcbr_engine import MTS_SPLIT, SPLITS

    p.add_argument("--chirality", default="10,10")
    p.add_argument("--length", type=float, default=25.0)
    p.add_argument("--coarsening", type=float, default=2.0)
    p.add_argument("--steps", type=int, default=None, help="NVE steps (default 10000; --quick 500)")
    p.add_argument("--dt-fs", type=float, default=1.0, help="NVE time step, fs (default 1)")
    p.add_argument("--temperature", type=float, default=10.0, help="initial K (default 10)")
    p.add_argument("--hourglass", type=float, default=0.1,
                   help="zero-energy-mode control, fraction of the lattice stiffness (0 = off)")
    p.add_argument("--mts-outer-dt", type=float, default=5.0, help="multiple time stepping: outer step, fs")
    p.add_argument("--mts-inner", type=int, default=5, help="inner steps per outer step")
    p.add_argument("--mts-steps", type=int, default=None, help="outer steps (default 10000; --quick 1000)")
    p.add_argument("--mts-sample-every", type=int, default=1,
                   help="outer steps between the energy samples of the drift fit (both integrators)")
    p.add_argument("--mts-length", type=float, default=50.0, help="the periodic vacancy tube's length, Å")
    p.add_argument("--mts-region", choices=("band", "disc", "ellipse"), default="ellipse",
                   help="its atomistic region (ellipse: 8 Å axial, --mts-r-arc around)")
    p.add_argument("--mts-r-arc", type=float, default=12.0, help="the ellipse's circumferential semi-axis, Å")
    p.add_argument("--mts-seed", type=int, default=7, help="seed of the first run's initial velocities")
    p.add_argument("--mts-seeds", type=int, default=None,
                   help="velocity draws (seeds --mts-seed, +1, ...), each run by both integrators "
                        "(default 6; --quick 1)")
    p.add_argument("--mts-split", choices=tuple(SPLITS), default=MTS_SPLIT,
                   help="the force split (DCBRDefectTubeModel split)")
    p.add_argument("--no-mts", action="store_true", help="skip the multiple-time-step run")


def drift_estimates(t, e):
    """Two estimates of the drift of an energy record ``e`` (E(t) - E(0)) at times ``t``:
    ``(fit, tenths)``: the least-squares line's rise over the record, and the mean of the last
    tenth minus that of the first. On uncorrelated noise of variance s^2 over n samples the
    rise has variance 12 s^2 / n, the tenths' 20 s^2 / n. Neither tells a drift from a slow
    exchange between modes; the mean over independent velocity draws does."""
    t, e = np.asarray(t, float), np.asarray(e, float)
    if len(t) < 20 or len(t) != len(e):
        raise ValueError(f"drift_estimates: need >= 20 samples of t and e of one length, "
                         f"got {len(t)} and {len(e)}")
    slope = np.polyfit(t, e, 1)[0]
    k = max(1, len(e) // 10)
    return float(slope * (t[-1] - t[0])), float(np.mean(e[-k:]) - np.mean(e[:k]))


def _mts_nve(args, n, m):
    """NVE energy drift of the r-RESPA integrator (upscale.engine.respa) on the periodic
    coupled vacancy tube (10 K start), against velocity Verlet at the inner step over the same
    simulated time, on the same ``--mts-seeds`` velocity draws, in the same run. A run's drift:
    :func:`drift_estimates`, relative to the initial kinetic energy and to the atoms' cohesive
    energy. ``*_drift_rel``: the mean of the fitted rise over the draws, ``*_drift_rel_sem`` its
    standard error; ``mts_pass``: |mean| < 1e-4 KE0, ``mts_pass_resolved``: |mean| + 2 sem <
    1e-4. The MTS energy fluctuates within a run (bounded, at the atoms' periods), so the fit
    samples every outer step by default."""
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.respa import RESPA
    from upscale.engine.simulation import Simulation
    from upscale.models.dcbr_defect import DCBRDefectTube
    from upscale.models.dcbr_engine import FIELD, DCBRDefectTubeModel

    Dt, inner = args.mts_outer_dt, args.mts_inner
    steps = args.mts_steps or (1000 if args.quick else 10000)
    nseeds = args.mts_seeds or (1 if args.quick else 6)
    every_outer = args.mts_sample_every
    if not (Dt > 0 and inner >= 1 and steps >= 20 and nseeds >= 1 and every_outer >= 1
            and steps // every_outer >= 20):
        raise SystemExit(f"--mts-outer-dt {Dt}, --mts-inner {inner}, --mts-steps {steps}, "
                         f"--mts-seeds {nseeds}, --mts-sample-every {every_outer}; valid: "
                         "> 0, >= 1, >= 20, >= 1, >= 1 with at least 20 samples")
    kw = {"r_arc": args.mts_r_arc} if args.mts_region == "ellipse" else {}
    tube = DCBRDefectTube(n, m, args.mts_length, coarsening=args.coarsening, vacancy=4,
                          r_atomistic=8.0, region=args.mts_region, **kw)
    r0 = tube.minimise(None, None, None, relax_box=True, gtol=1e-6)
    y, d, Lz = r0.y, r0.delta, r0.Lz
    acc = ACC_EV_A_AMU_IN_A_FS2
    mass, mass_d = tube.masses()
    seeds = [args.mts_seed + k for k in range(nseeds)]
    out = {"mts_tube": f"({n},{m}) {args.mts_length:g} Å K={args.coarsening:g}, "
                       f"region {args.mts_region}", "mts_free_atoms": tube.nf,
           "mts_outer_dt_fs": Dt, "mts_inner": inner, "mts_outer_steps": steps,
           "mts_seeds": seeds, "mts_split": args.mts_split,
           "mts_samples_per_run": steps // every_outer}
    rows, records = [], {}
    for seed in seeds:
        for name, integ, nsteps in (("mts", RESPA(Dt, inner, force=True), steps),
                                    ("vv", VelocityVerlet(Dt / inner, force=True), steps * inner)):
            rng = np.random.default_rng(seed)
            v = rng.standard_normal(y.shape) * np.sqrt(K_B_EV * args.temperature * acc
                                                       / mass)[:, None]
            v -= np.sum(mass[:, None] * v, axis=0) / mass.sum()
            vd = rng.standard_normal(d.shape) * np.sqrt(K_B_EV * args.temperature * acc
                                                        / mass_d)[:, None]
            vd[tube.slave_idx] = 0.0
            em = DCBRDefectTubeModel(tube, y=y, delta=d, Lz=Lz,
                                     split=args.mts_split)
            sim = Simulation(em.system(), None, em, em.conditions(), integ)
            st = sim.state
            st.v[em.y_rows] = v
            if len(tube.slave_idx):
                st.v[tube.slave_idx] = tube.Phi @ v[em.nd:]
            st.field_v[FIELD][:tube.N] = vd

            def total():  # the unknowns' and shifts' kinetic energy (a slave's follows its atoms)
                vv, ww = st.v[em.y_rows], st.field_v[FIELD][:tube.N]
                return em.energy(st) + 0.5 * (np.sum(mass[:, None] * vv * vv)
                                              + np.sum(mass_d[:, None] * ww * ww)) / acc
            e0, k0 = total(), 0.5 * np.sum(mass[:, None] * v * v) / acc
            every = every_outer * (1 if name == "mts" else inner)  # the same times
            es, ts, sampling = [], [], [0.0]

            def sample(s_):  # the energy record; its own CPU time is left out of cpu_ms_per_fs
                if s_.state.step % every == 0:
                    c0 = time.process_time()
                    es.append(total())
                    ts.append(s_.state.t)
                    sampling[0] += time.process_time() - c0
                return False
            t0 = time.process_time()
            sim.run(nsteps, callback=sample, progress=not args.quick)
            cpu = time.process_time() - t0 - sampling[0]
            es = np.array(es) - e0
            fit, tenths = drift_estimates(ts, es)
            records[(name, seed)] = (np.asarray(ts) * 1e-3, es / k0)  # (ps, KE0)
            rows.append({"integrator": name, "seed": seed, "drift_fit_rel": fit / k0,
                         "drift_tenths_rel": tenths / k0, "max_dev_rel": float(np.abs(es).max() / k0),
                         "drift_fit_rel_to_cohesive": fit / abs(tube.e0 * tube.n_atoms),
                         "cpu_ms_per_fs": 1e3 * cpu / (steps * Dt), "KE0_eV": float(k0)})
    for name in ("mts", "vv"):
        r = [q for q in rows if q["integrator"] == name]
        fits = np.array([q["drift_fit_rel"] for q in r])
        sem = float(fits.std(ddof=1) / math.sqrt(len(fits))) if len(fits) > 1 else math.nan
        out.update({f"{name}_drift_rel": float(fits.mean()), f"{name}_drift_rel_sem": sem,
                    f"{name}_drift_rel_seeds": fits.tolist(),
                    f"{name}_drift_tenths_rel_seeds": [q["drift_tenths_rel"] for q in r],
                    f"{name}_max_dev_rel": max(q["max_dev_rel"] for q in r),
                    f"{name}_drift_rel_to_cohesive": float(np.mean([q["drift_fit_rel_to_cohesive"]
                                                                    for q in r])),
                    f"{name}_cpu_ms_per_fs": float(np.mean([q["cpu_ms_per_fs"] for q in r]))})
    out["mts_initial_KE_eV"] = [q["KE0_eV"] for q in rows if q["integrator"] == "mts"]
    out["mts_pass"] = bool(abs(out["mts_drift_rel"]) < 1e-4)
    out["mts_pass_resolved"] = bool(nseeds > 1 and abs(out["mts_drift_rel"])
                                    + 2 * out["mts_drift_rel_sem"] < 1e-4)
    show(rows)
    _plot_energy_records(records, args.outdir)
    return out


def _plot_energy_records(records, outdir):
    """(E - E0) / KE0 against time for every run (``records[(integrator, seed)] = (t_ps,
    e)``), MTS and Verlet side by side."""
    with figure(Path(outdir) / "mts_energy.png", 1, 2, figsize=(10, 3.6), dpi=120, sharey=True) as (fig, axes):
        for (name, seed), (t, e) in records.items():
            axes[0 if name == "mts" else 1].plot(t, e, lw=0.8, label=f"seed {seed}")
        for ax, title in zip(axes, ("r-RESPA (outer / inner step)", "velocity Verlet (inner step)")):
            ax.set(xlabel="t (ps)", title=title)
            ax.axhline(0, color="k", lw=0.5)
        axes[0].set_ylabel("(E - E0) / KE0")
        axes[1].legend(fontsize=7)


def _dcbr_stability(args):
    """Critical time step (velocity Verlet: dt_c = 2 / omega_max) of the coarse tube and of
    the atomistic lattice, and the NVE energy drift of the coarse tube."""
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import ParticleSystem
    from upscale.models.dcbr import DCBRTube, DCBRTubeModel

    n, m = parse_chirality(args.chirality)
    steps = args.steps or (500 if args.quick else 10000)
    t = DCBRTube(n, m, args.length, coarsening=args.coarsening, hourglass=args.hourglass)
    r0 = t.minimise(t.x0, t.delta, t.L, relax_box=True, gtol=1e-9)
    y, d, L0 = r0.y, r0.delta, r0.Lz
    N = t.N
    Keff = t.condensed_hessian(y, d, L0)  # shifts condensed (Schur complement)
    mass = np.repeat(t.natoms_n * CARBON_MASS_AMU, 3)
    wk = np.linalg.eigvalsh(Keff)
    # zero-energy modes beyond the 4 rigid ones (3 translations, rotation about the axis)
    spurious = int((np.abs(wk) < 1e-6 * wk.max()).sum()) - 4
    lowest_nonrigid = float(np.sort(np.abs(wk))[4] / wk.max())  # 5th smallest |eigenvalue|
    w2 = np.linalg.eigvalsh(Keff / np.sqrt(np.outer(mass, mass)))
    dt_c_coarse = 2.0 / math.sqrt(w2.max()) * ASE_TIME_FS
    # atomistic: the relaxed lattice on the periodic piece, carbon mass
    q = t._q_n[0].copy()
    H, U = t.stability.hessian(q)
    wa = np.linalg.eigvalsh(H / CARBON_MASS_AMU)
    dt_c_atom = 2.0 / math.sqrt(wa.max()) * ASE_TIME_FS
    # NVE on the engine: velocity Verlet on the particles, shifts relaxed at every step
    # (upscale.models.dcbr.DCBRTubeModel), links held (no failure in a 10 K run)
    rng = np.random.default_rng(1)
    mass_n = t.natoms_n * CARBON_MASS_AMU
    v = rng.standard_normal((N, 3)) * np.sqrt(K_B_EV * args.temperature / mass_n)[:, None]
    v -= (v * t.natoms_n[:, None]).sum(0) / t.natoms_n.sum()
    t.delta = d
    model = DCBRTubeModel(t, failure=False)
    model.set_cell(L0)
    sim = Simulation(ParticleSystem(t.x0, t.natoms_n, CARBON_MASS_AMU,
                                    spacing=float(min(t.spacing))), None, model,
                     integrator=VelocityVerlet(dt=args.dt_fs / ASE_TIME_FS))
    sim.state.y[...] = y
    sim.state.v[...] = v
    sim.prepare()
    ke0 = sim.kinetic_energy()
    Etot0 = sim.energy() + ke0
    drift = []
    every = max(1, steps // 20)
    t0 = time.perf_counter()
    done = 0
    while done < steps:
        k = min(every, steps - done)
        sim.run(k)
        done += k
        if done % every == 0:
            drift.append((done, sim.energy() + sim.kinetic_energy() - Etot0))
    wall = time.perf_counter() - t0
    Et = sim.energy() + sim.kinetic_energy()
    rel = (Et - Etot0) / ke0
    maxdev = max(abs(e) for _, e in drift) / ke0
    res = {"dt_crit_coarse_fs": dt_c_coarse, "dt_crit_atomistic_fs": dt_c_atom,
            "dt_crit_ratio": dt_c_coarse / dt_c_atom, "nve_steps": steps, "nve_dt_fs": args.dt_fs,
            "nve_drift_rel_to_KE0": float(rel), "nve_max_deviation_rel_to_KE0": float(maxdev),
            "nve_initial_KE_eV": float(ke0), "nve_wall_s": wall, "particles": N,
            "zero_energy_modes_beyond_rigid": spurious, "hourglass": args.hourglass,
            "lowest_nonrigid_eigenvalue_over_max": lowest_nonrigid,
            "pass": bool(dt_c_coarse >= dt_c_atom and abs(maxdev) < 1e-2 and spurious == 0)}
    if not args.no_mts:
        res.update(_mts_nve(args, n, m))
    return res


case("dcbr-stability", "critical time step of the DCBR tube vs the atomistic lattice, NVE drift",
     add_arguments=_stability_args)(_dcbr_stability)


# ---------------------------------------------------------------------------- dcbr-defect-nve
def _defect_nve_args(p):
    p.add_argument("--chirality", default="10,10")
    p.add_argument("--length", type=float, default=100.0)
    p.add_argument("--coarsening", type=float, default=2.0)
    p.add_argument("--steps", type=int, default=None, help="NVE steps (default 10000; --quick 1000)")
    p.add_argument("--dt-fs", type=float, default=1.0)
    p.add_argument("--temperature", type=float, default=10.0, help="initial K (default 10)")


def _dcbr_defect_nve(args):
    """NVE energy drift of the periodic coupled tube with the vacancy
    (:func:`upscale.experiments.scenes.tube_tension.defect_nve`)."""
    from upscale.experiments.scenes.tube_tension import defect_nve

    n, m = parse_chirality(args.chirality)
    steps = args.steps or (1000 if args.quick else 10000)
    if not (steps >= 10 and args.dt_fs > 0 and args.temperature > 0):
        raise SystemExit(f"--steps {steps}, --dt-fs {args.dt_fs}, --temperature "
                         f"{args.temperature}; valid: steps >= 10, dt > 0, temperature > 0")
    return defect_nve(n, m, args.length, args.coarsening, steps=steps, dt_fs=args.dt_fs,
                      temperature=args.temperature, progress=not args.quick)


case("dcbr-defect-nve", "NVE energy drift of the coupled vacancy tube (periodic, 10 K start)",
     add_arguments=_defect_nve_args)(_dcbr_defect_nve)


#: the scene keywords of the three checks; lengths in Å
CHECKS = {
    "tension": dict(load="tension", length=100.0),
    "compression": dict(load="compression", length=120.0, defects="v2@0.5@0", step=0.001,
                        maximum=0.1),
    "torsion": dict(load="torsion", length=100.0, grip=10.0, step=1.0, maximum=120.0),
}


#: the thermal seeds of the dynamic comparison, each side
DYNAMIC_SEEDS = (1, 2, 3, 4)
FIGURES = {"strength_GPa": "strength", "strain_at_peak": "strain_at_peak",
           "youngs_TPa": "youngs"}


def _args(p):
    p.add_argument("--only", default=None, help="comma list of tension,compression,torsion")


def dynamic_pull(chir, length) -> dict:
    """Seed means of the dynamic pull, ours and LAMMPS's (module docstring)."""
    from upscale.build import swcnt

    atoms = swcnt(*chir, length=length)
    kw = dict(protocol="dynamic", grip=10.0, maximum=0.3, temperature=10.0, progress=False)
    runs = {m: [experiments.tension(atoms, model=m, seed=s, **kw).figures
                for s in DYNAMIC_SEEDS] for m in ("atomistic", "lammps")}
    out = {}
    for f, key in FIGURES.items():
        a, b = (float(np.mean([r[f] for r in runs[m]])) for m in ("atomistic", "lammps"))
        out[f"dynamic_{key}_err_pct"] = 100 * (a / b - 1)
    return out


def curve_error_pct(a, b) -> float:
    """max |y_a - y_b| / |peak of b| in per cent over the common load points up to the first
    drop of either curve (both from :class:`~upscale.experiments.result.Result`)."""
    from upscale.experiments.protocols import StopRule

    name = "curve/torque_eV" if "curve/torque_eV" in a.curves else "curve/stress_GPa"
    ya, yb = a.curves[name], b.curves[name]
    rule = StopRule()
    n = min(len(ya), len(yb))
    for k in (rule.failed_at(ya), rule.failed_at(yb)):
        if k is not None:
            n = min(n, k)
    return float(100 * np.max(np.abs(ya[:n] - yb[:n])) / np.max(np.abs(yb[:n])))


@case("protocol-atomistic", "engine atomistic tube vs LAMMPS under the same protocol "
      "object: tension, compression past buckling, torsion past buckling", _args)
def protocol_atomistic(args) -> dict:
    chir = (5, 5) if args.quick else (10, 10)
    only = args.only.split(",") if args.only else list(CHECKS)
    rows, out = [], {}
    for name in only:
        kw = dict(CHECKS[name], chirality=chir, progress=False)
        if args.quick:
            kw["length"] = 40.0
            if name == "torsion":
                kw["grip"] = 5.0
        ours = experiments.tension(model="atomistic", **kw)
        ref = experiments.tension(model="lammps", **kw)
        ours.to_json(args.outdir / f"{name}_atomistic.json")
        ref.to_json(args.outdir / f"{name}_lammps.json")
        ours.plot(args.outdir / f"{name}.png", other=ref)
        peak = "twist_at_peak_deg" if name == "torsion" else "strain_at_peak"
        err_curve = curve_error_pct(ours, ref)
        err_peak = 100 * abs(ours.figures[peak] / ref.figures[peak] - 1)
        rows.append({"load": name, "curve err %": err_curve, "peak at (ours)": ours.figures[peak],
                     "LAMMPS": ref.figures[peak], "peak err %": err_peak,
                     "ours s": ours.meta["wall_s"], "LAMMPS s": ref.figures["wall_s"]})
        out[f"{name}_curve_err_pct"] = err_curve
        out[f"{name}_peak_err_pct"] = err_peak
    show(rows)
    out.update(dynamic_pull(chir, 60.0 if args.quick else 100.0))
    res = {"tension_curve_err_pct": out.get("tension_curve_err_pct"),
           "compression_buckling_strain_err_pct": out.get("compression_peak_err_pct"),
           "torsion_buckling_angle_err_pct": out.get("torsion_peak_err_pct"), **out}
    checks = [out[f"{n}_curve_err_pct"] <= 1.0 for n in only]
    checks += [out[f"{n}_peak_err_pct"] <= 2.0 for n in only if n != "tension"]
    res["pass"] = bool(all(checks)) and len(only) == len(CHECKS) and not args.quick
    return res


BASELINE = Path(__file__).resolve().parents[1] / "baselines" / "main-99b82f2.json"
#: strength compared with main: tolerance (relative)
TOL = {"strength_GPa": 1e-4}


def _regression_args(p):
    p.add_argument("--vacancy", action="store_true", help="the 4-atom-vacancy tubes' table")


def change_vs_main(vacancy: bool, quick: bool) -> list[dict]:
    base = json.loads(BASELINE.read_text())
    table_rows = base["dcbr-table-vacancy" if vacancy else "dcbr-table"]["rows"]
    rows = []
    for r in table_rows:
        n, m = (int(v) for v in r["tube"].split()[0].strip("()").split(","))
        if quick and ((n, m) != (10, 10) or r["K"] != 2):
            continue
        res = experiments.tension(chirality=(n, m), length=100.0, model="dcbr",
                                  coarsening=r["K"], progress=False,
                                  **({"structure": _seed_vacancy_tube(n, m)} if vacancy
                                     else {"defects": ""}))
        kw = {"structure": _seed_vacancy_tube(n, m)} if vacancy else \
            {"chirality": (n, m), "length": 100.0}
        ref = experiments.tension(model="lammps", progress=False, **kw)
        d_s = 100 * (res.figures["strength_GPa"] / r["strength_GPa"] - 1)
        e_mod = 100 * abs(res.figures["youngs_TPa"] / ref.figures["youngs_TPa"] - 1)
        rows.append({"tube": r["tube"], "K": r["K"], "strength_GPa": res.figures["strength_GPa"],
                     "main": r["strength_GPa"], "change_pct": d_s,
                     "modulus_err_pct": e_mod, "main_modulus_err_pct": r["modulus_err_%"],
                     "strain_at_peak": res.figures["strain_at_peak"],
                     "main_strain_at_peak": r["strain_at_peak"],
                     "wall_s": res.meta["wall_s"], "main_wall_s": r["wall_s"]})
    return rows


def _seed_vacancy_tube(n, m):
    from upscale.build import swcnt, vacancy

    return vacancy(swcnt(n, m, length=100.0), n=4)


@case("tube-regression", "the coarse tube's quasi-static table (experiments.tension) against "
      "main's recorded figures (validation/baselines/main-99b82f2.json)", _regression_args,
      target="strength within 1e-4 relative of main's, modulus error within 1e-2 points, the "
             "same strain at peak, every row")
def tube_regression(args) -> dict:
    changes = change_vs_main(args.vacancy, args.quick)
    worst = max(abs(r["change_pct"]) for r in changes)
    worst_mod = max(abs(r["modulus_err_pct"] - r["main_modulus_err_pct"]) for r in changes)
    same_peak = all(r["strain_at_peak"] == r["main_strain_at_peak"] for r in changes)
    return {"rows": changes, "max_change_vs_main_pct": worst,
            "modulus_err_change_points_max": worst_mod, "strain_at_peak_same": same_peak,
            "pass": bool(worst <= 100 * TOL["strength_GPa"] and same_peak and worst_mod <= 1e-2)}
