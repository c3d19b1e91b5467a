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

Writes ``plate.json`` (result), ``damage.png`` (damage map), ``checkpoint.npz`` (every
``--checkpoint-every`` steps; ``--resume`` continues from it) and, with ``--every N``,
``traj.extxyz`` + ``vtk/`` + ``summary.json`` every N steps.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["PlateScene", "run_plate", "register"]

L_PLATE = 0.05
CRACK = 0.01
E_PLATE = 192e9
RHO = 8000.0
S0 = 0.04472
V_EDGE = 50.0
T_END = 1.4e-5


class PlateScene:
    """The pre-cracked plate, built but not run (see module docstring)."""

    def __init__(self, n: int = 500, *, model: str = "pmb", m: float = 3.015, Gc: float | None = None,
                 s0: float | None = None, dt: float | None = None, force_dt: bool = False,
                 t_end: float = T_END, velocity: float = V_EDGE):
        from upscale import models
        from upscale.engine import Simulation, bonds_crossing_segment, build_family, square_lattice
        from upscale.engine.conditions import Velocity, region
        from upscale.engine.integrators import VelocityVerlet

        cls = models.get(model)  # unknown name: one-line error listing the valid ones
        if int(n) < 10:
            raise ValueError(f"plate needs at least 10 particles a side, got {n}")
        if not (np.isfinite(t_end) and t_end > 0):
            raise ValueError(f"end time must be positive, got {t_end!r}")
        self.n, self.model_name, self.m, self.t_end = int(n), model, float(m), float(t_end)
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
        self.sim = Simulation(system, family, mdl, conds,
                              integrator=VelocityVerlet(dt=dt, force=force_dt))
        cut = bonds_crossing_segment(system.x0, (-CRACK / 2, 0.0), (CRACK / 2, 0.0))
        self.precrack = cut(family.owner, family.neighbors, family.xi)
        self.sim.state.intact[self.precrack] = False
        self.sim.prepare()  # checks the time step against the stable estimate
        self.steps = int(np.ceil(self.t_end / self.sim.integrator.dt - 1e-9))

    def crack_metrics(self, threshold: float = 0.35) -> dict:
        """Crack extent from the damaged particles (damage > threshold)."""
        x = self.sim.system.x0
        mu = self.sim.damage()
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


def run_plate(args) -> dict:
    from upscale.engine.checkpoint import Checkpoint
    from upscale.engine.kernels import set_threads
    from upscale.engine.output import Output
    from upscale.io import versions, write_json

    set_threads(args.threads)
    n = args.n or (100 if args.quick else 500)
    t0 = time.perf_counter()
    scene = PlateScene(n, model=args.model, m=args.horizon, Gc=args.Gc, s0=args.s0, dt=args.dt,
                       force_dt=args.force_dt, t_end=args.t_end)
    sim = scene.sim
    out = Path(args.out)
    # everything is validated: only now touch the disk
    out.mkdir(parents=True, exist_ok=True)
    ck = Checkpoint(out / "checkpoint.npz", every=args.checkpoint_every)
    resumed = False
    if args.resume:
        resumed = sim.resume(ck.path)
        if resumed:
            sim.prepare()
            ck.last_step = sim.state.step
    output = Output(out, every=args.every) if args.every else None
    setup_s = time.perf_counter() - t0
    remaining = max(0, scene.steps - sim.state.step)
    info = sim.run(remaining, output=output, checkpoint=ck, progress=not args.quiet,
                   meta={"scene": "plate", "n": n, "model": args.model})
    met = scene.crack_metrics()
    mu = sim.damage()
    title = (f"{args.model.upper()} plate {n}x{n}, t = {sim.state.t * 1e6:.2f} us, "
             f"{info['broken_bonds'] - int(scene.precrack.sum())} bonds broken")
    damage_png(out / "damage.png", sim.system, mu, title)
    wall = time.perf_counter() - t0
    result = {
        "scene": "pre-cracked plate (seed 004 sec. 2.4.2 / Madenci & Oterkus 2014)",
        "model": args.model, "particles": sim.system.n, "bonds": sim.family.nb,
        "spacing_m": scene.h, "horizon_m": sim.family.horizon, "thickness_m": sim.system.thickness,
        "E_Pa": E_PLATE, "density_kg_m3": RHO, "edge_velocity_m_s": V_EDGE,
        "critical_stretch": float(sim.models[0].s0), "dt_s": sim.integrator.dt,
        "stable_dt_estimate_s": sim.integrator.estimate, "steps": sim.state.step,
        "time_s": sim.state.t, "resumed": resumed,
        "precrack_bonds": int(scene.precrack.sum()),
        "broken_bonds": info["broken_bonds"],
        "broken_bonds_by_loading": info["broken_bonds"] - int(scene.precrack.sum()),
        "max_damage": float(mu.max()), **met,
        "kinetic_energy_J": sim.kinetic_energy(), "strain_energy_J": sim.energy(),
        "setup_s": setup_s, "run_wall_s": info["wall_s"], "wall_s": wall,
        "damage_png": str(out / "damage.png"),
        "notes": ("Table 2.1's 'elasticity modulus 576e9 N/m^3' = 3 x 192 GPa; E = 192 GPa, "
                  "s0 = 0.04472 and the mode-I orientation follow Madenci & Oterkus (2014)"),
    }
    write_json(out / "plate.json", {"result": result, "run": sim.describe(), "versions": versions()})
    rows = [("model", args.model), ("particles", sim.system.n), ("bonds", sim.family.nb),
            ("time step (s)", f"{sim.integrator.dt:.4g} (estimate {sim.integrator.estimate:.4g})"),
            ("steps", sim.state.step), ("time (s)", f"{sim.state.t:.4g}"),
            ("bonds broken by loading", result["broken_bonds_by_loading"]),
            ("crack length (m)", f"{met['crack_length_m']:.4g} (initial {CRACK})"),
            ("crack tips x (m)", f"{met['crack_tips_x_m'][0]:.4g}, {met['crack_tips_x_m'][1]:.4g}"),
            ("branched", met["branched"]), ("max damage", f"{mu.max():.3f}"),
            ("wall time (s)", f"{wall:.1f}"), ("damage map", out / "damage.png"),
            ("result", out / "plate.json")]
    w = max(len(r[0]) for r in rows)
    print("\n".join(f"{k.ljust(w)}  {v}" for k, v in rows))
    return result


def register(sub) -> None:
    p = sub.add_parser("plate", help="pre-cracked plate under edge velocities (PMB/LPS), damage map",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", default="pmb", help="peridynamic model: pmb (default) or lps")
    p.add_argument("--quick", action="store_true", help="100 x 100 particles (a few seconds)")
    p.add_argument("--n", type=int, default=None, help="particles per side (default 500, quick 100)")
    p.add_argument("--out", default="out/plate", help="output directory (default: %(default)s)")
    p.add_argument("--horizon", type=float, default=3.015, help="horizon / spacing (default %(default)s)")
    p.add_argument("--s0", type=float, default=None, help=f"critical stretch (default {S0})")
    p.add_argument("--Gc", type=float, default=None, help="fracture energy J/m^2 (instead of --s0)")
    p.add_argument("--t-end", type=float, default=T_END, help="end time in s (default %(default)s)")
    p.add_argument("--dt", type=float, default=None, help="time step (default 0.8 x stable estimate)")
    p.add_argument("--force-dt", action="store_true", help="allow a time step above the stable estimate")
    p.add_argument("--every", type=int, default=0, help="write extxyz/VTK/JSON every N steps (0: off)")
    p.add_argument("--checkpoint-every", type=int, default=200, help="checkpoint interval in steps")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.npz if present")
    p.add_argument("--threads", type=int, default=None, help="numba threads (default: all)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=lambda a: (run_plate(a), 0)[1])


if __name__ == "__main__":  # pragma: no cover
    from upscale.cli import main

    sys.exit(main(["plate", *sys.argv[1:]]))
