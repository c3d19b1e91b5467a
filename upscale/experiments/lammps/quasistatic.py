"""Quasi-static axial loading of a periodic tube or bundle in LAMMPS: tension and compression.

After the zero-stress relaxation (:func:`upscale.experiments.lammps.setup.relax_zero_stress`,
relaxed length L0), step k sets the axial strain eps_k = sign k * step (default step 0.5 %;
sign +1 in tension, -1 in compression): the cell is set to ``L0 (1 + eps_k)`` with the atoms
mapped affinely (``change_box ... remap``), then the energy is minimised at fixed cell by
:func:`upscale.experiments.lammps.setup.minimize_robust` (CG, ``etol 0``, ``ftol`` 1e-8 eV/Å
by default; if the largest force component is still above 1e-4 eV/Å, up to 5000 steps of
damped dynamics (``min_style quickmin``, 1 fs, at most 0.02 Å per step), then CG again, up
to 3 times; the residual force of every step is kept in the curve). These are the defaults;
the fallback's style (quickmin or FIRE), ``dmax``, time step, step limit and number of
cycles (0: CG only), the CG line search, ``fmax_tol`` and the strain step are keyword
arguments of :func:`quasi_static_tension`, recorded in ``protocol_detail``.

The stress is ``-p_zz V / (ntubes 2 pi R t L)`` (negative in compression). Failure is the
first step whose stress magnitude falls more than ``failure_drop`` (5 %) below the running
maximum of the magnitudes; the run stops ``after_failure`` steps later (default 1: one step
after the drop) or at ``max_strain``.

Each run returns a result dict with the curve, Young's modulus (fit over 0-2 % strain),
strength, strain at peak, failure strain (all signed: negative in compression), LAMMPS
version, potential file and checksum, protocol, date and wall time; a LAMMPS dump (``id
type x y z``) goes to ``dump`` when given.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
from ase import Atoms

from upscale.analysis.stress import WALL_THICKNESS, curve_metrics, stress_from_pressure
from upscale.experiments.lammps.potential import resolve_potential
from upscale.experiments.protocols import StopRule
from upscale.experiments.lammps.setup import (DAMPED_STYLE, DAMPED_STYLES, LINE_SEARCHES,
                                              check_atoms, common_record, gather_positions,
                                              minimize_robust, relax_zero_stress, thermo)
from upscale.experiments.lammps.restart import RunState, mpi_rank
# the LAMMPS instance factory, under a module-level name so a test can record the commands
from upscale.experiments.lammps.setup import new_instance as _setup

__all__ = ["quasi_static_tension", "quasi_static_compression", "check_damped_settings",
           "AXIAL_LOADS"]

AXIAL_LOADS = ("tension", "compression")


def check_damped_settings(fmax_tol, damped_style, damped_dmax, damped_timestep_ps,
                          damped_steps, damped_cycles, line_search) -> None:
    """One-line ValueErrors for bad settings of
    :func:`upscale.experiments.lammps.setup.minimize_robust` (shared by the quasi-static
    runners)."""
    if damped_style not in DAMPED_STYLES:
        raise ValueError(f"damped_style={damped_style!r}; valid: {', '.join(DAMPED_STYLES)}")
    if line_search not in LINE_SEARCHES:
        raise ValueError(f"line_search={line_search!r}; valid: {', '.join(LINE_SEARCHES)}")
    for name, v, lo in (("damped_dmax", damped_dmax, 0.0),
                        ("damped_timestep_ps", damped_timestep_ps, 0.0),
                        ("fmax_tol", fmax_tol, None)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                or (v <= 0 if lo is not None else v < 0):
            raise ValueError(f"{name}={v!r}; valid: a finite number "
                             + ("> 0" if lo is not None else ">= 0"))
    for name, v, lo in (("damped_cycles", damped_cycles, 0), ("damped_steps", damped_steps, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{name}={v!r}; valid: an integer >= {lo}")


def check_stop(after_failure, failure_drop) -> None:
    """One-line ValueErrors for a bad stop rule (``after_failure``, ``failure_drop``)."""
    if isinstance(after_failure, bool) or not isinstance(after_failure, (int, np.integer)) \
            or after_failure < 0:
        raise ValueError(f"after_failure={after_failure!r}; valid: an integer >= 0")
    if not (isinstance(failure_drop, (int, float)) and 0 < failure_drop < 1):
        raise ValueError(f"failure_drop={failure_drop!r}; valid: 0 < failure_drop < 1")


def minimizer_description(ftol, fmax_tol, damped_style, damped_dmax, damped_timestep_ps,
                          damped_steps, damped_cycles, line_search) -> str:
    """The ``protocol_detail["minimize"]`` text of :func:`minimize_robust`'s settings."""
    return (f"min_style cg (line search {line_search}), etol 0, ftol {ftol} eV/A, "
            "maxiter 20000; "
            + (f"while fmax > {fmax_tol} eV/A: {damped_style} (<= {damped_steps} "
               f"steps of {damped_timestep_ps:g} ps, dmax {damped_dmax:g} A, ftol "
               f"1e-3) then cg, at most {damped_cycles} cycles (the step cutoff "
               "stops CG line searches at the step)" if damped_cycles > 0 else
               "CG only, no damped dynamics (the residual fmax of each step is "
               "kept)"))


def quasi_static_tension(atoms: Atoms, potential="tersoff:BNC.tersoff", *, cutoff="step",
                         strain_step: float = 0.005, max_strain: float = 0.40,
                         ftol: float = 1e-8, fmax_tol: float = 1e-4,
                         relax_ftol: float = 1e-6, fit_max_strain: float = 0.02,
                         dump: str | Path | None = None, after_failure: int = 1,
                         progress=None, nprocs: int = 1, damped_style: str = DAMPED_STYLE,
                         damped_dmax: float = 0.02, damped_timestep_ps: float = 0.001,
                         damped_steps: int = 5000, damped_cycles: int = 3,
                         line_search: str = "quadratic", load: str = "tension",
                         failure_drop: float = 0.05, restart: str | Path | None = None) -> dict:
    """Quasi-static axial tension (or, with ``load="compression"``, compression) of a
    periodic tube or bundle (module docstring).

    Parameters
    ----------
    atoms : ase.Atoms
        Periodic along z, orthorhombic full-rank cell (from :mod:`upscale.build`).
    potential : str
        Spec for :func:`upscale.experiments.lammps.potential.resolve_potential`.
    cutoff : {"step", "standard"}
    strain_step, max_strain : float
        Strain increment and the largest strain magnitude applied (dimensionless; in
        compression the strains are ``-k strain_step``).
    ftol : float
        LAMMPS minimize force tolerance (2-norm of the global force vector), eV/Å.
    fmax_tol : float
        Largest force component, eV/Å, above which a strain step gets damped dynamics and
        CG again (module docstring).
    damped_style : {"quickmin", "fire"}
        LAMMPS ``min_style`` of the damped-dynamics fallback.
    damped_dmax, damped_timestep_ps, damped_steps : float, float, int
        Its largest move of an atom per step (Å, ``min_modify dmax``), time step (ps) and
        step limit.
    damped_cycles : int
        At most this many damped-dynamics + CG cycles per strain step; 0: CG only (the
        residual force of every step is still recorded).
    line_search : {"quadratic", "backtrack", "forcezero"}
        CG line search (``min_modify line``) of the strain steps (the zero-stress relaxation
        always uses the default, quadratic).
    after_failure : int
        Steps run after the failing one (the first more than ``failure_drop`` below the
        running maximum of the stress magnitude).
    load : {"tension", "compression"}
    dump : path, optional
        LAMMPS dump file (``id type x y z``), one frame per strain (the first is eps = 0).
    progress : callable, optional
        Called as ``progress(strain, stress_GPa)`` after each step.
    restart : path, optional
        A folder for restart files (:mod:`upscale.experiments.lammps.restart`): the state is
        saved after the relaxation and after every load step, and a run given the folder of
        a killed run of the same structure and protocol resumes after its last saved step
        (the dump, if any, cut back to that step). The record then also holds ``cost``:
        CPU time summed over ranks and segments, peak memory per rank.

    Returns
    -------
    dict
        Result record; ``curve`` holds ``strain``, ``stress_GPa``, ``energy_eV``, ``Lz_A``,
        ``fmax_eV_per_A``, ``damped_md_cycles``.
    """
    check_atoms(atoms)
    if load not in AXIAL_LOADS:
        raise ValueError(f"load={load!r}; valid: {', '.join(AXIAL_LOADS)}")
    top = 2.0 if load == "tension" else 0.5
    if not (0 < strain_step < max_strain <= top):
        raise ValueError(f"strain_step={strain_step}, max_strain={max_strain}; valid: "
                         f"0 < strain_step < max_strain <= {top:g}")
    check_damped_settings(fmax_tol, damped_style, damped_dmax, damped_timestep_ps,
                          damped_steps, damped_cycles, line_search)
    check_stop(after_failure, failure_drop)
    if nprocs != 1:
        from upscale.experiments.lammps.mpi import run_mpi  # noqa: PLC0415

        return run_mpi("quasi_static_tension", atoms, nprocs, potential=potential,
                       cutoff=cutoff, strain_step=strain_step, max_strain=max_strain,
                       ftol=ftol, fmax_tol=fmax_tol, relax_ftol=relax_ftol,
                       fit_max_strain=fit_max_strain, dump=dump, after_failure=after_failure,
                       damped_style=damped_style, damped_dmax=damped_dmax,
                       damped_timestep_ps=damped_timestep_ps, damped_steps=damped_steps,
                       damped_cycles=damped_cycles, line_search=line_search, load=load,
                       failure_drop=failure_drop,
                       restart=None if restart is None else str(restart),
                       progress=progress)
    sign = 1.0 if load == "tension" else -1.0
    t0 = time.perf_counter()
    pot = resolve_potential(potential, cutoff)
    rs = saved = None
    if restart is not None:
        rs = RunState(restart, _fingerprint(atoms, potential, cutoff, strain_step, load,
                                            ftol, fmax_tol, relax_ftol))
        saved = rs.load()
    if saved is None:
        relaxed, rinfo = relax_zero_stress(atoms, potential, cutoff, relax_ftol, _pot=pot)
        if rs is not None:
            rs.save(relaxed.get_positions(), relaxed.cell[2, 2], -1, {}, rinfo, 0)
    else:  # resume after the last saved load step
        rinfo = saved["relaxation"]
        relaxed = atoms.copy()
        lx, ly, _ = atoms.cell.lengths()
        relaxed.set_cell(np.diag([lx, ly, saved["Lz"]]))
        relaxed.set_positions(saved["positions"])
    L0, R = float(rinfo["L0_A"]), float(rinfo["radius_relaxed_A"])
    lmp, types = _setup(relaxed, pot, "s s p")
    ntubes = int(types.max())
    c0 = saved["curve"] if saved else {}
    strains, stresses, energies, lzs, fmaxes, fires = (
        list(c0.get(name, [])) for name in ("strain", "stress_GPa", "energy_eV", "Lz_A",
                                            "fmax_eV_per_A", "damped_md_cycles"))
    magnitudes = [sign * s for s in stresses]  # the stop rule's response (tension: stress)
    if dump is not None:
        dump = Path(dump)
        dump.parent.mkdir(parents=True, exist_ok=True)
        if saved is not None and dump.exists():
            if mpi_rank() == 0:
                with open(dump, "r+b") as fh:  # frames after the saved step are written again
                    fh.truncate(int(saved["dump_bytes"] or 0))
        elif dump.exists():
            dump.unlink()
    try:
        zlo = float(lmp.extract_box()[0][2])
        k, failed_at, aborted = (saved["k"] + 1 if saved else 0), None, None
        rule = StopRule(drop=failure_drop, after=after_failure)  # the protocols' one rule
        failed_at = rule.failed_at(magnitudes) if magnitudes else None
        while not (magnitudes and rule.done(magnitudes)):  # a resumed finished run: done
            if k * strain_step > max_strain + 1e-12:
                break
            eps = sign * (k * strain_step)
            lmp.command(f"change_box all z final {zlo!r} {zlo + L0 * (1.0 + eps)!r} "
                        "remap units box")
            try:
                mres = minimize_robust(lmp, ftol, fmax_tol, cycles=int(damped_cycles),
                                       md_steps=int(damped_steps), md_limit=damped_dmax,
                                       md_timestep=damped_timestep_ps,
                                       damped_style=damped_style, line_search=line_search)
            except Exception as exc:  # LAMMPS error inside a failing step (e.g. lost atoms)
                if failed_at is None and not stresses:
                    raise
                aborted = {"strain": eps, "error": str(exc).splitlines()[0]}
                break
            fmaxes.append(mres["fmax_eV_per_A"])
            fires.append(mres["damped_md_cycles"])
            th = thermo(lmp)
            s = float(stress_from_pressure(th["Pzz"], th["Volume"], th["Lz"], R,
                                           WALL_THICKNESS, ntubes))
            strains.append(eps)
            stresses.append(s)
            magnitudes.append(sign * s)
            energies.append(th["PotEng"])
            lzs.append(th["Lz"])
            if dump is not None:
                lmp.command(f"write_dump all custom {dump} id type x y z "
                            "modify sort id append yes")
            if progress is not None:
                progress(eps, s)
            if rs is not None:
                rs.save(gather_positions(lmp, len(atoms)), th["Lz"], k,
                        {"strain": strains, "stress_GPa": stresses, "energy_eV": energies,
                         "Lz_A": lzs, "fmax_eV_per_A": fmaxes, "damped_md_cycles": fires},
                        rinfo, dump.stat().st_size if dump is not None and mpi_rank() == 0
                        else None)
            failed_at = rule.failed_at(magnitudes)
            if rule.done(magnitudes):
                break
            k += 1
        cost = None
        if rs is not None:  # every rank's record written before rank 0 reads them
            rs.account()
            gather_positions(lmp, len(atoms))  # collective: a barrier
            cost = rs.cost()
    finally:
        lmp.close()
    res = common_record(atoms, pot, "quasi-static", rinfo, types)
    if cost is not None:
        res["cost"] = cost
    if load != "tension":
        res["kind"] = f"lammps-{load}"
    res["protocol_detail"] = {
        "boundary": "s s p (periodic along the axis z)",
        "relaxation": "fix box/relax z 0.0 vmax 0.001 + minimize (cg) x2, then fixed-box "
                      f"minimize, ftol {relax_ftol} eV/A",
        "strain_step": strain_step, "max_strain": max_strain,
        "minimize": minimizer_description(ftol, fmax_tol, damped_style, damped_dmax,
                                          damped_timestep_ps, damped_steps, damped_cycles,
                                          line_search),
        "fmax_tol_eV_per_A": fmax_tol, "damped_style": damped_style,
        "damped_dmax_A": damped_dmax, "damped_timestep_ps": damped_timestep_ps,
        "damped_steps": damped_steps, "damped_cycles": damped_cycles,
        "line_search": line_search,
        "stress": "-pzz V / (ntubes 2 pi R t Lz)",
        "after_failure_steps": after_failure}
    if load != "tension" or failure_drop != 0.05:
        res["protocol_detail"].update(
            load=load, strain=f"{'-' if sign < 0 else ''}k * strain_step, cell "
                              "L0 (1 + strain), atoms remapped affinely",
            failure=f"first |stress| more than {100 * failure_drop:g}% below the running "
                    "maximum of |stress|")
    res["curve"] = {"strain": strains, "stress_GPa": stresses, "energy_eV": energies,
                    "Lz_A": lzs, "fmax_eV_per_A": fmaxes, "damped_md_cycles": fires}
    res["max_residual_force_eV_per_A"] = max(fmaxes)
    res["aborted"] = aborted  # a LAMMPS error in a step after the peak ends the curve there
    res["zero_strain_stress_GPa"] = stresses[0]
    res.update(_signed_metrics(strains, stresses, sign, fit_max_strain, failure_drop))
    if aborted is not None and not res["failed"]:
        res.update(failed=True, failure_strain=aborted["strain"],
                   failure_note="LAMMPS stopped with an error inside this strain step")
    res["dump"] = str(dump) if dump is not None else None
    res["wall_s"] = time.perf_counter() - t0
    return res


def _fingerprint(atoms, *settings) -> str:
    """A digest of the structure and the settings a restart folder is tied to."""
    import hashlib
    import json

    return hashlib.sha256(json.dumps({
        "positions": np.round(atoms.get_positions(), 6).tolist(), "cell": atoms.cell.tolist(),
        "numbers": atoms.numbers.tolist(), "settings": [str(v) for v in settings]},
        sort_keys=True).encode()).hexdigest()


def _signed_metrics(strains, stresses, sign, fit_max_strain, drop) -> dict:
    """:func:`upscale.analysis.stress.curve_metrics` of the curve in tension; in
    compression of the magnitudes, the strains and stresses reported negative (the modulus
    is the slope, positive either way)."""
    kw = {"fit_max_strain": fit_max_strain}
    if drop != 0.05:
        kw["drop"] = drop
    if sign > 0:
        return curve_metrics(strains, stresses, **kw)
    m = curve_metrics([-e for e in strains], [-s for s in stresses], **kw)
    for key in ("max_stress_overall_GPa", "strain_at_max_stress_overall",
                "max_stress_before_failure_GPa", "strength_GPa", "strain_at_peak",
                "failure_strain"):
        if m.get(key) is not None:
            m[key] = -m[key]
    m["failure_criterion"] = m["failure_criterion"].replace("stress", "|stress|")
    return m


def quasi_static_compression(atoms: Atoms, potential="tersoff:BNC.tersoff", **kw) -> dict:
    """:func:`quasi_static_tension` with ``load="compression"``: the periodic cell shortened
    by ``strain_step`` per step, strains and stresses negative (module docstring)."""
    return quasi_static_tension(atoms, potential, load="compression", **kw)
