"""Loading protocols: what is done to a specimen, written once for every backend.

A protocol is a small frozen object, so the engine side and the LAMMPS side
(:mod:`upscale.experiments.lammps`) provably run the same one:

:class:`QuasiStatic`
    a ramp of the load parameter in equal steps; at every step the specimen is loaded
    affinely, relaxed by the engine's minimisers (bonds break between relaxations until
    none does) and recorded.
:class:`Dynamic`
    grips pulled (or twisted) at a constant rate by velocity Verlet with a thermostat on
    the free part, recorded every ``sample_every`` steps.

Loads (:data:`LOADS`): ``tension`` and ``compression`` (axial strain; compression is
negative strain and negative stress), ``torsion`` (twist of one grip against the other, in
degrees over the gauge; the response is the torque in eV). A periodic specimen is loaded
through its cell; a twist needs a finite tube with grips (``grip > 0``).

One stop rule (:class:`StopRule`) for every protocol and load: failure is the first record
whose response falls more than ``drop`` below the running maximum in magnitude; a
quasi-static run stops ``after`` records later, a dynamic one once the response is below
``below`` of the peak after failure. The figures of a curve are :func:`curve_figures`.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numpy as np

__all__ = ["LOADS", "StopRule", "QuasiStatic", "Dynamic", "curve_figures", "ramp",
           "Specimen"]

#: the loads a tube protocol knows
LOADS = ("tension", "compression", "torsion")


def _positive(**kw) -> None:
    for k, v in kw.items():
        if v is None:
            continue
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{k}={v!r}; valid: a finite number > 0")


@dataclasses.dataclass(frozen=True)
class StopRule:
    """When a loading run has failed and when it stops (module docstring).

    Parameters
    ----------
    drop : float
        failure: the first record more than ``drop`` (fraction) below the running maximum
        of the response's magnitude (0.05).
    after : int
        quasi-static: records kept after the failing one (1: one step after the drop).
    below : float, optional
        dynamic: stop once the response's magnitude is below ``below`` times its peak,
        after failure (0.2).
    """

    drop: float = 0.05
    after: int = 1
    below: float | None = None

    def __post_init__(self):
        if not 0 < self.drop < 1:
            raise ValueError(f"drop={self.drop!r}; valid: 0 < drop < 1")
        if self.after < 0:
            raise ValueError(f"after={self.after!r}; valid: an integer >= 0")
        if self.below is not None and not 0 <= self.below < 1:
            raise ValueError(f"below={self.below!r}; valid: 0 <= below < 1")

    def failed_at(self, response) -> int | None:
        """Index of the first record more than ``drop`` below the running maximum of
        ``|response|``, or None."""
        a = np.abs(np.asarray(response, dtype=float))
        if a.size == 0:
            return None
        run = np.maximum.accumulate(a)
        hit = np.nonzero((a < (1.0 - self.drop) * run) & (run > 0))[0]
        return int(hit[0]) if hit.size else None

    def done(self, response) -> bool:
        """True when a run with this response history should stop."""
        k = self.failed_at(response)
        if k is None:
            return False
        if self.below is not None:
            a = np.abs(np.asarray(response, dtype=float))
            return bool(a[-1] < self.below * a.max())
        return len(response) - 1 - k >= self.after


@dataclasses.dataclass(frozen=True)
class QuasiStatic:
    """A quasi-static ramp (module docstring).

    Parameters
    ----------
    load : {"tension", "compression", "torsion"}
        what is ramped.
    step : float
        load increment per step: axial strain (tension, compression) or twist in degrees
        (torsion); the references use 0.005 strain.
    maximum : float
        the largest load magnitude (strain, or degrees), reached only if the stop rule
        has not stopped the run.
    periodic : bool
        loaded through the periodic cell (tension, compression) or through grips.
    grip : float
        length gripped rigidly at each end of a finite tube, Å (0 for a periodic one).
    ftol : float
        relaxation tolerance: largest force component, eV/Å.
    perturb : float
        imperfection, Å: before every relaxation the free atoms are displaced by
        :meth:`perturbation` (Gaussian, this standard deviation per component, seeded by
        ``seed`` and the step). A perfect structure at a bifurcation (a tube twisted past
        buckling) is otherwise left on the unstable branch for as long as the minimiser's
        own rounding does not break its symmetry, which differs from one minimiser to the
        next; the same seeded imperfection on every backend makes the buckling point the
        protocol's, not the minimiser's. 0: none.
    seed : int
        seed of the imperfection.
    stop : StopRule
        failure and stop (default: one step after the first drop of 5 %).
    """

    load: Literal["tension", "compression", "torsion"] = "tension"
    step: float = 0.005
    maximum: float = 0.40
    periodic: bool = True
    grip: float = 0.0
    ftol: float = 1e-6
    perturb: float = 0.0
    seed: int = 0
    stop: StopRule = StopRule(drop=0.05, after=1)

    name = "quasi-static"

    def __post_init__(self):
        _check_load(self.load, self.periodic, self.grip)
        _positive(step=self.step, maximum=self.maximum, ftol=self.ftol)
        if not (math.isfinite(self.perturb) and self.perturb >= 0):
            raise ValueError(f"perturb={self.perturb!r}; valid: a finite number >= 0 Å")
        if self.step >= self.maximum:
            raise ValueError(f"step={self.step!r} >= maximum={self.maximum!r}; valid: "
                             "step < maximum")

    @property
    def sign(self) -> float:
        """-1 for compression, else +1: the sign of the applied strain."""
        return -1.0 if self.load == "compression" else 1.0

    def perturbation(self, k: int, free) -> np.ndarray:
        """(N, 3) Å: the imperfection added before the relaxation of step ``k`` (zero on
        the atoms ``free`` (N,) bool leaves out, and everywhere when ``perturb`` is 0).
        Deterministic in (``seed``, ``k``) and the atoms' order, so every backend adds the
        same one."""
        free = np.asarray(free, dtype=bool)
        out = np.zeros((free.size, 3))
        if self.perturb:
            rng = np.random.default_rng([int(self.seed), int(k)])
            out[free] = self.perturb * rng.standard_normal((int(free.sum()), 3))
        return out

    def values(self):
        """The load parameter of step k = 0, 1, ...: ``sign k step`` up to ``maximum``."""
        k = 0
        while k * self.step <= self.maximum + 1e-12:
            yield self.sign * k * self.step
            k += 1


@dataclasses.dataclass(frozen=True)
class Dynamic:
    """A dynamic pull (module docstring).

    Parameters
    ----------
    load : {"tension", "compression", "torsion"}
        what the grips do.
    speed : float
        grip speed, Å/ps each (tension, compression; 2 x speed apart) or twist rate of one
        grip against the other, degrees/ps (torsion).
    grip : float
        length of each grip, Å.
    dt : float
        time step, fs.
    temperature : float
        thermostat temperature of the free part, K (0: NVE, no thermostat).
    tau : float
        thermostat damping time, ps.
    sample_every : int
        steps per recorded sample.
    maximum : float
        largest strain (or twist, degrees).
    seed : int
        seed of the thermal start.
    stop : StopRule
        failure and stop (default: below 20 % of the peak after the first 5 % drop).
    """

    load: Literal["tension", "compression", "torsion"] = "tension"
    speed: float = 1.0
    grip: float = 50.0
    dt: float = 1.0
    temperature: float = 10.0
    tau: float = 0.1
    sample_every: int = 100
    maximum: float = 0.40
    seed: int = 1
    stop: StopRule = StopRule(drop=0.05, after=1, below=0.2)

    name = "dynamic"
    periodic = False

    def __post_init__(self):
        _check_load(self.load, False, self.grip)
        _positive(speed=self.speed, grip=self.grip, dt=self.dt, tau=self.tau,
                  maximum=self.maximum, sample_every=self.sample_every)
        if self.temperature < 0:
            raise ValueError(f"temperature={self.temperature!r}; valid: >= 0 K")

    @property
    def sign(self) -> float:
        return -1.0 if self.load == "compression" else 1.0


def _check_load(load, periodic, grip) -> None:
    if load not in LOADS:
        raise ValueError(f"load={load!r}; valid: {', '.join(LOADS)}")
    if load == "torsion" and periodic:
        raise ValueError("load='torsion' on a periodic tube: a twist needs a finite tube "
                         "with grips (periodic=False, grip > 0)")
    if not periodic and not (grip > 0):
        raise ValueError(f"grip={grip!r} on a finite tube; valid: > 0 Å")
    if periodic and grip:
        raise ValueError(f"grip={grip!r} on a periodic tube; valid: 0 (loaded through the cell)")


def curve_figures(load: float, response, protocol, fit_max: float = 0.02) -> dict:
    """The figures of one loading curve.

    Tension: ``strength_GPa`` the maximum before the first drop (:class:`StopRule`),
    ``strain_at_peak``, ``youngs_TPa`` the least-squares slope (with intercept) over
    ``|strain| <= fit_max``; compression: the same on magnitudes, reported negative
    (``strength_GPa`` < 0, ``strain_at_peak`` < 0); torsion (load in degrees, response in
    eV): ``peak_torque_eV``, ``twist_at_peak_deg``. ``failed`` tells whether a drop
    happened (otherwise the peak is the largest magnitude recorded).
    """
    x = np.asarray(load, dtype=float)
    y = np.asarray(response, dtype=float)
    k = protocol.stop.failed_at(y)
    a = np.abs(y[: k if k is not None else len(y)])
    i = int(np.argmax(a)) if a.size else 0
    out = {"failed": k is not None}
    if protocol.load == "torsion":
        out.update(peak_torque_eV=float(y[i]), twist_at_peak_deg=float(x[i]))
        return out
    sel = np.abs(x) <= fit_max + 1e-12
    E = np.polyfit(x[sel], y[sel], 1)[0] / 1000.0 if sel.sum() >= 2 else math.nan
    out.update(strength_GPa=float(y[i]), strain_at_peak=float(x[i]), youngs_TPa=float(E))
    return out


class Specimen:
    """What :func:`ramp` asks of a scene's specimen (an interface; engine and LAMMPS
    specimens implement it).

    ``apply(value)`` sets the load parameter (strain or twist, degrees) affinely from the
    current state; ``relax()`` minimises at that load, breaking bonds between
    minimisations until none breaks, and returns the bonds broken; ``record()`` returns the
    record of this step (a dict of floats; ``response`` is the stress in GPa or the torque
    in eV); ``checkpoint(k)`` (optional) saves what a resumed run needs.
    """

    def apply(self, value: float) -> None:  # pragma: no cover - interface
        raise NotImplementedError(f"{type(self).__name__} must define apply(value)")

    def relax(self) -> int:  # pragma: no cover - interface
        raise NotImplementedError(f"{type(self).__name__} must define relax()")

    def record(self) -> dict:  # pragma: no cover - interface
        raise NotImplementedError(f"{type(self).__name__} must define record()")


def ramp(specimen, protocol: QuasiStatic, progress=None, start: int = 0,
         records: list | None = None) -> dict:
    """Run ``protocol`` on ``specimen`` (a :class:`Specimen`): for each load value,
    ``apply``, ``relax``, ``record``; stop by ``protocol.stop`` or at ``maximum``.

    ``progress(k, value, record)`` is called after every step; ``start`` and ``records``
    continue a run resumed after step ``start - 1``. Returns the curve as columns
    ``{"load": [...], "response": [...], <record keys>: [...]}`` and ``failed_at`` (index
    or None).
    """
    records = list(records or [])
    for k, value in enumerate(protocol.values()):
        if k < start:
            continue
        specimen.apply(value)
        broken = specimen.relax()
        rec = {"load": float(value), **specimen.record(), "broken": int(broken)}
        records.append(rec)
        if hasattr(specimen, "checkpoint"):
            specimen.checkpoint(k, records)
        if progress is not None:
            progress(k, value, rec)
        if protocol.stop.done([r["response"] for r in records]):
            break
    cols = {key: np.array([r[key] for r in records], dtype=float) for key in records[0]}
    return {"curve": cols, "failed_at": protocol.stop.failed_at(cols["response"])}
