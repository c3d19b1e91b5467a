"""Tube tension scenes of the coarse DCBR model beside their LAMMPS references.

The scenes: quasi-static tension of a periodic tube (:func:`quasi_static_tension_engine`
on :class:`~upscale.models.dcbr.DCBRTube`, or :class:`~upscale.models.dcbr_defect.DCBRDefectTube`
with the 4-atom vacancy) and dynamic tension of the open tube held by grips
(:func:`dynamic_scene`, :func:`upscale.experiments.scenes.dcbr_dynamic.dynamic_tension`). One call,
:func:`run_tension_comparison`, runs a scene and puts it beside its LAMMPS record, the
figures every command and validation case reports (modulus, strength, strain at peak,
damage, crack angle, wall time, speed-up).

LAMMPS references (:func:`lammps_reference`) are LAMMPS tension runs of the same tube, the
same potential file and the same protocol, stored in ``data/reference/*.json`` (or cached
in a directory the caller names). This module only reads them; computing a missing one
needs a LAMMPS runner, which the caller passes (``runner``; the validation cases pass
theirs), else the lookup fails with a one-line error that says how to compute it.

Stress is on the wall thickness 3.4 Å (area 2 pi R t).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from upscale.experiments.references import reference_dir

__all__ = ["parse_chirality", "lammps_reference", "GRIPS", "dynamic_scene",
           "quasi_static_tension_engine", "defect_nve",
           "run_tension_comparison", "reference_grip_planes", "reference_held_planes",
           "tube_z_range", "crack_metrics", "plot_comparison", "ROOT", "REFERENCE_DIR"]

#: the repository's root (``data/reference`` lives there)
ROOT = Path(__file__).resolve().parents[3]
#: the stored LAMMPS references (:func:`upscale.experiments.references.reference_dir`)
REFERENCE_DIR = reference_dir()


def parse_chirality(text: str) -> tuple[int, int]:
    """``"N,M"`` -> ``(N, M)``; anything else is a one-line ValueError."""
    try:
        n, m = (int(v) for v in str(text).split(","))
    except ValueError:
        raise ValueError(f"--chirality {text!r}; valid: two integers 'N,M', e.g. 10,10") from None
    return n, m



def lammps_reference(n, m, length, *, protocol="quasi-static", strain_step=0.005,
                     vacancy=False, cutoff="step", potential="tersoff:BNC.tersoff",
                     progress=True, cache_dir=None, cache_tag=None, runner=None) -> dict:
    """LAMMPS tension record of the (n, m) tube: stored, cached, or computed by ``runner``.

    Parameters
    ----------
    n, m : int
        Chirality.
    length : float
        Built tube length (Å); with ``vacancy`` the 4-atom vacancy of
        :func:`upscale.build.vacancy`.
    protocol : {"quasi-static", "dynamic"}
    strain_step : float
        Quasi-static strain increment the record must have.
    cutoff : str
        Tersoff cut-off variant of the record (``"step"``: LAMMPS's step cut-off).
    cache_dir : path, optional
        Also search ``cache_dir/*.json`` (after ``data/reference``) and write a computed
        record there, named by the tube, the protocol and ``cache_tag`` (e.g. a checksum of
        the runner, so a changed runner computes anew; without a tag, a cached record of
        any tag that matches is taken, the newest first).
    runner : callable, optional
        ``runner(protocol, atoms, potential, cutoff, strain_step, progress) -> dict``
        computes a missing record (``progress(strain, stress_GPa)`` or None).

    Returns
    -------
    dict
        The record (``kind == "lammps-tension"``), with ``_source`` saying where it came from.

    Raises
    ------
    LookupError
        No stored or cached record matches and no ``runner`` was given.
    """
    from upscale.build import swcnt, vacancy as make_vacancy

    if protocol not in ("quasi-static", "dynamic"):
        raise ValueError(f"protocol={protocol!r}; valid: 'quasi-static', 'dynamic'")
    atoms = swcnt(n, m, length=length)
    if vacancy:
        atoms = make_vacancy(atoms, n=4)
    natoms = len(atoms)
    want_vac = 4 if vacancy else None

    def matches(r):
        st = r.get("structure", {})
        pd = r.get("protocol_detail", {})
        vac = st.get("vacancy")
        nvac = (vac.get("n") if isinstance(vac, dict) else vac) if vac else None
        return (r.get("kind") == "lammps-tension" and r.get("protocol") == protocol
                and list(st.get("chirality") or []) == [n, m] and st.get("n_atoms") == natoms
                and r.get("potential", {}).get("cutoff") == cutoff
                and (protocol != "quasi-static"
                     or abs(pd.get("strain_step", -1) - strain_step) < 1e-12)
                and ((nvac or None) == want_vac))

    def first_match(files, label):
        for f in files:
            try:
                r = json.loads(f.read_text())
            except (OSError, json.JSONDecodeError):
                continue
            r = r.get("result", r)
            if isinstance(r, dict) and matches(r):
                try:
                    r["_source"] = str(f.relative_to(ROOT)) + label
                except ValueError:
                    r["_source"] = str(f) + label
                return r
        return None

    r = first_match(sorted(REFERENCE_DIR.glob("*.json")), "")
    if r is not None:
        return r
    key = (f"{protocol}_{n}_{m}_{natoms}_{'vac4' if vacancy else 'pristine'}_{cutoff}_"
           f"{strain_step:g}")
    cache = Path(cache_dir) if cache_dir is not None else None
    if cache is not None:
        if cache_tag is not None:
            files = [cache / f"{key}_{cache_tag}.json"]
        else:
            files = sorted(cache.glob(f"{key}_*.json"), key=lambda p: p.stat().st_mtime,
                           reverse=True)
        r = first_match([f for f in files if f.is_file()], " (cache)")
        if r is not None:
            return r
    what = (f"LAMMPS {protocol} reference of the ({n},{m}) tube, {natoms} atoms"
            f"{', 4-atom vacancy' if vacancy else ''}, strain step {strain_step:g}")
    if runner is None:
        raise LookupError(f"no stored {what} (data/reference/); compute it with "
                          f"`python -m validation dcbr-tension --chirality {n},{m} "
                          f"--length {length:g}{' --vacancy' if vacancy else ''}"
                          f"{' --dynamic' if protocol == 'dynamic' else ''}`")
    from upscale.io import write_json

    print(f"{what} not stored: running it now", flush=True)
    cb = (lambda e, s: print(f"  lammps  strain {e:.4f}  stress {s:9.3f} GPa", flush=True)) \
        if progress else None
    r = runner(protocol, atoms, potential, cutoff, strain_step, cb)
    if cache is not None:
        write_json(cache / f"{key}_{cache_tag or 'untagged'}.json", r)
    r["_source"] = "computed now"
    return r


def _err_pct(a, b):
    return 100.0 * abs(a - b) / abs(b)



GRIPS = ("bands", "clamped")


def dynamic_scene(n, m, length, coarsening, ref, vacancy=True, grips=None,
                  r_atomistic=8.0, grow=None, r_grow=None, **kw):
    """The coarse model of the dynamic protocol and the keywords of its
    :func:`upscale.experiments.scenes.dcbr_dynamic.dynamic_tension` call, as every case builds it.

    ``grips``: ``None`` (default) picks ``"clamped"`` with the vacancy, ``"bands"`` without.
    ``"bands"``: atomistic bands of ``r_atomistic`` across both grip planes
    (:func:`upscale.experiments.scenes.dcbr_dynamic.grip_band_tube`), the grips holding the band atoms
    beyond them as LAMMPS's hold its atoms, on LAMMPS's own planes when the reference
    ``ref`` records them (its extensometer window; the seed-scale references predate it and
    the planes are then ``grip`` inside the lattice's end atoms, 0.2-1 Å off). With the
    vacancy its own region is kept. ``grips="clamped"`` (vacancy only): coarse rows up to the
    planes, held rigid in G (:meth:`~upscale.models.dcbr_defect.DCBRDefectTube.clamp_grips`);
    where the reference records its planes, they are the gauge (``dyn["gauge_planes"]``) and
    each clamp takes hold at LAMMPS's innermost held atoms (``dyn["planes"]``,
    :func:`reference_held_planes`). Why the default differs: a pristine tube breaks at a grip plane (LAMMPS's do: the held
    radius stretches the first free bonds), a concentration of a few atoms that the
    atomistic band carries and a clamped coarse row does not (``upscale.experiments.scenes.dcbr_dynamic``
    docstring); its bands leave 62 % of the 50 Å gauge's atoms coarse. With the vacancy, its
    own region and the two bands (rounded out to whole cells) cover 80 % of the gauge's
    atoms at coarsening 2 and all of them at 4 on these tubes ((10,10); the (50,50)
    likewise), so the gauge would no longer be coarse at all; measured that way (4 seeds)
    the small tubes were within 3.5 % (strength), 1.9 % (modulus) and 4.3 % (strain at
    peak) of LAMMPS, but that tests the atoms, not the coarse model. ``kw`` goes to the
    model (hourglass, step_crossing, region, ...). ``dyn["grips"]`` records the grips chosen.

    ``grow`` (clamped grips): the region the run grows to when the crack starts (e.g.
    ``"band"`` about a ``region="disc"``; :func:`upscale.experiments.scenes.dcbr_dynamic.dynamic_tension`,
    ``grow``), of half-width ``r_grow`` (default ``r_atomistic``); its tube is ``dyn["grow"]``."""
    from upscale.models.dcbr_defect import DCBRDefectTube  # noqa: PLC0415
    from upscale.experiments.scenes.dcbr_dynamic import grip_band_tube  # noqa: PLC0415

    if grips is None:
        grips = "clamped" if vacancy else "bands"
    if grips not in GRIPS or (grips == "clamped" and not vacancy):
        raise ValueError(f"grips={grips!r} (vacancy={vacancy}); valid: 'bands', or 'clamped' "
                         "with the vacancy")
    if grow is not None and grips != "clamped":
        raise ValueError(f"grow={grow!r} with grips={grips!r}; valid: grow with clamped grips")
    pd = ref.get("protocol_detail", {})
    grip = pd.get("grip_A", 50.0)
    dyn = {"grip": grip, "speed": pd.get("speed_A_per_ps_each_grip", 1.0)}
    if grips == "bands":
        model = grip_band_tube(n, m, length, coarsening, grip=grip, r_atomistic=r_atomistic,
                               vacancy=4 if vacancy else 0, **kw)
        planes = reference_grip_planes(ref) if "extensometer" in pd else None
        dyn.update(clamp=False, planes=planes)
    else:
        model = DCBRDefectTube(n, m, length, coarsening=coarsening, vacancy=4,
                               r_atomistic=r_atomistic, **kw)
        dyn.update(clamp=True)
        if grow is not None:
            big = kw | {"region": grow}
            if grow != "ellipse":
                big.pop("r_arc", None)
            dyn["grow"] = DCBRDefectTube(n, m, length, coarsening=coarsening, vacancy=4,
                                         r_atomistic=r_atomistic if r_grow is None else r_grow,
                                         **big)
        if "extensometer" in pd:  # LAMMPS's planes, and its held atoms (:func:`reference_held_planes`)
            dyn["gauge_planes"] = reference_grip_planes(ref)
            dyn["planes"] = reference_held_planes(model.X_atoms[:, 2], dyn["gauge_planes"])
    return model, dyn | {"grips": grips}



def run_tension_comparison(n, m, length, coarsening, strain_step=0.005, vacancy=False,
                           dynamic=False, outdir=None, plot=True, verbose=True,
                           hourglass=0.1, r_atomistic=8.0, region="band",
                           step_crossing="damped", temperature=10.0, grips=None, *,
                           cache_dir=None, runner=None) -> dict:
    """Coarse (DCBR) and LAMMPS quasi-static tension of one tube, with errors and speed-up.

    With ``vacancy`` the coarse model is :class:`upscale.models.dcbr_defect.DCBRDefectTube`
    (atomistic region of ``r_atomistic`` Å around the 4-atom vacancy) and the crack angles
    of both are compared. ``dynamic``: the open tube with grips of :func:`dynamic_scene`
    (``grips``; by default clamped coarse grips with the vacancy and, pristine, an atomistic
    band of ``r_atomistic`` Å across each grip plane: LAMMPS's pristine tubes fail next to a
    grip plane, where the held atoms keep the radius). ``cache_dir`` and ``runner`` go to
    :func:`lammps_reference`."""
    from upscale.models.dcbr import DCBRTube

    ref = lammps_reference(n, m, length, strain_step=strain_step, vacancy=vacancy,
                           protocol="dynamic" if dynamic else "quasi-static",
                           progress=verbose, cache_dir=cache_dir, runner=runner)
    t0 = time.perf_counter()
    banded = False  # atomistic bands across the grip planes (dynamic_scene's choice)
    if dynamic:
        kw = {"region": region} if vacancy else {}
        model, dyn = dynamic_scene(n, m, length, coarsening, ref, vacancy=vacancy, grips=grips,
                                   r_atomistic=r_atomistic, hourglass=hourglass,
                                   step_crossing=step_crossing, **kw)
        grips = dyn.pop("grips")
        banded = grips == "bands"
    elif vacancy:
        from upscale.models.dcbr_defect import DCBRDefectTube

        model = DCBRDefectTube(n, m, length, coarsening=coarsening, hourglass=hourglass,
                               vacancy=4, r_atomistic=r_atomistic, region=region,
                               step_crossing=step_crossing)
    else:
        model = DCBRTube(n, m, length, coarsening=coarsening, hourglass=hourglass)
    cb = (lambda e, s: print(f"  dcbr    strain {e:.4f}  stress {s:9.3f} GPa", flush=True)) \
        if verbose else None
    if dynamic:
        from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension

        res = dynamic_tension(model, progress=cb, temperature=temperature, **dyn)
        res["curve"]["Lz_A"] = [res["L0_A"]] * len(res["curve"]["strain"])
    else:
        res = quasi_static_tension_engine(model, strain_step=strain_step, progress=cb)
    wall = time.perf_counter() - t0
    out = {"chirality": f"{n},{m}", "coarsening": coarsening, "hourglass": hourglass,
           "atoms": model.n_atoms,
           "particles": model.N, "dof": res["dof"], "internal_dof": res.get("internal_dof", 3 * model.N),
           "dof_atoms": 3 * model.n_atoms,
           "modulus_TPa": res["youngs_modulus_TPa"], "modulus_lammps_TPa": ref["youngs_modulus_TPa"],
           "strength_GPa": res["strength_GPa"], "strength_lammps_GPa": ref["strength_GPa"],
           "strain_at_peak": res["strain_at_peak"], "strain_at_peak_lammps": ref["strain_at_peak"],
           "modulus_err_pct": _err_pct(res["youngs_modulus_TPa"], ref["youngs_modulus_TPa"]),
           "strength_err_pct": _err_pct(res["strength_GPa"], ref["strength_GPa"]),
           "strain_at_peak_err_pct": _err_pct(res["strain_at_peak"], ref["strain_at_peak"]),
           "wall_s": wall, "lammps_wall_s": ref.get("wall_s"),
           "lammps_source": ref.get("_source"),
           "L0_A": res["L0_A"], "L0_lammps_A": ref["relaxation"]["L0_A"],
           "radius_A": res["radius_relaxed_A"], "radius_lammps_A": ref["relaxation"]["radius_relaxed_A"],
           "protocol": "dynamic" if dynamic else "quasi-static",
           "grips": grips if dynamic else None,
           "temperature_K": temperature if dynamic else None}
    out["speedup"] = (out["lammps_wall_s"] / wall) if out["lammps_wall_s"] else None
    if dynamic and ref.get("youngs_modulus_ext_TPa") is not None:  # the same extensometer
        for k, ko in (("youngs_modulus_ext_TPa", "modulus_ext"), ("strain_at_peak_ext",
                                                                   "strain_at_peak_ext")):
            out[ko], out[f"{ko}_lammps"] = res.get(k), ref[k]
            out[f"{ko}_err_pct"] = _err_pct(res[k], ref[k]) if res.get(k) is not None else None
    if vacancy or banded:
        out.update({k: res[k] for k in ("setup_relax_s", "dynamics_s", "steps") if k in res})
        if res.get("first_damage"):
            out["first_damage_strain"] = res["first_damage"]["strain"]
            out["crack_start_to_vacancy_A"] = res["first_damage"]["distance_to_vacancy_A"]
            if banded and not vacancy:  # [min, median, max] distance into the gauge
                fd = res["first_damage"]
                out["first_damage_to_grip_plane_A"] = fd["distance_to_grip_plane_A"]
                out["first_damage_halves"] = [fd["n_bottom_half"], fd["n_top_half"]]
            dref = ref.get("damage", {})
            out["crack_start_to_vacancy_lammps_A"] = dref.get("crack_start_distance_to_vacancy_A")
        out.update({f"model_{k}": v for k, v in model.summary().items()})
        out.update({"region": region, "r_atomistic_A": r_atomistic,
                    "step_crossing": step_crossing, "dof": model.dof})
        out.update(crack_metrics(model, res))
        dref = ref.get("damage", {})
        out["crack_angle_lammps_deg"] = dref.get("crack_angle_to_axis_deg")
        out["first_damage_strain_lammps"] = dref.get("first_damage_strain")
        res["_atom_damage"] = out.pop("_atom_damage")
    if outdir is not None and plot:
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        name = f"dcbr_{'dynamic' if dynamic else 'tension'}_{n}_{m}" \
            f"{'_vac4' if vacancy else ('_pristine' if dynamic else '')}"
        plot_comparison(res, ref, out, outdir / f"{name}_K{coarsening:g}.png", model)
    out["_curve"] = res["curve"]
    return out



def reference_grip_planes(ref) -> tuple[float, float]:
    """The LAMMPS run's grip planes on the built tube's lattice (reference z, Å).

    LAMMPS's planes lie 50 Å inside its end atoms after the open-tube minimisation; which
    atoms end its tube depends on the periodic wrap after its zero-stress relaxation (the
    builder's layer at z = 0 sits on the cell boundary: it went to the top of the (10,10) and
    (17,0) tubes, not of the (12,6) one) and on the end atoms' relaxation (0.2-0.3 Å), so
    where the planes cut the lattice (for (17,0): across the inclined or the axial bonds)
    is an accident of the set-up that the coarse ends do not carry. The coarse scene holds
    the same atoms: its planes are LAMMPS's, recovered from the stored extensometer window
    (marks a quarter of the gauge inside the planes) and mapped back by the relaxed axial
    stretch L0 / built length (relaxation scales z about z = 0; the fit of the dumps' first
    frame to the built positions gives an offset of < 1e-3 Å)."""
    from upscale.analysis.stress import EXTENSOMETER_MARGIN

    pd = ref["protocol_detail"]
    lo, hi = pd["extensometer"]["window_A"]
    mg = pd["extensometer"].get("margin_of_gauge", EXTENSOMETER_MARGIN)
    g = (hi - lo) / (1.0 - 2.0 * mg)
    zb, zt = lo - mg * g, hi + mg * g
    if abs(g - pd["gauge_length_A"]) > 1e-6:
        raise ValueError(f"reference gauge {pd['gauge_length_A']} Å vs {g} Å from its "
                         "extensometer window; valid: a reference with a consistent record")
    s = ref["structure"]["length_built_A"] / ref["relaxation"]["L0_A"]
    return zb * s, zt * s


def reference_held_planes(z, planes) -> tuple[float, float]:
    """Where LAMMPS's grips take hold, for clamped coarse grips (reference z, Å).

    ``z``: the built lattice's atoms' axial coordinates; ``planes``: LAMMPS's grip planes on
    it (:func:`reference_grip_planes`). A grip holds the atoms beyond its plane, and the free
    part begins at the innermost of them: a lattice stretched uniformly between two held
    layers strains every bond across them as the rest, so the held layers' distance is the
    free length (in one dimension exactly the chain between its held atoms). A clamped
    coarse grip counts its held rows as sitting at its plane
    (:meth:`~upscale.models.dcbr_defect.DCBRDefectTube.clamp_grips`), so its plane goes there.
    How far LAMMPS's planes lie inside those atoms depends on where they cut the lattice:
    (17,0) 0.54 Å at each end, which with the coarse tube's own planes (50 Å inside its own
    end atoms, whose bottom layer LAMMPS's periodic wrap had put at the top) made the coarse
    gauge 2.3 % longer than LAMMPS's and the modulus by grip separation 2.3 % higher at the
    same grip stiffness."""
    z = np.asarray(z, dtype=float)
    lo, hi = z[z < planes[0]], z[z > planes[1]]
    if not (len(lo) and len(hi)):
        raise ValueError(f"planes={planes!r} hold no atom of a tube spanning "
                         f"{z.min():.2f}..{z.max():.2f} Å; valid: planes inside the tube")
    return float(lo.max()), float(hi.min())


def tube_z_range(model, y):
    """Axial extent of the tube: its living, carrying particles (a failed or slave particle
    can leave with the atoms it follows after the break)."""
    yp = model.particle_positions(y) if hasattr(model, "particle_positions") else y
    keep = model.alive & ~getattr(model, "is_slave", np.zeros(model.N, bool))
    if not keep.any():  # a pristine periodic tube fails everywhere at once: all of them
        keep = np.ones(model.N, bool)
    return float(yp[keep, 2].min()), float(yp[keep, 2].max())


def crack_metrics(model, res) -> dict:
    """Damage of the free atoms at the last step and the crack line through the damaged ones
    (unrolled wall, the references' convention: 90 deg = across the axis)."""
    from upscale.analysis.damage import crack_line, split_along_axis

    Lz = res["curve"]["Lz_A"][-1]
    mu = model.atom_damage(res["positions"], res["delta"], Lz)
    xf, _ = model.atom_positions(res["positions"], res["delta"], Lz)
    # the axis through the particles' centroid (an atom thrown off moves the free atoms' one)
    c = model.particle_positions(res["positions"])[:, :2].mean(axis=0)
    th = np.unwrap(np.arctan2(xf[:, 1] - c[1], xf[:, 0] - c[0]))
    R = res["radius_relaxed_A"]
    s_, z_ = R * ((th - model.vacancy_theta_z[0] + np.pi) % (2 * np.pi) - np.pi), xf[:, 2]
    # atoms thrown off the wall after fracture are left out (the references' rule)
    on_wall = np.abs(np.hypot(xf[:, 0] - c[0], xf[:, 1] - c[1]) - R) < 3.0
    # and those beyond the tube's ends
    z0, z1 = tube_z_range(model, res["positions"])
    on_wall &= (xf[:, 2] > z0) & (xf[:, 2] < z1)
    dmg = (mu > 0) & on_wall
    out = {"_atom_damage": mu, "damaged_atoms": int(dmg.sum()),
           "ejected_atoms": int((~on_wall).sum())}
    # the references' rule (validation.cases.references): damaged atoms separated by axial
    # gaps > 5 Å are separate cracks (or the two faces of an opened one), each fitted by its
    # own line; the one nearest the vacancy is reported
    zv = model.vacancy_theta_z[1] * Lz / model.L
    groups = [g for g in split_along_axis(z_[dmg], gap=5.0) if len(g) >= 2]
    if groups:
        lines = [crack_line(s_[dmg][g], z_[dmg][g], weights=mu[dmg][g]) for g in groups]
        line = lines[int(np.argmin([abs(ln["centre_z_A"] - zv) for ln in lines]))]
        out["crack_angle_deg"] = line["angle_to_axis_deg"]
        out["n_cracks"] = len(lines)
        out["crack_centre_to_vacancy_A"] = float(np.hypot(line["centre_s_A"],
                                                          line["centre_z_A"] - zv))
    else:
        out["crack_angle_deg"] = None
    return out


def plot_comparison(res, ref, out, path, model):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref_png = (ref.get("damage") or {}).get("damage_map_png")
    ref_png = (ROOT / ref_png) if ref_png else None
    side = ref_png is not None and ref_png.exists()  # LAMMPS's damage map beside ours
    fig, ax = plt.subplots(1, 3 if side else 2, figsize=(17 if side else 11, 4.2),
                           gridspec_kw={"width_ratios": [1, 1, 1.2]} if side else None)
    ax[0].plot(ref["curve"]["strain"], ref["curve"]["stress_GPa"], "k-o", ms=3, label="LAMMPS")
    ax[0].plot(res["curve"]["strain"], res["curve"]["stress_GPa"], "b-s", ms=3,
               label=f"DCBR, coarsening {out['coarsening']:g} ({out['particles']} particles)")
    ax[0].set_xlabel("axial strain")
    ax[0].set_ylabel("stress (GPa, t = 3.4 Å)")
    ax[0].set_title(f"({out['chirality']}) {out['protocol']} tension, {out['atoms']} atoms")
    ax[0].legend()
    yp = model.particle_positions(res["positions"]) if hasattr(model, "particle_positions") \
        else res["positions"]
    c = yp[:, :2].mean(axis=0)
    th = np.degrees(np.arctan2(yp[:, 1] - c[1], yp[:, 0] - c[0]))
    z0, z1 = tube_z_range(model, res["positions"])
    inside = (yp[:, 2] >= z0) & (yp[:, 2] <= z1)  # particles that left the tube not shown
    sc = ax[1].scatter(yp[inside, 2], th[inside], c=np.asarray(res["damage"])[inside], vmin=0,
                       vmax=1, cmap="viridis", s=18)
    if "_atom_damage" in res:  # the free atoms of the atomistic region
        xf, _ = model.atom_positions(res["positions"], res["delta"], res["curve"]["Lz_A"][-1])
        tha = np.degrees(np.arctan2(xf[:, 1] - c[1], xf[:, 0] - c[0]))
        keep = (np.abs(np.hypot(xf[:, 0] - c[0], xf[:, 1] - c[1]) - out["radius_A"]) < 3.0) \
            & (xf[:, 2] > z0) & (xf[:, 2] < z1)  # not thrown off
        ax[1].scatter(xf[keep, 2], tha[keep], c=res["_atom_damage"][keep], vmin=0, vmax=1,
                      cmap="viridis", s=6, marker=".")
        if out.get("crack_angle_deg") is not None:
            ax[1].set_title(f"damage at the last step; crack {out['crack_angle_deg']:.0f}° to the "
                            f"axis (LAMMPS {out.get('crack_angle_lammps_deg') or float('nan'):.0f}°)")
    fig.colorbar(sc, ax=ax[1], label="damage mu = 1 - R/T (eq. 5.16)")
    if side:
        ax[2].imshow(plt.imread(ref_png))
        ax[2].set_axis_off()
        ax[2].set_title(f"LAMMPS damage map ({ref_png.name})")
    ax[1].set_xlabel("z (Å)")
    ax[1].set_ylabel("theta (deg)")
    if "_atom_damage" not in res or out.get("crack_angle_deg") is None:
        ax[1].set_title("DCBR damage at the last step")
    fig.tight_layout()
    from upscale.io import atomic_write_bytes
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())



def quasi_static_tension_engine(tube, strain_step: float = 0.005, max_strain: float = 0.40,
                                gtol: float = 1e-6, after_failure: int = 1,
                                fit_max_strain: float = 0.02, progress=None,
                                checkpoint=None, output=None,
                                shift_gtol: float = 1e-10, resume: bool = False) -> dict:
    """Quasi-static axial tension of the periodic coarse tube on the engine (the LAMMPS
    runners' protocol).

    Zero-stress relaxation over positions, sublattice shifts and the cell length gives L0
    and R (mean wall radius); at eps_k = k ``strain_step`` the cell is set to L0 (1 + eps_k),
    the particles mapped affinely along z, the energy minimised at fixed cell, the failure
    rules applied and the minimisation repeated until no link breaks; stress
    sigma = (dE/dLz) / (2 pi R t), t = 3.4 Å. It stops ``after_failure`` steps after the
    first drop of more than 5 % below the running maximum (1, as the references' runner, so
    the last state, which the damage map and crack line are read from, is the step of
    LAMMPS's last frame), or at ``max_strain``. The tube runs as an engine model
    (:class:`upscale.models.dcbr.DCBRTubeModel`: shifts relaxed at every configuration) in
    a :class:`~upscale.engine.simulation.Simulation`, every load step minimised by the
    engine's L-BFGS-B
    (:class:`upscale.engine.minimisers.LBFGS`, memory 30, ``ftol = sqrt(3) gtol`` so that
    its per-component gradient test is ``gtol`` eV/Å, line searches of at most 20
    steps and a stop once an iteration lowers the energy by a relative 1e-15
    (``energy_rtol``), as in :meth:`DCBRTube.minimise`). The last matters after the peak:
    where a pair sits at the step cut-off the force test cannot be met, and without the
    energy test each minimisation went on through failed line searches, ended elsewhere
    and left forces that cost the vacancy tube its damped restarts; with it the vacancy
    tube's run was the tube's own load-step loop's computation (deleted since), bit for
    bit. The
    zero-stress relaxation, which also relaxes the cell length, is
    :meth:`DCBRTube.minimise` (``relax_box=True``): the cell length is not an engine
    variable. ``checkpoint``: a :class:`~upscale.engine.checkpoint.Checkpoint` written at
    every load step (state, shifts, links, the load step in its meta); ``output``: an
    :class:`~upscale.engine.output.Output` written at every load step (extxyz and VTK
    frames with displacement and the links' damage; ``state.step`` counts load steps).
    ``shift_gtol``: tolerance of the shifts' relaxation at every configuration (eV/Å).
    ``resume``: continue from ``checkpoint`` (if its file exists) after its load step; every
    load step's minimisation starts afresh, so the resumed run ends bit for bit where the
    uninterrupted one does.

    The vacancy tube (:class:`~upscale.models.dcbr_defect.DCBRDefectTube`, periodic,
    ``step_crossing="damped"``) runs through the same loop as the engine model
    :class:`~upscale.models.dcbr_engine.DCBRDefectTubeModel` (rows: its particles, the slaves
    tied to their atoms, then its free atoms): its zero-stress relaxation is its own
    ``minimise(relax_box=True)``; at every load step its ghost-force correction is taken at
    the new cell length (``prepare_step``, :meth:`~DCBRDefectTubeModel.store_ghost`); the
    engine's L-BFGS-B minimises the positions and the shifts together (the shifts its
    internal field, :meth:`~DCBRDefectTubeModel.static_shifts`, within the tube's
    ``shift_bound``), with the rigid turn about the axis held by bounds
    (:meth:`~DCBRDefectTubeModel.rotation_pins`); while a force component above 1e-4 eV/Å is
    left, the tube's damped dynamics and L-BFGS-B again, at most 3 times (its
    ``minimise``); the failure rules are the link rule and, where no link broke, the
    stability rule (:meth:`~DCBRDefectTubeModel.break_links_in_turn`). ``positions`` and
    ``delta`` are then the tube's unknowns (non-slave particles, then free atoms) and
    shifts; ``checkpoint`` / ``resume`` are for the pristine tube only.

    Returns a dict: ``curve`` (strain, stress_GPa, energy_eV, Lz_A, damage_max,
    broken_links), the metrics of :func:`upscale.analysis.stress.curve_metrics`, ``L0_A``,
    ``radius_relaxed_A``, ``area_A2``, ``dof``, ``particles``, ``atoms``, the final
    ``damage`` (N,), ``positions``, ``delta``, ``wall_s``, and
    ``minimiser`` (iterations and force evaluations in all, load steps whose minimisation
    ended above its tolerance).
    """
    import math

    from upscale.analysis.stress import curve_metrics
    from upscale.constants import CARBON_MASS_AMU, EV_PER_A3_IN_GPA, WALL_THICKNESS_A
    from upscale.engine.minimisers import LBFGS
    from upscale.engine.simulation import Simulation
    from upscale.engine.system import ParticleSystem
    from upscale.models.dcbr import DCBRTubeModel
    from upscale.models.dcbr_defect import DCBRDefectTube

    if not (0 < strain_step < max_strain <= 2.0):
        raise ValueError(f"strain_step={strain_step}, max_strain={max_strain}; valid: "
                         "0 < strain_step < max_strain <= 2")
    defect = isinstance(tube, DCBRDefectTube)
    if defect and (checkpoint is not None or resume):
        raise ValueError("checkpoint / resume with a DCBRDefectTube; valid: the pristine "
                         "DCBRTube (the defect tube's quasi-static run is not checkpointed)")
    if defect and (tube.step_crossing != "damped" or not tube.periodic):
        raise ValueError(f"a DCBRDefectTube with step_crossing={tube.step_crossing!r}, "
                         f"periodic={tube.periodic}; valid: the periodic tube with "
                         "step_crossing='damped'")
    t0 = time.perf_counter()
    restored = None
    if resume and checkpoint is not None and checkpoint.path.is_file():
        from upscale.engine.checkpoint import load_checkpoint

        restored = load_checkpoint(checkpoint.path, tube.x0)
        if restored[1].get("scene") != "tube quasi-static tension":
            raise ValueError(f"checkpoint {checkpoint.path} is not of a tube quasi-static "
                             f"tension ({restored[1].get('scene')!r})")
        y, d, L0 = restored[0].y, restored[0].extra["dcbr.delta"], restored[1]["L0_A"]
    else:
        r0 = tube.minimise(getattr(tube, "y_init", tube.x0), tube.delta, tube.L,
                           relax_box=True, gtol=gtol)
        y, d, L0 = r0.y, r0.delta, r0.Lz
    R = tube.radius(y, d) if restored is None else restored[1]["radius_relaxed_A"]
    area = 2 * math.pi * R * WALL_THICKNESS_A
    lbfgs = LBFGS(ftol=math.sqrt(3.0) * gtol, max_iter=5000, memory=30, maxls=20,
                  energy_rtol=1e-15)
    if defect:  # the rows: particles (slaves tied to their atoms), then the free atoms
        from upscale.models.dcbr_engine import DCBRDefectTubeModel

        model = DCBRDefectTubeModel(tube, y=y, delta=d, Lz=L0)
        sim = Simulation(model.system(), None, model, model.conditions())
        model.static_shifts(sim.state)  # minimised with the positions
        pins = model.rotation_pins()  # the rigid turn about the axis held
    else:
        # a particle's mass: its atoms (volume = atoms, density = the carbon mass)
        system = ParticleSystem(tube.x0, tube.natoms_n, CARBON_MASS_AMU,
                                spacing=float(min(tube.spacing)), units="atomic")
        model = DCBRTubeModel(tube, shift_gtol=shift_gtol)
        sim = Simulation(system, None, model)
        sim.state.y[...] = y
        sim.state.extra["dcbr.delta"][...] = d

    def relax():  # one minimisation at the current cell: (iterations, evaluations, converged)
        if not defect:
            r = sim.minimise(lbfgs, raise_on_fail=False)
            return r.iterations, r.n_force, r.converged
        lbfgs.bounds = (np.where(pins, sim.state.y, -np.inf), np.where(pins, sim.state.y, np.inf))
        r = sim.minimise(lbfgs, raise_on_fail=False)
        it, nf = r.iterations, r.n_force
        # the tube's restarts (DCBRDefectTube.minimise, step_crossing "damped"): while a
        # force component above 1e-4 eV/Å is left (a pair held at the step cutoff), damped
        # dynamics, which goes through the step, then L-BFGS again; at most 3 cycles
        for _ in range(3):
            if model.max_force(sim.state) <= 1e-4:
                break
            model.damped_relax(sim.state, pins)
            lbfgs.bounds = (np.where(pins, sim.state.y, -np.inf),
                            np.where(pins, sim.state.y, np.inf))
            r = sim.minimise(lbfgs, raise_on_fail=False)
            it, nf = it + r.iterations, nf + r.n_force
        return it, nf, r.converged

    break_links = model.break_links_in_turn if defect else model.break_bonds
    strains, stresses, energies, lzs, dmax, nbroken = [], [], [], [], [], []
    k, failed_at, Lprev = 0, None, L0
    n_it = n_f = unconverged = 0
    if restored is not None:
        st0, meta = restored
        sim.state.extra["dcbr.intact"][...] = st0.extra["dcbr.intact"]
        sim.state.extra["dcbr.alive"][...] = st0.extra["dcbr.alive"]
        c = meta["curve"]
        strains, stresses, energies = c["strain"], c["stress_GPa"], c["energy_eV"]
        lzs, dmax, nbroken = c["Lz_A"], c["damage_max"], c["broken_links"]
        k, failed_at, Lprev = meta["load_step"] + 1, meta["failed_at"], meta["cell_length_A"]
        n_it, n_f, unconverged = meta["iterations"], meta["force_evaluations"], meta["unconverged"]
        if failed_at is not None and k - 1 - failed_at >= after_failure:
            k = None  # the run had ended
    while k is not None:
        eps = k * strain_step
        if eps > max_strain + 1e-12:
            break
        Lz = L0 * (1.0 + eps)
        sim.state.y[:, 2] *= Lz / Lprev
        Lprev = Lz
        model.set_cell(Lz)
        if defect:  # the ghost-force correction of this load step
            tube.prepare_step(Lz)
            model.store_ghost(sim.state)
        for _ in range(4 * tube.N + 10):
            it, nf, ok = relax()
            n_it, n_f = n_it + it, n_f + nf
            unconverged += not ok
            nb = break_links(sim.state)
            if nb == 0 or not tube.alive.any():
                break
        s = model.cell_force(sim.state) / area * EV_PER_A3_IN_GPA
        strains.append(eps)
        stresses.append(float(s))
        energies.append(model.energy(sim.state))
        lzs.append(float(Lz))
        dmax.append(float(tube.damage.max()))
        nbroken.append(int((~tube.intact).sum()))
        sim.state.step = k
        if failed_at is None and s < 0.95 * max(stresses) and max(stresses) > 0:
            failed_at = k
        if checkpoint is not None:
            checkpoint.write(sim.state, {
                "scene": "tube quasi-static tension", "load_step": k, "strain": eps,
                "cell_length_A": Lz, "L0_A": float(L0), "radius_relaxed_A": R,
                "failed_at": failed_at, "iterations": n_it, "force_evaluations": n_f,
                "unconverged": unconverged,
                "curve": {"strain": strains, "stress_GPa": stresses, "energy_eV": energies,
                          "Lz_A": lzs, "damage_max": dmax, "broken_links": nbroken}})
        if output is not None:
            output.write(sim)
        if progress is not None:
            progress(eps, s)
        if failed_at is not None and k - failed_at >= after_failure:
            break
        k += 1
    res = {"model": "dcbr", "driver": "engine", "protocol": "quasi-static",
           "chirality": [tube.lattice.n, tube.lattice.m], "coarsening": tube.coarsening,
           "particles": tube.N, "dof": getattr(tube, "dof", 3 * tube.N),
           "internal_dof": 3 * tube.N if tube.relax_shift else 0,
           "atoms": tube.n_atoms, "L0_A": float(L0), "radius_relaxed_A": R, "area_A2": area,
           "area": "2 pi R t, R = mean wall radius after zero-stress relaxation, t = 3.4 A",
           "strain_step": strain_step,
           "curve": {"strain": strains, "stress_GPa": stresses, "energy_eV": energies,
                     "Lz_A": lzs, "damage_max": dmax, "broken_links": nbroken},
           "minimiser": {"iterations": n_it, "force_evaluations": n_f,
                         "minimisations_above_tolerance": unconverged}}
    res.update(curve_metrics(strains, stresses, fit_max_strain=fit_max_strain))
    res["damage"] = tube.damage
    if defect:  # the tube's unknowns (non-slave particles, then free atoms) and shifts
        yu, du = model.unknowns(sim.state)
        res["positions"], res["delta"] = yu, np.array(du, copy=True)
    else:
        res["positions"] = sim.state.y.copy()
        res["delta"] = sim.state.extra["dcbr.delta"].copy()
    res["wall_s"] = time.perf_counter() - t0
    return res


def defect_nve(n: int, m: int, length: float, coarsening: float, *, steps: int = 10000,
               dt_fs: float = 1.0, temperature: float = 10.0, seed: int = 7,
               progress: bool = False) -> dict:
    """NVE of the periodic coupled (n, m) tube with the vacancy (atomistic band, pads, slaves,
    ghost correction at the zero-stress state) from Gaussian velocities at ``temperature``
    K: the total energy's drift.

    The time loop is the engine's velocity Verlet (``dt_fs`` fs) on the tube's engine model
    (:class:`upscale.models.dcbr_engine.DCBRDefectTubeModel`: the shifts a field with
    inertia, the slave particles tied to their atoms); the energy counts the unknowns' and
    the shifts' kinetic energy (a slave's velocity follows its atoms'), sampled every 100
    steps. Returns ``drift_final_rel_to_kinetic`` and ``max_abs_deviation_rel_to_kinetic``
    (E - E0 over the initial kinetic energy), ``initial_kinetic_eV``, ``dof``, ``wall_s``.
    """
    from upscale.constants import ACC_EV_A_AMU_IN_A_FS2, K_B_EV
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.simulation import Simulation
    from upscale.models.dcbr_defect import DCBRDefectTube
    from upscale.models.dcbr_engine import FIELD, DCBRDefectTubeModel

    if not (steps >= 10 and dt_fs > 0 and temperature > 0):
        raise ValueError(f"steps={steps}, dt_fs={dt_fs}, temperature={temperature}; valid: "
                         "steps >= 10, dt_fs > 0, temperature > 0")
    model = DCBRDefectTube(n, m, length, coarsening=coarsening)
    r0 = model.minimise(None, None, None, relax_box=True, gtol=1e-6)
    y, d, Lz = r0.y, r0.delta, r0.Lz
    acc, kB, dt = ACC_EV_A_AMU_IN_A_FS2, K_B_EV, dt_fs
    mass, mass_d = model.masses()
    rng = np.random.default_rng(seed)
    v = rng.standard_normal(y.shape) * np.sqrt(kB * temperature * acc / mass)[:, None]
    v -= np.sum(mass[:, None] * v, axis=0) / mass.sum()
    vd = rng.standard_normal(d.shape) * np.sqrt(kB * temperature * acc / mass_d)[:, None]
    vd[model.slave_idx] = 0.0
    em = DCBRDefectTubeModel(model, y=y, delta=d, Lz=Lz)
    sim = Simulation(em.system(), None, em, em.conditions(),
                     VelocityVerlet(dt, force=True))
    st = sim.state
    st.v[em.y_rows] = v
    if len(model.slave_idx):
        st.v[model.slave_idx] = model.Phi @ v[len(model.dof_idx):]
    st.field_v[FIELD][:model.N] = vd

    def total():
        vv, ww = st.v[em.y_rows], st.field_v[FIELD][:model.N]
        return em.energy(st) + 0.5 * (np.sum(mass[:, None] * vv * vv)
                                      + np.sum(mass_d[:, None] * ww * ww)) / acc

    e0, k0 = total(), 0.5 * np.sum(mass[:, None] * v * v) / acc
    dev = []

    def every_100(sim_):
        if sim_.state.step % 100 == 0:
            dev.append((total() - e0) / k0)
    t0 = time.perf_counter()
    sim.run(steps, callback=every_100, progress=progress)
    wall = time.perf_counter() - t0
    dev = np.array(dev)
    return {"chirality": f"{n},{m}", "coarsening": coarsening, "steps": steps, "dt_fs": dt,
            "dof": model.dof, "initial_kinetic_eV": float(k0),
            "drift_final_rel_to_kinetic": float(dev[-1]),
            "max_abs_deviation_rel_to_kinetic": float(np.abs(dev).max()), "wall_s": wall}
