"""``upscale plate``: dynamic crack growth in a pre-cracked square plate (PMB or LPS).

The scene of seed 004, sec. 2.4.2 / Table 2.1 (plate column), which is the classical
benchmark of Madenci & Oterkus, *Peridynamic Theory and Its Applications* (Springer 2014),
"plate with a pre-existing crack under velocity boundary conditions":

=========================  =========================================================
plate                      0.05 m x 0.05 m, thickness = spacing (Table 2.1: particle
                           area 1e-8 m^2 for 500 x 500 particles), 2D plane stress
discretisation             500 x 500 particles (``--quick``: 100 x 100), spacing h
horizon                    delta = 3.015 h (Table 2.1: 3.01e-4 m for h = 1e-4 m)
material                   E = 192 GPa, nu = 1/3 (PMB's plane-stress value),
                           rho = 8000 kg/m^3 (Table 2.1)
pre-crack                  0.01 m long, horizontal, centred; bonds crossing it are
                           broken at t = 0 (so they count in the damage index)
failure                    critical stretch s0 = 0.04472 (Madenci & Oterkus), or from
                           ``--Gc`` (J/m^2)
loading                    the 3 top rows move at +50 m/s in y, the 3 bottom rows at
                           -50 m/s (Table 2.1: boundary velocity 50 m/s), other edges free
duration                   t = 1.4e-5 s (the snapshot time of seed 004 Fig. 2.6)
time step                  0.8 x the stable estimate (Silling-Askari bound)
=========================  =========================================================

Table 2.1 lists "elasticity modulus 576e9 N/m^3", which is 3 x 192 GPa; the text gives
no fracture energy and its velocity is applied "along the y axis on the left and right
edges" of a figure whose axes are not shown: we use the Madenci & Oterkus values and
orientation (mode-I opening of a horizontal crack) and say so in the result.

:func:`plate` returns a :class:`~upscale.experiments.result.Result` (figures, the crack's
history, the damage per particle); with ``workdir`` it also writes ``checkpoint.npz`` there
(every ``checkpoint_every`` steps; ``resume`` continues from it) and, with ``every=N``,
``traj.extxyz`` + ``vtk/`` + ``summary.json`` every N steps. :func:`damage_png` draws the
damage map as one pixel per particle.
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Literal

import numpy as np

from upscale.engine.memory import lattice_bonds, require_fit, run_memory
from upscale.experiments.result import Result, Timer, make_meta

__all__ = ["PlateScene", "plate", "damage_png"]

L_PLATE = 0.05
CRACK = 0.01
E_PLATE = 192e9
RHO = 8000.0
S0 = 0.04472
V_EDGE = 50.0
T_END = 1.4e-5
#: the build's peak per directed bond (GB): family build, pre-crack blocks, model and state
#: (a PMB plate of 10 M bonds peaked 40 bytes per bond above the imports)
_PEAK_GB_PER_BOND = 48e-9


class PlateScene:
    """The pre-cracked plate, built but not run (see module docstring)."""

    def __init__(self, n: int = 500, *, model: str = "pmb", m: float = 3.015, Gc: float | None = None,
                 s0: float | None = None, dt: float | None = None, force_dt: bool = False,
                 t_end: float = T_END, velocity: float = V_EDGE):
        from upscale import models
        from upscale.engine import Simulation, bonds_crossing_segment, build_family, square_lattice
        from upscale.engine.conditions import Velocity, region
        from upscale.engine.integrators import VelocityVerlet
        from upscale.engine.state import State

        cls = models.get(model)  # unknown name: one-line error listing the valid ones
        if int(n) < 10:
            raise ValueError(f"plate needs at least 10 particles a side, got {n}")
        if not (np.isfinite(t_end) and t_end > 0):
            raise ValueError(f"end time must be positive, got {t_end!r}")
        self.n, self.model_name, self.m, self.t_end = int(n), model, float(m), float(t_end)
        per_side = _PEAK_GB_PER_BOND * lattice_bonds(self.m, 2)  # GB per particle
        require_fit(self.n ** 2 * per_side, f"a plate of n={self.n} particles a side",
                    lambda gb: f"n={int(math.sqrt(gb / per_side))}")
        h = L_PLATE / self.n
        self.h = h
        system = square_lattice(self.n, self.n, h, thickness=h, density=RHO, plane="stress",
                                centered=True)
        family = build_family(system, self.m * h)
        if Gc is not None and s0 is not None:
            raise ValueError("give --s0 or --Gc, not both")
        crit = {"Gc": Gc} if Gc is not None else {"s0": S0 if s0 is None else s0}
        if model == "pmb":
            mdl = cls(E=E_PLATE, **crit)
        else:
            mdl = cls(E=E_PLATE, nu=1.0 / 3.0, **crit)
        top = region(system, "top rows", box=((None, L_PLATE / 2 - 3 * h, None), (None, None, None)))
        bottom = region(system, "bottom rows", box=((None, None, None), (None, -L_PLATE / 2 + 3 * h, None)))
        conds = [Velocity(top, (0.0, velocity, 0.0), components=(1,)),
                 Velocity(bottom, (0.0, -velocity, 0.0), components=(1,))]
        cut = bonds_crossing_segment(system.x0, (-CRACK / 2, 0.0), (CRACK / 2, 0.0))
        # block by block over whole rows: the owners and reference vectors of ~1 M bonds at a
        # time, not of all of them (32 bytes per bond, 3x the family's own 10 at 10 M bonds)
        self.precrack = np.zeros(family.nb, dtype=bool)
        for lo, hi in family.bond_blocks(1 << 20):
            b = np.arange(lo, hi)
            self.precrack[lo:hi] = cut(family.owner_of(b), family.neighbors[lo:hi], family.xi_of(b))
        state = State.reference(system.x0, family.nb)
        state.intact[self.precrack] = False
        # the whole body; on several MPI ranks the simulation keeps its rank's part
        self.system, self.family = system, family
        self.sim = Simulation(system, family, mdl, conds, state=state,
                              integrator=VelocityVerlet(dt=dt, force=force_dt))
        self.sim.prepare()  # checks the time step against the stable estimate
        self.steps = int(np.ceil(self.t_end / self.sim.integrator.dt - 1e-9))

    def crack_metrics(self, threshold: float = 0.35) -> dict:
        """Crack extent from the damaged particles (damage > threshold)."""
        x = self.system.x0
        mu = self.sim.gather(self.sim.damage())
        d = mu > threshold
        if not d.any():
            return {"crack_length_m": 0.0, "crack_tips_x_m": [0.0, 0.0], "max_abs_y_damaged_m": 0.0,
                    "branched": False}
        xs, ys = x[d, 0], x[d, 1]
        # branching: damage spread well off the crack line (more than 2 horizons)
        off = np.abs(ys) > 2 * self.m * self.h
        return {"crack_length_m": float(xs.max() - xs.min()), "crack_tips_x_m": [float(xs.min()), float(xs.max())],
                "max_abs_y_damaged_m": float(np.abs(ys).max()), "branched": bool(off.sum() > 10)}


def damage_png(path, system, mu, title: str) -> Path:
    """Damage map (particles coloured by mu) as a PNG, written atomically."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from upscale.io import atomic_write_bytes

    x = system.x0
    fig, ax = plt.subplots(figsize=(6.2, 5.2), dpi=150)
    h = system.spacing
    lo = x[:, :2].min(axis=0)
    ij = np.rint((x[:, :2] - lo) / h).astype(np.int64)
    shape = tuple(ij.max(axis=0) + 1)
    on_grid = np.allclose(lo + ij * h, x[:, :2], atol=1e-6 * h) and \
        np.unique(ij[:, 0] * shape[1] + ij[:, 1]).size == len(x)
    if on_grid:  # a lattice: one pixel per particle
        img = np.full(shape, np.nan)
        img[ij[:, 0], ij[:, 1]] = mu
        ext = np.array([lo[0] - h / 2, lo[0] + (shape[0] - 0.5) * h,
                        lo[1] - h / 2, lo[1] + (shape[1] - 0.5) * h]) * 1e3
        sc = ax.imshow(img.T, origin="lower", extent=ext, cmap="jet", vmin=0, vmax=1,
                       interpolation="nearest")
    else:
        sc = ax.scatter(x[:, 0] * 1e3, x[:, 1] * 1e3, c=mu, s=4, cmap="jet", vmin=0, vmax=1,
                        linewidths=0)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title, fontsize=9)
    fig.colorbar(sc, ax=ax, label="damage $\\mu = 1 - R/T$")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())


def plate(*, model: Literal["pmb", "lps"] = "pmb", quick: bool = False, n: int | None = None,
          horizon: float = 3.015, s0: float | None = None, Gc: float | None = None,
          t_end: float = T_END, dt: float | None = None, force_dt: bool = False, every: int = 0,
          checkpoint_every: int = 200, resume: bool = False, workdir: str | None = None,
          progress: bool = False) -> Result:
    """Dynamic crack growth in the pre-cracked square plate (module docstring).

    Parameters
    ----------
    model : {"pmb", "lps"}
        Peridynamic model of the plate.
    quick : bool
        100 x 100 particles instead of 500 x 500 when ``n`` is not given (a few seconds).
    n : int or None
        Particles per side (>= 10; None: 500, or 100 with ``quick``).
    horizon : float
        Horizon over spacing, delta / h (dimensionless).
    s0 : float or None
        Critical stretch (dimensionless; None: 0.04472 of Madenci & Oterkus unless Gc is given).
    Gc : float or None
        Fracture energy in J/m^2, instead of s0.
    t_end : float
        End time of the run in s.
    dt : float or None
        Time step in s (None: 0.8 x the stable estimate).
    force_dt : bool
        Allow a time step above the stable estimate.
    every : int
        Write extxyz, VTK and summary JSON to workdir every this many steps (0: off).
    checkpoint_every : int
        Checkpoint interval in steps (workdir/checkpoint.npz; only with workdir).
    resume : bool
        Continue from workdir/checkpoint.npz if it is there (needs workdir).
    workdir : str or None
        Folder for the checkpoint and the trajectory output (None: the run writes nothing).
    progress : bool
        Show a progress bar.
    """
    from upscale.engine.checkpoint import Checkpoint
    from upscale.engine.output import Output

    if int(every) < 0:
        raise ValueError(f"every={every!r} steps; valid: >= 0 (0: no trajectory output)")
    if int(checkpoint_every) < 1:
        raise ValueError(f"checkpoint_every={checkpoint_every!r} steps; valid: >= 1")
    if dt is not None and not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt={dt!r} s; valid: a positive time step or None")
    if workdir is None and (resume or every):
        raise ValueError(f"{'resume' if resume else f'every={every!r}'} needs a workdir "
                         "(the folder of the checkpoint and the trajectory)")
    params = dict(model=model, quick=quick, n=n, horizon=horizon, s0=s0, Gc=Gc, t_end=t_end,
                  dt=dt, force_dt=force_dt, every=every, checkpoint_every=checkpoint_every,
                  resume=resume, workdir=workdir)
    n = n or (100 if quick else 500)
    with Timer() as timer:
        t0 = time.perf_counter()
        scene = PlateScene(n, model=model, m=horizon, Gc=Gc, s0=s0, dt=dt, force_dt=force_dt,
                           t_end=t_end)
        sim = scene.sim
        ck, output, resumed = None, None, False
        if workdir is not None:   # everything is validated: only now touch the disk
            out = Path(workdir)
            out.mkdir(parents=True, exist_ok=True)
            ck = Checkpoint(out / "checkpoint.npz", every=checkpoint_every)
            if resume:
                resumed = sim.resume(ck.path)
                if resumed:
                    sim.prepare()
                    ck.last_step = sim.state.step
            output = Output(out, every=every) if every else None
        setup_s = time.perf_counter() - t0
        remaining = max(0, scene.steps - sim.state.step)
        hist = {"time_us": [], "broken_bonds": [], "crack_length_mm": [], "kinetic_energy_J": []}
        record = max(1, remaining // 100)

        def sample(s):
            if s.state.step % record == 0 or s.state.step == scene.steps:
                hist["time_us"].append(s.state.t * 1e6)
                hist["broken_bonds"].append(s.broken_bonds())
                hist["crack_length_mm"].append(scene.crack_metrics()["crack_length_m"] * 1e3)
                hist["kinetic_energy_J"].append(s.kinetic_energy())
            return False

        sample(sim)
        info = sim.run(remaining, output=output, checkpoint=ck, progress=progress, callback=sample,
                       meta={"scene": "plate", "n": n, "model": model})
    met = scene.crack_metrics()
    mu = sim.gather(sim.damage())
    pre = int(scene.precrack.sum())
    figures = {
        "particles": scene.system.n, "bonds": scene.family.nb, "spacing_m": scene.h,
        "horizon_m": sim.family.horizon, "thickness_m": sim.system.thickness, "E_Pa": E_PLATE,
        "density_kg_m3": RHO, "edge_velocity_m_s": V_EDGE,
        "critical_stretch": float(sim.models[0].s0), "dt_s": sim.integrator.dt,
        "stable_dt_estimate_s": sim.integrator.estimate, "steps": sim.state.step,
        "time_s": sim.state.t, "resumed": resumed, "precrack_bonds": pre,
        "broken_bonds": info["broken_bonds"], "broken_bonds_by_loading": info["broken_bonds"] - pre,
        "max_damage": float(mu.max()), "crack_length_m": met["crack_length_m"],
        "crack_tip_left_x_m": met["crack_tips_x_m"][0], "crack_tip_right_x_m": met["crack_tips_x_m"][1],
        "max_abs_y_damaged_m": met["max_abs_y_damaged_m"], "branched": met["branched"],
        "mpi_ranks": 1 if sim.part is None else sim.part.size,
        "kinetic_energy_J": sim.kinetic_energy(), "strain_energy_J": sim.energy(),
    }
    conventions = {
        "units": "SI (m, s, Pa, J); history in us and mm",
        "axes": "x along the pre-crack, y the loading direction; origin at the plate centre",
        "loading": "the 3 top rows move at +v in y, the 3 bottom rows at -v",
        "damage": "mu = 1 - intact/initial bonds of a particle; pre-crack bonds count as broken",
        "crack": "particles with damage > 0.35; branched: more than 10 of them over 2 horizons "
                 "off the crack line",
        "history": "sampled every 1 % of the run's steps (a resumed run: from the resumed step)",
        "notes": ("Table 2.1's 'elasticity modulus 576e9 N/m^3' = 3 x 192 GPa; E = 192 GPa, "
                  "s0 = 0.04472 and the mode-I orientation follow Madenci & Oterkus (2014)"),
    }
    meta = make_meta("plate", params, timer=timer, conventions=conventions,
                     plot={"history": {"x": "time_us", "y": ["crack_length_mm"]}},
                     setup_s=setup_s, run_wall_s=info["wall_s"], run=sim.describe(),
                     memory=run_memory(sim.system, sim.family, sim.models, sim.state))
    return Result(figures=figures, curves={f"history/{k}": v for k, v in hist.items()},
                  fields={"x0": scene.system.x0, "damage": mu}, meta=meta)
