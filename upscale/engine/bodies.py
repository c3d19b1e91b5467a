"""Several bodies in one :class:`~upscale.engine.simulation.Simulation`.

Each :class:`Body` is a :class:`~upscale.engine.system.ParticleSystem` with its own pair
family and its own models. :func:`assemble` stacks the bodies into one system (particles
of body k at rows ``offsets[k]:offsets[k+1]``, their bonds at ``bond_offsets[k]:...`` of
the state's ``intact``) and wraps every body model in a :class:`BodyModel`, which hands
the model views of its rows (positions, velocities, forces, bonds) so the model computes
on its own body exactly as it would alone. Models that act *between* bodies (e.g. a
Lennard-Jones pair across tubes) act on the whole assembled system and find each
particle's body in ``system.body_n`` (N,) int32.

    scene = assemble([Body(sys_a, fam_a, [PMB(...)], name="a"),
                      Body(sys_b, fam_b, [PMB(...)], name="b")],
                     interactions=[LennardJonesBetweenBodies(...)])
    sim = scene.simulation(conditions=..., integrator=...)

Every body must have the same dimension (and, in 2D, thickness and plane). A body model's
history arrays in ``state.extra`` are stored under ``"<body name>/<key>"`` (so two bodies
with the same model keep theirs apart); models update them in place. Likewise a body
model's fields with inertia (:mod:`upscale.engine.fields`, e.g. the coarse tube's sublattice
shifts) are the assembled fields ``"<body name>/<field>"`` (on the other bodies' rows: unit
inertia, no force, at rest), so a region of a body is given to field conditions and
thermostats on those names.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from upscale.engine.state import State
from upscale.engine.system import ParticleSystem

__all__ = ["Body", "BodyModel", "Assembly", "assemble"]


@dataclasses.dataclass(eq=False)
class Body:
    """One body: its system, its pair family (None if no model needs one), its models."""

    system: ParticleSystem
    family: object = None
    models: list = dataclasses.field(default_factory=list)
    name: str = "body"

    def __post_init__(self):
        if hasattr(self.models, "step_force"):
            self.models = [self.models]
        self.models = list(self.models)
        if not self.models:
            raise ValueError(f"body {self.name!r} has no model")


class _ExtraView(dict):
    """The body's slice of ``state.extra`` (keys without the body prefix)."""


class BodyModel:
    """A model of one body, acting on that body's rows of the assembled state.

    Presents the engine's model contract (``needs``, ``force_kind``, ``prepare``,
    ``init_state``, ``add_force``, ``step_force``, ``break_bonds``, ``energy``,
    ``energy_density``, ``stiffness_bound``, ``describe``, and the force split of
    :mod:`upscale.engine.respa`) and forwards each call to the wrapped model with the
    body's views.
    """

    def __init__(self, model, body: Body, rows: slice, bonds: slice):
        from dataclasses import replace

        self.model, self.body, self.rows, self.bonds = model, body, rows, bonds
        self.name = f"{body.name}:{model.name}"
        self.force_kind = model.force_kind
        self.needs = replace(model.needs, pairs=False, triplets=False, quadruplets=False)
        self._prefix = f"{body.name}/"
        self._view = None  # (signature, State): the last view, see :meth:`sub`

    # the engine's calls --------------------------------------------------------------
    def prepare(self, system, family=None, **kw) -> None:
        self._n = system.n
        b = self.body
        trip = quad = None
        if self.model.needs.triplets or self.model.needs.quadruplets:
            from upscale.engine import multibody

            if self.model.needs.triplets:
                trip = multibody.build_triplets(b.system.x0, b.family)
            if self.model.needs.quadruplets:
                quad = multibody.build_quadruplets(b.system.x0, b.family)
        self.model.prepare(b.system, b.family, triplets=trip, quadruplets=quad)

    def sub(self, state: State) -> State:
        """The body's view of ``state`` (rows and bonds are views: writes go through).

        The view is kept while ``state`` holds the same arrays (same objects, no key
        added or removed): then only its time and step are renewed. (Rebuilding the
        dictionaries of a state with many bodies' extras on every call of every model
        was a measurable part of a step.)"""
        sig = self._signature(state)
        v = self._view
        if v is not None and v[0] == sig:
            s = v[1]
            s.t, s.step = state.t, state.step
            return s
        r, k = self.rows, self.bonds
        p = self._prefix
        extra = _ExtraView({key[len(p):]: v for key, v in state.extra.items() if key.startswith(p)})
        fields = {key[len(p):]: v[r] for key, v in state.fields.items() if key.startswith(p)}
        field_v = {key[len(p):]: v[r] for key, v in state.field_v.items() if key.startswith(p)}
        s = State(self.body.system.x0, state.y[r], state.v[r], state.intact[k], state.t,
                  state.step, extra, fields, field_v)
        self._own = tuple((d, key) for d in ("extra", "fields", "field_v")
                          for key in getattr(state, d) if key.startswith(p))
        # (the objects themselves kept too: their ids cannot be reused while cached)
        self._view = (self._signature(state), s, state,
                      tuple(getattr(state, d).get(key) for d, key in self._own))
        return s

    def _signature(self, state) -> tuple:
        """What :meth:`sub`'s view is made of: the state, its arrays' identities and the
        number of keys of its dictionaries."""
        own = getattr(self, "_own", ())
        return (id(state), id(state.y), id(state.v), id(state.intact), len(state.extra),
                len(state.fields), len(state.field_v),
                tuple(id(getattr(state, d).get(key)) for d, key in own))

    def init_state(self, state) -> None:
        s = self.sub(state)
        self.model.init_state(s)
        for key, v in s.extra.items():
            state.extra[self._prefix + key] = v
        for store, own in ((state.fields, s.fields), (state.field_v, s.field_v)):
            for key, v in own.items():  # a field the model set up: into the assembled arrays
                full = store.setdefault(self._prefix + key,
                                        np.zeros((state.y.shape[0],) + np.shape(v)[1:]))
                full[self.rows] = v

    # fields with inertia (upscale.engine.fields) of the body model, as "<body>/<name>" on
    # the assembled rows (other bodies' rows: unit inertia, no force, they stay at rest)
    def fields(self) -> dict:
        fn = getattr(self.model, "fields", None)
        if not callable(fn):
            return {}
        from upscale.engine.fields import FieldSpec

        out = {}
        for name, spec in fn().items():
            inertia = np.ones(self._n)
            inertia[self.rows] = np.broadcast_to(np.asarray(spec.inertia, dtype=np.float64),
                                                 (self.body.system.n,))
            out[self._prefix + name] = FieldSpec(spec.ncomp, inertia, spec.unit, self.rows)
        return out

    def add_field_force(self, state, out) -> None:
        fn = getattr(self.model, "add_field_force", None)
        if fn is None:
            return
        p = self._prefix
        fn(self.sub(state), {key[len(p):]: v[self.rows] for key, v in out.items()
                             if key.startswith(p)})

    def field_stiffness_bound(self):
        fn = getattr(self.model, "field_stiffness_bound", None)
        if fn is None:
            return {}
        b = fn()
        if b is None:
            return None
        out = {}
        for name, r in b.items():
            full = np.zeros(self._n)
            full[self.rows] = r
            out[self._prefix + name] = full
        return out

    def particle_damage(self, state):
        mu = np.zeros(state.y.shape[0])
        fn = getattr(self.model, "particle_damage", None)
        if callable(fn):
            mu[self.rows] = fn(self.sub(state))
        return mu

    def add_force(self, state, out) -> None:
        self.model.add_force(self.sub(state), out[self.rows])

    # the force-split contract of multiple time stepping (upscale.engine.respa): forwarded
    # when the wrapped model splits its forces; otherwise the whole model is fast
    def add_group_force(self, state, out, group: str) -> None:
        split = getattr(self.model, "add_group_force", None)
        if split is not None:
            split(self.sub(state), out[self.rows], group)
        elif group == "fast":
            self.add_force(state, out)

    def add_group_field_force(self, state, out, group: str) -> None:
        split = getattr(self.model, "add_group_field_force", None)
        if split is None:
            if group == "fast":
                self.add_field_force(state, out)
            return
        p = self._prefix
        split(self.sub(state), {key[len(p):]: v[self.rows] for key, v in out.items()
                                if key.startswith(p)}, group)

    def group_energy(self, state, group: str) -> float:
        split = getattr(self.model, "group_energy", None)
        if split is not None:
            return float(split(self.sub(state), group))
        return self.energy(state) if group == "fast" else 0.0

    def prepare_split(self, state) -> None:
        fn = getattr(self.model, "prepare_split", None)
        if fn is not None:
            fn(self.sub(state))

    def step_force(self, state, out, *, failure=True) -> int:
        return self.model.step_force(self.sub(state), out[self.rows], failure=failure)

    def break_bonds(self, state) -> int:
        return self.model.break_bonds(self.sub(state))

    def force(self, state):
        out = np.zeros_like(state.y)
        self.add_force(state, out)
        return out

    def energy(self, state) -> float:
        return float(self.model.energy(self.sub(state)))

    def energy_density(self, state):
        w = np.zeros(state.y.shape[0])
        w[self.rows] = self.model.energy_density(self.sub(state))
        return w

    def stiffness_bound(self):
        r = self.model.stiffness_bound()
        if r is None:
            return None
        out = np.zeros(self._n)
        out[self.rows] = r
        return out

    def describe(self) -> dict:
        return {"body": self.body.name, **self.model.describe()}


@dataclasses.dataclass(eq=False)
class Assembly:
    """Bodies stacked into one system: ``system`` (with ``body_n``), ``models`` (the body
    models wrapped, then the interactions), ``offsets`` (B+1,) particle rows,
    ``bond_offsets`` (B+1,) bond rows, ``bodies``."""

    system: ParticleSystem
    models: list
    offsets: np.ndarray
    bond_offsets: np.ndarray
    bodies: list

    def rows(self, name: str) -> slice:
        """The particle rows of body ``name``."""
        for k, b in enumerate(self.bodies):
            if b.name == name:
                return slice(int(self.offsets[k]), int(self.offsets[k + 1]))
        raise ValueError(f"no body {name!r}; valid: {[b.name for b in self.bodies]}")

    def mask(self, name: str) -> np.ndarray:
        """(N,) bool of body ``name``'s particles (for regions and thermostats)."""
        m = np.zeros(self.system.n, bool)
        m[self.rows(name)] = True
        return m

    def reference_state(self) -> State:
        return State.reference(self.system.x0, int(self.bond_offsets[-1]))

    def simulation(self, conditions=(), integrator=None, **kw):
        """A :class:`~upscale.engine.simulation.Simulation` of the assembly."""
        from upscale.engine.simulation import Simulation

        return Simulation(self.system, None, self.models, conditions, integrator,
                          state=self.reference_state(), **kw)


def assemble(bodies, interactions=()) -> Assembly:
    """Stack ``bodies`` (sequence of :class:`Body`) into one :class:`Assembly`.

    Raises ValueError on an empty list, repeated body names, or bodies of different
    dimension / thickness / plane.
    """
    bodies = list(bodies)
    if not bodies:
        raise ValueError("assemble needs at least one body")
    names = [b.name for b in bodies]
    if len(set(names)) != len(names):
        raise ValueError(f"body names must differ, got {names}")
    s0 = bodies[0].system
    for b in bodies[1:]:
        s = b.system
        if (s.dim != s0.dim or s.plane != s0.plane or s.thickness != s0.thickness
                or s.units != s0.units):
            raise ValueError(f"body {b.name!r} has dim {s.dim}, plane {s.plane!r}, thickness "
                             f"{s.thickness}, units {s.units!r}; body {bodies[0].name!r} has dim "
                             f"{s0.dim}, plane {s0.plane!r}, thickness {s0.thickness}, units "
                             f"{s0.units!r}: all bodies must agree")
    n = np.cumsum([0] + [b.system.n for b in bodies])
    nb = np.cumsum([0] + [(b.family.nb if b.family is not None else 0) for b in bodies])
    system = ParticleSystem(np.concatenate([b.system.x0 for b in bodies]),
                            np.concatenate([b.system.volume for b in bodies]),
                            np.concatenate([b.system.density for b in bodies]),
                            np.concatenate([b.system.material for b in bodies]),
                            dim=s0.dim, thickness=s0.thickness, plane=s0.plane,
                            spacing=min(b.system.spacing for b in bodies), units=s0.units)
    system.body_n = np.repeat(np.arange(len(bodies), dtype=np.int32), np.diff(n))
    models = []
    for k, b in enumerate(bodies):
        rows, bonds = slice(int(n[k]), int(n[k + 1])), slice(int(nb[k]), int(nb[k + 1]))
        models += [BodyModel(m, b, rows, bonds) for m in b.models]
    for m in interactions:
        models.append(m)
    return Assembly(system, models, n, nb, bodies)
