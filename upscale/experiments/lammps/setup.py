"""Set-up shared by the LAMMPS runners: a LAMMPS instance holding a structure, the
minimisers, the zero-stress relaxation, the common part of every result record.

Units ``metal`` (Å, eV, ps, bar); stresses in GPa with the wall-thickness convention of
:mod:`upscale.analysis.stress`.

Zero-stress relaxation (every run starts from it, :func:`relax_zero_stress`)
    The periodic structure (cell along z, vacuum around) is minimised with
    ``fix box/relax z 0.0`` (conjugate gradients, atoms and the axial cell length), twice (the
    box/relax reference changes), then once more at fixed box. The relaxed axial length is
    L0 and all strains are measured from it. R for the area is the mean distance of the atoms
    of tube 1 from its axis after this relaxation. Long tubes start from a short tube's
    relaxed shape (:func:`prescale`).

The robust minimiser of the quasi-static steps (:func:`minimize_robust`)
    CG (``etol 0``, ``ftol`` on the 2-norm of the force vector); if the largest force
    component is still above ``fmax_tol``, damped dynamics (``quickmin`` or FIRE) then CG
    again, a few times: with the step cutoff a C-C bond crossing 2.1 Å makes the energy jump
    by ~2.4 eV, which stops CG line searches with a bond held at the step.

Set-up minimiser of the dynamic tension (:class:`MinSettings`)
    ``min_style`` cg (line search quadratic, backtrack or forcezero), sd, hftn, fire or
    quickmin, the norm the force tolerance bounds (``min_modify norm``: ``two``, the 2-norm
    of the global 3N force vector, LAMMPS's default and the references'; ``inf``, the
    largest force component; ``max``, the largest per-atom force), the damped styles' time
    step and FIRE's keywords. Only cg and sd move the cell: with the others the two
    box/relax minimisations of the zero-stress relaxation use cg. The defaults are the
    references' set-up, command for command. :func:`minimize_logged` records each set-up
    minimisation (wall time, iterations and force evaluations from LAMMPS's log, stopping
    criterion, energy, largest force component and 2-norm).
"""
from __future__ import annotations

import dataclasses
import math
import re
import tempfile
import time
from pathlib import Path

import numpy as np
from ase import Atoms

from upscale.analysis.stress import WALL_THICKNESS, Extensometer, stress_from_pressure
from upscale.experiments.lammps.cache import cache_dir
from upscale.experiments.lammps.potential import Potential, resolve_potential

__all__ = ["CARBON_MASS", "default_dump_dir", "check_atoms", "atom_types", "mean_radius",
           "new_instance", "gather_positions", "thermo", "extensometer_commands",
           "per_tube_grip_commands", "minimize", "minimize_robust", "DAMPED_STYLE",
           "DAMPED_STYLES", "LINE_SEARCHES", "SETUP_MIN_STYLES", "DAMPED_MIN_STYLES",
           "BOX_RELAX_STYLES", "MIN_NORMS", "MinSettings", "minimize_logged", "prescale",
           "relax_zero_stress", "common_record"]

CARBON_MASS = 12.011  # amu


def default_dump_dir() -> Path:
    """Where LAMMPS dumps go by default: ``cache_dir("dumps")`` (outside the repository)."""
    return cache_dir("dumps")


def check_atoms(atoms):
    if not isinstance(atoms, Atoms) or len(atoms) == 0:
        raise ValueError(f"atoms={type(atoms).__name__}; valid: a non-empty ase.Atoms")
    if not atoms.pbc[2]:
        raise ValueError("atoms.pbc[2] is False; valid: a structure periodic along z (the tube "
                         "axis), e.g. from upscale.build.swcnt")
    cell = atoms.cell.array
    if abs(np.linalg.det(cell)) < 1e-9 or np.abs(cell - np.diag(np.diag(cell))).max() > 1e-9:
        raise ValueError("atoms.cell must be orthorhombic with full rank (vacuum around the "
                         "tube); build it with upscale.build.swcnt/bundle")


def atom_types(atoms) -> np.ndarray:
    if "mol-id" in atoms.arrays:
        mol = np.asarray(atoms.arrays["mol-id"], dtype=int)
        uniq = np.unique(mol)
        return np.searchsorted(uniq, mol) + 1
    return np.ones(len(atoms), dtype=int)


def mean_radius(atoms, types) -> float:
    xc, yc = atoms.info.get("axis_xy", atoms.cell.lengths()[:2] / 2)
    sel = types == 1
    if "tube_centres" in atoms.info:
        xc, yc = atoms.info["tube_centres"][0]
    p = atoms.positions[sel]
    # centre of the relaxed tube: mean of its atoms in x, y (it may drift slightly)
    c = p[:, :2].mean(axis=0) if "tube_centres" not in atoms.info else np.array([xc, yc])
    return float(np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]).mean())


def new_instance(atoms, pot: Potential, boundary: str, box=None, nprocs_screen=False,
                 log=None):
    """A LAMMPS instance holding ``atoms`` (ids 1..N in ASE order), types per tube, the
    potential's pair commands, ``units metal``, ``min_style cg`` and the thermo columns the
    runners read (``pe pxx pyy pzz lx ly lz vol fmax fnorm``)."""
    from potentials.lammps_runtime import new_lammps  # noqa: PLC0415

    types = atom_types(atoms)
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


def gather_positions(lmp, n) -> np.ndarray:
    """(n, 3) positions in atom-id order (collective: every MPI rank gets them)."""
    x = lmp.gather_atoms("x", 1, 3)
    return np.ctypeslib.as_array(x).reshape(n, 3).copy()


def thermo(lmp) -> dict:
    """The last thermo output as a dict (``PotEng``, ``Pzz``, ``Lz``, ``Fmax``, ...)."""
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


def minimize(lmp, ftol, maxiter=20000):
    """``minimize 0.0 ftol maxiter 10*maxiter`` (energy tolerance 0: the force decides)."""
    lmp.command(f"minimize 0.0 {ftol} {maxiter} {10 * maxiter}")


DAMPED_STYLE = "quickmin"  # the default damped-dynamics minimiser of the fallback
DAMPED_STYLES = ("quickmin", "fire")
LINE_SEARCHES = ("quadratic", "backtrack", "forcezero")


def minimize_robust(lmp, ftol, fmax_tol=1e-4, cycles=3, maxiter=20000,
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
    minimize(lmp, ftol, maxiter)
    th = thermo(lmp)
    k = 0
    while th["Fmax"] > fmax_tol and k < cycles:
        lmp.commands_list([f"timestep {md_timestep!r}", f"min_style {damped_style}",
                           f"min_modify dmax {md_limit!r}"])
        minimize(lmp, 1e-3, md_steps)
        lmp.commands_list(cg + ["min_modify dmax 0.1"])
        minimize(lmp, ftol, maxiter)
        th = thermo(lmp)
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


def minimize_logged(lmp, ftol, settings: MinSettings, label: str, stats: list,
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
            minimize(lmp, ftol, settings.maxiter)
        finally:
            wall = time.perf_counter() - t0
            lmp.command("log none")
        text = log.read_text(errors="replace")
    it = _MIN_STATS.findall(text)
    stop = _MIN_STOP.findall(text)
    th = thermo(lmp)
    stats.append({"stage": label, "style": settings.style_for(box_relax), "wall_s": wall,
                  "iterations": int(it[-1][0]) if it else None,
                  "force_evaluations": int(it[-1][1]) if it else None,
                  "stop": stop[-1].strip() if stop else None,
                  "energy_eV": float(th["PotEng"]), "fmax_eV_per_A": float(th["Fmax"]),
                  "fnorm_eV_per_A": float(th["Fnorm"])})


def prescale(atoms, pot, ftol):
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
    types = atom_types(out)
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
    check_atoms(atoms)
    pot = _pot or resolve_potential(potential, cutoff)
    atoms = prescale(atoms, pot, ftol)
    lmp, types = new_instance(atoms, pot, "s s p")
    try:
        vmax = 0.001 if minimiser is None else minimiser.box_vmax
        lmp.command(f"fix br all box/relax z 0.0 vmax {vmax!r}")
        if minimiser is None:  # the references' set-up (CG, 2-norm), no records
            minimize(lmp, ftol)
            minimize(lmp, ftol)
            lmp.command("unfix br")
            minimize(lmp, ftol)
        else:
            st = [] if stats is None else stats
            minimize_logged(lmp, ftol, minimiser, "box_relax_1", st, box_relax=True)
            minimize_logged(lmp, ftol, minimiser, "box_relax_2", st, box_relax=True)
            lmp.command("unfix br")
            minimize_logged(lmp, ftol, minimiser, "fixed_box", st)
        th = thermo(lmp)
        x = gather_positions(lmp, len(atoms))
    finally:
        lmp.close()
    out = atoms.copy()
    cell = atoms.cell.lengths()  # x, y: the builder's vacuum box (LAMMPS shrink-wraps them)
    out.set_cell(np.diag([cell[0], cell[1], th["Lz"]]))
    out.set_positions(x)
    R = mean_radius(out, types)
    ntubes = int(types.max())
    s = float(stress_from_pressure(th["Pzz"], th["Volume"], th["Lz"], R, WALL_THICKNESS, ntubes))
    return out, {"L0_A": float(th["Lz"]), "radius_relaxed_A": R, "pzz_bar": float(th["Pzz"]),
                 "stress_GPa": s, "energy_eV": float(th["PotEng"])}


def common_record(atoms, pot, protocol, relax_info, types) -> dict:
    """The part of a result record every runner shares: kind, protocol name, structure,
    relaxation, stress convention, potential provenance, LAMMPS version, date, versions."""
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
