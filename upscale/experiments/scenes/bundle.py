"""A bundle of tubes, each with its own model, coupled by van der Waals forces and pulled in
dynamic tension (seed 004 sec. 5.3.2): the scene's parts. The scene function
``experiments.bundle`` (``upscale bundle``, :mod:`upscale.experiments.scenes.bundle_scene`)
builds a :class:`BundleScene`, runs its pull
(:func:`upscale.experiments.scenes.bundle_pull.dynamic_tension`) and returns a Result.

    upscale bundle --chirality 10,10 --coarsening 2 [--compare lammps]

The scene (:class:`BundleScene`) puts every tube of :func:`upscale.build.bundle` (a central
tube and up to six around it) on the engine as its own body (:mod:`upscale.engine.bodies`):

* ``tersoff``: the atomistic tube, every atom a particle (:mod:`upscale.models.tersoff`);
* ``dcbr``: the coarse open tube at coarsening K, :class:`~upscale.models.dcbr.model.
  DCBRModel` built from the tube's own atoms (the lattice carried by particles K lattice
  constants apart), set up as the single tube's dynamic pull sets it up
  (:func:`upscale.experiments.scenes.tube_coarse_pull.setup_open_tube`): atomistic bands
  of half-width ``r_atomistic`` across both grip planes and atomistic regions of radius
  ``r_atomistic`` at every defect the model finds (the open ends; the vacancy, if the tube
  has it);
* ``dcbr-defect``: the same model (the name of the old vacancy tube; the new model finds a
  vacancy in the tube's atoms itself).

Optionally (``grip_keep``, e.g. :data:`GRIP_KEEP_A`, the vdW cutoff and 2 Å; default
None: whole tubes, the validated setting) a coarse tube is built of only its whole cells
that reach at least ``grip_keep`` Å beyond each grip plane: the material deeper in a grip
moves rigidly with it and meets only the other tubes' rigid grips during the pull, and
every free atom still sees all its neighbours within the cutoff; the coarse tube has
about half its particles and no separate atomistic region at its open ends. Not the
default: in the set-up minimisation the atomistic tube's grip ends, which then reach past
the coarse tubes' ends, feel those ends' van der Waals pull, so the gauge starts 0.08 Å
shorter on (10,10) and the early response is softer (bundle-tension).

The tubes interact through ``tube-vdw`` (:mod:`upscale.models.tube_vdw`): the LAMMPS
references' 12-6 Lennard-Jones (``lj/cut``, eps = 2.84 meV, sigma = 3.4 Å, cut at
10.2 Å) between the atoms of different tubes, a coarse tube's atoms reconstructed from its
particles by its own lattice map and their forces pulled back through that map. The
default bundle is the seed's: the central tube atomistic with the 4-atom vacancy, the six
outer ones coarse.

Dynamic tension (the LAMMPS references' protocol, ``upscale.experiments.lammps.tension``):

1. every tube starts from the zero-stress lattice of the atomistic tube (axial and radial
   ratios of a short periodic tube relaxed at zero axial stress: the same lattice for every
   model; a coarse tube the zero-stress lattice of its own particles, relaxed open with its
   grips' lateral components held, as the single tube's pull), then the open bundle is
   minimised (L-BFGS on the atomistic tubes and the vdW, the coarse tubes held: their
   shifts are a field with inertia, which a static minimiser does not carry),
   optionally every tube, the coarse ones too, is quenched toward rest for up to
   ``settle_ps`` (default 0: none; :class:`~upscale.engine.thermostats.Quench` on the
   run's integrator), so that the coarse tubes, set up alone, start nearer equilibrium
   with the vdW of their neighbours, as the references' minimisation of the whole bundle
   leaves them;
2. grips: on every tube the material within ``grip`` Å (default 50) of the bundle's end
   atoms (a coarse tube: its rows beyond its own set-up's planes, their particles' shifts
   held), moved rigidly apart at ``speed`` Å/ps each (default 1); the free part starts on
   the linear axial velocity ramp between the grip speeds plus Gaussian thermal velocities
   at ``temperature`` (default 10 K; the x, y temperature set to it exactly, zero total
   momentum), under a Nose-Hoover chain (``chain`` long, default 3) on the free part's
   x and y velocities and the coarse tubes' shifts (damping 0.1 ps: LAMMPS ``fix nvt``
   with ``compute temp/partial 1 1 0``, whose chain is 3 long), or one per tube (``thermostat="per-tube"``). LAMMPS's single
   thermostat holds each tube at the temperature because its tubes are alike; the tubes
   of a mixed bundle are not (a coarse tube's x, y motion carries a breathing
   oscillation, its shifts take up heat), so one thermostat holds only their mean and
   the atomistic tube runs colder than the others; the one thermostat's temperature is
   that of the atoms the rows stand for (each coarse tube's kinetic energy weighted by
   its atoms' dofs over its explicit ones, :mod:`~upscale.experiments.scenes.
   bundle_thermostat`), so a crack's heat drives it as it drives the references';
   multiple time stepping (r-RESPA, ``integrator="respa"``, the default: 5 inner steps of
   1 fs) or velocity Verlet at 1 fs;
3. strain = grip separation change / initial gauge (the grip planes' distance); the stress
   of tube k is the mean of its two grips' reactions over its wall area 2 pi R t (t = 3.4 Å,
   R the mean radius of the central tube after the minimisation), the bundle stress the
   mean over the tubes (= total reaction / (ntubes 2 pi R t), the references'
   convention); each sample the mean of 10 readings over 100 steps; the run stops when the
   bundle stress has fallen below 20 % of its maximum after failure, or at ``max_strain``.

Strength, modulus and strain at peak as the references' (:func:`upscale.analysis.stress.
curve_metrics`); each tube's failure is the first drop of its own curve by more than 5 %
below its running maximum, and the order of the tubes' failure strains is the failure
sequence. Damage: per atom (atomistic tubes, mu = 1 - bonds left / bonds at the start,
< 2.0 Å at the start, broken beyond 2.1 Å), per particle (coarse tubes, the model's own).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from upscale.constants import ACC_EV_A_AMU_IN_A_FS2, CARBON_MASS_AMU
from upscale.models.dcbr.model import FIELD

__all__ = ["TubeSpec", "BundleScene", "TUBE_MODELS", "zero_stress_ratios", "add_run_options",
           "parse_specs", "reference_name", "particle_rows", "INTEGRATOR", "INNER",
           "COARSE_PAIRS", "SEED", "GRIP_KEEP_A"]

TUBE_MODELS = ("tersoff", "dcbr", "dcbr-defect")
LJ_EPSILON_EV, LJ_SIGMA_A = 2.84e-3, 3.4   # the references' pair (Girifalco et al. 2000)
LJ_CUTOFF_A = 3.0 * LJ_SIGMA_A
LATTICE_A = 1.42 * math.sqrt(3.0)           # graphene lattice constant of the builder
#: an atom's mass in the scene's units (eV, Å, fs: amu / (Å/fs^2 per eV/(Å amu)))
ATOM_MASS = CARBON_MASS_AMU / ACC_EV_A_AMU_IN_A_FS2

# The validated setting, the one place its defaults are written: :meth:`BundleScene.create`,
# ``bundle_pull.dynamic_tension``, :func:`add_run_options` (``bundle-tension``) and the scene
# function (``upscale bundle``) read them. The accuracy rows against LAMMPS's three seeds
# (``bundle-tension``) run with r-RESPA, 5 inner steps of 1 fs, under the Nose-Hoover chain
# of 3; the van der Waals between coarse tubes through their reconstructed atoms is the
# form within 1 % of the all-atomistic bundle at rest (``bundle-vdw``; lumped sites are not).
#: the pull's time stepping: "respa" (multiple time stepping) or "verlet"
INTEGRATOR = "respa"
#: 1 fs inner steps per outer step of r-RESPA
INNER = 5
#: the vdW between two coarse tubes: "atoms" (reconstructed) or "sites" (lumped particles)
COARSE_PAIRS = "atoms"
#: the thermal seed (the LAMMPS references' default seed number)
SEED = 4928459
#: material kept beyond each grip plane of a coarse tube with the optional trimming, Å
#: (module docstring): the vdW cutoff (10.2 Å) and 2 Å
GRIP_KEEP_A = LJ_CUTOFF_A + 2.0


@dataclasses.dataclass
class TubeSpec:
    """One tube of a bundle: its model, coarsening and (coarse tubes) the radius of the
    atomistic regions and half-width of the grip bands (Å); ``length`` (Å) only to check
    that all tubes agree."""

    model: str = "tersoff"
    coarsening: float = 1.0
    r_atomistic: float = 8.0
    length: float | None = None

    def __post_init__(self):
        if self.model not in TUBE_MODELS:
            raise ValueError(f"unknown tube model {self.model!r}; valid: "
                             f"{', '.join(TUBE_MODELS)}")
        if not (np.isfinite(self.coarsening) and self.coarsening >= 1.0):
            raise ValueError(f"coarsening {self.coarsening!r}; valid: a number >= 1")

    @classmethod
    def parse(cls, text: str, coarsening: float = 2.0) -> "TubeSpec":
        """``"tersoff"``, ``"dcbr"``, ``"dcbr:4"`` (model:coarsening), ``"dcbr-defect:2"``."""
        name, _, k = str(text).partition(":")
        try:
            kk = float(k) if k else (1.0 if name == "tersoff" else coarsening)
        except ValueError:
            raise ValueError(f"tube {text!r}: coarsening {k!r} is not a number; valid: "
                             "MODEL or MODEL:K, e.g. dcbr:2") from None
        return cls(name, kk)


def zero_stress_ratios(n: int, m: int, potential: str = "BNC.tersoff", cells: int | None = None,
                       ftol: float = 1e-5) -> dict:
    """Axial and radial ratios of the zero-stress atomistic tube to the builder's.

    A periodic (n, m) tube of whole cells (>= 10 Å) is minimised at fixed period (engine
    L-BFGS, Tersoff with the step cutoff) at three periods around the builder's; the
    minimum of the parabola through their energies is the zero-axial-stress period
    (LAMMPS ``fix box/relax z 0``), its mean radius (at a final minimisation there) the
    radius. Returns ``{"axial", "radial", "L0_A", "radius_A", "period_built_A"}``."""
    from upscale.build import chirality, swcnt
    from upscale.engine.minimisers import LBFGS
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import ParticleSystem
    from upscale.models.tersoff import TersoffModel

    T = chirality(n, m).cell_length
    k = cells or max(2, math.ceil(10.0 / T))  # (the builder needs two cells at least)
    probe = swcnt(n, m, k * T)
    L = probe.cell[2, 2]
    cx, cy = probe.info["axis_xy"]
    x0 = probe.get_positions() - [cx, cy, 0.0]

    def relax(lz, x_start):
        x = x_start.copy()
        x[:, 2] *= lz / L
        sim = Simulation(ParticleSystem(x, 1.0, CARBON_MASS_AMU, units="atomic"),
                         models=[TersoffModel(potential, period_z=lz)])
        sim.minimise(LBFGS(ftol=ftol, max_iter=5000))
        return sim.energy(), sim.state.y.copy()

    ratios = (0.995, 1.0, 1.005)
    ee = []
    start = x0
    for r in (1.0,):  # a first relaxation at the built period: the radius settles
        _, start = relax(L * r, x0)
    for r in ratios:
        e, _ = relax(L * r, start)
        ee.append(e)
    a, b, _ = np.polyfit(np.array(ratios) - 1.0, ee, 2)
    r0 = 1.0 - b / (2 * a)
    _, y = relax(L * r0, start)
    R = float(np.hypot(y[:, 0], y[:, 1]).mean())
    return {"axial": float(r0), "radial": R / probe.info["radius"], "L0_A": float(L * r0),
            "radius_A": R, "period_built_A": float(L), "cells": int(k)}


class BundleScene:
    """The bodies, models and interaction of a bundle (module docstring); build it with
    :meth:`create`."""

    def __init__(self, atoms, specs, bodies, assembly, vdw, maps, info):
        self.atoms, self.specs, self.bodies = atoms, specs, bodies
        self.assembly, self.vdw, self.maps, self.info = assembly, vdw, maps, info
        self.body_models = [m for m in assembly.models if m is not vdw]
        self.ntubes = len(specs)

    # ------------------------------------------------------------------ construction
    @classmethod
    def create(cls, chirality, length: float, specs, *, spacing: str = "vdw",
               gap: float = 3.4, vacancy_tube: int | None = 0, grip: float = 50.0,
               ratios: dict | None = None, centres=None, allow_overlap: bool = False,
               epsilon: float = LJ_EPSILON_EV, sigma: float = LJ_SIGMA_A,
               rc: float = LJ_CUTOFF_A, vdw_every: int = 1,
               coarse_pairs: str = COARSE_PAIRS,
               grip_keep: float | None = None) -> "BundleScene":
        """A bundle of ``len(specs)`` (n, m) tubes of ``length`` Å.

        ``specs``: one :class:`TubeSpec` (or model name) per tube, the central tube first
        (then the hexagon's vertices at 0, 60, ... degrees); ``spacing`` ``"vdw"`` (walls
        ``gap`` Å apart) or ``"seed"`` (centres 2.2 R apart); ``vacancy_tube``: the tube
        with the 4-atom vacancy (None: none; only the central tube, 0, is supported, the
        references' bundle); ``ratios``: :func:`zero_stress_ratios` (computed if None; the
        lattice every tube starts from). ``centres`` (ntubes, 2) Å overrides the hexagon
        (then the overlap check names the pair). Raises ValueError (one line) for overlapping
        tubes, tubes of different lengths, an unknown model name, a coarsening the length
        does not admit. ``vdw_every``: the vdW forces recomputed every that many steps
        (:class:`~upscale.models.tube_vdw.TubeVdW` ``every``); ``coarse_pairs``:
        ``"atoms"`` (default, :data:`COARSE_PAIRS`) or ``"sites"`` (two coarse tubes
        interact through their particles as lumped sites, the cheaper integrated form; an
        atomistic tube always sees a coarse tube's reconstructed atoms); ``grip_keep``: a
        coarse tube's whole cells kept beyond each grip plane, at least this many Å
        (module docstring; None, the default: the whole tube).
        """
        if coarse_pairs not in ("atoms", "sites"):
            raise ValueError(f"coarse_pairs={coarse_pairs!r}; valid: 'atoms' or 'sites'")
        if grip_keep is not None and not (np.isfinite(grip_keep) and grip_keep >= rc):
            raise ValueError(f"grip_keep={grip_keep!r} Å; valid: None (whole tubes) or at "
                             f"least the vdW cutoff, {rc:g} Å")
        from upscale.build import bundle, chirality as check_chirality, vacancy

        n, m = chirality
        check_chirality(n, m)
        specs = [s if isinstance(s, TubeSpec) else TubeSpec.parse(str(s)) for s in specs]
        if not 1 <= len(specs) <= 7:
            raise ValueError(f"{len(specs)} tubes; valid: 1 to 7 (the centre and the hexagon)")
        for k, s in enumerate(specs):
            if s.length is not None and abs(s.length - length) > 1e-6:
                raise ValueError(f"tube {k + 1} has length {s.length:g} Å, the bundle "
                                 f"{length:g} Å; valid: every tube of the same length")
        if vacancy_tube not in (None, 0):
            raise ValueError(f"vacancy_tube={vacancy_tube!r}; valid: 0 (the central tube) or "
                             "None")
        atoms = bundle(n, m, length, ntubes=len(specs), spacing=spacing, gap=gap)
        if centres is not None:
            c = np.asarray(centres, dtype=float)
            if c.shape != (len(specs), 2):
                raise ValueError(f"centres of shape {c.shape}; valid: ({len(specs)}, 2)")
            old = np.asarray(atoms.info["tube_centres"])
            mol = atoms.arrays["mol-id"]
            x = atoms.get_positions()
            for k in range(len(specs)):
                x[mol == k + 1, :2] += c[k] - old[k]
            atoms.set_positions(x)
            atoms.info["tube_centres"] = c.tolist()
        _check_overlap(atoms, sigma, allow_overlap)
        L = atoms.info["length"]
        L_free = L - 2.0 * grip
        if not (np.isfinite(grip) and 0.0 <= grip and L_free > 0.0):
            raise ValueError(f"grip={grip:g} Å on a {L:.1f} Å tube; valid: 0 <= grip < "
                             f"{0.5 * L:.1f} Å (half the length)")
        for k, s in enumerate(specs):
            if s.model != "tersoff":
                rows = L_free / (s.coarsening * LATTICE_A)
                if rows < 3.0:
                    kmax = L_free / (3.0 * LATTICE_A)
                    if kmax < 1.0:
                        raise ValueError(
                            f"grip={grip:g} Å leaves a {L_free:.1f} Å gauge of a {L:.1f} Å "
                            f"tube, less than the 3 particle rows of tube {k + 1}; valid: "
                            f"grip <= {0.5 * (L - 3.0 * LATTICE_A):.1f} Å")
                    raise ValueError(
                        f"tube {k + 1}: coarsening {s.coarsening:g} leaves {rows:.1f} particle "
                        f"rows in the {L_free:.1f} Å gauge of a {atoms.info['length']:.1f} Å "
                        f"tube with {grip:g} Å grips; valid: coarsening <= {kmax:.2f}")
        if vacancy_tube is not None:
            atoms = vacancy(atoms, n=4)
        ratios = ratios or zero_stress_ratios(n, m)
        built, atoms = atoms, _prescale(atoms, ratios)
        from upscale.engine.bodies import Body, assemble
        from upscale.engine.system import ParticleSystem
        from upscale.models.tersoff import TersoffModel
        from upscale.models.tube_vdw import AtomisticMap, CoarseTubeMap, TubeVdW

        mol = atoms.arrays["mol-id"]
        bodies, coarse, prepared = [], {}, {}
        z_mid = float(atoms.get_positions()[mol == 1, 2].mean())
        for k, s in enumerate(specs):
            name = f"tube{k + 1}"
            if s.model == "tersoff":
                x = atoms.get_positions()[mol == k + 1]
                bodies.append(Body(ParticleSystem(x, 1.0, ATOM_MASS, spacing=1.42,
                                                  units="atomic"),
                                   None, [TersoffModel()], name=name))
            else:
                sel = built.arrays["mol-id"] == k + 1
                tube = _trimmed(built[sel], grip, grip_keep)
                em, st = _coarse_tube(tube, s, tube.info["grip_A"], z_mid, prepared)
                coarse[k] = (em, st)
                bodies.append(Body(ParticleSystem(st["y"], 1.0, density=em.masses(),
                                                  spacing=em.tube.bond, units="atomic"),
                                   None, [em], name=name))
        assembly = assemble(bodies)
        maps = []
        for k, b in enumerate(bodies):
            rows = assembly.rows(b.name)
            if k not in coarse:
                maps.append(AtomisticMap(rows))
                continue
            bm = next(mm for mm in assembly.models if getattr(mm, "body", None) is b)
            maps.append(CoarseTubeMap(bm, field=f"{b.name}/{FIELD}"))
        sites = None
        if coarse_pairs == "sites" and coarse:
            from upscale.models.tube_vdw import LumpedMap

            sites = [LumpedMap(assembly.rows(b.name), _atoms_per_row(coarse[k][0]))
                     if k in coarse else None for k, b in enumerate(bodies)]
        vdw = TubeVdW(maps, epsilon, sigma, rc=rc, every=vdw_every, sites=sites)
        assembly.models.append(vdw)
        info = {"chirality": [n, m], "length_A": float(atoms.info["length"]),
                "spacing": spacing, "wall_gap_A": float(atoms.info["wall_gap"]),
                "ratios": ratios, "grip_A": grip, "vacancy_tube": vacancy_tube,
                "tubes": [dataclasses.asdict(s) for s in specs],
                "vdw_every": int(vdw_every), "coarse_pairs": coarse_pairs,
                "grip_keep_A": grip_keep,
                "n_atoms": len(atoms), "atoms_per_tube": np.bincount(mol)[1:].tolist()}
        scene = cls(atoms, specs, bodies, assembly, vdw, maps, info)
        scene.coarse = coarse
        return scene

    # ------------------------------------------------------------------ states
    def state_at_rest(self):
        """The assembled state at the scene's start (atomistic tubes on the zero-stress
        lattice, coarse tubes as their set-up left them) with every model prepared."""
        sim = self.assembly.simulation(conditions=self.extra_conditions())
        self.start(sim.state)
        sim.apply_displacement(0.0, None)
        return sim.state

    def start(self, state) -> None:
        """Write the coarse tubes' set-up into an assembled ``state`` (mutated): each one's
        shifts (the field of its particle rows and ``extra["<body>/dcbr.delta"]``) and its
        ghost-force load at the set-up stretch, its grips' rows holding it
        (:meth:`ghost_load`)."""
        for k, (em, st) in self.coarse.items():
            name = self.bodies[k].name
            r0, nd = self.assembly.rows(name).start, particle_rows(em)
            dof = np.arange(em.tube.N) if em.coupling is None else em.coupling.dof_idx
            state.fields[f"{name}/{FIELD}"][r0:r0 + nd] = st["delta"][dof]
            state.extra[f"{name}/{FIELD}"][...] = st["delta"]
        self.ghost_load(state, 0.0)

    def ghost_load(self, state, strain: float, held: dict | None = None) -> None:
        """Ask every coarse tube for its ghost-force dead load (``state.extra``
        ``"<body>/dcbr.ghost"``, ``"<body>/dcbr.ghost_hold"``, which the model follows:
        :meth:`~upscale.models.dcbr.model.DCBRModel.stretch_ghost`) at the axial stretch
        lam_z0 (1 + ``strain``) of its gauge, the rows ``held[k]`` (n,) bool of tube k (its
        grips; default: the rows beyond its set-up's planes) at the set-up stretch lam_z0
        (the single tube's pull)."""
        for k, (em, st) in self.coarse.items():
            if not st["ghost"]:
                continue
            name, lam0 = self.bodies[k].name, st["lam_z0"]
            hold = st["bottom"] | st["top"] if held is None else held[k]
            state.extra[f"{name}/dcbr.ghost"] = np.array([lam0 * (1.0 + strain), lam0])
            state.extra[f"{name}/dcbr.ghost_hold"] = np.asarray(hold, bool).copy()

    def atoms_at_rest(self):
        """The bundle's ase.Atoms at the scene's starting lattice, open boundaries (for
        LAMMPS); ``arrays["mol-id"]`` = tube."""
        a = self.atoms.copy()
        a.pbc = False
        return a

    def lumped_vdw(self):
        """``tube-vdw`` with the coarse tubes as lumped sites (the integrated form's simplest
        variant: each particle a site of the atoms it carries), for comparison."""
        from upscale.models.tube_vdw import LumpedMap, TubeVdW

        maps = []
        for k, (mp, b) in enumerate(zip(self.maps, self.bodies)):
            if self.specs[k].model == "tersoff":
                maps.append(mp)
            else:
                maps.append(LumpedMap(self.assembly.rows(b.name),
                                      _atoms_per_row(self.coarse[k][0])))
        v = TubeVdW(maps, self.vdw.eps, self.vdw.sigma, rc=self.vdw.rc)
        v.prepare(self.assembly.system)
        return v

    def extra_conditions(self) -> list:
        """The conditions the bodies' models need themselves (none: a coarse tube's slave
        particles are no rows of the new model)."""
        return []

    @property
    def dof(self) -> int:
        """Degrees of freedom: 3 per atom of an atomistic tube; a coarse tube's rows
        (non-slave particles and free atoms, 3 each) and its particle rows' shifts (3 each)."""
        total = 0
        for k, b in enumerate(self.bodies):
            total += 3 * b.system.n
            if k in self.coarse:
                total += 3 * particle_rows(self.coarse[k][0])
        return total

    def coarse_models(self):
        """``[(tube index, BodyModel, set-up dict)]`` of the coarse tubes."""
        out = []
        for k, (em, st) in self.coarse.items():
            bm = next(mm for mm in self.assembly.models if getattr(mm, "model", None) is em)
            out.append((k, bm, st))
        return out


def _check_overlap(atoms, sigma, allow):
    """Tubes whose nearest atoms are closer than sigma / 2 (where the LJ repulsion of one
    pair exceeds 45 eV, more than a covalent bond's energy) overlap."""
    from scipy.spatial import cKDTree

    mol = atoms.arrays["mol-id"]
    x = atoms.get_positions()
    lim = 0.5 * sigma
    ids = np.unique(mol)
    trees = {k: cKDTree(x[mol == k]) for k in ids}
    for a in ids:
        for b in ids[ids > a]:
            d, _ = trees[a].query(x[mol == b], k=1, distance_upper_bound=2 * sigma)
            dmin = float(np.min(d))
            if dmin < lim and not allow:
                raise ValueError(f"tubes {a} and {b} overlap: nearest atoms {dmin:.3f} Å apart, "
                                 f"inside the repulsive wall of the van der Waals pair "
                                 f"(< sigma/2 = {lim:.2f} Å); valid: walls further apart "
                                 "(e.g. spacing 'vdw', gap 3.4 Å)")


def _prescale(atoms, ratios):
    """Positions scaled to the zero-stress lattice: z by ``axial``, about each tube's axis
    by ``radial``."""
    out = atoms.copy()
    x = out.get_positions()
    mol = out.arrays["mol-id"]
    centres = np.asarray(out.info["tube_centres"])
    for k, c in enumerate(centres):
        sel = mol == k + 1
        x[sel, :2] = c + (x[sel, :2] - c) * ratios["radial"]
    x[:, 2] *= ratios["axial"]
    out.set_positions(x)
    out.info["length"] = float(out.info["length"]) * ratios["axial"]
    return out


def particle_rows(model) -> int:
    """The particle rows of a coarse tube's state (all its particles, or its coupling's
    non-slave ones; the free atoms' rows follow)."""
    c = model.coupling
    return model.tube.N if c is None else len(c.dof_idx)


def _atoms_per_row(model):
    """Atoms each row of a coarse tube stands for: a particle row its weight w_c, an atom
    row 1 (a slave particle's weight, on no row, is left out)."""
    c = model.coupling
    if c is None:
        return np.asarray(model.tube.natoms_n, dtype=float)
    return np.r_[np.asarray(model.tube.natoms_n, dtype=float)[c.dof_idx], np.ones(c.nf)]


def _trimmed(tube_atoms, grip, keep):
    """One tube of :func:`upscale.build.bundle` (whole cells from z = 0, ``info``
    ``unit_cell_length`` and ``length``) without the whole cells lying more than ``keep`` Å
    beyond its grip planes (``grip`` Å inside its ends); ``keep`` None: the tube itself.
    ``info["grip_A"]``: the grip of the trimmed tube (its planes where the whole tube's
    were)."""
    out = tube_atoms.copy()
    out.info["grip_A"] = float(grip)
    if keep is None:
        return out
    T = float(tube_atoms.info["unit_cell_length"])
    cut = int(math.floor((grip - keep) / T + 1e-9))
    if cut <= 0:
        return out
    z = tube_atoms.positions[:, 2]
    L = float(tube_atoms.info["length"])
    out = tube_atoms[(z >= cut * T - 1e-6) & (z < L - cut * T - 1e-6)]
    out.info["grip_A"] = float(grip - cut * T)
    return out


def _coarse_tube(tube_atoms, spec, grip, z_mid, prepared):
    """A coarse tube of the bundle: :class:`~upscale.models.dcbr.model.DCBRModel` of
    ``tube_atoms`` (one tube of :func:`upscale.build.bundle` as built, :func:`_trimmed`,
    opened), set up by
    :func:`~upscale.experiments.scenes.tube_coarse_pull.setup_open_tube` (bands across the
    grip planes, regions at its defects, relaxed open), its atoms' axial middle moved to
    ``z_mid`` (the atomistic centre tube's). Returns (the model with inertial shifts, the
    set-up dict: ``y`` (n, 3), ``delta`` (N, 3), ``bottom``/``top`` (n,) grip rows,
    ``gauge``, ``lam_z0``, ``ghost``, ...).

    Tubes alike up to a translation are set up once (``prepared``): the set-up is moved
    to each, whose model is built from its own atoms (the ghost load and the lattice map
    act about its own axis) and must have the same rows (a tie broken otherwise by
    round-off would change them; then it is set up itself)."""
    from upscale.engine.state import State
    from upscale.experiments.scenes.tube_coarse_pull import open_tube, setup_open_tube
    from upscale.models.dcbr.model import DCBRModel

    a = open_tube(tube_atoms)
    K, r_at = spec.coarsening, spec.r_atomistic
    kw = dict(shifts="inertial", failure=False, stability=False, r_atomistic=r_at)
    key = (len(a), K, r_at, grip)  # (the atoms themselves are compared below)
    if key not in prepared:
        st = setup_open_tube(a, K, grip=grip, r_atomistic=r_at)
        em = DCBRModel(st["atoms"], K, select=st["select"], **kw)
        s0 = State.reference(st["y"].copy(), 0)
        em.init_state(s0)
        s0.extra[FIELD][...] = st["delta"]
        dz = z_mid - float(em.atom_positions(s0)[:, 2].mean())
        prepared[key] = (st, em.x0.copy(), a.positions.copy(), dz)
    st, x0, X0, dz = prepared[key]
    mean0 = X0.mean(axis=0)
    # this tube's atoms moved along the axis so that its middle lands where the prepared
    # tube's lands (z_mid); its set-up moved from the prepared tube's place to its own
    mk = a.positions.mean(axis=0)
    a.positions[:, 2] += dz + mean0[2] - mk[2]
    move = np.array([mk[0] - mean0[0], mk[1] - mean0[1], dz])
    if np.allclose(a.positions, X0 + move, rtol=0.0, atol=1e-9):
        em = DCBRModel(a, K, select=st["select"], **kw)
        if em.x0.shape == x0.shape and np.allclose(em.x0, x0 + move, rtol=0.0, atol=1e-9):
            return em, dict(st, atoms=a, y=st["y"] + move)
    st = setup_open_tube(a, K, grip=grip, r_atomistic=r_at)
    return DCBRModel(st["atoms"], K, select=st["select"], **kw), st


def add_run_options(p) -> None:
    """The options of a dynamic bundle run shared by ``upscale bundle`` and the validation
    case ``bundle-tension``: overlap, vdW schedule, coarse pairs, strain, time stepping,
    thermostat."""
    p.add_argument("--allow-overlap", action="store_true",
                   help="run tubes closer than the van der Waals wall (the seed's hexagon)")
    p.add_argument("--max-strain", type=float, default=0.40,
                   help="stop the pull at this strain (default 0.40, the references')")
    p.add_argument("--integrator", choices=("verlet", "respa"), default=INTEGRATOR,
                   help="multiple time stepping (respa: the vdW at an outer step of "
                   "--inner fs) or velocity Verlet at 1 fs "
                   f"(default {INTEGRATOR})")
    p.add_argument("--inner", type=int, default=INNER,
                   help=f"1 fs inner steps per outer step with respa: 1, 2, 5, 10 (default "
                   f"{INNER})")
    p.add_argument("--thermostat", choices=("bundle", "per-tube"), default="bundle",
                   help="one Nose-Hoover on all tubes' free parts (default) or one per tube")
    p.add_argument("--chain", type=int, default=3,
                   help="Nose-Hoover chain length (default 3, LAMMPS's fix nvt; 1 = one "
                   "thermostat variable)")
    p.add_argument("--settle", type=float, default=0.0,
                   help="ps of quench of every tube (the coarse ones too) after the set-up "
                   "minimisation, before the pull (default 0: the coarse tubes as set up)")
    p.add_argument("--coarse-pairs", choices=("atoms", "sites"), default=COARSE_PAIRS,
                   help="two coarse tubes interact through reconstructed atoms or through "
                   f"their particles as lumped sites (default {COARSE_PAIRS})")
    p.add_argument("--vdw-every", type=int, default=1,
                   help="vdW forces recomputed every N steps, held in between (velocity "
                   "Verlet only; default 1)")


# ---------------------------------------------------------------------- names
def parse_specs(tubes, ntubes, coarsening):
    """The tubes' specs: ``tubes`` a comma list (``"tersoff,dcbr:2"``, centre first), or
    None (or empty) for the atomistic centre and ``ntubes - 1`` coarse tubes ``dcbr:K``."""
    if not tubes:
        if not (isinstance(ntubes, (int, np.integer)) and 2 <= ntubes <= 7):
            raise ValueError(f"ntubes={ntubes!r}; valid: 2 to 7 (the centre and the hexagon)")
        return [TubeSpec("tersoff")] + [TubeSpec("dcbr", coarsening)] * (ntubes - 1)
    return [TubeSpec.parse(t.strip(), coarsening) for t in str(tubes).split(",")]


def reference_name(chirality, spacing="vdw", vacancy=True, ntubes=7, seed=None) -> str:
    """The name of the stored LAMMPS bundle reference (``data/reference/<name>.json``,
    ``reference-tension --bundle``); ``seed`` None for the references' default seed."""
    n, m = chirality
    name = f"dyn_{n}-{m}_{'vac4' if vacancy else 'pristine'}_bundle{ntubes}"
    if spacing == "seed":
        name += "_hex"
    if seed is not None:
        name += f"_s{seed}"
    return name

