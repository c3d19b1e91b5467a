"""Dynamic tension of the coarse tube (the LAMMPS references' dynamic protocol), with a
vacancy or pristine.

The time loop is the shared dynamic pull (:func:`upscale.experiments.pull.pull`) over the
engine: the tube as :class:`upscale.models.dcbr_engine.DCBRDefectTubeModel`, checkpoints
with exact resume, extxyz / VTK output, the blow-up guard. Units: eV, Å, fs, amu; stress
in GPa on the wall area 2 pi R t, t = 3.4 Å.

:func:`dynamic_tension` follows ``upscale.experiments.lammps.tension.dynamic_tension`` step for step,
on a :class:`~upscale.models.dcbr_defect.DCBRDefectTube`:

1. the tube on the zero-stress uniform lattice (L0; LAMMPS relaxes the periodic tube with
   its vacancy, which changes L0 by a few 1e-4, and an open tube's length relaxes anyway);
2. the axial periodicity is removed (G is rebuilt without links across the cell boundary)
   and the open tube is minimised once (R = mean atom radius after it);
3. end grips of ``grip`` Å move rigidly apart at ``speed`` Å/ps each. As LAMMPS's, a grip
   holds the atoms within ``grip`` of the open tube's end atoms: here the rows of particles
   that lie beyond that plane, and (clamped coarse grips) also a row less than half a
   row spacing inside it; the rest starts with the linear axial velocity ramp between the
   grip planes; velocity Verlet, ``dt`` fs;
4. strain = grip separation change / gauge, the initial distance between the grip planes
   (LAMMPS's definition, so strain(t) is the same function of time in both runs), at the
   middle of each ``sample``-step block as LAMMPS's. Stress = mean of the two grips'
   reaction forces (sum of -dE/dz over each grip's particles, averaged over the block) over
   2 pi R t; the run stops when the stress has fallen below 20 % of its maximum after
   failure, or at ``max_strain``. Strength as LAMMPS's (the maximum before the first drop of
   5 %), with the first drop taken at or after the first broken bond (see the code). An
   extensometer (:class:`upscale.analysis.stress.Extensometer`, the same in the LAMMPS
   runner) also reads the strain between two marks inside the gauge.

Grips (:func:`upscale.experiments.scenes.tube_tension.dynamic_scene`). The pristine tubes get an
atomistic band across each grip plane (:func:`grip_band_tube`, "Atomistic bands" below): the
grip then holds atoms as LAMMPS's does, where those tubes break. The vacancy tubes keep
clamped coarse grips (``clamp=True``, the default of this function for a model without
bands): with bands, the vacancy's region and the bands would cover most of a 50 Å gauge's
atoms at coarsening 2-4, and the gauge would no longer be coarse.

The gauge (``gauge_planes``) and where a clamp takes hold (``planes``). Which atoms end
LAMMPS's open tube depends on its periodic wrap and on the end atoms' relaxation, so its
planes, 50 Å inside them, cut the lattice elsewhere than planes 50 Å inside the coarse tube's
own end atoms: the coarse gauge came out longer than LAMMPS's, the strain at a given grip
separation smaller and the modulus by grip separation higher at the same static grip
stiffness. The validation scenes therefore take LAMMPS's planes as the gauge (the strain's
length, the extensometer's window and the velocity ramp), and put each clamp where LAMMPS's
grip takes hold, at its innermost held atoms
(:func:`upscale.experiments.scenes.tube_tension.reference_held_planes`): a lattice stretched
uniformly between held layers strains the bonds across them as the rest, and a clamped
coarse grip counts its held rows as sitting at its plane.

Clamped grips (``clamp=True``, :meth:`DCBRDefectTube.clamp_grips`, build_gain's ``clamp``).
With the plain centred stencil a grip is too compliant: the rows next to a plane mix the
grip's zero strain into theirs, the grips' own rows take strain from the gauge, and the two
row parities (the centred stencil's nearly decoupled chains) end one row apart in the grips;
the effective gauge is about a row spacing longer per grip (``python -m validation
dcbr-grip-stiffness`` measures the static grip stiffness against LAMMPS's). Clamped, once
the open tube has relaxed, G is linearised about that state and fitted against the axial
coordinate clamped at the planes (material beyond a plane has no strain to give), a held row
counting as sitting at its plane; the held rows whose families reach the gauge (the edges)
stand for the material between the plane and the gauge (their fit is taken about the plane,
so they see that gap's strain), the others have a fixed G, the families that reach past a
plane are fitted about their particle (so the row next to a plane feels its own position),
and the weights are the gauge's length shares, corrected next to the planes so that the
uniform gauge is an equilibrium (:meth:`DCBRDefectTube._balanced_grip_weights`: with the
length shares alone the first free row was pulled into the gauge at uniform strain and the
grip's edge rows broke first). A gauge stretched uniformly between rigid grips then gives
every particle exactly its strain and stays so when it is relaxed. Holding the row less than
h/2 inside a plane keeps the gap between the plane and the first free row at least h/2 (a
thinner gap is a soft spot that the kernel-weighted fit hardly sees).

Ghost forces with clamped grips (:meth:`DCBRDefectTube.clamp_grips`, ``Lz0``;
:meth:`DCBRDefectTube.prepare_step`). The ghost-force correction of the atomistic region is
the gradient of a pristine twin at the uniform stretch. A periodic twin is right far from
the grips, but at coarsening 4 a 50 Å gauge holds five rows and the region's coupling
(rounded out to whole cells) borders the grips: the periodic twin's dead load then falls on
held rows, where it is no ghost force but part of the measured reaction, and the rows next
to them are balanced for the periodic G, not the clamped one. So the twin is opened and
clamped like the tube (linearised about its own uniform lattice at the set-up stretch), its
uniform state has the gauge uniform and the grips' rows moved rigidly with their planes
(:meth:`DCBRDefectTube.clamped_uniform_state`), its gradient there is the dead load of every
free particle and atom, and on the grips' rows the dead load is what the twin's grips carry
beyond the uniform tube's tension T = N / L de/dlam_z (the patch test at the grips: a
pristine tube stretched uniformly between them is in equilibrium and its grips carry T).
(A vacancy region lowered until its coupling kept a row spacing from the grips was tried
first; its narrow band is narrower than the path of LAMMPS's crack in the seed-scale tubes,
whose crack then stopped at the band's edge.)

Masses (:meth:`DCBRDefectTube.masses`): a free atom 12.011 amu; a particle carries m_C
max(w_c, N_c/2) (its atoms, at least half its nominal share, so that interface particles
with few atoms do not set a tiny stable step); the sublattice shift of a particle is a
dynamic unknown with the reduced mass of the two sublattices, m_C max(w_c, N_c/2) / 4 (the
optical mode), held with the grip on a grip's particles (a rigid grip moves its B atoms with
its A atoms; clamped and banded grips alike) but a clamped grip's edges, whose energy is the
gauge material's between the plane and the first free row (free atoms, whose shifts relax).

Thermostat, as the LAMMPS runs: Gaussian velocities at ``temperature`` (default 10 K) on the
free part, and a Nose-Hoover thermostat (damping ``tdamp``, default 100 fs) whose temperature
is measured from the x, y velocities of the free particles and atoms and the shift velocities
(the axial stretching flow is not heat); ``temperature=0`` runs plain NVE from rest. Without
it, the energy a crack releases stays in the atomistic band (the coarse particles cannot carry
its short waves away, which reflect at the interface) and throws atoms off the wall after
the break (``curve["atoms_off_wall"]`` counts them).

Ghost-force correction (:meth:`DCBRDefectTube.prepare_sides`): refreshed every ``sample``
steps (a dead load in between), on each side of the atomistic region at the axial stretch
that side's interface particles carry (``ghost="local"``), so that after the break each half's
correction relaxes with it; ``ghost="grips"`` takes it at the grips' strain for the whole tube
(after the break it pushes load that nothing balances into the interface atoms).

Atomistic bands across the grip planes (:func:`grip_band_tube`, :func:`pristine_grip_tube`;
``python -m validation dcbr-tension --dynamic``, with or without ``--vacancy``). LAMMPS's
pristine (10,10) and (12,6) tubes fail at the grip planes (their dumps: the first free bonds
next to the held atoms are the longest all along the pull): a rigid grip keeps its atoms at
their radius, so the wall next to it cannot contract and its bonds across the plane stretch
more; (17,0) fails in the gauge. A clamped coarse grip edge does not carry this
concentration (with the length-share weights it overdid it, with the balanced weights the
gap is strained as the gauge). The site is set by the protocol (the planes), not by chance,
so the pristine scene puts an atomistic band (``r_atomistic``, default 8 Å, whole cells)
across each grip plane; the band atoms beyond a plane are held by the grip as LAMMPS's (no
clamp: the grip's edge is atomistic) and the grip's particles' sublattice shifts are held
too (a rigid grip moves its B atoms with its A atoms). Where a plane cuts the lattice decides
which bonds cross it ((17,0): the inclined or the axial ones), and LAMMPS's planes lie 50 Å
inside its end atoms after its set-up, which depends on its periodic wrap and on the end
atoms' relaxation, neither of which coarse ends carry; ``planes`` therefore takes the
reference's own planes (the validation case recovers them from the stored run), which makes
the coarse grips hold exactly LAMMPS's atoms; without it the planes are ``grip`` inside the
uniform lattice's end atoms (a fraction of an Å off). The ghost-force dead load on the
grips' rows stays at its set-up value (a grip does not stretch; :func:`_hold_grip_ghost`).
The gauge between the bands is coarse and fails only by the link rule unless the
lattice-stability rule of the quasi-static scene is applied too (``stability=True``: every
``sample`` steps, on the most loaded particle carrying at least half its atoms, in its
instantaneous thermal state). The pristine scene leaves it off: at coarsening 1 the most
loaded of ~1000 two-atom particles is tested in an instantaneous state with the thermal
noise of a particle that small and fails mid-gauge long before the periodic tube's lattice
becomes unstable.

Multiple time stepping (``integrator="respa"``, :class:`upscale.engine.respa.RESPA` on the
split of :meth:`upscale.models.dcbr_engine.DCBRDefectTubeModel.add_group_force`): the
coarse particles' lattice energy and hourglass term are evaluated once per outer step, the
atomistic region with its pads at every inner step of ``dt`` (the atoms' own step, as
LAMMPS's). The sublattice shifts' optical mode is as fast as the atoms (its reduced mass is
a quarter of a particle's); it goes with the fast group through the coarse energy's
second-order expansion in the shifts
(:meth:`~upscale.models.dcbr_engine.DCBRDefectTubeModel.prepare_split`, renewed at every
sample with the ghost-force refresh), which also carries the slow forces' constant part,
so that what is applied as an impulse once per outer step is only their change. The
ghost-force dead load goes with the fast group as well (``split="ghost"``,
:data:`~upscale.models.dcbr_engine.MTS_SPLIT`): in the slow group its change, small as it
is, makes the NVE energy drift at a 5 fs outer step (``dcbr-stability``). After the
tube has failed, an atom kicked by the step cutoff may trip the engine's blow-up guard; the
run then ends there with its curve (``blowup_after_failure``), as LAMMPS's runs stop on a
runaway atom. The atomistic region may be shaped around the vacancy
(``DCBRDefectTube(region="disc" | "ellipse")``), but the crack then leaves the atoms at the
region's edge, where the coarse link rule does not carry its tip and arrests it; the band
keeps the crack's whole path atomistic.

A region that grows with the crack (``grow``, :func:`grow_region`). Up to the crack a disc
about the vacancy is enough: the loading is elastic outside it, and the crack starts at
the vacancy (the vacancy's first bonds break at the peak on (30,60) and about 0.02 strain
before it on (50,50)). The band costs its atoms at every inner step all along. So the run
starts on the disc and, at the first sample at which one of its bonds has broken, moves
to the band: the tube with the band is set up beside the disc's (same grips, same clamp,
no minimisation of its own), and the state is carried over
(:meth:`~upscale.models.dcbr_defect.DCBRDefectTube.carry_state`: the new atoms where the
carriers' maps put them, with those maps' velocities plus thermal ones at the scene's
temperature). From there the run is the band's; a checkpoint written after the switch
resumes on the band, bit for bit.

Other differences from the LAMMPS runs, stated: the coarse failure rule is the link rule
only (checked every ``sample`` steps; the lattice-stability rule needs a Hessian, the coarse
region stays far below its instability strain when the vacancy fails, and the pristine
scene leaves it off for the reasons above), and the thermal velocities are drawn by numpy,
so a run is one draw of the thermal noise like the reference's (``python -m validation
dcbr-seeds`` / ``reference-seeds`` give the spreads).
"""
from __future__ import annotations

import math
import time

import numpy as np

from upscale.constants import K_B_EV
from upscale.models.dcbr import EV_PER_A3_IN_GPA, WALL_THICKNESS, uniform_map_frame
from upscale.models.dcbr_defect import ACC_UNIT, CARBON_MASS
from upscale.engine.checkpoint import Checkpoint
from upscale.experiments.protocols import Dynamic
from upscale.experiments.pull import PullSpecimen, pull

__all__ = ["dynamic_tension", "open_tube_with_grips", "grow_region", "static_grip_stiffness",
           "grip_band_tube", "pristine_grip_tube", "run_metrics", "CARBON_MASS"]


def grip_band_tube(n: int, m: int, length: float, coarsening: float, grip: float = 50.0,
                   r_atomistic: float = 8.0, vacancy: int = 4, **kw):
    """A tube of the dynamic scene with an atomistic band across each grip plane (module
    docstring, "Pristine tubes"), and the 4-atom vacancy with its own region unless
    ``vacancy=0``.

    A :class:`~upscale.models.dcbr_defect.DCBRDefectTube` with bands of half-width
    ``r_atomistic`` centred on the planes ``grip`` Å inside the end atoms (reference
    lattice); :func:`open_tube_with_grips` then holds the band atoms beyond each plane with
    the grip, so the first free bonds next to the held atoms are the potential's own, as in
    LAMMPS, and no coarse row stands for the gap between a plane and the gauge.
    ``kw`` goes to the model (hourglass, step_crossing, ...)."""
    from upscale.build import swcnt  # noqa: PLC0415
    from upscale.models.dcbr_defect import DCBRDefectTube  # noqa: PLC0415

    z = swcnt(n, m, length).positions[:, 2]
    if not 0 < 2 * (grip + r_atomistic) < z.max() - z.min():
        raise ValueError(f"grip={grip} Å, r_atomistic={r_atomistic} Å in a "
                         f"{z.max() - z.min():.1f} Å tube; valid: grip > 0 and the two bands "
                         "(grip + r_atomistic from each end) not overlapping")
    model = DCBRDefectTube(n, m, length, coarsening=coarsening, vacancy=vacancy,
                           r_atomistic=r_atomistic, band_z=(z.min() + grip, z.max() - grip),
                           **kw)
    return model


def pristine_grip_tube(n: int, m: int, length: float, coarsening: float, grip: float = 50.0,
                       r_atomistic: float = 8.0, **kw):
    """The pristine tube of the dynamic scene: :func:`grip_band_tube` with ``vacancy=0``."""
    return grip_band_tube(n, m, length, coarsening, grip, r_atomistic, vacancy=0, **kw)

def open_tube_with_grips(model, grip: float, gtol: float = 1e-4, clamp: bool | None = None,
                         planes=None, gauge_planes=None, grows_to=None) -> dict:
    """Steps 1-3 of the module docstring: the open tube relaxed with its grips.

    ``clamp``: clamped coarse grips (module docstring); ``None`` (default): clamped unless
    the model has atomistic bands across the planes (``model.band_z``), which need none.

    ``planes``: the grip planes' reference z (Å, the lattice of ``model.X_atoms``) instead
    of ``grip`` inside the end atoms: with atomistic bands across them, the planes the atoms
    are held beyond (module docstring, "Atomistic bands"); with clamped grips, where the
    clamp takes hold (a held row counts as sitting there: the innermost held material,
    module docstring, "The gauge"). ``gauge_planes`` (reference z, default ``planes``):
    the planes whose distance is the gauge of the strain, and between which the
    extensometer and the velocity ramp lie. ``grows_to``: the tube the run may grow its
    region to (:func:`grow_region`); the rows its pad atoms follow are not held by a
    clamp's half-row rule either, so that both tubes have the same grips.

    Returns a dict: ``y``, ``delta`` (the relaxed unknowns), ``L0``, ``R`` (mean atom radius),
    ``area`` (2 pi R t), the grip masks ``bottom`` and ``top`` over the rows of ``y``, the grip
    planes ``zb`` < ``zt`` (Å, after the set-up relaxation), the gauge planes ``gb`` < ``gt``
    (likewise), ``gauge`` = gt - gb, ``grip_rows`` (the innermost grip rows'
    distance) and ``clamped`` (the clamp's planes, rigid particles and the particle
    positions G was linearised about; None without a clamp), which :func:`grow_region`
    repeats on a larger region."""
    # the zero-stress uniform lattice (an open tube relaxes its own length, so the periodic
    # zero-stress iteration of the quasi-static scene is not needed), then the tube is
    # opened (G without links across the cell boundary) and minimised once
    lt, lz, sh = model.uniform_lattice(None)
    y, d, L0 = model.uniform_state(lt, lz, sh)
    if L0 - 2 * grip <= 0:
        raise ValueError(f"grip={grip} Å leaves no free length in a {L0:.1f} Å tube; "
                         f"valid: grip < {L0 / 2:.1f}")
    model.periodic = False
    model.clamp = None  # (a model opened before: its clamp is set again below)
    tw = getattr(model, "_twin", None)
    if tw is not None and getattr(tw, "clamp", None) is not None:  # (and its twin)
        tw.periodic, tw.clamp = True, None
        tw.natoms_n = tw._natoms_unclamped.copy()
        tw._build_gain(None)
        del model._clamp_Lz0
    model._build_gain(None)
    model.prepare_step(L0)
    nd = len(model.dof_idx)
    z = y[:, 2]
    zlo, zhi = model.particle_positions(y)[:, 2].min(), model.particle_positions(y)[:, 2].max()
    rows0 = np.unique(np.round(model.x0[:, 2], 6))
    h = float(np.median(np.diff(rows0))) * L0 / model.L if len(rows0) > 1 else 0.0
    if clamp is None:
        clamp = getattr(model, "band_z", None) is None
    # LAMMPS's grips hold the atoms within ``grip`` of the open tube's end atoms; here a row
    # of particles belongs to a grip when it lies below (above) that plane, i.e. most of the
    # atoms of its slab do. The planes are taken on the tube's own atoms (uniform lattice at
    # L0), and moved with the end rows by the set-up relaxation below (LAMMPS: after its
    # open-tube minimisation)
    za = model.X_atoms[:, 2] * (L0 / model.L)
    zb, zt = float(za.min()) + grip, float(za.max()) - grip
    banded = getattr(model, "band_z", None) is not None
    for name, pl in (("planes", planes), ("gauge_planes", gauge_planes)):
        if pl is not None and not (len(pl) == 2 and za.min() < pl[0] * L0 / model.L
                                   < pl[1] * L0 / model.L < za.max()):
            raise ValueError(f"{name}={pl!r}; valid: two reference z inside the tube "
                             f"({za.min() * model.L / L0:.2f}..{za.max() * model.L / L0:.2f} Å), "
                             "lower first")
    if planes is not None:  # given on the reference lattice (the validation scenes)
        zb, zt = float(planes[0]) * L0 / model.L, float(planes[1]) * L0 / model.L
    # the gauge planes, as offsets from the grip planes (they move with them below)
    db, dt_ = (0.0, 0.0) if gauge_planes is None else \
        (float(gauge_planes[0]) * L0 / model.L - zb, float(gauge_planes[1]) * L0 / model.L - zt)
    zb_ref, zt_ref = zb * model.L / L0, zt * model.L / L0  # the planes in reference z
    bottom = np.zeros(len(y), bool)
    top = np.zeros(len(y), bool)
    # with ``clamp`` a row also belongs to a grip when it lies less than half a row
    # spacing inside the plane: it is the grip's node at the plane (DCBRDefectTube.
    # clamp_grips), and the gauge's first free row is then at least h/2 from it
    # (not a row that pad atoms of the atomistic region follow: holding it would hold them,
    # gauge atoms, too, and stiffen a gauge that is all atomistic but for those rows)
    hold = 0.5 * h if clamp else 0.0
    carrier = np.zeros(model.N, bool)
    carrier[model._pad["c"]] = True
    if grows_to is not None:
        carrier[grows_to._pad["c"]] = True
    inner = carrier[model.dof_idx]
    bottom[:nd] = (z[:nd] < zb) | ((z[:nd] < zb + hold) & ~inner)
    top[:nd] = (z[:nd] > zt) | ((z[:nd] > zt - hold) & ~inner)
    if banded:  # atomistic bands across the grip planes: the atoms beyond a plane are held
        # by the grip, as LAMMPS's (the grip's edge is then atomistic and needs no clamp)
        if clamp:
            raise ValueError("clamp=True with atomistic bands across the grip planes; "
                             "valid: clamp=False (the atoms at the planes are held exactly)")
        bottom[nd:] = z[nd:] < zb
        top[nd:] = z[nd:] > zt
    elif model.nf and (np.any(z[nd:] < zb + hold) or np.any(z[nd:] > zt - hold)):
        raise ValueError("the atomistic region reaches into a grip; valid: a longer tube or "
                         "shorter grips")
    if not (bottom.any() and top.any()):
        raise ValueError(f"grip={grip} Å holds no row of particles (rows {h:.2f} Å apart); "
                         f"valid: grip > {0.5 * h:.2f}")
    grips = bottom | top
    # the set-up minimisation holds the grips' x and y: the ghost-force dead load is not
    # invariant under a rigid turn about the axis (its energy goes as -A cos(phi)), and left
    # free the minimiser turned some open tubes by about half a turn, after which the dead
    # loads pushed on the wrong atoms; the grips hold x and y
    # during the pull anyway, as LAMMPS's do
    fixed = np.zeros_like(y, bool)
    fixed[grips, :2] = True
    end_lo, end_hi = (z[:nd] < zlo + 1e-6), (z[:nd] > zhi - 1e-6)  # the end rows
    z_pre = z[:nd].copy()
    z_pre_a = z[nd:].copy()
    r = model.minimise(y, d, L0, gtol=gtol, fixed=fixed)
    y, d = r.y, r.delta
    # the grip planes follow the end rows' relaxation (the end atoms move with them)
    if banded:  # the planes follow the lattice they cut (the band atoms within 3 Å of
        # each); the coarse end rows' own relaxation is no measure of where the atoms are
        za0 = z_pre_a
        near_b, near_t = np.abs(za0 - zb) < 3.0, np.abs(za0 - zt) < 3.0
        zb += float(np.mean(y[nd:][near_b, 2] - za0[near_b]))
        zt += float(np.mean(y[nd:][near_t, 2] - za0[near_t]))
        # LAMMPS picks its grip atoms after the set-up minimisation: so here
        bottom[nd:] = y[nd:, 2] < zb
        top[nd:] = y[nd:, 2] > zt
    else:
        zb += float(np.mean(y[:nd][end_lo, 2] - z_pre[end_lo]))
        zt += float(np.mean(y[:nd][end_hi, 2] - z_pre[end_hi]))
    clamped = None
    if clamp:  # the grips' particles held rigid in G from here on (DCBRDefectTube.clamp_grips)
        yp = model.particle_positions(y)
        rigid = np.zeros(model.N, bool)
        rigid[model.dof_idx] = bottom[:nd] | top[:nd]
        model.clamp_grips(zb_ref, zt_ref, rigid, yp, Lz0=L0)  # (rebuilds G and its twin)
        clamped = {"planes_ref": (zb_ref, zt_ref), "rigid": rigid, "y_ref": yp}
        model.prepare_step(L0)
        fixed[grips] = True
        r = model.minimise(y, d, L0, gtol=gtol, fixed=fixed)
        y, d = r.y, r.delta
    R = model.radius(y, d)
    z = y[:, 2]
    # the gauge is LAMMPS's: the initial distance between its grip planes (gauge_planes), so
    # that strain(t) = 2 v t / gauge is the same function of time in both runs (the distance
    # between the innermost grip rows is 0 to 2 h longer and would lower the strain at a
    # given grip separation, most at coarsening 4).
    gb, gt = zb + db, zt + dt_
    return {"y": y, "delta": d, "L0": float(L0), "R": R, "area": 2 * math.pi * R * WALL_THICKNESS,
            "bottom": bottom, "top": top, "zb": zb, "zt": zt, "gb": gb, "gt": gt,
            "gauge": float(gt - gb),
            "grip_rows": float(z[top].min() - z[bottom].max()), "clamped": clamped,
            "ghost0": {k: np.array(v, copy=True) if isinstance(v, np.ndarray) else v
                       for k, v in model._ghost.items()}}


def grow_region(big, model, st) -> dict:
    """Set up ``big``, a tube of ``model``'s lattice with an atomistic region containing
    ``model``'s (:meth:`~upscale.models.dcbr_defect.DCBRDefectTube.carry_state`), as
    :func:`open_tube_with_grips` set up ``model`` (``st`` its result), so that a run can
    continue on it: opened, its grips clamped about the same particle positions (G is
    linearised about the relaxed open tube of ``model``; the particles are the same, and
    the grown region's own relaxation would only move the atoms of the region), the
    ghost-force correction at the set-up length. No minimisation: the state comes from
    ``model``'s (``carry_state``). Returns ``st`` for ``big``: its set-up state carried
    over (``y``, ``delta``, the extensometer's reference) and the grip masks over its rows;
    the planes, gauge and area are ``model``'s. Clamped grips only (the scene of the vacancy
    tubes)."""
    cl = st.get("clamped")
    if cl is None:
        raise ValueError("grow_region needs clamped grips (the vacancy scene); valid: "
                         "open_tube_with_grips(..., clamp=True) on the smaller region")
    if getattr(big, "band_z", None) is not None:
        raise ValueError("grow_region: a tube with atomistic bands across the grips; valid: "
                         "the vacancy's own region only")
    L0 = st["L0"]
    big.periodic, big.clamp = False, None
    big._build_gain(None)
    big.prepare_step(L0)
    nd = len(model.dof_idx)
    bottom_p, top_p = np.zeros(model.N, bool), np.zeros(model.N, bool)
    bottom_p[model.dof_idx], top_p[model.dof_idx] = st["bottom"][:nd], st["top"][:nd]
    held = bottom_p | top_p
    if held[big.slave_idx].any() or len(big._pad["c"]) and held[big._pad["c"]].any():
        raise ValueError("the grown atomistic region reaches into a grip; valid: a longer "
                         "tube, shorter grips or a smaller region")
    big.clamp_grips(*cl["planes_ref"], cl["rigid"], cl["y_ref"], Lz0=L0)
    big.prepare_step(L0)
    y, d = big.carry_state(model, st["y"], st["delta"], Lz=L0)
    ndb = len(big.dof_idx)
    bottom, top = np.zeros(len(y), bool), np.zeros(len(y), bool)
    bottom[:ndb], top[:ndb] = bottom_p[big.dof_idx], top_p[big.dof_idx]
    return st | {"y": y, "delta": d, "bottom": bottom, "top": top,
                 "ghost0": {k: np.array(v, copy=True) if isinstance(v, np.ndarray) else v
                            for k, v in big._ghost.items()}}


class _TubePull(PullSpecimen):
    """The coarse tube of :func:`dynamic_tension` as a :class:`~upscale.experiments.pull.
    PullSpecimen`: the time loop is :func:`~upscale.experiments.pull.pull`'s.

    The tube as :class:`~upscale.models.dcbr_engine.DCBRDefectTubeModel` (rows: particles,
    then free atoms; the shifts a field with inertia), its slave particles tied to their
    atoms, the grips :class:`~upscale.engine.conditions.Grip` conditions moving rigidly at
    -+``vz``, the engine's velocity Verlet inside
    :class:`~upscale.engine.thermostats.NoseHoover` half steps on x, y of the free rows and
    on the shifts, with the scene's ``ndf`` (or :class:`~upscale.engine.respa.RESPA`,
    ``inner`` fast steps per outer step of ``dt``, on the model's force ``split``). After
    every step the grips' mean reaction and the extensometer strain are accumulated
    (``read``); every ``sample`` steps the scene's ``on_sample`` (the failure rules, the
    ghost-force refresh, after which the forces are computed again). ``grow``: the scene's
    ``grow_to(y, d, v, vd)``, which moves it to the larger tube (``switch``): a new
    simulation of that tube from the same step and time, its reference rows the grown
    tube's set-up state (so the grips move and the displacements count as before), the
    thermostat keeping its variable; the extra ``dcbr.grown`` marks a checkpoint written
    after the switch, which resumes on the larger tube."""

    def __init__(self, scene: dict, tube, st, y, d, v, vd, dfree, ndf, ext):
        self.scene = scene
        self.rec = scene["rec"]
        self.cur = {"ext": ext}
        self.build(tube, st, y, d, v, vd, dfree, ndf)

    def build(self, tube, st, y, d, v, vd, dfree, ndf, t=0.0, step=0):
        """A simulation of ``tube``, its reference rows the set-up state ``st`` (the start
        of the pull), at unknowns y, shifts d, rates v, vd (None: at the reference, at
        rest), time ``t`` and ``step``."""
        from upscale.engine.conditions import Grip, Region  # noqa: PLC0415
        from upscale.engine.integrators import VelocityVerlet  # noqa: PLC0415
        from upscale.engine.simulation import Simulation  # noqa: PLC0415
        from upscale.engine.thermostats import NoseHoover  # noqa: PLC0415
        from upscale.models.dcbr_engine import FIELD, DCBRDefectTubeModel  # noqa: PLC0415

        sc = self.scene
        vz = sc["vz"]
        em = DCBRDefectTubeModel(tube, y=st["y"], delta=st["delta"], Lz=sc["L0"],
                                 split=sc["split"])
        n, N, rows = em.n, em.N, em.y_rows
        bottom, top = np.zeros(n, bool), np.zeros(n, bool)
        bottom[rows], top[rows] = st["bottom"], st["top"]
        grips = [Grip(Region("grip bottom", bottom), velocity=(0.0, 0.0, -vz), record_every=0),
                 Grip(Region("grip top", top), velocity=(0.0, 0.0, vz), record_every=0)]
        conds = em.conditions(held_shifts=~dfree) + grips
        thermostat = NoseHoover(sc["temperature"], sc["tdamp"], components=(0, 1),
                                fields=(FIELD,), ndf=ndf, k_B=K_B_EV) if sc["thermo"] else None
        if sc["inner"] is None:
            integrator = VelocityVerlet(sc["dt"], force=True, thermostat=thermostat)
        else:
            from upscale.engine.respa import RESPA  # noqa: PLC0415

            integrator = RESPA(sc["dt"], int(sc["inner"]), thermostat=thermostat, force=True)
        sim = Simulation(em.system(), None, [em], conds, integrator)
        state = sim.state
        state.t, state.step = float(t), int(step)
        if y is not None and step > 0:  # (a state carried over)
            state.y[...] = em.rows(y)
            state.fields[FIELD][:N] = d
        if v is not None:
            state.v[rows] = v
            if len(tube.slave_idx):
                state.v[tube.slave_idx] = tube.Phi @ v[em.nd:]
            state.field_v[FIELD][:N] = vd
        self.cur.update(em=em, rows=rows, N=N, bottom=bottom, top=top, tube=tube)
        self.simulation = sim
        return sim

    # ------------------------------------------------------------------ PullSpecimen
    def read(self, sim) -> None:
        """The grips' reaction (what they exert on the tube, -sum F over the region, from
        the unzeroed forces on the prescribed rows) and the extensometer strain."""
        cur, rec = self.cur, self.rec
        R = sim.reactions
        rec["blk"].append(0.5 * (-R[cur["top"], 2].sum() + R[cur["bottom"], 2].sum()))
        rec["eblk"].append(cur["ext"].strain(self.scene["z_ext"](sim.state.y[cur["rows"]])))

    def sample(self, sim) -> dict:
        from upscale.models.dcbr_engine import FIELD  # noqa: PLC0415

        s_, cur, rec = sim.state, self.cur, self.rec
        em, stability = cur["em"], self.scene["stability"]

        def links():  # (with the stability rule, its time includes the link rule's)
            ts = time.perf_counter()
            nb = em.break_links(s_, stability=stability)
            if stability:
                rec["t_stab"] += time.perf_counter() - ts
            return nb

        def refresh():
            em.store_ghost(s_)
            # (a multiple-time-step integrator keeps its own group forces)
            getattr(sim.integrator, "update_forces", lambda s: s.update_forces())(sim)
        self.scene["on_sample"](int(s_.step), s_.y[cur["rows"]], s_.v[cur["rows"]],
                                s_.fields[FIELD][:cur["N"]], links, refresh)
        return {"load": rec["strains"][-1], "response": rec["stresses"][-1]}

    def load(self, sim) -> float:
        sc = self.scene
        return 2 * sc["vz"] * int(sim.state.step) * sc["dt"] / sc["gauge"]

    def wants_switch(self) -> bool:
        return bool(self.rec.get("grow_pending"))

    def switch(self) -> None:
        from upscale.models.dcbr_engine import FIELD  # noqa: PLC0415

        sim, cur = self.simulation, self.cur
        s_ = sim.state
        yk, dk = cur["em"].unknowns(s_)
        th = getattr(sim.integrator, "thermostat", None)
        self.rec["grow_pending"] = False
        g = self.scene["grow"](yk, np.array(dk, copy=True), s_.v[cur["rows"]].copy(),
                               np.array(s_.field_v[FIELD][:cur["N"]], copy=True))
        cur["ext"] = g["ext"]
        new = self.build(g["tube"], g["st"], g["y"], g["delta"], g["v"], g["vdelta"],
                         g["dfree"], g["ndf"], s_.t, s_.step)
        new.state.extra["dcbr.grown"] = np.int64(s_.step)
        # (the correction set at the switch, under a new version: a run resumed from a
        # checkpoint of this simulation takes it from the extras, not from its set-up)
        cur["em"].store_ghost(new.state)
        if th is not None:
            new.integrator.thermostat.xi = th.xi

    def bookkeeping(self) -> dict:
        return self.rec

    def restore(self, book: dict) -> None:
        self.rec.update(book)

    def prepare_resume(self, path) -> None:
        """A checkpoint written after the region grew belongs to the larger tube."""
        with np.load(path) as z:
            grown = "extra__dcbr.grown" in z.files
        if grown:
            g = self.scene["grow"](None, None, None, None)
            self.cur["ext"] = g["ext"]
            self.build(g["tube"], g["st"], None, None, None, None, g["dfree"], g["ndf"])

    def unknowns(self):
        """(y, delta) of the current state, the tube's unknowns."""
        yk, dk = self.cur["em"].unknowns(self.simulation.state)
        return yk, np.array(dk, copy=True)


def _hold_grip_ghost(model, st) -> None:
    """With atomistic bands across the grip planes, the ghost-force dead load on the grips'
    rows (and on their particles' shifts) is put back to its set-up value (``st["ghost0"]``).

    The correction of a load step is taken at the gauge's stretch, but a grip's interface
    (band atoms and coarse rows beyond the plane) does not stretch: it is held as it was
    set up. Its dead load enters no motion, only the grips' reaction force; at the gauge's
    stretch it would add a strain-proportional term to it (a stiffer static grip,
    ``dcbr-grip-stiffness``). No-op without bands."""
    if getattr(model, "band_z", None) is None or model._ghost is None:
        return
    g, g0 = model._ghost, st["ghost0"]
    rows = st["bottom"] | st["top"]
    held = np.zeros(model.N, bool)
    held[model.dof_idx] = rows[:len(model.dof_idx)]
    for k, r in (("y", rows), ("gy", rows), ("d", held), ("gd", held)):
        g[k] = np.where(r[:, None], g0[k], g[k])
    for k in ("gr", "gt", "thu", "rhou"):  # the cached cylindrical components go stale
        g.pop(k, None)


def _where(z, strain, u, zb, zt, what="n_atoms") -> dict:
    """Where damage first appeared in the pristine scene: the damaged atoms' (or coarse
    particles') signed distances into the gauge from the nearer grip plane (the planes
    moved out by ``u``; negative = inside a grip), and how many lie on each half."""
    lo = z < 0.5 * (zb + zt)
    dist = np.where(lo, z - (zb - u), (zt + u) - z)
    return {"strain": strain, what: int(len(z)), "distance_to_vacancy_A": None,
            "n_bottom_half": int(lo.sum()), "n_top_half": int((~lo).sum()),
            "distance_to_grip_plane_A": [float(np.min(dist)), float(np.median(dist)),
                                         float(np.max(dist))]}


def static_grip_stiffness(model, grip: float = 50.0, strain: float = 0.0025,
                          gtol: float = 1e-6, clamp: bool | None = None,
                          planes=None, gauge_planes=None) -> dict:
    """Force per grip separation of the open tube held by its grips, statically.

    The tube of :func:`open_tube_with_grips` (the dynamic scene's set-up); the grips are moved
    apart by ``strain`` times the gauge (all their components held), the free part is
    minimised with the ghost-force correction at that stretch, and the grips' mean reaction
    F (less its value at the set-up state, ``force_at_setup_eV_per_A``: clamping the grips
    leaves a small reaction, which would otherwise bias k at small strain) gives
    k = F / separation (eV/Å^2). k is free of any gauge convention, so it compares the coarse
    grips with LAMMPS's (``upscale.experiments.lammps.tension.static_grip_stiffness``) directly;
    ``modulus_TPa`` = (F / area) / strain with LAMMPS's gauge."""
    if not (0 < strain < 0.05):
        raise ValueError(f"strain={strain!r}; valid: 0 < strain < 0.05 (the linear range)")
    st = open_tube_with_grips(model, grip, gtol, clamp=clamp, planes=planes,
                              gauge_planes=gauge_planes)
    y0, d0, L0 = st["y"], st["delta"], st["L0"]
    bottom, top = st["bottom"], st["top"]
    grips = bottom | top
    _, gy, _, _ = model.energy_and_gradient(y0, d0, L0)  # the grips' reaction at the set-up
    F0 = 0.5 * (gy[top, 2].sum() - gy[bottom, 2].sum())
    u = 0.5 * strain * st["gauge"]
    y = y0.copy()
    y[bottom, 2] -= u
    y[top, 2] += u
    zc = 0.5 * (st["gb"] + st["gt"])
    y[~grips, 2] = zc + (y0[~grips, 2] - zc) * (1 + strain)  # affine start
    model.prepare_step(L0 * (1 + strain))
    model._ghost["Lz"] = float(L0)  # the open tube's energy is called with L0
    _hold_grip_ghost(model, st)
    fixed = np.zeros_like(y, bool)
    fixed[grips] = True
    r = model.minimise(y, d0.copy(), L0, gtol=gtol, fixed=fixed)
    y, d, info = r.y, r.delta, r.info
    _, gy, _, _ = model.energy_and_gradient(y, d, L0)
    F = 0.5 * (gy[top, 2].sum() - gy[bottom, 2].sum()) - F0
    return {"k_eV_per_A2": float(F / (2 * u)), "force_eV_per_A": float(F), "strain": strain,
            "force_at_setup_eV_per_A": float(F0),
            "gauge_length_A": st["gauge"], "grip_rows_distance_A": st["grip_rows"],
            "radius_A": st["R"], "modulus_TPa": float(F / st["area"] * EV_PER_A3_IN_GPA
                                                      / strain / 1000.0),
            "max_force_eV_A": info["max_force_eV_A"]}


def run_metrics(strains, stresses, exts, first, fit_max_strain: float = 0.02,
                plateau_fraction: float = 0.0) -> dict:
    """The curve metrics of a dynamic run, on the grip strain and on the extensometer.

    :func:`upscale.analysis.stress.curve_metrics` on (``strains``, ``stresses``), then,
    when ``first`` (the first damage, a dict with its ``strain``) comes after the failure
    drop that rule found, again from that strain on: a 5 % dip of the grip stress before any
    bond has broken is an oscillation of the coarse tube (the zero-energy-like row mode next
    to the grips rings at a few hundred fs at coarsening 3-4), not failure; LAMMPS's
    references fail on their first drop. The first drop's values are kept as
    ``strength_first_drop_GPa``, ``strain_at_peak_first_drop``. Last, the extensometer
    metrics (:func:`upscale.analysis.stress.extensometer_metrics`) of the final strength
    sample, so that ``strain_at_peak_ext`` always belongs to the same sample as
    ``strain_at_peak`` (taken before the correction they would be the first drop's sample's).
    The extensometer's fit takes the samples up to the peak only: its window selects by the
    extensometer strain, and after a break next to a grip (the pristine tubes) the unloaded
    gauge springs back below ``fit_max_strain`` (a fit through those samples gives a modulus
    near zero); a vacancy tube breaks inside the window, whose strain then grows.

    ``plateau_fraction``: the plateau-then-rise rule of ``curve_metrics``, which flags the
    switching-function artefact of the standard cutoff; with the step cutoff there is none,
    and on the coarse tube's grip stress (which rings by a few GPa at coarsening 3-4) it
    took a flat sample before the real peak for the strength, so the caller turns it off
    (0) with the step cutoff (the LAMMPS references, step cutoff too, never trigger it)."""
    from upscale.analysis.stress import curve_metrics, extensometer_metrics  # noqa: PLC0415

    def metrics(**kw):
        return curve_metrics(strains, stresses, fit_max_strain=fit_max_strain,
                             plateau_fraction=plateau_fraction, **kw)

    res = metrics()
    if first is not None and res["failed"] and res["failure_strain"] < first["strain"] - 1e-12:
        plain = {"strength_first_drop_GPa": res["strength_GPa"],
                 "strain_at_peak_first_drop": res["strain_at_peak"]}
        res.update(metrics(failure_from_strain=first["strain"]))
        res.update(plain)
    ipk = int(np.nonzero(np.asarray(strains) == res["strain_at_peak"])[0][0]) + 1
    res.update(extensometer_metrics(strains[:ipk], exts[:ipk], stresses[:ipk],
                                    res["strain_at_peak"], fit_max_strain))
    return res


def dynamic_tension(model, grip: float = 50.0, speed: float = 1.0, dt: float = 1.0,
                    max_strain: float = 0.3, sample: int = 100, fit_max_strain: float = 0.02,
                    progress=None, gtol: float = 1e-4, temperature: float = 10.0,
                    tdamp: float = 100.0, seed: int = 12345, ghost: str = "local",
                    monitor=None, clamp: bool | None = None, stability: bool = False,
                    planes=None, gauge_planes=None,
                    checkpoint=None, checkpoint_every: int = 500, resume: bool = False,
                    output=None, engine_progress: bool = False, integrator: str = "verlet",
                    outer_dt: float | None = None, inner: int | None = None,
                    split: str | None = None, grow=None, grow_thermal: bool = True) -> dict:
    """Dynamic tension of an open coarse tube with end grips (module docstring).

    Returns a dict like the LAMMPS runner's: ``curve`` (strain, stress_GPa, time_ps,
    extensometer_strain, and per sample ``atoms_off_wall`` and ``free_atom_kinetic_eV``),
    the curve metrics (with ``youngs_modulus_ext_TPa``, ``strain_at_peak_ext`` on the
    extensometer strain, whose window is in ``extensometer``),
    ``first_damage`` (strain, atoms, distance to the vacancy), ``L0_A``,
    ``radius_relaxed_A``, ``dof``, ``wall_s`` (``setup_relax_s`` + ``dynamics_s``), the final
    unknowns (``positions``, ``delta``) and ``damage``. ``monitor(step, y, v, delta,
    stress)``, if given, is called at every sample; ``ghost`` picks the correction's stretch
    (module docstring); ``temperature=0`` runs NVE from rest; ``clamp``: as
    :func:`open_tube_with_grips`; ``planes``, ``gauge_planes``: the grip and gauge planes
    (:func:`open_tube_with_grips`); the grips' particles' sublattice shifts are held with
    them (see the code); ``stability`` also applies
    the lattice-stability rule (:meth:`DCBRDefectTube.check_stability`) every ``sample``
    steps (its time in ``stability_s``).

    The time loop is :func:`~upscale.experiments.pull.pull` on :class:`_TubePull` (the
    engine's velocity Verlet with :class:`~upscale.engine.thermostats.NoseHoover` on x, y
    and the shifts, the grips as :class:`~upscale.engine.conditions.Grip` conditions, the
    blow-up guard); ``checkpoint`` (a path: a checkpoint every ``checkpoint_every`` steps),
    ``resume`` (continue from that checkpoint, bit for bit), ``output`` (an
    :class:`~upscale.engine.output.Output`: extxyz / VTK frames) and ``engine_progress``
    (the engine's progress bar).

    ``integrator="respa"``: multiple time stepping
    (:class:`~upscale.engine.respa.RESPA`), the coarse particles' lattice energy at the
    outer step ``outer_dt`` fs, the atomistic region, its coupling and the ghost-force
    dead load (with the coarse energy's expansion in the shifts,
    :meth:`~upscale.models.dcbr_engine.DCBRDefectTubeModel.prepare_split`) at ``inner``
    steps of ``dt`` in each (``outer_dt = inner dt``; give either). ``sample`` stays
    counted in steps of ``dt`` (a multiple of ``inner``), so the stress samples are the
    same blocks of time; ``dt_fs`` in the result is then the outer step. ``split``: which
    forces are slow (:data:`~upscale.models.dcbr_engine.SPLITS`; default
    :data:`~upscale.models.dcbr_engine.MTS_SPLIT`, ``"ghost"``): ``"coarse"`` all the
    coarse particles' lattice energy and hourglass links and the ghost-force dead load;
    ``"ghost"`` the same less the dead load, which is fast (the energy drift at a 5 fs outer
    step comes from the dead load applied as an impulse); ``"interface"`` the lattice
    energy of the particles with a slave in their G stencil fast; ``"atoms-free"`` both
    fast, so that the slow forces never act on the atoms (more work per fast step).

    ``grow`` (clamped grips): a :class:`~upscale.models.dcbr_defect.DCBRDefectTube`
    of the same tube whose atomistic region contains ``model``'s, e.g. the band about a
    disc. The run starts on ``model``; at the first sample at which one of its atoms has a
    broken bond (the crack has started, and a crack cannot leave an atomistic region: at
    its edge the coarse link rule does not carry the tip)
    the state is carried over to ``grow`` (:meth:`~upscale.models.dcbr_defect.DCBRDefectTube.
    carry_state`, set up by :func:`grow_region`) and the run continues on it. A disc
    carries the loading up to the crack at a fraction of the band's cost; the band then
    carries the crack around the tube. The result's ``grown_at`` gives the step, time and
    strain of the switch (None if it did not happen), ``region_free_atoms`` the free atoms
    before and after, ``dynamics_before_growth_s`` the wall time of the dynamics up to the
    switch. ``grow_thermal`` (default): the atoms that become free get thermal velocities at
    ``temperature`` on top of their carried ones (drawn as at the start, from ``seed`` and
    the step), which the coarse state cannot carry.
    """
    from upscale.analysis.stress import Extensometer  # noqa: PLC0415

    if not (grip > 0 and speed > 0 and dt > 0 and 0 < max_strain <= 1 and sample >= 1):
        raise ValueError(f"grip={grip}, speed={speed}, dt={dt}, max_strain={max_strain}, "
                         f"sample={sample}; valid: all > 0, max_strain <= 1, sample >= 1")
    if not (temperature >= 0 and tdamp > 0):
        raise ValueError(f"temperature={temperature!r} K, tdamp={tdamp!r} fs; valid: "
                         "temperature >= 0 (0: no thermostat), tdamp > 0")
    from upscale.models.dcbr_engine import MTS_SPLIT, SPLITS  # noqa: PLC0415

    if split is not None and split not in SPLITS:
        raise ValueError(f"split={split!r}; valid: {', '.join(map(repr, SPLITS))}")
    if split is not None and integrator != "respa":
        raise ValueError(f"split={split!r} with integrator={integrator!r}; valid: a force "
                         "split needs integrator='respa'")
    split = MTS_SPLIT if split is None else split
    if integrator not in ("verlet", "respa"):
        raise ValueError(f"integrator={integrator!r}; valid: 'verlet' (velocity Verlet at dt) "
                         "or 'respa' (multiple time stepping, outer_dt / inner)")
    if integrator == "respa":
        if inner is None and outer_dt is None:
            raise ValueError("integrator='respa' needs outer_dt (fs) or inner (steps of dt)")
        if inner is None:
            inner = int(round(outer_dt / dt))
        if outer_dt is None:
            outer_dt = inner * dt
        if not (inner >= 1 and abs(inner * dt - outer_dt) < 1e-9 * outer_dt
                and sample % inner == 0):
            raise ValueError(f"outer_dt={outer_dt!r}, inner={inner!r}, dt={dt!r}, "
                             f"sample={sample!r}; valid: outer_dt = inner * dt and sample a "
                             "multiple of inner")
        dt, sample = float(outer_dt), sample // int(inner)
    else:
        inner = None
    if ghost not in ("local", "grips"):
        raise ValueError(f"ghost={ghost!r}; valid: 'local' (each side's correction at the "
                         "stretch its interface particles carry) or 'grips' (at the grips' strain)")
    if grow is not None and not model.nf:
        raise ValueError(f"grow with {model.nf} free atoms; valid: a model with an "
                         "atomistic region")
    t0 = time.perf_counter()
    acc = ACC_UNIT
    st = open_tube_with_grips(model, grip, gtol, clamp=clamp, planes=planes,
                              gauge_planes=gauge_planes, grows_to=grow)
    st_grow = None if grow is None else grow_region(grow, model, st)
    y, d, L0, R, area = st["y"], st["delta"], st["L0"], st["R"], st["area"]
    bottom, top, zb, zt, gauge = st["bottom"], st["top"], st["zb"], st["zt"], st["gauge"]
    grips, nd, grip_rows = bottom | top, len(model.dof_idx), st["grip_rows"]
    free_len = L0 - 2 * grip
    banded = getattr(model, "band_z", None) is not None
    # where first damage is located: against the grip planes in a pristine tube with bands
    # (where LAMMPS's break), against the vacancy when there is one
    at_planes = banded and not np.any(model.removed)
    t_relax = time.perf_counter() - t0
    c_relax = time.process_time()
    t_grown = None  # wall time of the dynamics when the region grew (this process's)

    def z_ext(y):  # the extensometer's points: every particle, then the free atoms
        return np.r_[model.particle_positions(y)[:, 2], y[nd:, 2]]

    def extensometer(tube, st_):  # (on the set-up state, the start of the pull)
        return Extensometer(np.r_[tube.particle_positions(st_["y"])[:, 2],
                                  st_["y"][len(tube.dof_idx):, 2]],
                            *Extensometer.window(st["gb"], st["gt"]),
                            weights=np.r_[tube.natoms_n, np.ones(tube.nf)])
    ext = extensometer(model, st)
    z = y[:, 2]
    zlo, zhi = model.particle_positions(y)[:, 2].min(), model.particle_positions(y)[:, 2].max()
    mass, mass_d = model.masses()
    vz = 1e-3 * speed  # Å/fs
    v = np.zeros_like(y)
    # the axial velocity ramp: the uniform strain rate of the gauge (a ramp ending elsewhere
    # starts the gauge's axial standing wave)
    zc = 0.5 * (st["gb"] + st["gt"])  # between the gauge planes, as LAMMPS's velocity ramp
    v[:, 2] = np.clip((z - zc) / (0.5 * gauge), -1, 1) * vz
    v[bottom, 2], v[top, 2] = -vz, vz
    vd = np.zeros_like(d)
    movable = ~grips
    # thermal start and Nose-Hoover thermostat on the x, y velocities of the free part (and
    # the sublattice shifts), as LAMMPS's fix nvt with compute temp/partial 1 1 0
    kB = K_B_EV
    rng = np.random.default_rng(seed)
    thermo = temperature > 0
    if thermo:
        sd = np.sqrt(kB * temperature * acc / mass[movable])
        vt = rng.standard_normal((int(movable.sum()), 3)) * sd[:, None]
        vt -= np.sum(mass[movable, None] * vt, axis=0) / mass[movable].sum()  # no net momentum
        v[movable] += vt
        vd += rng.standard_normal(vd.shape) * np.sqrt(kB * temperature * acc / mass_d)[:, None]
        # slave particles carry at most half their atoms (often none): their shifts have
        # next to no stiffness and would drift with any velocity given to them
        vd[model.slave_idx] = 0.0
    # the grips are LAMMPS's rigid bodies: their particles' sublattice shifts (B atoms
    # against A atoms) are held too. Left free, the shift of an end row at coarsening 1 (few
    # links, little stiffness) drifts with its thermal velocity and breaks links inside a
    # grip, which the strength rule then takes as the first damage. Not so a clamped grip's
    # edges (DCBRDefectTube.clamp_grips, ``grip_edges``): their energy is the strain energy
    # of the gauge material between the plane and the first free row (their weight is its
    # length share, their G its strain), free atoms in LAMMPS whose sublattices relax, so
    # their shifts stay free; held, that gap would take the unrelaxed (stiffer) response
    # (``python -m validation dcbr-energy``: without the shift relaxation the strain energy
    # is several per cent high). The static grip stiffness relaxes them likewise.
    def free_shifts(tube, grips):
        """(shifts free (N,) bool, thermostat degrees of freedom)."""
        df = np.ones(tube.N, bool)
        df[tube.dof_idx[grips[:len(tube.dof_idx)]]] = False
        if getattr(tube, "clamp", None) is not None:
            df[tube.grip_edges] = True
        return df, 2 * int((~grips).sum()) + 3 * int((df & ~tube.is_slave).sum())
    dfree, ndf = free_shifts(model, grips)
    vd[~dfree] = 0.0
    # the ghost-force correction on each side of the atomistic region at the stretch that
    # side's interface particles carry (their own uniform map's lam_z), so that it follows
    # each half as it relaxes after the tube breaks
    # (a carrier held by a grip does not stretch: with bands across the grip planes only
    # the gauge's carriers measure a side's stretch)
    def sides(tube, grips):
        """The carriers of the pads below and above the vacancy, less the grips' (c_lo, c_hi)."""
        held = np.zeros(tube.N, bool)
        held[tube.dof_idx] = grips[:len(tube.dof_idx)]
        pc = tube._pad["c"]
        pad_lo = tube.x0[pc, 2] < tube.vacancy_theta_z[1]
        return np.unique(pc[pad_lo & ~held[pc]]), np.unique(pc[~pad_lo & ~held[pc]])
    c_lo, c_hi = sides(model, grips)

    def refresh_ghost(y, strain):
        if ghost == "grips" or model.nf == 0:
            model.prepare_step(L0 * (1 + strain))
            model._ghost["Lz"] = float(L0)  # the open tube's energy is called with L0
            _hold_grip_ghost(model, st)
            return
        F = model.gain.deformation(model.particle_positions(y), np.array([0.0, 0.0, L0]))
        with np.errstate(invalid="ignore", divide="ignore"):  # failed particles: F = 0
            _, _, lz, _ = uniform_map_frame(np.einsum("nia,nab->nib", F, model.S))

        def side(c):  # mean stretch of the side's intact interface particles (none: at rest)
            ok = model.alive[c] & np.isfinite(lz[c])
            return model.L * float(np.mean(lz[c][ok])) if ok.any() else float(L0)
        model.prepare_sides(side(c_lo), side(c_hi), L0)
        _hold_grip_ghost(model, st)

    rec = {"strains": [], "stresses": [], "times": [], "off_wall": [], "kinetic": [],
           "exts": [], "blk": [], "eblk": [], "smax": 0.0, "failed": False, "first": None,
           "t_stab": 0.0, "step": 0}
    sep0 = 2 * vz  # separation rate

    def on_sample(step, y, v, d, break_links, refresh_forces):
        """The end of a ``sample``-step block (both loops): the block's stress, the
        diagnostics, the failure rules, the ghost-force refresh; True to stop."""
        blk, eblk = rec["blk"], rec["eblk"]
        strain = sep0 * step * dt / gauge
        s = float(np.mean(blk)) / area * EV_PER_A3_IN_GPA
        rec["exts"].append(float(np.mean(eblk)))
        rec["blk"], rec["eblk"] = [], []
        # the block's mean stress belongs to its mid-time (as the LAMMPS runner)
        rec["strains"].append(sep0 * (step - 0.5 * sample) * dt / gauge)
        rec["stresses"].append(s)
        rec["times"].append(step * dt * 1e-3)
        # diagnostics: free atoms more than 3 Å off the wall (thrown off), and the
        # kinetic energy of the free atoms (eV)
        xf = y[nd:]
        cc = model.particle_positions(y)[:, :2].mean(axis=0)
        rec["off_wall"].append(int(np.sum(np.abs(np.hypot(xf[:, 0] - cc[0], xf[:, 1] - cc[1])
                                                  - R) > 3.0)))
        rec["kinetic"].append(float(0.5 * np.sum(mass[nd:, None] * v[nd:] ** 2) / acc))
        rec["smax"] = smax = max(rec["smax"], s)
        if progress is not None:
            progress(strain, s)
        if monitor is not None:  # monitor(step, y, v, delta, stress): a look inside
            monitor(step, y, v, d, s)
        first = rec["first"]
        # the atoms' damage, read by the first-damage record and the growth trigger
        grows = grow is not None and rec.get("grown_at") is None
        mu = model.atom_damage(y, d, L0) if model.nf and (first is None or grows) else None
        if first is None and model.nf:
            if mu.max() > 0 and at_planes:  # where: each atom's signed distance into
                # the gauge from the nearer grip plane (negative: inside the grip)
                first = _where(y[nd:][mu > 0, 2], strain, 0.5 * sep0 * step * dt, zb, zt)
            elif mu.max() > 0:  # where the first bonds broke, on the unrolled wall
                xf = y[nd:][mu > 0]
                c = model.particle_positions(y)[:, :2].mean(axis=0)
                th = np.arctan2(xf[:, 1] - c[1], xf[:, 0] - c[0])
                dth = np.angle(np.mean(np.exp(1j * (th - model.vacancy_theta_z[0]))))
                zv = model.vacancy_theta_z[1] * L0 / model.L  # on the relaxed tube
                zmid = 0.5 * (zlo + zhi) - 0.5 * (model.x0[:, 2].min() + model.x0[:, 2].max()) \
                    * L0 / model.L
                first = {"strain": strain, "n_atoms": int((mu > 0).sum()),
                         "distance_to_vacancy_A": float(np.hypot(
                             R * dth, xf[:, 2].mean() - (zv + zmid)))}
        broke = break_links()
        if broke and at_planes and first is None:  # the first damage is a coarse link's
            g = model.gain
            hit = np.zeros(model.N, bool)
            hit[g.pair_i[~model.intact]] = True
            hit |= ~model.alive
            first = _where(model.particle_positions(y)[hit, 2], strain,
                           0.5 * sep0 * step * dt, zb, zt, what="particles")
        rec["first"] = first
        refresh_ghost(y, strain)
        refresh_forces()
        if s < 0.95 * smax:
            rec["failed"] = True
        stop = (rec["failed"] and s < 0.2 * smax) or strain >= max_strain
        if grows and not stop and mu is not None and mu.max() > 0:  # the crack started
            rec["grown_at"] = {"step": int(step), "time_ps": step * dt * 1e-3,
                               "strain": float(strain)}
            rec["grow_pending"] = True
            nonlocal t_grown
            t_grown = time.perf_counter() - t0 - t_relax
            return True
        return stop

    model0 = model

    def grow_to(y_, d_, v_, vd_):
        """The scene moved to ``grow`` (:class:`_TubePull`): its state carried over
        from the current tube's (none on a resumed run, whose state is the checkpoint's),
        then its ghost-force correction at that state."""
        nonlocal model, st, nd, grips, mass, mass_d, dfree, ndf, c_lo, c_hi, ext
        old, model, st = model, grow, st_grow
        nd, grips = len(model.dof_idx), st["bottom"] | st["top"]
        mass, mass_d = model.masses()
        dfree, ndf = free_shifts(model, grips)
        c_lo, c_hi = sides(model, grips)
        ext = extensometer(model, st)
        out = {"tube": model, "st": st, "dfree": dfree, "ndf": ndf, "ext": ext,
               "y": None, "delta": None, "v": None, "vdelta": None}
        if y_ is not None:
            yn, dn, vn, vdn = model.carry_state(old, y_, d_, v_, vd_, Lz=L0)
            vdn[~dfree] = 0.0
            if thermo and grow_thermal:  # the new atoms' thermal velocities (the coarse
                # state has none), drawn as at the start, from the seed and the step
                new = nd + np.nonzero(~np.isin(model.free_idx, old.free_idx))[0]
                rg = np.random.default_rng([seed, int(rec["grown_at"]["step"])])
                vt = rg.standard_normal((len(new), 3)) * np.sqrt(
                    kB * temperature * acc / mass[new])[:, None]
                vn[new] += vt - vt.mean(axis=0)
            refresh_ghost(yn, 0.0)
            out.update(y=yn, delta=dn, v=vn, vdelta=vdn)
        return out

    scene = {"rec": rec, "vz": vz, "L0": L0, "split": split, "temperature": temperature,
             "tdamp": tdamp, "thermo": thermo, "inner": inner, "dt": dt, "gauge": gauge,
             "z_ext": z_ext, "stability": stability, "on_sample": on_sample,
             "grow": None if grow is None else grow_to}
    spec = _TubePull(scene, model, st, y, d, v, vd, dfree, ndf, ext)
    spec.max_steps = int(np.ceil(max_strain * gauge / (2 * vz * dt))) + 2 * sample
    protocol = Dynamic(load="tension", speed=speed, grip=grip, dt=dt, sample_every=sample,
                       temperature=temperature, tau=tdamp * 1e-3, maximum=max_strain,
                       seed=seed)
    out = pull(spec, protocol, checkpoint=None if checkpoint is None else
               Checkpoint(checkpoint, int(checkpoint_every)), resume=resume, output=output,
               engine_progress=engine_progress, meta={"scene": "dcbr dynamic tension"})
    rec["blowup_after_failure"] = out["blowup_after_failure"]
    step, (y, d) = out["steps"], spec.unknowns()
    strains, stresses, exts, first = rec["strains"], rec["stresses"], rec["exts"], rec["first"]
    times, off_wall, kinetic, t_stab = rec["times"], rec["off_wall"], rec["kinetic"], rec["t_stab"]
    res = {"model": "dcbr-defect", "protocol": "dynamic", "chirality":
           [model.lattice.n, model.lattice.m], "coarsening": model.coarsening,
           "particles": model.N, "dof": model.dof, "atoms": model.n_atoms, "L0_A": float(L0),
           "radius_relaxed_A": R, "area_A2": area, "grip_A": grip, "speed_A_per_ps": speed,
           "dt_fs": dt, "integrator": integrator, "inner_steps": inner,
           "steps": step, "free_length_A": free_len, "gauge_length_A": gauge,
           "grip_rows_distance_A": grip_rows,
           "curve": {"strain": strains, "stress_GPa": stresses, "time_ps": times,
                     "atoms_off_wall": off_wall, "free_atom_kinetic_eV": kinetic,
                     "extensometer_strain": exts},
           "extensometer": ext.describe()}
    res.update(run_metrics(strains, stresses, exts, first, fit_max_strain,
                           plateau_fraction=0.0 if model.cutoff == "step" else 0.05))
    res["first_damage"] = first
    res["grown_at"] = rec.get("grown_at")
    res["dynamics_before_growth_s"] = t_grown
    res["region_free_atoms"] = [int(model0.nf)] + ([int(grow.nf)] if grow is not None else [])
    res["blowup_after_failure"] = rec.get("blowup_after_failure")
    res["positions"], res["delta"] = y, d
    res["damage"] = model.damage
    res["wall_s"] = time.perf_counter() - t0
    res["setup_relax_s"] = t_relax  # build excluded (the caller times it)
    res["stability_s"] = t_stab
    res["grip_planes_A"] = [float(zb), float(zt)]
    res["gauge_planes_A"] = [float(st["gb"]), float(st["gt"])]
    res["grip_bottom"], res["grip_top"] = bottom, top  # masks over the rows of positions
    res["dynamics_s"] = res["wall_s"] - t_relax
    res["dynamics_cpu_s"] = time.process_time() - c_relax  # this process's CPU time
    return res
