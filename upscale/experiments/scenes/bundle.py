"""A bundle of tubes, each with its own model, coupled by van der Waals forces and pulled in
dynamic tension (seed 004 sec. 5.3.2): the scene's parts. The scene function
``experiments.bundle`` (``upscale bundle``, :mod:`upscale.experiments.scenes.bundle_scene`)
builds a :class:`BundleScene`, runs :func:`dynamic_tension` and returns a Result.

    upscale bundle --chirality 10,10 --coarsening 2 [--compare lammps]

The scene (:class:`BundleScene`) puts every tube of :func:`upscale.build.bundle` (a central
tube and up to six around it) on the engine as its own body (:mod:`upscale.engine.bodies`):

* ``tersoff``: the atomistic tube, every atom a particle (:mod:`upscale.models.tersoff`);
* ``dcbr``: the coarse open tube at coarsening K (its engine model, the lattice carried by
  particles K lattice constants apart);
* ``dcbr-defect``: the coarse tube with an atomistic region of radius ``r_atomistic`` around
  the vacancy.

The tubes interact through ``tube-vdw`` (:mod:`upscale.models.tube_vdw`): the LAMMPS
references' 12-6 Lennard-Jones (``lj/cut``, eps = 2.84 meV, sigma = 3.4 Å, cut at
10.2 Å) between the atoms of different tubes, a coarse tube's atoms reconstructed from its
particles by its own lattice map and their forces pulled back through that map. The
default bundle is the seed's: the central tube atomistic with the 4-atom vacancy, the six
outer ones coarse.

Dynamic tension (the LAMMPS references' protocol, ``upscale.experiments.lammps.tension``):

1. every tube starts from the zero-stress lattice of the atomistic tube (axial and radial
   ratios of a short periodic tube relaxed at zero axial stress: the same lattice for every
   model), then the open bundle is minimised (L-BFGS on the atomistic tubes and the vdW,
   the coarse tubes held: a static minimiser does not carry their slave ties and shifts),
   optionally every tube, the coarse ones too, is quenched toward rest for up to
   ``settle_ps`` (default 0: none; :class:`~upscale.engine.thermostats.Quench` on the
   run's integrator), so that the coarse tubes, set up alone, start nearer equilibrium
   with the vdW of their neighbours, as the references' minimisation of the whole bundle
   leaves them;
2. grips: on every tube the material within ``grip`` Å (default 50) of the bundle's end
   atoms, moved rigidly apart at ``speed`` Å/ps each (default 1); the free part starts on
   the linear axial velocity ramp between the grip speeds plus Gaussian thermal velocities
   at ``temperature`` (default 10 K; the x, y temperature set to it exactly, zero total
   momentum), under a Nose-Hoover chain (``chain`` long, default 3) on the free part's
   x and y velocities and the coarse tubes' shifts (damping 0.1 ps: LAMMPS ``fix nvt``
   with ``compute temp/partial 1 1 0``, whose chain is 3 long), or one per tube (``thermostat="per-tube"``). LAMMPS's single
   thermostat holds each tube at the temperature because its tubes are alike; the tubes
   of a mixed bundle are not (a coarse tube's x, y motion carries a breathing
   oscillation, its shifts take up heat), so one thermostat holds only their mean and
   the atomistic tube runs colder than the others; multiple time stepping (r-RESPA,
   ``integrator="respa"``, the default: 5 inner steps of 1 fs) or velocity Verlet at 1 fs;
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
import time

import numpy as np

from upscale.analysis.plots import save_figure
from upscale.constants import ACC_EV_A_AMU_IN_A_FS2, CARBON_MASS_AMU, K_B_EV, WALL_THICKNESS_A

__all__ = ["TubeSpec", "BundleScene", "TUBE_MODELS", "dynamic_tension", "zero_stress_ratios",
           "check_run_options", "add_run_options", "parse_specs", "reference_name",
           "tube_failures", "INTEGRATOR", "INNER", "COARSE_PAIRS", "SEED"]

TUBE_MODELS = ("tersoff", "dcbr", "dcbr-defect")
LJ_EPSILON_EV, LJ_SIGMA_A = 2.84e-3, 3.4   # the references' pair (Girifalco et al. 2000)
LJ_CUTOFF_A = 3.0 * LJ_SIGMA_A
LATTICE_A = 1.42 * math.sqrt(3.0)           # graphene lattice constant of the builder
#: half-width (Å) of the atomistic band of a pristine coarse tube (``dcbr``): the coarse
#: tube model carries one; 1 Å rounds out to one row of whole particle cells
PRISTINE_BAND_A = 1.0
#: an atom's mass in the scene's units (eV, Å, fs: amu / (Å/fs^2 per eV/(Å amu)))
ATOM_MASS = CARBON_MASS_AMU / ACC_EV_A_AMU_IN_A_FS2

# The validated setting, the one place its defaults are written: :meth:`BundleScene.create`,
# :func:`dynamic_tension`, :func:`add_run_options` (``bundle-tension``) and the scene
# function (``upscale bundle``) read them. validation/results/bundle.md: the accuracy rows
# against LAMMPS's three seeds under the Nose-Hoover chain of 3 (the default chain; (10,10)
# +3.19 / -1.10 / +5.97 %, (7,13) +1.76 / +2.30 / -1.22 % in strength / modulus / strain at
# peak, and K = 1-4) ran with r-RESPA, 5 inner steps of 1 fs; the van der Waals between
# coarse tubes through their reconstructed atoms is the form within 1 % of the all-atomistic
# bundle at rest (2.0e-4; lumped sites between coarse tubes: 4.3e-2).
#: the pull's time stepping: "respa" (multiple time stepping) or "verlet"
INTEGRATOR = "respa"
#: 1 fs inner steps per outer step of r-RESPA
INNER = 5
#: the vdW between two coarse tubes: "atoms" (reconstructed) or "sites" (lumped particles)
COARSE_PAIRS = "atoms"
#: the thermal seed (the LAMMPS references' default seed number)
SEED = 4928459


@dataclasses.dataclass
class TubeSpec:
    """One tube of a bundle: its model, coarsening and (``dcbr-defect``) the radius of the
    atomistic region; ``length`` (Å) only to check that all tubes agree."""

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
               coarse_pairs: str = COARSE_PAIRS) -> "BundleScene":
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
        atomistic tube always sees a coarse tube's reconstructed atoms).
        """
        if coarse_pairs not in ("atoms", "sites"):
            raise ValueError(f"coarse_pairs={coarse_pairs!r}; valid: 'atoms' or 'sites'")
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
        atoms = _prescale(atoms, ratios)
        from upscale.engine.bodies import Body, assemble
        from upscale.engine.system import ParticleSystem
        from upscale.models.tersoff import TersoffModel
        from upscale.models.tube_vdw import AtomisticMap, TubeVdW

        from upscale.models.tube_vdw import CoarseTubeMap

        mol = atoms.arrays["mol-id"]
        bodies, coarse, prepared = [], {}, {}
        zc_all = float(atoms.get_positions()[mol == 1, 2].mean())
        for k, s in enumerate(specs):
            name = f"tube{k + 1}"
            if s.model == "tersoff":
                x = atoms.get_positions()[mol == k + 1]
                bodies.append(Body(ParticleSystem(x, 1.0, ATOM_MASS, spacing=1.42,
                                                  units="atomic"),
                                   None, [TersoffModel()], name=name))
            else:
                c = np.asarray(atoms.info["tube_centres"][k], dtype=float)
                em, st = _coarse_model((n, m), length, s,
                                       vacancy_tube == k, grip, c, zc_all, prepared)
                coarse[k] = (em, st)
                bodies.append(em.body(name))
        assembly = assemble(bodies)
        maps, conds = [], []
        for k, b in enumerate(bodies):
            rows = assembly.rows(b.name)
            if k not in coarse:
                maps.append(AtomisticMap(rows))
                continue
            em, st = coarse[k]
            bm = next(mm for mm in assembly.models if getattr(mm, "body", None) is b)
            natoms = int(len(em.tube.X_atoms) - em.tube.removed.sum())
            maps.append(CoarseTubeMap(bm, natoms, field=f"{b.name}/{_FIELD}"))
            conds += em.conditions(assembly.system.n, rows.start, field=f"{b.name}/{_FIELD}",
                                   prefix=f"{b.name} ")
        sites = None
        if coarse_pairs == "sites" and coarse:
            from upscale.models.tube_vdw import LumpedMap

            sites = [LumpedMap(assembly.rows(b.name), _atoms_per_particle(b))
                     if k in coarse else None for k, b in enumerate(bodies)]
        vdw = TubeVdW(maps, epsilon, sigma, rc=rc, every=vdw_every, sites=sites)
        assembly.models.append(vdw)
        info = {"chirality": [n, m], "length_A": float(atoms.info["length"]),
                "spacing": spacing, "wall_gap_A": float(atoms.info["wall_gap"]),
                "ratios": ratios, "grip_A": grip, "vacancy_tube": vacancy_tube,
                "tubes": [dataclasses.asdict(s) for s in specs],
                "vdw_every": int(vdw_every), "coarse_pairs": coarse_pairs,
                "n_atoms": len(atoms), "atoms_per_tube": np.bincount(mol)[1:].tolist()}
        scene = cls(atoms, specs, bodies, assembly, vdw, maps, info)
        scene.conditions, scene.coarse = conds, coarse
        return scene

    # ------------------------------------------------------------------ states
    def state_at_rest(self):
        """The assembled state at the scene's start (atomistic tubes on the zero-stress
        lattice, coarse tubes as their set-up left them) with every model prepared."""
        sim = self.assembly.simulation(conditions=self.extra_conditions())
        sim.apply_displacement(0.0, None)
        return sim.state

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
                maps.append(LumpedMap(self.assembly.rows(b.name), _atoms_per_particle(b)))
        v = TubeVdW(maps, self.vdw.eps, self.vdw.sigma, rc=self.vdw.rc)
        v.prepare(self.assembly.system)
        return v

    def extra_conditions(self) -> list:
        """The conditions the bodies' models need themselves (e.g. a coarse tube's ties)."""
        return list(getattr(self, "conditions", []))

    @property
    def dof(self) -> int:
        """Degrees of freedom: 3 per atom of an atomistic tube; a coarse tube's unknowns
        (non-slave particles and free atoms, 3 each) and its particles' shifts (3 each)."""
        total = 0
        for k, b in enumerate(self.bodies):
            if k in self.coarse:
                em = self.coarse[k][0]
                total += 3 * (em.nd + em.nf) + 3 * em.N
            else:
                total += 3 * b.system.n
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


def _atoms_per_particle(body):
    em = body.models[0]
    return np.r_[np.asarray(em.tube.natoms_n, dtype=float), np.ones(em.nf)]


_FIELD = "dcbr.delta"  # the coarse tube model's shift field (upscale.models.dcbr_engine)


def _coarse_model(chirality, length, spec, has_vacancy, grip, centre, z_mid, prepared):
    """A coarse tube (``DCBRDefectTube``: ``dcbr`` a pristine tube whose atomistic region is
    one row of particle cells in the middle, ``dcbr-defect`` the 4-atom vacancy with a
    region of ``spec.r_atomistic``), opened and relaxed with clamped grips in its own frame
    (:func:`upscale.experiments.scenes.dcbr_dynamic.open_tube_with_grips`), then placed with its axis
    on ``centre`` and its middle at ``z_mid``, as an engine model. Identical tubes are set
    up once (``prepared``) and copied."""
    import copy

    from upscale.models.dcbr_defect import DCBRDefectTube
    from upscale.experiments.scenes.dcbr_dynamic import open_tube_with_grips
    from upscale.models.dcbr_engine import DCBRDefectTubeModel

    n, m = chirality
    defect = spec.model == "dcbr-defect"
    vac = 4 if (defect and has_vacancy) else 0
    r_at = spec.r_atomistic if defect else PRISTINE_BAND_A
    key = (n, m, round(length, 6), spec.coarsening, vac, r_at, grip)
    if key not in prepared:
        tube = DCBRDefectTube(n, m, length, coarsening=spec.coarsening, vacancy=vac,
                              r_atomistic=r_at)
        st = open_tube_with_grips(tube, grip=grip, clamp=True)
        prepared[key] = (tube, st)
    tube, st = copy.deepcopy(prepared[key])
    y = st["y"].copy()
    shift = np.array([centre[0], centre[1], 0.0])
    nd = len(tube.dof_idx)
    xa = np.vstack([y[nd:], tube.mapped_atoms(y, st["delta"], st["L0"], tube.atom_map())])
    shift[2] = z_mid - float(xa[:, 2].mean())  # its atoms' middle on the central tube's
    em = DCBRDefectTubeModel(tube, y=y + shift, delta=st["delta"], Lz=st["L0"])
    st = dict(st, shift=shift)
    return em, st


# ---------------------------------------------------------------------- dynamic tension
def dynamic_tension(scene: BundleScene, *, grip: float | None = None, speed: float = 1.0,
                    temperature: float = 10.0, dt_fs: float = 1.0, tdamp_ps: float = 0.1,
                    max_strain: float = 0.40, seed: int = SEED, sample_every: int = 100,
                    ftol: float = 1e-2, progress: bool = True, max_steps: int = 200000,
                    snapshot_every: int = 500, integrator: str = INTEGRATOR,
                    inner: int = INNER, record_readings: bool = False,
                    thermostat: str = "bundle",
                    per_tube_damping_ps: float | None = None,
                    settle_ps: float = 0.0, chain: int = 3) -> dict:
    """The references' dynamic tension of ``scene`` (module docstring). Returns the result
    dict: ``curve`` (strain, stress_GPa, stress_per_tube_GPa, time_ps), metrics, per-tube
    failure strains and order, damage per tube, timings.

    ``integrator="respa"`` (default, :data:`INTEGRATOR`, ``inner`` :data:`INNER`): multiple
    time stepping (:class:`upscale.engine.respa.RESPA`), outer step ``inner * dt_fs``:
    slow are the coarse tubes' lattice energies (their shift modes and the atomistic
    regions are fast, :meth:`~upscale.models.dcbr_engine.DCBRDefectTubeModel.prepare_split`,
    renewed every sample) and the inter-tube van der Waals; fast the atomistic tubes
    (Tersoff) at ``dt_fs``. ``inner`` must divide 10 (the grips are read every 10 fs
    steps) and the scene's vdW must not be held between steps (``vdw_every=1``).
    ``"verlet"``: velocity Verlet at ``dt_fs``.
    ``thermostat``: ``"bundle"`` (default; one Nose-Hoover on every tube's free part, the
    references' ``fix nvt`` on all free atoms) or ``"per-tube"`` (one per tube, each on
    its own free rows and shifts, damping ``per_tube_damping_ps``, default
    ``tdamp_ps * sqrt(ntubes)``: each tube's own heat then drives its thermostat as
    strongly as a tube's heat drives the one thermostat of ``ntubes`` like tubes). ``record_readings``: keep every grip reading (``curve["readings"]``: time in fs and
    each tube's tension in eV/Å, every 10 fs) besides the sample means."""
    from tqdm.auto import tqdm

    from upscale.analysis.stress import curve_metrics, stress_from_force
    from upscale.engine.conditions import Grip, Region
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.minimisers import LBFGS

    check_run_options(integrator=integrator, inner=inner, thermostat=thermostat, chain=chain,
                      settle_ps=settle_ps, max_strain=max_strain, speed=speed, dt_fs=dt_fs,
                      sample_every=sample_every, vdw_every=int(scene.info.get("vdw_every", 1)))
    per = int(inner) if integrator == "respa" else 1
    t0 = time.perf_counter()
    c0 = time.process_time()
    grip = scene.info["grip_A"] if grip is None else float(grip)
    asm = scene.assembly
    system = asm.system
    n = system.n
    coarse = scene.coarse_models()
    # 1. the open bundle minimised: the atomistic tubes and the vdW (the coarse tubes were
    # relaxed with their clamped grips at set-up, and are held here: their slave ties are
    # kinematic conditions a minimiser does not carry along)
    from upscale.engine.conditions import Fixed

    hold = np.zeros(n, bool)
    for k, bm, st in coarse:
        hold[bm.rows] = True
    conds0 = list(scene.extra_conditions())
    if hold.any():
        conds0.append(Fixed(Region("coarse tubes", hold)))
    sim0 = asm.simulation(conditions=conds0)
    t_min0 = time.perf_counter()
    res_min = sim0.minimise(LBFGS(ftol=ftol, max_iter=500), raise_on_fail=False) \
        if not hold.all() else None
    settle = None
    if coarse and settle_ps > 0:
        # ... then every tube together, the coarse ones too, by the molecular-dynamics
        # quench (their slave ties and shifts move as in the run): the start in equilibrium
        # with the vdW that the references' minimisation of the whole bundle gives
        sim0, settle = _settle(asm, scene, sim0, dt_fs, settle_ps, ftol, per)
    t_min = time.perf_counter() - t_min0
    y = sim0.state.y.copy()
    # grips: the atomistic tubes' atoms beyond a plane `grip` inside the bundle's end atoms
    # (LAMMPS's), the coarse tubes' rows their own set-up clamped
    atomistic = np.ones(n, bool)
    atomistic[hold] = False
    za = y[atomistic, 2] if atomistic.any() else y[:, 2]
    zmin, zmax = float(za.min()), float(za.max())
    zb, zt = zmin + grip, zmax - grip
    sep0 = zt - zb
    if sep0 < 10.0:
        raise ValueError(f"grip={grip} Å leaves a gauge of {sep0:.2f} Å; valid: 2 grip <= "
                         "L - 10 Å")
    # the curve's metrics need three samples: sample k sits at strain (k - 1/2) p, p the strain
    # of `sample_every` steps, and the run ends with the first sample past max_strain
    per_sample = 2.0 * speed * sample_every * dt_fs * 1e-3 / sep0
    if max_strain < 1.5 * per_sample:
        raise ValueError(f"max_strain={max_strain:g} gives fewer than 3 samples of the curve "
                         f"(one every {per_sample:.3g} strain); valid: max_strain >= "
                         f"{1.5 * per_sample:.3g}, or a smaller sample_every")
    v = speed * 1e-3                        # Å/fs (the scene's time unit is the fs)
    dt = float(dt_fs)
    tubes = [asm.rows(b.name) for b in scene.bodies]
    coarse_of = {k: (bm, st) for k, bm, st in coarse}
    grips, bot_mask, top_mask = [], np.zeros(n, bool), np.zeros(n, bool)
    slave = np.zeros(n, bool)
    for k, rows in enumerate(tubes):
        b, t = np.zeros(n, bool), np.zeros(n, bool)
        if k in coarse_of:
            bm, st = coarse_of[k]
            em = bm.model
            b[rows.start + em.y_rows[st["bottom"]]] = True
            t[rows.start + em.y_rows[st["top"]]] = True
            slave[rows.start + em.tube.slave_idx] = True
        else:
            zk = np.zeros(n, bool)
            zk[rows] = True
            b = zk & (y[:, 2] < zb)
            t = zk & (y[:, 2] > zt)
        bot_mask |= b
        top_mask |= t
        gb = Grip(Region(f"bot{k + 1}", b), velocity=(0.0, 0.0, -v), record_every=0)
        gt = Grip(Region(f"top{k + 1}", t), velocity=(0.0, 0.0, v), record_every=0)
        grips.append((gb, gt))
    free = ~(bot_mask | top_mask)
    # the grips' prescribed path starts where the minimisation left them: u0 = y - x0
    x0 = system.x0
    for gb, gt in grips:
        for g, vz in ((gb, -v), (gt, v)):
            idx = g.region.index
            u0 = (y[idx] - x0[idx])
            g.value = (lambda t, _u=u0, _v=vz: _u + np.array([0.0, 0.0, _v]) * t)
    # 2. velocities: ramp + Gaussian thermal (x, y temperature exactly T, zero momentum);
    # the coarse tubes' shifts thermal too (their reduced masses), slaves follow their atoms
    rng = np.random.default_rng(seed)
    mass = system.mass
    vel = np.zeros((n, 3))
    moving = free & ~slave
    fields = [f"{scene.bodies[k].name}/{_FIELD}" for k in coarse_of]
    field_v = {}
    if temperature > 0:
        vel[moving] = rng.normal(size=(int(moving.sum()), 3)) * np.sqrt(
            K_B_EV * temperature / mass[moving])[:, None]
        p = (mass[moving, None] * vel[moving]).sum(axis=0) / mass[moving].sum()
        vel[moving] -= p
        Txy = (mass[moving, None] * vel[moving, :2] ** 2).sum() / (2 * moving.sum() * K_B_EV)
        vel[moving] *= math.sqrt(temperature / Txy)
        for k, (bm, st) in coarse_of.items():
            em = bm.model
            md = em.fields()[_FIELD].inertia[:em.N]
            vd = np.zeros((n, 3))
            r0 = tubes[k].start
            vd[r0:r0 + em.N] = rng.normal(size=(em.N, 3)) * np.sqrt(
                K_B_EV * temperature / md)[:, None]
            vd[r0 + em.tube.slave_idx] = 0.0
            field_v[f"{scene.bodies[k].name}/{_FIELD}"] = vd
    vel[free, 2] += np.clip(-v + 2 * v * (y[free, 2] - zb) / sep0, -v, v)
    vel[bot_mask, 2] = -v
    vel[top_mask, 2] = v
    conds = [g for pair in grips for g in pair]
    conds += scene.extra_conditions()
    thermo = None
    tau_tube = tdamp_ps
    if temperature > 0:
        from upscale.engine.thermostats import NoseHooverChain

        # degrees of freedom: x, y of the moving rows, and the coarse tubes' free shifts
        ndf = 2 * int(moving.sum()) + sum(3 * (bm.model.N - len(bm.model.tube.slave_idx))
                                          for bm, _ in coarse_of.values())
        frows = np.zeros(n, bool)
        for k in coarse_of:
            frows[tubes[k]] = True
        if thermostat == "bundle":
            thermo = NoseHooverChain(temperature, 1e3 * tdamp_ps, region=free, chain=chain,
                                     components=(0, 1), fields=tuple(fields),
                                     field_region=frows if fields else None, ndf=ndf,
                                     k_B=K_B_EV)
        else:  # one per tube, each on its own free rows (and shifts)
            from upscale.engine.thermostats import ThermostatGroup

            members = []
            tau_tube = tdamp_ps * math.sqrt(len(tubes)) if per_tube_damping_ps is None \
                else float(per_tube_damping_ps)
            for k, rows in enumerate(tubes):
                mk = np.zeros(n, bool)
                mk[rows] = True
                nk = 2 * int((moving & mk).sum())
                fk = ()
                if k in coarse_of:
                    em = coarse_of[k][0].model
                    nk += 3 * (em.N - len(em.tube.slave_idx))
                    fk = (f"{scene.bodies[k].name}/{_FIELD}",)
                members.append(NoseHooverChain(temperature, 1e3 * tau_tube, region=free & mk,
                                               chain=chain, components=(0, 1), fields=fk,
                                               field_region=mk if fk else None, ndf=nk,
                                               k_B=K_B_EV))
            thermo = ThermostatGroup(members)
    if integrator == "respa":
        from upscale.engine.respa import RESPA

        integ = RESPA(dt * per, per, thermostat=thermo, force=True)
    else:
        integ = VelocityVerlet(dt, force=True, thermostat=thermo)
    sim = asm.simulation(conditions=conds, integrator=integ)
    # (a multiple-time-step integrator keeps its own group forces and renews the split)
    update_forces = getattr(integ, "update_forces", None) or (lambda s: s.update_forces())
    sim.state.y[...] = y
    sim.state.v[...] = vel
    _copy_fields(sim0.state, sim.state)
    for key, vd in field_v.items():
        sim.state.field_v[key][...] = vd
    for k, bm, st in coarse:  # slaves' velocities from their atoms
        em = bm.model
        r0 = tubes[k].start
        if len(em.tube.slave_idx):
            atoms_v = sim.state.v[r0 + em.N:r0 + em.N + em.nf]
            sim.state.v[r0 + em.tube.slave_idx] = em.tube.Phi @ atoms_v
    R = _central_radius(scene, y)
    # per-tube kinetic temperature of the x, y motion of the moving rows (eq. (1) of
    # upscale.engine.thermostats) and of the coarse tubes' free shifts, for the record
    t_rows = [np.flatnonzero(moving[r]) + r.start for r in tubes]
    t_mass = [mass[i, None] for i in t_rows]
    t_shift = {}
    for k, (bm, st) in coarse_of.items():
        em = bm.model
        keep = np.ones(em.N, bool)
        keep[em.tube.slave_idx] = False
        idx = np.flatnonzero(keep)
        t_shift[k] = (f"{scene.bodies[k].name}/{_FIELD}", tubes[k].start + idx,
                      em.fields()[_FIELD].inertia[idx, None])

    def tube_temperatures():
        out = []
        for k in range(len(tubes)):
            vv = sim.state.v[t_rows[k], :2]
            txy = float(np.sum(t_mass[k] * vv * vv)) / (2 * max(len(t_rows[k]), 1) * K_B_EV)
            tsh = None
            if k in t_shift:
                f, i, inert = t_shift[k]
                fv = sim.state.field_v[f][i]
                tsh = float(np.sum(inert * fv * fv)) / (3 * len(i) * K_B_EV)
            out.append((txy, tsh))
        return out

    def tube_radii():
        # each tube's mean radius (Å) of its moving rows about their own x, y centre: the
        # breathing of a tube's cross-section
        out = []
        for i in t_rows:
            p = sim.state.y[i, :2]
            c = p.mean(axis=0)
            out.append(float(np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]).mean()))
        return out

    # 3. the pull
    strains, stresses, per_tube, times, temps, readings = [], [], [], [], [], []
    radii = []
    smax, failed = -np.inf, False
    bar = tqdm(disable=not progress, unit="sample", desc="bundle tension", mininterval=1.0)
    t_dyn0 = time.perf_counter()
    nread = sample_every // 10
    snaps = []
    broken_links: dict = {}
    step = 0
    try:
        while True:
            acc = np.zeros(len(tubes))
            tacc = np.zeros((len(tubes), 2))
            for _ in range(nread):
                sim.run(10 // per)
                for k, (gb, gt) in enumerate(grips):
                    # force on the bottom grip's atoms from the tube: -reaction; tension =
                    # mean of the bottom one's +z and the top one's -z
                    acc[k] += 0.5 * (-gb.reaction_now[2] + gt.reaction_now[2])
                tacc += np.nan_to_num(np.array(tube_temperatures(), dtype=float))
                if record_readings:
                    readings.append([sim.state.t] + [
                        0.5 * (-gb.reaction_now[2] + gt.reaction_now[2]) for gb, gt in grips])
            step += sample_every
            Fk = acc / nread
            if coarse:
                strain_now = 2.0 * speed * step * dt_fs * 1e-3 / sep0
                for k, bm, st in coarse:
                    sub = bm.sub(sim.state)
                    broken_links[k] = broken_links.get(k, 0) + bm.model.break_links(sub)
                    tube = bm.model.tube
                    tube.prepare_step(st["L0"] * (1.0 + strain_now))
                    g = tube.ghost_correction
                    if g is not None:  # the open tube's energy is called with L0
                        g["Lz"] = float(st["L0"])
                        tube.ghost_correction = g
                    bm.model.store_ghost(sub)
                update_forces(sim)
            tmid = (step - 0.5 * sample_every) * dt_fs * 1e-3
            eps = 2.0 * speed * tmid / sep0
            sk = [float(stress_from_force(f, R, WALL_THICKNESS_A, 1)) for f in Fk]
            s = float(np.mean(sk))
            strains.append(eps)
            stresses.append(s)
            per_tube.append(sk)
            times.append(tmid)
            temps.append((tacc / nread).tolist())
            radii.append(tube_radii())
            smax = max(smax, s)
            bar.update(1)
            bar.set_postfix_str(f"strain {100 * eps:.1f}%  stress {s:.1f} GPa")
            if snapshot_every and step % snapshot_every == 0:
                snaps.append((step, sim.state.y.copy()))
            if smax > 0 and s < 0.95 * smax:  # (a bundle still in compression has not failed)
                failed = True
            if (failed and s < 0.2 * smax) or eps > max_strain or step >= max_steps:
                break
    finally:
        bar.close()
    t_dyn = time.perf_counter() - t_dyn0
    res = {"protocol": "dynamic", "scene": scene.info,
           "protocol_detail": {"grip_A": grip, "speed_A_per_ps_each_grip": speed,
                               "timestep_fs": dt_fs, "temperature_K": temperature,
                               "integrator": integ.name,
                               "outer_step_fs": dt_fs * per,
                               "thermostat": f"Nose-Hoover chain of {chain} on the free "
                                             f"part's vx, vy, damping {tdamp_ps} ps"
                                             + (f", one per tube (damping {tau_tube:.4g} ps)"
                                                if thermostat == "per-tube" else ""),
                               "seed": seed,
                               "gauge_length_A": sep0, "sample_every_steps": sample_every,
                               "minimisation": None if res_min is None else {
                                   "converged": bool(res_min.converged),
                                   "fmax": float(res_min.fmax),
                                   "iterations": int(res_min.iterations),
                                   "coarse_tubes_held": bool(hold.any())},
                               "settle": settle},
           "stress_convention": {"wall_thickness_A": WALL_THICKNESS_A, "radius_A": R,
                                 "area": "per tube 2 pi R t; bundle: mean over the tubes"},
           "curve": {"strain": strains, "stress_GPa": stresses,
                     "stress_per_tube_GPa": per_tube, "time_ps": times,
                     "temperature_per_tube_K": temps, "radius_per_tube_A": radii}}
    if record_readings:  # every reading: (time fs, per-tube tension eV/Å)
        res["curve"]["readings"] = readings
    res.update(curve_metrics(strains, stresses))
    res.update(tube_failures(strains, per_tube))
    res["damage"] = tube_damage(scene, sim, y)
    res["dof"] = scene.dof
    res["coarse_links_broken"] = {int(k) + 1: int(v) for k, v in broken_links.items()}
    res["particles"] = int(system.n)
    res["timing_s"] = {"minimisation": t_min, "dynamics": t_dyn, "steps": step}
    res["wall_s"] = time.perf_counter() - t0
    res["cpu_s"] = time.process_time() - c0
    res["_final_y"] = sim.state.y
    res["_start_y"] = y
    return res


def check_run_options(*, integrator=INTEGRATOR, inner=INNER, thermostat="bundle", chain=3,
                      settle_ps=0.0, max_strain=0.40, speed=1.0, dt_fs=1.0, sample_every=100,
                      vdw_every=1) -> None:
    """The options of :func:`dynamic_tension` checked, before anything is built: a one-line
    ValueError naming the first bad one."""
    if not (isinstance(chain, (int, np.integer)) and chain >= 1):
        raise ValueError(f"chain={chain!r}; valid: a Nose-Hoover chain length >= 1")
    if not (np.isfinite(settle_ps) and settle_ps >= 0):
        raise ValueError(f"settle_ps={settle_ps!r}; valid: a quench time >= 0 ps")
    if thermostat not in ("bundle", "per-tube"):
        raise ValueError(f"thermostat={thermostat!r}; valid: 'bundle' or 'per-tube'")
    for name, val in (("max_strain", max_strain), ("speed", speed), ("dt_fs", dt_fs)):
        if not (np.isfinite(val) and val > 0):
            raise ValueError(f"{name}={val!r}; valid: a number > 0")
    if not (isinstance(sample_every, (int, np.integer)) and sample_every >= 1):
        raise ValueError(f"sample_every={sample_every!r}; valid: an integer >= 1 (steps)")
    if not (isinstance(vdw_every, (int, np.integer)) and vdw_every >= 1):
        raise ValueError(f"vdw_every={vdw_every!r}; valid: an integer >= 1 (steps)")
    if integrator not in ("verlet", "respa"):
        raise ValueError(f"integrator={integrator!r}; valid: 'verlet' or 'respa'")
    if integrator == "respa":
        if not (isinstance(inner, (int, np.integer)) and inner >= 1 and 10 % inner == 0):
            raise ValueError(f"inner={inner!r}; valid: 1, 2, 5 or 10 (inner steps per outer "
                             "step; the grips are read every 10 steps)")
        if vdw_every != 1:
            raise ValueError(f"vdw_every={vdw_every} with integrator='respa'; "
                             "valid: 1 (multiple time stepping puts the vdW in the slow group)")


def _at_rest(state) -> None:
    """Zero every rate of ``state``: velocities and the fields' rates."""
    state.v[...] = 0.0
    for w in state.field_v.values():
        w[...] = 0.0


def _settle(asm, scene, sim0, dt_fs, settle_ps, ftol, inner):
    """The bundle after ``sim0``'s minimisation quenched to rest with every tube free
    (:class:`~upscale.engine.thermostats.Quench` on the run's integrator: velocity Verlet at
    ``dt_fs``, or r-RESPA with ``inner`` steps of ``dt_fs`` when ``inner > 1``) until the
    largest force on a free dof or shift is at most ``ftol`` (eV/Å), or for ``settle_ps``.
    Returns the quenched simulation and its record."""
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.thermostats import Quench

    q = Quench()
    if inner > 1:
        from upscale.engine.respa import RESPA

        integ = RESPA(float(dt_fs) * inner, int(inner), thermostat=q, force=True)
    else:
        integ = VelocityVerlet(float(dt_fs), force=True, thermostat=q)
    sim = asm.simulation(conditions=list(scene.extra_conditions()), integrator=integ)
    sim.state.y[...] = sim0.state.y
    _copy_fields(sim0.state, sim.state)
    _at_rest(sim.state)
    fm = [np.inf]
    every = max(1, 20 // inner)

    def fmax(s):
        f = float(np.sqrt(np.einsum("nc,nc->n", s.F, s.F)).max())
        for g in s.G.values():
            f = max(f, float(np.abs(g).max()) if g.size else 0.0)
        return f

    def done(s):
        if s.state.step % every:
            return False
        fm[0] = fmax(s)
        return fm[0] <= ftol

    sim.prepare()
    f0 = fmax(sim)
    out = sim.run(int(round(1e3 * settle_ps / (dt_fs * inner))), callback=done)
    fm[0] = fmax(sim)
    _at_rest(sim.state)
    return sim, {"method": "md quench (FIRE mixing)", "time_ps": float(sim.state.t) * 1e-3,
                 "fmax_start_eV_A": f0, "fmax_eV_A": fm[0], "converged": bool(fm[0] <= ftol),
                 "zeroed": int(q.zeroed), "wall_s": out["wall_s"]}


def tube_failures(strains, per_tube, drop: float = 0.05) -> dict:
    """Each tube's failure strain (first sample more than ``drop`` below its running
    maximum; None: not failed) and the order (tube numbers, 1 = centre, earliest first)."""
    P = np.asarray(per_tube, dtype=float)
    e = np.asarray(strains, dtype=float)
    out = []
    for k in range(P.shape[1]):
        run = np.maximum.accumulate(P[:, k])
        bad = np.nonzero(P[:, k] < (1 - drop) * run)[0]
        out.append(float(e[bad[0]]) if len(bad) else None)
    order = sorted([k for k in range(len(out)) if out[k] is not None], key=lambda k: out[k])
    return {"tube_failure_strain": out, "failure_order": [k + 1 for k in order],
            "central_tube_fails_first": bool(order and order[0] == 0
                                             and (len(order) < 2 or out[order[1]] > out[0]))}


def tube_damage(scene, sim, y_start) -> list[dict]:
    """Per tube: damage of its atoms (atomistic) or particles (coarse) in the last state,
    unrolled coordinates (s, z) for the maps."""
    from upscale.analysis.damage import unroll
    from upscale.models.tersoff import atom_damage, initial_bonds

    out = []
    st = sim.state
    for k, b in enumerate(scene.bodies):
        rows = scene.assembly.rows(b.name)
        if scene.specs[k].model == "tersoff":
            bonds = initial_bonds(y_start[rows])
            mu = atom_damage(st.y[rows], bonds)
            x = st.y[rows]
        else:
            mdl = [mm for mm in sim.models if getattr(mm, "body", None) is b][0]
            mu = np.asarray(mdl.model.particle_damage(mdl.sub(st)), dtype=float)
            x = st.y[rows]
        c = np.median(y_start[rows][:, :2], axis=0)
        s, z = unroll(x, c)
        out.append({"tube": k + 1, "model": scene.specs[k].model, "mu": mu, "s": s, "z": z,
                    "damaged_fraction": float(np.mean(mu > 0)), "max_mu": float(mu.max())})
    return out


def _central_radius(scene, y):
    rows = scene.assembly.rows(scene.bodies[0].name)
    p = y[rows]
    z = p[:, 2]
    mid = (z > z.min() + 10.0) & (z < z.max() - 10.0)
    c = p[mid, :2].mean(axis=0)
    return float(np.hypot(p[mid, 0] - c[0], p[mid, 1] - c[1]).mean())


def _copy_fields(src, dst):
    for k, v in getattr(src, "fields", {}).items():
        if k in dst.fields:
            dst.fields[k][...] = v
    for k, v in getattr(src, "extra", {}).items():
        if k in dst.extra and hasattr(v, "shape"):
            dst.extra[k][...] = v


# ---------------------------------------------------------------------- plots
def plot_curves(res, path, lammps=None, title=""):
    """Bundle and per-tube stress-strain curves, ours (solid) and LAMMPS's (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, what in zip(axs, ("bundle", "tubes")):
        for src, r, ls in (("engine", res, "-"), ("LAMMPS", lammps, "--")):
            if r is None:
                continue
            e = 100 * np.asarray(r["curve"]["strain"])
            if what == "bundle":
                ax.plot(e, r["curve"]["stress_GPa"], ls, lw=1.5, label=f"bundle, {src}")
            else:
                P = r["curve"].get("stress_per_tube_GPa")
                if P is None:
                    continue
                P = np.asarray(P)
                for k in range(P.shape[1]):
                    ax.plot(e[:len(P)], P[:, k], ls, lw=1.0 if k else 1.8, color=f"C{k}",
                            label=f"tube {k + 1}{' (centre)' if k == 0 else ''}, {src}")
        ax.set_xlabel("axial strain (%)")
        ax.set_ylabel("stress (GPa), wall t = 3.4 Å")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=2)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path, dpi=130)


def plot_damage_maps(res, path, title=""):
    """The damage of every tube on its unrolled surface, side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = res["damage"]
    fig, axs = plt.subplots(1, len(d), figsize=(2.3 * len(d), 4.6), sharey=True)
    axs = np.atleast_1d(axs)
    for ax, t in zip(axs, d):
        mu = np.asarray(t["mu"])
        o = np.argsort(mu)
        sc = ax.scatter(np.asarray(t["s"])[o], np.asarray(t["z"])[o], c=mu[o],
                        s=np.where(mu[o] > 0, 6.0, 1.5), cmap="inferno_r", vmin=0, vmax=1,
                        linewidths=0)
        ax.set_title(f"tube {t['tube']}: {t['model']}", fontsize=8)
        ax.set_xlabel("s = R θ (Å)", fontsize=7)
    axs[0].set_ylabel("z (Å)")
    fig.colorbar(sc, ax=list(axs), label="damage mu", shrink=0.8)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path, dpi=130)


def add_run_options(p) -> None:
    """The options of a dynamic bundle run shared by ``upscale bundle`` and the validation
    case ``bundle-tension``: overlap, vdW schedule, coarse pairs, strain, time stepping,
    thermostat."""
    p.add_argument("--allow-overlap", action="store_true",
                   help="run tubes closer than the van der Waals wall (the seed's hexagon)")
    p.add_argument("--max-strain", type=float, default=0.40,
                   help="stop the pull at this strain (default 0.40, the references')")
    p.add_argument("--integrator", choices=("verlet", "respa"), default=INTEGRATOR,
                   help="multiple time stepping (respa: the coarse tubes' lattice and the "
                   "vdW at an outer step of --inner fs) or velocity Verlet at 1 fs "
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

