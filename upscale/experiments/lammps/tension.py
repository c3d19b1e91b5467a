"""LAMMPS tension tests of tubes and bundles (quasi-static and dynamic), through its Python module.

Protocols (units ``metal``: Å, eV, ps, bar; stress in GPa with the wall-thickness convention
of :mod:`upscale.analysis.stress`):

Zero-stress relaxation (every test starts from it)
    The periodic structure (cell along z, vacuum around) is minimised with
    ``fix box/relax z 0.0`` (conjugate gradients, atoms and the axial cell length), twice (the
    box/relax reference changes), then once more at fixed box. The relaxed axial length is
    L0 and all strains are measured from it. R for the area is the mean distance of the atoms
    of tube 1 from its axis after this relaxation.

Quasi-static tension (periodic tube or bundle)
    Axial strain eps_k = k * step (default 0.5%): the cell is set to ``L0 (1 + eps_k)`` with
    the atoms mapped affinely (``change_box ... remap``), then the energy is minimised at fixed
    cell (CG, ``etol 0``, ``ftol`` 1e-8 eV/Å by default; if the largest force component is
    still above 1e-4 eV/Å, up to 5000 steps of damped dynamics (``min_style quickmin``, 1 fs, at most
    0.02 Å per step), then CG again, up to 3 times: the step cutoff makes the energy jump by ~2.4 eV when a C–C bond crosses 2.1 Å,
    which stops CG line searches with a bond held at the step; the residual force of every
    step is kept in the curve). These are the defaults; the fallback's style (quickmin or
    FIRE), ``dmax``, time step, step limit and number of cycles (0: CG only), the CG line
    search, ``fmax_tol`` and the strain step are keyword arguments of
    :func:`quasi_static_tension`, recorded in ``protocol_detail``. The stress is
    ``-p_zz V / (ntubes 2 pi R t L)``. The run stops two steps after failure (first drop of
    more than 5 % below the running maximum) or at ``max_strain``.

Dynamic tension (non-periodic tube or bundle, seed 004 sec. 5.3.1)
    After the periodic relaxation the axial periodicity is removed (the tube is cut at the
    cell boundary) and the open tube is minimised once. End grips of ``grip`` Å (default
    50 Å) move rigidly apart at ``speed`` Å/ps each (default 1 Å/ps, i.e. 2 Å/ps relative),
    their atoms integrated with ``fix nve`` under ``fix setforce 0 0 0``. The free part starts
    with a linear axial velocity ramp between the grip speeds (no start-up shock) and random
    thermal velocities at ``temperature`` (default 10 K), and runs under a Nose–Hoover
    thermostat (``fix nvt``, damping 0.1 ps) whose temperature is measured from the x and y
    velocity components only (``compute temp/partial 1 1 0``), so the axial stretching flow is
    neither counted as heat nor damped. Time step 1 fs. Strain is the grip separation change
    over the initial free length ``L0 - 2 grip``; stress is the mean of the reaction forces on
    the two grips (the total force on each before ``setforce`` zeroes it, averaged over the
    last 100 steps of each 100-step sample) over ``ntubes 2 pi R t``. The extensometer strain
    (:class:`upscale.analysis.stress.Extensometer`, the coarse runner's definition) is the
    least-squares slope of the axial displacement against the axial position at the start
    of the pull (after the open-tube minimisation) over the atoms between two marks a
    quarter of the gauge inside each grip plane, evaluated inside LAMMPS (``fix
    store/state`` keeps z0, an atom-style variable and ``compute reduce`` give the slope)
    and averaged by the same ``fix ave/time`` as the stress, so each sample's strain on the
    marks belongs to the same instants as its stress; it is free of the grips' compliance
    (cost: within the timing noise, 4.38/4.40 s against 4.34/4.42 s without for the
    (10,10) vacancy reference's 2900 steps).
    The run stops when the stress has fallen below 20 % of its maximum after failure, or at
    ``max_strain``, or (a
    ``fix halt`` checked every 10 steps) when the shrink-wrapped box exceeds
    ``max_box_volume`` (1e8 Å^3): with the step cutoff an atom can be kicked off at tens of
    Å/fs after fracture and LAMMPS's neighbour bins grow with the box (a 60 Å (50,50) test
    tube reached 7 GB and minutes per 100 steps); ``aborted`` records where.

Set-up minimiser of the dynamic tension (:class:`MinSettings`, the ``min_*`` keywords of
:func:`dynamic_tension`, :func:`open_tube_setup` for the set-up alone)
    ``min_style`` cg (line search quadratic, backtrack or forcezero), sd, hftn, fire or
    quickmin, the norm the force tolerance bounds (``min_modify norm``: ``two``, the 2-norm
    of the global 3N force vector, LAMMPS's default and the references'; ``inf``, the
    largest force component; ``max``, the largest per-atom force), the damped styles' time
    step and FIRE's keywords. Only cg and sd move the cell: with the others the two
    box/relax minimisations of the zero-stress relaxation use cg. The defaults are the
    references' set-up, command for command. Every set-up minimisation is recorded in
    ``res["setup_minimisation"]`` (wall time, iterations and force evaluations from LAMMPS's
    log, stopping criterion, energy, largest force component and 2-norm).

Each run returns a result dict (:func:`quasi_static_tension`, :func:`dynamic_tension`) with
the curve, Young's modulus (fit over 0-2 % strain), strength, strain at peak, failure strain
(dynamic: also ``youngs_modulus_ext_TPa`` and ``strain_at_peak_ext`` on the extensometer),
LAMMPS version, potential file and checksum, protocol, date and wall time; a LAMMPS dump
(``id type x y z``) goes to ``dump_dir`` (default ``~/.cache/upscale/dumps``, outside the
repository).
"""
from __future__ import annotations

import dataclasses
import math
import os
import re
import tempfile
import time
from pathlib import Path

import numpy as np
from ase import Atoms

from upscale.analysis.stress import (WALL_THICKNESS, Extensometer, curve_metrics,
                                     extensometer_metrics, stress_from_force,
                                     stress_from_pressure)
from upscale.experiments.lammps.potential import Potential, resolve_potential

__all__ = ["relax_zero_stress", "quasi_static_tension", "dynamic_tension", "default_dump_dir",
           "static_grip_stiffness", "CARBON_MASS", "MinSettings", "SETUP_MIN_STYLES",
           "MIN_NORMS", "open_tube_setup"]

CARBON_MASS = 12.011  # amu


def default_dump_dir() -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "upscale" / "dumps"
    return base


def _check_atoms(atoms):
    if not isinstance(atoms, Atoms) or len(atoms) == 0:
        raise ValueError(f"atoms={type(atoms).__name__}; valid: a non-empty ase.Atoms")
    if not atoms.pbc[2]:
        raise ValueError("atoms.pbc[2] is False; valid: a structure periodic along z (the tube "
                         "axis), e.g. from upscale.build.swcnt")
    cell = atoms.cell.array
    if abs(np.linalg.det(cell)) < 1e-9 or np.abs(cell - np.diag(np.diag(cell))).max() > 1e-9:
        raise ValueError("atoms.cell must be orthorhombic with full rank (vacuum around the "
                         "tube); build it with upscale.build.swcnt/bundle")


def _types(atoms) -> np.ndarray:
    if "mol-id" in atoms.arrays:
        mol = np.asarray(atoms.arrays["mol-id"], dtype=int)
        uniq = np.unique(mol)
        return np.searchsorted(uniq, mol) + 1
    return np.ones(len(atoms), dtype=int)


def _mean_radius(atoms, types) -> float:
    xc, yc = atoms.info.get("axis_xy", atoms.cell.lengths()[:2] / 2)
    sel = types == 1
    if "tube_centres" in atoms.info:
        xc, yc = atoms.info["tube_centres"][0]
    p = atoms.positions[sel]
    # centre of the relaxed tube: mean of its atoms in x, y (it may drift slightly)
    c = p[:, :2].mean(axis=0) if "tube_centres" not in atoms.info else np.array([xc, yc])
    return float(np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]).mean())


def _setup(atoms, pot: Potential, boundary: str, box=None, nprocs_screen=False, log=None):
    """A LAMMPS instance holding ``atoms`` (ids 1..N in ASE order), types per tube."""
    from potentials.lammps_runtime import new_lammps  # noqa: PLC0415

    types = _types(atoms)
    ntypes = int(types.max())
    lmp = new_lammps(log=log)
    L = atoms.cell.lengths() if box is None else np.asarray(box)
    lmp.commands_list([
        "units metal", "atom_style atomic", "atom_modify map array sort 0 0",
        f"boundary {boundary}",
        f"region box block 0 {float(L[0])!r} 0 {float(L[1])!r} 0 {float(L[2])!r} units box",
        f"create_box {ntypes} box",
        f"mass * {CARBON_MASS}",
    ])
    pos = atoms.get_positions().copy()
    if atoms.pbc[2] and "p" in boundary.split()[2]:
        pos[:, 2] = np.mod(pos[:, 2], L[2])
        pos[pos[:, 2] >= L[2], 2] -= L[2]
    n = len(atoms)
    lmp.create_atoms(n, list(range(1, n + 1)), [int(t) for t in types],
                     pos.ravel().tolist())
    created = int(lmp.get_natoms())
    if created != n:
        lmp.close()
        raise RuntimeError(f"LAMMPS created {created} of {n} atoms (outside the box?)")
    lmp.commands_list(pot.commands(ntypes, lj_between_types=ntypes > 1))
    lmp.commands_list(["neighbor 1.0 bin", "neigh_modify delay 0 every 1 check yes",
                       "thermo_style custom step pe pxx pyy pzz lx ly lz vol fmax fnorm",
                       "thermo_modify norm no", "min_style cg"])
    return lmp, types


def _positions(lmp, n) -> np.ndarray:
    x = lmp.gather_atoms("x", 1, 3)
    return np.ctypeslib.as_array(x).reshape(n, 3).copy()


def _thermo(lmp) -> dict:
    return dict(lmp.last_thermo())


def extensometer_commands(ext: Extensometer) -> list[str]:
    """LAMMPS commands measuring :class:`Extensometer` ``ext`` (unit weights) as ``v_exteps``.

    To be issued with the atoms at their reference positions (the start of the pull): group
    ``ext`` = the atoms between the marks (region block, bounds included as in ``ext``),
    ``fix ext0 ext store/state 0 z`` keeps their z0, and ``v_exteps`` = sum over the group of
    (z0 - zbar) (z - z0) / szz with ``ext``'s zbar and szz, i.e. ``ext.strain``. ``v_extn``
    counts the group's atoms (to check it against ``ext.n``)."""
    return [f"region rext block INF INF INF INF {ext.lo!r} {ext.hi!r} units box",
            "group ext region rext", "fix ext0 ext store/state 0 z",
            f"variable extu atom (f_ext0-{ext.zbar!r})*(z-f_ext0)",
            "compute exts ext reduce sum v_extu",
            f"variable exteps equal c_exts/{ext.szz!r}",
            "variable extn equal count(ext)"]


def per_tube_grip_commands(ntubes: int) -> list[str]:
    """Groups ``botK``/``topK`` (tube K's grip atoms, atom type K) and ``fix sfbK``/``sftK``
    (setforce 0) whose global vectors are tube K's grip reactions; none for one tube."""
    if ntubes <= 1:
        return []
    out = []
    for k in range(1, ntubes + 1):
        out += [f"group tube{k} type {k}", f"group bot{k} intersect bot tube{k}",
                f"group top{k} intersect top tube{k}",
                f"fix sfb{k} bot{k} setforce 0.0 0.0 0.0",
                f"fix sft{k} top{k} setforce 0.0 0.0 0.0"]
    return out


def _minimize(lmp, ftol, maxiter=20000):
    lmp.command(f"minimize 0.0 {ftol} {maxiter} {10 * maxiter}")


DAMPED_STYLE = "quickmin"  # the default damped-dynamics minimiser of the fallback
DAMPED_STYLES = ("quickmin", "fire")
LINE_SEARCHES = ("quadratic", "backtrack", "forcezero")


def _minimize_robust(lmp, ftol, fmax_tol=1e-4, cycles=3, maxiter=20000,
                     md_steps=5000, md_limit=0.02, md_timestep=0.001,
                     damped_style=DAMPED_STYLE, line_search="quadratic") -> dict:
    """CG, and while the largest force component stays above ``fmax_tol`` eV/Å, damped
    dynamics then CG again (at most ``cycles`` times; 0: CG only).

    With the step cutoff the energy jumps by ~2.4 eV when a C–C bond crosses 2.1 Å, so the
    CG line search stops ("linesearch alpha is zero") with a stretched bond held at the step
    and a residual force of order 1 eV/Å. Damped dynamics is force-based and, like MD, steps
    over the 2e-5 Å switching window: by default LAMMPS ``min_style quickmin`` (velocity
    projected on the force, zeroed when it points uphill; ``md_timestep`` ps steps, 1 fs; no
    atom moves more than ``md_limit`` Å per step), at most ``md_steps`` steps, then CG
    converges the new state. ``damped_style="fire"`` uses LAMMPS's FIRE (its default
    parameters, the same time step and ``dmax``) instead; it was tried first and lost atoms
    when a pristine tube failed; a viscous ``nve/limit`` run did not carry cracks through.
    ``line_search`` is the CG line search (``min_modify line``; LAMMPS resets it, and
    ``dmax``, on every ``min_style``, so it is set after each). Returns the final ``fmax``
    and the number of damped cycles.
    """
    cg = ["min_style cg"] + ([f"min_modify line {line_search}"]
                             if line_search != "quadratic" else [])
    if line_search != "quadratic":
        lmp.commands_list(cg)
    _minimize(lmp, ftol, maxiter)
    th = _thermo(lmp)
    k = 0
    while th["Fmax"] > fmax_tol and k < cycles:
        lmp.commands_list([f"timestep {md_timestep!r}", f"min_style {damped_style}",
                           f"min_modify dmax {md_limit!r}"])
        _minimize(lmp, 1e-3, md_steps)
        lmp.commands_list(cg + ["min_modify dmax 0.1"])
        _minimize(lmp, ftol, maxiter)
        th = _thermo(lmp)
        k += 1
    return {"fmax_eV_per_A": float(th["Fmax"]), "damped_md_cycles": k}


SETUP_MIN_STYLES = ("cg", "sd", "hftn", "fire", "quickmin")
DAMPED_MIN_STYLES = ("fire", "quickmin")
BOX_RELAX_STYLES = ("cg", "sd")  # LAMMPS refuses fix box/relax with the others
MIN_NORMS = ("two", "inf", "max")


@dataclasses.dataclass(frozen=True)
class MinSettings:
    """The LAMMPS minimiser of a set-up minimisation (``min_style`` + ``min_modify``).

    ``style``: one of :data:`SETUP_MIN_STYLES`. ``line``: the line search of ``cg`` and
    ``sd`` (``quadratic``, ``backtrack``, ``forcezero``). ``norm``: the norm the force
    tolerance ``ftol`` (eV/Å) bounds (``min_modify norm``): ``two``, the 2-norm of the whole
    3N force vector (LAMMPS's default); ``inf``, the largest force component; ``max``, the
    largest per-atom force magnitude. ``timestep_ps`` (damped styles: the ``timestep`` of
    the minimiser's dynamics; FIRE's own step grows up to ``tmax`` times it) and ``dmax``
    (Å: the largest move of an atom per iteration or line-search step) are LAMMPS's defaults
    (1 fs in metal units, 0.1 Å) when None. ``box_vmax``: ``fix box/relax``'s largest
    fractional volume change per iteration in the zero-stress relaxation. ``fire``: extra ``min_modify`` keywords of FIRE
    (e.g. ``("integrator", "verlet", "tmax", "4")``). ``maxiter``: iterations per minimize
    (force evaluations at most 10x that).

    Only CG and SD move the cell (LAMMPS refuses ``fix box/relax`` with damped dynamics and
    HFTN): with another style the periodic zero-stress relaxation's two box/relax
    minimisations use CG with the same norm; every other minimisation uses ``style``. The defaults are the stored references'
    set-up (CG, quadratic line search, 2-norm).
    """
    style: str = "cg"
    line: str = "quadratic"
    norm: str = "two"
    timestep_ps: float | None = None
    dmax: float | None = None
    fire: tuple = ()
    maxiter: int = 20000
    box_vmax: float = 0.001

    def __post_init__(self):
        if self.style not in SETUP_MIN_STYLES:
            raise ValueError(f"min style={self.style!r}; valid: {', '.join(SETUP_MIN_STYLES)}")
        if self.line not in LINE_SEARCHES:
            raise ValueError(f"line search={self.line!r}; valid: {', '.join(LINE_SEARCHES)}")
        if self.norm not in MIN_NORMS:
            raise ValueError(f"force norm={self.norm!r}; valid: {', '.join(MIN_NORMS)}")
        for name in ("timestep_ps", "dmax", "box_vmax"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}={v!r}; valid: None or a positive number")
        if isinstance(self.maxiter, bool) or not isinstance(self.maxiter, int) \
                or self.maxiter < 1:
            raise ValueError(f"maxiter={self.maxiter!r}; valid: an integer >= 1")
        if len(self.fire) % 2 or (self.fire and self.style != "fire"):
            raise ValueError(f"fire={self.fire!r} with style {self.style!r}; valid: keyword, "
                             "value pairs of min_modify, with style 'fire' only")

    def style_for(self, box_relax: bool) -> str:
        """The style of a minimisation (with ``fix box/relax`` if ``box_relax``)."""
        return "cg" if (box_relax and self.style not in BOX_RELAX_STYLES) else self.style

    def commands(self, box_relax: bool = False) -> list[str]:
        """The commands that select this minimiser (LAMMPS resets ``min_modify`` on every
        ``min_style``); ``box_relax``: for a minimisation with ``fix box/relax``."""
        style = self.style_for(box_relax)
        out = [f"min_style {style}"]
        if style in ("cg", "sd") and self.line != "quadratic":
            out.append(f"min_modify line {self.line}")
        if self.norm != "two":
            out.append(f"min_modify norm {self.norm}")
        if self.dmax is not None:
            out.append(f"min_modify dmax {self.dmax!r}")
        if style == "fire" and self.fire:
            out.append("min_modify " + " ".join(str(v) for v in self.fire))
        if style in DAMPED_MIN_STYLES:
            out.append(f"timestep {(self.timestep_ps or 0.001)!r}")
        return out

    def describe(self) -> dict:
        return dataclasses.asdict(self)


_MIN_STATS = re.compile(r"Iterations, force evaluations = (\d+) (\d+)")
_MIN_STOP = re.compile(r"Stopping criterion = (.+)")


def _minimize_logged(lmp, ftol, settings: MinSettings, label: str, stats: list,
                     box_relax: bool = False) -> None:
    """``minimize 0 ftol`` with ``settings``; appends to ``stats`` this minimisation's
    record: ``label``, the style used, wall time (s), iterations and force evaluations (from
    LAMMPS's log), stopping criterion, final energy (eV), largest force component (eV/Å)
    and the force 2-norm (eV/Å)."""
    lmp.commands_list(settings.commands(box_relax))
    with tempfile.TemporaryDirectory(prefix="upscale-min-") as d:
        log = Path(d) / "min.log"
        lmp.command(f"log {log}")
        t0 = time.perf_counter()
        try:
            _minimize(lmp, ftol, settings.maxiter)
        finally:
            wall = time.perf_counter() - t0
            lmp.command("log none")
        text = log.read_text(errors="replace")
    it = _MIN_STATS.findall(text)
    stop = _MIN_STOP.findall(text)
    th = _thermo(lmp)
    stats.append({"stage": label, "style": settings.style_for(box_relax), "wall_s": wall,
                  "iterations": int(it[-1][0]) if it else None,
                  "force_evaluations": int(it[-1][1]) if it else None,
                  "stop": stop[-1].strip() if stop else None,
                  "energy_eV": float(th["PotEng"]), "fmax_eV_per_A": float(th["Fmax"]),
                  "fnorm_eV_per_A": float(th["Fnorm"])})


def _prescale(atoms, pot, ftol):
    """Start long tubes near their relaxed shape (``box/relax`` alone needs ~1e4 CG steps).

    A short pristine tube of the same chirality (>= 10 Å, whole cells) is relaxed first; the
    structure is then scaled by its axial ratio L0/L along z and by its radial ratio
    R_relaxed/R about each tube's centre line. Only a starting guess: the full relaxation
    follows. Structures without ``info["chirality"]`` are returned unchanged.
    """
    info = atoms.info
    if "chirality" not in info or "unit_cell_length" not in info or info.get("_prescaled"):
        return atoms
    from upscale.build import swcnt  # noqa: PLC0415

    n, m = info["chirality"]
    T = info["unit_cell_length"]
    k = max(2, math.ceil(10.0 / T))
    if k >= info.get("ncells", 0):
        return atoms
    probe = swcnt(n, m, k * T, bond=info.get("bond", 1.42))
    probe.info["_prescaled"] = True
    _, pinfo = relax_zero_stress(probe, ftol=ftol, _pot=pot)
    rz = pinfo["L0_A"] / probe.cell[2, 2]
    rr = pinfo["radius_relaxed_A"] / probe.info["radius"]
    out = atoms.copy()
    x = out.get_positions()
    centres = np.asarray(info.get("tube_centres", [info["axis_xy"]]), dtype=float)
    types = _types(out)
    for t in range(1, int(types.max()) + 1):
        sel = types == t
        c = centres[t - 1] if len(centres) >= t else centres[0]
        x[sel, :2] = c + (x[sel, :2] - c) * rr
    x[:, 2] *= rz
    cell = out.cell.lengths()
    out.set_cell(np.diag([cell[0], cell[1], cell[2] * rz]))
    out.set_positions(x)
    out.info["_prescaled"] = True
    return out


def relax_zero_stress(atoms: Atoms, potential="tersoff:BNC.tersoff", cutoff="step",
                      ftol: float = 1e-6, _pot: Potential | None = None,
                      minimiser: MinSettings | None = None, stats: list | None = None):
    """Relax atoms and the axial cell length to zero axial stress (see module docstring).

    Returns
    -------
    relaxed : ase.Atoms
        Copy of ``atoms`` with relaxed positions and cell ``(Lx, Ly, L0)``.
    info : dict
        ``L0_A``, ``radius_relaxed_A``, ``pzz_bar`` and ``stress_GPa`` after relaxation,
        ``energy_eV``.
    """
    _check_atoms(atoms)
    pot = _pot or resolve_potential(potential, cutoff)
    atoms = _prescale(atoms, pot, ftol)
    lmp, types = _setup(atoms, pot, "s s p")
    try:
        vmax = 0.001 if minimiser is None else minimiser.box_vmax
        lmp.command(f"fix br all box/relax z 0.0 vmax {vmax!r}")
        if minimiser is None:  # the references' set-up (CG, 2-norm), no records
            _minimize(lmp, ftol)
            _minimize(lmp, ftol)
            lmp.command("unfix br")
            _minimize(lmp, ftol)
        else:
            st = [] if stats is None else stats
            _minimize_logged(lmp, ftol, minimiser, "box_relax_1", st, box_relax=True)
            _minimize_logged(lmp, ftol, minimiser, "box_relax_2", st, box_relax=True)
            lmp.command("unfix br")
            _minimize_logged(lmp, ftol, minimiser, "fixed_box", st)
        th = _thermo(lmp)
        x = _positions(lmp, len(atoms))
    finally:
        lmp.close()
    out = atoms.copy()
    cell = atoms.cell.lengths()  # x, y: the builder's vacuum box (LAMMPS shrink-wraps them)
    out.set_cell(np.diag([cell[0], cell[1], th["Lz"]]))
    out.set_positions(x)
    R = _mean_radius(out, types)
    ntubes = int(types.max())
    s = float(stress_from_pressure(th["Pzz"], th["Volume"], th["Lz"], R, WALL_THICKNESS, ntubes))
    return out, {"L0_A": float(th["Lz"]), "radius_relaxed_A": R, "pzz_bar": float(th["Pzz"]),
                 "stress_GPa": s, "energy_eV": float(th["PotEng"])}


def _common(atoms, pot, protocol, relax_info, types) -> dict:
    from potentials.lammps_runtime import lammps_version  # noqa: PLC0415
    from upscale.io import versions  # noqa: PLC0415

    info = atoms.info
    return {
        "kind": "lammps-tension", "protocol": protocol,
        "structure": {
            "chirality": list(info.get("chirality", ())) or None,
            "n_atoms": len(atoms), "ntubes": int(types.max()),
            "length_built_A": info.get("length"), "ncells": info.get("ncells"),
            "radius_ideal_A": info.get("radius"),
            "vacancy": info.get("vacancy"),
            "bundle_spacing": info.get("spacing"), "bundle_wall_gap_A": info.get("wall_gap"),
        },
        "relaxation": relax_info,
        "stress_convention": {
            "wall_thickness_A": WALL_THICKNESS,
            "area": "ntubes * 2 pi R t, R = mean radius of tube 1 after zero-stress relaxation",
            "radius_A": relax_info["radius_relaxed_A"]},
        "potential": pot.provenance(),
        "lammps_version": lammps_version(),
        "nprocs": 1,
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "versions": versions(),
    }


def quasi_static_tension(atoms: Atoms, potential="tersoff:BNC.tersoff", *, cutoff="step",
                         strain_step: float = 0.005, max_strain: float = 0.40,
                         ftol: float = 1e-8, fmax_tol: float = 1e-4,
                         relax_ftol: float = 1e-6, fit_max_strain: float = 0.02,
                         dump: str | Path | None = None, after_failure: int = 1,
                         progress=None, nprocs: int = 1, damped_style: str = DAMPED_STYLE,
                         damped_dmax: float = 0.02, damped_timestep_ps: float = 0.001,
                         damped_steps: int = 5000, damped_cycles: int = 3,
                         line_search: str = "quadratic") -> dict:
    """Quasi-static axial tension of a periodic tube or bundle (module docstring).

    Parameters
    ----------
    atoms : ase.Atoms
        Periodic along z, orthorhombic full-rank cell (from :mod:`upscale.build`).
    potential : str
        Spec for :func:`upscale.experiments.lammps.potential.resolve_potential`.
    cutoff : {"step", "standard"}
    strain_step, max_strain : float
        Strain increment and the largest strain applied (dimensionless).
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
    dump : path, optional
        LAMMPS dump file (``id type x y z``), one frame per strain (the first is eps = 0).
    progress : callable, optional
        Called as ``progress(strain, stress_GPa)`` after each step.

    Returns
    -------
    dict
        Result record; ``curve`` holds ``strain``, ``stress_GPa``, ``energy_eV``, ``Lz_A``.
    """
    _check_atoms(atoms)
    if not (0 < strain_step < max_strain <= 2.0):
        raise ValueError(f"strain_step={strain_step}, max_strain={max_strain}; valid: "
                         "0 < strain_step < max_strain <= 2")
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
    if nprocs != 1:
        from upscale.experiments.lammps.mpi import run_mpi  # noqa: PLC0415

        return run_mpi("quasi_static_tension", atoms, nprocs, potential=potential,
                       cutoff=cutoff, strain_step=strain_step, max_strain=max_strain,
                       ftol=ftol, fmax_tol=fmax_tol, relax_ftol=relax_ftol,
                       fit_max_strain=fit_max_strain, dump=dump, after_failure=after_failure,
                       damped_style=damped_style, damped_dmax=damped_dmax,
                       damped_timestep_ps=damped_timestep_ps, damped_steps=damped_steps,
                       damped_cycles=damped_cycles, line_search=line_search)
    t0 = time.perf_counter()
    pot = resolve_potential(potential, cutoff)
    relaxed, rinfo = relax_zero_stress(atoms, potential, cutoff, relax_ftol, _pot=pot)
    L0, R = float(rinfo["L0_A"]), float(rinfo["radius_relaxed_A"])
    lmp, types = _setup(relaxed, pot, "s s p")
    ntubes = int(types.max())
    strains, stresses, energies, lzs, fmaxes, fires = [], [], [], [], [], []
    if dump is not None:
        dump = Path(dump)
        dump.parent.mkdir(parents=True, exist_ok=True)
        if dump.exists():
            dump.unlink()
    try:
        zlo = float(lmp.extract_box()[0][2])
        k, failed_at, aborted = 0, None, None
        while True:
            eps = k * strain_step
            if eps > max_strain + 1e-12:
                break
            lmp.command(f"change_box all z final {zlo!r} {zlo + L0 * (1.0 + eps)!r} "
                        "remap units box")
            try:
                mres = _minimize_robust(lmp, ftol, fmax_tol, cycles=int(damped_cycles),
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
            th = _thermo(lmp)
            s = float(stress_from_pressure(th["Pzz"], th["Volume"], th["Lz"], R,
                                           WALL_THICKNESS, ntubes))
            strains.append(eps)
            stresses.append(s)
            energies.append(th["PotEng"])
            lzs.append(th["Lz"])
            if dump is not None:
                lmp.command(f"write_dump all custom {dump} id type x y z "
                            "modify sort id append yes")
            if progress is not None:
                progress(eps, s)
            if failed_at is None and s < 0.95 * max(stresses) and max(stresses) > 0:
                failed_at = k
            if failed_at is not None and k - failed_at >= after_failure:
                break
            k += 1
    finally:
        lmp.close()
    res = _common(atoms, pot, "quasi-static", rinfo, types)
    res["protocol_detail"] = {
        "boundary": "s s p (periodic along the axis z)",
        "relaxation": "fix box/relax z 0.0 vmax 0.001 + minimize (cg) x2, then fixed-box "
                      f"minimize, ftol {relax_ftol} eV/A",
        "strain_step": strain_step, "max_strain": max_strain,
        "minimize": (f"min_style cg (line search {line_search}), etol 0, ftol {ftol} eV/A, "
                     "maxiter 20000; "
                     + (f"while fmax > {fmax_tol} eV/A: {damped_style} (<= {damped_steps} "
                        f"steps of {damped_timestep_ps:g} ps, dmax {damped_dmax:g} A, ftol "
                        f"1e-3) then cg, at most {damped_cycles} cycles (the step cutoff "
                        "stops CG line searches at the step)" if damped_cycles > 0 else
                        "CG only, no damped dynamics (the residual fmax of each step is "
                        "kept)")),
        "fmax_tol_eV_per_A": fmax_tol, "damped_style": damped_style,
        "damped_dmax_A": damped_dmax, "damped_timestep_ps": damped_timestep_ps,
        "damped_steps": damped_steps, "damped_cycles": damped_cycles,
        "line_search": line_search,
        "stress": "-pzz V / (ntubes 2 pi R t Lz)",
        "after_failure_steps": after_failure}
    res["curve"] = {"strain": strains, "stress_GPa": stresses, "energy_eV": energies,
                    "Lz_A": lzs, "fmax_eV_per_A": fmaxes, "damped_md_cycles": fires}
    res["max_residual_force_eV_per_A"] = max(fmaxes)
    res["aborted"] = aborted  # a LAMMPS error in a step after the peak ends the curve there
    res["zero_strain_stress_GPa"] = stresses[0]
    res.update(curve_metrics(strains, stresses, fit_max_strain=fit_max_strain))
    if aborted is not None and not res["failed"]:
        res.update(failed=True, failure_strain=aborted["strain"],
                   failure_note="LAMMPS stopped with an error inside this strain step")
    res["dump"] = str(dump) if dump is not None else None
    res["wall_s"] = time.perf_counter() - t0
    return res


def open_tube_setup(atoms: Atoms, potential="tersoff:BNC.tersoff", *, cutoff="step",
                    ftol: float = 1e-6, minimiser: MinSettings | None = None,
                    periodic_relaxation: bool = True, relaxed: Atoms | None = None) -> dict:
    """The set-up of :func:`dynamic_tension` alone: the periodic zero-stress relaxation
    (unless ``periodic_relaxation`` is False, see :func:`dynamic_tension`), the tube cut at
    the cell boundary and minimised open, all with ``minimiser`` (default
    :class:`MinSettings`: the references' CG) to ``ftol`` eV/Å in its norm. ``relaxed``:
    an already relaxed periodic structure (from :func:`relax_zero_stress`); only the open
    tube is then minimised.

    Returns a dict: ``stages`` (one record per minimize, :func:`_minimize_logged`: wall
    time, iterations, force evaluations, stopping criterion, energy, largest force
    component), ``wall_s`` (the whole set-up, with the prescaling and LAMMPS's set-up),
    ``iterations``, ``force_evaluations`` (sums), the open tube's ``energy_eV``,
    ``fmax_eV_per_A`` (largest force component) and ``fnorm_eV_per_A``, ``L0_A``,
    ``relaxed`` (the periodic structure the tube was cut from) and ``positions`` ((N, 3),
    Å, ASE order, the minimised open tube)."""
    _check_atoms(atoms)
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
        relaxed = _prescale(atoms, pot, ftol)
    periodic = relaxed.copy()
    L0 = float(relaxed.cell[2, 2])
    n = len(relaxed)
    x = relaxed.get_positions()
    x[:, 2] = np.mod(x[:, 2], L0)
    x[x[:, 2] >= L0, 2] -= L0
    relaxed.set_positions(x)
    lmp, _ = _setup(relaxed, pot, "s s s", box=relaxed.cell.lengths().copy())
    try:
        _minimize_logged(lmp, ftol, settings, "open_tube", stats)
        x = _positions(lmp, n)
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
                    pull_rounds: int = 1, between_rounds=None) -> dict:
    """Dynamic tension with end grips pulled apart at constant speed (module docstring).

    Parameters
    ----------
    ftol : float
        Force tolerance of the set-up minimisations, eV/Å, in the norm ``min_norm``.
    min_style, min_line, min_norm, min_timestep_ps, min_dmax, min_fire, min_maxiter
        The set-up minimiser (:class:`MinSettings`: style, line search, the norm ``ftol``
        bounds, damped-dynamics time step, largest move per iteration, FIRE keywords,
        iterations per minimize); the defaults are the stored references' (CG, quadratic
        line search, 2-norm of the global force vector).
    periodic_relaxation : bool
        True (default): the periodic zero-stress relaxation (module docstring) before the
        tube is cut open. False: the open tube is minimised straight from the prescaled
        structure (:func:`_prescale`: a short periodic tube's relaxed axial and radial
        ratios; L0 is then the prescaled cell length and R the mean atom radius of the
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
    _check_atoms(atoms)
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
                       periodic_relaxation=periodic_relaxation)
    settings = MinSettings(min_style, min_line, min_norm, min_timestep_ps, min_dmax,
                           tuple(min_fire), min_maxiter)
    t0 = time.perf_counter()
    c0 = time.process_time()  # CPU time of this process (LAMMPS runs in it): load-free
    pot = resolve_potential(potential, cutoff)
    min_stats: list = []
    if periodic_relaxation:
        relaxed, rinfo = relax_zero_stress(atoms, potential, cutoff, ftol, _pot=pot,
                                           minimiser=settings, stats=min_stats)
    else:
        relaxed = _prescale(atoms, pot, ftol)
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
    lmp, types = _setup(relaxed, pot, "s s s", box=box)
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
        _minimize_logged(lmp, ftol, settings, "open_tube", min_stats)
        t_open = time.perf_counter() - t1
        x_open = _positions(lmp, n)
        if rinfo["radius_relaxed_A"] is None:
            opened = relaxed.copy()
            opened.set_positions(x_open)
            R = rinfo["radius_relaxed_A"] = _mean_radius(opened, types)
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
                lmp, _ = _setup(opened, pot, "s s s", box=box)
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
                if s < 0.95 * smax:
                    failed = True
                if (failed and s < 0.2 * smax) or eps > max_strain or step >= max_steps:
                    break
            t_dyn = time.perf_counter() - t2
            m = curve_metrics(strains, stresses, fit_max_strain=fit_max_strain)
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
    res = _common(atoms, pot, "dynamic", rinfo, types)
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
    res.update(curve_metrics(strains, stresses, fit_max_strain=fit_max_strain))
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
    _check_atoms(atoms)
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
    lmp, types = _setup(relaxed, pot, "s s s", box=relaxed.cell.lengths().copy())
    try:
        _minimize(lmp, ftol)
        x = _positions(lmp, n)
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
        _minimize(lmp, ftol)
        lmp.command("run 0")
        from potentials.lammps_runtime import lammps_module  # noqa: PLC0415

        c = lammps_module()
        fb = lmp.extract_fix("sfb", c.LMP_STYLE_GLOBAL, c.LMP_TYPE_VECTOR, 2)
        ft = lmp.extract_fix("sft", c.LMP_STYLE_GLOBAL, c.LMP_TYPE_VECTOR, 2)
        fmax = float(_thermo(lmp)["Fmax"])
    finally:
        lmp.close()
    F = 0.5 * (fb - ft)  # tension: the bottom grip is pulled +z, the top one -z
    res = _common(atoms, pot, "static-grip", rinfo, types)
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
