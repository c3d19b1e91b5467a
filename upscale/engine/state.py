"""The mutable state of a run: positions, velocities, time, bond state, model extras."""
from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["State"]


@dataclasses.dataclass(eq=False)
class State:
    """Current state of a particle system.

    Attributes
    ----------
    x0 : (N, 3)
        Reference positions (shared with the :class:`~upscale.engine.system.ParticleSystem`,
        never modified).
    y : (N, 3)
        Current positions (the primary kinematic variable; ``u = y - x0``).
    v : (N, 3)
        Velocities.
    t : float
        Time.
    step : int
        Steps taken.
    intact : (nb,) bool
        Bond state on the engine's pair family (True = intact).
    extra : dict[str, ndarray]
        Model-owned state that must survive a restart (e.g. history variables). Keys are
        prefixed with the model name; saved and restored by the checkpoint.
    fields, field_v : dict[str, ndarray]
        Generalised degrees of freedom beyond the translations (``name -> (N, k)``) and
        their rates, declared by the models (:mod:`upscale.engine.fields`); empty unless
        a model has fields.
    """

    x0: np.ndarray
    y: np.ndarray
    v: np.ndarray
    intact: np.ndarray
    t: float = 0.0
    step: int = 0
    extra: dict = dataclasses.field(default_factory=dict)
    fields: dict = dataclasses.field(default_factory=dict)
    field_v: dict = dataclasses.field(default_factory=dict)

    @classmethod
    def reference(cls, x0: np.ndarray, nb: int) -> "State":
        """The reference state: y = x0, v = 0, all bonds intact."""
        x0 = np.ascontiguousarray(x0, dtype=np.float64)
        return cls(x0=x0, y=x0.copy(), v=np.zeros_like(x0), intact=np.ones(nb, dtype=bool))

    @property
    def u(self) -> np.ndarray:
        """Displacements ``y - x0`` (N, 3) (a new array)."""
        return self.y - self.x0

    @u.setter
    def u(self, value) -> None:
        self.y[...] = self.x0 + np.asarray(value, dtype=np.float64)

    def copy(self) -> "State":
        return State(self.x0, self.y.copy(), self.v.copy(), self.intact.copy(), self.t,
                     self.step, {k: np.array(v, copy=True) for k, v in self.extra.items()},
                     {k: v.copy() for k, v in self.fields.items()},
                     {k: v.copy() for k, v in self.field_v.items()})
