"""``upscale tipd SCENE``: the scenes of seed 003 (tensor-involved PD) and its comparison
models (correspondence / NOSB, LPS, PMB).

Each scene is a plain function of its parameters returning a JSON-able dict (SI units).

``mms``
    Manufactured solutions 5.1.1 (2D: u = (sin pi(x+y), cos pi(x+y)) on [-0.25, 0.25]^2,
    D = [[5, 3, 0], [3, 5, 0], [0, 0, 6]]) and 5.1.2 (3D: u = (sin, sin, cos) of
    pi(x+y+z) on [-0.25, 0.25]^3, C of (98) with 18.1 for the printed "181", Voigt order
    of the paper (11, 22, 33, 12, 23, 13)). Particles at cell centres of spacing dx, a
    layer of width delta outside the domain (2 delta for Ti-PD with the surface correction,
    whose forces couple particles 2 delta apart) holds the exact displacement (Dirichlet), the
    interior carries the body force ``b = -div(C : eps(u))`` (closed form:
    ``b_p = pi^2 C_paqb k_a k_b u_q`` for ``u = A sin(pi k.x) + B cos(pi k.x)``). One
    linear static solve (:func:`upscale.engine.static.solve_linear`); the relative L2
    error is over the domain particles. Oscillation index: the L2 norm of the error minus
    its 3 x 3 (3 x 3 x 3) box average, relative to the norm of the exact field: the part
    of the error at the grid scale.
``strip``
    Free-contraction tension of a strip (plane stress): grips of width delta at both ends
    prescribe u_x only (u_y of one particle of the left grip held), the rest is free. The
    apparent Poisson ratio ``-eps_yy/eps_xx`` and modulus ``sigma_xx/eps_xx`` are fitted
    on the middle third of the strip (strains from least-squares slopes of u_x(x) and
    u_y(y); stress from the grip reaction / (width x thickness)).
``eigen``
    Eigenvalues of the free-body stiffness of a small square/cube: counts of zero and
    negative ones (relative to the largest, threshold 1e-10).
``rotation``
    A free body spun rigidly about z (velocity Verlet, no loads): relative change of the
    angular momentum and the strain energy picked up over a given rotation angle.
``hole`` (:mod:`upscale.experiments.scenes.tipd_hole`)
    The plate with a hole 5.2.1 / 5.2.2 with clamped grips; ``hole_adr`` the Table 1 ADR run.
``branching`` (:mod:`upscale.experiments.scenes.tipd_branching`)
    Crack branching in glass 5.3 (Ha & Bobaru geometry).

Command line: ``upscale tipd mms --dx 0.025 0.0125 [--dim 3] [--model nosb
--stabilisation wan]``, ``upscale tipd strip --nu 0.1``, ``upscale tipd hole --material
ortho --dx 0.0005``, ``upscale tipd branching --stress 24e6 --dx 0.0005 [--model lps]``;
each writes ``OUT/tipd_SCENE.json`` (and plots).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

__all__ = ["MMS_2D_C", "MMS_3D_C", "mms_body", "mms", "strip", "eigen_counts", "rotation",
           "make_model", "surface_kw", "surface_of", "register"]

#: seed 003 sec. 5.1.1 (Voigt 11, 22, 12)
MMS_2D_C = np.array([[5.0, 3.0, 0.0], [3.0, 5.0, 0.0], [0.0, 0.0, 6.0]])
#: seed 003 eq. (98), Voigt order (11, 22, 33, 12, 23, 13); the printed "181" is 18.1
MMS_3D_C = np.array([[18.1, 10.3, 7.2, 0, 0, 0], [10.3, 18.1, 7.2, 0, 0, 0],
                     [7.2, 7.2, 10.3, 0, 0, 0], [0, 0, 0, 5.2, 0, 0], [0, 0, 0, 0, 5.2, 0],
                     [0, 0, 0, 0, 0, 3.5]])


def make_model(name: str, C=None, *, E=None, nu=None, order="standard", angle=None,
               calibration="discrete", stabilisation=None, Cs=100.0, **kw):
    """A Ti-PD / NOSB / LPS / PMB model from one set of material arguments."""
    from upscale import models

    if name == "tipd":
        return models.create("tipd", C=C, E=E, nu=nu, order=order, angle=angle,
                             calibration=calibration, **kw)
    if name == "nosb":
        return models.create("nosb", C=C, E=E, nu=nu, order=order, angle=angle,
                             stabilisation=stabilisation, Cs=Cs, **kw)
    if name in ("lps", "pmb"):
        if E is None:
            raise ValueError(f"model {name!r} is isotropic: give E and nu, not C")
        return models.create(name, E=E, nu=nu, **kw)
    raise ValueError(f"unknown model {name!r}; valid: 'tipd', 'nosb', 'lps', 'pmb'")


def surface_kw(model: str, surface: str | None) -> dict:
    """The surface-correction keyword for Ti-PD (other models have none); None: the
    model's default (:func:`upscale.models.tipd.default_surface`)."""
    if model == "tipd":
        return {} if surface is None else {"surface": surface}
    if surface not in (None, "none"):
        raise ValueError(f"surface correction {surface!r} is a Ti-PD option, not one of {model!r}")
    return {}


def surface_of(model: str, surface: str | None, failure: bool = False) -> str | None:
    """The surface correction a scene's Ti-PD uses (None for the other models)."""
    from upscale.models.tipd import default_surface

    if model != "tipd":
        return None
    return default_surface(failure) if surface is None else surface


# ---------------------------------------------------------------------------- MMS
def _mms_field(x, dim):
    s = np.pi * x[:, :dim].sum(axis=1)
    u = np.zeros((x.shape[0], 3))
    if dim == 2:
        u[:, 0], u[:, 1] = np.sin(s), np.cos(s)
    else:
        u[:, 0], u[:, 1], u[:, 2] = np.sin(s), np.sin(s), np.cos(s)
    return u


def mms_body(dx: float, dim: int, m: float = 3.0, layer: float = 1.0):
    """Particles at cell centres of [-0.25, 0.25]^d plus a layer of ceil(layer m) cells
    outside (``layer`` horizons wide); returns (system, domain mask (N,), grid shape of the
    domain)."""
    from upscale.engine import cubic_lattice, square_lattice

    n = int(round(0.5 / dx))
    if not np.isclose(n * dx, 0.5, rtol=1e-9) or n < 4:
        raise ValueError(f"dx must divide 0.5 into at least 4 cells, got dx = {dx!r}")
    if not (np.isfinite(layer) and layer >= 1):
        raise ValueError(f"layer must be at least one horizon, got {layer!r}")
    layer = int(np.ceil(layer * m - 1e-9))
    nt = n + 2 * layer
    o = -0.25 - (layer - 0.5) * dx
    if dim == 2:
        s = square_lattice(nt, nt, dx, origin=(o, o))
    else:
        s = cubic_lattice(nt, nt, nt, dx, origin=(o, o, o))
    dom = np.all(np.abs(s.x0[:, :dim]) < 0.25, axis=1)
    return s, dom, (n,) * dim


def mms(model: str = "tipd", *, dim: int = 2, dx: float = 0.005, m: float = 3.0,
        calibration: str = "discrete", stabilisation=None, Cs: float = 100.0,
        method: str | None = None, return_fields: bool = False, surface: str | None = None,
        bond_associated: bool = False, layer: float | None = None) -> dict:
    """Manufactured solution 5.1.1 (2D) / 5.1.2 (3D) with one model (module docstring);
    ``surface``: Ti-PD's surface correction (:class:`~upscale.models.tipd.TiPD`);
    ``layer``: width of the layer of exact displacement, in horizons; default two for Ti-PD
    with the surface correction (its forces couple particles 2 delta apart, so a
    one-horizon layer feeds gradients of truncated families into the free particles), one
    otherwise (the paper's set-up).

    Returns ``{"rel_l2": ..., "oscillation": ..., "dx_m", "horizon_m", "particles",
    "solve": {...}, "wall_time_s"}`` (and the fields with ``return_fields``)."""
    from scipy.ndimage import uniform_filter

    from upscale.engine import State, build_family
    from upscale.engine.static import solve_linear
    from upscale.models.tipd import voigt_to_tensor

    t0 = time.perf_counter()
    surf = surface_of(model, surface)
    if layer is None:
        layer = 2.0 if surf == "correspondence" else 1.0
    s, dom, shape = mms_body(dx, dim, m, layer)
    fam = build_family(s, m * dx * (1 + 1e-9))
    Cv, order = (MMS_2D_C, "standard") if dim == 2 else (MMS_3D_C, "tian")
    skw = surface_kw(model, surface)
    if bond_associated:
        if model != "nosb":
            raise ValueError(f"bond_associated is a NOSB option, not one of {model!r}")
        skw["bond_associated"] = True
    if surf == "correspondence":   # the layer of exact displacement extends the body: no free surface
        skw["surface_bulk"] = lambda x: ~np.all(np.abs(x[:, :dim]) < 0.25, axis=1)
    mdl = make_model(model, Cv, order=order, calibration=calibration,
                     stabilisation=stabilisation, Cs=Cs, **skw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mdl.prepare(s, fam)
    C = voigt_to_tensor(Cv, order)
    k = np.ones(dim)
    Ck = np.einsum("paqb,a,b->pq", C, k, k)
    u_ex = _mms_field(s.x0, dim)
    b = np.zeros_like(u_ex)
    b[:, :dim] = np.pi ** 2 * u_ex[:, :dim] @ Ck.T
    f_ext = np.where(dom[:, None], b * s.volume[:, None], 0.0)
    st = State.reference(s.x0, fam.nb)
    if method is None:
        method = "direct" if model == "tipd" and dim == 2 else ("cg" if model == "tipd" or dim == 2
                                                                or bond_associated else "matrix-free")
    info = solve_linear(mdl, st, fixed=~dom, u_prescribed=u_ex, f_ext=f_ext, method=method,
                        tol=1e-12)
    u = st.y - s.x0
    e = (u - u_ex)[dom][:, :dim]
    rel = float(np.linalg.norm(e) / np.linalg.norm(u_ex[dom][:, :dim]))
    # the domain particles are in lattice order: reshape to the grid
    eg = e.reshape(*shape, dim)
    smooth = np.stack([uniform_filter(eg[..., c], size=3, mode="nearest") for c in range(dim)], -1)
    osc = float(np.linalg.norm(eg - smooth) / np.linalg.norm(u_ex[dom][:, :dim]))
    out = {"model": model, "dim": dim, "dx_m": dx, "horizon_m": fam.horizon, "m": m,
           "calibration": calibration if model == "tipd" else None,
           "stabilisation": stabilisation if model == "nosb" else None,
           "surface": surf,
           "bond_associated": bool(bond_associated), "layer_horizons": layer,
           "particles": s.n, "bonds": fam.nb, "rel_l2": rel, "oscillation": osc,
           "max_abs_err": float(np.abs(e).max()), "solve": info,
           "wall_time_s": time.perf_counter() - t0}
    if return_fields:
        out["x"] = s.x0[dom]
        out["u"] = u[dom]
        out["u_exact"] = u_ex[dom]
    return out


# ---------------------------------------------------------------------------- strip
def strip(model: str = "tipd", *, E: float = 70e9, nu: float | None = 0.25, C=None,
          nx: int = 60, ny: int = 20, dx: float = 1e-3, m: float = 3.015, strain: float = 1e-4,
          calibration: str = "discrete", stabilisation=None, surface: str | None = None) -> dict:
    """Free-contraction tension of a plane-stress strip (module docstring). ``C`` (Voigt,
    axis 1 along x) instead of ``E``/``nu`` for an anisotropic material. Returns the
    apparent Poisson ratio and modulus."""
    from upscale.engine import State, build_family, square_lattice
    from upscale.engine.newton import solve
    from upscale.engine.static import solve_linear

    s = square_lattice(nx, ny, dx, plane="stress")
    fam = build_family(s, m * dx)
    mdl = make_model(model, C, E=None if C is not None else E, nu=None if C is not None else nu,
                     calibration=calibration, stabilisation=stabilisation,
                     **surface_kw(model, surface))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mdl.prepare(s, fam)
    x = s.x0
    delta = fam.horizon
    Lx = (nx - 1) * dx
    left, right = x[:, 0] < delta - 1e-12, x[:, 0] > Lx - delta + 1e-12
    fixed = np.zeros((s.n, 3), dtype=bool)
    fixed[left | right, 0] = True
    pin = np.flatnonzero(left)[np.argmin(np.abs(x[left, 1] - x[:, 1].mean()))]
    fixed[pin, 1] = True
    ubar = np.zeros((s.n, 3))
    ubar[right, 0] = strain * Lx
    st = State.reference(s.x0, fam.nb)
    if model in ("tipd", "nosb"):          # linear: one solve
        solve_linear(mdl, st, fixed=fixed, u_prescribed=ubar, method="direct")
    else:                                  # geometrically nonlinear LPS / PMB: Newton
        solve(mdl, st, fixed=fixed, u_prescribed=ubar, tol=1e-10)
    F = mdl.residual(st).reshape(s.n, 3)
    u = st.y - s.x0
    mid = (x[:, 0] > Lx / 3) & (x[:, 0] < 2 * Lx / 3)
    exx = np.polyfit(x[mid, 0], u[mid, 0], 1)[0]
    eyy = np.polyfit(x[mid, 1], u[mid, 1], 1)[0]
    reaction = -F[right, 0].sum()
    width = ny * dx
    sigma = reaction / (width * s.thickness)
    return {"model": model, "nu_apparent": float(-eyy / exx), "E_apparent_Pa": float(sigma / exx),
            "eps_xx": float(exx), "eps_yy": float(eyy), "nx": nx, "ny": ny, "dx_m": dx,
            "horizon_m": delta, "strain": strain}


# ---------------------------------------------------------------------------- eigen
def eigen_counts(model: str = "tipd", *, dim: int = 2, E: float = 70e9, nu: float = 0.25, C=None,
                 plane: str = "stress", n: int | None = None, m: float = 3.015,
                 calibration: str = "discrete", stabilisation=None, surface: str | None = None,
                 shape=None, clamped: bool = False) -> dict:
    """Zero and negative eigenvalues of the free-body stiffness (module docstring);
    ``shape``: lattice counts (default n per side); ``clamped``: the particles within one
    horizon of the x = min end held (the stiffness of a body that cannot move rigidly)."""
    from upscale.engine import State, build_family, cubic_lattice, square_lattice

    n = n or (10 if dim == 2 else 5)
    shape = tuple(shape) if shape is not None else (n,) * dim
    s = square_lattice(*shape, 1e-3, plane=plane) if dim == 2 else cubic_lattice(*shape, 1e-3)
    fam = build_family(s, m * 1e-3)
    mdl = make_model(model, C, E=None if C is not None else E, nu=None if C is not None else nu,
                     calibration=calibration, stabilisation=stabilisation,
                     **surface_kw(model, surface))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mdl.prepare(s, fam)
    K = mdl.tangent(State.reference(s.x0, fam.nb)).toarray()
    free = np.zeros((s.n, 3), dtype=bool)
    free[:, :dim] = True
    if clamped:
        free[s.x0[:, 0] < s.x0[:, 0].min() + m * 1e-3 - 1e-9] = False
    Kf = K[free.ravel()][:, free.ravel()]
    ev = np.linalg.eigvalsh(0.5 * (Kf + Kf.T))
    sc = np.abs(ev).max()
    return {"model": model, "dim": dim, "nu": nu, "plane": plane, "particles": s.n,
            "zero": int((np.abs(ev) <= 1e-10 * sc).sum()),
            "negative": int((ev < -1e-10 * sc).sum()),
            "min_over_max": float(ev.min() / sc),
            "rigid_modes": 0 if clamped else dim * (dim + 1) // 2}


# ---------------------------------------------------------------------------- rotation
def rotation(model: str = "tipd", *, E: float = 70e9, nu: float = 0.25, n: int = 10,
             angle: float = 0.2, omega: float = 1e3, rho: float = 2440.0, m: float = 3.015,
             calibration: str = "discrete", surface: str | None = None) -> dict:
    """Free 2D body spun rigidly about its centre at ``omega`` (rad/s), velocity Verlet until
    it has turned by ``angle`` (rad): relative change of the angular momentum L_z and strain
    energy over the initial kinetic energy."""
    from upscale.engine import Simulation, build_family, square_lattice
    from upscale.engine.integrators import VelocityVerlet

    s = square_lattice(n, n, 1e-3, density=rho, plane="stress", centered=True)
    fam = build_family(s, m * 1e-3)
    mdl = make_model(model, E=E, nu=nu, **({"calibration": calibration, **surface_kw(model, surface)}
                                           if model == "tipd" else {}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = Simulation(s, fam, [mdl], integrator=VelocityVerlet(safety=0.5))
    st = sim.state
    st.v[:, 0] = -omega * s.x0[:, 1]
    st.v[:, 1] = omega * s.x0[:, 0]

    def Lz():
        mv = s.mass[:, None] * st.v
        return float(np.sum(st.y[:, 0] * mv[:, 1] - st.y[:, 1] * mv[:, 0]))

    L0, K0 = Lz(), sim.kinetic_energy()
    sim.prepare()
    steps = int(np.ceil(angle / omega / sim.integrator.dt))
    sim.run(steps)
    return {"model": model, "nu": nu, "calibration": calibration if model == "tipd" else None,
            "angle_rad": angle, "omega_rad_per_s": omega,
            "steps": steps, "L0": L0, "L1": Lz(), "dL_over_L": float((Lz() - L0) / L0),
            "strain_energy_over_kinetic": float(sim.energy() / K0)}


# ---------------------------------------------------------------------------- CLI
def _run(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.scene_tipd == "mms":
        rows = []
        for dx in args.dx:
            r = mms(args.model, dim=args.dim, dx=dx, calibration=args.calibration,
                    stabilisation=args.stabilisation, surface=args.surface)
            print(f"{args.model} dim={args.dim} dx={dx:g}: rel L2 {r['rel_l2']:.4e}, "
                  f"oscillation {r['oscillation']:.3e} ({r['wall_time_s']:.1f} s)")
            rows.append(r)
        res = {"scene": "tipd mms", "runs": rows}
        if len(rows) > 1:
            h = np.log([r["dx_m"] for r in rows])
            e = np.log([r["rel_l2"] for r in rows])
            res["order"] = float(np.polyfit(h, e, 1)[0])
            print(f"order {res['order']:.3f}")
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt

            fig, ax = plt.subplots(figsize=(4.5, 3.5))
            ax.loglog([r["dx_m"] for r in rows], [r["rel_l2"] for r in rows], "o-", label=args.model)
            ax.set_xlabel("dx (m)")
            ax.set_ylabel("relative L2 error")
            ax.legend()
            fig.tight_layout()
            fig.savefig(out / "mms_error.png", dpi=120)
            plt.close(fig)
    elif args.scene_tipd == "strip":
        res = strip(args.model, nu=args.nu, calibration=args.calibration, surface=args.surface)
        print(f"{args.model} nu={args.nu}: apparent nu {res['nu_apparent']:.4f}, "
              f"E {res['E_apparent_Pa']:.4e} Pa")
    elif args.scene_tipd == "hole":
        from upscale.experiments.scenes.tipd_hole import hole

        res = hole(args.model, material=args.material, dx=args.dx[0] if args.dx else 1e-3,
                   surface=args.surface,
                   **({"calibration": args.calibration} if args.calibration else {}))
        print(json.dumps({k: v for k, v in res.items() if not isinstance(v, list)}, default=float))
    else:
        from upscale.experiments.scenes.tipd_branching import branching

        res = branching(args.model, stress=args.stress, dx=args.dx[0] if args.dx else 1e-3,
                        critical=args.critical, progress=not args.quiet, outdir=out)
        print(json.dumps({k: v for k, v in res.items() if not isinstance(v, (list, dict, np.ndarray))},
                         default=float))
    from upscale.io import write_json

    write_json(out / f"tipd_{args.scene_tipd}.json", res)
    return 0


def register(sub) -> None:
    p = sub.add_parser("tipd", help="Ti-PD scenes: mms | strip | hole | branching",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene_tipd", choices=["mms", "strip", "hole", "branching"])
    p.add_argument("--model", default="tipd", help="tipd (default), nosb, lps, pmb")
    p.add_argument("--dim", type=int, default=2)
    p.add_argument("--dx", type=float, nargs="*", default=None, help="spacing(s) in m")
    p.add_argument("--calibration", default=None,
                   help="Ti-PD: discrete or continuum (default: discrete; hole: continuum)")
    p.add_argument("--surface", default=None, choices=["none", "correspondence"],
                   help="Ti-PD surface correction: correspondence or none (default: correspondence "
                        "for the elastic scenes, none with failure)")
    p.add_argument("--stabilisation", default=None, help="NOSB: silling or wan (default none)")
    p.add_argument("--nu", type=float, default=0.25)
    p.add_argument("--material", default="iso", help="hole: iso or ortho")
    p.add_argument("--stress", type=float, default=12e6, help="branching: edge traction (Pa)")
    p.add_argument("--critical", default="tipd", help="branching, Ti-PD: tipd (60) or osb (62)")
    p.add_argument("--out", default="out/tipd")
    p.add_argument("--quiet", action="store_true")

    def run(a):
        if a.calibration is None and a.scene_tipd != "hole":
            a.calibration = "discrete"
        if a.dx is None:
            a.dx = [0.025, 0.0125, 0.00625] if a.scene_tipd == "mms" else None
        return _run(a)

    p.set_defaults(func=run)


if __name__ == "__main__":  # pragma: no cover
    from upscale.cli import main

    sys.exit(main(["tipd", *sys.argv[1:]]))
