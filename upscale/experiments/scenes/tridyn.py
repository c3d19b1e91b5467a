"""Tridynamic beam scenes (seed 004 ch. 2-3): static beams under uniform load against
Euler-Bernoulli and Timoshenko, and dispersion from the models' force routines against
the classical branches and the peridynamic bar.

References (closed forms, none produced by the models): EB deflections under uniform load
(simply supported ``5 q L^4/(384 EI)``, clamped-clamped ``q L^4/(384 EI)``, cantilever tip
``q L^4/(8 EI)``) plus the Timoshenko shear term ``q L^2/(8 k G A)`` (ss, mid-span) or
``q L^2/(2 k G A)`` (cantilever tip); the Timoshenko dispersion relation (C.16-C.17)
``(k_s G k^2 - rho w^2)(EI k^2/A + k_s G - rho I w^2/A) = (k_s G k)^2`` solved with the
flexural root in the cancellation-free form ``X_- = 2 c/(B + sqrt(B^2 - 4 a c))``; the
peridynamic bar ``rho w^2 = (4E/delta^2) Cin(k delta)`` and its truncation 3.55.

The scenes ``upscale beam``, ``upscale plate-bending`` and ``upscale dispersion`` are
:mod:`upscale.experiments.scenes.tridyn_scenes` (functions returning a ``Result``); the
``plot_*`` functions here draw the seed's figures from the dicts of this module.

The EB beam with the rotary inertia of its sections (Rayleigh beam, mass matrix of
:mod:`upscale.engine.mass`) is compared with ``omega^2 = EI k^4/(rho (A + I k^2))``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from upscale.analysis.plots import save_figure

__all__ = ["beam_static", "timoshenko_branches", "beam_dispersion", "pd_bar_dispersion",
           "cin", "SUPPORT_PAIRS", "plate_long_wave", "rayleigh_branch",
           "rayleigh_dispersion", "rayleigh_mode"]

SUPPORT_PAIRS = {"ss": ("ss", "ss"), "cc": ("cc", "cc"), "cantilever": ("cc", "free")}

# seed 004 eq. 3.58 (spacing not given in the text: dx = 0.01 h here)
STEEL = dict(E=200e9, rho=7850.0, ks=5.0 / 6.0, h=1e-7, nu=0.3)


def cin(x):
    """Cin(x) = int_0^x (1 - cos t)/t dt, by quadrature of ``2 sin^2(t/2)/t`` (no
    cancellation at small x)."""
    from scipy.integrate import quad

    x = np.atleast_1d(np.asarray(x, dtype=float))
    out = np.array([quad(lambda t: 2.0 * np.sin(0.5 * t) ** 2 / t if t > 0 else 0.0, 0.0, v,
                         epsabs=0, epsrel=1e-13, limit=200)[0] for v in x])
    return out


def timoshenko_branches(k, *, E, G, ks, A, I, rho):
    """Flexural and thickness-shear ``omega^2`` (rad^2/s^2) of the Timoshenko beam
    (C.16-C.17) for wavenumbers k (1/m)."""
    k = np.asarray(k, dtype=float)
    r = I / A
    s = ks * G * k ** 2
    e = E * I * k ** 2 / A
    g = ks * G
    B = s * r + e + g
    disc = np.sqrt(B * B - 4 * r * s * e)
    return 2 * s * e / (B + disc) / rho, (B + disc) / (2 * r) / rho


# =========================================================================== statics
def beam_static(*, theory="eb", support="ss", n=100, ratio=1.0, variant="consistent",
                length=1.0, load=5.0, E=200e9, nu=0.3, width=0.05, height=0.001,
                density=8050.0, shear_factor=5.0 / 6.0, **model_kw) -> dict:
    """Static deflection of a beam under uniform load q (N/m) by a sparse LU solve of the
    model's operator (:func:`upscale.engine.fields.solve_static`).

    Default section and load: seed 004 sec. 2.4.1 read as a 0.05 x 0.001 m section, 5 N/m,
    steel E = 200 GPa (Table 2.1's area 5e-8 m^2, N/m^2 load unit and 200e11 Pa are read
    as misprints). Returns profiles, the maximum deflection against the closed form (EB;
    Timoshenko adds the shear term), the solver's residual and the operator's asymmetry."""
    from upscale.engine import fields
    from upscale.engine.simulation import Simulation
    from upscale.models.tridynamics import beam, beam_reference

    if support not in SUPPORT_PAIRS:
        raise ValueError(f"unknown support {support!r}; valid: {', '.join(SUPPORT_PAIRS)}")
    sup = SUPPORT_PAIRS[support]
    system, family, model, conds, body = beam(
        length=length, n=n, horizon_ratio=ratio, theory=theory, supports=sup, E=E, nu=nu,
        width=width, height=height, density=density, shear_factor=shear_factor,
        variant=variant, load=load, **model_kw)
    sim = Simulation(system, family, model, conds)
    rep = fields.solve_static(sim)
    x = system.x0[body, 0]
    w = sim.state.y[body, 2] - system.x0[body, 2]
    EI = E * width * height ** 3 / 12.0
    kGA = shear_factor * E / (2 * (1 + nu)) * width * height if theory == "timoshenko" else None
    ref = beam_reference(x, length, load, EI, sup, kGA=kGA)
    i = int(np.argmax(np.abs(ref)))
    return {"theory": theory, "support": support, "variant": variant, "n": int(n),
            "delta_over_dx": float(ratio), "x_m": x, "w_m": w, "w_ref_m": ref,
            "wmax_m": float(w[i]), "wmax_ref_m": float(ref[i]),
            "wmax_err_pct": float(100 * (w[i] / ref[i] - 1)), "residual": rep["residual"],
            "asymmetry": rep["asymmetry"], "model": model.describe(), "_sim": sim}


# =========================================================================== dispersion
def _chain(n_each_side, dx, area, density):
    from upscale.engine.system import ParticleSystem

    x = np.arange(-n_each_side, n_each_side + 1) * dx
    return ParticleSystem(x[:, None], area * dx, density, dim=1, spacing=dx)


def beam_dispersion(*, theory="timoshenko", variant="consistent", ratio=1, kh=None,
                    dx_over_h=0.01, E=STEEL["E"], nu=STEEL["nu"], rho=STEEL["rho"],
                    ks=STEEL["ks"], h=STEEL["h"], **model_kw) -> dict:
    """Branches of a tridynamic beam (square section h x h) from its force routine, beside
    the classical ones, wavenumbers ``kh`` (k times the depth h)."""
    from upscale.engine.dispersion import dispersion
    from upscale.engine.families import build_family
    from upscale.engine.simulation import Simulation
    from upscale.models.tridynamics import TridynEB, TridynTimoshenko

    kh = np.array([0.01, 0.05, 0.1, 0.5, 1.0]) if kh is None else np.asarray(kh, float)
    dx = dx_over_h * h
    A, I = h * h, h ** 4 / 12.0
    G = E / (2 * (1 + nu))
    m = int(np.ceil(ratio))
    system = _chain(2 * m + 4, dx, A, rho)
    family = build_family(system, ratio * dx * (1 + 1e-9))
    if theory == "timoshenko":
        model = TridynTimoshenko(E, nu, area=A, second_moment=I, shear_factor=ks,
                                 variant=variant, **model_kw)
    else:
        model = TridynEB(E, area=A, second_moment=I, variant=variant, **model_kw)
    sim = Simulation(system, family, model, [])
    k = kh / h
    d = dispersion(sim, k)
    out = {"theory": theory, "variant": variant, "delta_over_dx": float(ratio),
           "dx_over_h": dx_over_h, "kh": kh, "model": model.describe(), "D": d["D"],
           "mass": d["mass"], "dofs": d["dofs"]}
    if theory == "timoshenko":
        D, M = d["D"], d["mass"]
        out["axial"] = (D[:, 0, 0] / M[0]).real
        fl, sh = [], []
        for Dk in D:
            ev = np.sort(np.linalg.eigvals(Dk[1:, 1:] / M[1:, None]).real)
            fl.append(ev[0])
            sh.append(ev[1])
        out["flexural"], out["shear"] = np.array(fl), np.array(sh)
        out["axial_ref"] = E / rho * k ** 2
        out["flexural_ref"], out["shear_ref"] = timoshenko_branches(
            k, E=E, G=G, ks=ks, A=A, I=I, rho=rho)
    else:
        out["flexural"] = (d["omega2"][:, 0]).real
        out["flexural_ref"] = E * I / (rho * A) * k ** 4
    return out


def pd_bar_dispersion(*, ratio=3.0, kdelta=None, E=STEEL["E"], rho=STEEL["rho"],
                      delta=1e-8, area=1e-14) -> dict:
    """The project's bond-based bar (PMB, 1D, ``c = 2E/(A delta^2)``) from its force
    routine, against its lattice sum ``rho w^2 = sum_j c V_j (1 - cos k xi_j)/|xi_j|``, the
    continuum relation ``(4E/delta^2) Cin(k delta)`` and 3.55."""
    from upscale.engine.dispersion import dispersion
    from upscale.engine.families import build_family
    from upscale.engine.simulation import Simulation
    from upscale.models.bond_based import PMB

    kd = np.array([0.1, 0.5, 1.0, 2.0, 3.0]) if kdelta is None else np.asarray(kdelta, float)
    dx = delta / ratio
    m = int(np.ceil(ratio))
    system = _chain(2 * m + 4, dx, area, rho)
    family = build_family(system, delta * (1 + 1e-9))
    model = PMB(E=E)
    sim = Simulation(system, family, model, [])
    k = kd / delta
    d = dispersion(sim, k, amplitude=0.2 * dx, dofs=[("y", 0)])
    w2 = d["omega2"][:, 0].real
    c = model.c
    xi = np.arange(1, m + 1) * dx
    xi = xi[xi <= delta * (1 + 1e-9)]
    lattice = np.array([2 * np.sum(c * area * dx * (1 - np.cos(kk * xi)) / xi) for kk in k]) / rho
    cont = 4 * E / delta ** 2 * cin(kd) / rho
    trunc = E / rho * k ** 2 * (1 - kd ** 2 / 24)
    return {"delta_over_dx": float(ratio), "kdelta": kd, "omega2": w2, "lattice": lattice,
            "continuum": cont, "eq_3_55": trunc, "c": c}


# =========================================================================== plots
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_beams(results: list, path) -> Path:
    """Deflection profiles for several horizons against the closed form (Figs. 2.3-2.5)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    r0 = results[0]
    ax.plot(r0["x_m"], r0["w_ref_m"] * 1e3, "k-", lw=2, label="closed form")
    for r in results:
        ax.plot(r["x_m"], r["w_m"] * 1e3, "--", label=f"{r['variant']} delta/dx={r['delta_over_dx']:g} "
                f"({r['wmax_err_pct']:+.2f} %)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("w (mm)")
    ax.set_title(f"{r0['theory']} beam, {r0['support']}, N={r0['n']}")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def plot_dispersion(results: list, path, h=STEEL["h"]) -> Path:
    """Frequency and phase speed against k h in the normalisation of Figs. 3.3-3.8:
    ``Omega = omega h / v_s`` with ``v_s = sqrt(G/rho)``; phase speed ``Omega/(k h sqrt(k_s))``."""
    plt = _plt()
    G = STEEL["E"] / (2 * (1 + STEEL["nu"]))
    vs = np.sqrt(G / STEEL["rho"])
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for r in results:
        kh = r["kh"]
        for br, st in (("axial", "-"), ("flexural", "--"), ("shear", ":")):
            if br not in r:
                continue
            Om = np.sqrt(np.abs(r[br])) * h / vs
            lab = f"{r['variant']} d/dx={r['delta_over_dx']:g} {br}"
            if r is not results[0] and br == "axial":
                continue
            axes[0].plot(kh, Om, st, label=lab)
            axes[1].plot(kh, Om / (kh * np.sqrt(STEEL["ks"])), st, label=lab)
    r = results[0]
    for br in ("axial", "flexural", "shear"):
        if br + "_ref" in r:
            Om = np.sqrt(r[br + "_ref"]) * h / vs
            axes[0].plot(r["kh"], Om, "k.", ms=4)
            axes[1].plot(r["kh"], Om / (r["kh"] * np.sqrt(STEEL["ks"])), "k.", ms=4)
    axes[0].set_xlabel("k h")
    axes[0].set_ylabel("Omega = omega h / v_s")
    axes[1].set_xlabel("k h")
    axes[1].set_ylabel("Omega / (k h sqrt(k_s))")
    axes[1].set_yscale("log")
    axes[0].set_yscale("log")
    axes[0].set_xscale("log")
    axes[1].set_xscale("log")
    axes[0].legend(fontsize=6)
    fig.suptitle("tridynamic beam branches (dots: classical Timoshenko / bar)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def plot_plate(results: list, path) -> Path:
    """Mid-line deflection of the simply supported plate against Navier + Mindlin."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    r0 = results[0]
    ax.plot(r0["x_m"], r0["w_ref_m"] * 1e6, "k-", lw=2, label="Navier + Mindlin shear")
    for r in results:
        ax.plot(r["x_m"], r["w_m"] * 1e6, "--", label=f"tridynamic n={r['n']} delta/dx="
                f"{r['delta_over_dx']:g} (centre {r['err_pct']:+.3f} %)")
    ax.set_xlabel("x (m), y = a/2")
    ax.set_ylabel("w (um)")
    ax.set_title(f"simply supported square plate, h/a = {r0['h_over_a']:g}, uniform load")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def plot_plate_dispersion(r: dict, path) -> Path:
    """Relative error of the plate's five branches against Mindlin, per direction."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    names = ("flexural", "SH", "P", "twist-shear", "thickness-shear")
    for ang, e in r["rel_err"].items():
        for b, nm in enumerate(names):
            ax.loglog(r["kdx"], np.maximum(e[:, b], 1e-16), marker="o", ms=3,
                      label=f"{nm} {ang:g} deg")
    ax.set_xlabel("k dx")
    ax.set_ylabel("|omega^2 / Mindlin - 1|")
    ax.set_title(f"tridynamic plate, delta/dx = {r['delta_over_dx']:g}, h = {r['h_over_dx']:g} dx")
    ax.legend(fontsize=6, ncol=3)
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


# =========================================================================== dynamics
def beam_nve(*, theory="eb", n=100, ratio=1.0, length=1.0, height=0.01, width=0.01,
             E=200e9, nu=0.3, density=7850.0, steps=10_000, safety=0.8, rotary=False,
             **model_kw) -> dict:
    """Free vibration of a beam held by clamped walls (zero displacements and rotations
    on a layer one influence radius deep beyond each end), released from a smooth bump
    ``w = w0 sin^4(pi x/L)`` (w to w''' vanish at the walls; phi = w' for Timoshenko):
    relative drift of the total energy (translational and rotary
    kinetic plus the model's energy) over ``steps`` velocity-Verlet steps at ``safety`` x the
    engine's stable estimate, and that estimate against the sharp limit
    :func:`upscale.engine.fields.critical_dt`. ``rotary`` (EB): the sections' rotary inertia
    as a mass matrix (:class:`upscale.engine.mass.MassMatrixVerlet`, Rayleigh beam); the
    kinetic energy then includes its coupling part."""
    from upscale.engine import conditions as cnd
    from upscale.engine import fields
    from upscale.engine.families import build_family
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import ParticleSystem
    from upscale.models.tridynamics import TridynEB, TridynTimoshenko

    dx = length / n
    ng = int(np.ceil(2 * ratio)) + 1
    idx = np.arange(-ng, n + 1 + ng)
    x = idx * dx
    A, I = width * height, width * height ** 3 / 12.0
    system = ParticleSystem(x[:, None], A * dx, density, dim=1, spacing=dx)
    family = build_family(system, ratio * dx * (1 + 1e-9))
    if theory == "eb":
        model = TridynEB(E, area=A, second_moment=I, **model_kw)
    else:
        model = TridynTimoshenko(E, nu, area=A, second_moment=I, **model_kw)
    wall = cnd.Region("walls", (idx <= 0) | (idx >= n))
    conds = [cnd.Fixed(wall)]
    if theory == "timoshenko":
        conds.append(fields.FixedField(wall, "rot", (0,)))
    sim = Simulation(system, family, model, conds, integrator=VelocityVerlet(safety=safety))
    w0 = 1e-3 * height
    inside = (idx > 0) & (idx < n)
    s_ = np.sin(np.pi * x[inside] / length)
    c_ = np.cos(np.pi * x[inside] / length)
    sim.state.y[inside, 2] += w0 * s_ ** 4
    if theory == "timoshenko":
        sim.state.fields["rot"][inside, 0] = 4 * w0 * np.pi / length * s_ ** 3 * c_
    crit = fields.critical_dt(sim)
    if rotary:
        if theory != "eb":
            raise ValueError(f"rotary mass matrix is for theory 'eb', got {theory!r}")
        from upscale.engine.mass import ConsistentMass, MassMatrixVerlet

        sim.integrator = MassMatrixVerlet(ConsistentMass(model.rotary_mass(mask=inside)),
                                          safety=safety)
    sim.prepare()
    est = sim.integrator.estimate

    def total():
        return sim.kinetic_energy() + sim.energy()

    E0 = total()
    hist = [E0]
    every = max(steps // 200, 1)
    for _ in range(steps // every):
        sim.run(every)
        hist.append(total())
    hist = np.array(hist)
    return {"theory": theory + "".join(f" {k}={v}" for k, v in model_kw.items()),
            "rotary": bool(rotary), "steps": int(sim.state.step), "dt_s": sim.integrator.dt,
            "estimate_s": est, "critical_s": crit, "estimate_over_critical": est / crit,
            "rel_drift": float(np.max(np.abs(hist - E0)) / E0),
            "final_rel_change": float((hist[-1] - E0) / E0)}


# =========================================================================== plate
def mindlin_branches(k, *, E, nu, h, rho, ks=5.0 / 6.0):
    """The five Mindlin plate branches ``omega^2`` (4.62) for wavenumbers k, ascending at
    long waves: flexural, SH (mu k^2/rho), P (E k^2/((1 - nu^2) rho)), twist-shear
    ``(mu r k^2 + k_s mu)/(rho r)`` and thickness-shear, r = h^2/12."""
    k = np.asarray(k, float)
    mu = E / (2 * (1 + nu))
    C = E / (1 - nu ** 2)
    r = h * h / 12.0
    flex, ts = timoshenko_branches(k, E=C, G=mu, ks=ks, A=1.0, I=r, rho=rho)
    return np.stack([flex, mu * k ** 2 / rho, C * k ** 2 / rho,
                     (mu * r * k ** 2 + ks * mu) / (rho * r), ts], axis=-1)


def plate_dispersion(*, ratio=1, kdx=None, angles_deg=(0.0, 90.0, 45.0), h_over_dx=10.0,
                     E=200e9, nu=0.3, rho=7850.0, ks=5.0 / 6.0, dx=1e-3) -> dict:
    """Branches of the tridynamic plate from its force routine along several directions,
    beside Mindlin's (:func:`mindlin_branches`), wavenumbers ``kdx`` (k times the
    spacing)."""
    from upscale.engine.dispersion import dynamical_matrix
    from upscale.engine.families import build_family
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import square_lattice
    from upscale.models.tridynamics import TridynPlate

    kdx = np.array([0.005, 0.01, 0.02, 0.05]) if kdx is None else np.asarray(kdx, float)
    h = h_over_dx * dx
    m = int(np.ceil(ratio))
    nside = 2 * (2 * m + 3) + 1
    system = square_lattice(nside, nside, dx, thickness=h, density=rho, centered=True)
    family = build_family(system, ratio * dx * (1 + 1e-9))
    model = TridynPlate(E, nu, thickness=h, shear_factor=ks)
    sim = Simulation(system, family, model, [])
    ref = mindlin_branches(kdx / dx, E=E, nu=nu, h=h, rho=rho, ks=ks)
    out = {"delta_over_dx": float(ratio), "h_over_dx": h_over_dx, "kdx": kdx, "ref": ref,
           "angles_deg": list(angles_deg), "branches": {}, "rel_err": {}}
    from upscale.engine.fields import mass_vector

    c = None
    for ang in angles_deg:
        th = np.deg2rad(ang)
        w2 = []
        for kk in kdx / dx:
            kv = kk * np.array([np.cos(th), np.sin(th)])
            D = dynamical_matrix(sim, kv, c)
            if c is None:
                from upscale.engine.dispersion import centre_particle

                c = centre_particle(sim)
            M = mass_vector(sim).reshape(system.n, 5)[c]
            s = 1 / np.sqrt(M)
            H = s[:, None] * D * s[None, :]
            w2.append(np.linalg.eigvalsh(0.5 * (H + H.conj().T)))
        w2 = np.array(w2)
        out["branches"][ang] = w2
        out["rel_err"][ang] = np.abs(w2 / ref - 1)
    out["rel_err_max"] = float(max(v.max() for v in out["rel_err"].values()))
    return out


def plate_bending(*, n=40, ratio=1.0, a=1.0, h=0.1, q=1e3, E=200e9, nu=0.3,
                  density=7850.0, ks=5.0 / 6.0) -> dict:
    """Simply supported square plate under uniform load q (N/m^2), sparse LU solve of the
    tridynamic plate, centre deflection against the Navier series with the Mindlin shear
    term (:func:`upscale.models.tridynamics.navier_mindlin`)."""
    from upscale.engine import fields
    from upscale.engine.simulation import Simulation
    from upscale.models.tridynamics import navier_mindlin, plate

    system, family, model, conds, body = plate(a=a, n=n, thickness=h, horizon_ratio=ratio,
                                                E=E, nu=nu, density=density,
                                                shear_factor=ks, load=q)
    sim = Simulation(system, family, model, conds)
    rep = fields.solve_static(sim)
    x = system.x0
    w = sim.state.y[:, 2] - x[:, 2]
    c = int(np.argmin(np.sum((x[:, :2] - 0.5 * a) ** 2, axis=1)))
    wm, wk = navier_mindlin(0.5 * a, 0.5 * a, a, q, E, nu, h, ks)
    mid = body & (np.abs(x[:, 1] - 0.5 * a) < 1e-9 * a)
    xs = x[mid, 0]
    order = np.argsort(xs)
    prof_ref = navier_mindlin(xs[order], np.full(order.size, 0.5 * a), a, q, E, nu, h, ks)[0]
    return {"n": int(n), "delta_over_dx": float(ratio), "h_over_a": h / a,
            "w_centre_m": float(w[c]), "navier_mindlin_m": float(wm[0]),
            "navier_kirchhoff_m": float(wk[0]), "err_pct": float(100 * (w[c] / wm[0] - 1)),
            "residual": rep["residual"], "asymmetry": rep["asymmetry"],
            "x_m": xs[order], "w_m": w[mid][order], "w_ref_m": prof_ref, "_sim": sim}


def plate_energy_random(*, n=12, ratio=2.0, samples=200, seed=0, h=0.1) -> dict:
    """Energy of random fields (all five degrees of freedom, free plate) over their squared
    norm in the natural scaling (translations / dx, rotations): min, max, and the smallest
    non-zero eigenvalue of the assembled stiffness (rigid modes excluded)."""
    from upscale.engine import fields
    from upscale.engine.simulation import Simulation
    from upscale.models.tridynamics import plate

    system, family, model, conds, body = plate(a=1.0, n=n, thickness=h, horizon_ratio=ratio,
                                                support="free")
    sim = Simulation(system, family, model, [])
    rng = np.random.default_rng(seed)
    st = sim.state
    es = []
    for _ in range(samples):
        st.y[...] = system.x0
        st.y[:, :3] += 1e-6 * rng.normal(size=(system.n, 3))
        st.fields["rot"][...] = 1e-6 * rng.normal(size=(system.n, 2)) / system.spacing
        es.append(sim.energy())
    st.y[...] = system.x0
    st.fields["rot"][...] = 0.0
    K = fields.operator(sim).toarray()
    ev = np.linalg.eigvalsh(0.5 * (K + K.T))
    return {"min_energy_J": float(min(es)), "max_energy_J": float(max(es)),
            "eig_min": float(ev[0]), "eig_max": float(ev[-1]),
            "negative_eigs": int(np.sum(ev < -1e-12 * ev[-1])),
            "zero_eigs": int(np.sum(np.abs(ev) <= 1e-10 * ev[-1])), "samples": samples}


def plate_nve(*, n=20, ratio=1.0, a=1.0, h=0.05, E=200e9, nu=0.3, density=7850.0,
              steps=10_000, safety=0.8) -> dict:
    """Free vibration of a plate held by clamped walls (a frame of fixed particles, one
    influence radius deep), released from its static deflection under a smooth load
    ``q0 sin^2(pi x/a) sin^2(pi y/a)``: relative drift of the total energy over ``steps`` velocity-Verlet
    steps at ``safety`` x the stable estimate, and the estimate against the sharp limit."""
    from upscale.engine import conditions as cnd
    from upscale.engine import fields
    from upscale.engine.families import build_family
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import ParticleSystem
    from upscale.models.tridynamics import TridynPlate

    dx = a / n
    ng = int(np.ceil(2 * ratio)) + 1
    ii = np.arange(-ng, n + 1 + ng)
    I, J = np.meshgrid(ii, ii, indexing="ij")
    I, J = I.ravel(), J.ravel()
    x = np.stack([I * dx, J * dx, np.zeros(I.size)], axis=1)
    system = ParticleSystem(x, dx * dx * h, density, dim=2, thickness=h, spacing=dx)
    family = build_family(system, ratio * dx * (1 + 1e-9))
    model = TridynPlate(E, nu, thickness=h)
    inside = (I > 0) & (I < n) & (J > 0) & (J < n)
    wall = cnd.Region("walls", ~inside)
    conds = [cnd.Fixed(wall), fields.FixedField(wall, "rot", (0, 1))]
    # initial state: the static deflection under the load q0 sin^2(pi x/a) sin^2(pi y/a)
    # (smooth and in equilibrium with itself, so mostly the lowest modes), then released
    X, Y = np.pi * x[inside, 0] / a, np.pi * x[inside, 1] / a
    val = np.zeros((inside.sum(), 3))
    val[:, 2] = 1e3 * np.sin(X) ** 2 * np.sin(Y) ** 2
    loaded = Simulation(system, family, model,
                        conds + [cnd.BodyForce(cnd.Region("inside", inside), val)])
    fields.solve_static(loaded)
    sim = Simulation(system, family, model, conds, integrator=VelocityVerlet(safety=safety),
                     state=loaded.state.copy())
    crit = fields.critical_dt(sim)
    sim.prepare()
    est = sim.integrator.estimate

    def total():
        return sim.kinetic_energy() + sim.energy()

    E0 = total()
    hist = [E0]
    every = max(steps // 100, 1)
    for _ in range(steps // every):
        sim.run(every)
        hist.append(total())
    hist = np.array(hist)
    return {"theory": "plate", "steps": int(sim.state.step), "dt_s": sim.integrator.dt,
            "estimate_s": est, "critical_s": crit, "estimate_over_critical": est / crit,
            "rel_drift": float(np.max(np.abs(hist - E0)) / E0),
            "final_rel_change": float((hist[-1] - E0) / E0)}


def step_scan(*, theory="eb", factors=(0.98, 1.02), n=60, steps=400, seed=0) -> list:
    """Velocity Verlet at ``factor`` x the sharp critical step (:func:`critical_dt`, forced
    past the engine's estimate where needed) from a random initial state (all modes
    excited): the largest relative change of the total energy; above 1 the highest mode
    grows without bound, below it stays bounded."""
    from upscale.engine import conditions as cnd
    from upscale.engine import fields
    from upscale.engine.families import build_family
    from upscale.engine.integrators import BlowUp, VelocityVerlet
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import ParticleSystem
    from upscale.models.tridynamics import TridynEB, TridynTimoshenko

    dx = 1.0 / n
    idx = np.arange(-3, n + 4)
    x = idx * dx
    A, I = 1e-4, 1e-4 * 1e-4 / 12
    system = ParticleSystem(x[:, None], A * dx, 7850.0, dim=1, spacing=dx)
    family = build_family(system, dx * (1 + 1e-9))
    model = TridynEB(200e9, area=A, second_moment=I) if theory == "eb" else \
        TridynTimoshenko(200e9, 0.3, area=A, second_moment=I)
    wall = cnd.Region("walls", (idx <= 0) | (idx >= n))
    conds = [cnd.Fixed(wall)]
    if theory == "timoshenko":
        conds.append(fields.FixedField(wall, "rot", (0,)))
    out = []
    for f in factors:
        probe = Simulation(system, family, model, conds)
        crit = fields.critical_dt(probe)
        sim = Simulation(system, family, model, conds,
                         integrator=VelocityVerlet(dt=f * crit, force=True))
        rng = np.random.default_rng(seed)
        inside = ~wall.mask
        sim.state.y[inside, 2] += 1e-9 * rng.normal(size=inside.sum())
        if theory == "timoshenko":
            sim.state.fields["rot"][inside, 0] = 1e-7 * rng.normal(size=inside.sum())
        sim.prepare()
        E0 = fields.kinetic_energy(sim) + sim.energy()
        worst, blew = 0.0, False
        try:
            for _ in range(steps // 20):
                sim.run(20)
                worst = max(worst, abs((fields.kinetic_energy(sim) + sim.energy()) / E0 - 1))
                if worst > 1e6:
                    break
        except BlowUp:
            blew, worst = True, float("inf")
        out.append({"theory": theory, "dt_over_critical": f, "critical_s": crit,
                    "estimate_s": sim.integrator.estimate, "max_rel_energy_change": worst,
                    "blew_up": blew or worst > 1e3})
    return out


def plate_long_wave(*, variant="text", text_triplets="lines", ratio=1, kdx=1e-3, h_over_dx=10.0,
                    E=200e9, nu=0.3, rho=7850.0, ks=5.0 / 6.0, dx=1e-3) -> dict:
    """Long-wave coefficients of the plate model, read off its dynamical matrix (from its
    force routine, :func:`upscale.engine.dispersion.dynamical_matrix`) at ``k dx = kdx``
    along x, y and 45 degrees: for a term ``C f,ab`` in the equation of dof g,
    ``D_gf(k) / V = C k_a k_b``; the shear term ``k_s mu (w,x - phi_x)`` of the phi_x row
    is ``D_phix,phix(0) / V``. Returns ``{term: (model, printed local limit 4.60 with 4.63,
    Mindlin 4.62)}`` (phi terms with I/A = h^2/12), the spurious ``v: u`` coupling of a wave
    along x (Mindlin: 0), the lowest ``omega^2`` over the three directions relative to the
    largest (negative: the model is unstable) and the operator's asymmetry."""
    from upscale.engine.dispersion import centre_particle, dynamical_matrix
    from upscale.engine.families import build_family
    from upscale.engine.fields import mass_vector
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import square_lattice
    from upscale.models.tridynamics import TridynPlate, literal_local_coefficients

    h = h_over_dx * dx
    m = int(np.ceil(ratio))
    nside = 2 * (2 * m + 3) + 1
    system = square_lattice(nside, nside, dx, thickness=h, density=rho, centered=True)
    family = build_family(system, ratio * dx * (1 + 1e-9))
    model = TridynPlate(E, nu, thickness=h, shear_factor=ks, variant=variant,
                        text_triplets=text_triplets)
    sim = Simulation(system, family, model, [])
    c = centre_particle(sim)
    V = float(system.volume[c])
    k = kdx / dx
    s2 = np.sqrt(0.5)
    Dx, Dy, Dd, D0 = (dynamical_matrix(sim, kv, c).real / V for kv in
                      (np.array([k, 0.0]), np.array([0.0, k]), np.array([k * s2, k * s2]),
                       np.zeros(2)))
    k2 = k * k
    u, v, w, px, py = range(5)
    val = {"u: u,xx": Dx[u, u] / k2, "u: u,yy": Dy[u, u] / k2, "u: v,xy": Dd[u, v] / (k2 / 2),
           "v: v,yy": Dy[v, v] / k2, "v: v,xx": Dx[v, v] / k2, "v: u,xy": Dd[v, u] / (k2 / 2),
           "w: w,xx - phi_x,x": Dx[w, w] / k2,
           "phi_x: phi_x,xx": (Dx[px, px] - D0[px, px]) / k2,
           "phi_x: phi_x,yy": (Dy[px, px] - D0[px, px]) / k2,
           "phi_x: phi_y,xy": Dd[px, py] / (k2 / 2),
           "phi_y: phi_y,yy": (Dy[py, py] - D0[py, py]) / k2,
           "phi_y: phi_y,xx": (Dx[py, py] - D0[py, py]) / k2,
           "phi_y: phi_x,xy": Dd[py, px] / (k2 / 2),
           "phi_x: k_s mu (w,x - phi_x)": D0[px, px]}
    lit = literal_local_coefficients(E, nu, ks, I_over_A=h * h / 12.0)
    lit["phi_x: k_s mu (w,x - phi_x)"] = (ks * E / (2 * (1 + nu)),) * 2
    out = {"terms": {t: (float(val[t]), float(lit[t][0]), float(lit[t][1])) for t in val}}
    out["spurious_v_u_along_x"] = float(abs(Dx[v, u]) / k2)
    M = mass_vector(sim).reshape(system.n, 5)[c] / V
    scan = {}
    for kq in (kdx, 0.01, 0.1, 1.0, np.pi):
        lo, hi = np.inf, 0.0
        for th in (0.0, 0.5 * np.pi, 0.25 * np.pi):
            kv = kq / dx * np.array([np.cos(th), np.sin(th)])
            ev = np.linalg.eigvals(dynamical_matrix(sim, kv, c) / V / M[:, None])
            lo, hi = min(lo, ev.real.min()), max(hi, ev.real.max())
        scan[float(kq)] = float(lo / hi)
    out["min_over_max_omega2_by_kdx"] = scan
    out["min_over_max_omega2"] = float(min(scan.values()))
    Dfull = dynamical_matrix(sim, np.array([k, 0.0]), c)
    out["asymmetry"] = float(np.abs(Dfull - Dfull.conj().T).max() / np.abs(Dfull).max())
    out["model"] = model.describe()
    return out


# =========================================================================== Rayleigh beam
def rayleigh_branch(k, *, E, A, I, rho):
    """Rayleigh beam (EB with rotary inertia): ``omega^2 = EI k^4 / (rho (A + I k^2))``."""
    k = np.asarray(k, float)
    return E * I * k ** 4 / (rho * (A + I * k * k))


def rayleigh_dispersion(*, ratio=1, kh=None, dx_over_h=0.01, E=STEEL["E"], rho=STEEL["rho"],
                        h=STEEL["h"]) -> dict:
    """Flexural branch of the EB tridynamic beam with the rotary inertia of its sections:
    ``omega^2 = D(k) / M(k)``, D from the force routine (:func:`beam_dispersion`'s chain),
    ``M(k)`` the plane-wave symbol of the mass matrix (:func:`upscale.engine.mass.mass_symbol`
    of the lumped mass plus :meth:`TridynEB.rotary_mass`), beside the Rayleigh closed form
    and EB without rotary inertia. Square section h x h."""
    from upscale.engine.dispersion import centre_particle, dispersion
    from upscale.engine.families import build_family
    from upscale.engine.mass import ConsistentMass, mass_symbol
    from upscale.engine.simulation import Simulation
    from upscale.models.tridynamics import TridynEB

    kh = np.array([0.01, 0.05, 0.1, 0.5, 1.0]) if kh is None else np.asarray(kh, float)
    dx = dx_over_h * h
    A, I = h * h, h ** 4 / 12.0
    m = int(np.ceil(ratio))
    system = _chain(2 * m + 4, dx, A, rho)
    family = build_family(system, ratio * dx * (1 + 1e-9))
    model = TridynEB(E, area=A, second_moment=I)
    sim = Simulation(system, family, model, [])
    k = kh / h
    d = dispersion(sim, k)
    D = d["D"][:, 0, 0].real
    c = centre_particle(sim)
    M = ConsistentMass(model.rotary_mass()).matrix(system)
    Mk = mass_symbol(M, system.x0[:, 0], c, k).real
    w2 = D / Mk
    ref = rayleigh_branch(k, E=E, A=A, I=I, rho=rho)
    eb = E * I / (rho * A) * k ** 4
    return {"kh": kh, "delta_over_dx": float(ratio), "dx_over_h": dx_over_h, "omega2": w2,
            "rayleigh": ref, "eb": eb, "rel_err": np.abs(w2 / ref - 1),
            "eb_over_rayleigh": eb / ref, "rel_err_max": float(np.max(np.abs(w2 / ref - 1)))}


def rayleigh_mode(*, n=100, mode=4, length=1.0, height=0.05, E=200e9, density=7850.0,
                  periods=3.0, safety=0.8, rotary=True) -> dict:
    """Free vibration of a simply supported EB beam released in mode ``mode``
    (``w = w0 sin(mode pi x/L)``), integrated by :class:`upscale.engine.mass.MassMatrixVerlet`
    with the rotary mass (``rotary``; plain velocity Verlet otherwise): the angular
    frequency from the zero crossings of the modal amplitude against the discrete
    prediction ``D(k)/M(k)`` (exact for a sine mode of the supported chain, up to the
    time step), the Rayleigh closed form and EB (the energy drift is measured by
    :func:`beam_nve` with ``rotary=True``: the mirror ghosts of the supports make the
    model's energy over all particles differ from the conserved one)."""
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.mass import ConsistentMass, MassMatrixVerlet
    from upscale.engine.simulation import Simulation
    from upscale.models.tridynamics import beam

    system, family, model, conds, body = beam(length=length, n=n, horizon_ratio=1.0,
                                              theory="eb", supports=("ss", "ss"), E=E,
                                              width=height, height=height, density=density)
    sim = Simulation(system, family, model, conds, integrator=VelocityVerlet(safety=safety))
    if rotary:   # the coupling needs the prepared model (its body and section)
        sim.integrator = MassMatrixVerlet(ConsistentMass(model.rotary_mass(mask=body)),
                                          safety=safety)
    x = system.x0[:, 0]
    k = mode * np.pi / length
    shape = np.where(body, np.sin(k * x), 0.0)
    w0 = 1e-4 * height
    sim.state.y[body, 2] += w0 * shape[body]
    sim.prepare()
    A, I = height * height, height ** 4 / 12.0
    dx = length / n
    # discrete prediction: the model's symbol (EB operator at delta = dx) and the mass symbol
    Dk = E * I / A * (2 - 2 * np.cos(k * dx)) ** 2 / dx ** 4      # force density per w
    Mk = density * (1 + (I / A) * (2 - 2 * np.cos(k * dx)) / dx ** 2) if rotary else density
    w_pred = float(np.sqrt(Dk / Mk))
    dt = sim.integrator.dt
    steps = int(np.ceil(periods * 2 * np.pi / (w_pred * dt)))
    amp = []
    norm = float(np.sum(shape[body] ** 2))
    for _ in range(steps):
        sim.integrator.step(sim)
        amp.append(float(np.sum(sim.state.y[body, 2] * shape[body]) / norm))
    a = np.array(amp)
    t = dt * np.arange(1, steps + 1)
    s = np.flatnonzero(np.sign(a[:-1]) != np.sign(a[1:]))
    tz = t[s] - a[s] * (t[s + 1] - t[s]) / (a[s + 1] - a[s])
    w_meas = float(np.pi / np.mean(np.diff(tz))) if tz.size > 2 else float("nan")
    return {"mode": mode, "n": n, "h_over_L": height / length, "rotary": rotary, "dt_s": dt,
            "steps": steps, "omega_measured": w_meas, "omega_discrete": w_pred,
            "omega_rayleigh": float(np.sqrt(rayleigh_branch(k, E=E, A=A, I=I, rho=density))),
            "omega_eb": float(np.sqrt(E * I / (density * A)) * k * k),
            "measured_over_discrete": w_meas / w_pred}
