"""CPD static scenes: a bar in tension and a cantilever under a tip load (2D and 3D), solved
with the Newton-Raphson solver (:mod:`upscale.engine.newton`) on the CPD model
(:mod:`upscale.models.cpd`), against closed-form solutions.

Bar (length L, cross-section A = W t (2D, plane stress) or W H (3D)): the left end layer
(one horizon thick) is held axially, one particle is pinned laterally, a total force ``F`` is
spread uniformly over the right end layer. Reference: uniaxial stress, ``u(x2) - u(x1) =
F (x2 - x1)/(E A)`` in the gauge section (middle 40 %) and lateral strain ``-nu F/(E A)``.

Cantilever (free length L from the clamp face to the loaded end, depth H, width t or W): a
clamp one horizon thick (all dofs), a total transverse load ``P`` spread over the last
column. Reference: Timoshenko ``v = P L^3/(3 E I) + P L/(kappa G A)`` (``kappa = 5/6``),
and Euler-Bernoulli ``P L^3/(3 E I)``.

:func:`cpd` runs either as a :class:`~upscale.experiments.result.Result` (figures, the
displacement profile along the body, the displacements per particle); :func:`plot` draws
the deformed body of a :func:`bar_tension` / :func:`cantilever` dict. Command line:
``upscale cpd --scene bar --dim 2 --dx 1e-3 --ratio 3``.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Literal

import numpy as np

from upscale.analysis.plots import save_figure
from upscale.engine import newton
from upscale.engine.families import build_family
from upscale.engine.state import State
from upscale.engine.system import cubic_lattice, square_lattice
from upscale.engine.memory import run_memory
from upscale.experiments.result import Result, Timer, make_meta

__all__ = ["bar_tension", "cantilever", "cpd", "plot"]


def _body(dim, nx, ny, nz, dx, thickness):
    if dim == 2:
        return square_lattice(nx, ny, dx, thickness=thickness, plane="stress")
    return cubic_lattice(nx, ny, nz, dx)


def _model(dim, E, nu, delta, mode, quadrature, calibration, surface_correction):
    from upscale.models.cpd import CPD

    return CPD(horizon=delta, dim=dim, E=E, nu=nu, mode=mode, quadrature=quadrature,
               calibration=calibration, surface_correction=surface_correction)


def bar_tension(*, dim: int = 2, E: float = 1e9, nu: float = 0.4, length: float = 40e-3,
                width: float = 10e-3, dx: float = 1e-3, ratio: float = 3.0,
                strain: float = 1e-4, mode: str = "auto", quadrature: str = "volume",
                calibration: str = "discrete", partial_volume: str | None = "linear",
                surface_correction: bool = False, steps: int = 1, tol: float = 1e-10,
                checkpoint=None, resume: bool = False) -> dict:
    """Bar in uniaxial tension (force controlled). Returns a dict of results (SI units).

    ``ratio`` = delta/dx; ``strain`` sets the load ``F = strain E A``. In 3D the section is
    ``width x width``; in 2D the thickness is ``dx``. ``checkpoint`` / ``resume``: see
    :func:`upscale.engine.newton.solve`.
    """
    nx = int(round(length / dx)) + 1
    ny = int(round(width / dx)) + 1
    t = dx
    s = _body(dim, nx, ny, ny, dx, t)
    delta = ratio * dx
    fam = build_family(s, delta, partial_volume=partial_volume)
    model = _model(dim, E, nu, delta, mode, quadrature, calibration, surface_correction)
    t0 = time.perf_counter()
    model.prepare(s, fam)
    t_prep = time.perf_counter() - t0
    x = s.x0
    xmin, xmax = x[:, 0].min(), x[:, 0].max()
    left = x[:, 0] < xmin + delta - 1e-9 * dx
    right = x[:, 0] > xmax - delta + 1e-9 * dx
    W = (ny - 1) * dx + dx          # cell-based section: ny cells of dx
    A = W * t if dim == 2 else W * W
    F = strain * E * A
    fixed = np.zeros((s.n, 3), bool)
    fixed[left, 0] = True
    c = x.mean(axis=0)
    pin = int(np.argmin(np.linalg.norm((x - c) * [0, 1, 1] + (x[:, 0] - xmin)[:, None] * [1, 0, 0], axis=1)))
    fixed[pin, 1:] = True
    if dim == 3:  # stop the rotation about x: a second left particle held in z
        off = np.flatnonzero(left & (np.abs(x[:, 2] - x[pin, 2]) < 1e-9 * dx) & (np.abs(x[:, 1] - x[pin, 1]) > 0.5 * dx))
        fixed[off[0], 2] = True
    f = np.zeros((s.n, 3))
    f[right, 0] = F / right.sum()
    st = State.reference(x, fam.nb)
    res = newton.solve(model, st, fixed=fixed, f_ext=f, steps=steps, tol=tol,
                       checkpoint=checkpoint, resume=resume)
    u = st.y - x
    L_bar = xmax - xmin
    gauge = (x[:, 0] > xmin + 0.3 * L_bar) & (x[:, 0] < xmin + 0.7 * L_bar)
    eps_ax = np.polyfit(x[gauge, 0], u[gauge, 0], 1)[0]
    eps_ref = F / (E * A)
    lat = []
    for k in range(1, dim):
        xc = x[:, k] - x[:, k].mean()
        inner = gauge & (np.abs(xc) <= 0.5 * (W - dx) - delta + 1e-9 * dx)
        sel = inner if inner.sum() > 3 and np.ptp(xc[inner]) > 0 else gauge
        lat.append(np.polyfit(xc[sel], u[sel, k], 1)[0])
    nu_meas = -float(np.mean(lat)) / eps_ax
    x1, x2 = xmin + 0.3 * L_bar, xmin + 0.7 * L_bar
    return {
        "scene": "bar", "dim": dim, "dx_m": dx, "delta_over_dx": ratio, "horizon_m": delta,
        "particles": s.n, "E_Pa": E, "nu": nu, "force_N": F,
        "gauge_elongation_m": float(eps_ax * (x2 - x1)),
        "gauge_elongation_ref_m": float(eps_ref * (x2 - x1)),
        "displacement_err_pct": float(100 * (eps_ax / eps_ref - 1)),
        "nu_measured": nu_meas, "poisson_err_pct": float(100 * (nu_meas / nu - 1)),
        "newton": res.as_dict(), "newton_report": res.report(), "prepare_s": t_prep,
        "solve_s": res.wall_time_s, "constants": list(model.C),
        "interactions_per_point": {k: float(np.mean(v)) for k, v in model.counts.items()},
        "_state": (s, st), "_memory": run_memory(s, fam, [model], st),
    }


def cantilever(*, dim: int = 2, E: float = 1e9, nu: float = 0.4, length: float = 40e-3,
               depth: float = 8e-3, dx: float = 1e-3, ratio: float = 3.0,
               deflection: float = 1e-3, mode: str = "auto", quadrature: str = "volume",
               calibration: str = "discrete", partial_volume: str | None = "linear",
               surface_correction: bool = False, steps: int = 1, tol: float = 1e-10) -> dict:
    """Cantilever under a transverse tip load; ``deflection`` (fraction of L) sets ``P``
    from the Euler-Bernoulli formula so that the response stays linear. In 3D the width
    equals the depth; in 2D the thickness is ``dx`` (plane stress)."""
    delta = ratio * dx
    n_clamp = int(np.floor(delta / dx + 1e-9))          # clamp layers of one horizon
    nx = int(round(length / dx)) + n_clamp
    ny = int(round(depth / dx))
    t = dx
    s = _body(dim, nx, ny, ny, dx, t)
    fam = build_family(s, delta, partial_volume=partial_volume)
    model = _model(dim, E, nu, delta, mode, quadrature, calibration, surface_correction)
    t0 = time.perf_counter()
    model.prepare(s, fam)
    t_prep = time.perf_counter() - t0
    x = s.x0
    xmin, xmax = x[:, 0].min(), x[:, 0].max()
    clamp = x[:, 0] < xmin + n_clamp * dx - 0.5 * dx
    tip = x[:, 0] > xmax - 0.5 * dx
    x_face = xmin + n_clamp * dx - 0.5 * dx
    L = xmax - x_face                       # clamp face to the loaded column
    H = ny * dx
    b = t if dim == 2 else ny * dx
    I = b * H ** 3 / 12.0
    A = b * H
    G = E / (2 * (1 + nu))
    P = deflection * L * 3 * E * I / L ** 3
    v_eb = P * L ** 3 / (3 * E * I)
    v_timo = v_eb + P * L / (5.0 / 6.0 * G * A)
    f = np.zeros((s.n, 3))
    f[tip, 1] = -P / tip.sum()
    st = State.reference(x, fam.nb)
    res = newton.solve(model, st, fixed=clamp, f_ext=f, steps=steps, tol=tol)
    v = -float((st.y - x)[tip, 1].mean())
    return {
        "scene": "cantilever", "dim": dim, "dx_m": dx, "delta_over_dx": ratio,
        "horizon_m": delta, "particles": s.n, "E_Pa": E, "nu": nu, "load_N": P,
        "free_length_m": L, "depth_m": H, "tip_deflection_m": v,
        "euler_bernoulli_m": v_eb, "timoshenko_m": v_timo,
        "deflection_err_pct": float(100 * (v / v_timo - 1)),
        "deflection_err_vs_eb_pct": float(100 * (v / v_eb - 1)),
        "newton": res.as_dict(), "newton_report": res.report(), "prepare_s": t_prep,
        "solve_s": res.wall_time_s, "constants": list(model.C),
        "interactions_per_point": {k: float(np.mean(v_)) for k, v_ in model.counts.items()},
        "_state": (s, st), "_memory": run_memory(s, fam, [model], st),
    }


def plot(result: dict, path, scale: float | None = None) -> Path:
    """Deformed configuration (displacement magnified) coloured by displacement magnitude."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s, st = result["_state"]
    u = st.y - s.x0
    mag = np.linalg.norm(u, axis=1)
    L = np.ptp(s.x0[:, 0])
    if scale is None:
        scale = 0.1 * L / max(mag.max(), 1e-300)
    yd = s.x0 + scale * u
    fig, ax = plt.subplots(figsize=(7, 3))
    sc = ax.scatter(yd[:, 0] * 1e3, yd[:, 1] * 1e3, c=mag * 1e6, s=8, cmap="viridis")
    ax.scatter(s.x0[:, 0] * 1e3, s.x0[:, 1] * 1e3, s=1, c="0.8", zorder=0)
    fig.colorbar(sc, ax=ax, label="|u| (um)")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    key = "displacement_err_pct" if result["scene"] == "bar" else "deflection_err_pct"
    ax.set_title(f"CPD {result['scene']} {result['dim']}D, delta/dx={result['delta_over_dx']:g}, "
                 f"x{scale:.3g}; error {result[key]:+.2f} %")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def cpd(*, scene: Literal["bar", "cantilever"] = "bar", dim: Literal[2, 3] = 2, E: float = 1e9,
        nu: float = 0.4, dx: float = 1e-3, ratio: float = 3.0,
        mode: Literal["auto", "C1C2", "C1C3", "C2C3"] = "auto") -> Result:
    """CPD static bar in tension or cantilever under a tip load, Newton solve, against the
    closed forms (module docstring).

    Parameters
    ----------
    scene : {"bar", "cantilever"}
        Bar in uniaxial tension (40 x 10 mm) or cantilever under a tip load (40 x 8 mm).
    dim : {2, 3}
        Dimension (2: plane stress, thickness dx; 3: square section).
    E : float
        Young's modulus in Pa.
    nu : float
        Poisson's ratio (dimensionless; within the range CPD reaches).
    dx : float
        Particle spacing in m (positive, at most half the section).
    ratio : float
        Horizon over spacing, delta / dx (dimensionless).
    mode : {"auto", "C1C2", "C1C3", "C2C3"}
        3D calibration mode: which two of the three CPD constants are free.
    """
    section = 10e-3 if scene == "bar" else 8e-3
    if not (np.isfinite(dx) and 0 < dx <= section / 2):
        raise ValueError(f"dx={dx!r} m; valid: 0 < dx <= {section / 2:g} m (half the section)")
    if not (np.isfinite(ratio) and ratio > 0):
        raise ValueError(f"ratio={ratio!r}; valid: a positive horizon over spacing")
    if scene not in ("bar", "cantilever"):
        raise ValueError(f"scene={scene!r}; valid: 'bar', 'cantilever'")
    params = dict(scene=scene, dim=dim, E=E, nu=nu, dx=dx, ratio=ratio, mode=mode)
    kw = dict(dim=int(dim), E=E, nu=nu, dx=dx, ratio=ratio, mode=mode)
    with Timer() as timer:
        r = bar_tension(**kw) if scene == "bar" else cantilever(**kw)
    s, st = r["_state"]
    x0, u = s.x0, st.y - s.x0
    cols = np.rint((x0[:, 0] - x0[:, 0].min()) / dx).astype(np.int64)
    counts = np.bincount(cols)
    xs = np.bincount(cols, weights=x0[:, 0]) / counts
    curves = {"profile/x_m": xs}
    if scene == "bar":
        curves["profile/u_x_m"] = np.bincount(cols, weights=u[:, 0]) / counts
        y = ["u_x_m"]
    else:   # deflection (downward positive) and the closed forms from the clamp face
        curves["profile/v_m"] = -np.bincount(cols, weights=u[:, 1]) / counts
        L, H, P, G = r["free_length_m"], r["depth_m"], r["load_N"], E / (2 * (1 + nu))
        b = dx if int(dim) == 2 else H
        I, A = b * H ** 3 / 12.0, b * H
        z = np.clip(xs - (x0[:, 0].max() - L), 0.0, None)
        eb = P * z ** 2 * (3 * L - z) / (6 * E * I)
        curves["profile/v_euler_bernoulli_m"] = eb
        curves["profile/v_timoshenko_m"] = eb + P * z / (5.0 / 6.0 * G * A)
        y = ["v_m", "v_timoshenko_m"]
    newton = r["newton"]
    skip = ("scene", "newton", "newton_report", "prepare_s", "solve_s", "constants",
            "interactions_per_point")
    figures = {k: v for k, v in r.items() if not k.startswith("_") and k not in skip}
    figures.update(newton_converged=newton["converged"], newton_residuals=newton["n_residual"],
                   newton_tangents=newton["n_tangent"],
                   newton_iterations=sum(t["iterations"] for t in newton["steps"]))
    figures.update({f"{k}_per_point": v for k, v in r["interactions_per_point"].items()})
    conventions = {
        "units": "SI (m, N, Pa)",
        "axes": "x along the bar or beam; the cantilever's load acts in -y",
        "errors": "err_pct = 100 (model / closed form - 1); the bar's over its gauge section "
                  "(the middle 40 %), the cantilever's tip deflection against Timoshenko "
                  "(kappa = 5/6) and Euler-Bernoulli",
        "profile": "mean over each column of particles (x0 to 1e-9 m); v is the downward "
                   "deflection; the closed forms are measured from the clamp face",
    }
    meta = make_meta("cpd", params, timer=timer, conventions=conventions,
                     plot={"profile": {"x": "x_m", "y": y}}, newton=newton,
                     newton_report=r["newton_report"], constants=r["constants"],
                     prepare_s=r["prepare_s"], solve_s=r["solve_s"], memory=r["_memory"])
    return Result(figures=figures, curves=curves, fields={"x0": x0, "u": u}, meta=meta)
