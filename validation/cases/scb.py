"""SCB cases (seed 004 ch. 6): the FE reference, the elastic particle model against it, Table
6.2 and the spacing convergence of the critical load.

``scb-fem``: geometry factors Y_I, Y_II, T* of the eight angles (scikit-fem, tip-refined P2
mesh, :mod:`validation.fem_scb`) against those implied by Table 6.2's own K and P columns.
``scb-elastic``: the unified model (elastic) against the FE with the same boundary conditions
(the 3 x 3 particle patches held as blocks): Y_I, Y_II from a Williams-expansion fit of the
near field, load-patch compliance; rollers and the literal pinned supports.
``scb-table``: r_s calibrated at alpha = 0 only (a scan over ``--r-s-candidates`` for the
averaged-stress criteria; the stored calibration for the energy criterion), P_c at the eight
angles, K through the FE factors, errors against the experiment and the paper's own;
initiation angles against MTS and GMTS. ``scb-convergence``: P_c at dx = 1, 0.5, 0.25 mm with
r_s fixed in metres and with r_s = 2 dx. ``scb-rate``: explicit dynamics at three loading
times against the quasi-static P_c; the load patch's velocity rises smoothly over
``RATE_RISE`` of the loading time (a velocity jump leaves an undamped vibration that shifts
the first failure by about 1 / (omega_1 t_c) of the load).

P_c is the peak before the load first falls below ``--stop-fraction`` of it.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from validation.registry import case, figure, show

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "data" / "experiments" / "scb_table_6_2.json"
ALPHAS = (0.0, 10.0, 20.0, 30.0, 40.0, 43.0, 47.0, 50.0)
R, A_CRACK, T_THICK = 0.05, 0.015, 0.005
RATE_RISE = 0.3        # scb-rate: load-patch velocity rise time / loading time (SCBScene.explicit)
R_C_GMTS = 1.5e-4      # GMTS critical distance (m): (K_Ic / sigma_t)^2 / 2 pi, sigma_t = 70 MPa (assumed)


def _exp():
    return json.loads(TABLE.read_text())


def _fe(alpha, w, supports="rollers", quick=False, patch="segment", block=None):
    from validation.fem_scb import solve_scb

    return solve_scb(alpha, w=w, supports=supports, h_tip=8e-5 if quick else 2e-5, patch=patch, block=block)


def _fe_block(alpha, dx, supports="rollers", quick=False):
    """FE with the particle model's boundary conditions: every point inside the box of the
    patch particles' centres (half width 1.5 dx, depth 2.5 dx from the edge) is held."""
    return _fe(alpha, 3 * dx, supports, quick, patch="block", block=(1.5 * dx, 2.5 * dx))


def _outdir(args):
    out = Path(args.outdir) / "scb"
    out.mkdir(parents=True, exist_ok=True)
    return out


# ---------------------------------------------------------------------------- scb-fem
@case("scb-fem", "SCB FE reference: Y_I, Y_II, T* for the eight angles (scikit-fem + gmsh)")
def run_fem(args):
    quick = args.quick
    w = 1.5e-3  # load/support width: 3 x 0.5 mm
    ex = _exp()
    f = R * 2 * T_THICK / np.sqrt(np.pi * A_CRACK)
    rows, res = [], []
    for i, al in enumerate(ALPHAS):
        r = _fe(al, w, quick=quick)
        Yi_t = ex["exp_K_I"][i] * 1e6 * f / (ex["exp_P_c_kN"][i] * 1e3)
        Yii_t = ex["exp_K_II"][i] * 1e6 * f / (ex["exp_P_c_kN"][i] * 1e3)
        res.append(r)
        rows.append({"alpha": al, "Y_I": r["Y_I"], "Y_II": r["Y_II"], "T*": r["T_star"],
                     "Y_I(tab 6.2)": Yi_t, "Y_II(tab 6.2)": Yii_t, "dofs": r["n_dofs"]})
    pin = _fe(0.0, w, "pinned", quick=quick)
    show(rows, fmt=".4f")
    dYI = [abs(r["Y_I"] - q["Y_I(tab 6.2)"]) for r, q in zip(res, rows)]
    return {"alpha_deg": list(ALPHAS), "Y_I": [r["Y_I"] for r in res], "Y_II": [r["Y_II"] for r in res],
            "T_star": [r["T_star"] for r in res],
            "compliance_um_per_N": res[0]["compliance_m_per_N"] * 1e6,
            "Y_I_pinned_alpha0": pin["Y_I"], "Y_I_vs_table_absdiff_max": max(dYI),
            "Y_II_vs_table_absdiff_max": max(abs(r["Y_II"] - q["Y_II(tab 6.2)"]) for r, q in zip(res, rows)),
            "w_m": w, "h_tip_m": res[0]["h_tip_m"]}


# ---------------------------------------------------------------------------- scb-elastic
def _el_args(p):
    p.add_argument("--dx", type=float, default=None, help="particle spacing in m (default 1e-3, quick 2e-3)")


@case("scb-elastic", "SCB elastic: unified particle model vs FE (Y_I, Y_II, compliance; rollers and pinned)", _el_args)
def run_elastic(args):
    """The FE reference carries the particle model's boundary conditions (the load and
    support patches are 3 x 3 particle blocks, so the FE holds the box of their centres,
    ``_fe_block``). The particle factors come from the Williams fit over the annulus
    0.2 a < r < 0.6 a (``method="williams"``, 10 orders)."""
    from upscale.experiments.scenes.scb import SCBScene

    quick = args.quick
    dx = args.dx or (2e-3 if quick else 1e-3)
    rows = []
    eI, eII, eC = [], [], []
    for al in ALPHAS:
        sc = SCBScene(al, dx=dx)
        fe = _fe_block(al, dx, quick=quick)
        st, P = sc.elastic()
        k = sc.stress_intensity(st, P, method="williams", n_terms=10)
        C = 1e-5 / P
        row = {"alpha": al, "Y_I": k["Y_I"], "Y_I FE": fe["Y_I"], "Y_II": k["Y_II"], "Y_II FE": fe["Y_II"],
               "C um/N": C * 1e6, "C FE": fe["compliance_m_per_N"] * 1e6, "T* W": k["T_star"], "T* FE": fe["T_star"]}
        if abs(fe["Y_I"]) > 0.1:
            eI.append(100 * (k["Y_I"] / fe["Y_I"] - 1))
        if abs(fe["Y_II"]) > 0.1:
            eII.append(100 * (k["Y_II"] / fe["Y_II"] - 1))
        eC.append(100 * (C / fe["compliance_m_per_N"] - 1))
        if al == 0.0:
            c_err = eC[-1]
        rows.append(row)
    fe_p = _fe_block(0.0, dx, "pinned", quick=quick)
    sc = SCBScene(0.0, dx=dx, supports="pinned")
    st, P = sc.elastic()
    kp = sc.stress_intensity(st, P, method="williams", n_terms=10)
    out = {"dx_m": dx, "stabilisation": sc.model.stabilisation, "gain_order": 1,
           "Y_I_err_pct_max": float(max(np.abs(eI))), "Y_II_err_pct_max": float(max(np.abs(eII))),
           "Y_I_err_pct": [float(e) for e in eI], "Y_II_err_pct": [float(e) for e in eII],
           "compliance_err_pct": float(c_err), "compliance_err_pct_max": float(max(np.abs(eC))),
           "compliance_err_pct_all": [float(e) for e in eC],
           "pinned_Y_I_particle": kp["Y_I"], "pinned_Y_I_fe": fe_p["Y_I"],
           "pinned_compliance_um_per_N": 1e-5 / P * 1e6, "pinned_compliance_fe_um_per_N": fe_p["compliance_m_per_N"] * 1e6,
           "rollers_Y_I_fe": rows[0]["Y_I FE"], "rows": rows}
    out["pass"] = bool(out["Y_I_err_pct_max"] < 5 and out["Y_II_err_pct_max"] < 5 and out["compliance_err_pct_max"] < 5)
    return out


# ---------------------------------------------------------------------------- scb-table
def _mts_angle(KI, KII):
    th = np.linspace(-np.pi * 0.999, np.pi * 0.999, 20001)
    s = np.cos(th / 2) * (KI * np.cos(th / 2) ** 2 - 1.5 * KII * np.sin(th))
    return float(np.degrees(th[np.argmax(s)]))


def _gmts_angle(KI, KII, T, rc=R_C_GMTS):
    th = np.linspace(-np.pi * 0.999, np.pi * 0.999, 20001)
    s = (np.cos(th / 2) * (KI * np.cos(th / 2) ** 2 - 1.5 * KII * np.sin(th)) / np.sqrt(2 * np.pi * rc)
         + T * np.sin(th) ** 2)
    return float(np.degrees(th[np.argmax(s)]))


def _table_args(p):
    p.add_argument("--dx", type=float, default=None, help="spacing in m (default 2e-3)")
    p.add_argument("--alphas", default=None, help="comma list of angles (default the eight; quick 0,30,50)")
    p.add_argument("--r-s", type=float, default=None, help="use this r_s (m) instead of calibrating")
    p.add_argument("--stop-fraction", type=float, default=0.5,
                   help="a run ends when the load falls below this fraction of its peak")
    p.add_argument("--criterion", default="principal", choices=("principal", "normal", "energy"),
                   help="failure rule of the unified model (default %(default)s)")
    p.add_argument("--r-s-candidates", default="1e-3,2e-3,3e-3",
                   help="principal/normal criteria: r_s values (m) tried at alpha = 0 (default %(default)s)")


def calibrate_r_s_scan(dx, P_target, candidates, criterion="principal", log=print, growth=None):
    """P_c at alpha = 0 for each candidate r_s (m); the closest to ``P_target``, refined by
    one linear interpolation when two candidates bracket it. For the averaged-stress
    criteria P_c depends on r_s only through the body's non-singular terms and the
    discretisation (the criterion reproduces K_Ic in a K-dominated field), so the
    dependence is weak and need not be monotone: a scan, not a secant."""
    from upscale.experiments.scenes.scb import run_scb

    hist = []

    def trial(r):
        res = run_scb(0.0, dx=dx, r_s=r, stop_fraction=0.6, criterion=criterion, growth=growth)
        hist.append((r, res["P_c_N"], res["wall_s"]))
        log(f"  calibration: r_s = {r * 1e3:.4f} mm -> P_c = {res['P_c_N'] / 1e3:.4f} kN ({res['wall_s']:.0f} s)")

    for r in candidates:
        trial(r)
    hist.sort()
    for (r1, P1, _), (r2, P2, _) in zip(hist, hist[1:]):
        if (P1 - P_target) * (P2 - P_target) < 0:
            trial(r1 + (P_target - P1) * (r2 - r1) / (P2 - P1))
            break
    # A disc of radius r_s holds the same particles over a range of r_s, so the interpolated
    # r_s can tie with a candidate to round-off: a tie (1e-9 relative) goes to the candidate.
    best = min(hist, key=lambda h: (round(abs(h[1] / P_target - 1), 9), h[0] not in candidates))
    return best[0], hist


def _plot_curves(path, curves):
    with figure(path, dpi=150) as (fig, ax):
        for al, c in curves:
            ax.plot(np.array(c["displacement_m"]) * 1e3, np.array(c["load_N"]) / 1e3, ".-", ms=2,
                    label=f"{al:g} deg")
        ax.set(xlabel="load-point displacement (mm)", ylabel="P (kN)")
        ax.legend(fontsize=7)


@case("scb-table", "SCB Table 6.2: P_c at the eight angles with r_s calibrated at alpha = 0 only", _table_args)
def run_table(args):
    from upscale.experiments.scenes.scb import calibrated_r_s, damage_png, default_growth, run_scb

    quick = args.quick
    dx = args.dx or 2e-3
    al_s = args.alphas
    alphas = [float(a) for a in al_s.split(",")] if al_s else ([0.0, 30.0, 50.0] if quick else list(ALPHAS))
    ex = _exp()
    exP = dict(zip(ex["alpha_deg"], ex["exp_P_c_kN"]))
    thP = dict(zip(ex["alpha_deg"], ex["theo_P_c_kN"]))
    t0 = time.perf_counter()
    r_s = args.r_s
    crit = args.criterion
    growth = default_growth(crit)
    cal = None
    if r_s is None and crit == "energy":   # its stored calibration (r_s / dx at alpha = 0)
        r_s = calibrated_r_s("energy", dx)
    elif r_s is None:
        cands = [float(v) for v in args.r_s_candidates.split(",")]
        r_s, cal = calibrate_r_s_scan(dx, exP[0.0] * 1e3, cands, criterion=crit, growth=growth)
    print(f"r_s = {r_s * 1e3:.4f} mm (calibrated at alpha = 0 only)" if cal else f"r_s = {r_s * 1e3:.4f} mm (given)")
    out = _outdir(args)
    rows, curves = [], []
    for al in alphas:
        res = run_scb(al, dx=dx, r_s=r_s, stop_fraction=args.stop_fraction, keep=True, criterion=crit,
                      growth=growth)
        fe = _fe(al, 3 * dx, quick=True)
        f = np.sqrt(np.pi * A_CRACK) / (2 * R * T_THICK)
        P = res["P_c_N"]
        KI, KII = fe["Y_I"] * P * f, fe["Y_II"] * P * f
        T = fe["T_star"] * P / (2 * R * T_THICK)
        err = 100 * (res["P_c_kN"] / exP[al] - 1)
        perr = 100 * (thP[al] / exP[al] - 1)
        row = {"alpha": al, "P_c kN": res["P_c_kN"], "exp kN": exP[al], "err %": err, "paper kN": thP[al],
               "paper err %": perr, "K_I": KI / 1e6, "K_II": KII / 1e6,
               "init deg": res["initiation_angle_deg"], "MTS deg": _mts_angle(KI, KII),
               "GMTS deg": _gmts_angle(KI, KII, T), "wall s": res["wall_s"],
               "equilibria": len(res["curve"]["load_N"]), "stop": res["curve"]["stop_reason"],
               "final/peak": res["curve"]["load_N"][-1] / res["P_c_N"],
               "solver s": res["curve"]["time_split_s"]["newton"],
               "failure s": res["curve"]["time_split_s"]["failure"]}
        rows.append(row)
        print(f"alpha {al:4.1f}: P_c {res['P_c_kN']:.4f} kN, {res['wall_s']:.0f} s", flush=True)
        sc, mu = res.pop("_scene"), res.pop("_damage")
        res.pop("_state")
        pts = np.asarray(res["crack_path_m"]) if res["crack_path_m"] else None
        damage_png(out / f"scb_damage_{al:g}.png", sc, mu,
                   f"alpha = {al:g} deg, dx = {dx * 1e3:g} mm, P_c = {res['P_c_kN']:.3f} kN", pts)
        if al == 30.0 and pts is not None:
            y_, xe_, xm_, off = path_offset(pts, dx)
            row["path offset mm mean"] = float(np.nanmean(np.abs(off)) * 1e3)
            row["path offset mm max"] = float(np.nanmax(np.abs(off)) * 1e3)
            path_png(out / "scb_path_30_vs_experiment.png", sc, mu, pts,
                     f"alpha = 30 deg, dx = {dx * 1e3:g} mm: mean |offset| {row['path offset mm mean']:.2f} mm")
        curves.append((al, res["curve"]))
    _plot_curves(out / "scb_curves.png", curves)
    e = np.array([abs(r["err %"]) for r in rows])
    pe = np.array([abs(100 * (thP[a] / exP[a] - 1)) for a in ALPHAS])
    res = {"dx_m": dx, "r_s_m": r_s, "criterion": crit, "growth": growth, "tip_factor": "solved", "calibration": cal,
           "alpha_deg": alphas,
           "P_c_kN": [r["P_c kN"] for r in rows], "P_c_err_pct": [r["err %"] for r in rows],
           "P_c_err_pct_mean": float(e.mean()), "P_c_err_pct_max": float(e.max()),
           "paper_P_c_err_pct_mean": float(pe.mean()), "paper_P_c_err_pct_max": float(pe.max()),
           "K_I_MPa_sqrt_m": [r["K_I"] for r in rows], "K_II_MPa_sqrt_m": [r["K_II"] for r in rows],
           "initiation_angle_deg": [r["init deg"] for r in rows],
           "MTS_angle_deg": [r["MTS deg"] for r in rows], "GMTS_angle_deg": [r["GMTS deg"] for r in rows],
           "GMTS_r_c_m": R_C_GMTS, "wall_s": time.perf_counter() - t0,
           "path_alpha30_offset_mm_mean": next((r["path offset mm mean"] for r in rows if "path offset mm mean" in r), None),
           "path_alpha30_offset_mm_max": next((r["path offset mm max"] for r in rows if "path offset mm max" in r), None),
           "rows": rows}
    res["pass"] = bool(len(alphas) == 8 and e.mean() < pe.mean() and e.max() <= pe.max())
    return res


# ---------------------------------------------------------------------------- scb-convergence
def _conv_args(p):
    p.add_argument("--dxs", default=None,
                   help="comma list of spacings in m, coarsest first (default 1e-3,5e-4,2.5e-4; "
                        "quick 2e-3,1.5e-3)")
    p.add_argument("--alphas", default=None, help="comma list of angles (default 0,30,50; quick 0)")
    p.add_argument("--r-s", type=float, default=None,
                   help="r_s in m held fixed (default: the stored calibration, "
                        "data/reference/scb_calibration.json)")


CONV_STOP = 0.6        # scb-convergence: stop fraction of its runs


@case("scb-convergence", "SCB: P_c versus spacing, r_s fixed in metres and r_s = 2 dx, and "
      "versus horizon / spacing", _conv_args,
      target="P_c changes by less than 5 % from dx = 0.5 to 0.25 mm (delta/dx = 3, r_s fixed "
             "in metres) at alpha = 0, 30, 50 (issue 19)")
def run_convergence(args):
    """Issue 19's sweep: dx = 1, 0.5, 0.25 mm at alpha = 0, 30, 50 with delta/dx = 3, r_s held
    in metres ("fixed r_s") and r_s = 2 dx; delta/dx = 2 and 4 at the middle spacing.
    ``P_c_change_pct_max``: the largest |change| of P_c between the two finest spacings with
    r_s held in metres (the pass); the same with r_s = 2 dx and over the horizon ratios
    beside it."""
    from upscale.experiments.scenes.scb import calibrated_r_s, run_scb

    quick = args.quick
    dxs = [float(v) for v in (args.dxs or ("2e-3,1.5e-3" if quick else
                                           "1e-3,5e-4,2.5e-4")).split(",")]
    alphas = [float(v) for v in (args.alphas or ("0" if quick else "0,30,50")).split(",")]
    r_s = args.r_s or calibrated_r_s("principal", dxs[0])
    mid = dxs[len(dxs) // 2]
    rows = []

    def one(al, dx, m, mode, r):
        res = run_scb(al, dx=dx, m=m, r_s=r, stop_fraction=CONV_STOP)
        rows.append({"alpha": al, "dx mm": dx * 1e3, "delta/dx": m, "mode": mode,
                     "r_s mm": r * 1e3, "particles": res["scene"]["particles"],
                     "P_c kN": res["P_c_kN"], "initiation deg": res["initiation_angle_deg"],
                     "stop": res["curve"]["stop_reason"], "wall s": res["wall_s"]})
        print(rows[-1], flush=True)
        return res["P_c_kN"]

    ch = []
    for al in alphas:
        for mode in ("fixed r_s", "r_s = 2 dx"):
            P = [one(al, dx, 3.0, mode, r_s if mode == "fixed r_s" else 2 * dx) for dx in dxs]
            ch += [{"alpha": al, "mode": mode, "dx mm": f"{d0 * 1e3:g} -> {d1 * 1e3:g}",
                    "finest": d1 == dxs[-1], "change_pct": 100 * (b / a - 1)}
                   for d0, d1, a, b in zip(dxs, dxs[1:], P, P[1:])]
        if not quick:
            P3 = next(r["P_c kN"] for r in rows if r["alpha"] == al
                      and r["dx mm"] == mid * 1e3 and r["mode"] == "fixed r_s")
            for m in (2.0, 4.0):
                ch.append({"alpha": al, "mode": f"delta/dx {m:g} vs 3", "dx mm": f"{mid * 1e3:g}",
                           "finest": False,
                           "change_pct": 100 * (one(al, mid, m, "fixed r_s", r_s) / P3 - 1)})
    def worst(sel):
        v = [abs(c["change_pct"]) for c in ch if sel(c)]
        return float(max(v)) if v else None

    fixed = worst(lambda c: c["mode"] == "fixed r_s" and c["finest"])
    return {"dx_m": dxs, "alpha_deg": alphas, "r_s_m": r_s, "rows": rows, "changes": ch,
            "P_c_change_pct_max": fixed,
            "P_c_change_pct_max_r_s_2dx": worst(lambda c: c["mode"] == "r_s = 2 dx"
                                                 and c["finest"]),
            "P_c_change_pct_max_m": worst(lambda c: c["mode"].startswith("delta/dx")),
            "pass": bool(fixed is not None and fixed < 5 and dxs[-1] <= 0.25e-3)}


# ---------------------------------------------------------------------------- scb-rate
def _rate_args(p):
    p.add_argument("--dx", type=float, default=None,
                   help="spacing in m (default 1e-3, the calibrated one; quick 2e-3, where the alpha = 0 tip "
                        "lies on a particle row, a/dx = 7.5, so the front rule's P_c is not the 1 mm one)")
    p.add_argument("--r-s", type=float, default=None,
                   help="r_s in m (default: 1e-3 for the averaged-stress criteria, 0.075 for 'energy')")
    p.add_argument("--criterion", default="principal", choices=("principal", "normal", "energy"),
                   help="failure rule (default %(default)s)")
    p.add_argument("--times", default=None, help="comma list of loading times in s to 1 mm "
                   "(default 2e-3,5e-3,1.5e-2; quick 1e-3,2e-3,4e-3)")


@case("scb-rate", "SCB: explicit dynamics at three loading times against the quasi-static P_c", _rate_args)
def run_rate(args):
    from upscale.engine import damage
    from upscale.experiments.scenes.scb import SCBScene, default_growth, run_scb

    quick = args.quick
    crit = args.criterion
    growth = default_growth(crit)
    dx, r_s = args.dx or (2e-3 if quick else 1e-3), args.r_s
    if r_s is None:
        r_s = 0.075 if crit == "energy" else 1e-3
    times = [float(v) for v in (args.times or ("1e-3,2e-3,4e-3" if quick else "2e-3,5e-3,1.5e-2")).split(",")]
    rise = RATE_RISE
    qs = run_scb(0.0, dx=dx, r_s=r_s, stop_fraction=0.5, keep=True, criterion=crit, growth=growth)
    P_qs = qs["P_c_N"]
    mu_qs = qs.pop("_damage")
    qs.pop("_scene"), qs.pop("_state")
    print(f"quasi-static: P_c = {P_qs / 1e3:.4f} kN at {qs['displacement_at_P_c_m'] * 1e3:.4f} mm")
    rows = []
    u_end = 1e-3
    for T in times:
        sc = SCBScene(0.0, dx=dx, r_s=r_s, criterion=crit, growth=growth)
        t, d, P, st, info = sc.explicit(T, u_end, every=1, rise=rise * T)
        mu = damage(sc.family, st.intact)
        k = int(np.argmax(P))
        overlap = float(np.sum((mu > 0.35) & (mu_qs > 0.35)) / max(1, np.sum(mu_qs > 0.35)))
        fb = info["first_break"]
        rows.append({"loading time to 1 mm (s)": T, "rate mm/s": u_end / T * 1e3, "P_c kN": P[k] / 1e3,
                     "first break kN": fb[2] / 1e3 if fb else None,
                     "err %": 100 * (P[k] / P_qs - 1), "d at P_c mm": d[k] * 1e3,
                     "damaged overlap with QS": overlap, "steps": info["steps"], "wall s": info["wall_s"]})
        print(rows[-1], flush=True)
    errs = [r["err %"] for r in rows]
    mono = all(abs(b) <= abs(a) + 1e-9 for a, b in zip(errs, errs[1:]))
    return {"dx_m": dx, "r_s_m": r_s, "criterion": crit, "growth": growth,
            "tip_factor": qs["scene"]["model"].get("tip_factor"), "P_c_quasi_static_kN": P_qs / 1e3, "loading_times_s": times,
            "rise_fraction": rise,
            "P_c_kN": [r["P_c kN"] for r in rows], "P_c_rate_err_pct": errs,
            "P_c_rate_err_pct_slowest": float(errs[-1]), "monotone": bool(mono),
            "P_c_falls_with_loading_time": bool(all(b <= a for a, b in zip(errs, errs[1:]))),
            "first_break_kN": [r["first break kN"] for r in rows],
            "damaged_overlap": [r["damaged overlap with QS"] for r in rows],
            "pass": bool(abs(errs[-1]) < 2 and mono)}


# ---------------------------------------------------------------------------- crack path at 30 deg
PATH_30 = ROOT / "data" / "experiments" / "scb_path_alpha30_ayatollahi2006.json"


def path_offset(pts, dx, y_lo=None, y_hi=None):
    """Horizontal distance (m) between a model crack path and the experimental alpha = 30 deg
    path (``PATH_30``) at the experiment's points: at each point's height y, the model's x
    is the mean x of the path particles ``pts`` (k, 2) within dx / 2 of y (a band one row
    high); points between ``y_lo`` and ``y_hi`` (default: 2 mm above the first point to
    2 mm below the last, i.e. clear of the tip and of the load patch). Returns (y (n,),
    x_exp (n,), x_model (n,), offset (n,)), NaN where the model has no particle at that height."""
    exp = json.loads(PATH_30.read_text())
    xe, ye = np.asarray(exp["x_m"]), np.asarray(exp["y_m"])
    y_lo = ye[0] + 2e-3 if y_lo is None else y_lo
    y_hi = ye[-1] - 2e-3 if y_hi is None else y_hi
    sel = (ye >= y_lo) & (ye <= y_hi)
    pts = np.asarray(pts, float).reshape(-1, 2)
    xm = np.full(sel.sum(), np.nan)
    for k, y in enumerate(ye[sel]):
        band = np.abs(pts[:, 1] - y) <= 0.5 * dx * (1 + 1e-9)
        if band.any():
            xm[k] = pts[band, 0].mean()
    return ye[sel], xe[sel], xm, xm - xe[sel]


def path_png(path, scene, mu, pts, title):
    """Damage map near the crack (``scene``, ``mu``; None: none) with the model's path
    particles and the experimental alpha = 30 deg path of ``PATH_30`` (Ayatollahi et al.
    2006) overlaid."""
    exp = json.loads(PATH_30.read_text())
    with figure(path, figsize=(4.2, 5.6), dpi=150) as (fig, ax):
        if scene is not None:
            x = scene.system.x0
            win = (np.abs(x[:, 0]) < 0.02) & (x[:, 1] > 0.005)
            ax.scatter(x[win, 0] * 1e3, x[win, 1] * 1e3, c=mu[win], s=(scene.dx * 5e3) ** 2, cmap="Greys",
                       vmin=0, vmax=1, marker="s", linewidths=0)
        tip = 15.0 * np.array([np.sin(np.radians(30.0)), np.cos(np.radians(30.0))])
        ax.plot([0, tip[0]], [0, tip[1]], "b-", lw=1.5, label="pre-crack")
        if pts is not None and len(pts):
            ax.plot(np.asarray(pts)[:, 0] * 1e3, np.asarray(pts)[:, 1] * 1e3, "r.", ms=1.5,
                    label="model path (damage >= 0.35)")
        ax.plot(np.asarray(exp["x_m"]) * 1e3, np.asarray(exp["y_m"]) * 1e3, "g-o", ms=3, lw=1.2,
                label="experiment (Ayatollahi et al. 2006)")
        ax.set(xlim=(-20, 20), ylim=(5, 50), aspect="equal", xlabel="x (mm)", ylabel="y (mm)")
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=7, loc="lower left")
    return Path(path)


# ------------------------------------------------------------------ scb-geometry-convergence
def _geo_args(p):
    p.add_argument("--dxs", default=None,
                   help="comma list of spacings in m (default 1e-3,5e-4,2.5e-4,1.25e-4; quick 2e-3,1e-3)")
    p.add_argument("--alphas", default=None, help="comma list of angles (default 0,30,50; quick 0)")


@case("scb-geometry-convergence", "SCB geometry factors of the elastic particle model from dx = 1 to "
      "0.125 mm against the FE with the same patches (data/reference/scb_fem_block.json)", _geo_args)
def run_geometry_convergence(args):
    """Y_I and Y_II (Williams fit, 10 orders) of the elastic unified model at each spacing
    against the FE reference with the particle model's load and support blocks at that
    spacing, read from ``data/reference/scb_fem_block.json`` (``python -m validation.fem_scb
    --block``; a spacing it does not hold, e.g. the quick variant's 2 mm, is solved here).
    A factor whose FE value is below 0.1 in magnitude (Y_II at 0 deg, Y_I near 50 deg) has no
    relative error (as ``scb-elastic``). ``pass``: the finest spacing completed and its
    factors within 5 % of the FE's."""
    import resource

    from upscale.experiments.references import reference_file
    from upscale.experiments.scenes.scb import SCBScene
    from validation.fem_scb import solve_scb

    quick = args.quick
    dxs = [float(v) for v in args.dxs.split(",")] if args.dxs else \
        ([2e-3, 1e-3] if quick else [1e-3, 5e-4, 2.5e-4, 1.25e-4])
    alphas = [float(v) for v in args.alphas.split(",")] if args.alphas else ([0.0] if quick else [0.0, 30.0, 50.0])
    stored = json.loads(reference_file("scb_fem_block.json").read_text())["rows"]
    rows = []
    for dx in dxs:
        for al in alphas:
            fe = next((r for r in stored if np.isclose(r["dx_m"], dx) and np.isclose(r["alpha_deg"], al)), None)
            if fe is None:
                fe = solve_scb(al, w=3 * dx, patch="block", block=(1.5 * dx, 2.5 * dx))
            t0 = time.perf_counter()
            sc = SCBScene(al, dx=dx)
            st, P = sc.elastic()
            k = sc.stress_intensity(st, P, method="williams", n_terms=10)
            rows.append({"dx mm": dx * 1e3, "alpha": al, "particles": sc.system.n,
                         "Y_I": k["Y_I"], "Y_I FE": fe["Y_I"], "Y_II": k["Y_II"], "Y_II FE": fe["Y_II"],
                         "Y_I err %": 100 * (k["Y_I"] / fe["Y_I"] - 1) if abs(fe["Y_I"]) > 0.1 else None,
                         "Y_II err %": 100 * (k["Y_II"] / fe["Y_II"] - 1) if abs(fe["Y_II"]) > 0.1 else None,
                         "wall s": time.perf_counter() - t0,
                         "peak GB so far": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6})
            show(rows[-1:])

    def worst(dx, key):
        v = [abs(r[key]) for r in rows if np.isclose(r["dx mm"], dx * 1e3) and r[key] is not None]
        return float(max(v)) if v else None

    out = {"dx_m": dxs, "alpha_deg": alphas,
           "Y_I_err_pct_max_by_dx": [worst(dx, "Y_I err %") for dx in dxs],
           "Y_II_err_pct_max_by_dx": [worst(dx, "Y_II err %") for dx in dxs],
           "finest_dx_m": min(dxs), "rows": rows}
    fin = [worst(min(dxs), k) for k in ("Y_I err %", "Y_II err %")]
    out["pass"] = bool(all(v is None or v < 5 for v in fin))
    return out
