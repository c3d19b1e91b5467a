"""Engine against LAMMPS PERI: the same pre-cracked block run by the engine's PMB / LPS and
by ``pair_style peri/pmb`` / ``peri/lps`` (:class:`upscale.engine.lammps_peri.LammpsPeri`,
whose docstring gives every convention and how the engine matches it).
"""
from __future__ import annotations

import numpy as np

from upscale.engine.lammps_peri import LAMMPS_EXAMPLE, LammpsPeri

__all__ = ["compare"]


def compare(style: str, *, counts=(16, 16, 6), steps: int = 200, perturb: float = 0.02,
            v0: float = 2.0, volume_spread: float = 0.1, seed: int = 0,
            mat: dict | None = None) -> dict:
    """Run the same bodies with LAMMPS peri/<style> and the engine; return the figures.

    1. Forces: on the sc lattice perturbed by ``perturb`` x lc (Gaussian), no failure.
    2. Dynamics: the pre-cracked block (crack plane y = (ny/2 + 0.5) lc for
       x < (nx/2 - 0.4) lc, through z), particle volumes lc^3 (1 + volume_spread u),
       u uniform in [-1, 1] (so the volume-weighted damage of each particle identifies its
       set of broken bonds), initial velocity v_y = v0 (y - y_c)/(H/2), ``steps`` velocity
       Verlet steps of LAMMPS's fix nve.
    3. Well-posedness: ``critical_stretch_margin_min`` is the smallest |s - s00| of any bond
       whose fate was decided in some step (engine run, bonds intact before that step);
       ``stretch_max_abs_diff_final`` the largest stretch difference between the codes at
       the end. A margin orders of magnitude above that difference means round-off cannot
       make the two codes break different bonds (the comparison is not chaotic).
    """
    import time

    from upscale.engine.families import build_family
    from upscale.engine.integrators import VelocityVerlet, stable_time_step
    from upscale.engine.kernels import bond_stretch
    from upscale.engine.simulation import Simulation
    from upscale.engine.state import State
    from upscale.engine.system import ParticleSystem
    from upscale.models.bond_based import PMB, LammpsContact
    from upscale.models.state_based import LPS

    p = dict(LAMMPS_EXAMPLE, **(mat or {}))
    lc, delta, rho = p["lc"], p["horizon"], p["density"]
    if style == "pmb":
        params = {"c": p["c"], "s00": p["s00"]}
    elif style == "lps":
        params = {"K": p["K"], "G": p["G"], "s00": p["s00"]}
    else:
        raise ValueError(f"unknown LAMMPS peri style {style!r}; valid: 'pmb', 'lps'")

    def engine_models(s0, fam_contact=None):
        if style == "pmb":
            m = PMB(c=p["c"], s0=s0)
            ct = LammpsContact.for_pmb(p["c"], delta, lc, family=fam_contact)
        else:
            m = LPS(K=p["K"], G=p["G"], s0=s0)
            ct = LammpsContact.for_lps(p["K"], delta, lc, family=fam_contact)
        return m, ct

    out: dict = {"style": style, "lattice_counts": list(counts), "lc_m": lc, "horizon_m": delta}
    rng = np.random.default_rng(seed)

    # ---- 1. forces on a perturbed lattice (failure off: s00 huge) ---------------------
    lp = LammpsPeri(style, counts, lc, delta, rho, {**params, "s00": 1e3}, dt=p["dt"])
    try:
        x = lp.positions()
        sysm = ParticleSystem(x, lc ** 3, rho, spacing=lc)
        fam = build_family(sysm, delta, partial_volume="lammps")
        xp = x + rng.normal(scale=perturb * lc, size=x.shape)
        fl = lp.force_on(xp)
    finally:
        lp.close()
    m, ct = engine_models(None)
    m.prepare(sysm, fam)
    ct.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    st.y[...] = xp
    fe = m.force(st)
    ct.add_force(st, fe)
    scale = np.abs(fl).max()
    out.update(particles=int(sysm.n), bonds=int(fam.nb),
               force_rel_err=float(np.abs(fe - fl).max() / scale),
               force_contacts_active=int(ct.last_active))
    # the conventions' effect: the engine's defaults (no edge factor) against LAMMPS
    fam0 = build_family(sysm, delta)
    m0, _ = engine_models(None)
    m0.prepare(sysm, fam0)
    out["force_rel_diff_without_lammps_edge_factor"] = float(np.abs(m0.force(st) - fl).max() / scale)

    # ---- 2. 200 Verlet steps of a pre-cracked block -----------------------------------
    nx, ny, _ = counts
    crack = ((nx / 2 - 0.4) * lc, (ny / 2 + 0.5) * lc)
    lp = LammpsPeri(style, counts, lc, delta, rho, params, crack=crack, dt=p["dt"])
    try:
        x = lp.positions()
        typ = lp.types()
        vol = lc ** 3 * (1.0 + volume_spread * rng.uniform(-1, 1, size=len(x)))
        lp.set_volumes(vol)
        sysm = ParticleSystem(x, vol, rho, spacing=lc)
        full = build_family(sysm, delta, partial_volume="lammps")
        ti, tj = typ[full.owner], typ[full.neighbors]
        fam = full.remove_bonds(((ti == 2) & (tj == 3)) | ((ti == 3) & (tj == 2)))
        m, ct = engine_models(p["s00"], full)
        sim = Simulation(sysm, fam, [m, ct], integrator=VelocityVerlet(dt=p["dt"], force=True),
                         damage_weights="volume")
        yc = 0.5 * (x[:, 1].max() + x[:, 1].min())
        H = x[:, 1].max() - x[:, 1].min()
        v = np.zeros_like(x)
        v[:, 1] = v0 * (x[:, 1] - yc) / (H / 2)
        sim.state.v[...] = v
        lp.create_bonds()
        lp.set_velocities(v)
        t0 = time.perf_counter()
        lp.run(steps)
        t_lmp = time.perf_counter() - t0
        # well-posedness: how close any bond came to the critical stretch when its fate was
        # decided (engine side, every step, over the bonds intact before that step). A
        # margin far above the trajectories' difference means the two codes cannot break
        # different bonds by round-off.
        margin = [np.inf]
        intact_before = sim.state.intact.copy()

        def watch(s):
            st = s.state
            stretch = bond_stretch(fam.offsets, fam.neighbors, fam.length, st.y)
            gap = np.abs(stretch[intact_before] - p["s00"])
            if gap.size:
                margin[0] = min(margin[0], float(gap.min()))
            intact_before[...] = st.intact
            return False

        t0 = time.perf_counter()
        sim.run(steps)
        t_eng = time.perf_counter() - t0
        # the same run again with the margin watch (not timed)
        sim_w = Simulation(sysm, fam, list(engine_models(p["s00"], full)),
                           integrator=VelocityVerlet(dt=p["dt"], force=True), damage_weights="volume")
        sim_w.state.v[...] = v
        sim_w.run(steps, callback=watch)
        if not np.array_equal(sim_w.state.y, sim.state.y):
            raise RuntimeError("the engine is not deterministic: the watched run differs")
        ul = lp.positions() - x
        dl = lp.damage()
    finally:
        lp.close()
    ue = sim.state.y - x
    s_diff = np.abs(bond_stretch(fam.offsets, fam.neighbors, fam.length, sim.state.y)
                    - bond_stretch(fam.offsets, fam.neighbors, fam.length, x + ul)).max()
    de = sim.damage()
    broken = int(np.count_nonzero(~sim.state.intact))
    # per particle: count of broken bonds, and the volume-weighted damage, which with
    # distinct random volumes identifies the set of broken partners
    est = stable_time_step(sysm, [m, ct])
    out.update(
        block_particles=int(sysm.n), block_bonds=int(fam.nb), precrack_bonds_removed=int(full.nb - fam.nb),
        steps=int(steps), dt_s=p["dt"], stable_dt_estimate_s=est,
        disp_rel_err_200_steps=float(np.abs(ue - ul).max() / np.abs(ul).max()),
        max_displacement_m=float(np.abs(ul).max()),
        broken_bonds_engine=broken,
        damage_max_abs_diff=float(np.abs(de - dl).max()),
        broken_bonds_identical=bool(np.abs(de - dl).max() < 1e-12 and broken > 0),
        critical_stretch_margin_min=margin[0],
        critical_stretch_margin_rel=margin[0] / p["s00"],
        stretch_max_abs_diff_final=float(s_diff),
        max_damage=float(dl.max()),
        contacts_active_max=int(ct.max_active),
        wall_lammps_s=t_lmp, wall_engine_s=t_eng,
    )
    return out
