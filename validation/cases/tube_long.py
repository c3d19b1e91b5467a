"""bench-dcbr-long: where coarse-graining pays, a (10,10) tube of 1 µm with 20 defects.

The tube: ``upscale.build.swcnt(10, 10, 10000 Å)`` (162,640 atoms, periodic) with 20
defects, five each of v1, v2, v4 and sw (``upscale.defects``), placed by
``numpy.random.default_rng(51)``: kinds in a random order, axial fractions uniform in
[0.05, 0.95] at least 0.02 (200 Å, beyond two atomistic regions) apart, azimuths uniform in
[0, 360) degrees (:func:`long_tube_defects`). Protocol: the tube scene's quasi-static
tension (``make_protocol("quasi-static", "tension")``).

``--reference`` makes the LAMMPS side (hours): the backend on 2 MPI ranks with restart
files in the user cache (:mod:`upscale.experiments.lammps.restart`), so a killed run
resumes at its last load step when the command is given again; when it finishes, the record
(with its CPU time over ranks and segments, peak memory per rank, machine and load) goes to
``data/reference/qs_long_tube.json``, a collection the tube scene reads. The case then runs
the coarse tube (``experiments.tension(model="dcbr")`` at the scene's defaults) in this
process and compares: CPU time (issue 51: at least 20x less than LAMMPS's), strength
(within 5 %) and the failing defect (the defect nearest each side's failure position, the
same for both).
"""
from __future__ import annotations

import json
import resource
import time

import numpy as np

from validation.registry import case

KINDS = ("v1", "v2", "v4", "sw")
REFERENCE = "qs_long_tube.json"
LENGTH_A = 10000.0


def long_tube_defects(seed: int = 51, per_kind: int = 5, gap: float = 0.02) -> str:
    """The defects string of the module docstring."""
    rng = np.random.default_rng(seed)
    kinds = list(rng.permutation(np.repeat(KINDS, per_kind)))
    z: list[float] = []
    while len(z) < len(kinds):
        c = float(rng.uniform(0.05, 0.95))
        if all(abs(c - o) >= gap for o in z):
            z.append(c)
    ang = rng.uniform(0.0, 360.0, len(kinds))
    return ",".join(f"{k}@{zi:.3f}@{a:.0f}" for k, zi, a in zip(kinds, sorted(z), ang))


def _tube():
    from upscale.experiments.scenes.tube import tube_structure

    return tube_structure(None, (10, 10), LENGTH_A, long_tube_defects())


def _make_reference(atoms, proto) -> None:
    import dataclasses
    import os

    from upscale.experiments import lammps
    from upscale.experiments.lammps.cache import cache_dir
    from upscale.experiments.references import reference_dir
    from upscale.experiments.scenes.tube import damage_onset
    from upscale.io import versions, write_json

    load0 = os.getloadavg()
    dump = cache_dir("dumps") / "long_tube.dump"
    restart = cache_dir("restart") / "long_tube"
    print(f"LAMMPS reference of the 1 um tube ({len(atoms)} atoms) on 2 ranks: hours; restart "
          f"files in {restart} (give the command again to resume)", flush=True)
    r = lammps.run(atoms, proto, potential="tersoff:BNC.tersoff", nprocs=2, dump=dump,
                   restart=restart, progress=True)
    r["atom_damage_onset"] = damage_onset(dump, len(r["curve"]["load"]))
    write_json(reference_dir() / REFERENCE, {
        "provenance": {
            "what": "LAMMPS quasi-static tension of the 1 um (10,10) tube with 20 defects "
                    "(validation/cases/tube_long.py docstring), 2 MPI ranks, resumed from "
                    "restart files where interrupted",
            "made_by": "python -m validation bench-dcbr-long --reference",
            "cost": r.get("cost"), "load_at_last_start": load0,
            "protocol": dataclasses.asdict(proto), "versions": versions()},
        "tubes": [{"chirality": [10, 10], "length_A": LENGTH_A,
                   "defects": long_tube_defects(), "lammps": r,
                   "command": "python -m validation bench-dcbr-long --reference"}]})


def _nearest(z, defects, period) -> tuple[str, float]:
    d = [abs((z - rec["at"][2] + period / 2) % period - period / 2) for rec in defects]
    k = int(np.argmin(d))
    return defects[k]["kind"], float(d[k])


@case("bench-dcbr-long", "the 1 um (10,10) tube with 20 defects: coarse tube against LAMMPS "
      "(2 ranks, restart files) in quasi-static tension, CPU time, strength, failing defect",
      add_arguments=lambda p: p.add_argument(
          "--reference", action="store_true",
          help="make (or resume) the LAMMPS reference first: hours on 2 ranks"),
      target="whole coarse run >= 20x less CPU than LAMMPS's, strength within 5 %, the "
             "same failing defect (issue 51)")
def _bench_long(args):
    from upscale import experiments
    from upscale.experiments.references import reference_dir
    from upscale.experiments.scenes.tube import make_protocol

    atoms, proto = _tube(), make_protocol("quasi-static", "tension")
    if args.reference:
        _make_reference(atoms, proto)
    path = reference_dir() / REFERENCE
    if not path.is_file():
        raise SystemExit(f"{path.name} is not made; run: python -m validation "
                         "bench-dcbr-long --reference (hours on 2 ranks, resumable)")
    ref = json.loads(path.read_text())
    lmp = ref["tubes"][0]["lammps"]
    ours_cpu, t0 = time.process_time(), time.perf_counter()
    ours = experiments.tension(atoms, model="dcbr")
    cpu = time.process_time() - ours_cpu
    period = float(atoms.cell[2, 2])
    kind, dz = _nearest(ours.figures["failure_z_A"], atoms.info["defects"], period)
    lz = experiments.tension(atoms, model="lammps").figures["failure_z_A"]
    kind_l, dz_l = _nearest(lz, atoms.info["defects"], period)
    strength_l = lmp["figures"]["strength_GPa"]
    out = {"atoms": len(atoms), "coarse_cpu_s": cpu, "coarse_wall_s": time.perf_counter() - t0,
           "lammps_cpu_s": lmp["cost"]["cpu_s"],
           "speedup_whole": lmp["cost"]["cpu_s"] / cpu,
           "strength_GPa": ours.figures["strength_GPa"], "strength_GPa_lammps": strength_l,
           "strength_err_pct": 100.0 * (ours.figures["strength_GPa"] / strength_l - 1.0),
           "failure_z_A": ours.figures["failure_z_A"], "failure_z_A_lammps": lz,
           "failure_defect": kind, "failure_defect_lammps": kind_l,
           "failure_site_matches": bool(kind == kind_l and abs(ours.figures["failure_z_A"]
                                                              - lz) <= 16.0),
           "coarse_peak_memory_GB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
           "lammps_peak_memory_GB": float(sum(lmp["cost"]["peak_rss_GB_per_rank"]))}
    out["pass"] = bool(out["speedup_whole"] >= 20 and abs(out["strength_err_pct"]) <= 5
                       and out["failure_site_matches"])
    return out
