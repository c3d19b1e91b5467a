"""Boundary and loading conditions on named regions, each possibly time-dependent.

A :class:`Region` is a named set of particles selected by a predicate on the reference
positions or by a box (``system.select``); a region selecting nothing is an error.
A condition's ``value`` is a 3-vector, an array (n_region, 3), or a callable ``f(t)``
returning either. ``components`` restricts a kinematic condition to some axes.

Kinematic conditions (:class:`Fixed`, :class:`Displacement`, :class:`Velocity`) constrain
degrees of freedom: the integrators overwrite them and give them zero acceleration.
Load conditions (:class:`Force` in N per particle, :class:`BodyForce` in N/m^3) add to the
particle forces.

A :class:`Grip` is a region moved rigidly (``u(t) = u0 + velocity t``) or held at a
displacement, on some components; it records its reaction, the force it exerts on the
body, ``R = -sum_{i in region} F_i`` on its components (``F_i`` the internal plus external
force on particle i: the grip supplies what holds the region on its prescribed path, inertia
aside, which is zero for a rigid motion at constant velocity).
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np
from numba import njit

__all__ = ["Region", "region", "Condition", "Fixed", "Displacement", "Velocity", "Force",
           "BodyForce", "Grip", "constrained_dofs"]


@dataclasses.dataclass(eq=False)
class Region:
    """A named set of particles: ``mask`` (N,) bool and ``index`` (k,) int64."""

    name: str
    mask: np.ndarray

    def __post_init__(self):
        self.mask = np.asarray(self.mask, dtype=bool)
        if not self.mask.any():
            raise ValueError(f"region {self.name!r} selects no particle")
        self.index = np.flatnonzero(self.mask)

    @property
    def size(self) -> int:
        return int(self.index.size)


def region(system, name: str, where: Callable | None = None, box=None) -> Region:
    """Select a :class:`Region` of ``system`` by predicate ``where(x0)`` and/or ``box=(lo, hi)``."""
    return Region(name, system.select(where, box=box, name=name))


def _components(components) -> np.ndarray:
    c = np.atleast_1d(np.asarray(components, dtype=np.int64))
    if c.size == 0 or c.min() < 0 or c.max() > 2:
        raise ValueError(f"components must be a subset of (0, 1, 2), got {components!r}")
    return c


class Condition:
    """Base class: ``kinematic`` conditions constrain dofs, others add forces."""

    kinematic = False

    def __init__(self, region: Region, value=0.0, components=(0, 1, 2)):
        if not isinstance(region, Region):
            raise TypeError(f"condition needs a Region, got {type(region).__name__}")
        self.region = region
        self.value = value
        self.components = _components(components)

    def evaluate(self, t: float) -> np.ndarray:
        """The value at time t as an (n_region, 3) array."""
        v = self.value(t) if callable(self.value) else self.value
        v = np.asarray(v, dtype=np.float64)
        if v.ndim == 0:
            v = np.full(3, float(v))
        out = np.broadcast_to(v, (self.region.size, 3))
        if not np.isfinite(out).all():
            raise ValueError(f"condition on region {self.region.name!r} gave a non-finite value at t={t:g}")
        return out

    def describe(self) -> dict:
        return {"type": type(self).__name__, "region": self.region.name, "particles": self.region.size,
                "components": self.components.tolist(),
                "value": "f(t)" if callable(self.value) else np.asarray(self.value).tolist()}


class Displacement(Condition):
    """Prescribed displacement ``u = value(t)`` on the given components."""

    kinematic = True

    def apply(self, state, t: float, dt: float | None = None) -> None:
        """Mutates ``state.y`` (and ``state.v`` = du/dt by finite difference if ``dt``)."""
        idx, c = self.region.index, self.components
        u = self.evaluate(t)
        yc = state.x0[idx][:, c] + u[:, c]
        if dt:
            uprev = self.evaluate(t - dt)
            state.v[np.ix_(idx, c)] = (u[:, c] - uprev[:, c]) / dt
        state.y[np.ix_(idx, c)] = yc


class Fixed(Displacement):
    """Zero displacement and velocity on the given components."""

    def __init__(self, region: Region, components=(0, 1, 2)):
        super().__init__(region, 0.0, components)


class Velocity(Condition):
    """Prescribed velocity ``v = value(t)`` on the given components (positions follow)."""

    kinematic = True

    def apply_velocity(self, state, t: float) -> None:
        """Mutates ``state.v``."""
        idx, c = self.region.index, self.components
        state.v[np.ix_(idx, c)] = self.evaluate(t)[:, c]


class Force(Condition):
    """External force per particle (N) on every particle of the region."""

    def add(self, F: np.ndarray, system, t: float) -> None:
        np.add.at(F, self.region.index, self.evaluate(t) * _mask(self.components))


class BodyForce(Condition):
    """External body force density (N/m^3); the particle force is value * V_i."""

    def add(self, F: np.ndarray, system, t: float) -> None:
        idx = self.region.index
        np.add.at(F, idx, self.evaluate(t) * _mask(self.components) * system.volume[idx, None])


class Grip(Displacement):
    """A region moved rigidly at ``velocity`` from displacement ``u0``, or held at
    ``displacement`` (a 3-vector, or a callable of t), on ``components``; records its
    reaction (module docstring) after every force evaluation in :attr:`history`.

    Parameters
    ----------
    region : Region
    velocity : 3-vector, optional
        Grip speed (length / time), the prescribed displacement is ``u0 + velocity t``.
    displacement : 3-vector or callable f(t), optional
        A held (or prescribed) displacement instead of ``velocity``.
    u0 : 3-vector
        Displacement at t = 0 with ``velocity``.
    components : subset of (0, 1, 2)
    record_every : int
        Keep every n-th reaction in :attr:`history` (0: none).
    """

    def __init__(self, region: Region, velocity=None, displacement=None, *, u0=(0.0, 0.0, 0.0),
                 components=(0, 1, 2), record_every: int = 1):
        if (velocity is None) == (displacement is None):
            raise ValueError("a grip needs exactly one of velocity= or displacement=")
        if velocity is not None:
            vel = np.asarray(velocity, dtype=np.float64).reshape(3)
            start = np.asarray(u0, dtype=np.float64).reshape(3)
            if not (np.isfinite(vel).all() and np.isfinite(start).all()):
                raise ValueError(f"grip {region.name!r}: velocity {velocity!r} / u0 {u0!r} "
                                 "must be finite")
            value = lambda t, _v=vel, _u=start: _u + _v * t  # noqa: E731
        else:
            value = displacement
        super().__init__(region, value, components)
        self.velocity = velocity
        self._rigid = None if velocity is None else (start, vel)
        self._x0 = None  # (reference positions, their region rows) of the last state
        self.record_every = int(record_every)
        self.reaction_now = np.zeros(3)
        self.history: list[tuple[float, np.ndarray]] = []
        self._calls = 0

    def apply(self, state, t: float, dt: float | None = None) -> None:
        """As :meth:`Displacement.apply` (the same numbers); a grip moving at a velocity
        takes its one rigid displacement instead of a value per particle."""
        if self._rigid is None:
            return super().apply(state, t, dt)
        u0, vel = self._rigid
        u = u0 + vel * t
        if not np.isfinite(u).all():
            raise ValueError(f"condition on region {self.region.name!r} gave a non-finite "
                             f"value at t={t:g}")
        idx, c = self.region.index, self.components
        if self._x0 is None or self._x0[0] is not state.x0:
            self._x0 = (state.x0, state.x0[idx][:, c], len(c) == 3)
        x0r, full = self._x0[1], self._x0[2]
        if full:
            _rigid_rows(state.y, idx, x0r, u)
            if dt:
                _rigid_rows(state.v, idx, None, (u - (u0 + vel * (t - dt))) / dt)
            return
        if dt:
            state.v[np.ix_(idx, c)] = ((u - (u0 + vel * (t - dt))) / dt)[c]
        state.y[np.ix_(idx, c)] = x0r + u[c]

    def reaction(self, F: np.ndarray) -> np.ndarray:
        """``-sum_{i in region} F_i`` on the grip's components (3,) from forces ``F`` (N, 3)."""
        r = -F[self.region.index].sum(axis=0)
        out = np.zeros(3)
        out[self.components] = r[self.components]
        return out

    def record(self, F: np.ndarray, t: float) -> None:
        """Mutates :attr:`reaction_now` (and :attr:`history`) from the unconstrained forces."""
        self.reaction_now = self.reaction(F)
        self._calls += 1
        if self.record_every and self._calls % self.record_every == 0:
            self.history.append((float(t), self.reaction_now.copy()))

    def describe(self) -> dict:
        d = super().describe()
        d["velocity"] = None if self.velocity is None else np.asarray(self.velocity).tolist()
        return d


def _mask(components) -> np.ndarray:
    m = np.zeros(3)
    m[components] = 1.0
    return m


def constrained_dofs(n: int, conditions) -> np.ndarray:
    """(N, 3) bool: the degrees of freedom a kinematic condition prescribes."""
    m = np.zeros((n, 3), dtype=bool)
    for cnd in conditions:
        if cnd.kinematic:
            m[np.ix_(cnd.region.index, cnd.components)] = True
    return m


@njit(cache=True)
def _rigid_rows(a_nc, idx_i, x0_ic, u_c):
    """a[idx] = x0 + u (x0 None: a[idx] = u), u one 3-vector for every row."""
    for i in range(idx_i.shape[0]):
        r = idx_i[i]
        for k in range(3):
            if x0_ic is None:
                a_nc[r, k] = u_c[k]
            else:
                a_nc[r, k] = x0_ic[i, k] + u_c[k]
