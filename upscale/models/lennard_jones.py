"""Lennard-Jones between bodies: the van der Waals pair across tubes, as an engine model.

Shifted-force 12-6 Lennard-Jones (:func:`potentials.lj.lj_energy_forces`, LAMMPS
``lj/smooth/linear``)

    phi_SF(r) = 4 eps [(sigma/r)^12 - (sigma/r)^6] - phi(rc) - (r - rc) phi'(rc),  r < rc,

between particles of *different* bodies of an assembly (:mod:`upscale.engine.bodies`:
``system.body_n``); pairs within a body are left to that body's own model. Units are the
scene's (eV and Å for tubes; ``eps`` an energy, ``sigma`` and ``rc`` lengths); the force
is per particle (``force_kind = "particle"``). The neighbour list
(:func:`potentials.neighbours.neighbour_list`, open boundaries) is rebuilt when a particle
has moved more than half the ``skin`` since the last build.
"""
from __future__ import annotations

import numpy as np

from potentials.lj import lj_energy_forces
from potentials.neighbours import neighbour_list
from upscale.models import register
from upscale.models.base import Model, Needs, check_positive

__all__ = ["LennardJonesBetweenBodies"]


class LennardJonesBetweenBodies(Model):
    """Shifted-force Lennard-Jones between the bodies of an assembly (module docstring).

    Parameters
    ----------
    epsilon, sigma : float
        Well depth (energy) and zero-crossing distance (length).
    rc : float, optional
        Cut-off (default 3 sigma).
    skin : float, optional
        Neighbour-list skin (default 0.3 sigma).
    """

    name = "lj-between-bodies"
    needs = Needs(pairs=False, energy=True)
    force_kind = "particle"

    def __init__(self, epsilon: float, sigma: float, *, rc: float | None = None,
                 skin: float | None = None):
        check_positive(epsilon=epsilon, sigma=sigma, rc=rc, skin=skin)
        self.eps, self.sigma = float(epsilon), float(sigma)
        self.rc = float(rc) if rc is not None else 3.0 * self.sigma
        self.skin = float(skin) if skin is not None else 0.3 * self.sigma
        self._y_built = None

    def prepare(self, system, family=None, **kw) -> None:
        body = getattr(system, "body_n", None)
        if body is None:
            raise ValueError("lj-between-bodies acts between bodies: give it the system of "
                             "upscale.engine.bodies.assemble(...) (it has no body_n)")
        super().prepare(system, family, **kw)
        self.body_n = np.ascontiguousarray(body, dtype=np.int64)

    def _list(self, y):
        if self._y_built is None or np.max(np.sum((y - self._y_built) ** 2, axis=1)) > (0.5 * self.skin) ** 2:
            self._nl = neighbour_list(y, np.zeros((3, 3)), (False, False, False), self.rc + self.skin)
            self._y_built = y.copy()
        return self._nl

    def _evaluate(self, state):
        y = np.ascontiguousarray(state.y)
        first, j, shift = self._list(y)
        return lj_energy_forces(y, np.zeros((3, 3)), first, j, shift, self.eps, self.sigma,
                                self.rc, self.body_n, True)

    def add_force(self, state, out) -> None:
        out += self._evaluate(state)[2]

    def energy(self, state) -> float:
        return float(self._evaluate(state)[0])

    def energy_density(self, state):
        return self._evaluate(state)[1] / self.system.volume

    def stiffness_bound(self):
        """None: the pair stiffness grows without bound at close approach, so no reference
        bound holds; give the integrator a ``dt``."""
        return None

    def describe(self) -> dict:
        return {"model": self.name, "epsilon": self.eps, "sigma": self.sigma, "rc": self.rc}


register("lj-between-bodies", LennardJonesBetweenBodies)
