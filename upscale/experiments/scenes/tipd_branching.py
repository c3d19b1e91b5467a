"""Dynamic crack branching in soda-lime glass (seed 003 sec. 5.3).

The text's geometry is incomplete (its sizes, step count and final time disagree); it is the
benchmark of Ha & Bobaru, Int. J. Fract. 162 (2010) 229, which this scene uses:

=================  ==========================================================================
plate              100 mm x 40 mm, thickness = dx (plane stress), centred at the origin
pre-crack          from the left edge to the centre along y = 0 (bonds crossing it removed)
material           rho = 2440 kg/m^3, E = 72 GPa, nu = 0.22, G0 = 135 J/m^2
loading            traction sigma (12 or 24 MPa) on the top and bottom edges from t = 0
                   (a force sigma dx t on each particle of the outer rows)
discretisation     dx = 0.5 mm (200 x 80) and dx/2, or the paper's 400 x 160 points (0.25 mm);
                   horizon delta = 3 dx; the partial-volume factor of the "linear" rule
                   (:func:`upscale.engine.build_family`) by default
time               velocity Verlet at 0.8 of the stable estimate, to 46 us (12 MPa) or
                   32 us (24 MPa, the text's 3.2e-5 s)
models             Ti-PD with s0 from (60) or (62); LPS (s0 of (62)); PMB (bond-based s0)
=================  ==========================================================================

Crack tip: the largest x of a particle with damage >= ``tip_damage`` (default 0.35) in the
damaged cluster (8-connected on the lattice) that reaches within delta of the notch tip
(every ``record_dt``, default 0.25 us; damage that starts elsewhere, e.g. at the loaded
edges, is reported apart as ``edge_damage``). Speed: least-squares slopes over a sliding
window of ``speed_window`` (default 2 us), of the recorded tip (``v_max_records``, ``v_mean``)
and of the tip's path (``v_max``): the points (t, x) at which a particle beyond every earlier
one joined the crack, timed to the step (:func:`front_events`), from 2 delta past the notch
to 2 delta before the far edge. Coalescence: damage grown
apart from the crack (particles damaged at the previous record, not connected to it then,
some more than delta from it: nearer is the tip's own process zone) that joins it; such a
join that moves the tip forward by more than delta is a jump, not a crack speed, so the
peak speeds leave out the windows that hold one (``v_max_with_coalescence`` keeps them);
``v_mean`` is the mean of the recorded tip's slopes from 2 delta to branching. The recorded
tip moves in steps of dx, and the largest of its slopes is biased high by up to ~dx / window;
the path's points carry no such staircase.
Branching: the first record at which the crack, less the particles that joined it by
coalescence, holds particles farther than 2 delta from the notch line on both sides (the
main crack may go on between the branches); branching position x_b: the smallest x of those
off-line particles then (where the branches are 2 delta off the line).
Branch angle: the mean over the two branches of the angle to the notch line of the segment
from the branch's first particle 2 delta off the line to its particle farthest from the line
at the end of the run; ``branch_origin_x_m``: where those segments, extended, meet the line.
(The angle from that farthest particle to x_b on the line is biased high: x_b lies
2 delta / tan(theta) past the branch point.) Symmetry: the fraction of damaged
particles (>= ``tip_damage``) whose mirror image about y = 0 is not damaged.
"""
from __future__ import annotations

import math
import time
import warnings
from pathlib import Path

import numpy as np

from upscale.engine.memory import lattice_bonds, require_fit, run_memory

__all__ = ["branching", "simulate", "measure", "front_events", "sliding_slopes", "path_peak",
           "branch_angle", "plot_damage", "rayleigh_speed", "lattice_fracture_energy", "GLASS"]

#: peak of a run per directed bond (GB): family, the model's per-bond arrays and state
_PEAK_GB_PER_BOND = 40e-9
GLASS = {"rho": 2440.0, "E": 72e9, "nu": 0.22, "G0": 135.0}
LX, LY = 0.1, 0.04


def rayleigh_speed(E=GLASS["E"], nu=GLASS["nu"], rho=GLASS["rho"]) -> float:
    """Rayleigh wave speed (m/s) from the exact Rayleigh equation (3D/plane-strain
    moduli)."""
    from scipy.optimize import brentq

    G = E / (2 * (1 + nu))
    cs = np.sqrt(G / rho)
    k2 = (1 - 2 * nu) / (2 * (1 - nu))          # (cs/cp)^2

    def f(x):                                   # x = (cR/cs)^2
        return x ** 3 - 8 * x ** 2 + (24 - 16 * k2) * x - 16 * (1 - k2)

    return float(cs * np.sqrt(brentq(f, 1e-6, 0.999999)))


def lattice_fracture_energy(model: str = "tipd", *, dx: float = 5e-4, m: float = 3.0,
                            critical: str = "tipd", partial_volume: str | None = "linear",
                            window: int = 48, angle_deg: float = 0.0, offsets: int = 16) -> dict:
    """The fracture energy the lattice of the branching scene actually carries: the energy of
    the bonds that cross a straight cut, each at the critical stretch, per unit cut area,
    against the G0 its critical stretch was calibrated for (with the continuum integral).

    ``G_lattice = (1/(2 a t)) sum_{pairs crossing the cut, |x_i.t - dx/4| < a} (1/2) s0^2 xi.K_p xi``
    (J/m^2), K_p the pair stiffness (N/m): Ti-PD ``V_i M_ij`` (its (39)), PMB
    ``c V_i V_j beta n n / |xi|``; i the pair's particle below the cut, t the cut's direction,
    a = ``window`` spacings (an integer: along the lattice axis the window then holds whole
    periods, and the dx/4 shift keeps particles off its ends; along any other direction the
    window's ends cut rows, a relative error of order dx / (2 a), 0.2 % at m = 1 and 45 deg),
    the thickness t. The cut is the line at ``angle_deg`` to the x axis (the
    lattice's axis) through the patch centre, shifted normal to itself by ``offsets`` evenly
    spaced amounts over one spacing; the result is their mean, with the spread
    (``G_lattice_range``): a crack does not choose where between the rows it runs. Every bond is taken at s0 at once: the energy a crack front
    dissipates per unit area when it cuts the lattice (the continuum version of this sum is
    how (60), (62) and the bond-based s0 are derived). Also the lattice stiffness of a bulk
    particle against the continuum one, ``S_1111`` of the family's fourth moment over the
    material's (Ti-PD; :meth:`TiPD.lattice_moment`): a discretisation at m = delta / dx is
    the continuum model with its stiffness and toughness scaled by these two ratios.
    A square patch reaching one horizon and more beyond the window, with the scene's
    spacing, horizon and partial-volume rule; LPS has no pair energy and is refused."""
    from upscale import models
    from upscale.engine import build_family, square_lattice

    if model not in ("tipd", "pmb"):
        raise ValueError(f"lattice_fracture_energy needs a pair model; got {model!r}, valid: 'tipd', 'pmb'")
    if int(window) != window or window < 1:
        raise ValueError(f"window must be a whole number of spacings >= 1, got {window!r}")
    if not np.isfinite(angle_deg):
        raise ValueError(f"angle_deg must be finite, got {angle_deg!r}")
    if int(offsets) < 1:
        raise ValueError(f"offsets must be a positive count, got {offsets!r}")
    delta = m * dx * (1 + 1e-9)
    n = 2 * (int(window) + int(np.ceil(3 * m)) + 2)
    s = square_lattice(n, n, dx, thickness=dx, density=GLASS["rho"], plane="stress", centered=True)
    fam = build_family(s, delta, partial_volume=partial_volume)
    E, nu, G0 = GLASS["E"], GLASS["nu"], GLASS["G0"]
    mdl = (models.create("tipd", E=E, nu=nu, G0=G0, critical=critical) if model == "tipd"
           else models.create("pmb", E=E, nu=nu, Gc=G0))
    mdl.prepare(s, fam)
    th = np.deg2rad(angle_deg)
    tan, nrm = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
    x0 = s.x0[:, :2]
    i, j, xi = fam.owner, fam.neighbors, fam.xi[:, :2]
    V = s.volume
    if model == "tipd":
        quad = np.empty(fam.nb)
        for lo in range(0, fam.nb, 1 << 18):
            b = np.arange(lo, min(fam.nb, lo + (1 << 18)))
            K = mdl.bond_matrices(b) * V[i[b]][:, None, None]
            quad[b] = np.einsum("ka,kab,kb->k", xi[b], K, xi[b])
        stiff = float(mdl.lattice_moment()[0, 0, 0, 0] / mdl.S[0, 0, 0, 0])
    else:
        quad = mdl.c * mdl.w_b * V[i] * fam.length
        stiff = None
    a = window * dx
    dn, dxi = x0 @ nrm, xi @ nrm
    inside = np.abs(x0[i] @ tan - dx / 4) < a
    Gs, npairs = [], []
    for c in (np.arange(int(offsets)) + 0.5) / int(offsets) * dx:
        sel = inside & (dn[i] < c) & (dn[j] > c)        # each crossing pair once
        Gs.append(0.5 * mdl.s0 ** 2 * quad[sel].sum() / (2 * a * s.thickness))
        npairs.append(int(sel.sum()))
    G = float(np.mean(Gs))
    return {"model": model, "critical": critical if model == "tipd" else None, "dx_m": dx, "m": m,
            "horizon_m": fam.horizon, "angle_deg": float(angle_deg), "s0": float(mdl.s0),
            "G_lattice_J_m2": G, "G_lattice_range": [float(min(Gs)) / G0, float(max(Gs)) / G0],
            "G0_J_m2": G0, "G_lattice_over_G0": G / G0, "stiffness_1111_over_continuum": stiff,
            "crossing_pairs_mean": float(np.mean(npairs)), "partial_volume": partial_volume}


def branching(model: str = "tipd", *, stress: float = 12e6, dx: float = 5e-4,
              critical: str = "tipd", t_end: float | None = None, m: float = 3.0,
              record_dt: float = 0.25e-6, load_width: float | None = None, tip_damage: float = 0.35,
              speed_window: float = 2e-6, partial_volume: str | None = "linear", progress: bool = False,
              outdir=None) -> dict:
    """Run the branching scene (module docstring) and measure it: :func:`simulate` followed
    by :func:`measure`, with the damage sampled every step (the tip's path is timed to the
    step). Returns the
    crack-tip history and its measures (SI units), and the final ``damage`` (n,) with the
    reference ``positions_m`` (n, 2) as arrays (not JSON); with ``outdir`` also the damage map."""
    t0 = time.perf_counter()
    _check_measure(tip_damage, record_dt, speed_window)
    run = simulate(model, stress=stress, dx=dx, critical=critical, t_end=t_end, m=m,
                   load_width=load_width, sample_dt=None, thresholds=(tip_damage,),
                   partial_volume=partial_volume, progress=progress)
    res = measure(run, tip_damage=tip_damage, record_dt=record_dt, speed_window=speed_window)
    res["wall_time_s"] = time.perf_counter() - t0
    if outdir is not None:
        res["damage_png"] = plot_damage(run, outdir)
    return res


def _check_measure(tip_damage, record_dt, speed_window):
    if not 0.0 < tip_damage < 1.0:
        raise ValueError(f"tip_damage must lie in (0, 1), got {tip_damage!r}")
    if not (np.isfinite(record_dt) and record_dt > 0):
        raise ValueError(f"record_dt must be a positive time in s, got {record_dt!r}")
    if not (np.isfinite(speed_window) and speed_window > 0):
        raise ValueError(f"speed_window must be a positive time in s, got {speed_window!r}")


def simulate(model: str = "tipd", *, stress: float = 12e6, dx: float = 5e-4, critical: str = "tipd",
             t_end: float | None = None, m: float = 3.0, load_width: float | None = None,
             sample_dt: float | None = None, thresholds=(0.35,), partial_volume: str | None = "linear",
             progress: bool = False, checkpoint=None, checkpoint_every: int = 500) -> dict:
    """Run the branching scene with horizon ``delta = m dx``; the traction acts on the rows
    within ``load_width`` (m, a multiple of dx; default dx: the outer row) of the top and
    bottom edges, shared equally between them (a grid refinement at a fixed horizon keeps the
    loaded layer with ``load_width`` = the coarse dx).

    Bonds only break, so a particle's damage never decreases and the damaged set at any time
    is fixed by the step at which the damage first reached each threshold. The run keeps
    that step, ``onset_step[thr]`` (n,) (``steps + 1`` where never), for every threshold in
    ``thresholds``, sampling the damage every ``sample_every = round(sample_dt / dt)`` steps
    (every step with ``sample_dt`` None). :func:`measure` then rebuilds the crack at any record
    interval that is a multiple of the sampling, for any of those thresholds, without
    rerunning the dynamics.

    ``partial_volume`` is the family's edge correction (:func:`upscale.engine.build_family`):
    "linear" (default), "lammps" or None. The default is the rule under which the branching
    positions and speeds agree best between dx and dx/2 at the same horizon (m = 3 and 6):
    without it the lattice sum at m = 3 misses the bonds' volume at the horizon's edge, and
    the coarse grid is effectively a different material near the tip.

    ``checkpoint``: a file (.npz) written every ``checkpoint_every`` steps with the state, the
    onset steps and the sample times (``state.extra``); a run given the file of a killed run
    of the same scene resumes there and ends as the uninterrupted run would have."""
    from upscale import models
    from upscale.engine import Simulation, bonds_crossing_segment, build_family, square_lattice
    from upscale.engine.conditions import Force, region
    from upscale.engine.integrators import VelocityVerlet

    thresholds = tuple(float(v) for v in thresholds)
    for v in thresholds:
        if not 0.0 < v < 1.0:
            raise ValueError(f"a damage threshold must lie in (0, 1), got {v!r}")
    if sample_dt is not None and not (np.isfinite(sample_dt) and sample_dt > 0):
        raise ValueError(f"sample_dt must be a positive time in s or None (every step), got {sample_dt!r}")
    t0 = time.perf_counter()
    if t_end is None:
        t_end = 46e-6 if stress < 18e6 else 32e-6
    nx, ny = int(round(LX / dx)), int(round(LY / dx))
    per = _PEAK_GB_PER_BOND * lattice_bonds(m, 2)  # GB per particle
    require_fit(nx * ny * per, f"the branching plate at dx={dx:g} m ({nx} x {ny} particles)",
                lambda gb: f"dx={math.sqrt(LX * LY * per / gb):.3g} m")
    s = square_lattice(nx, ny, dx, thickness=dx, density=GLASS["rho"], plane="stress", centered=True)
    delta = m * dx * (1 + 1e-9)
    x0 = s.x0
    cross = bonds_crossing_segment(x0, (-LX / 2 - dx, 0.0), (0.0, 0.0))

    def crack(i, j, xi):          # both directions of a bond, whatever the rounding
        return cross(i, j, xi) | cross(j, i, -xi)

    fam = build_family(s, delta, exclude=crack, partial_volume=partial_volume)
    E, nu, G0 = GLASS["E"], GLASS["nu"], GLASS["G0"]
    if model == "tipd":
        mdl = models.create("tipd", E=E, nu=nu, G0=G0, critical=critical)
    elif model == "lps":
        mdl = models.create("lps", E=E, nu=nu, Gc=G0)
    elif model == "pmb":
        mdl = models.create("pmb", E=E, nu=nu, Gc=G0)
    else:
        raise ValueError(f"unknown model {model!r}; valid: 'tipd', 'lps', 'pmb'")
    ytop, ybot = x0[:, 1].max(), x0[:, 1].min()
    rows = 1 if load_width is None else int(round(load_width / dx))
    if rows < 1 or not np.isclose(rows * dx, load_width if load_width is not None else dx, rtol=1e-6):
        raise ValueError(f"load_width must be a positive multiple of dx = {dx!r} m, got {load_width!r}")
    f = stress * dx * s.thickness / rows
    lw = (rows - 0.5) * dx
    conds = [Force(region(s, "top edge", where=lambda x: x[:, 1] > ytop - lw), [0.0, f, 0.0]),
             Force(region(s, "bottom edge", where=lambda x: x[:, 1] < ybot + lw), [0.0, -f, 0.0])]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = Simulation(s, fam, [mdl], conditions=conds, integrator=VelocityVerlet(safety=0.8))
    sim.prepare()
    dt = sim.integrator.dt
    steps = int(np.ceil(t_end / dt))
    every = 1 if sample_dt is None else max(1, int(round(sample_dt / dt)))
    never = steps + 1
    keys = {v: f"branching.onset_{v:g}" for v in thresholds}  # carried by checkpoints
    for key in keys.values():
        sim.state.extra[key] = np.full(s.n, never, dtype=np.int64)
    sim.state.extra["branching.t"] = np.full(steps + 1, np.nan)  # time of the sampled steps

    def cb(sm):
        st = sm.state
        if st.step % every:
            return False
        d = sm.damage()
        for v, key in keys.items():
            on = st.extra[key]
            on[(d >= v) & (on == never)] = st.step
        st.extra["branching.t"][st.step] = st.t
        return False

    ck = None
    if checkpoint is not None:
        from upscale.engine.checkpoint import Checkpoint

        ck = Checkpoint(checkpoint, checkpoint_every)
        if sim.resume(ck.path) and sim.state.step > 0:
            cb(sim)  # the engine writes step k's checkpoint before step k's callback

    sim.run(steps - sim.state.step, progress=progress, callback=cb, checkpoint=ck)
    onset = {v: sim.state.extra[key] for v, key in keys.items()}
    tt = sim.state.extra["branching.t"]
    times = {int(k): float(tt[k]) for k in np.flatnonzero(np.isfinite(tt))}
    return {"_memory": run_memory(s, fam, [mdl], sim.state),
            "model": model, "critical": critical if model == "tipd" else None, "stress_Pa": stress,
            "dx_m": dx, "m": m, "delta_m": delta, "horizon_m": fam.horizon, "partial_volume": partial_volume,
            "nx": nx, "ny": ny,
            "load_rows": rows, "particles": s.n, "dt_s": float(dt), "steps": int(sim.state.step),
            "t_end_s": float(sim.state.t), "s0": float(mdl.s0), "broken_bonds": int(sim.broken_bonds()),
            "sample_every": every, "sample_times": times, "onset_step": onset,
            "positions_m": x0[:, :2].copy(), "damage": sim.damage(),
            "run_wall_s": time.perf_counter() - t0}


def measure(run: dict, *, tip_damage: float = 0.35, record_dt: float = 0.25e-6,
            speed_window: float = 2e-6) -> dict:
    """The crack measures of the module docstring from a :func:`simulate` run: the crack is
    the set of particles with damage >= ``tip_damage`` (one of the run's thresholds), recorded
    every ``record_every = round(record_dt / dt)`` steps (a multiple of the run's sampling),
    the speed the least-squares slope over a sliding window of ``speed_window`` (s). These
    three are choices of the measurement, not of the model."""
    from scipy.ndimage import label
    from scipy.spatial import cKDTree

    _check_measure(tip_damage, record_dt, speed_window)
    if float(tip_damage) not in run["onset_step"]:
        raise ValueError(f"tip_damage {tip_damage!r} was not sampled by the run; valid: "
                         f"{sorted(run['onset_step'])}")
    on = run["onset_step"][float(tip_damage)]
    dt, every = run["dt_s"], run["sample_every"]
    record_every = max(1, int(round(record_dt / dt)))
    if record_every % every:
        raise ValueError(f"record_dt {record_dt!r} s is {record_every} steps, not a multiple of the "
                         f"run's sampling ({every} steps of {dt!r} s)")
    x0, dx, delta, nx, ny = run["positions_m"], run["dx_m"], run["delta_m"], run["nx"], run["ny"]
    n = x0.shape[0]
    rec_t, rec_tip, rec_up, rec_lo = [], [], [], []
    state = {"branch": None, "cluster": np.zeros(n, dtype=bool), "damaged": np.zeros(n, dtype=bool)}
    never = np.iinfo(np.int64).max
    in_crack = np.full(n, never, dtype=np.int64)   # first record step at which a particle is in the crack
    onset = np.full(n, np.inf)            # first record time at which a particle's damage >= tip_damage
    merges = []                           # records at which damage grown apart joined the crack
    merged = np.zeros(n, dtype=bool)      # the particles that joined the crack that way

    # lattice indices of the particles (regular grid, x slowest) for cluster labelling
    ix = np.rint((x0[:, 0] - x0[:, 0].min()) / dx).astype(int)
    iy = np.rint((x0[:, 1] - x0[:, 1].min()) / dx).astype(int)
    notch = np.flatnonzero((np.abs(x0[:, 0]) < delta) & (np.abs(x0[:, 1]) < delta))

    def crack_cluster(dam):
        """Damaged particles 8-connected to the notch tip (damage elsewhere, e.g. at the
        loaded edges, is not the crack)."""
        g = np.zeros((nx, ny), dtype=bool)
        g[ix, iy] = dam
        lab, _ = label(g, structure=np.ones((3, 3), dtype=int))
        ids = {int(lab[ix[k], iy[k]]) for k in notch} - {0}
        return dam & np.isin(lab[ix, iy], list(ids)) if ids else np.zeros_like(dam)

    for step in sorted(k for k in run["sample_times"] if k % record_every == 0):
        t = run["sample_times"][step]
        dmg = on <= step
        onset[dmg & np.isinf(onset)] = t
        cl = crack_cluster(dmg)
        # coalescence: particles damaged at the previous record, apart from the crack then
        joined = cl & state["damaged"] & ~state["cluster"]
        if joined.any() and state["cluster"].any():
            # damage within a horizon of the crack is its own process zone; farther, a crack apart
            gap = cKDTree(x0[state["cluster"]]).query(x0[joined])[0].max()
            if gap > delta:
                prev_tip = rec_tip[-1] if rec_tip else 0.0
                merges.append({"t_s": t, "particles": int(joined.sum()), "gap_m": float(gap),
                               "x_m": [float(x0[joined, 0].min()), float(x0[joined, 0].max())],
                               "y_m": [float(x0[joined, 1].min()), float(x0[joined, 1].max())],
                               "advances_tip": bool(x0[joined, 0].max() > prev_tip + delta)})
                merged[joined] = True
        state["cluster"], state["damaged"] = cl, dmg
        in_crack[cl & (in_crack == never)] = step
        ahead = cl & (x0[:, 0] > -dx)
        if not ahead.any():
            tip, up, lo = 0.0, (0.0, 0.0), (0.0, 0.0)
        else:
            xi = np.flatnonzero(ahead)
            tip = float(x0[xi, 0].max())
            u = xi[x0[xi, 1] > 0]
            lw = xi[x0[xi, 1] < 0]
            # branch tips: the cluster's particles farthest from the notch line
            up = (float(x0[u[np.argmax(x0[u, 1])], 0]), float(x0[u, 1].max())) if u.size else (0.0, 0.0)
            lo = (float(x0[lw[np.argmin(x0[lw, 1])], 0]), float(x0[lw, 1].min())) if lw.size else (0.0, 0.0)
            grown = xi[~merged[xi]]       # a branch grows from the crack; coalesced damage is not one
            if state["branch"] is None and grown.size:
                yy = x0[grown, 1]
                off = np.abs(yy) > 2 * delta
                if (yy > 2 * delta).any() and (yy < -2 * delta).any():
                    # where each branch first lies 2 delta off the line: its particle of least x
                    starts = []
                    for side in (grown[yy > 2 * delta], grown[yy < -2 * delta]):
                        k = side[np.argmin(x0[side, 0])]
                        starts.append((float(x0[k, 0]), float(x0[k, 1])))
                    state["branch"] = (t, float(x0[grown[off], 0].min()), starts)
        rec_t.append(t)
        rec_tip.append(tip)
        rec_up.append(up)
        rec_lo.append(lo)

    t_arr, tip_arr = np.array(rec_t), np.array(rec_tip)
    # speed: sliding least-squares slope over the window (0 where too few records)
    w = speed_window
    v = np.nan_to_num(sliding_slopes(t_arr, tip_arr, w), nan=0.0)
    inside = tip_arr < LX / 2 - 2 * delta            # before the tip reaches the far edge
    vmax_all = float(v[inside].max()) if inside.any() else float(v.max())
    # running tip: windows holding a coalescence that moved the tip forward are not a speed
    jumps = np.array([c["t_s"] for c in merges if c["advances_tip"]])
    running = inside.copy()
    for tj in jumps:
        running &= np.abs(t_arr - tj) > w / 2 + 0.5 * record_every * dt
    vmax_rec = float(v[running].max()) if running.any() else vmax_all
    # peak from the tip's path: the crack's particles (less those joined by coalescence) in
    # the order they joined it; each beyond every earlier one is a point (t, x) of the path,
    # exact in x and timed by the run's sampling (by the record where a particle was damaged
    # before it joined). The least-squares slope over the window through these points has no
    # dx staircase in it.
    lo_x, hi_x = 2 * delta, LX / 2 - 2 * delta     # past the notch's start-up, before the far edge
    crack_x = state["cluster"] & (x0[:, 0] > -dx)
    ev = front_events(x0[:, 0], on, in_crack, crack_x & ~merged, run["sample_times"], record_every)
    pad = w / 2 + 0.5 * record_every * dt
    vmax = path_peak(*ev, w, lo_x, hi_x, exclude=jumps, pad=pad)
    vmax = vmax_rec if vmax is None else vmax
    # with the coalesced particles on the path (timed by the record at which they joined)
    ev_all = front_events(x0[:, 0], on, in_crack, crack_x, run["sample_times"], record_every)
    peak_all = path_peak(*ev_all, w, lo_x, hi_x)
    vmax_all = vmax_all if peak_all is None else peak_all
    # mean running speed before branching: the records' peak is the largest of many noisy
    # slopes of a tip that moves in steps of dx (biased high by up to ~dx / window); their mean is not
    br = state["branch"]
    before = running & (tip_arr > 2 * delta) & (t_arr <= (br[0] if br is not None else np.inf))
    vmean = float(v[before].mean()) if before.any() else None
    cR = rayleigh_speed()
    angle, origin = None, None
    if br is not None:
        sides = [branch_angle(start, tip) for start, tip in zip(br[2], (rec_up[-1], rec_lo[-1]))]
        sides = [v for v in sides if v is not None]
        if sides:
            angle = float(np.mean([v[0] for v in sides]))
            origin = float(np.mean([v[1] for v in sides]))
    d = run["damage"]
    dam = d >= tip_damage
    # symmetry about y = 0: lattice row iy mirrors row ny - 1 - iy (ny even, centred)
    index = np.empty((nx, ny), dtype=np.int64)
    index[ix, iy] = np.arange(n)
    mirror = index[ix, ny - 1 - iy]
    asym = float((dam & ~dam[mirror]).sum() / max(dam.sum(), 1))
    edge_damage = int((dam & ~crack_cluster(dam)).sum())
    keep = ("model", "critical", "stress_Pa", "dx_m", "horizon_m", "partial_volume", "load_rows", "particles",
            "dt_s", "steps", "t_end_s", "s0", "broken_bonds")
    return {**{k: run[k] for k in keep}, "_memory": run.get("_memory"), "tip_damage": float(tip_damage),
            "record_dt_s": record_every * dt, "speed_window_s": float(w), "cR_m_per_s": cR,
            "v_max_m_per_s": vmax, "v_max_over_cR": vmax / cR,
            "v_max_records_m_per_s": vmax_rec, "v_max_records_over_cR": vmax_rec / cR,
            "v_max_with_coalescence_m_per_s": vmax_all, "v_max_with_coalescence_over_cR": vmax_all / cR,
            "v_mean_m_per_s": vmean, "v_mean_over_cR": None if vmean is None else vmean / cR,
            "branching_t_s": None if br is None else br[0], "branching_x_m": None if br is None else br[1],
            "branch_angle_deg": angle, "branch_origin_x_m": origin, "asymmetry_fraction": asym,
            "damaged_off_crack": edge_damage,
            "tip_t_s": rec_t, "tip_x_m": rec_tip, "tip_v_m_per_s": v.tolist(),
            "upper_tip_xy_m": rec_up, "lower_tip_xy_m": rec_lo, "coalescence": merges,
            "positions_m": x0.copy(), "damage": d, "damage_onset_s": onset}


def front_events(x, onset, in_crack, crack, sample_times, record_every):
    """Points (t, x) of the crack tip's path: the particles of ``crack`` (n,) bool in the
    order they joined the crack (``onset`` (n,) step at which the damage reached the
    threshold, or, where the particle was damaged more than ``record_every`` steps before
    ``in_crack`` (n,), the record step at which it joined), each kept when it lies beyond
    every earlier one. Returns times (s) and x (m), both (k,)."""
    idx = np.flatnonzero(crack)
    if idx.size == 0:
        return np.zeros(0), np.zeros(0)
    step = np.where(in_crack[idx] - onset[idx] < record_every, onset[idx], in_crack[idx])
    order = np.lexsort((x[idx], step))
    st, xs = step[order], x[idx][order]
    ahead = np.r_[True, xs[1:] > np.maximum.accumulate(xs)[:-1]]
    return np.array([sample_times[int(k)] for k in st[ahead]]), xs[ahead]


def sliding_slopes(t, x, window, min_span=0.0):
    """Least-squares slope dx/dt of the points (t, x) (k,) over the window of ``window`` (s)
    centred on each point: (k,), NaN where the window holds fewer than three points or
    spans no more than ``min_span`` (s)."""
    out = np.full(t.size, np.nan)
    for k in range(t.size):
        sel = np.abs(t - t[k]) <= window / 2
        if sel.sum() >= 3 and np.ptp(t[sel]) > min_span:
            out[k] = np.polyfit(t[sel], x[sel], 1)[0]
    return out


def path_peak(t, x, window, x_lo, x_hi, exclude=(), pad=0.0):
    """Largest least-squares slope dx/dt (m/s) of the path points (t, x) with x_lo < x < x_hi
    over windows of ``window`` (s) centred on each point, holding at least three points
    spread over more than half the window; windows whose centre lies within ``pad`` of a
    time in ``exclude`` are left out. None when no window qualifies."""
    keep = (x > x_lo) & (x < x_hi)
    t, x = t[keep], x[keep]
    v = sliding_slopes(t, x, window, 0.5 * window)
    exclude = np.asarray(exclude, dtype=float)
    if exclude.size:
        v[np.any(np.abs(t[:, None] - exclude[None, :]) <= pad, axis=1)] = np.nan
    return float(np.nanmax(v)) if np.isfinite(v).any() else None


def branch_angle(start, tip):
    """Angle (degrees) of a branch to the notch line, and the x (m) at which the branch's
    line meets it, from two of its points: ``start`` (x, y), where it first lies 2 delta
    off the line, and its ``tip`` (x, y), the crack's particle farthest from the line on that
    side. None when the tip is not beyond the start."""
    (xs, ys), (xt, yt) = start, tip
    rise, run = abs(yt) - abs(ys), xt - xs
    if run <= 0 or rise <= 0:
        return None
    return float(np.degrees(np.arctan2(rise, run))), float(xs - abs(ys) * run / rise)


def plot_damage(run: dict, outdir) -> str:
    """The final damage map of a run as ``damage_<model>_<stress>_dx<dx>.png`` in ``outdir``;
    returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x0, d, model, critical = run["positions_m"], run["damage"], run["model"], run["critical"]
    stress, dx, m, rows = run["stress_Pa"], run["dx_m"], run["m"], run["load_rows"]
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(6, 2.6))
    sc = ax.scatter(x0[:, 0] * 1e3, x0[:, 1] * 1e3, c=d, s=0.3, cmap="inferno", vmin=0, vmax=1)
    ax.set_aspect("equal")
    ax.set_title(f"{model}{'(' + critical + ')' if model == 'tipd' else ''} {stress / 1e6:g} MPa, "
                 f"t = {run['t_end_s'] * 1e6:.1f} us")
    fig.colorbar(sc, ax=ax, label="damage")
    fig.tight_layout()
    tag = (f"{model}{'_' + critical if model == 'tipd' else ''}_{stress / 1e6:g}MPa_dx{dx * 1e3:g}mm"
           + ("" if m == 3 else f"_m{m:g}") + ("" if rows == 1 else f"_load{rows}"))
    path = out / f"damage_{tag}.png"
    fig.savefig(path, dpi=150)
    plt.close(fig)
    return str(path)
