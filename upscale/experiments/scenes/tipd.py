"""``upscale tipd --case CASE``: the scenes of seed 003 (tensor-involved PD) and its comparison
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

:func:`tipd` runs one of ``mms``, ``strip``, ``hole``, ``branching`` and returns a
:class:`~upscale.experiments.result.Result`. Command line: ``upscale tipd --case mms --dx
0.025,0.0125 [--dim 3] [--model nosb --stabilisation wan]``, ``upscale tipd --case strip
--nu 0.1``, ``upscale tipd --case hole --material ortho --dx 0.0005``, ``upscale tipd
--case branching --stress 24e6 --dx 0.0005 [--model lps]``; each writes ``OUT/tipd.json``,
its CSV tables and ``tipd.png``.
"""
from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Literal

import numpy as np

from upscale.experiments.result import Result, Timer, make_meta

__all__ = ["MMS_2D_C", "MMS_3D_C", "mms_body", "mms", "strip", "eigen_counts", "rotation",
           "make_model", "surface_kw", "surface_of", "tipd", "plot_mms_error"]

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


# ---------------------------------------------------------------------------- scene
def tipd(case: Literal["mms", "strip", "hole", "branching"] = "mms", *,
         model: Literal["tipd", "nosb", "lps", "pmb"] = "tipd", dim: Literal[2, 3] = 2,
         dx: tuple[float, ...] | None = None,
         calibration: Literal["discrete", "continuum"] | None = None,
         surface: Literal["none", "correspondence"] | None = None,
         stabilisation: Literal["silling", "wan"] | None = None, nu: float = 0.25,
         material: Literal["iso", "ortho"] = "iso", stress: float = 12e6,
         critical: Literal["tipd", "osb"] = "tipd", progress: bool = False) -> Result:
    """The Ti-PD scenes of seed 003 with one model: manufactured solution, strip, plate
    with a hole, crack branching (module docstring).

    Parameters
    ----------
    case : {"mms", "strip", "hole", "branching"}
        Which scene: manufactured solution, free-contraction strip, plate with a hole, branching.
    model : {"tipd", "nosb", "lps", "pmb"}
        Particle model (hole: tipd or nosb; branching: tipd, lps or pmb).
    dim : {2, 3}
        Dimension of the manufactured solution (the other cases are 2D).
    dx : tuple of float or None
        Spacing(s) in m; mms: one run each (None: 0.025, 0.0125, 0.00625); hole and branching: one (None: 1e-3); strip: not used.
    calibration : {"discrete", "continuum"} or None
        Ti-PD calibration (None: discrete; hole: continuum).
    surface : {"none", "correspondence"} or None
        Ti-PD surface correction (None: correspondence for the elastic cases, none with failure).
    stabilisation : {"silling", "wan"} or None
        NOSB zero-energy stabilisation (None: none).
    nu : float
        Strip: Poisson's ratio of the isotropic material (dimensionless).
    material : {"iso", "ortho"}
        Hole: isotropic or orthotropic plate.
    stress : float
        Branching: traction on the top and bottom edges in Pa.
    critical : {"tipd", "osb"}
        Branching, Ti-PD: critical stretch from eq. (60) (tipd) or (62) (osb).
    progress : bool
        Branching: show a progress bar.
    """
    if case not in ("mms", "strip", "hole", "branching"):
        raise ValueError(f"case={case!r}; valid: 'mms', 'strip', 'hole', 'branching'")
    if dx is not None:
        dx = tuple(float(v) for v in ([dx] if np.isscalar(dx) else dx))
        bad = [v for v in dx if not (np.isfinite(v) and v > 0)]
        if bad or not dx:
            raise ValueError(f"dx={bad[0] if bad else dx!r} m; valid: positive spacings")
        if case in ("hole", "branching") and len(dx) > 1:
            raise ValueError(f"dx={dx!r}: case {case!r} takes one spacing")
    if int(dim) != 2 and case != "mms":
        raise ValueError(f"dim={dim!r}: case {case!r} is 2D; valid: dim=2 (dim=3 for 'mms')")
    params = dict(case=case, model=model, dim=dim, dx=dx, calibration=calibration,
                  surface=surface, stabilisation=stabilisation, nu=nu, material=material,
                  stress=stress, critical=critical)
    cal = calibration or "discrete"
    with Timer() as timer:
        if case == "mms":
            out = _mms_result(model, int(dim), dx or (0.025, 0.0125, 0.00625), cal, stabilisation,
                              surface)
        elif case == "strip":
            r = strip(model, nu=nu, calibration=cal, stabilisation=stabilisation, surface=surface)
            out = _split(r), {}, {}, {}
        elif case == "hole":
            from upscale.experiments.scenes.tipd_hole import hole

            r = hole(model, material=material, dx=dx[0] if dx else 1e-3, surface=surface,
                     stabilisation=stabilisation,
                     **({"calibration": calibration} if calibration else {}))
            out = _hole_result(r)
        else:
            from upscale.experiments.scenes.tipd_branching import branching

            r = branching(model, stress=stress, dx=dx[0] if dx else 1e-3, critical=critical,
                          progress=progress)
            out = _branching_result(r)
    (figures, settings), curves, fields, plot = out
    conventions = {
        "units": "SI (m, Pa, N, s)",
        "rel_l2": "mms: |u - u_exact| / |u_exact| over the domain particles (L2); oscillation: "
                  "the error less its 3 x 3 (x 3) box average, relative to |u_exact|",
        "strip": "apparent nu = -eps_yy / eps_xx and E = sigma_xx / eps_xx on the middle third",
        "hole": "Kt = sigma_xx / (F / (W t)) at the particle next to the hole's top",
        "branching": "tip: the crack's largest x with damage >= tip_damage; speeds over a "
                     "sliding window (tipd_branching module docstring); NaN: not reached",
    }
    memory = r.get("_memory") if case in ("hole", "branching") else None
    meta = make_meta("tipd", params, timer=timer, conventions=conventions, plot=plot,
                     settings=settings, **({"memory": memory} if memory else {}))
    return Result(figures=figures, curves=curves, fields=fields, meta=meta)


def _split(r: dict, skip=(), nan=()) -> tuple[dict, dict]:
    """(figures, settings) of a result dict: the numbers (and, as NaN, the None of the keys
    in ``nan``: a measure not reached) and the rest (names, None options, lists)."""
    figures, settings = {}, {}
    for k, v in r.items():
        if k in skip or k.startswith("_"):
            continue
        if k in nan and v is None:
            figures[k] = np.nan
        elif isinstance(v, (bool, int, float, np.integer, np.floating, np.bool_)) \
                and k not in ("bond_associated",):
            figures[k] = v
        else:
            settings[k] = v
    return figures, settings


def _mms_result(model, dim, dxs, calibration, stabilisation, surface):
    rows = [mms(model, dim=dim, dx=v, calibration=calibration, stabilisation=stabilisation,
                surface=surface) for v in dxs]
    figures = {"horizon_over_dx": rows[0]["m"], "layer_horizons": rows[0]["layer_horizons"]}
    settings = {"solve": [], "wall_time_s": []}
    for v, r in zip(dxs, rows):
        f, s = _split(r, skip=("dx_m", "dim", "wall_time_s", "m", "layer_horizons"))
        figures.update({f"dx{v:g}_{k}": x for k, x in f.items()})
        settings["solve"].append(s.pop("solve"))
        settings["wall_time_s"].append(r["wall_time_s"])
        settings.update(s)
    if len(rows) > 1:
        figures["order"] = float(np.polyfit(np.log(dxs), np.log([r["rel_l2"] for r in rows]), 1)[0])
    curves = {"convergence/dx_m": np.array(dxs), "convergence/rel_l2": [r["rel_l2"] for r in rows],
              "convergence/oscillation": [r["oscillation"] for r in rows]}
    plot = {"convergence": {"x": "dx_m", "y": ["rel_l2"]}}
    return (figures, settings), curves, {}, plot


def _hole_result(r):
    figures, settings = _split(r, skip=("wall_time_s",))
    for k in ("mid_xy_m", "mid_u_m", "edge_xy_m", "edge_u_m", "Kt_point_m"):
        settings.pop(k)
    figures["Kt_point_x_m"], figures["Kt_point_y_m"] = r["Kt_point_m"]
    curves = {}
    for row in ("mid", "edge"):
        xy, u = np.asarray(r[f"{row}_xy_m"]), np.asarray(r[f"{row}_u_m"])
        o = np.lexsort((xy[:, 1], xy[:, 0]))
        curves.update({f"{row}/x_m": xy[o, 0], f"{row}/y_m": xy[o, 1], f"{row}/u_x_m": u[o, 0],
                       f"{row}/u_y_m": u[o, 1]})
    plot = {"mid": {"x": "x_m", "y": ["u_x_m"]}, "edge": {"x": "x_m", "y": ["u_y_m"]}}
    return (figures, settings), curves, {}, plot


def _branching_result(r):
    arrays = ("tip_t_s", "tip_x_m", "tip_v_m_per_s", "upper_tip_xy_m", "lower_tip_xy_m",
              "positions_m", "damage", "damage_onset_s")
    figures, settings = _split(r, skip=arrays + ("wall_time_s",),
                               nan=("v_mean_m_per_s", "v_mean_over_cR", "branching_t_s",
                                    "branching_x_m", "branch_angle_deg", "branch_origin_x_m"))
    up, lo = np.asarray(r["upper_tip_xy_m"]).reshape(-1, 2), np.asarray(r["lower_tip_xy_m"]).reshape(-1, 2)
    curves = {"tip/t_s": r["tip_t_s"], "tip/x_m": r["tip_x_m"], "tip/v_m_per_s": r["tip_v_m_per_s"],
              "tip/upper_x_m": up[:, 0], "tip/upper_y_m": up[:, 1], "tip/lower_x_m": lo[:, 0],
              "tip/lower_y_m": lo[:, 1]}
    pos = np.asarray(r["positions_m"])
    x0 = np.zeros((pos.shape[0], 3))
    x0[:, :2] = pos
    fields = {"x0": x0, "damage": r["damage"], "damage_onset_s": r["damage_onset_s"]}
    settings["wall_time_s"] = r["wall_time_s"]
    return (figures, settings), curves, fields, {"tip": {"x": "t_s", "y": ["x_m"]}}


def plot_mms_error(result: Result, path) -> Path:
    """The manufactured solution's relative L2 error against the spacing, log-log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from upscale.analysis.plots import save_figure

    fig, ax = plt.subplots(figsize=(4.5, 3.5))
    ax.loglog(result.curves["convergence/dx_m"], result.curves["convergence/rel_l2"], "o-",
              label=result.meta["params"]["model"])
    ax.set_xlabel("dx (m)")
    ax.set_ylabel("relative L2 error")
    ax.legend()
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)
