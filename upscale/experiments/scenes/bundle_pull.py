"""The bundle's dynamic tension on the shared pull (:func:`upscale.experiments.pull.pull`).

The protocol is the one of :mod:`upscale.experiments.scenes.bundle` (its module docstring,
steps 1-3): the open bundle minimised (and optionally quenched), grips on every tube moved
rigidly apart, the free part on a linear axial velocity ramp plus Gaussian thermal
velocities under a Nose-Hoover chain on its x, y velocities and the coarse tubes' shifts,
r-RESPA or velocity Verlet. :class:`_BundlePull` reads each tube's grips every 10 fs (the
references' ``fix ave/time`` readings), and every ``sample_every`` fs gives the sample: the
mean of its readings as each tube's stress, the bundle stress their mean, the coarse tubes'
links broken (:meth:`~upscale.models.dcbr.model.DCBRModel.break_bonds`, the link rule) and
their ghost-force dead loads renewed at the grips' strain
(:meth:`~upscale.experiments.scenes.bundle.BundleScene.ghost_load`). The loop, the
stop rule (the first sample 5 % below the running maximum, then below 20 % of it), the
checkpoints and the blow-up handling are the pull's.
"""
from __future__ import annotations

import math
import time

import numpy as np

from upscale.constants import K_B_EV, WALL_THICKNESS_A
from upscale.experiments.protocols import Dynamic
from upscale.experiments.pull import PullSpecimen, pull
from upscale.experiments.scenes.bundle import INNER, INTEGRATOR, SEED, particle_rows
from upscale.models.dcbr.model import FIELD as _FIELD

__all__ = ["dynamic_tension", "check_run_options", "tube_failures", "tube_damage"]


def dynamic_tension(scene, *, grip: float | None = None, speed: float = 1.0,
                    temperature: float = 10.0, dt_fs: float = 1.0, tdamp_ps: float = 0.1,
                    max_strain: float = 0.40, seed: int = SEED, sample_every: int = 100,
                    ftol: float = 1e-2, progress: bool = True, max_steps: int = 200000,
                    snapshot_every: int = 500, integrator: str = INTEGRATOR,
                    inner: int = INNER, record_readings: bool = False,
                    thermostat: str = "bundle",
                    per_tube_damping_ps: float | None = None,
                    settle_ps: float = 0.0, chain: int = 3) -> dict:
    """The references' dynamic tension of ``scene`` (a
    :class:`~upscale.experiments.scenes.bundle.BundleScene`; module docstring). Returns the
    result dict: ``curve`` (strain, stress_GPa, stress_per_tube_GPa, time_ps), metrics,
    per-tube failure strains and order, damage per tube, timings.

    ``integrator="respa"`` (default, :data:`~upscale.experiments.scenes.bundle.INTEGRATOR`,
    ``inner`` :data:`~upscale.experiments.scenes.bundle.INNER`): multiple time stepping
    (:class:`upscale.engine.respa.RESPA`), outer step ``inner * dt_fs``: slow is the
    inter-tube van der Waals; fast the tubes (Tersoff, and the coarse tubes whole: their
    atomistic bands and regions need the 1 fs step) at ``dt_fs``. ``inner`` must divide
    10 (the grips are read every 10 fs steps) and the
    scene's vdW must not be held between steps (``vdw_every=1``). ``"verlet"``: velocity
    Verlet at ``dt_fs``. ``thermostat``: ``"bundle"`` (default; one Nose-Hoover chain on
    every tube's free part, the references' ``fix nvt`` on all free atoms) or
    ``"per-tube"`` (one per tube, each on its own free rows and shifts, damping
    ``per_tube_damping_ps``, default ``tdamp_ps * sqrt(ntubes)``: each tube's own heat then
    drives its thermostat as strongly as a tube's heat drives the one thermostat of
    ``ntubes`` like tubes). ``record_readings``: keep every grip reading
    (``curve["readings"]``: time in fs and each tube's tension in eV/Å, every 10 fs)."""
    from upscale.analysis.stress import curve_metrics

    check_run_options(integrator=integrator, inner=inner, thermostat=thermostat, chain=chain,
                      settle_ps=settle_ps, max_strain=max_strain, speed=speed, dt_fs=dt_fs,
                      sample_every=sample_every, vdw_every=int(scene.info.get("vdw_every", 1)))
    per = int(inner) if integrator == "respa" else 1
    t0, c0 = time.perf_counter(), time.process_time()
    grip = scene.info["grip_A"] if grip is None else float(grip)
    start = _minimised_start(scene, dt_fs, settle_ps, ftol, per)
    y, hold = start["y"], start["hold"]
    grips, free, zb, sep0 = _grips(scene, y, hold, grip, speed)
    per_sample = 2.0 * speed * sample_every * dt_fs * 1e-3 / sep0
    if max_strain < 1.5 * per_sample:
        # (the curve's metrics need three samples: sample k sits at strain (k - 1/2) p)
        raise ValueError(f"max_strain={max_strain:g} gives fewer than 3 samples of the curve "
                         f"(one every {per_sample:.3g} strain); valid: max_strain >= "
                         f"{1.5 * per_sample:.3g}, or a smaller sample_every")
    thermo, tau_tube = _thermostat(scene, grips, free, temperature, tdamp_ps, thermostat,
                                   chain, per_tube_damping_ps, start["sim"].state,
                                   (zb, zb + sep0))
    sim = _simulation(scene, start["sim"], y, grips, free, zb, sep0, speed, dt_fs,
                      temperature, seed, thermo, integrator, per)
    spec = _BundlePull(scene, sim, grips, free, per, sample_every, speed, dt_fs,
                       sep0, _central_radius(scene, y), record_readings, snapshot_every)
    spec.max_steps = int(math.ceil(max_steps / per))
    protocol = Dynamic(load="tension", speed=speed, grip=grip, dt=dt_fs,
                       temperature=temperature, tau=tdamp_ps, sample_every=sample_every,
                       maximum=max_strain, seed=seed)
    out = _pull_with_bar(spec, protocol, progress)
    c = spec.curve
    res = {"protocol": "dynamic", "scene": scene.info,
           "protocol_detail": _detail(grip, speed, dt_fs, temperature, sim.integrator.name,
                                      per, chain, tdamp_ps, thermostat, tau_tube, seed, sep0,
                                      sample_every, start),
           "stress_convention": {"wall_thickness_A": WALL_THICKNESS_A, "radius_A": spec.R,
                                 "area": "per tube 2 pi R t; bundle: mean over the tubes"},
           "curve": {k: c[k] for k in ("strain", "stress_GPa", "stress_per_tube_GPa",
                                       "time_ps", "temperature_per_tube_K",
                                       "radius_per_tube_A")}}
    if record_readings:  # every reading: (time fs, per-tube tension eV/Å)
        res["curve"]["readings"] = c["readings"]
    res.update(curve_metrics(c["strain"], c["stress_GPa"]))
    res.update(tube_failures(c["strain"], c["stress_per_tube_GPa"]))
    res["damage"] = tube_damage(scene, sim, y)
    res["dof"] = scene.dof
    res["coarse_links_broken"] = {int(k) + 1: int(v) for k, v in spec.broken_links.items()}
    res["particles"] = int(scene.assembly.system.n)
    res["blowup_after_failure"] = out["blowup_after_failure"]
    res["timing_s"] = {"minimisation": start["wall_s"], "dynamics": out["dynamics_s"],
                       "steps": int(sim.state.step) * per}
    res["wall_s"] = time.perf_counter() - t0
    res["cpu_s"] = time.process_time() - c0
    res["_final_y"] = sim.state.y
    res["_start_y"] = y
    return res


def _pull_with_bar(spec, protocol, progress: bool) -> dict:
    from tqdm.auto import tqdm

    bar = tqdm(disable=not progress, unit="sample", desc="bundle tension", mininterval=1.0)

    def show(rec):
        bar.update(1)
        bar.set_postfix_str(f"strain {100 * rec['load']:.1f}%  stress "
                            f"{rec['response']:.1f} GPa")
    try:
        return pull(spec, protocol, progress=show)
    finally:
        bar.close()


def _detail(grip, speed, dt_fs, temperature, integ_name, per, chain, tdamp_ps, thermostat,
            tau_tube, seed, sep0, sample_every, start) -> dict:
    res_min = start["minimisation"]
    return {"grip_A": grip, "speed_A_per_ps_each_grip": speed, "timestep_fs": dt_fs,
            "temperature_K": temperature, "integrator": integ_name,
            "outer_step_fs": dt_fs * per,
            "thermostat": f"Nose-Hoover chain of {chain} on the free part's vx, vy, damping "
                          f"{tdamp_ps} ps" + (f", one per tube (damping {tau_tube:.4g} ps)"
                                              if thermostat == "per-tube" else
                                              ", on the represented atoms' temperature"),
            "seed": seed, "gauge_length_A": sep0, "sample_every_steps": sample_every,
            "minimisation": None if res_min is None else {
                "converged": bool(res_min.converged), "fmax": float(res_min.fmax),
                "iterations": int(res_min.iterations),
                "coarse_tubes_held": bool(start["hold"].any())},
            "settle": start["settle"]}


# ---------------------------------------------------------------------- set-up
def _minimised_start(scene, dt_fs, settle_ps, ftol, per) -> dict:
    """Step 1: the open bundle minimised (L-BFGS on the atomistic tubes and the vdW, the
    coarse tubes held at their set-up: their shifts are a field with inertia, which a
    static minimiser does not carry), then, with ``settle_ps``, every tube quenched
    together (:func:`_settle`)."""
    from upscale.engine.conditions import Fixed, Region
    from upscale.engine.minimisers import LBFGS

    asm = scene.assembly
    n = asm.system.n
    coarse = scene.coarse_models()
    hold = np.zeros(n, bool)
    for _, bm, _ in coarse:
        hold[bm.rows] = True
    conds0 = list(scene.extra_conditions())
    if hold.any():
        conds0.append(Fixed(Region("coarse tubes", hold)))
    sim0 = asm.simulation(conditions=conds0)
    scene.start(sim0.state)
    t = time.perf_counter()
    res_min = sim0.minimise(LBFGS(ftol=ftol, max_iter=500), raise_on_fail=False) \
        if not hold.all() else None
    settle = None
    if coarse and settle_ps > 0:
        sim0, settle = _settle(asm, scene, sim0, dt_fs, settle_ps, ftol, per)
    return {"sim": sim0, "y": sim0.state.y.copy(), "hold": hold, "minimisation": res_min,
            "settle": settle, "wall_s": time.perf_counter() - t}


def _grips(scene, y, hold, grip, speed):
    """Step 2's grips: on every tube the rows beyond two planes ``grip`` inside the bundle's
    end atoms (LAMMPS's grips: the same planes for every tube; the atomistic tubes' end
    atoms set them; a coarse tube's particle rows' shifts held with them,
    :func:`_held_shifts`; its atomistic bands straddle the planes); each pair moves at
    -+``speed`` Å/ps from where the minimisation left it. Returns (grips per tube, free
    rows, bottom plane z, gauge length)."""

    asm = scene.assembly
    n = asm.system.n
    atomistic = ~hold
    za = y[atomistic, 2] if atomistic.any() else y[:, 2]
    zb, zt = float(za.min()) + grip, float(za.max()) - grip
    sep0 = zt - zb
    if sep0 < 10.0:
        raise ValueError(f"grip={grip} Å leaves a gauge of {sep0:.2f} Å; valid: 2 grip <= "
                         "L - 10 Å")
    v = speed * 1e-3                        # Å/fs (the scene's time unit is the fs)
    grips, bot, top = [], np.zeros(n, bool), np.zeros(n, bool)
    for k, b in enumerate(scene.bodies):
        mine = np.zeros(n, bool)
        mine[asm.rows(b.name)] = True
        gb, gt = mine & (y[:, 2] < zb), mine & (y[:, 2] > zt)
        bot |= gb
        top |= gt
        grips.append((_moving_grip(f"bot{k + 1}", gb, y, asm.system.x0, -v),
                      _moving_grip(f"top{k + 1}", gt, y, asm.system.x0, v)))
    return grips, ~(bot | top), zb, sep0


def _moving_grip(name, mask, y, x0, vz):
    """A :class:`~upscale.engine.conditions.Grip` of the rows ``mask`` moving at ``vz``
    (Å/fs) along z from where they are in ``y``: the prescribed displacement from the
    reference rows ``x0`` is u(t) = (y - x0) + vz t e_z, per row (a grip given a velocity
    moves its rows rigidly from ``x0``, which would put the minimised rows back there)."""
    from upscale.engine.conditions import Grip, Region

    idx = np.flatnonzero(mask)
    u0, vel = y[idx] - x0[idx], np.array([0.0, 0.0, vz])
    return Grip(Region(name, mask), displacement=lambda t: u0 + vel * t, record_every=0)


def _gripped(scene, grips) -> dict:
    """{tube index: (n,) bool}: a coarse tube's rows in its grips."""
    return {k: (grips[k][0].region.mask | grips[k][1].region.mask)[bm.rows]
            for k, bm, _ in scene.coarse_models()}


def _held_shifts(scene, grips) -> dict:
    """{tube index: (n,) bool}: a coarse tube's particle rows in its grips, whose shifts
    the grips hold at their set-up value (the single tube's pull)."""
    out = {}
    for k, g in _gripped(scene, grips).items():
        held = np.zeros(len(g), bool)
        nd = particle_rows(scene.coarse[k][0])
        held[:nd] = g[:nd]
        out[k] = held
    return out


def _free_shifts(scene, grips) -> dict:
    """{tube index: rows (assembled) of a coarse tube's free shifts}: its particle rows
    outside its grips."""
    asm = scene.assembly
    return {k: asm.rows(scene.bodies[k].name).start
            + np.flatnonzero(~held[:particle_rows(scene.coarse[k][0])])
            for k, held in _held_shifts(scene, grips).items()}


def _thermostat(scene, grips, free, temperature, tdamp_ps, thermostat, chain, per_tube_ps,
                state, planes):
    """Step 2's Nose-Hoover chain on the free part's x, y velocities and the coarse tubes'
    free shifts: one for the bundle on the temperature of the atoms the rows stand for
    (:mod:`upscale.experiments.scenes.bundle_thermostat`; the coarse tubes' atoms counted
    at ``state`` between the grip ``planes``), or one per tube on its own rows;
    (thermostat or None, per-tube damping in ps)."""
    if not temperature > 0:
        return None, tdamp_ps
    from upscale.engine.thermostats import NoseHooverChain, ThermostatGroup

    asm = scene.assembly
    n = asm.system.n
    tubes = [asm.rows(b.name) for b in scene.bodies]
    coarse_of = {k: bm for k, bm, _ in scene.coarse_models()}
    nshift = {k: len(r) for k, r in _free_shifts(scene, grips).items()}
    if thermostat == "bundle":
        from upscale.experiments.scenes.bundle_thermostat import chain as represented

        frows = np.zeros(n, bool)
        for k in coarse_of:
            frows[tubes[k]] = True
        fields = tuple(f"{scene.bodies[k].name}/{_FIELD}" for k in coarse_of)
        return represented(scene, state, free, _free_shifts(scene, grips), planes,
                           temperature, 1e3 * tdamp_ps, chain, fields,
                           frows if fields else None), tdamp_ps
    tau = tdamp_ps * math.sqrt(len(tubes)) if per_tube_ps is None else float(per_tube_ps)
    members = []
    for k, rows in enumerate(tubes):
        mk = np.zeros(n, bool)
        mk[rows] = True
        nk, fk = 2 * int((free & mk).sum()), ()
        if k in coarse_of:
            nk += 3 * nshift[k]
            fk = (f"{scene.bodies[k].name}/{_FIELD}",)
        members.append(NoseHooverChain(temperature, 1e3 * tau, region=free & mk, chain=chain,
                                       components=(0, 1), fields=fk,
                                       field_region=mk if fk else None, ndf=nk, k_B=K_B_EV))
    return ThermostatGroup(members), tau


def _simulation(scene, sim0, y, grips, free, zb, sep0, speed, dt_fs, temperature,
                seed, thermo, integrator, per):
    """The pull's simulation at the minimised start, with step 2's velocities: the axial
    ramp between the grip speeds plus Gaussian thermal velocities (x, y temperature
    exactly T, zero momentum), the coarse tubes' free shifts thermal too (their reduced
    masses), their grips' shifts held, their ghost-force loads at the start."""
    from upscale.engine.conditions import Region
    from upscale.engine.fields import FixedField
    from upscale.engine.integrators import VelocityVerlet

    asm = scene.assembly
    n, mass = asm.system.n, asm.system.mass
    tubes = [asm.rows(b.name) for b in scene.bodies]
    coarse = scene.coarse_models()
    v = speed * 1e-3
    rng = np.random.default_rng(seed)
    vel = np.zeros((n, 3))
    field_v = {}
    free_shift = _free_shifts(scene, grips)
    if temperature > 0:
        vel[free] = rng.normal(size=(int(free.sum()), 3)) * np.sqrt(
            K_B_EV * temperature / mass[free])[:, None]
        p = (mass[free, None] * vel[free]).sum(axis=0) / mass[free].sum()
        vel[free] -= p
        Txy = (mass[free, None] * vel[free, :2] ** 2).sum() / (2 * free.sum() * K_B_EV)
        vel[free] *= math.sqrt(temperature / Txy)
        for k, bm, _ in coarse:
            em = bm.model
            nd = particle_rows(em)
            md = em.fields()[_FIELD].inertia[:nd]
            vd = np.zeros((n, 3))
            r0 = tubes[k].start
            vd[r0:r0 + nd] = rng.normal(size=(nd, 3)) * np.sqrt(
                K_B_EV * temperature / md)[:, None]
            keep = np.zeros(n, bool)
            keep[free_shift[k]] = True
            vd[~keep] = 0.0
            field_v[f"{scene.bodies[k].name}/{_FIELD}"] = vd
    vel[free, 2] += np.clip(-v + 2 * v * (y[free, 2] - zb) / sep0, -v, v)
    for gb, gt in grips:
        vel[gb.region.index, 2], vel[gt.region.index, 2] = -v, v
    conds = [g for pair in grips for g in pair] + list(scene.extra_conditions())
    for k, held in _held_shifts(scene, grips).items():
        if held.any():
            mask = np.zeros(n, bool)
            mask[tubes[k]] = held
            name = scene.bodies[k].name
            conds.append(FixedField(Region(f"{name} grip shifts", mask), f"{name}/{_FIELD}",
                                    (0, 1, 2), hold=True))
    if integrator == "respa":
        from upscale.engine.respa import RESPA

        integ = RESPA(dt_fs * per, per, thermostat=thermo, force=True)
    else:
        integ = VelocityVerlet(float(dt_fs), force=True, thermostat=thermo)
    sim = asm.simulation(conditions=conds, integrator=integ)
    sim.state.y[...] = y
    sim.state.v[...] = vel
    _copy_fields(sim0.state, sim.state)
    for key, vd in field_v.items():
        sim.state.field_v[key][...] = vd
    scene.ghost_load(sim.state, 0.0, _gripped(scene, grips))
    return sim


# ---------------------------------------------------------------------- helpers
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
    scene.ghost_load(sim.state, 0.0)
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


# ---------------------------------------------------------------------- the pull
class _BundlePull(PullSpecimen):
    """The bundle as a :class:`~upscale.experiments.pull.PullSpecimen` (module docstring):
    each tube's grips read every 10 fs, the sample every ``sample_every`` fs."""

    def __init__(self, scene, sim, grips, moving, per, sample_every, speed, dt_fs, sep0, R,
                 record_readings, snapshot_every):
        asm = scene.assembly
        self.simulation, self.scene, self.grips = sim, scene, grips
        self.inner, self.read_every = per, 10 // per
        self.nread = sample_every // 10
        self.sample_every, self.speed, self.dt_fs, self.sep0, self.R = \
            sample_every, speed, dt_fs, sep0, R
        self.record_readings, self.snapshot_every = record_readings, snapshot_every
        self.update_forces = getattr(sim.integrator, "update_forces", None) \
            or (lambda s: s.update_forces())
        self.coarse = scene.coarse_models()
        self.gripped = _gripped(scene, grips)
        self.broken_links: dict = {}
        self.snapshots: list = []
        tubes = [asm.rows(b.name) for b in scene.bodies]
        mass = asm.system.mass
        self.t_rows = [np.flatnonzero(moving[r]) + r.start for r in tubes]
        self.t_mass = [mass[i, None] for i in self.t_rows]
        self.t_shift = {}
        for k, bm, _ in self.coarse:
            idx = _free_shifts(scene, grips)[k]
            self.t_shift[k] = (f"{scene.bodies[k].name}/{_FIELD}", idx,
                               bm.model.fields()[_FIELD].inertia[idx - tubes[k].start, None])
        self.acc, self.tacc = np.zeros(len(tubes)), np.zeros((len(tubes), 2))
        self.curve = {"strain": [], "stress_GPa": [], "stress_per_tube_GPa": [],
                      "time_ps": [], "temperature_per_tube_K": [], "radius_per_tube_A": [],
                      "readings": []}

    def steps_fs(self, sim) -> int:
        return int(sim.state.step) * self.inner

    def load(self, sim) -> float:
        """The last sample's strain (the run ends with the first sample past the maximum)."""
        c = self.curve["strain"]
        return c[-1] if c else 0.0

    def read(self, sim) -> None:
        if int(sim.state.step) % self.read_every:
            return
        for k, (gb, gt) in enumerate(self.grips):
            # force on the bottom grip's atoms from the tube: -reaction; tension = mean of
            # the bottom one's +z and the top one's -z
            self.acc[k] += 0.5 * (-gb.reaction_now[2] + gt.reaction_now[2])
        self.tacc += np.nan_to_num(np.array(self.tube_temperatures(sim), dtype=float))
        if self.record_readings:
            self.curve["readings"].append([sim.state.t] + [
                0.5 * (-gb.reaction_now[2] + gt.reaction_now[2]) for gb, gt in self.grips])

    def sample(self, sim) -> dict:
        from upscale.analysis.stress import stress_from_force

        step = self.steps_fs(sim)
        Fk = self.acc / self.nread
        if self.coarse:
            self.renew_coarse(sim, 2.0 * self.speed * step * self.dt_fs * 1e-3 / self.sep0)
        tmid = (step - 0.5 * self.sample_every) * self.dt_fs * 1e-3
        eps = 2.0 * self.speed * tmid / self.sep0
        sk = [float(stress_from_force(f, self.R, WALL_THICKNESS_A, 1)) for f in Fk]
        s = float(np.mean(sk))
        c = self.curve
        c["strain"].append(eps)
        c["stress_GPa"].append(s)
        c["stress_per_tube_GPa"].append(sk)
        c["time_ps"].append(tmid)
        c["temperature_per_tube_K"].append((self.tacc / self.nread).tolist())
        c["radius_per_tube_A"].append(self.tube_radii(sim))
        if self.snapshot_every and step % self.snapshot_every == 0:
            self.snapshots.append((step, sim.state.y.copy()))
        self.acc, self.tacc = np.zeros_like(self.acc), np.zeros_like(self.tacc)
        return {"load": eps, "response": s}

    def renew_coarse(self, sim, strain_now: float) -> None:
        """The coarse tubes' links broken (the link rule) and their ghost-force loads
        renewed at the grips' strain, then the forces."""
        for k, bm, _ in self.coarse:
            n = bm.model.break_bonds(bm.sub(sim.state))
            self.broken_links[k] = self.broken_links.get(k, 0) + n
        self.scene.ghost_load(sim.state, strain_now, self.gripped)
        self.update_forces(sim)

    def tube_temperatures(self, sim) -> list:
        """Per tube, the kinetic temperature of the x, y motion of its moving rows (eq. (1)
        of :mod:`upscale.engine.thermostats`) and of a coarse tube's free shifts (None for
        an atomistic tube), K."""
        out = []
        for k, rows in enumerate(self.t_rows):
            vv = sim.state.v[rows, :2]
            txy = float(np.sum(self.t_mass[k] * vv * vv)) / (2 * max(len(rows), 1) * K_B_EV)
            tsh = None
            if k in self.t_shift:
                f, i, inert = self.t_shift[k]
                fv = sim.state.field_v[f][i]
                tsh = float(np.sum(inert * fv * fv)) / (3 * len(i) * K_B_EV)
            out.append((txy, tsh))
        return out

    def tube_radii(self, sim) -> list:
        """Each tube's mean radius (Å) of its moving rows about their own x, y centre (the
        breathing of a tube's cross-section)."""
        out = []
        for i in self.t_rows:
            p = sim.state.y[i, :2]
            c = p.mean(axis=0)
            out.append(float(np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]).mean()))
        return out

    def bookkeeping(self) -> dict:
        return {"acc": self.acc.tolist(), "tacc": self.tacc.tolist(), "curve": self.curve,
                "broken_links": {str(k): int(v) for k, v in self.broken_links.items()}}

    def restore(self, book: dict) -> None:
        self.acc, self.tacc = np.array(book["acc"]), np.array(book["tacc"])
        self.curve = book["curve"]
        self.broken_links = {int(k): v for k, v in book["broken_links"].items()}
