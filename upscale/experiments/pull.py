"""The dynamic pull: one time loop for every :class:`~upscale.experiments.protocols.Dynamic`
protocol on the engine (the tube, coarse or atomistic, and the bundle).

The specimen builds an engine :class:`~upscale.engine.simulation.Simulation` whose grips
move at the protocol's rate (:class:`~upscale.engine.conditions.Grip` conditions) under the
protocol's thermostat; :func:`pull` advances it with the engine's integrator
(``Simulation.run``), lets the specimen read the grips after every step, and every
``protocol.sample_every`` steps asks it for the sample's record (the block's mean response
at the block's middle time, as the LAMMPS runner averages ``fix ave/time``). The run stops
by the protocol's :class:`~upscale.experiments.protocols.StopRule` (failure: the first
sample ``drop`` below the running maximum of the response along the load; stop: below
``below`` of the peak after failure), at ``protocol.maximum`` of the load, or at the
specimen's step limit.

Checkpoints are the engine's: the records and the specimen's own bookkeeping
(:meth:`PullSpecimen.bookkeeping`) travel in the state's extras (JSON), written before the
checkpoint of the next step, so a run killed at any step resumes from its last checkpoint
bit for bit (the engine writes the checkpoint of step k before that step's callback, which
the resumed run then does first). A blow-up after failure ends the run with the curve up to
there (an atom kicked off after fracture, as LAMMPS's runs end on a runaway atom's box);
before failure it is raised with the engine's diagnosis.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

__all__ = ["PullSpecimen", "pull"]

#: the extras key of the records and the specimen's bookkeeping in a checkpoint
EXTRA = "pull.records"


class PullSpecimen:
    """What :func:`pull` asks of a specimen (an interface).

    ``simulation``: the current engine simulation (grips, thermostat, integrator set up);
    ``max_steps``: the step limit; ``read(sim)``: after every step, accumulate what a
    sample averages; ``sample(sim)``: at the end of a block, the block's record (a dict
    with ``load`` and ``response``, JSON numbers), breaking bonds and refreshing forces as
    the model needs; ``load(sim)``: the load (strain, or twist in degrees) checked against
    ``protocol.maximum`` after each sample: the grips' load now, or the last sample's. Optional: ``wants_switch()`` (asked after
    every sample) and ``switch()`` (the specimen replaces its simulation, which continues
    from the same step and time: an atomistic region that grows), ``bookkeeping()`` /
    ``restore(dict)`` (the JSON state a resumed run needs) and ``prepare_resume(path)``
    (rebuild the simulation a checkpoint at ``path`` belongs to).
    """

    simulation = None
    max_steps: int = 0
    #: time steps of the protocol's ``dt`` per engine step (a multiple-time-step
    #: integrator's inner steps): the protocol's ``sample_every`` counts the former
    inner: int = 1

    def read(self, sim) -> None:  # pragma: no cover - interface
        raise NotImplementedError(f"{type(self).__name__} must define read(sim)")

    def sample(self, sim) -> dict:  # pragma: no cover - interface
        raise NotImplementedError(f"{type(self).__name__} must define sample(sim)")

    def load(self, sim) -> float:  # pragma: no cover - interface
        raise NotImplementedError(f"{type(self).__name__} must define load(sim)")

    def wants_switch(self) -> bool:
        return False

    def switch(self) -> None:  # pragma: no cover - interface
        raise NotImplementedError(f"{type(self).__name__} asked for a switch it cannot make")

    def bookkeeping(self) -> dict:
        return {}

    def restore(self, book: dict) -> None:
        pass

    def prepare_resume(self, path) -> None:
        pass


def pull(specimen, protocol, *, progress=None, checkpoint=None, resume: bool = False,
         output=None, engine_progress: bool = False, meta: dict | None = None) -> dict:
    """Run the dynamic ``protocol`` on ``specimen`` (module docstring).

    Parameters
    ----------
    specimen : PullSpecimen
    protocol : Dynamic
        its ``sample_every``, ``maximum`` and ``stop`` are read here; the grips' rate, the
        time step and the thermostat are the specimen's simulation's.
    progress : callable, optional
        ``progress(record)`` after every sample.
    checkpoint : Checkpoint, optional
        the engine's checkpoint (path and interval); ``resume`` continues from it.
    output : Output, optional
        the engine's frames (extxyz / VTK).

    Returns
    -------
    dict
        ``records`` (one dict per sample), ``steps``, ``failed_at`` (sample index or None),
        ``blowup_after_failure`` (the diagnosis, or None), ``dynamics_s`` (wall time).
    """
    from upscale.engine.integrators import BlowUp  # noqa: PLC0415
    from upscale.io import NumpyJSON  # noqa: PLC0415

    t0 = time.perf_counter()
    every = int(protocol.sample_every) // int(specimen.inner)
    run = {"records": [], "step": 0, "book": {}, "switch": False}
    ck_every = checkpoint.every if checkpoint is not None else 0

    def save(sim, step):
        run["step"], run["book"] = int(step), specimen.bookkeeping()
        sim.state.extra[EXTRA] = np.frombuffer(json.dumps(run, cls=NumpyJSON).encode(), dtype=np.uint8)

    def finished(sim) -> bool:
        return bool(run["records"] and (protocol.stop.done(_along(run["records"], protocol))
                                        or abs(specimen.load(sim)) >= protocol.maximum))

    def callback(sim) -> bool:
        step = int(sim.state.step)
        specimen.read(sim)
        stop = False
        if step % every == 0:
            run["records"].append(specimen.sample(sim))
            if progress is not None:
                progress(run["records"][-1])
            stop = finished(sim)
            run["switch"] = not stop and bool(specimen.wants_switch())
            stop = stop or run["switch"]
        if stop or (ck_every and (step + 1) % ck_every == 0):
            save(sim, step)
        return stop

    if resume and checkpoint is not None and Path(checkpoint.path).is_file():
        done = _resume(specimen, checkpoint, run, callback, save, finished)
    else:
        save(specimen.simulation, 0)
        done = False
    blowup = None
    while not done:
        if run.get("switch"):  # the specimen moves to its new simulation, same step and time
            specimen.switch()
            run["switch"] = False
            save(specimen.simulation, specimen.simulation.state.step)
            if checkpoint is not None:  # (the first checkpoint of the new one, at once)
                checkpoint.last_step = None
        sim = specimen.simulation
        left = max(int(specimen.max_steps) - int(sim.state.step), 0)
        if not left:
            break
        try:
            sim.run(left, output=output, checkpoint=checkpoint, progress=engine_progress,
                    callback=callback, meta=meta)
        except BlowUp as e:
            if protocol.stop.failed_at(_along(run["records"], protocol)) is None:
                raise
            blowup = str(e)
            break
        done = not run.get("switch")
    return {"records": run["records"], "steps": int(specimen.simulation.state.step),
            "failed_at": protocol.stop.failed_at(_along(run["records"], protocol)),
            "blowup_after_failure": blowup,
            "dynamics_s": time.perf_counter() - t0}


def _along(records, protocol) -> list:
    """The responses along the load (tension positive, compression's sign turned), a
    response against the load counted as zero: a specimen still pushed back by its start
    (a bundle in compression at the first samples) has not failed."""
    return [max(protocol.sign * r["response"], 0.0) for r in records]


def _resume(specimen, checkpoint, run, callback, save, finished) -> bool:
    """Continue from ``checkpoint``: the specimen's simulation restored, the records and
    bookkeeping from the extras, the interrupted step's callback done first. Returns True
    when that callback ended the run, or the checkpoint is of a finished one."""
    specimen.prepare_resume(checkpoint.path)
    sim = specimen.simulation
    sim.resume(checkpoint.path)
    extra = sim.state.extra.get(EXTRA)
    sim.prepare()
    if extra is not None:
        run.update(json.loads(bytes(extra).decode()))
        specimen.restore(run["book"])
    checkpoint.last_step = None
    step = int(sim.state.step)
    if step > 0 and run["step"] < step:
        if callback(sim) and not run.get("switch"):
            return True
    elif not run.get("switch") and finished(sim):
        return True
    if not run.get("switch"):
        save(sim, step)
    return False
