"""Tridynamic beams and plates (seed 004 ch. 2-4) against beam and plate theory.

``tridyn-dispersion``: the models' force routines applied to plane waves against
(i) the text's own analytic dispersion coefficients 3.42-3.51, evaluated here directly
from the printed formulas, (ii) the classical Timoshenko branches C.16-C.17 and the bar,
(iii) the peridynamic bar's lattice sum and ``(4E/delta^2) Cin(k delta)``, 3.55, (iv) the
EB beam with rotary inertia (mass matrix) against the Rayleigh beam. ``bench-tridyn`` times
by the wall clock as issue 18 stated it (the process CPU time beside it).
"""
from __future__ import annotations

import os
import time

import numpy as np

from validation.registry import case, show


# =========================================================================== 3.42-3.51
def text_coefficients(offsets, dx, V, k, edge_factor=1.0, self_pairs=True):
    """A1, B1, B2, C2, C3, C4 of eq. 3.51 for a centre at x = 0 with neighbours at
    ``offsets * dx`` (ordered double sums over j, k; j = k included if ``self_pairs``; the
    j-k edge terms of P and Q times ``edge_factor``), from 3.42-3.48 as printed."""
    xs = np.asarray(offsets, float) * dx
    A1 = B1 = B2 = C2 = C3 = C4 = 0j
    e = edge_factor
    for xj in xs:
        for xk in xs:
            if xj == xk and not self_pairs:
                continue
            Lj, Lk = np.exp(1j * k * xj), np.exp(1j * k * xk)
            xij, xik, xjk = abs(xj), abs(xk), abs(xk - xj)
            ijk = 1.0 / xjk if xjk > 0 else 0.0
            nij, nik, njk = np.sign(xj), np.sign(xk), np.sign(xk - xj)
            T_ijk = (Lj - 1) / xij + (Lk - 1) / xik
            T_jki = (Lk - Lj) * ijk + (1 - Lj) / xij
            T_kij = (1 - Lk) / xik + (Lj - Lk) * ijk
            P_ijk, P_jki, P_kij = T_ijk, e * (Lk - Lj) * ijk + (1 - Lj) / xij, \
                (1 - Lk) / xik + e * (Lj - Lk) * ijk
            Q_ijk = -nij / 2 * (1 + Lj) - nik / 2 * (1 + Lk)
            Q_jki = -e * njk / 2 * (Lj + Lk) + nij / 2 * (1 + Lj)      # n_ji = -n_ij
            Q_kij = nik / 2 * (1 + Lk) + e * njk / 2 * (Lj + Lk)       # n_ki, n_kj
            w = V * V

            def row(X, Y, Z):
                return ((1 / xij + 1 / xik) * X - Y / xij - Z / xik) * w / 3

            def rown(X, Y, Z):
                return ((nij + nik) * X - nij * Y - nik * Z) * w / 6

            A1 += row(T_ijk, T_jki, T_kij)
            C4 += row(T_ijk, T_jki, T_kij)  # J has the form of T (3.45)
            B1 += row(P_ijk, P_jki, P_kij)
            B2 += row(Q_ijk, Q_jki, Q_kij)
            C2 += rown(P_ijk, P_jki, P_kij)
            C3 += rown(Q_ijk, Q_jki, Q_kij)
    return A1, B1, B2, C2, C3, C4


def _coeff_check(ratios, nks, edge_factors=(1.0, 2.0)):
    """Max relative difference between the force routine's D(k) and the printed
    coefficients (force density per amplitude: D = -K x coefficient x V)."""
    from upscale.experiments.scenes.tridyn import beam_dispersion

    worst, rows = 0.0, []
    for ef in edge_factors:
        for m in ratios:
            dx_over_h = 0.01
            h = 1e-7
            dx = dx_over_h * h
            kh = np.linspace(0.0, np.pi / dx_over_h, nks + 1)[1:] * (1 - 1e-9)  # to the BZ edge
            r = beam_dispersion(theory="timoshenko", variant="text", ratio=m, kh=kh,
                                dx_over_h=dx_over_h, edge_factor=ef)
            Ke, Kp, Ks = (r["model"][k] for k in ("K_eps", "K_phi", "K_psi"))
            V = h * h * dx
            offs = [o for o in range(-m, m + 1) if o != 0]
            err = 0.0
            for kk, D in zip(kh / h, r["D"]):
                A1, B1, B2, C2, C3, C4 = text_coefficients(offs, dx, V, kk, ef)
                ref = -V * np.array([[Ke * A1, 0, 0], [0, Ks * B1, Ks * B2],
                                     [0, Ks * C2, Ks * C3 + Kp * C4]])
                scale = np.abs(ref).max(axis=1, keepdims=True)
                err = max(err, float(np.max(np.abs(D - ref) / scale)))
            rows.append({"edge_factor": ef, "delta/dx": m, "wavenumbers": nks,
                         "max rel. diff (row-scaled)": err})
            worst = max(worst, err)
    return worst, rows


@case("tridyn-dispersion", "tridynamic beam dispersion from the force routines vs the text's "
      "coefficients 3.42-3.51, Timoshenko C.16-C.17 and the PD bar (lattice sum, Cin, 3.55)",
      )
def run_dispersion(args):
    from upscale.experiments.scenes.tridyn import beam_dispersion, pd_bar_dispersion

    quick = getattr(args, "quick", False)
    ratios = (1, 2) if quick else (1, 2, 3, 4)
    # (i) the text's own coefficients
    coeff_err, crow = _coeff_check(ratios, 8 if quick else 24)
    show(crow, "force routine vs printed coefficients 3.42-3.51 (text variant)")
    # (ii) consistent Timoshenko vs C.16-C.17, dx/h = 0.01
    kh = np.array([0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0])
    trow, tim_err = [], {}
    for m in ratios:
        r = beam_dispersion(theory="timoshenko", variant="consistent", ratio=m, kh=kh,
                            shear_integration="ends")
        ef = np.abs(r["flexural"] / r["flexural_ref"] - 1)
        es = np.abs(r["shear"] / r["shear_ref"] - 1)
        ea = np.abs(r["axial"] / r["axial_ref"] - 1)
        tim_err[m] = (float(max(ef.max(), es.max())), float(ea[0]))
        trow.append({"delta/dx": m, "flexural max": float(ef.max()), "thickness-shear max": float(es.max()),
                     "axial at kh=0.01": float(ea[0])})
    show(trow, "consistent Timoshenko beam vs C.16-C.17 (k h in [0.01, 1], dx/h = 0.01)")
    # text variant, delta/dx = 1, without (x1) and with (x2) the appendix factor
    tf, trow2 = {}, []
    for ef in (1.0, 2.0):
        row = _long_wave(beam_dispersion(theory="timoshenko", variant="text", ratio=1,
                                         kh=np.array([1e-3, 1e-4]), edge_factor=ef))
        trow2.append({"edge_factor": ef, **row})
        tf[ef] = (row["shear cutoff ratio"], row["flexural ratio kh=1e-3"])
    show(trow2, "text-faithful beam, delta/dx = 1: model / Timoshenko (cutoff: k -> 0 limit of "
         "the phi-phi entry, k_s G A/(rho I))")
    # (iii) PD bar
    brow, lat = [], 0.0
    kd = np.array([0.1, 0.2, 0.5, 1.0, 2.0, 3.0])
    conv = []
    for ratio in ((2, 4, 8, 16) if quick else (2, 4, 8, 16, 32, 64)):
        r = pd_bar_dispersion(ratio=ratio, kdelta=kd)
        e_lat = float(np.max(np.abs(r["omega2"] / r["lattice"] - 1)))
        e_cont = float(np.max(np.abs(r["omega2"] / r["continuum"] - 1)))
        lat = max(lat, e_lat)
        conv.append((ratio, e_cont))
        brow.append({"delta/dx": ratio, "vs lattice sum": e_lat, "vs 4E Cin/(rho delta^2)": e_cont})
    p = np.polyfit(np.log([c[0] for c in conv]), np.log([c[1] for c in conv]), 1)[0]
    r = pd_bar_dispersion(ratio=4, kdelta=np.array([0.1, 0.25, 0.5]))
    e355 = float(np.max(np.abs(r["eq_3_55"] / r["continuum"] - 1)))
    show(brow, "PD bar (PMB 1D, c = 2E/(A delta^2)) from the force routine")
    # (iv) EB with the sections' rotary inertia (mass matrix) vs the Rayleigh beam
    from upscale.experiments.scenes.tridyn import rayleigh_dispersion

    rrow, ray = [], {}
    for m in ratios:
        r = rayleigh_dispersion(ratio=m, kh=kh)
        ray[m] = r["rel_err_max"]
        for kk, e, f in zip(kh, r["rel_err"], r["eb_over_rayleigh"]):
            rrow.append({"delta/dx": m, "k h": kk, "rel. err vs Rayleigh": e,
                         "EB (no rotary) / Rayleigh": f})
    show(rrow, "EB beam with rotary inertia (mass matrix), omega^2 = D(k)/M(k) vs Rayleigh "
          "EI k^4/(rho (A + I k^2)), dx/h = 0.01")
    m1 = tim_err[1]
    out = {
        "rayleigh_rel_err_max": ray[1],
        "rayleigh_rel_err_by_ratio": {str(m): v for m, v in ray.items()},
        "coeff_rel_err_max": coeff_err,
        "timoshenko_rel_err_max": m1[0],
        "timoshenko_rel_err_by_ratio": {str(m): v[0] for m, v in tim_err.items()},
        "axial_long_wave_rel_err": m1[1],
        "pd_bar_lattice_rel_err": lat,
        "pd_bar_continuum_order": float(-p),
        "eq_3_55_rel_err_kdelta_le_0_5": e355,
        "tf_shear_cutoff_ratio_x1": tf[1.0][0], "tf_flexural_long_wave_ratio_x1": tf[1.0][1],
        "tf_shear_cutoff_ratio_x2": tf[2.0][0], "tf_flexural_long_wave_ratio_x2": tf[2.0][1],
    }
    out["pass"] = bool(coeff_err < 1e-10 and m1[0] < 1e-4 and m1[1] < 1e-6 and lat < 1e-12
                       and e355 < 1e-4 and ray[1] < 1e-4)
    return out


def _long_wave(r):
    """Long-wave ratios of a text-variant beam: the k -> 0 limit of the phi-phi entry over
    k_s G A / (rho I), the flexural branch at k h = 1e-3 and the axial one, over Timoshenko's."""
    from upscale.experiments.scenes.tridyn import STEEL

    D, M = r["D"][1], r["mass"]
    ref = STEEL["ks"] * STEEL["E"] / (2 * (1 + STEEL["nu"])) / STEEL["rho"] / (STEEL["h"] ** 2 / 12.0)
    return {"shear cutoff ratio": float((D[2, 2] / M[2]).real / ref),
            "flexural ratio kh=1e-3": float(r["flexural"][0] / r["flexural_ref"][0]),
            "axial ratio": float(r["axial"][0] / r["axial_ref"][0])}


# =========================================================================== statics
@case("tridyn-beam", "tridynamic beams under uniform load vs Euler-Bernoulli / Timoshenko "
      "closed forms; convergence order; literal calibration; stable step and NVE drift",
      )
def run_beam(args):
    from upscale.experiments.scenes.tridyn import beam_static, beam_nve

    quick = getattr(args, "quick", False)
    rows, errs = [], []
    ns = (50, 100, 200) if quick else (50, 100, 200, 400)
    orders = {}
    for sup in ("ss", "cc", "cantilever"):
        e_n = []
        for n in ns:
            r = beam_static(theory="eb", support=sup, n=n, ratio=1)
            e_n.append(abs(r["wmax_err_pct"]))
            rows.append({"support": sup, "N": n, "delta/dx": 1, "variant": "consistent",
                         "w_max (m)": r["wmax_m"], "EB (m)": r["wmax_ref_m"],
                         "err %": r["wmax_err_pct"], "residual": r["residual"]})
            if n >= 100:
                errs.append(abs(r["wmax_err_pct"]))
        orders[sup] = float(-np.polyfit(np.log(ns), np.log(e_n), 1)[0])
    show(rows, "EB beams, q = 5 N/m, L = 1 m, 0.05 x 0.001 m, E = 200 GPa (delta/dx = 1)")
    # literal vs consistent calibration against delta/L
    rows2 = []
    for var, xi in (("text", "spacing"), ("consistent", None)):
        for m in ((1, 2, 3) if quick else (1, 2, 3, 4, 6)):
            kw = {"xi": xi} if xi else {}
            r = beam_static(theory="eb", support="ss", n=100, ratio=m, variant=var, **kw)
            rows2.append({"variant": var + (f" xi={xi}" if xi else ""), "delta/dx": m,
                          "delta/L": m / 100,
                          "w_max / EB": r["wmax_m"] / r["wmax_ref_m"],
                          "(m+1)/2 x w_max/EB": (m + 1) / 2 * r["wmax_m"] / r["wmax_ref_m"]
                          if xi == "spacing" else ""})
    show(rows2, "simply supported EB beam, N = 100: literal calibration 2.19 (xi = dx) vs the "
          "long-wave one")
    # Timoshenko h/L = 0.1
    rows3, terr = [], []
    for sup in ("ss", "cantilever", "cc"):
        r = beam_static(theory="timoshenko", support=sup, n=100, ratio=1, height=0.1)
        rows3.append({"support": sup, "h/L": 0.1, "w_max (m)": r["wmax_m"],
                      "EB + shear (m)": r["wmax_ref_m"], "err %": r["wmax_err_pct"]})
        terr.append(abs(r["wmax_err_pct"]))
    show(rows3, "consistent Timoshenko beam, h/L = 0.1, N = 100, delta/dx = 1")
    # stability and NVE
    nve = []
    for th in ("eb", "timoshenko"):
        r = beam_nve(theory=th, steps=2000 if quick else 10000)
        nve.append(r)
    from upscale.experiments.scenes.tridyn import step_scan

    nve.append(beam_nve(theory="eb", rotary=True, steps=2000 if quick else 10000))
    from upscale.experiments.scenes.tridyn import rayleigh_mode

    modes = [rayleigh_mode(rotary=rot) for rot in (True, False)]
    show(modes, "simply supported EB beam (N = 100, h/L = 0.05) released in mode 4: angular frequency "
         "from velocity Verlet with the rotary mass matrix and with lumped mass")
    scan = step_scan(theory="eb") + step_scan(theory="timoshenko")
    show(scan, "velocity Verlet at 0.98 and 1.02 x the sharp critical step, random initial state")
    show([{k: v for k, v in r.items() if not isinstance(v, (list, np.ndarray))} for r in nve],
         "explicit dynamics (velocity Verlet, 0.8 x the Gershgorin estimate)")
    out = {"eb_wmax_err_pct_max": float(max(errs)), "eb_order": float(min(orders.values())),
           "eb_order_by_support": orders,
           "timoshenko_wmax_err_pct": float(max(terr)),
           "text_stiffening_ratio_by_delta_over_dx": {
               str(r["delta/dx"]): 1 / r["w_max / EB"] for r in rows2
               if r["variant"] == "text xi=spacing"},
           "nve_rel_drift_max": float(max(r["rel_drift"] for r in nve)),
           "nve_rel_drift_eb_rotary": float(nve[-1]["rel_drift"]),
           "rayleigh_mode_measured_over_discrete": modes[0]["measured_over_discrete"],
           "rayleigh_mode_discrete_over_closed_form": modes[0]["omega_discrete"] / modes[0]["omega_rayleigh"],
           "rayleigh_mode_shift_vs_lumped": modes[0]["omega_measured"] / modes[1]["omega_measured"],
           "dt_estimate_over_critical": {r["theory"] + ("+rotary" if r.get("rotary") else ""): r["estimate_over_critical"] for r in nve},
           "critical_step_confirmed": bool(all(r["blew_up"] == (r["dt_over_critical"] > 1)
                                               for r in scan))}
    out["pass"] = bool(out["eb_wmax_err_pct_max"] < 0.5 and out["timoshenko_wmax_err_pct"] < 1.0
                       and abs(out["rayleigh_mode_measured_over_discrete"] - 1) < 1e-4
                       and out["nve_rel_drift_max"] < 1e-4
                       and all(r["estimate_over_critical"] <= 1.0 for r in nve)
                       and out["critical_step_confirmed"])
    return out


# =========================================================================== bench
def _best(fns, reps):
    """Fastest of ``reps`` calls (s) of each of ``fns`` ({name: callable}) by the wall clock,
    and by the process CPU time beside it, the calls interleaved round by round so that a
    change of the machine's load hits every path alike."""
    wall = {k: np.inf for k in fns}
    cpu = dict(wall)
    for _ in range(reps):
        for k, fn in fns.items():
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            wall[k] = min(wall[k], time.perf_counter() - t0)
            cpu[k] = min(cpu[k], time.process_time() - c0)
    return wall, cpu


def _stepper(mod, st, n, nrot):
    """One force evaluation of ``mod`` (translations and, if it has them, rotations)."""
    out = np.zeros((n, 3))
    fo = {"rot": np.zeros((n, nrot))}

    def step():
        out[...] = 0.0
        mod.add_force(st, out)
        if hasattr(mod, "add_field_force"):
            fo["rot"][...] = 0.0
            mod.add_field_force(st, fo)

    return step


@case("bench-tridyn", "time per particle-step of the tridynamic beam and plate kernels vs the PMB kernel "
      "(same particles, same horizon, one run, wall time)",
      target="beam and plate time per particle-step at most 3x the PMB kernel's (wall time, one run)")
def run_bench(args):
    from upscale.engine import State, build_family, line_lattice, square_lattice
    from upscale.models.bond_based import PMB
    from upscale.models.tridynamics import TridynEB, TridynPlate, TridynTimoshenko

    quick = getattr(args, "quick", False)
    load0 = os.getloadavg()[0]
    reps = 5 if quick else 20
    rows, ratio, ratio_cpu = [], {}, {}

    def race(label, s, fam, st, models, nrot):
        steps = {}
        for name, mod in models.items():
            mod.prepare(s, fam)
            steps[name] = _stepper(mod, st, s.n, nrot)
            steps[name]()  # compile
        wall, cpu = _best(steps, reps)
        for name in models:
            if name != "pmb":
                ratio[f"{name} delta/dx={label}"] = wall[name] / wall["pmb"]
                ratio_cpu[f"{name} delta/dx={label}"] = cpu[name] / cpu["pmb"]
                rows.append({"model": name, "delta/dx": label, "particles": s.n,
                             "PMB s/particle-step": wall["pmb"] / s.n,
                             "wall / PMB": wall[name] / wall["pmb"],
                             "CPU / PMB": cpu[name] / cpu["pmb"]})

    n = 20_000 if quick else 100_000
    for m in (1, 3):   # beams: a line of particles
        s = line_lattice(n, 1e-3, area=1e-6, density=7850.0)
        fam = build_family(s, m * 1e-3 * (1 + 1e-9))
        st = State.reference(s.x0, fam.nb)
        rng = np.random.default_rng(0)
        st.y[:, 0] += 1e-9 * rng.normal(size=n)
        st.y[:, 2] += 1e-9 * rng.normal(size=n)
        st.fields["rot"] = 1e-6 * rng.normal(size=(n, 1))
        st.field_v["rot"] = np.zeros((n, 1))
        race(m, s, fam, st, {"pmb": PMB(E=200e9),
                             "eb": TridynEB(200e9, area=1e-6, second_moment=1e-13),
                             "timoshenko": TridynTimoshenko(200e9, 0.3, area=1e-6,
                                                            second_moment=1e-13)}, 1)
    side = 100 if quick else 200
    for m in (1, 2):   # plate: a square lattice, PMB in plane stress on the same particles
        s = square_lattice(side, side, 1e-3, thickness=1e-3, density=7850.0)
        fam = build_family(s, m * 1e-3 * (1 + 1e-9))
        st = State.reference(s.x0, fam.nb)
        rng = np.random.default_rng(1)
        st.y[:, :3] += 1e-9 * rng.normal(size=(s.n, 3))
        st.fields["rot"] = 1e-6 * rng.normal(size=(s.n, 2))
        st.field_v["rot"] = np.zeros((s.n, 2))
        race(m, s, fam, st, {"pmb": PMB(E=200e9),
                             "plate": TridynPlate(200e9, 0.3, thickness=1e-3)}, 2)
    show(rows)
    beam = [v for k, v in ratio.items() if not k.startswith("plate")]
    plate = [v for k, v in ratio.items() if k.startswith("plate")]
    out = {"beam_step_over_pmb": float(max(beam)), "plate_step_over_pmb": float(max(plate)),
           "step_over_pmb": ratio, "step_over_pmb_cpu": ratio_cpu,
           "load_average_start_end": [load0, os.getloadavg()[0]], "clock": "wall"}
    out["pass"] = bool(out["beam_step_over_pmb"] <= 3.0 and out["plate_step_over_pmb"] <= 3.0)
    return out


# =========================================================================== plate
@case("tridyn-plate", "tridynamic FSDT plate: printed local limit vs Mindlin 4.62, dispersion "
      "of the corrected plate along x, y, 45 deg, positivity, Navier-Mindlin square plate, NVE")
def run_plate(args):
    from upscale.experiments.scenes.tridyn import plate_bending, plate_dispersion, plate_energy_random, plate_nve
    from upscale.models.tridynamics import literal_local_coefficients

    quick = getattr(args, "quick", False)
    E, nu = 200e9, 0.3
    lit = literal_local_coefficients(E, nu)
    rows = [{"term": k, "literal (4.60, 4.63)": v[0], "Mindlin 4.62": v[1], "ratio": v[0] / v[1]}
            for k, v in lit.items()]
    show(rows, "printed local limit with the printed constants vs Mindlin (E = 200 GPa, nu = 0.3, "
          "I/A = 1)")
    drow, derr = [], {}
    for m in ((1,) if quick else (1, 2)):
        r = plate_dispersion(ratio=m)
        derr[m] = r["rel_err_max"]
        for ang, e in r["rel_err"].items():
            drow.append({"delta/dx": m, "angle (deg)": ang,
                         **{f"{nm}": float(e[:, b].max()) for b, nm in
                            enumerate(("flexural", "SH", "P", "twist-shear", "thickness-shear"))}})
    show(drow, "corrected plate vs Mindlin, max relative error of omega^2 for k dx <= 0.05 "
          "(h = 10 dx)")
    en = plate_energy_random(samples=50 if quick else 200)
    prow, perr = [], None
    for n in ((20, 40) if quick else (20, 40, 60)):
        r = plate_bending(n=n)
        prow.append({"n": n, "h/a": r["h_over_a"], "w_centre (m)": r["w_centre_m"],
                     "Navier+Mindlin (m)": r["navier_mindlin_m"],
                     "Navier Kirchhoff (m)": r["navier_kirchhoff_m"], "err %": r["err_pct"],
                     "residual": r["residual"]})
        perr = r["err_pct"]
    show(prow, "simply supported square plate, uniform load (a = 1 m, h = 0.1 m), delta/dx = 1")
    nve = plate_nve(steps=2000 if quick else 10_000)
    show([nve], "explicit dynamics, plate (20 x 20, velocity Verlet at 0.8 x the estimate)")
    out = {"mindlin_rel_err_max": float(derr[1]),
           "mindlin_rel_err_by_ratio": {str(k): v for k, v in derr.items()},
           "navier_err_pct": float(perr),
           "min_energy_random": en["min_energy_J"], "negative_eigenvalues": en["negative_eigs"],
           "literal_v_xx_over_mindlin": float(lit["v: v,xx"][0] / lit["v: v,xx"][1]),
           "nve_rel_drift": nve["rel_drift"],
           "dt_estimate_over_critical": nve["estimate_over_critical"]}
    out["pass"] = bool(out["mindlin_rel_err_max"] < 1e-3 and abs(perr) < 1.0
                       and en["min_energy_J"] > 0 and en["negative_eigs"] == 0
                       and nve["rel_drift"] < 1e-4 and nve["estimate_over_critical"] <= 1)
    return out
