"""Quasi-static torsion of a finite tube in LAMMPS, held by rigid end grips.

Set-up
    The zero-stress relaxation of the periodic tube
    (:func:`upscale.experiments.lammps.setup.relax_zero_stress`), then, as the dynamic
    tension does, the axial periodicity is removed (the tube is cut at the cell boundary,
    boundary ``s s s``) and the open tube is minimised with all atoms free
    (:func:`upscale.experiments.lammps.setup.minimize_robust`). The grips are the atoms
    within ``grip`` Å of each end (``z <= z_min + grip``, ``z >= z_max - grip``); they are
    held rigidly (``fix setforce 0 0 0``) in every later minimisation. The axis is the mean
    (x, y) of the open tube's atoms; the gauge is the distance between the grip planes.

Step k (twist phi_k = k * step, degrees)
    The top grip is rotated rigidly about the axis by the increment phi_k - phi_{k-1}, the
    bottom grip stays, and every free atom is first rotated by the affine fraction
    ``(z0 - z_bottom_plane) / gauge`` of the increment (z0: its height at the start of the
    twist); then the free atoms are minimised (the same robust minimiser as the
    quasi-static tension).

Torque
    After each minimisation the grips' ``setforce`` is lifted for one force evaluation
    (``unfix``, ``run 0``, the per-atom forces gathered, the fix restored): with F_i the
    force on atom i and (x_i, y_i) relative to the axis, M = sum over a grip's atoms of
    ``x_i F_iy - y_i F_ix`` is the z-moment the tube exerts on that grip. The response is
    the torque the top grip applies to the tube, ``T = -M_top`` (eV; positive for a positive
    twist, as a tensile stress is positive); ``-M_bottom`` is the bottom grip's and equals T
    at equilibrium (kept as ``torque_bottom_eV``). Failure: the first record whose |T| falls
    more than ``failure_drop`` below the running maximum; the run stops ``after_failure``
    records later or at ``max_twist``.

Figures: ``torsional_stiffness_eV_per_rad`` (least-squares slope, with intercept, of T
against the twist in radians over ``|phi| <= fit_max_twist``), the thin-wall shear modulus
``shear_modulus_TPa`` = stiffness * gauge / (2 pi R^3 t) (R the relaxed mean radius, t
3.4 Å), ``peak_torque_eV`` and ``twist_at_peak_deg`` (before failure), ``failure_twist_deg``.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
from ase import Atoms

from upscale.analysis.stress import WALL_THICKNESS
from upscale.experiments.lammps.potential import resolve_potential
from upscale.experiments.protocols import StopRule
from upscale.experiments.lammps.quasistatic import (check_damped_settings, check_stop,
                                                    minimizer_description)
from upscale.experiments.lammps.setup import (DAMPED_STYLE, check_atoms, common_record,
                                              gather_positions, minimize_robust, new_instance,
                                              relax_zero_stress, thermo)

__all__ = ["quasi_static_torsion", "EV_PER_A3_IN_GPA"]

EV_PER_A3_IN_GPA = 160.21766208


def _gather_forces(lmp, n) -> np.ndarray:
    f = lmp.gather_atoms("f", 1, 3)
    return np.ctypeslib.as_array(f).reshape(n, 3).copy()


def _scatter_positions(lmp, x) -> None:
    lmp.scatter_atoms("x", 1, 3, np.ctypeslib.as_ctypes(np.ascontiguousarray(x).ravel()))


def quasi_static_torsion(atoms: Atoms, potential="tersoff:BNC.tersoff", *, cutoff="step",
                         grip: float = 10.0, twist_step: float = 1.0,
                         max_twist: float = 90.0, ftol: float = 1e-8,
                         fmax_tol: float = 1e-4, relax_ftol: float = 1e-6,
                         fit_max_twist: float | None = None,
                         dump: str | Path | None = None, after_failure: int = 1,
                         failure_drop: float = 0.05, progress=None, nprocs: int = 1,
                         damped_style: str = DAMPED_STYLE, damped_dmax: float = 0.02,
                         damped_timestep_ps: float = 0.001, damped_steps: int = 5000,
                         damped_cycles: int = 3, line_search: str = "quadratic",
                         perturbation=None) -> dict:
    """Quasi-static torsion of the open tube between rigid grips (module docstring).

    Parameters
    ----------
    atoms : ase.Atoms
        A periodic tube (from :func:`upscale.build.swcnt`); it is relaxed periodic, then cut
        open.
    grip : float
        Axial length of each grip, Å (``2 grip`` must leave a free part >= 10 Å).
    twist_step, max_twist : float
        Twist increment (its sign the sense: positive counter-clockwise about +z seen from
        the top) and largest twist magnitude of the top grip against the bottom one,
        degrees.
    perturbation : callable, optional
        ``perturbation(k, free) -> (N, 3)`` Å added to the positions before the
        minimisation of step k (``free`` (N,) bool: the atoms outside the grips), e.g.
        :meth:`upscale.experiments.protocols.QuasiStatic.perturbation`: the same seeded
        imperfection as the engine's run.
    fit_max_twist : float, optional
        Twist (degrees) up to which the torsional stiffness is fitted; default
        ``max(2 twist_step, min(5, max_twist))`` (at least three records).
    ftol, fmax_tol, damped_*, line_search
        The robust minimiser, as in
        :func:`upscale.experiments.lammps.quasistatic.quasi_static_tension` (also for the
        open tube's set-up minimisation).
    relax_ftol : float
        Force tolerance of the periodic zero-stress relaxation, eV/Å.
    after_failure, failure_drop : int, float
        The stop rule (module docstring).
    dump : path, optional
        LAMMPS dump (``id type x y z``), one frame per twist (the first at zero twist).
    progress : callable, optional
        ``progress(twist_deg, torque_eV)`` after each step.

    Returns
    -------
    dict
        Result record (``kind`` ``"lammps-torsion"``); ``curve`` holds ``twist_deg``,
        ``torque_eV``, ``torque_bottom_eV``, ``energy_eV``, ``fmax_eV_per_A``,
        ``damped_md_cycles``.
    """
    check_atoms(atoms)
    for name, v in (("grip", grip), ("max_twist", max_twist)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                or v <= 0:
            raise ValueError(f"{name}={v!r}; valid: a finite number > 0")
    if isinstance(twist_step, bool) or not isinstance(twist_step, (int, float)) \
            or not 0 < abs(twist_step) < max_twist:
        raise ValueError(f"twist_step={twist_step!r}, max_twist={max_twist!r}; valid: "
                         "0 < |twist_step| < max_twist")
    check_damped_settings(fmax_tol, damped_style, damped_dmax, damped_timestep_ps,
                          damped_steps, damped_cycles, line_search)
    check_stop(after_failure, failure_drop)
    if fit_max_twist is None:
        fit_max_twist = max(2.0 * abs(twist_step), min(5.0, max_twist))
    if nprocs != 1:
        from upscale.experiments.lammps.mpi import run_mpi  # noqa: PLC0415

        return run_mpi("quasi_static_torsion", atoms, nprocs, potential=potential,
                       cutoff=cutoff, grip=grip, twist_step=twist_step, max_twist=max_twist,
                       ftol=ftol, fmax_tol=fmax_tol, relax_ftol=relax_ftol,
                       fit_max_twist=fit_max_twist, dump=dump, after_failure=after_failure,
                       failure_drop=failure_drop, damped_style=damped_style,
                       damped_dmax=damped_dmax, damped_timestep_ps=damped_timestep_ps,
                       damped_steps=damped_steps, damped_cycles=damped_cycles,
                       line_search=line_search)
    mkw = dict(cycles=int(damped_cycles), md_steps=int(damped_steps), md_limit=damped_dmax,
               md_timestep=damped_timestep_ps, damped_style=damped_style,
               line_search=line_search)
    t0 = time.perf_counter()
    pot = resolve_potential(potential, cutoff)
    relaxed, rinfo = relax_zero_stress(atoms, potential, cutoff, relax_ftol, _pot=pot)
    L0, R = float(rinfo["L0_A"]), float(rinfo["radius_relaxed_A"])
    if L0 - 2.0 * grip < 10.0:
        raise ValueError(f"grip={grip} Å leaves a free length {L0 - 2 * grip:.2f} Å of a "
                         f"{L0:.2f} Å tube; valid: 2 grip <= L0 - 10 Å (use a longer tube)")
    n = len(relaxed)
    x = relaxed.get_positions()
    x[:, 2] = np.mod(x[:, 2], L0)
    x[x[:, 2] >= L0, 2] -= L0
    relaxed.set_positions(x)
    lmp, types = new_instance(relaxed, pot, "s s s", box=relaxed.cell.lengths().copy())
    if dump is not None:
        dump = Path(dump)
        dump.parent.mkdir(parents=True, exist_ok=True)
        if dump.exists():
            dump.unlink()
    twists, torques, torques_bot, energies, fmaxes, fires = [], [], [], [], [], []
    try:
        open_min = minimize_robust(lmp, ftol, fmax_tol, **mkw)  # the open tube, all free
        x0 = gather_positions(lmp, n)
        zb = float(x0[:, 2].min()) + float(grip)
        zt = float(x0[:, 2].max()) - float(grip)
        gauge = zt - zb
        axis = x0[:, :2].mean(axis=0)
        bot, top = x0[:, 2] <= zb, x0[:, 2] >= zt
        frac = np.clip((x0[:, 2] - zb) / gauge, 0.0, 1.0)
        frac[bot], frac[top] = 0.0, 1.0
        lmp.commands_list([
            f"region rbot block INF INF INF INF INF {zb!r} units box",
            f"region rtop block INF INF INF INF {zt!r} INF units box",
            "group bot region rbot", "group top region rtop", "group grips union bot top",
            "variable nbot equal count(bot)", "variable ntop equal count(top)"])
        counts = (int(round(lmp.extract_variable("nbot"))),
                  int(round(lmp.extract_variable("ntop"))))
        if counts != (int(bot.sum()), int(top.sum())):
            raise RuntimeError(f"grips: LAMMPS's regions hold {counts} atoms, the Python "
                               f"masks {(int(bot.sum()), int(top.sum()))}")
        hold = "fix hold grips setforce 0.0 0.0 0.0"
        lmp.command(hold)
        k, phi_prev, failed_at, aborted = 0, 0.0, None, None
        rule = StopRule(drop=failure_drop, after=after_failure)  # the protocols' one rule
        while k * abs(twist_step) <= max_twist + 1e-12:
            phi = k * twist_step
            dphi = math.radians(phi - phi_prev)
            dx_k = None if perturbation is None else perturbation(k, ~(bot | top))
            if dphi or (dx_k is not None and dx_k.any()):
                x = gather_positions(lmp, n)
                a = dphi * frac
                c, s = np.cos(a), np.sin(a)
                dx, dy = x[:, 0] - axis[0], x[:, 1] - axis[1]
                x[:, 0] = axis[0] + c * dx - s * dy
                x[:, 1] = axis[1] + s * dx + c * dy
                if dx_k is not None:
                    x += dx_k
                _scatter_positions(lmp, x)
            try:
                mres = minimize_robust(lmp, ftol, fmax_tol, **mkw)
            except Exception as exc:  # LAMMPS error inside a failing step
                if failed_at is None and not torques:
                    raise
                aborted = {"twist_deg": phi, "error": str(exc).splitlines()[0]}
                break
            # the grips' moments: one force evaluation without the setforce
            lmp.commands_list(["unfix hold", "run 0 post no"])
            f = _gather_forces(lmp, n)
            x = gather_positions(lmp, n)
            energy = float(thermo(lmp)["PotEng"])
            lmp.command(hold)
            rx, ry = x[:, 0] - axis[0], x[:, 1] - axis[1]
            mz = rx * f[:, 1] - ry * f[:, 0]
            T, Tb = -float(mz[top].sum()), float(mz[bot].sum())
            twists.append(phi)
            torques.append(T)
            torques_bot.append(Tb)
            energies.append(energy)
            fmaxes.append(mres["fmax_eV_per_A"])
            fires.append(mres["damped_md_cycles"])
            if dump is not None:
                lmp.command(f"write_dump all custom {dump} id type x y z "
                            "modify sort id append yes")
            if progress is not None:
                progress(phi, T)
            failed_at = rule.failed_at(torques)
            if rule.done(torques):
                break
            phi_prev = phi
            k += 1
    finally:
        lmp.close()
    res = common_record(atoms, pot, "quasi-static", rinfo, types)
    res["kind"] = "lammps-torsion"
    res["protocol_detail"] = {
        "boundary": "s s s (open tube, cut at the periodic boundary after relaxation)",
        "relaxation": "fix box/relax z 0.0 vmax 0.001 + minimize (cg) x2, then fixed-box "
                      f"minimize, ftol {relax_ftol} eV/A; then the open tube minimised",
        "load": "torsion", "grip_A": grip, "gauge_length_A": gauge,
        "axis_xy_A": [float(axis[0]), float(axis[1])],
        "twist_step_deg": twist_step, "max_twist_deg": max_twist,
        "twist": "top grip rotated rigidly about the axis, bottom grip fixed; free atoms "
                 "first rotated by the affine fraction (z0 - z_bottom_plane) / gauge of the "
                 "increment, then minimised with the grips held (fix setforce 0 0 0)",
        "torque": "T = -sum over the top grip of (x F_y - y F_x) about the axis (the torque "
                  "the top grip applies to the tube), forces from one evaluation without "
                  "the setforce",
        "minimize": minimizer_description(ftol, fmax_tol, damped_style, damped_dmax,
                                          damped_timestep_ps, damped_steps, damped_cycles,
                                          line_search),
        "fmax_tol_eV_per_A": fmax_tol, "damped_style": damped_style,
        "damped_dmax_A": damped_dmax, "damped_timestep_ps": damped_timestep_ps,
        "damped_steps": damped_steps, "damped_cycles": damped_cycles,
        "line_search": line_search, "after_failure_steps": after_failure,
        "failure": f"first |torque| more than {100 * failure_drop:g}% below the running "
                   "maximum of |torque|",
        "open_tube_fmax_eV_per_A": open_min["fmax_eV_per_A"]}
    res["curve"] = {"twist_deg": twists, "torque_eV": torques, "torque_bottom_eV": torques_bot,
                    "energy_eV": energies, "fmax_eV_per_A": fmaxes, "damped_md_cycles": fires}
    res["max_residual_force_eV_per_A"] = max(fmaxes)
    res["aborted"] = aborted
    res.update(_torsion_metrics(twists, torques, failed_at, fit_max_twist, gauge, R))
    if aborted is not None and not res["failed"]:
        res.update(failed=True, failure_twist_deg=aborted["twist_deg"],
                   failure_note="LAMMPS stopped with an error inside this twist step")
    res["dump"] = str(dump) if dump is not None else None
    res["wall_s"] = time.perf_counter() - t0
    return res


def _torsion_metrics(twists, torques, failed_at, fit_max_twist, gauge, R) -> dict:
    phi = np.asarray(twists, dtype=float)
    T = np.asarray(torques, dtype=float)
    upto = failed_at if failed_at is not None else len(T)
    ipeak = int(np.argmax(np.abs(T[:upto]))) if upto else 0
    sel = np.abs(phi) <= fit_max_twist + 1e-12
    if sel.sum() >= 2:
        k = float(np.polyfit(np.radians(phi[sel]), T[sel], 1)[0])  # eV / rad
    else:
        k = math.nan
    J = 2.0 * math.pi * R ** 3 * WALL_THICKNESS  # thin-wall polar moment, Å^4
    return {"torsional_stiffness_eV_per_rad": k, "torsion_fit_max_twist_deg": fit_max_twist,
            "shear_modulus_TPa": k * gauge / J * EV_PER_A3_IN_GPA / 1000.0,
            "peak_torque_eV": float(T[ipeak]) if len(T) else math.nan,
            "twist_at_peak_deg": float(phi[ipeak]) if len(phi) else math.nan,
            "failure_twist_deg": float(phi[failed_at]) if failed_at is not None else None,
            "failed": failed_at is not None,
            "failure_criterion": "first |torque| drop below the running maximum (see "
                                 "protocol_detail.failure)"}
