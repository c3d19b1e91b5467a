"""``experiments.tension``: one single-wall carbon tube under a loading protocol.

The structure is any ``ase.Atoms`` of one carbon tube along z (a file ASE reads, or
:func:`upscale.build.swcnt` with defects from :mod:`upscale.defects`); the model is
``atomistic`` (the engine's Tersoff on every atom, :mod:`.tube_atomistic`), ``dcbr`` (the
coarse tube) or ``lammps`` (the reference backend, :mod:`upscale.experiments.lammps`).
The protocol objects of :mod:`upscale.experiments.protocols` are built here from the
scene's parameters, so every model runs the same one.

Figures (:func:`tube_result`): ``strength_GPa``, ``strain_at_peak``, ``youngs_TPa``
(tension and compression, :func:`upscale.experiments.protocols.curve_figures`; compression
negative), ``peak_torque_eV`` and ``twist_at_peak_deg`` (torsion), and where the tube
failed: ``failure_z_A``, ``failure_angle_deg``, the median axial position and azimuth, in
the reference configuration, of the atoms (or particles) whose bonds broke between the
peak and the last record. Stress on the wall area 2 pi R t, t = 3.4 Å, R the mean wall
radius after the zero-stress relaxation.
"""
from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from upscale.experiments.protocols import Dynamic, QuasiStatic, curve_figures, ramp
from upscale.experiments.result import Result, Timer, make_meta

__all__ = ["tension", "tube_structure", "make_protocol", "tube_result", "MODELS"]

#: the models the tube scene takes
MODELS = ("dcbr", "atomistic", "lammps")

#: load parameter defaults per load: (step, maximum)
_RAMP = {"tension": (0.005, 0.40), "compression": (0.005, 0.40), "torsion": (1.0, 120.0)}

#: the quasi-static imperfection per load, Å (QuasiStatic.perturb): torsion has no defect to
#: pick its buckling mode; 1e-2 Å is large enough that a relaxation stopped at 1e-6 eV/Å
#: leaves the unstable branch at the step where it becomes unstable (as LAMMPS's CG does)
_PERTURB = {"torsion": 1e-2}

#: the gripped length at each end where the protocol needs grips, Å
_GRIP = {"torsion": 10.0, "dynamic": 50.0}


def tension(structure=None, *, chirality: tuple[int, int] = (10, 10), length: float = 100.0,
            defects: str = "", model: Literal["dcbr", "atomistic", "lammps"] = "dcbr",
            coarsening: float = 2.0,
            protocol: Literal["quasi-static", "dynamic"] = "quasi-static",
            load: Literal["tension", "compression", "torsion"] = "tension",
            step: float | None = None, maximum: float | None = None,
            grip: float | None = None, perturb: float | None = None,
            temperature: float = 10.0, seed: int = 1, seeds: int = 1,
            potential: str = "BNC.tersoff", reference: bool = True,
            checkpoint_every: int = 1000, resume: bool = False, workdir: str | None = None,
            progress: bool = True) -> Result:
    """One tube under a loading protocol (module docstring).

    Parameters
    ----------
    structure : ase.Atoms, optional
        the tube (any structure ASE reads); default built from ``chirality``, ``length``
        and ``defects``.
    chirality : tuple of int
        (n, m) of the built tube.
    length : float
        length of the built tube, Å.
    defects : str
        comma list of KIND@ZFRAC@ANGLE placed on the built tube (KIND v1, v2, v4, sw,
        adatom; ZFRAC the axial fraction 0..1; ANGLE the azimuth, degrees).
    model : {"dcbr", "atomistic", "lammps"}
        the coarse tube, the engine's Tersoff on every atom, or LAMMPS.
    coarsening : float
        particle spacing over lattice constant of the coarse tube (dcbr only).
    protocol : {"quasi-static", "dynamic"}
        a ramp with relaxations, or grips pulled at a speed with a thermostat.
    load : {"tension", "compression", "torsion"}
        axial strain (compression negative) or twist of one grip against the other.
    step : float, optional
        load increment per step: strain (default 0.005) or degrees (default 1).
    maximum : float, optional
        largest load: strain (default 0.40) or degrees (default 120).
    grip : float, optional
        gripped length at each end, Å (default: none for a periodic ramp, 10 for torsion,
        50 for a dynamic pull).
    perturb : float, optional
        quasi-static imperfection, Å: seeded random displacements of the free atoms before
        every relaxation (default 1e-2 in torsion, which has no defect to pick its buckling
        mode; 0 otherwise).
    temperature : float
        thermostat temperature of a dynamic pull, K.
    seed : int
        seed of a dynamic pull's thermal start (and of a quasi-static imperfection).
    seeds : int
        runs on seeds ``seed, seed + 1, ...``: the figures are their means (each figure's
        standard deviation as ``<figure>_sd``, every run's figures in the curve table
        ``seeds/``), the curve and fields the first run's.
    potential : str
        LAMMPS .tersoff file of the atoms (default the references' BNC.tersoff, step cutoff).
    checkpoint_every : int
        dynamic pull on the engine: a checkpoint every this many steps in
        ``workdir/tension_seed<SEED>.npz`` (only with ``workdir``).
    resume : bool
        continue each seed's pull from its checkpoint where there is one (bit for bit;
        needs ``workdir``).
    workdir : str, optional
        folder of the checkpoints.
    reference : bool
        model lammps: run LAMMPS where no stored or cached run matches (its estimated cost
        printed first; the run cached in ~/.cache/upscale); False: only stored or cached
        runs (a missing one is a LookupError).
    progress : bool
        print one line per load step.
    """
    if model not in MODELS:
        raise ValueError(f"model={model!r}; valid: {', '.join(MODELS)}")
    if not (isinstance(seeds, (int, np.integer)) and seeds >= 1):
        raise ValueError(f"seeds={seeds!r}; valid: an integer >= 1 (runs on seed, seed + 1, ...)")
    if not (isinstance(checkpoint_every, (int, np.integer)) and checkpoint_every >= 1):
        raise ValueError(f"checkpoint_every={checkpoint_every!r} steps; valid: an integer >= 1")
    if resume and workdir is None:
        raise ValueError("resume=True needs a workdir (the folder of the checkpoints)")
    params = dict(chirality=tuple(chirality), length=length, defects=defects, model=model,
                  checkpoint_every=checkpoint_every, resume=resume, workdir=workdir,
                  reference=reference,
                  coarsening=coarsening, protocol=protocol, load=load, step=step,
                  maximum=maximum, grip=grip, perturb=perturb, temperature=temperature,
                  seed=seed, seeds=seeds, potential=potential)
    protos = [make_protocol(protocol, load, step=step, maximum=maximum, grip=grip,
                            perturb=perturb, temperature=temperature, seed=seed + k)
              for k in range(seeds)]
    atoms = tube_structure(structure, chirality, length, defects)
    if structure is not None:
        params["structure"] = f"Atoms({atoms.get_chemical_formula()})"
    show = _printer(progress, model)
    results = []
    for proto in protos:
        ck = None
        if workdir is not None and isinstance(proto, Dynamic) and model != "lammps":
            Path(workdir).mkdir(parents=True, exist_ok=True)
            ck = {"path": Path(workdir) / f"tension_seed{proto.seed}.npz",
                  "every": int(checkpoint_every), "resume": bool(resume)}
        with Timer() as timer:
            if model == "atomistic":
                run = _run_atomistic(atoms, proto, potential, show, ck)
            elif model == "lammps":
                run = _run_lammps(atoms, proto, potential, reference)
            else:
                run = _run_dcbr(atoms, proto, coarsening, potential, show, ck)
        results.append(tube_result(run, proto, params, timer))
    return results[0] if seeds == 1 else seed_means(results)


def seed_means(results: list) -> Result:
    """One :class:`Result` of runs on several seeds (:func:`tension`'s ``seeds``)."""
    first = results[0]
    figs, curves = {}, dict(first.curves)
    curves["seeds/seed"] = np.array([r.meta["protocol"]["seed"] for r in results], float)
    for k, v in first.figures.items():
        vals = np.array([r.figures[k] for r in results], dtype=float)
        curves[f"seeds/{k}"] = vals
        figs[k] = float(np.mean(vals)) if k != "failed" else bool(vals.all())
        if k not in ("failed", "atoms", "particles", "dof"):
            figs[f"{k}_sd"] = float(np.std(vals, ddof=1))
    meta = dict(first.meta)
    meta["seeds"] = [int(s) for s in curves["seeds/seed"]]
    meta["wall_s"] = float(sum(r.meta["wall_s"] for r in results))
    return Result(figures=figs, curves=curves, fields=dict(first.fields), meta=meta)


def make_protocol(protocol: str, load: str, *, step=None, maximum=None, grip=None,
                  perturb=None, temperature=10.0, seed=1):
    """The protocol object of the tube scene's parameters (defaults per load)."""
    if protocol not in ("quasi-static", "dynamic"):
        raise ValueError(f"protocol={protocol!r}; valid: quasi-static, dynamic")
    if load not in _RAMP:
        raise ValueError(f"load={load!r}; valid: {', '.join(_RAMP)}")
    s0, m0 = _RAMP[load]
    step = s0 if step is None else step
    maximum = m0 if maximum is None else maximum
    if protocol == "dynamic":
        return Dynamic(load=load, grip=_GRIP["dynamic"] if grip is None else grip,
                       maximum=maximum, temperature=temperature, seed=seed)
    grip = _GRIP.get(load, 0.0) if grip is None else grip
    perturb = _PERTURB.get(load, 0.0) if perturb is None else perturb
    return QuasiStatic(load=load, step=step, maximum=maximum, periodic=not grip, grip=grip,
                       perturb=perturb, seed=seed)


def tube_structure(structure, chirality, length, defects: str = ""):
    """The scene's tube: ``structure`` checked (carbon only), or built and defected."""
    if structure is None:
        from upscale.build import swcnt

        n, m = (int(v) for v in chirality)
        structure = swcnt(n, m, length=float(length))
        if defects:
            from upscale.defects import apply_defects

            structure = apply_defects(structure, defects)
    elif defects:
        from upscale.defects import apply_defects

        structure = apply_defects(structure, defects)
    sym = set(structure.get_chemical_symbols())
    if sym != {"C"}:
        raise ValueError(f"structure has elements {sorted(sym)}; valid: carbon only (C)")
    if len(structure) < 20:
        raise ValueError(f"structure has {len(structure)} atoms; valid: a tube of >= 20 atoms")
    return structure


# --------------------------------------------------------------------- the three models
def _run_atomistic(atoms, proto, potential, show, ck=None) -> dict:
    from upscale.experiments.scenes.tube_atomistic import AtomisticTube

    if isinstance(proto, Dynamic):
        return _pull_atomistic(atoms, proto, potential, show, ck)
    tube = AtomisticTube(atoms, proto, potential)
    out, damage = _ramp_with_damage(tube, proto, show)
    return {"curve": out["curve"], "x0": tube.x_rest, "damage_steps": damage,
            "axis": tube.axis, "radius_A": tube.radius, "dof": 3 * len(atoms),
            "atoms": len(atoms), "particles": len(atoms),
            "minimisations": tube.minimisations, "unconverged": tube.unconverged}


def _ramp_with_damage(tube, proto, show):
    """:func:`ramp` of a specimen with ``damage()``: (its output, the damage after each
    step)."""
    damage = []

    def step(k, value, rec):
        damage.append(tube.damage())
        if show:
            show(value, rec["response"])

    return ramp(tube, proto, progress=step), damage


def _pull_atomistic(atoms, proto, potential, show, ck=None) -> dict:
    """The dynamic pull of the atoms on the engine (:class:`AtomisticPull`); ``ck``: the
    checkpoint's path, interval and whether to resume from it."""
    from upscale.engine.checkpoint import Checkpoint
    from upscale.experiments.pull import pull
    from upscale.experiments.scenes.tube_atomistic import AtomisticPull

    tube = AtomisticPull(atoms, proto, potential)
    out = pull(tube, proto, progress=(lambda r: show(r["load"], r["response"])) if show else None,
               checkpoint=Checkpoint(ck["path"], ck["every"]) if ck else None,
               resume=bool(ck and ck["resume"]))
    recs = out["records"]
    curve = {"load": np.array([r["load"] for r in recs]),
             "response": np.array([r["response"] for r in recs]),
             "time_ps": np.array([r["time_ps"] for r in recs]),
             "broken_bonds": np.array([r["broken_bonds"] for r in recs], dtype=float)}
    return {"curve": curve, "x0": tube.x_rest, "damage_steps": [tube.damage()],
            "axis": tube.axis, "radius_A": tube.radius, "dof": 3 * len(atoms),
            "atoms": len(atoms), "particles": len(atoms), "minimisations": tube.minimisations,
            "steps": out["steps"], "blowup_after_failure": out["blowup_after_failure"]}


def _run_lammps(atoms, proto, potential, run_missing: bool) -> dict:
    """A stored reference of ``data/reference/`` where one matches the structure and the
    protocol, else a cached run (:func:`_cached_lammps`), else a LAMMPS run now."""
    r = _stored_reference(atoms, proto, potential)
    if r is None:
        r = _cached_lammps(atoms, proto, potential, run_missing)
    c = r["curve"]
    x0 = atoms.get_positions()
    onset = r.get("atom_damage_onset")  # where the run kept it (a stored record does not)
    steps = [] if onset is None else \
        [((np.asarray(onset) >= 0) & (np.asarray(onset) <= k)).astype(float)
         for k in range(len(c["load"]))]
    return {"curve": {"load": np.asarray(c["load"]), "response": np.asarray(c["response"])},
            "x0": x0, "damage_steps": steps,
            "axis": x0[:, :2].mean(0), "wall_s": float(r.get("wall_s", np.nan)),
            "radius_A": r.get("relaxation", {}).get("radius_relaxed_A", np.nan),
            "dof": 3 * len(atoms), "atoms": len(atoms), "particles": len(atoms),
            "lammps": r.get("lammps_version"), "source": r.get("_source", "computed now")}


#: LAMMPS's cost per atom and load step on one core of this project's machines, s (measured
#: on the (10,10) tubes: tension, compression, torsion); for the estimate printed before a run
_LAMMPS_S_PER_ATOM_STEP = 5e-3


def _cached_lammps(atoms, proto, potential, run_missing: bool) -> dict:
    """The LAMMPS run of ``atoms`` under ``proto`` from the cache (keyed by a hash of the
    structure, the protocol, the potential and the backend's code), or run now and cached."""
    import dataclasses
    import hashlib
    import json

    from upscale.experiments import lammps
    from upscale.experiments.lammps.cache import cache_dir
    from upscale.io import write_json

    code = hashlib.sha256()
    for f in sorted(Path(lammps.__file__).parent.glob("*.py")):
        code.update(f.read_bytes())
    key = hashlib.sha256(json.dumps({
        "positions": np.round(atoms.get_positions(), 6).tolist(), "cell": atoms.cell.tolist(),
        "pbc": atoms.pbc.tolist(), "numbers": atoms.numbers.tolist(), "potential": potential,
        "protocol": [type(proto).__name__, dataclasses.asdict(proto)],
        "code": code.hexdigest(), "damage": "onset per atom from the dump"},
        sort_keys=True).encode()).hexdigest()[:20]
    path = cache_dir("references") / f"tube_{key}.json"
    if path.is_file():
        return json.loads(path.read_text())
    if not run_missing:
        raise LookupError(f"no stored or cached LAMMPS run of this structure and protocol "
                          f"({path.name}); valid: reference=True (--reference) to run it")
    steps = int(proto.maximum / proto.step) + 1 if isinstance(proto, QuasiStatic) else 0
    if steps:
        est = _LAMMPS_S_PER_ATOM_STEP * len(atoms) * steps
        print(f"LAMMPS reference not stored: running it now ({len(atoms)} atoms, up to "
              f"{steps} load steps: up to about {est / 60:.0f} min on one core; cached in "
              f"{path.parent})", flush=True)
    if isinstance(proto, QuasiStatic) and proto.load != "torsion":
        dump = cache_dir("dumps") / f"tube_{key}.dump"
        r = lammps.run(atoms, proto, potential=f"tersoff:{potential}", dump=dump)
        r["atom_damage_onset"] = damage_onset(dump, len(r["curve"]["load"]))
    else:
        r = lammps.run(atoms, proto, potential=f"tersoff:{potential}")
    write_json(path, r)
    return r


def damage_onset(dump, records: int) -> list[int]:
    """Per atom, the index of the first of the last ``records`` frames of a periodic tube's
    LAMMPS dump (one frame per load step, ``id type x y z``) in which one of its bonds is
    broken: bonds closer than 2.0 Å in the first frame, broken beyond 2.1 Å (minimum image
    along z); -1 where none broke."""
    from ase.io import read

    from upscale.experiments.scenes.tube_atomistic import bond_lengths, bond_pairs

    frames = read(dump, index=":", format="lammps-dump-text")
    bonds = bond_pairs(frames[0].positions, frames[0].cell[2, 2])
    onset = np.full(len(frames[0]), -1, dtype=np.int64)
    for k, f in enumerate(frames[len(frames) - records:]):
        broken = bond_lengths(f.positions, bonds, f.cell[2, 2]) > 2.1
        hit = np.unique(bonds[broken])
        onset[hit[onset[hit] < 0]] = k
    return onset.tolist()


def _stored_reference(atoms, proto, potential) -> dict | None:
    from upscale.experiments.scenes.tube_tension import lammps_reference

    info = atoms.info
    vac = info.get("vacancy")
    if potential != "BNC.tersoff":
        return None
    r = _stored_collection_reference(atoms, proto)
    if r is not None:
        return r
    if info.get("defects"):  # the seed's vacancy placed through `defects`, or none stored
        ch, L = info.get("chirality"), info.get("length")
        if ch is None or L is None or not _is_seed_vacancy(atoms, ch, L):
            return None
        vac = {"n": 4}
    if (info.get("chirality") is None or not isinstance(proto, QuasiStatic)
            or proto.load != "tension" or not proto.periodic or (vac and vac.get("n") != 4)):
        return None
    n, m = info["chirality"]
    try:
        r = lammps_reference(n, m, info["length"], strain_step=proto.step,
                             vacancy=bool(vac), progress=False)
    except LookupError:
        return None
    if len(atoms) != r["structure"]["n_atoms"]:
        return None
    r["curve"] = {"load": r["curve"]["strain"], "response": r["curve"]["stress_GPa"]}
    return r


def _stored_collection_reference(atoms, proto) -> dict | None:
    """The record of a ``data/reference/qs_*.json`` collection (``{"provenance", "tubes":
    [...]}``: tubes built by :func:`tube_structure` from a chirality, a length and a
    defects string, run by the LAMMPS backend) whose protocol is ``proto`` and whose
    structure, rebuilt from its recipe, has ``atoms``' positions (to 1e-6 Å); None where
    none matches."""
    import dataclasses
    import json

    from upscale.experiments.scenes.tube_tension import REFERENCE_DIR

    chir = atoms.info.get("chirality")
    if chir is None or not isinstance(proto, QuasiStatic):
        return None
    want = dataclasses.asdict(proto)
    for path in sorted(Path(REFERENCE_DIR).glob("qs_*.json")):
        tubes = json.loads(path.read_text()).get("tubes")
        for t in tubes if isinstance(tubes, list) else ():
            got = t["lammps"]["protocol"]
            if (tuple(t["chirality"]) != tuple(chir) or len(atoms) !=
                    t["lammps"]["structure"]["n_atoms"]
                    or any(got.get(k) != want[k] for k in ("load", "step", "maximum",
                                                          "periodic", "grip", "perturb"))):
                continue
            built = tube_structure(None, t["chirality"], t["length_A"], t["defects"])
            if np.allclose(built.get_positions(), atoms.get_positions(), atol=1e-6):
                return {**t["lammps"], "_source": f"{path.name}: {t['command']}"}
    return None


def _run_dcbr(atoms, proto, coarsening, potential, show, ck=None) -> dict:
    """The coarse tube: the seed's pristine and 4-atom vacancy tubes in tension on their
    validated scenes (told apart by ``atoms.info`` of :mod:`upscale.build`;
    :func:`quasi_static_tension_engine`, the dynamic pull of :func:`_pull_dcbr`), any other
    structure, and compression, on :class:`~upscale.models.dcbr.model.DCBRModel`
    (:func:`_ramp_coarse`, :func:`_pull_coarse`)."""
    from upscale.experiments.scenes.tube_tension import quasi_static_tension_engine

    qs = isinstance(proto, QuasiStatic)
    if proto.load == "torsion" or (qs and not proto.periodic) or \
            (not qs and proto.load != "tension"):
        raise ValueError(f"model='dcbr' with load={proto.load!r}, protocol={proto.name!r}, "
                         f"periodic={getattr(proto, 'periodic', False)}; valid: periodic "
                         "quasi-static tension or compression, or dynamic tension (the rest: "
                         "model='atomistic' or 'lammps')")
    info = atoms.info
    ch, L = info.get("chirality"), info.get("length")
    vac = info.get("vacancy")
    placed = [d["kind"] for d in info.get("defects", [])]
    if placed and ch is not None and L is not None and _is_seed_vacancy(atoms, ch, L):
        vac, placed = {"n": 4}, []  # (the seed's vacancy, placed through `defects`)
    if ch is None or L is None or placed or (vac and vac.get("n") != 4) or \
            proto.load == "compression":
        if isinstance(proto, Dynamic):
            return _pull_coarse(atoms, proto, coarsening, potential, show, ck)
        return _ramp_coarse(atoms, proto, coarsening, potential, show)
    n, m = ch
    if isinstance(proto, Dynamic):
        return _pull_dcbr(n, m, L, bool(vac), proto, coarsening, potential, show, ck)
    qs = dict(strain_step=proto.step, max_strain=proto.maximum,
              progress=(lambda e, s: show(e, s)) if show else None)
    if vac:
        from upscale.models.dcbr_defect import DCBRDefectTube

        tube = DCBRDefectTube(n, m, L, coarsening=coarsening, vacancy=4,
                              potential=f"tersoff:{potential}")
        res = quasi_static_tension_engine(tube, **qs)
    else:
        from upscale.models.dcbr import DCBRTube

        tube = DCBRTube(n, m, L, coarsening=coarsening, potential=f"tersoff:{potential}")
        res = quasi_static_tension_engine(tube, **qs)
    c = res["curve"]
    x0 = np.asarray(tube.x0)
    return {"curve": {"load": np.asarray(c["strain"]), "response": np.asarray(c["stress_GPa"]),
                      "energy_eV": np.asarray(c["energy_eV"])},
            "x0": x0, "damage_steps": [np.asarray(res["damage"], dtype=float)],
            "axis": x0[:, :2].mean(0), "radius_A": res["radius_relaxed_A"], "dof": res["dof"],
            "atoms": res["atoms"], "particles": res["particles"]}


def _ramp_coarse(atoms, proto, coarsening, potential, show) -> dict:
    """Any periodic tube coarse-grained from its atoms
    (:class:`~upscale.experiments.scenes.tube_coarse.CoarseTube` on
    :class:`~upscale.models.dcbr.model.DCBRModel`: atomistic regions at its defects) under
    the quasi-static ramp."""
    from upscale.experiments.scenes.tube_coarse import CoarseTube

    tube = CoarseTube(atoms, proto, coarsening, potential)
    out, damage = _ramp_with_damage(tube, proto, show)
    d = tube.model.describe()
    return {"curve": out["curve"], "x0": tube.x_rest, "damage_steps": damage,
            "axis": tube.centre[:2], "radius_A": tube.radius, "dof": 6 * tube.model.n,
            "atoms": len(atoms), "particles": d["particles"],
            "minimisations": tube.minimisations, "unconverged": tube.unconverged}


def _pull_coarse(atoms, proto, coarsening, potential, show, ck=None) -> dict:
    """Any tube's dynamic pull on :class:`~upscale.models.dcbr.model.DCBRModel`
    (:func:`~upscale.experiments.scenes.tube_coarse_pull.coarse_dynamic_tension`: the tube
    opened, atomistic bands across the grip planes and regions at its defects)."""
    from upscale.experiments.scenes.tube_coarse_pull import coarse_dynamic_tension

    r = coarse_dynamic_tension(
        atoms, coarsening, grip=proto.grip, speed=proto.speed, dt=proto.dt,
        sample=proto.sample_every, temperature=proto.temperature, tdamp=1e3 * proto.tau,
        seed=proto.seed, max_strain=proto.maximum, potential=potential,
        progress=(lambda rec: show(rec["load"], rec["response"])) if show else None,
        **({"checkpoint": ck["path"], "checkpoint_every": ck["every"], "resume": ck["resume"]}
           if ck else {}))
    c, d = r["curve"], r["describe"]
    return {"curve": {"load": np.asarray(c["strain"]), "response": np.asarray(c["stress_GPa"]),
                      "time_ps": np.asarray(c["time_ps"])},
            "x0": r["x0_rows"], "damage_steps": [np.asarray(r["damage"], float)],
            "axis": np.asarray(r["x0_rows"])[:, :2].mean(0), "radius_A": r["radius_relaxed_A"],
            "dof": 6 * len(r["x0_rows"]), "atoms": len(atoms), "particles": d["particles"],
            "steps": r["steps"], "blowup_after_failure": r["blowup_after_failure"]}


def _is_seed_vacancy(atoms, chirality, length) -> bool:
    """True when ``atoms`` is the built tube less exactly the seed's 4-atom vacancy
    (:func:`upscale.build.vacancy` at its default point), whatever placed it."""
    from upscale.build import swcnt, vacancy

    ref = vacancy(swcnt(*(int(v) for v in chirality), length=float(length)))
    if len(ref) != len(atoms):
        return False
    a, b = (np.round(x.get_positions(), 6) for x in (atoms, ref))
    return bool(np.array_equal(a[np.lexsort(a.T)], b[np.lexsort(b.T)]))


def _pull_dcbr(n, m, length, vacancy, proto, coarsening, potential, show, ck=None) -> dict:
    """The coarse tube's dynamic pull (:func:`~upscale.experiments.scenes.dcbr_dynamic.
    dynamic_tension` on the shared pull), built as ``dcbr-seeds`` builds it
    (:func:`~upscale.experiments.scenes.tube_tension.dynamic_scene`: clamped grips with the
    vacancy, atomistic bands across the grip planes without), on the stored LAMMPS
    reference's grip planes where one of this tube and protocol is stored."""
    from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension
    from upscale.experiments.scenes.tube_tension import dynamic_scene, lammps_reference

    try:
        ref = lammps_reference(n, m, length, protocol="dynamic", vacancy=vacancy,
                               potential=f"tersoff:{potential}", progress=False)
    except LookupError:
        ref = {}
    pd = ref.get("protocol_detail", {})
    if (pd.get("grip_A"), pd.get("speed_A_per_ps_each_grip")) != (proto.grip, proto.speed):
        ref = {"protocol_detail": {"grip_A": proto.grip,
                                   "speed_A_per_ps_each_grip": proto.speed}}
    model, dyn = dynamic_scene(n, m, length, coarsening, ref, vacancy=vacancy,
                               potential=f"tersoff:{potential}")
    dyn.pop("grips")
    r = dynamic_tension(model, seed=proto.seed, temperature=proto.temperature, dt=proto.dt,
                        sample=proto.sample_every, max_strain=proto.maximum,
                        tdamp=1e3 * proto.tau, progress=show, **dyn,
                        **({"checkpoint": ck["path"], "checkpoint_every": ck["every"],
                            "resume": ck["resume"]} if ck else {}))
    c = r["curve"]
    L0 = r["L0_A"]
    mu = model.atom_damage(r["positions"], r["delta"], L0)
    x0 = np.r_[model.x0[~model.is_slave], model.X_atoms[model.free_idx]]
    dmg = np.r_[np.asarray(model.damage, float)[~model.is_slave], mu]
    return {"curve": {"load": np.asarray(c["strain"]), "response": np.asarray(c["stress_GPa"]),
                      "time_ps": np.asarray(c["time_ps"])},
            "x0": x0, "damage_steps": [dmg], "axis": np.zeros(2),
            "radius_A": r["radius_relaxed_A"], "dof": r["dof"], "atoms": r["atoms"],
            "particles": r["particles"], "steps": r["steps"],
            "blowup_after_failure": r["blowup_after_failure"]}


# --------------------------------------------------------------------- the Result
def tube_result(run: dict, proto, params: dict, timer: Timer) -> Result:
    """The scene's :class:`Result` from a model's run dict (module docstring)."""
    c = run["curve"]
    x, y = np.asarray(c["load"], dtype=float), np.asarray(c["response"], dtype=float)
    figs = curve_figures(x, y, proto)
    torsion = proto.load == "torsion"
    xname, yname = ("twist_deg", "torque_eV") if torsion else ("strain", "stress_GPa")
    curves = {f"curve/{xname}": x, f"curve/{yname}": y}
    for k, v in c.items():
        if k not in ("load", "response"):
            curves[f"curve/{k}"] = np.asarray(v, dtype=float)
    steps = run["damage_steps"]
    fields = {"x0": run["x0"]}
    if steps:
        fields["damage"] = np.asarray(steps[-1], dtype=float)
        figs.update(_failure_site(run["x0"], steps, y, proto, run["axis"]))
    else:
        figs.update(failure_z_A=float("nan"), failure_angle_deg=float("nan"))
    figs.update(atoms=run["atoms"], particles=run["particles"], dof=run["dof"],
                radius_A=float(run["radius_A"]),
                wall_s=float(run.get("wall_s", timer.wall_s)))
    meta = make_meta("tension", params, timer=timer, seeds=[proto.seed],
                     conventions={"stress_area": "2 pi R t, t = 3.4 A, R mean wall radius "
                                  "after the zero-stress relaxation",
                                  "compression": "negative strain and stress",
                                  "torque": "eV, sign of the twist", "length_unit": "A",
                                  "unroll": [float(v) for v in run["axis"]]},
                     plot={"curve": {"x": xname, "y": [yname]}},
                     protocol={"name": proto.name, **_asdict(proto)},
                     model_detail={k: run[k] for k in ("minimisations", "unconverged", "lammps",
                                                       "source", "steps",
                                                       "blowup_after_failure") if k in run})
    return Result(figures=figs, curves=curves, fields=fields, meta=meta)


def _failure_site(x0, damage_steps, response, proto, axis) -> dict:
    """Median z and azimuth (reference configuration) of what broke between the peak and
    the last record; NaN where nothing broke."""
    k = proto.stop.failed_at(response)
    i = int(np.argmax(np.abs(response[: k if k is not None else len(response)])))
    before = damage_steps[i] if len(damage_steps) == len(response) else 0.0
    new = np.asarray(damage_steps[-1]) - before > 0
    if not new.any():
        return {"failure_z_A": float("nan"), "failure_angle_deg": float("nan")}
    p = np.asarray(x0)[new]
    th = np.arctan2(p[:, 1] - axis[1], p[:, 0] - axis[0])
    mean = np.angle(np.exp(1j * th).mean())
    ang = np.degrees(mean + np.median(np.angle(np.exp(1j * (th - mean)))))
    return {"failure_z_A": float(np.median(p[:, 2])), "failure_angle_deg": float(ang % 360.0)}


def _asdict(proto) -> dict:
    import dataclasses

    return dataclasses.asdict(proto)


def _printer(progress: bool, model: str):
    if not progress:
        return None

    def show(value, response):
        print(f"  {model:9s} load {value:9.4f}  response {response:10.4f}", flush=True)
    return show
