"""The tridynamic scenes as functions returning a :class:`~upscale.experiments.result.Result`:
``beam`` (static beams against Euler-Bernoulli / Timoshenko), ``plate-bending`` (the simply
supported plate against Navier + Mindlin) and ``dispersion`` (branches from the models'
force routines against the classical ones). The physics is :mod:`upscale.experiments.scenes.tridyn`
(:func:`~upscale.experiments.scenes.tridyn.beam_static`,
:func:`~upscale.experiments.scenes.tridyn.plate_bending`, the dispersion functions); its
``plot_*`` functions still draw the seed's figures from those dicts.

Command line::

    upscale beam --theory eb --support ss --n 100 --ratios 1,2,3
    upscale beam --theory timoshenko --height 0.001 --ratios 1,2,3 --shear-integration bond
    upscale plate-bending --n 20,40
    upscale dispersion --model tridyn-timoshenko --variant consistent --ratio 1
    upscale dispersion --model tridyn-plate --variant text --text-triplets lines
    upscale dispersion --model tridyn-eb --rotary

Figures of a run over several horizons or grids carry the run as a prefix
(``ratio2_wmax_err_pct``, ``n40_w_centre_m``), the unit stays the suffix.
"""
from __future__ import annotations

import re
from typing import Literal

import numpy as np

from upscale.experiments.result import Result, Timer, make_meta
from upscale.experiments.scenes import tridyn

__all__ = ["beam", "plate_bending_scene", "dispersion"]

_W2 = "rad2_s2"   # suffix of omega^2 columns (rad^2/s^2)


def _tag(prefix: str, value) -> str:
    return f"{prefix}{value:g}"


# =========================================================================== beam
def beam(*, theory: Literal["eb", "timoshenko"] = "eb",
         support: Literal["ss", "cc", "cantilever"] = "ss",
         variant: Literal["text", "consistent"] = "consistent", n: int = 100,
         ratios: tuple[float, ...] = (1.0, 2.0, 3.0), height: float = 0.001,
         free_end: Literal["second-order", "linear"] = "second-order",
         shear_integration: Literal["bond", "ends"] | None = None) -> Result:
    """Tridynamic beam under uniform load against Euler-Bernoulli / Timoshenko (seed 004
    sec. 2.4.1: 1 m, 0.05 m wide, steel, 5 N/m), one static solve per horizon.

    Parameters
    ----------
    theory : {"eb", "timoshenko"}
        Beam theory of the tridynamic model.
    support : {"ss", "cc", "cantilever"}
        Simply supported, clamped at both ends, or clamped-free.
    variant : {"text", "consistent"}
        The model as printed in the seed or its consistent form.
    n : int
        Spacings along the beam (at least 4).
    ratios : tuple of float
        Horizons over spacing delta / dx, one run each (comma-separated on the command line).
    height : float
        Beam depth h in m.
    free_end : {"second-order", "linear"}
        Ghosts beyond a free end of the text EB beam (no moment, no shear).
    shear_integration : {"bond", "ends"} or None
        Timoshenko: rotation in a pair's shear measure, integrated along the bond or the
        mean of the two ends (None: the model's default, "ends").
    """
    ratios = tuple(float(r) for r in ratios)
    if not ratios or not all(np.isfinite(r) and r > 0 for r in ratios):
        raise ValueError(f"ratios={ratios!r}; valid: one or more positive delta/dx values")
    params = dict(theory=theory, support=support, variant=variant, n=n, ratios=ratios,
                  height=height, free_end=free_end, shear_integration=shear_integration)
    kw = {"free_end": free_end}
    if theory == "timoshenko" and shear_integration is not None:
        kw["shear_integration"] = shear_integration
    with Timer() as timer:
        res = [tridyn.beam_static(theory=theory, support=support, n=n, ratio=r,
                                  variant=variant, height=height, **kw) for r in ratios]
    r0 = res[0]
    figures = {"n": int(n), "wmax_ref_m": r0["wmax_ref_m"]}
    same_x = all(np.array_equal(r["x_m"], r0["x_m"]) for r in res)
    curves = {"profile/x_m": r0["x_m"], "profile/w_ref_m": r0["w_ref_m"]} if same_x else {}
    ys = ["w_ref_m"]
    for ratio, r in zip(ratios, res):
        t = _tag("ratio", ratio)
        figures.update({f"{t}_wmax_m": r["wmax_m"], f"{t}_wmax_err_pct": r["wmax_err_pct"],
                        f"{t}_residual": r["residual"], f"{t}_asymmetry": r["asymmetry"]})
        if same_x:
            curves[f"profile/{t}_w_m"] = r["w_m"]
            ys.append(f"{t}_w_m")
        else:    # the body's nodes differ: one table per horizon
            curves.update({f"{t}/x_m": r["x_m"], f"{t}/w_m": r["w_m"], f"{t}/w_ref_m": r["w_ref_m"]})
    conventions = {
        "units": "SI (m, N/m)",
        "deflection": "w along the load (+z), at the body's nodes x in [0, L]",
        "reference": "Euler-Bernoulli closed form under uniform load; Timoshenko adds the "
                     "shear term (k = 5/6)",
        "errors": "wmax_err_pct = 100 (w / w_ref - 1) at the node of the largest reference "
                  "deflection; residual: the static solve's relative residual; asymmetry: "
                  "the operator's",
    }
    plot = {"profile": {"x": "x_m", "y": ys}} if same_x else \
        {_tag("ratio", r): {"x": "x_m", "y": ["w_m", "w_ref_m"]} for r in ratios}
    meta = make_meta("beam", params, timer=timer, conventions=conventions, plot=plot,
                     models=[r["model"] for r in res])
    return Result(figures=figures, curves=curves, meta=meta)


# =========================================================================== plate bending
def plate_bending_scene(*, n: tuple[int, ...] = (20, 40), ratio: float = 1.0,
                        thickness: float = 0.1) -> Result:
    """Tridynamic simply supported square plate (a = 1 m, steel) under uniform load
    against Navier + Mindlin, one static solve per grid.

    Parameters
    ----------
    n : tuple of int
        Spacings per side, one run each (comma-separated on the command line).
    ratio : float
        Horizon over spacing delta / dx.
    thickness : float
        Plate thickness h in m (the side is a = 1 m).
    """
    ns = tuple(int(v) for v in n)
    if not ns or min(ns) < 2:
        raise ValueError(f"n={n!r}; valid: one or more grids of at least 2 spacings a side")
    if not (np.isfinite(ratio) and ratio > 0):
        raise ValueError(f"ratio={ratio!r}; valid: a positive delta/dx")
    if not (np.isfinite(thickness) and thickness > 0):
        raise ValueError(f"thickness={thickness!r} m; valid: a positive thickness")
    params = dict(n=ns, ratio=ratio, thickness=thickness)
    with Timer() as timer:
        res = [tridyn.plate_bending(n=k, ratio=ratio, h=thickness) for k in ns]
    r0 = res[0]
    figures = {"delta_over_dx": r0["delta_over_dx"], "h_over_a": r0["h_over_a"],
               "navier_mindlin_m": r0["navier_mindlin_m"],
               "navier_kirchhoff_m": r0["navier_kirchhoff_m"]}
    curves, plot = {}, {}
    for k, r in zip(ns, res):
        t = f"n{k}"
        figures.update({f"{t}_w_centre_m": r["w_centre_m"], f"{t}_err_pct": r["err_pct"],
                        f"{t}_residual": r["residual"], f"{t}_asymmetry": r["asymmetry"]})
        curves.update({f"{t}/x_m": r["x_m"], f"{t}/w_m": r["w_m"], f"{t}/w_ref_m": r["w_ref_m"]})
        plot[t] = {"x": "x_m", "y": ["w_m", "w_ref_m"]}
    conventions = {
        "units": "SI (m, N/m^2)",
        "load": "q = 1 kPa uniform, w along it; E = 200 GPa, nu = 0.3, k_s = 5/6",
        "reference": "Navier series with the Mindlin shear term (Kirchhoff: without it)",
        "errors": "err_pct = 100 (w_centre / navier_mindlin - 1)",
        "profile": "the mid-line y = a/2 (tables nN: one per grid)",
    }
    meta = make_meta("plate-bending", params, timer=timer, conventions=conventions, plot=plot)
    return Result(figures=figures, curves=curves, meta=meta)


# =========================================================================== dispersion
_PLATE_BRANCHES = ("flexural", "SH", "P", "twist-shear", "thickness-shear")


def _slug(term: str) -> str:
    return re.sub(r"[^A-Za-z0-9,]+", "_", term).strip("_")


def dispersion(*, model: Literal["tridyn-timoshenko", "tridyn-eb", "tridyn-plate", "pmb"]
               = "tridyn-timoshenko", variant: Literal["text", "consistent"] = "consistent",
               ratio: float = 1.0, edge_factor: float = 1.0,
               text_triplets: Literal["lines", "cross"] = "lines", rotary: bool = False,
               brillouin: bool = False, compare_text: bool = False) -> Result:
    """Dispersion of a linear model from its force routine against the classical branches
    (Timoshenko / EB beam, Rayleigh beam, Mindlin plate, the peridynamic bar).

    Parameters
    ----------
    model : {"tridyn-timoshenko", "tridyn-eb", "tridyn-plate", "pmb"}
        Model whose dynamical matrix is read (pmb: the bond-based bar).
    variant : {"text", "consistent"}
        Tridynamic model as printed or consistent (tridyn-plate with "text": its long-wave coefficients).
    ratio : float
        Horizon over spacing delta / dx.
    edge_factor : float
        Appendix C factor of the Timoshenko beam (1 or 2).
    text_triplets : {"lines", "cross"}
        Triangles of the printed plate (tridyn-plate, variant text).
    rotary : bool
        tridyn-eb with the sections' rotary inertia (Rayleigh beam).
    brillouin : bool
        Beam wavenumbers up to the zone edge (k h to 0.99 pi / 0.01).
    compare_text : bool
        Timoshenko: add the text-faithful beam without and with the appendix factor.
    """
    if not (np.isfinite(ratio) and ratio > 0):
        raise ValueError(f"ratio={ratio!r}; valid: a positive delta/dx")
    params = dict(model=model, variant=variant, ratio=ratio, edge_factor=edge_factor,
                  text_triplets=text_triplets, rotary=rotary, brillouin=brillouin,
                  compare_text=compare_text)
    kh = np.geomspace(0.01, 3.0, 25)
    extra = {}
    with Timer() as timer:
        if model == "tridyn-plate" and variant == "text":
            figures, curves, plot, extra = _plate_long_wave(ratio, text_triplets)
        elif model == "tridyn-eb" and rotary:
            figures, curves, plot = _rayleigh(ratio, kh)
        elif model == "tridyn-plate":
            figures, curves, plot = _plate_dispersion(ratio)
        elif model == "pmb":
            figures, curves, plot = _pd_bar(ratio)
        elif model in ("tridyn-timoshenko", "tridyn-eb"):
            if brillouin:
                kh = np.geomspace(0.01, 0.99 * np.pi / 0.01, 40)  # to the zone edge, dx = 0.01 h
            figures, curves, plot, extra = _beam_dispersion(model, variant, ratio, kh,
                                                            edge_factor, compare_text)
        else:
            raise ValueError(f"unknown model {model!r}; valid: 'tridyn-timoshenko', "
                             "'tridyn-eb', 'tridyn-plate', 'pmb'")
    conventions = {
        "units": "SI; omega^2 columns in rad^2/s^2 (suffix rad2_s2); wavenumbers "
                 "dimensionless (k h: h the beam depth; k dx; k delta)",
        "rel_err": "|omega^2 / reference - 1| per branch",
        "beams": "square section h x h, h = 1e-7 m, dx = 0.01 h, steel (seed 004 eq. 3.58)",
    }
    meta = make_meta("dispersion", params, timer=timer, conventions=conventions, plot=plot,
                     **extra)
    return Result(figures=figures, curves=curves, meta=meta)


def _beam_dispersion(model, variant, ratio, kh, edge_factor, compare_text):
    theory = "timoshenko" if model == "tridyn-timoshenko" else "eb"
    kw = {"edge_factor": edge_factor} if theory == "timoshenko" else {}
    r = tridyn.beam_dispersion(theory=theory, variant=variant, ratio=ratio, kh=kh, **kw)
    figures = {"delta_over_dx": r["delta_over_dx"], "dx_over_h": r["dx_over_h"]}
    curves = {"dispersion/kh": r["kh"]}
    ys = []
    runs = [("", r)]
    if theory == "timoshenko" and compare_text:
        runs += [(f"text_x{ef:g}_", tridyn.beam_dispersion(theory=theory, variant="text",
                                                          ratio=ratio, kh=kh, edge_factor=ef))
                 for ef in (1.0, 2.0)]
    for pre, rr in runs:
        for br in ("axial", "flexural", "shear"):
            if br not in rr:
                continue
            rel = np.abs(rr[br] / rr[br + "_ref"] - 1)
            figures[f"{pre}{br}_rel_err_max"] = float(rel.max())
            curves[f"dispersion/{pre}{br}_{_W2}"] = rr[br]
            curves[f"dispersion/{pre}{br}_rel_err"] = rel
            if not pre:
                curves[f"dispersion/{br}_ref_{_W2}"] = rr[br + "_ref"]
            ys.append(f"{pre}{br}_rel_err")
    return figures, curves, {"dispersion": {"x": "kh", "y": ys}}, {"model_description": r["model"]}


def _rayleigh(ratio, kh):
    r = tridyn.rayleigh_dispersion(ratio=ratio, kh=kh)
    figures = {"delta_over_dx": r["delta_over_dx"], "dx_over_h": r["dx_over_h"],
               "rel_err_max": r["rel_err_max"]}
    curves = {"dispersion/kh": r["kh"], f"dispersion/omega2_{_W2}": r["omega2"],
              f"dispersion/rayleigh_{_W2}": r["rayleigh"], f"dispersion/eb_{_W2}": r["eb"],
              "dispersion/rel_err": r["rel_err"], "dispersion/eb_over_rayleigh": r["eb_over_rayleigh"]}
    return figures, curves, {"dispersion": {"x": "kh", "y": ["rel_err"]}}


def _plate_dispersion(ratio):
    r = tridyn.plate_dispersion(ratio=ratio, kdx=np.geomspace(0.005, 0.5, 12))
    figures = {"delta_over_dx": r["delta_over_dx"], "h_over_dx": r["h_over_dx"],
               "rel_err_max": r["rel_err_max"]}
    curves, plot = {}, {}
    long = r["kdx"] <= 0.05 + 1e-12
    for ang, e in r["rel_err"].items():
        t = _tag("angle", ang)
        curves[f"{t}/kdx"] = r["kdx"]
        for b, name in enumerate(_PLATE_BRANCHES):
            figures[f"{t}_{name}_rel_err_max"] = float(e[long, b].max())   # k dx <= 0.05
            curves[f"{t}/{name}_{_W2}"] = r["branches"][ang][:, b]
            curves[f"{t}/{name}_ref_{_W2}"] = r["ref"][:, b]
            curves[f"{t}/{name}_rel_err"] = e[:, b]
        plot[t] = {"x": "kdx", "y": [f"{name}_rel_err" for name in _PLATE_BRANCHES]}
    return figures, curves, plot


def _plate_long_wave(ratio, text_triplets):
    r = tridyn.plate_long_wave(variant="text", text_triplets=text_triplets, ratio=ratio)
    figures = {}
    for term, (mv, lit, ref) in r["terms"].items():
        figures[f"{_slug(term)}_over_mindlin"] = mv / ref
        figures[f"{_slug(term)}_printed_over_mindlin"] = lit / ref
    figures.update(spurious_v_u_along_x=r["spurious_v_u_along_x"],
                   min_over_max_omega2=r["min_over_max_omega2"], asymmetry=r["asymmetry"])
    scan = r["min_over_max_omega2_by_kdx"]
    curves = {"scan/kdx": np.array(list(scan)), "scan/min_over_max_omega2": np.array(list(scan.values()))}
    extra = {"terms": {t: {"model": v[0], "printed_local_limit": v[1], "mindlin": v[2]}
                       for t, v in r["terms"].items()}, "model_description": r["model"]}
    return figures, curves, {"scan": {"x": "kdx", "y": ["min_over_max_omega2"]}}, extra


def _pd_bar(ratio):
    r = tridyn.pd_bar_dispersion(ratio=ratio)
    figures = {"delta_over_dx": r["delta_over_dx"], "c_N_m6": r["c"],
               "omega2_vs_lattice_max_rel_dev": float(np.max(np.abs(r["omega2"] / r["lattice"] - 1))),
               "omega2_vs_continuum_max_rel_dev": float(np.max(np.abs(r["omega2"] / r["continuum"] - 1)))}
    curves = {"dispersion/kdelta": r["kdelta"], f"dispersion/omega2_{_W2}": r["omega2"],
              f"dispersion/lattice_{_W2}": r["lattice"], f"dispersion/continuum_{_W2}": r["continuum"],
              f"dispersion/eq_3_55_{_W2}": r["eq_3_55"]}
    ys = [f"omega2_{_W2}", f"continuum_{_W2}", f"eq_3_55_{_W2}"]
    return figures, curves, {"dispersion": {"x": "kdelta", "y": ys}}
