"""``experiments.bundle`` (``upscale bundle``): the 7-tube bundle in dynamic tension as a
plain function returning a :class:`~upscale.experiments.result.Result`.

    upscale bundle --chirality 10,10 --coarsening 2 [--compare lammps]

The scene's parts (:class:`~upscale.experiments.scenes.bundle.BundleScene`, its tubes'
models, the van der Waals between them) are in :mod:`upscale.experiments.scenes.bundle`,
its pull (:func:`~upscale.experiments.scenes.bundle_pull.dynamic_tension`) in
:mod:`upscale.experiments.scenes.bundle_pull`. The
defaults are the validated setting (``bundle-tension``, ``bundle-vdw``): r-RESPA 5 x 1 fs
(:data:`~upscale.experiments.scenes.bundle.INTEGRATOR`), reconstructed atoms between coarse
tubes (:data:`~upscale.experiments.scenes.bundle.COARSE_PAIRS`), one Nose-Hoover chain of 3.

``model="lammps"`` is the stored full-atomistic LAMMPS reference of the same bundle
(``data/reference/dyn_<n>-<m>_vac4_bundle7[_s<seed>].json``,
:data:`~upscale.experiments.scenes.tube_tension.REFERENCE_DIR`) as a Result with the same
figure names, so ``upscale bundle --compare lammps`` prints the relative errors.

Figures: the bundle's ``strength_GPa``, ``strain_at_peak``, ``youngs_TPa``,
``failure_strain`` (:func:`upscale.analysis.stress.curve_metrics`); per tube (1 = the
centre) ``tube{k}_strength_GPa`` (its curve's maximum before its own failure, the whole
curve's where it did not fail) and ``tube{k}_failure_strain`` (first sample more than 5 %
below its running maximum; NaN: not failed); ``central_tube_fails_first``; ``atoms`` (of the
bundle represented), ``particles`` (rows of the run), ``dof``, ``wall_s`` (the whole run,
set-up included). Curves: ``curve/strain``, ``curve/stress_GPa``, ``curve/time_ps``,
``curve/tube{k}_stress_GPa``; ``temperature/`` (the engine's per-tube x, y kinetic
temperature of the moving rows, ``tube{k}_shift_K`` of a coarse tube's shifts). Fields:
``x0`` (N, 3), ``damage`` (N,), ``tube`` (N,) per row.
"""
from __future__ import annotations

import json
import math
from typing import Literal

import numpy as np

from upscale.experiments.result import Result, Timer, make_meta
from upscale.experiments.scenes.bundle import (COARSE_PAIRS, INNER, INTEGRATOR, SEED,
                                               BundleScene, parse_specs, reference_name)
from upscale.experiments.scenes.bundle_pull import (check_run_options, dynamic_tension,
                                                    tube_failures)

__all__ = ["bundle", "bundle_result", "lammps_bundle_reference", "reference_result",
           "MODELS"]

#: the models of the scene: the mixed bundle on the engine, or the LAMMPS reference
MODELS = ("coarse", "lammps")

_DROP = 0.05  # a tube's failure: first sample this fraction below its running maximum


def bundle(*, chirality: tuple[int, int] = (10, 10), length: float = 150.0,
           coarsening: float = 2.0, tubes: str | None = None, ntubes: int = 7,
           spacing: Literal["vdw", "seed"] = "vdw", gap: float = 3.4, vacancy: bool = True,
           allow_overlap: bool = False, grip: float = 50.0, speed: float = 1.0,
           temperature: float = 10.0, max_strain: float = 0.40,
           integrator: Literal["verlet", "respa"] = INTEGRATOR, inner: int = INNER,
           thermostat: Literal["bundle", "per-tube"] = "bundle", chain: int = 3,
           settle: float = 0.0, coarse_pairs: Literal["atoms", "sites"] = COARSE_PAIRS,
           vdw_every: int = 1, seed: int = SEED,
           model: Literal["coarse", "lammps"] = "coarse", progress: bool = True) -> Result:
    """A bundle of tubes (atomistic centre, coarse outer tubes) coupled by van der Waals,
    in dynamic tension (module docstring).

    Parameters
    ----------
    chirality : tuple of int
        (n, m) of every tube (also the text "N,M").
    length : float
        length of the built tubes, Å.
    coarsening : float
        coarsening K of the outer tubes (particles K lattice constants apart).
    tubes : str, optional
        MODEL[:K] of each tube, centre first, e.g. tersoff,dcbr:2 (none: tersoff, then dcbr:K).
    ntubes : int
        number of tubes, 2 to 7, when tubes is not given.
    spacing : {"vdw", "seed"}
        walls gap Å apart, or centres 2.2 R apart (the seed's hexagon: overlapping walls).
    gap : float
        wall gap of spacing "vdw", Å.
    vacancy : bool
        the 4-atom vacancy in the central tube (--no-vacancy: a pristine centre).
    allow_overlap : bool
        run tubes closer than the van der Waals wall (the seed's hexagon).
    grip : float
        gripped length at each end of every tube, Å.
    speed : float
        speed of each grip, Å/ps.
    temperature : float
        thermostat temperature of the free part, K.
    max_strain : float
        stop the pull at this strain (the references' 0.40).
    integrator : {"verlet", "respa"}
        r-RESPA (the vdW at an outer step of inner fs) or velocity Verlet at 1 fs.
    inner : int
        1 fs inner steps per outer step with respa: 1, 2, 5 or 10.
    thermostat : {"bundle", "per-tube"}
        one Nose-Hoover on every tube's free part (the references' fix nvt) or one per tube.
    chain : int
        Nose-Hoover chain length (3: LAMMPS's fix nvt; 1: one thermostat variable).
    settle : float
        ps of quench of every tube after the set-up minimisation (0: none).
    coarse_pairs : {"atoms", "sites"}
        two coarse tubes interact through reconstructed atoms or as lumped particle sites.
    vdw_every : int
        vdW forces recomputed every N steps, held in between (velocity Verlet only).
    seed : int
        seed of the thermal velocities (with model lammps: the reference of that seed).
    model : {"coarse", "lammps"}
        the mixed bundle on the engine, or the stored all-atomistic LAMMPS reference.
    progress : bool
        a progress bar of the pull.
    """
    n, m = _chirality(chirality)
    for name, val, unit, ok, valid in (
            ("length", length, " Å", lambda v: v > 0, "a tube length > 0 Å"),
            ("gap", gap, " Å", lambda v: v > 0, "a wall gap > 0 Å"),
            ("grip", grip, " Å", lambda v: v >= 0, "a gripped length >= 0 Å"),
            ("speed", speed, " Å/ps", lambda v: v > 0, "a grip speed > 0 Å/ps"),
            ("temperature", temperature, " K", lambda v: v >= 0, "a temperature >= 0 K"),
            ("max_strain", max_strain, "", lambda v: v > 0, "a strain > 0"),
            ("coarsening", coarsening, "", lambda v: v >= 1, "a coarsening >= 1")):
        if not (_real(val) and ok(val)):
            raise ValueError(f"{name}={val!r}{unit}; valid: {valid}")
    if spacing not in ("vdw", "seed"):
        raise ValueError(f"spacing={spacing!r}; valid: 'vdw' or 'seed'")
    if model not in MODELS:
        raise ValueError(f"model={model!r}; valid: {', '.join(MODELS)}")
    if coarse_pairs not in ("atoms", "sites"):
        raise ValueError(f"coarse_pairs={coarse_pairs!r}; valid: 'atoms' or 'sites'")
    check_run_options(integrator=integrator, inner=inner, thermostat=thermostat, chain=chain,
                      settle_ps=settle, max_strain=max_strain, speed=speed,
                      vdw_every=vdw_every)
    specs = parse_specs(tubes, ntubes, coarsening)
    if not 2 <= len(specs) <= 7:
        what = f"tubes={tubes!r}" if tubes else f"ntubes={ntubes!r}"
        raise ValueError(f"{what}: {len(specs)} tube(s); valid: 2 to 7 tubes (the centre and up "
                         "to six around it: the van der Waals acts between tubes)")
    params = dict(chirality=(n, m), length=float(length), coarsening=float(coarsening),
                  tubes=tubes, ntubes=int(ntubes), spacing=spacing, gap=float(gap),
                  vacancy=bool(vacancy), allow_overlap=bool(allow_overlap), grip=float(grip),
                  speed=float(speed), temperature=float(temperature),
                  max_strain=float(max_strain), integrator=integrator, inner=int(inner),
                  thermostat=thermostat, chain=int(chain), settle=float(settle),
                  coarse_pairs=coarse_pairs, vdw_every=int(vdw_every), seed=int(seed),
                  model=model)
    if model == "lammps":
        with Timer() as timer:
            ref, files = lammps_bundle_reference((n, m), length=length, spacing=spacing,
                                                 gap=gap, vacancy=vacancy, ntubes=len(specs),
                                                 seed=seed, grip=grip, speed=speed,
                                                 temperature=temperature)
        return reference_result(ref, files, params, timer)
    with Timer() as timer:
        scene = BundleScene.create((n, m), length, specs, spacing=spacing, gap=gap,
                                   vacancy_tube=0 if vacancy else None, grip=grip,
                                   allow_overlap=allow_overlap, vdw_every=vdw_every,
                                   coarse_pairs=coarse_pairs)
        run = dynamic_tension(scene, speed=speed, temperature=temperature,
                              max_strain=max_strain, seed=seed, progress=progress,
                              integrator=integrator, inner=inner, thermostat=thermostat,
                              chain=chain, settle_ps=settle)
    return bundle_result(run, scene, params, timer)


# --------------------------------------------------------------------- checks
def _real(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) \
        and math.isfinite(float(v))


def _chirality(value) -> tuple[int, int]:
    """``(n, m)`` from a pair of integers or the text ``"N,M"``; a one-line ValueError
    naming the value otherwise."""
    from upscale.build import chirality as check

    valid = "two integers N,M of a tube, e.g. (10, 10) or '10,10'"
    parts = value.strip("() ").split(",") if isinstance(value, str) else value
    try:
        parts = list(parts)
        nm = [int(p) if isinstance(p, str) else p for p in parts]
        if len(nm) != 2 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                   for v in nm):
            raise ValueError
        n, m = (int(v) for v in nm)
        check(n, m)
    except (TypeError, ValueError):
        raise ValueError(f"chirality={value!r}; valid: {valid}") from None
    return n, m


# --------------------------------------------------------------------- the engine's run
def _tube_figures(strain, per_tube, ntubes) -> dict:
    """Per tube: strength (maximum before its own failure) and failure strain (NaN: not
    failed); NaN where the curves are missing or shorter than three samples."""
    from upscale.analysis.stress import curve_metrics

    figs = {}
    P = None if per_tube is None else np.asarray(per_tube, dtype=float)
    ok = P is not None and P.ndim == 2 and P.shape[1] == ntubes and len(P) >= 3
    e = np.asarray(strain, dtype=float)[: len(P)] if ok else None
    fails = tube_failures(e, P, drop=_DROP) if ok else None
    for k in range(ntubes):
        figs[f"tube{k + 1}_strength_GPa"] = \
            curve_metrics(e, P[:, k], drop=_DROP)["strength_GPa"] if ok else math.nan
    for k in range(ntubes):
        f = fails["tube_failure_strain"][k] if ok else None
        figs[f"tube{k + 1}_failure_strain"] = math.nan if f is None else float(f)
    figs["central_tube_fails_first"] = fails["central_tube_fails_first"] if ok else math.nan
    return figs


def _conventions(radius_A, area: str) -> dict:
    return {"stress_area": area, "radius_A": float(radius_A), "wall_thickness_A": 3.4,
            "strain": "grip separation change / initial gauge (the grip planes' distance), "
                      "at a sample's mid-time",
            "sample": "mean of 10 grip readings over 100 steps of 1 fs",
            "tubes": "1 = the central tube, 2-7 the hexagon's vertices at 0, 60, ... degrees",
            "tube_failure": f"first sample more than {100 * _DROP:g} % below the tube's "
                            "running maximum",
            "tube_strength": "maximum of the tube's curve before its failure (the whole "
                             "curve's where it did not fail)",
            "length_unit": "A", "time_unit": "ps"}


def bundle_result(run: dict, scene: BundleScene, params: dict, timer: Timer) -> Result:
    """The scene's :class:`Result` from :func:`dynamic_tension`'s dict (module docstring)."""
    c = run["curve"]
    ntubes = scene.ntubes
    strain = np.asarray(c["strain"], dtype=float)
    P = np.asarray(c["stress_per_tube_GPa"], dtype=float)
    figs = {"strength_GPa": run["strength_GPa"], "strain_at_peak": run["strain_at_peak"],
            "youngs_TPa": run["youngs_modulus_TPa"],
            "failure_strain": math.nan if run["failure_strain"] is None
            else run["failure_strain"]}
    figs.update(_tube_figures(strain, P, ntubes))
    figs.update(atoms=int(scene.info["n_atoms"]), particles=int(run["particles"]),
                dof=int(run["dof"]), wall_s=float(timer.wall_s))
    curves = {"curve/strain": strain, "curve/stress_GPa": c["stress_GPa"],
              "curve/time_ps": c["time_ps"]}
    for k in range(ntubes):
        curves[f"curve/tube{k + 1}_stress_GPa"] = P[:, k]
    T = np.asarray(c["temperature_per_tube_K"], dtype=float)  # (samples, tubes, [xy, shift])
    curves["temperature/strain"] = strain
    for k in range(ntubes):
        curves[f"temperature/tube{k + 1}_K"] = T[:, k, 0]
        if scene.specs[k].model != "tersoff":
            curves[f"temperature/tube{k + 1}_shift_K"] = T[:, k, 1]
    x0 = np.asarray(run["_start_y"], dtype=float)
    damage, tube = np.zeros(len(x0)), np.zeros(len(x0), dtype=int)
    for k, (d, b) in enumerate(zip(run["damage"], scene.bodies)):
        rows = scene.assembly.rows(b.name)
        damage[rows] = np.asarray(d["mu"], dtype=float)
        tube[rows] = k + 1
    conv = _conventions(run["stress_convention"]["radius_A"],
                        "per tube 2 pi R t, t = 3.4 A, R the mean radius of the central tube "
                        "after the set-up minimisation; the bundle's stress the mean over the "
                        "tubes (= total grip reaction / (ntubes 2 pi R t))")
    conv["fields"] = ("rows of the engine's assembly, tube by tube (field 'tube'); x0 at the "
                      "start of the pull; damage per atom (atomistic tubes: 1 - bonds left / "
                      "bonds at the start) or per particle and free atom (coarse tubes)")
    plot = {"curve": {"x": "strain", "y": ["stress_GPa"]},
            "temperature": {"x": "strain", "y": [f"tube{k + 1}_K" for k in range(ntubes)][:3]}}
    meta = make_meta("bundle", params, timer=timer, seeds=[params["seed"]], conventions=conv,
                     plot=plot, protocol=run["protocol_detail"], bundle=scene.info,
                     failure_order=run["failure_order"], timing_s=run["timing_s"],
                     run_wall_s=run["wall_s"], run_cpu_s=run["cpu_s"],
                     coarse_links_broken={str(k): v for k, v in
                                          run["coarse_links_broken"].items()},
                     damage={f"tube{d['tube']}": {"model": d["model"],
                                                  "damaged_fraction": d["damaged_fraction"],
                                                  "max_mu": d["max_mu"]}
                             for d in run["damage"]})
    return Result(figures=figs, curves=curves,
                  fields={"x0": x0, "damage": damage, "tube": tube}, meta=meta)


# --------------------------------------------------------------------- the LAMMPS reference
def lammps_bundle_reference(chirality, *, length=150.0, spacing="vdw", gap=3.4, vacancy=True,
                            ntubes=7, seed=SEED, grip=50.0, speed=1.0,
                            temperature=10.0) -> tuple[dict, list[str]]:
    """The stored LAMMPS reference of this bundle and seed (``REFERENCE_DIR``, the kept
    run's per-tube curves from its ``_rerun`` file where it has none) and the files read.
    A one-line ValueError when none is stored or its protocol differs."""
    from upscale.experiments.scenes.tube_tension import REFERENCE_DIR

    n, m = chirality
    name = reference_name((n, m), spacing, vacancy, ntubes, None if seed == SEED else seed)
    if abs(gap - 3.4) > 1e-9:
        name += f"_gap{gap:g}"
    path = REFERENCE_DIR / f"{name}.json"
    if not path.is_file():
        raise ValueError(
            f"no stored LAMMPS reference {name}.json in {REFERENCE_DIR}; compute it with "
            f"python -m validation reference-tension --chirality {n},{m} --length {length:g} "
            f"{'--vacancy ' if vacancy else ''}--dynamic --bundle {ntubes}"
            f"{'' if seed == SEED else f' --seed {seed}'} --save-reference")
    ref = json.loads(path.read_text())
    files = [path.name]
    rerun = path.with_name(f"{name}_rerun.json")  # the kept run again, per-tube reactions
    if "stress_per_tube_GPa" not in ref["curve"] and rerun.is_file():
        ref["curve"]["stress_per_tube_GPa"] = json.loads(rerun.read_text())["curve"][
            "stress_per_tube_GPa"]
        files.append(rerun.name)
    proto = ref.get("protocol_detail", {})
    for what, ours, key in (("length", length, None), ("grip", grip, "grip_A"),
                            ("speed", speed, "speed_A_per_ps_each_grip"),
                            ("temperature", temperature, "temperature_K")):
        theirs = ref.get("spec", {}).get("length") if key is None else proto.get(key)
        if theirs is not None and abs(float(theirs) - float(ours)) > 1e-9 * max(1.0, ours):
            raise ValueError(f"{what}={ours:g}: the stored LAMMPS reference {name} has "
                             f"{what} {float(theirs):g}; valid: {float(theirs):g} with "
                             "model='lammps'")
    return ref, files


def reference_result(ref: dict, files: list[str], params: dict, timer: Timer) -> Result:
    """A stored LAMMPS bundle reference as a :class:`Result` with the scene's figure
    names (module docstring); ``x0`` the built bundle (before LAMMPS's relaxation)."""
    from upscale.build import bundle as build_bundle, vacancy as make_vacancy

    c = ref["curve"]
    st = ref["structure"]
    ntubes = int(st.get("ntubes", params["ntubes"]))
    natoms = int(st["n_atoms"])
    strain = np.asarray(c["strain"], dtype=float)
    P = c.get("stress_per_tube_GPa")
    figs = {"strength_GPa": ref["strength_GPa"], "strain_at_peak": ref["strain_at_peak"],
            "youngs_TPa": ref["youngs_modulus_TPa"],
            "failure_strain": math.nan if ref.get("failure_strain") is None
            else ref["failure_strain"]}
    figs.update(_tube_figures(strain, P, ntubes))
    figs.update(atoms=natoms, particles=natoms, dof=3 * natoms,
                wall_s=float(ref.get("wall_s", math.nan)))
    curves = {"curve/strain": strain, "curve/stress_GPa": c["stress_GPa"],
              "curve/time_ps": c["time_ps"]}
    if P is not None:
        P = np.asarray(P, dtype=float)
        for k in range(P.shape[1]):
            curves[f"curve/tube{k + 1}_stress_GPa"] = P[:, k]
    n, m = params["chirality"]
    atoms = build_bundle(n, m, params["length"], ntubes=ntubes, spacing=params["spacing"],
                         gap=params["gap"])
    if params["vacancy"]:
        atoms = make_vacancy(atoms, n=4)
    fields = {}
    if len(atoms) == natoms:
        fields = {"x0": atoms.get_positions(), "tube": np.asarray(atoms.arrays["mol-id"])}
    conv = _conventions(ref["stress_convention"]["radius_A"],
                        f"{ref['stress_convention']['area']}, t = 3.4 A (the references')")
    conv["fields"] = ("the built bundle's atoms (before LAMMPS's relaxation), tube by tube; "
                      "no per-atom damage is stored")
    meta = make_meta("bundle", params, timer=timer, seeds=[params["seed"]], conventions=conv,
                     plot={"curve": {"x": "strain", "y": ["stress_GPa"]}},
                     protocol=ref.get("protocol_detail"), source=files,
                     lammps=ref.get("lammps_version"), aborted=ref.get("aborted"),
                     reference_script=ref.get("script"))
    return Result(figures=figs, curves=curves, fields=fields, meta=meta)
