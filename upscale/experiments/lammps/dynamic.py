"""Dynamic tension of an open tube or bundle in LAMMPS, its set-up, and the static
stiffness of its grips.

Dynamic tension (non-periodic tube or bundle, seed 004 sec. 5.3.1, :func:`dynamic_tension`)
    After the periodic zero-stress relaxation
    (:func:`upscale.experiments.lammps.setup.relax_zero_stress`) the axial periodicity is
    removed (the tube is cut at the cell boundary) and the open tube is minimised once. End
    grips of ``grip`` Å (default 50 Å) move rigidly apart at ``speed`` Å/ps each (default
    1 Å/ps, i.e. 2 Å/ps relative), their atoms integrated with ``fix nve`` under ``fix
    setforce 0 0 0``. The free part starts with a linear axial velocity ramp between the grip
    speeds (no start-up shock) and random thermal velocities at ``temperature`` (default
    10 K), and runs under a Nose-Hoover thermostat (``fix nvt``, damping 0.1 ps) whose
    temperature is measured from the x and y velocity components only (``compute
    temp/partial 1 1 0``), so the axial stretching flow is neither counted as heat nor
    damped. Time step 1 fs. Strain is the grip separation change over the initial free
    length ``L0 - 2 grip``; stress is the mean of the reaction forces on the two grips (the
    total force on each before ``setforce`` zeroes it, averaged over the last 100 steps of
    each 100-step sample) over ``ntubes 2 pi R t``. The extensometer strain
    (:class:`upscale.analysis.stress.Extensometer`, the coarse runner's definition) is the
    least-squares slope of the axial displacement against the axial position at the start
    of the pull (after the open-tube minimisation) over the atoms between two marks a
    quarter of the gauge inside each grip plane, evaluated inside LAMMPS (``fix
    store/state`` keeps z0, an atom-style variable and ``compute reduce`` give the slope)
    and averaged by the same ``fix ave/time`` as the stress, so each sample's strain on the
    marks belongs to the same instants as its stress; it is free of the grips' compliance
    (cost: within the timing noise, 4.38/4.40 s against 4.34/4.42 s without for the
    (10,10) vacancy reference's 2900 steps).
    The run stops when the stress has fallen below 20 % (``stop_below``) of its maximum
    after failure (the first sample 5 % (``failure_drop``) below the running maximum), or
    at ``max_strain``, or (a ``fix halt`` checked every 10 steps) when the shrink-wrapped
    box exceeds ``max_box_volume`` (1e8 Å^3): with the step cutoff an atom can be kicked
    off at tens of Å/fs after fracture and LAMMPS's neighbour bins grow with the box (a
    60 Å (50,50) test tube reached 7 GB and minutes per 100 steps); ``aborted`` records
    where.

Set-up minimiser (:class:`upscale.experiments.lammps.setup.MinSettings`, the ``min_*``
keywords of :func:`dynamic_tension`, :func:`open_tube_setup` for the set-up alone): every
set-up minimisation is recorded in ``res["setup_minimisation"]``.

The result dict holds the curve, Young's modulus (fit over 0-2 % strain), strength, strain
at peak, failure strain, ``youngs_modulus_ext_TPa`` and ``strain_at_peak_ext`` on the
extensometer, LAMMPS version, potential file and checksum, protocol, date and wall time; a
LAMMPS dump (``id type x y z``) goes to ``dump`` when given.

Static grip stiffness (:func:`static_grip_stiffness`): the same set-up, the grips moved
apart once by a small strain and the free atoms minimised with the grips held.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
from ase import Atoms

from upscale.analysis.stress import (WALL_THICKNESS, Extensometer, curve_metrics,
                                     extensometer_metrics, stress_from_force)
from upscale.experiments.lammps.potential import resolve_potential
from upscale.experiments.lammps.setup import (MinSettings, check_atoms, common_record,
                                              extensometer_commands, gather_positions,
                                              mean_radius, minimize, minimize_logged,
                                              new_instance, per_tube_grip_commands,
                                              prescale, relax_zero_stress, thermo)

__all__ = ["open_tube_setup", "dynamic_tension", "static_grip_stiffness"]


def open_tube_setup(atoms: Atoms, potential="tersoff:BNC.tersoff", *, cutoff="step",
                    ftol: float = 1e-6, minimiser: MinSettings | None = None,
                    periodic_relaxation: bool = True, relaxed: Atoms | None = None) -> dict:
    """The set-up of :func:`dynamic_tension` alone: the periodic zero-stress relaxation
    (unless ``periodic_relaxation`` is False, see :func:`dynamic_tension`), the tube cut at
    the cell boundary and minimised open, all with ``minimiser`` (default
    :class:`MinSettings`: the references' CG) to ``ftol`` eV/Å in its norm. ``relaxed``:
    an already relaxed periodic structure (from :func:`relax_zero_stress`); only the open
    tube is then minimised.

    Returns a dict: ``stages`` (one record per minimize, :func:`minimize_logged`: wall
    time, iterations, force evaluations, stopping criterion, energy, largest force
    component), ``wall_s`` (the whole set-up, with the prescaling and LAMMPS's set-up),
    ``iterations``, ``force_evaluations`` (sums), the open tube's ``energy_eV``,
    ``fmax_eV_per_A`` (largest force component) and ``fnorm_eV_per_A``, ``L0_A``,
    ``relaxed`` (the periodic structure the tube was cut from) and ``positions`` ((N, 3),
    Å, ASE order, the minimised open tube)."""
    check_atoms(atoms)
    settings = minimiser or MinSettings()
    t0 = time.perf_counter()
    pot = resolve_potential(potential, cutoff)
    stats: list = []
    if relaxed is not None:
        relaxed = relaxed.copy()
    elif periodic_relaxation:
        relaxed, _ = relax_zero_stress(atoms, potential, cutoff, ftol, _pot=pot,
                                       minimiser=settings, stats=stats)
    else:
        relaxed = prescale(atoms, pot, ftol)
    periodic = relaxed.copy()
    L0 = float(relaxed.cell[2, 2])
    n = len(relaxed)
    x = relaxed.get_positions()
    x[:, 2] = np.mod(x[:, 2], L0)
    x[x[:, 2] >= L0, 2] -= L0
    relaxed.set_positions(x)
    lmp, _ = new_instance(relaxed, pot, "s s s", box=relaxed.cell.lengths().copy())
    try:
        minimize_logged(lmp, ftol, settings, "open_tube", stats)
        x = gather_positions(lmp, n)
    finally:
        lmp.close()
    last = stats[-1]
    return {"settings": settings.describe(), "ftol_eV_per_A": ftol,
            "periodic_relaxation": bool(periodic_relaxation), "stages": stats,
            "wall_s": time.perf_counter() - t0,
            "iterations": sum(st["iterations"] or 0 for st in stats),
            "force_evaluations": sum(st["force_evaluations"] or 0 for st in stats),
            "energy_eV": last["energy_eV"], "fmax_eV_per_A": last["fmax_eV_per_A"],
            "fnorm_eV_per_A": last["fnorm_eV_per_A"], "L0_A": L0, "relaxed": periodic,
            "positions": x}


def dynamic_tension(atoms: Atoms, potential="tersoff:BNC.tersoff", *, cutoff="step",
                    grip: float = 50.0, speed: float = 1.0, temperature: float = 10.0,
                    timestep: float = 0.001, tdamp: float = 0.1, max_strain: float = 0.40,
                    sample_every: int = 100, dump_every: int = 200,
                    fit_max_strain: float = 0.02, dump: str | Path | None = None,
                    seed: int = 4928459, ftol: float = 1e-6, progress=None,
                    max_steps: int = 200000, max_box_volume: float = 1e8,
                    nprocs: int = 1, min_style: str = "cg", min_line: str = "quadratic",
                    min_norm: str = "two", min_timestep_ps: float | None = None,
                    min_dmax: float | None = None, min_fire: tuple = (),
                    min_maxiter: int = 20000, periodic_relaxation: bool = True,
                    pull_rounds: int = 1, between_rounds=None, failure_drop: float = 0.05,
                    stop_below: float | None = 0.2) -> dict:
    """Dynamic tension with end grips pulled apart at constant speed (module docstring).

    Parameters
    ----------
    failure_drop, stop_below : float
        Failure is the first sample more than ``failure_drop`` below the running maximum
        of the stress; the run stops once the stress is below ``stop_below`` times that
        maximum after failure (None: only at ``max_strain``).
    ftol : float
        Force tolerance of the set-up minimisations, eV/Å, in the norm ``min_norm``.
    min_style, min_line, min_norm, min_timestep_ps, min_dmax, min_fire, min_maxiter
        The set-up minimiser (:class:`MinSettings`: style, line search, the norm ``ftol``
        bounds, damped-dynamics time step, largest move per iteration, FIRE keywords,
        iterations per minimize); the defaults are the stored references' (CG, quadratic
        line search, 2-norm of the global force vector).
    periodic_relaxation : bool
        True (default): the periodic zero-stress relaxation (:func:`relax_zero_stress`)
        before the tube is cut open. False: the open tube is minimised straight from the
        prescaled structure (:func:`prescale`: a short periodic tube's relaxed axial and
        radial ratios; L0 is then the prescaled cell length and R the mean atom radius of the
        minimised open tube), as the coarse model starts from its zero-stress lattice.
    grip : float
        Axial length of each end grip, Å (``2 grip`` must leave a free part >= 10 Å).
    speed : float
        Speed of each grip, Å/ps (they separate at ``2 speed``).
    temperature : float
        Thermostat temperature of the free part, K.
    timestep, tdamp : float
        Time step and Nose–Hoover damping time, ps.
    sample_every, dump_every : int
        Steps between stress samples (each the average over its interval, sampled every 10
        steps) and between dump frames.
    max_box_volume : float
        Å^3. With the step cutoff an atom can be kicked off at tens of Å/fs after fracture;
        the shrink-wrapped box follows it and LAMMPS's neighbour bins grow with the box
        volume (gigabytes, minutes per step). A ``fix halt`` (checked every 10 steps) stops
        the run once the box volume exceeds this; ``res["aborted"]`` then records the step
        and strain (the curve ends at the last full sample).
    pull_rounds : int
        How many times the pull is run from the same set-up state, for timing (benchmarks
        race it against another code in alternating rounds): every round after the first
        starts a new LAMMPS instance on the opened, minimised tube's positions (no
        minimisation, no dump) and runs the same pull. The result is the first round's;
        ``res["pull_rounds"]`` lists each round's dynamics wall time, steps, strength and
        strain at peak (later rounds agree with the first up to the round-off of the new
        instance, amplified by the dynamics after fracture).
    between_rounds : callable or None
        Called with the round's index after each pull round but the last (the other code's
        round of an alternating race).
    """
    check_atoms(atoms)
    if not (isinstance(pull_rounds, (int, np.integer)) and pull_rounds >= 1):
        raise ValueError(f"pull_rounds={pull_rounds!r}; valid: an integer >= 1")
    for name, v in (("grip", grip), ("speed", speed), ("timestep", timestep),
                    ("tdamp", tdamp), ("max_strain", max_strain)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name}={v!r}; valid: a positive number")
    if not temperature >= 0:
        raise ValueError(f"temperature={temperature!r} K; valid: >= 0")
    if sample_every % 10:
        raise ValueError(f"sample_every={sample_every}; valid: a multiple of 10")
    if not (isinstance(failure_drop, (int, float)) and 0 < failure_drop < 1):
        raise ValueError(f"failure_drop={failure_drop!r}; valid: 0 < failure_drop < 1")
    if stop_below is not None and not (isinstance(stop_below, (int, float))
                                       and 0 <= stop_below < 1):
        raise ValueError(f"stop_below={stop_below!r}; valid: None or 0 <= stop_below < 1")
    if nprocs != 1:
        if pull_rounds != 1:
            raise ValueError(f"pull_rounds={pull_rounds} with nprocs={nprocs}; valid: "
                             "pull_rounds=1 when LAMMPS runs on several ranks")
        from upscale.experiments.lammps.mpi import run_mpi  # noqa: PLC0415

        return run_mpi("dynamic_tension", atoms, nprocs, potential=potential, cutoff=cutoff,
                       grip=grip, speed=speed, temperature=temperature, timestep=timestep,
                       tdamp=tdamp, max_strain=max_strain, sample_every=sample_every,
                       dump_every=dump_every, fit_max_strain=fit_max_strain, dump=dump,
                       seed=seed, ftol=ftol, max_steps=max_steps,
                       max_box_volume=max_box_volume, min_style=min_style, min_line=min_line,
                       min_norm=min_norm, min_timestep_ps=min_timestep_ps, min_dmax=min_dmax,
                       min_fire=tuple(min_fire), min_maxiter=min_maxiter,
                       periodic_relaxation=periodic_relaxation,
                       failure_drop=failure_drop, stop_below=stop_below)
    settings = MinSettings(min_style, min_line, min_norm, min_timestep_ps, min_dmax,
                           tuple(min_fire), min_maxiter)
    metric_kw = {"fit_max_strain": fit_max_strain}
    if failure_drop != 0.05:
        metric_kw["drop"] = failure_drop
    t0 = time.perf_counter()
    c0 = time.process_time()  # CPU time of this process (LAMMPS runs in it): load-free
    pot = resolve_potential(potential, cutoff)
    min_stats: list = []
    if periodic_relaxation:
        relaxed, rinfo = relax_zero_stress(atoms, potential, cutoff, ftol, _pot=pot,
                                           minimiser=settings, stats=min_stats)
    else:
        relaxed = prescale(atoms, pot, ftol)
        rinfo = {"L0_A": float(relaxed.cell[2, 2]), "radius_relaxed_A": None,
                 "pzz_bar": None, "stress_GPa": None, "energy_eV": None,
                 "note": "no periodic relaxation: prescaled structure; R from the open tube"}
    t_periodic = time.perf_counter() - t0
    L0, R = rinfo["L0_A"], rinfo["radius_relaxed_A"]
    free0 = L0 - 2.0 * grip
    if free0 < 10.0:
        raise ValueError(f"grip={grip} Å leaves a free length {free0:.2f} Å of a {L0:.2f} Å "
                         "tube; valid: 2 grip <= L0 - 10 Å (use a longer tube)")
    n = len(relaxed)
    x = relaxed.get_positions()
    x[:, 2] = np.mod(x[:, 2], L0)
    x[x[:, 2] >= L0, 2] -= L0
    relaxed.set_positions(x)
    box = relaxed.cell.lengths().copy()
    lmp, types = new_instance(relaxed, pot, "s s s", box=box)
    ntubes = int(types.max())
    if dump is not None:
        dump = Path(dump)
        dump.parent.mkdir(parents=True, exist_ok=True)
        if dump.exists():
            dump.unlink()
    rounds, first = [], None
    try:
        # open tube: relax the cut ends once (all atoms free), then grips from the new ends
        t1 = time.perf_counter()
        minimize_logged(lmp, ftol, settings, "open_tube", min_stats)
        t_open = time.perf_counter() - t1
        x_open = gather_positions(lmp, n)
        if rinfo["radius_relaxed_A"] is None:
            opened = relaxed.copy()
            opened.set_positions(x_open)
            R = rinfo["radius_relaxed_A"] = mean_radius(opened, types)
        extra_wall = extra_cpu = 0.0  # the rounds after the first, and the turns between
        for rnd in range(pull_rounds):
            if rnd == 1:
                te, ce = time.perf_counter(), time.process_time()
            if rnd:  # a timing round: the same pull on a new instance of the opened tube
                if between_rounds is not None:
                    between_rounds(rnd - 1)
                lmp.close()
                lmp = None
                opened = relaxed.copy()
                opened.set_positions(x_open)
                lmp, _ = new_instance(opened, pot, "s s s", box=box)
            t2 = time.perf_counter()
            strains, stresses, times, exts, per_tube = [], [], [], [], []
            x = x_open.copy()
            zmin, zmax = float(x[:, 2].min()), float(x[:, 2].max())
            zb, zt = zmin + float(grip), zmax - float(grip)
            sep0 = zt - zb
            v = float(speed)
            # the extensometer: z0 of the atoms between the marks kept by fix store/state
            # (stored when defined: now, at the start of the pull); its slope sum
            # c_i (z_i - z0_i) with the coefficients of Extensometer written out as an
            # atom-style variable
            ext = Extensometer(x[:, 2], *Extensometer.window(zb, zt))
            lmp.commands_list([
                f"region rbot block INF INF INF INF INF {zb!r} units box",
                f"region rtop block INF INF INF INF {zt!r} INF units box",
                "group bot region rbot", "group top region rtop",
                "group grips union bot top", "group free subtract all grips",
                *extensometer_commands(ext),
                "reset_timestep 0",
                f"timestep {timestep}",
                "compute tpart free temp/partial 1 1 0",
                f"velocity free create {max(temperature, 1e-6)!r} {seed} dist gaussian mom yes "
                "rot no temp tpart",
                f"velocity free ramp vz {-v!r} {v!r} z {zb!r} {zt!r} sum yes units box",
                f"velocity bot set 0 0 {-v!r} units box",
                f"velocity top set 0 0 {v!r} units box",
                # per-tube grip reactions of a bundle: setforce fixes on each tube's part of the
                # grips, defined before the whole-grip ones (which then see zero force and hold
                # the grips; the total reaction is the sum over the tubes)
                *per_tube_grip_commands(ntubes),
                "fix sfb bot setforce 0.0 0.0 0.0", "fix sft top setforce 0.0 0.0 0.0",
                "fix grips grips nve",
                f"fix nvt free nvt temp {max(temperature, 1e-6)!r} {max(temperature, 1e-6)!r} "
                f"{tdamp!r}",
                "fix_modify nvt temp tpart",
                f"fix avg all ave/time 10 {sample_every // 10} {sample_every} f_sfb[3] f_sft[3] "
                "v_exteps" + "".join(f" f_sfb{k}[3] f_sft{k}[3]" for k in range(1, ntubes + 1)
                                     if ntubes > 1),
                "thermo_style custom step pe ke c_tpart",
                f"thermo {sample_every}",
                "variable boxvol equal lx*ly*lz",
                f"fix runaway all halt 10 v_boxvol > {float(max_box_volume)!r} error continue "
                "message no",
            ])
            if dump is not None and rnd == 0:
                lmp.commands_list([f"dump d all custom {dump_every} {dump} id type x y z",
                                   "dump_modify d sort id"])
            from potentials.lammps_runtime import lammps_module  # noqa: PLC0415

            consts = lammps_module()
            LMP_STYLE_GLOBAL = consts.LMP_STYLE_GLOBAL
            LMP_TYPE_VECTOR = consts.LMP_TYPE_VECTOR
            step = 0
            # setup run (later runs skip setup with "pre no"); also dump frame 0 at zero strain
            lmp.command("run 0 post no")
            n_ext = int(round(lmp.extract_variable("extn")))
            if n_ext != ext.n:  # LAMMPS's region and the Python window must hold the same atoms
                raise RuntimeError(f"extensometer: LAMMPS's window holds {n_ext} atoms, the "
                                   f"Python one {ext.n}")
            smax = -np.inf
            failed = False
            aborted = None
            while True:
                lmp.command(f"run {sample_every} pre no post no")
                if lmp.get_thermo("step") < step + sample_every:  # fix halt: runaway atom
                    aborted = {"step": int(lmp.get_thermo("step")),
                               "strain": float(2.0 * v * lmp.get_thermo("step") * timestep / sep0),
                               "box_volume_A3": float(lmp.get_thermo("vol")),
                               "error": f"box volume > {max_box_volume:g} A^3 (an atom thrown "
                                        "off the tube); run stopped"}
                    break
                step += sample_every
                fb = lmp.extract_fix("avg", LMP_STYLE_GLOBAL, LMP_TYPE_VECTOR, 0)
                ft = lmp.extract_fix("avg", LMP_STYLE_GLOBAL, LMP_TYPE_VECTOR, 1)
                F = 0.5 * (fb - ft)  # tension: bottom grip pulled +z by the tube, top grip -z
                exts.append(float(lmp.extract_fix("avg", LMP_STYLE_GLOBAL, LMP_TYPE_VECTOR, 2)))
                if ntubes > 1:
                    Fk = [0.5 * (lmp.extract_fix("avg", LMP_STYLE_GLOBAL, LMP_TYPE_VECTOR,
                                                 3 + 2 * k)
                                 - lmp.extract_fix("avg", LMP_STYLE_GLOBAL, LMP_TYPE_VECTOR,
                                                   4 + 2 * k)) for k in range(ntubes)]
                    F = float(sum(Fk))
                    per_tube.append([float(stress_from_force(f, R, WALL_THICKNESS, 1)) for f in Fk])
                # the sample averages the interval; assign it to the interval's mid-time
                tmid = (step - 0.5 * sample_every) * timestep
                eps = 2.0 * v * tmid / sep0
                s = float(stress_from_force(F, R, WALL_THICKNESS, ntubes))
                strains.append(eps)
                stresses.append(s)
                times.append(tmid)
                smax = max(smax, s)
                if progress is not None and rnd == 0:
                    progress(eps, s)
                if s < (1.0 - failure_drop) * smax:
                    failed = True
                if (failed and stop_below is not None and s < stop_below * smax) \
                        or eps > max_strain or step >= max_steps:
                    break
            t_dyn = time.perf_counter() - t2
            m = curve_metrics(strains, stresses, **metric_kw)
            rounds.append({"dynamics_s": t_dyn, "steps": step,
                           "strength_GPa": m["strength_GPa"],
                           "strain_at_peak": m["strain_at_peak"]})
            if rnd == 0:
                first = (strains, stresses, times, exts, per_tube, aborted, step, t_dyn)
        if pull_rounds > 1:
            extra_wall, extra_cpu = time.perf_counter() - te, time.process_time() - ce
    finally:
        if lmp is not None:
            lmp.close()
    strains, stresses, times, exts, per_tube, aborted, step, t_dyn = first
    res = common_record(atoms, pot, "dynamic", rinfo, types)
    res["protocol_detail"] = {
        "boundary": "s s s (open tube, cut at the periodic boundary after relaxation)",
        "grip_A": grip, "speed_A_per_ps_each_grip": speed, "timestep_ps": timestep,
        "thermostat": f"Nose-Hoover NVT on the free part, {temperature} K, damping {tdamp} ps, "
                      "temperature from vx, vy only (compute temp/partial 1 1 0); grips: fix "
                      "nve + setforce 0 (rigid, constant velocity)",
        "initial_velocity": "linear axial ramp between the grip speeds + Gaussian thermal "
                            f"velocities (seed {seed})",
        "temperature_K": temperature, "gauge_length_A": sep0,
        "strain": "(grip separation - initial) / initial free length",
        "strain_rate_per_ps": 2 * v / sep0,
        "stress": "mean reaction force of the two grips / (ntubes 2 pi R t), each sample "
                  f"averaged over {sample_every} steps (every 10 steps)",
        "dump_every_steps": dump_every,
        "extensometer": ext.describe()}
    res["protocol_detail"]["max_box_volume_A3"] = max_box_volume
    res["curve"] = {"strain": strains, "stress_GPa": stresses, "time_ps": times,
                    "extensometer_strain": exts}
    if ntubes > 1:
        # (nsamples, ntubes): each tube's grip reaction over its own area 2 pi R t
        res["curve"]["stress_per_tube_GPa"] = per_tube
        res["protocol_detail"]["stress_per_tube"] = (
            "mean reaction of the two grips on each tube's own atoms / (2 pi R t); the bundle "
            "stress is their mean")
    res["aborted"] = aborted
    res.update(curve_metrics(strains, stresses, **metric_kw))
    res.update(extensometer_metrics(strains, exts, stresses, res["strain_at_peak"],
                                    fit_max_strain))
    if aborted is not None and not res["failed"]:
        res.update(failed=True, failure_strain=aborted["strain"],
                   failure_note="run stopped: an atom thrown off the tube (box volume)")
    res["dump"] = str(dump) if dump is not None else None
    # the run's own time: set-up and first pull (the further rounds and the turns between
    # them are ``pull_rounds_extra_wall_s``)
    res["wall_s"] = time.perf_counter() - t0 - extra_wall
    res["cpu_s"] = time.process_time() - c0 - extra_cpu
    res["load_avg_end"] = list(os.getloadavg())
    # where the time went: the periodic zero-stress relaxation (with the set-up), the open
    # tube's minimisation, and the pull (dynamics, sampling and dump)
    res["timing_s"] = {"zero_stress_relaxation": t_periodic, "open_tube_minimisation": t_open,
                       "dynamics": t_dyn, "steps": step}
    res["pull_rounds"] = rounds
    res["pull_rounds_extra_wall_s"] = extra_wall
    res["setup_minimisation"] = {"settings": settings.describe(), "ftol_eV_per_A": ftol,
                                 "periodic_relaxation": bool(periodic_relaxation),
                                 "stages": min_stats}
    return res


def static_grip_stiffness(atoms: Atoms, potential="tersoff:BNC.tersoff", *, cutoff="step",
                          grip: float = 50.0, strain: float = 0.0025, ftol: float = 1e-8,
                          relax_ftol: float = 1e-6) -> dict:
    """Force per grip separation of the open tube held by the dynamic protocol's grips.

    The set-up of :func:`dynamic_tension` (zero-stress periodic relaxation, the tube cut open
    and minimised, grips = the atoms within ``grip`` of the end atoms); then the grips are
    moved apart rigidly by ``strain`` times the gauge (the grip planes' distance) and the
    free atoms are minimised with the grips held (``fix setforce 0 0 0``; CG to ``ftol``).
    The grips' mean reaction F gives k = F / separation (eV/Å^2), a stiffness free of any
    gauge convention; ``modulus_TPa`` = (F / area) / strain with the gauge above.
    """
    check_atoms(atoms)
    if not (0 < strain < 0.05):
        raise ValueError(f"strain={strain!r}; valid: 0 < strain < 0.05 (the linear range)")
    t0 = time.perf_counter()
    pot = resolve_potential(potential, cutoff)
    relaxed, rinfo = relax_zero_stress(atoms, potential, cutoff, relax_ftol, _pot=pot)
    L0, R = rinfo["L0_A"], rinfo["radius_relaxed_A"]
    if L0 - 2.0 * grip < 10.0:
        raise ValueError(f"grip={grip} Å leaves a free length {L0 - 2 * grip:.2f} Å of a "
                         f"{L0:.2f} Å tube; valid: 2 grip <= L0 - 10 Å (use a longer tube)")
    n = len(relaxed)
    x = relaxed.get_positions()
    x[:, 2] = np.mod(x[:, 2], L0)
    relaxed.set_positions(x)
    lmp, types = new_instance(relaxed, pot, "s s s", box=relaxed.cell.lengths().copy())
    try:
        minimize(lmp, ftol)
        x = gather_positions(lmp, n)
        zb, zt = float(x[:, 2].min()) + float(grip), float(x[:, 2].max()) - float(grip)
        sep0 = zt - zb
        u = 0.5 * strain * sep0
        lmp.commands_list([
            f"region rbot block INF INF INF INF INF {zb!r} units box",
            f"region rtop block INF INF INF INF {zt!r} INF units box",
            "group bot region rbot", "group top region rtop",
            "fix sfb bot setforce 0.0 0.0 0.0", "fix sft top setforce 0.0 0.0 0.0",
            f"displace_atoms bot move 0 0 {-u!r} units box",
            f"displace_atoms top move 0 0 {u!r} units box"])
        minimize(lmp, ftol)
        lmp.command("run 0")
        from potentials.lammps_runtime import lammps_module  # noqa: PLC0415

        c = lammps_module()
        fb = lmp.extract_fix("sfb", c.LMP_STYLE_GLOBAL, c.LMP_TYPE_VECTOR, 2)
        ft = lmp.extract_fix("sft", c.LMP_STYLE_GLOBAL, c.LMP_TYPE_VECTOR, 2)
        fmax = float(thermo(lmp)["Fmax"])
    finally:
        lmp.close()
    F = 0.5 * (fb - ft)  # tension: the bottom grip is pulled +z, the top one -z
    res = common_record(atoms, pot, "static-grip", rinfo, types)
    res.update({"k_eV_per_A2": float(F / (2 * u)), "force_eV_per_A": float(F),
                "strain": strain, "grip_A": grip, "gauge_length_A": sep0,
                "modulus_TPa": float(stress_from_force(F, R, WALL_THICKNESS, int(types.max())))
                / strain / 1000.0,
                "max_residual_force_eV_per_A": fmax, "wall_s": time.perf_counter() - t0,
                "protocol_detail": {
                    "set-up": "as dynamic_tension: zero-stress periodic relaxation, cut open "
                              f"at the cell boundary, minimised (ftol {ftol} eV/A)",
                    "grips": f"atoms within {grip} A of the end atoms, moved apart rigidly by "
                             f"strain * gauge, held by fix setforce 0 0 0",
                    "minimize": f"min_style cg, etol 0, ftol {ftol} eV/A",
                    "k": "mean grip reaction / grip separation"}})
    return res
