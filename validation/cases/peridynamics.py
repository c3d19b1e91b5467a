"""Peridynamics on the engine against LAMMPS (``pair_style peri/pmb``, ``peri/lps``, the engine
in LAMMPS's conventions, :mod:`upscale.engine.lammps_peri`), linear elasticity and its own
stability limits. ``bench-memory`` counts the bytes kept per directed bond
(:func:`upscale.engine.memory.bytes_per_bond`, after one force evaluation; the system's
arrays not charged).
"""
from __future__ import annotations

import os
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from validation.registry import case, show
from validation.registry import threads as _threads


# ---------------------------------------------------------------------------- LAMMPS
def _lammps_case(style: str, args) -> dict:
    from upscale.experiments.scenes.peri_lammps import compare

    _threads(1)
    counts = (10, 10, 4) if args.quick else (16, 16, 6)
    r = compare(style, counts=counts, steps=200)
    ok = (r["force_rel_err"] <= 1e-10 and r["disp_rel_err_200_steps"] <= 1e-8
          and r["broken_bonds_identical"]
          and r["critical_stretch_margin_min"] > 1e3 * r["stretch_max_abs_diff_final"])
    return {**r, "pass": bool(ok)}


@case("pmb-vs-lammps", "PMB in LAMMPS conventions vs LAMMPS peri/pmb: forces, 200 steps of a pre-cracked block, broken bonds",
      target="forces within 1e-10 (relative), displacements after 200 steps within 1e-8, the same broken bonds")
def pmb_vs_lammps(args):
    return _lammps_case("pmb", args)


@case("lps-vs-lammps", "LPS in LAMMPS conventions vs LAMMPS peri/lps: forces, 200 steps of a pre-cracked block, broken bonds",
      target="forces within 1e-10 (relative), displacements after 200 steps within 1e-8, the same broken bonds")
def lps_vs_lammps(args):
    return _lammps_case("lps", args)


# ---------------------------------------------------------------------------- benchmark


class _LammpsPairTimer:
    """LAMMPS peri/<style> on the benchmark block, bonds built once; :meth:`time` runs
    ``steps`` steps and returns (Pair seconds per step from LAMMPS's timer breakdown, CPU
    seconds per step of the process over the run). The block is at rest in its reference
    state: no bond breaks, no neighbour rebuild."""

    def __init__(self, style: str, n_cells: int, log: str):
        from upscale.engine.lammps_peri import LAMMPS_EXAMPLE as P, LammpsPeri

        params = {"c": P["c"]} if style == "pmb" else {"K": P["K"], "G": P["G"]}
        self.log = log
        self.lp = LammpsPeri(style, (n_cells,) * 3, P["lc"], P["horizon"], P["density"],
                             {**params, "s00": P["s00"]}, log=log)
        self.lp.create_bonds()
        self.lp.lmp.command("run 1")
        self.bonds = int(re.findall(r"total # of bonds = (\d+)", Path(log).read_text())[0])

    def time(self, steps: int) -> tuple[float, float]:
        c0 = time.process_time()
        self.lp.lmp.command(f"run {int(steps)}")
        cpu = (time.process_time() - c0) / steps
        pair = float(re.findall(r"^Pair\s*\|\s*([0-9.eE+-]+)", Path(self.log).read_text(), re.M)[-1])
        return pair / steps, cpu

    def close(self):
        self.lp.close()


def _engine_force_time(model, state, reps: int) -> tuple[float, float]:
    """(best wall seconds, best CPU seconds) of one ``step_force`` over ``reps`` calls."""
    out = np.zeros_like(state.y)
    model.step_force(state, out)  # compile / warm
    wall = cpu = np.inf
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        model.step_force(state, out)
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu


def memory_bandwidth(n: int = 50_000_000, reps: int = 5) -> dict:
    """STREAM-like triad ``a = b + s c`` on three float64 arrays of ``n`` elements (400 MB
    each by default, far beyond the caches), counted as STREAM counts it (24 bytes per
    element: two reads, one write). Best of ``reps`` by numba on one thread, by wall time
    and by the process's CPU time (on a loaded machine the bandwidth one core gets while it
    runs)."""
    import numba as nb

    @nb.njit(parallel=True)
    def triad(a, b, c, s):
        for i in nb.prange(a.shape[0]):
            a[i] = b[i] + s * c[i]

    def timed(fn):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        return time.perf_counter() - t0, time.process_time() - c0

    a = np.zeros(n)
    b = np.ones(n)
    c = np.full(n, 2.0)
    _threads(1)  # and left there
    triad(a, b, c, 3.0)
    ts = [timed(lambda: triad(a, b, c, 3.0)) for _ in range(reps)]
    return {"numba_1thread": 24.0 * n / min(w for w, _ in ts) / 1e9,
            "numba_1thread_cpu": 24.0 * n / min(cp for _, cp in ts) / 1e9}


@case("bench-pmb", "PMB and LPS bond-force throughput vs LAMMPS peri/pmb, peri/lps on a ~30k-particle block, one "
      "core; bytes per bond, memory bandwidth, 2-thread speed-up",
      target="bond-force throughput at least 4x LAMMPS's on one core")
def bench_pmb(args):
    from upscale.engine import ParticleSystem, build_family
    from upscale.engine.lammps_peri import LAMMPS_EXAMPLE as P, LammpsPeri
    from upscale.engine.state import State
    from upscale.models.bond_based import PMB
    from upscale.models.state_based import LPS

    n = 20 if args.quick else 30  # lattice cells a side
    steps = 10 if args.quick else 20
    reps = 10 if args.quick else 20
    rounds = 2 if args.quick else 5  # interleaved (engine, LAMMPS, ...); the best of each kept
    lp = LammpsPeri("pmb", (n,) * 3, P["lc"], P["horizon"], P["density"], {"c": P["c"], "s00": P["s00"]})
    x = lp.positions()
    lp.close()
    sysm = ParticleSystem(x, P["lc"] ** 3, P["density"], spacing=P["lc"])
    fam = build_family(sysm, P["horizon"], partial_volume="lammps")
    models = {"pmb": PMB(c=P["c"], s0=P["s00"]), "lps": LPS(K=P["K"], G=P["G"], s0=P["s00"])}
    for m in models.values():
        m.prepare(sysm, fam)
    state = State.reference(sysm.x0, fam.nb)
    load0 = os.getloadavg()[0]
    avail = _threads(None)
    two = min(2, max(avail, 1)) >= 2
    best: dict = {}

    def keep(key, value):
        best[key] = min(best.get(key, np.inf), value)

    with tempfile.TemporaryDirectory() as d:
        lmp = {s: _LammpsPairTimer(s, n, os.path.join(d, f"log.{s}")) for s in models}
        try:
            for _ in range(rounds):  # interleaved: both codes see the same machine load
                for s, m in models.items():
                    _threads(1)
                    w, c = _engine_force_time(m, state, reps)
                    keep(f"{s}_engine_1t", w)
                    keep(f"{s}_engine_1t_cpu", c)
                    pair, cpu = lmp[s].time(steps)
                    keep(f"{s}_lammps_pair", pair)
                    keep(f"{s}_lammps_cpu", cpu)
                    if two:
                        _threads(2)
                        keep(f"{s}_engine_2t", _engine_force_time(m, state, reps)[0])
            bonds = {s: lmp[s].bonds for s in models}
        finally:
            for t in lmp.values():
                t.close()
    bw = memory_bandwidth()
    _threads(avail)
    load1 = os.getloadavg()[0]
    nb_ = fam.nb
    out: dict = {"particles": int(sysm.n), "bonds": int(nb_), "bonds_lammps": bonds["pmb"],
                 "bonds_match": bool(bonds["pmb"] == nb_ == bonds["lps"]),
                 "classes": int(models["pmb"].bonds.classes()[1].size), "rounds": rounds}
    for s, m in models.items():
        t1, t1c, pair = best[f"{s}_engine_1t"], best[f"{s}_engine_1t_cpu"], best[f"{s}_lammps_pair"]
        t2 = best.get(f"{s}_engine_2t", float("nan"))
        sb = m.stream_bytes()
        pre = "" if s == "pmb" else "lps_"
        out.update({
            f"{pre}lammps_pair_s_per_step": pair,
            f"{pre}engine_force_s_1thread": t1, f"{pre}engine_force_s_2threads": t2,
            f"{pre}engine_bonds_per_s_1thread": nb_ / t1, f"{pre}lammps_bonds_per_s_1core": bonds[s] / pair,
            f"{pre}throughput_ratio_vs_lammps_1core": (nb_ / t1) / (bonds[s] / pair),
            f"{pre}throughput_ratio_vs_lammps_1core_cpu_time": best[f"{s}_lammps_cpu"] / t1c,
            f"{pre}speedup_2threads": t1 / t2 if np.isfinite(t2) else None,
            f"{pre}bytes_per_bond": sb / nb_, f"{pre}bytes_per_eval": sb,
            f"{pre}achieved_GBps_1thread": sb / t1 / 1e9, f"{pre}achieved_GBps_1thread_cpu": sb / t1c / 1e9,
        })
    ratio = out["throughput_ratio_vs_lammps_1core"]
    out.update({
        "memory_bandwidth_GBps": bw["numba_1thread_cpu"], "memory_bandwidth_GBps_1thread_wall": bw["numba_1thread"],
        "load_average_start": load0, "load_average_end": load1, "cpu_count": os.cpu_count(),
        "pass": bool(ratio >= 4.0),
    })
    return out


# ---------------------------------------------------------------------------- elasticity


def continuum_energy_density(eps, E, nu, dim, plane="stress") -> float:
    """W = lambda/2 tr(eps)^2 + mu eps:eps (2D: plane stress/strain in-plane strain)."""
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    e = np.asarray(eps, dtype=float)
    e = 0.5 * (e + e.T)  # small-strain tensor of the displacement gradient
    if dim == 2:
        e = e[:2, :2]
        if plane == "stress":
            lam = 2 * lam * mu / (lam + 2 * mu)
    return float(0.5 * lam * np.trace(e) ** 2 + mu * np.sum(e * e))


DEFORMATIONS = {
    "isotropic stretch": lambda d: np.diag([1.0, 1.0, 1.0 if d == 3 else 0.0]) * 1e-3,
    "uniaxial stretch": lambda d: np.diag([1e-3, 0.0, 0.0]),
    "simple shear": lambda d: np.array([[0, 1e-3, 0], [0, 0, 0], [0, 0, 0.0]]),
}


def bulk_energy_error(model_name: str, dim: int, *, m: float = 3.015, partial_volume=None,
                      plane: str = "stress", calibration: str = "continuum", nu: float | None = None,
                      deformation: str = "uniaxial stretch") -> float:
    """Relative error of the bulk energy density of a homogeneous deformation."""
    from upscale.engine import build_family, cubic_lattice, square_lattice
    from upscale.engine.state import State
    from upscale.models.bond_based import PMB
    from upscale.models.state_based import LPS

    E, h = 70e9, 1e-3
    half = int(np.ceil(m)) + 2
    k = 2 * half + 1
    if dim == 3:
        sysm = cubic_lattice(k, k, k, h, centered=True)
    else:
        sysm = square_lattice(k, k, h, centered=True, plane=plane, thickness=h)
    fam = build_family(sysm, m * h, partial_volume=partial_volume)
    if model_name == "pmb":
        model = PMB(E=E, nu=nu, calibration=calibration)
        nu_eff = nu if nu is not None else (0.25 if (dim == 3 or plane == "strain") else 1 / 3)
    else:
        nu_eff = 0.3 if nu is None else nu
        model = LPS(E=E, nu=nu_eff)
    model.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    eps = DEFORMATIONS[deformation](dim)
    st.y[...] = sysm.x0 + sysm.x0 @ eps.T
    W = model.energy_density(st)
    centre = int(np.argmin(np.linalg.norm(sysm.x0, axis=1)))
    return float(W[centre] / continuum_energy_density(eps, E, nu_eff, dim, plane) - 1.0)


def poisson_bar(dim: int = 2, *, cells=(61, 21, 1), m: float = 3.015, partial_volume="linear",
                nu: float = 0.3, plane: str = "stress", tol: float = 1e-7) -> dict:
    """LPS bar stretched along x by prescribed axial displacement of its end layers (free
    laterally), solved to equilibrium by ADR; nu_eff = -eps_yy / eps_xx in the middle third.

    Symmetry planes (y = y_c, z = z_c) carry u_y = 0 / u_z = 0 to remove rigid motions
    without constraining the contraction."""
    from upscale.engine import Simulation, build_family, cubic_lattice, square_lattice
    from upscale.engine.conditions import Displacement, region
    from upscale.engine.integrators import AdaptiveDynamicRelaxation
    from upscale.models.state_based import LPS

    h = 1e-3
    nx, ny, nz = cells
    sysm = cubic_lattice(nx, ny, nz, h) if dim == 3 else square_lattice(nx, ny, h, plane=plane)
    fam = build_family(sysm, m * h, partial_volume=partial_volume)
    x = sysm.x0
    L = x[:, 0].max()
    strain = 1e-4
    yc, zc = x[:, 1].mean(), x[:, 2].mean()
    conds = [
        Displacement(region(sysm, "left grip", box=((None,) * 3, (2.5 * h, None, None))), 0.0, components=(0,)),
        Displacement(region(sysm, "right grip", box=((L - 2.5 * h, None, None), (None,) * 3)),
                     (strain * L, 0, 0), components=(0,)),
        Displacement(region(sysm, "y symmetry plane", where=lambda p: np.isclose(p[:, 1], yc)), 0.0,
                     components=(1,)),
    ]
    if dim == 3:
        conds.append(Displacement(region(sysm, "z symmetry plane", where=lambda p: np.isclose(p[:, 2], zc)),
                                  0.0, components=(2,)))
    else:
        conds.append(Displacement(region(sysm, "plane", where=lambda p: np.ones(len(p), bool)), 0.0,
                                  components=(2,)))
    sim = Simulation(sysm, fam, LPS(E=70e9, nu=nu), conds)
    t0 = time.perf_counter()
    res = sim.relax(AdaptiveDynamicRelaxation(tol=tol, max_steps=50_000))
    u = sim.state.u
    mid = (x[:, 0] > L / 3) & (x[:, 0] < 2 * L / 3)
    exx = np.polyfit(x[mid, 0], u[mid, 0], 1)[0]
    eyy = np.polyfit(x[mid, 1], u[mid, 1], 1)[0]
    nu_eff = -eyy / exx
    expected = nu / (1 - nu) if (dim == 2 and plane == "strain") else nu
    return {"dim": dim, "cells": list(cells), "particles": sysm.n, "horizon_over_h": m,
            "partial_volume": partial_volume, "plane": plane if dim == 2 else None,
            "adr_iterations": res["iterations"], "adr_converged": res["converged"],
            "nu_expected": expected, "nu_measured": float(nu_eff),
            "nu_rel_err": float(nu_eff / expected - 1), "wall_s": time.perf_counter() - t0}


@case("pd-elasticity", "PMB/LPS bulk energy density vs linear elasticity (2D, 3D) and the LPS Poisson contraction of a bar",
      target="bulk energy density within 1 % (isotropic and stretch), LPS Poisson contraction within 5 %")
def pd_elasticity(args):
    _threads(None)
    rows = []
    horizons = (3.015, 4.015)
    for model in ("pmb", "lps"):
        for dim, plane in ((3, "stress"), (2, "stress"), (2, "strain")):
            for m in horizons:
                for pv in (None, "linear"):
                    calib = "lattice" if model == "pmb" else "continuum"
                    row = {"model": model, "dim": dim, "plane": plane if dim == 2 else "-",
                           "delta/h": m, "partial_volume": str(pv), "calibration": calib}
                    for d in DEFORMATIONS:
                        row[d] = bulk_energy_error(model, dim, m=m, partial_volume=pv, plane=plane,
                                                   calibration=calib, deformation=d)
                    rows.append(row)
    bars = [poisson_bar(2, cells=(61, 21, 1)), poisson_bar(2, cells=(61, 21, 1), plane="strain"),
            poisson_bar(2, cells=(61, 21, 1), partial_volume=None)]
    if not args.quick:
        bars.append(poisson_bar(2, cells=(81, 29, 1), m=4.015))
        bars.append(poisson_bar(3, cells=(41, 15, 15)))
        bars.append(poisson_bar(3, cells=(41, 15, 15), partial_volume=None))
    iso = [abs(r["isotropic stretch"]) for r in rows]
    best = [r for r in rows if r["partial_volume"] == "linear" and r["delta/h"] == max(horizons)]
    stretch_err = max(max(abs(r["isotropic stretch"]), abs(r["uniaxial stretch"])) for r in best)
    main_bars = [b for b in bars if b["partial_volume"] == "linear"]
    poisson_err = max(abs(b["nu_rel_err"]) for b in main_bars)
    return {"energy_isotropic_max_rel_err": max(iso),
            "energy_stretch_max_rel_err_linear_pv": stretch_err,
            "energy_stretch_max_rel_err_linear_pv_horizon": max(horizons),
            "energy_table": rows, "poisson_bars": bars,
            "poisson_max_rel_err": poisson_err,
            "pass": bool(max(iso) <= 0.01 and stretch_err <= 0.01 and poisson_err <= 0.05)}


# ---------------------------------------------------------------------------- stability


def nve_drift(model_name: str = "pmb", dim: int = 2, steps: int = 10_000, safety: float = 0.8,
              cells: int | None = None, every: int = 10) -> dict:
    """Total-energy drift of an NVE run started from a smooth velocity field.

    H = kinetic + strain energy, sampled every ``every`` steps. Velocity Verlet conserves a
    shadow energy: H oscillates (bounded, ``fluctuation`` = peak-to-peak / mean) around a
    constant. The drift is the secular part: the least-squares linear trend of H over the
    run, ``drift = |slope| T / <H>``; ``drift_windows`` compares the means of the first and
    last 5% of the samples (noisier: it includes the oscillation)."""
    from upscale.engine import Simulation, build_family, cubic_lattice, square_lattice
    from upscale.engine.integrators import VelocityVerlet, linearised_critical_dt
    from upscale.models import create

    h = 1e-3
    if dim == 3:
        k = cells or 8
        sysm = cubic_lattice(k, k, k, h, density=2000.0)
    else:
        k = cells or 20
        sysm = square_lattice(k, k, h, density=2000.0)
    fam = build_family(sysm, 3.015 * h)
    kw = {"E": 70e9} if model_name == "pmb" else {"E": 70e9, "nu": 0.3}
    sim = Simulation(sysm, fam, create(model_name, **kw), integrator=VelocityVerlet(safety=safety))
    x = sysm.x0
    span = np.where(np.ptp(x, axis=0) > 0, np.ptp(x, axis=0), 1.0)
    sim.state.v[:, 0] = np.sin(np.pi * x[:, 0] / span[0]) * np.cos(np.pi * x[:, 1] / span[1])
    sim.state.v[:, 1] = 0.5 * np.cos(np.pi * x[:, 0] / span[0])
    sim.prepare()
    H = []

    def sample(s):
        if s.state.step % every == 0:
            H.append(s.kinetic_energy() + s.energy())

    t0 = time.perf_counter()
    sim.run(steps, callback=sample)
    H = np.asarray(H)
    w = max(1, len(H) // 20)
    tt = np.arange(len(H), dtype=float)
    slope = np.polyfit(tt, H, 1)[0]
    return {"model": model_name, "dim": dim, "particles": sysm.n, "steps": steps,
            "dt_s": sim.integrator.dt, "stable_estimate_s": sim.integrator.estimate,
            "sharp_critical_dt_s": linearised_critical_dt(sim),
            "drift": float(abs(slope) * (len(H) - 1) / H.mean()),
            "drift_windows": float(abs(H[-w:].mean() - H[:w].mean()) / H.mean()),
            "fluctuation": float(np.ptp(H) / H.mean()), "wall_s": time.perf_counter() - t0}


def forced_blowup(outdir, factor: float = 2.0, model_name: str = "pmb") -> dict:
    """Run at ``factor`` x the stable estimate with force=True; checkpoint every 5 steps.

    Returns the diagnosis and what is on disk."""
    from upscale.engine import Simulation, build_family, square_lattice
    from upscale.engine.checkpoint import Checkpoint, load_checkpoint
    from upscale.engine.integrators import BlowUp, VelocityVerlet, stable_time_step
    from upscale.models import create

    h = 1e-3
    sysm = square_lattice(16, 16, h, density=2000.0)
    fam = build_family(sysm, 3.015 * h)
    model = create(model_name, **({"E": 70e9} if model_name == "pmb" else {"E": 70e9, "nu": 0.3}))
    model.prepare(sysm, fam)
    est = stable_time_step(sysm, [model])
    sim = Simulation(sysm, fam, model, integrator=VelocityVerlet(dt=factor * est, force=True))
    rng = np.random.default_rng(1)
    sim.state.v[:, :2] = rng.normal(scale=1e-3, size=(sysm.n, 2))
    ck = Checkpoint(Path(outdir) / "blowup_checkpoint.npz", every=5)
    msg = None
    try:
        sim.run(5000, checkpoint=ck)
    except BlowUp as exc:
        msg = str(exc)
    out = {"factor_over_estimate": factor, "detected": msg is not None, "diagnosis": msg,
           "blowup_step": int(sim.state.step)}
    if ck.path.is_file():
        st, meta = load_checkpoint(ck.path, sysm.x0, nb=fam.nb)
        out.update(checkpoint_step=st.step, checkpoint_finite=bool(np.isfinite(st.y).all() and np.isfinite(st.v).all()),
                   checkpoint_max_speed=float(np.abs(st.v).max()))
    return out


@case("pd-stability", "Stable step vs sharp limit, NVE drift over 10,000 steps at 0.8 of it, refusal, blow-up detection, restart",
      target="NVE drift below 1e-4 over 10,000 steps; a too-large step refused naming the stable estimate; a forced blow-up detected with a finite checkpoint kept")
def pd_stability(args):
    from upscale.engine import Simulation, build_family, square_lattice
    from upscale.engine.integrators import VelocityVerlet
    from upscale.models import create

    _threads(1)
    runs = [nve_drift("pmb", 2), nve_drift("lps", 2)]
    if not args.quick:
        runs += [nve_drift("pmb", 3), nve_drift("lps", 3)]
    # refusal
    sysm = square_lattice(10, 10, 1e-3, density=2000.0)
    fam = build_family(sysm, 3.015e-3)
    sim = Simulation(sysm, fam, create("pmb", E=70e9), integrator=VelocityVerlet(dt=1.0))
    try:
        sim.run(1)
        refusal = None
    except ValueError as exc:
        refusal = str(exc)
    blow = forced_blowup(args.outdir)
    drift = max(r["drift"] for r in runs)
    ok = (drift < 1e-4 and refusal is not None and "stable estimate" in refusal and blow["detected"]
          and blow.get("checkpoint_finite", False))
    return {"nve_runs": runs, "nve_max_drift": drift, "refusal_message": refusal, "blowup": blow,
            "pass": bool(ok)}


E, NU, GC = 70e9, 1.0 / 3.0, 8.0
SPACING = 1e-3


def _models(horizon):
    from upscale.models.bond_based import PMB
    from upscale.models.correspondence import Correspondence
    from upscale.models.cpd import CPD
    from upscale.models.state_based import LPS
    from upscale.models.tipd import TiPD

    return {
        "pmb": (lambda: PMB(E=E, nu=NU, Gc=GC), "intact (bool per bond)"),
        "lps": (lambda: LPS(E=E, nu=NU, Gc=GC), "intact (bool per bond)"),
        "tipd": (lambda: TiPD(E=E, nu=NU), "intact (bool per bond)"),
        "nosb": (lambda: Correspondence(E=E, nu=NU), "intact (bool per bond)"),
        "cpd": (lambda: CPD(horizon=horizon, dim=2, E=E, nu=NU),
                "intact (bool per bond) + bool per triplet and quadruplet"),
    }


def measure(cells: int) -> list[dict]:
    """One row per model: bonds, and bytes per bond kept in per-bond buffers, in
    per-particle buffers, and in the run's bond state
    (:func:`upscale.engine.memory.bytes_per_bond`)."""
    from upscale.engine import State, build_family, square_lattice
    from upscale.engine.memory import bytes_per_bond

    s = square_lattice(cells, cells, SPACING, thickness=SPACING)
    horizon = 3.015 * SPACING
    rows = []
    for name, (make, state_name) in _models(horizon).items():
        fam = build_family(s, horizon)
        m = make()
        m.prepare(s, fam)
        st = State.reference(s.x0, fam.nb)
        m.init_state(st)
        m.force(st)
        b = bytes_per_bond(s, fam, [m], st)
        rows.append({"model": name, "bonds": fam.nb, "bond_B": b["bond"], "state_B": b["state"],
                     "bond+state_B": b["bond"] + b["state"], "target_B": 16.0 + b["state"],
                     "per_particle_B": b["particle"], "all_kept_B": b["total"], "state": state_name})
    return rows


@case("bench-memory", "bytes kept per bond by PMB, LPS, Ti-PD, NOSB and CPD on a 2D plate "
      "(target: at most 16 plus the model's per-bond state)")
def bench_memory(args):
    _threads(1)
    cells = 60 if args.quick else 120  # particles a side (120: 403k bonds)
    rows = measure(cells)
    show(rows, fmt=".2f")
    out = {"plate_particles": cells * cells, "bonds": rows[0]["bonds"]}
    ok = True
    for r in rows:
        m = r["model"]
        out[f"bytes_per_bond_{m}"] = round(r["bond+state_B"], 3)
        out[f"state_bytes_per_bond_{m}"] = round(r["state_B"], 3)
        out[f"all_kept_bytes_per_bond_{m}"] = round(r["all_kept_B"], 3)
        ok &= r["bond+state_B"] <= r["target_B"]
    out["pass"] = bool(ok)
    return out
