"""One entry point of the LAMMPS backend: :func:`run` a protocol object on a structure.

The protocol is the same object the engine side takes (:mod:`upscale.experiments.protocols`);
:func:`run` maps it onto the runner of its load:

* ``QuasiStatic(load="tension", periodic=True)``:
  :func:`~upscale.experiments.lammps.quasistatic.quasi_static_tension`;
* ``QuasiStatic(load="compression", periodic=True)``: the same runner, the cell shortened
  (strain ``-k step``);
* ``QuasiStatic(load="torsion", periodic=False, grip=G)``:
  :func:`~upscale.experiments.lammps.torsion.quasi_static_torsion` (twist in degrees);
* ``Dynamic(load="tension")``: :func:`~upscale.experiments.lammps.dynamic.dynamic_tension`
  (``dt`` in fs becomes its ``timestep`` in ps, ``tau`` its ``tdamp``).

The protocol fixes what is done (load, step or speed, maximum, grips, thermostat, seed, the
stop rule); ``**settings`` are the LAMMPS side's own keywords (cutoff, minimiser tolerances
and fallback, dump, progress, nprocs, ...), never one the protocol already fixes. The
engine's relaxation tolerance ``QuasiStatic.ftol`` (largest force component) is not used:
the LAMMPS minimisers keep their references' settings (``ftol`` on the 2-norm, 1e-8 eV/Å,
with damped dynamics while the largest component is above ``fmax_tol`` = 1e-4 eV/Å), as
``protocol_detail`` records.

The result is the runner's record (its keys unchanged) with, in addition, the curve columns
``load`` (strain, or twist in degrees) and ``response`` (stress in GPa, or torque in eV), so
every load reads the same way; ``figures`` (:func:`upscale.experiments.protocols.curve_figures`
of that curve); ``protocol`` = ``dataclasses.asdict(protocol)`` (the runner's protocol name,
``"quasi-static"`` or ``"dynamic"``, moves to ``protocol_name``).
"""
from __future__ import annotations

import dataclasses

from upscale.experiments.protocols import Dynamic, QuasiStatic, curve_figures

__all__ = ["run", "OWNED"]

#: runner keywords the protocol fixes, per runner (passing them in ``settings`` is an error)
OWNED = {
    "quasi_static_tension": ("strain_step", "max_strain", "after_failure", "failure_drop",
                             "load"),
    "quasi_static_torsion": ("grip", "twist_step", "max_twist", "after_failure",
                             "failure_drop"),
    "dynamic_tension": ("grip", "speed", "timestep", "temperature", "tdamp", "sample_every",
                        "seed", "max_strain", "failure_drop", "stop_below"),
}


def _owned(runner: str, settings: dict) -> None:
    clash = sorted(set(settings) & set(OWNED[runner]))
    if clash:
        raise ValueError(f"settings {', '.join(clash)}: fixed by the protocol object; valid: "
                         "set them on the protocol (step, maximum, grip, speed, dt, ...)")


def run(atoms, protocol, potential="tersoff:BNC.tersoff", **settings) -> dict:
    """Run ``protocol`` (a :class:`~upscale.experiments.protocols.QuasiStatic` or
    :class:`~upscale.experiments.protocols.Dynamic`) on ``atoms`` with LAMMPS (module
    docstring).

    Raises
    ------
    TypeError
        ``protocol`` is not a protocol object.
    NotImplementedError
        A load the LAMMPS backend does not run: a quasi-static tension or compression
        through grips (``periodic=False``), a dynamic compression or torsion.
    ValueError
        ``settings`` hold a keyword the protocol fixes.
    """
    from upscale.experiments.lammps.dynamic import dynamic_tension  # noqa: PLC0415
    from upscale.experiments.lammps.quasistatic import quasi_static_tension  # noqa: PLC0415
    from upscale.experiments.lammps.torsion import quasi_static_torsion  # noqa: PLC0415

    if isinstance(protocol, QuasiStatic):
        stop = {"after_failure": protocol.stop.after, "failure_drop": protocol.stop.drop}
        if protocol.load == "torsion":
            _owned("quasi_static_torsion", settings)
            res = quasi_static_torsion(atoms, potential, grip=protocol.grip,
                                       twist_step=protocol.step, max_twist=protocol.maximum,
                                       perturbation=protocol.perturbation, **stop, **settings)
            x, y = res["curve"]["twist_deg"], res["curve"]["torque_eV"]
        elif protocol.perturb:
            raise NotImplementedError(
                f"QuasiStatic(perturb={protocol.perturb!r}) with load={protocol.load!r}: the "
                "LAMMPS backend adds the imperfection in torsion only; valid: perturb=0")
        elif protocol.periodic:
            _owned("quasi_static_tension", settings)
            res = quasi_static_tension(atoms, potential, load=protocol.load,
                                       strain_step=protocol.step, max_strain=protocol.maximum,
                                       **stop, **settings)
            x, y = res["curve"]["strain"], res["curve"]["stress_GPa"]
        else:
            raise NotImplementedError(
                f"QuasiStatic(load={protocol.load!r}, periodic=False): the LAMMPS backend "
                "loads tension and compression through the periodic cell; valid: "
                "periodic=True (or Dynamic for a gripped pull)")
        res["protocol_detail"]["engine_ftol_unused"] = (
            f"QuasiStatic.ftol={protocol.ftol:g} eV/A is the engine's tolerance; LAMMPS "
            "minimises as 'minimize' says")
    elif isinstance(protocol, Dynamic):
        if protocol.load != "tension":
            raise NotImplementedError(
                f"Dynamic(load={protocol.load!r}): the LAMMPS backend runs dynamic tension "
                "only; valid: load='tension' (or QuasiStatic for compression and torsion)")
        _owned("dynamic_tension", settings)
        res = dynamic_tension(atoms, potential, grip=protocol.grip, speed=protocol.speed,
                              timestep=protocol.dt / 1000.0, temperature=protocol.temperature,
                              tdamp=protocol.tau, sample_every=protocol.sample_every,
                              seed=protocol.seed, max_strain=protocol.maximum,
                              failure_drop=protocol.stop.drop, stop_below=protocol.stop.below,
                              **settings)
        x, y = res["curve"]["strain"], res["curve"]["stress_GPa"]
    else:
        raise TypeError(f"protocol={type(protocol).__name__}; valid: a QuasiStatic or Dynamic "
                        "object of upscale.experiments.protocols")
    res["curve"]["load"] = [float(v) for v in x]
    res["curve"]["response"] = [float(v) for v in y]
    res["figures"] = curve_figures(x, y, protocol) if len(x) else {}
    res["protocol_name"] = res["protocol"]
    res["protocol"] = dataclasses.asdict(protocol)
    return res
