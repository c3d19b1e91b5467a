"""Multiple time stepping: the reversible reference-system propagator (r-RESPA).

Tuckerman, Berne & Martyna (1992), "Reversible multiple time scale molecular dynamics",
J. Chem. Phys. 97, 1990, eq. (2.18) (the "impulse" or Verlet-I form; Grubmueller et al.
1991). The forces are split, F = F_fast + F_slow, each the gradient of its own part of the
same energy, E = E_fast + E_slow. One outer step of length Dt is the Trotter
factorisation

    exp(iL Dt) ~ exp(iL_slow Dt/2) [exp(iL_fast dt/2) exp(iL_drift dt) exp(iL_fast dt/2)]^n
                 exp(iL_slow Dt/2),    dt = Dt / n,

that is: a half kick with the slow forces, n velocity Verlet steps with the fast ones, a
half kick with the slow forces at the end positions. It is symplectic and time
reversible, so the energy of the full system is conserved without drift (its
fluctuation is O(Dt^2) in the slow forces and O(dt^2) in the fast ones) as long as Dt
stays clear of the resonances at half periods of the fast motion the slow forces excite
(Dt < T_fast / 2 is always safe). With n = 1 it is velocity Verlet.

The split is the models' (the contract, :mod:`upscale.engine`): a model may provide
``add_group_force(state, out, group)`` and ``add_group_field_force(state, out, group)``
for ``group`` in ``("fast", "slow")`` (and ``group_energy(state, group)``), whose sums
over the groups are its ``add_force`` / ``add_field_force`` / ``energy`` (a model with
per-particle forces may also give ``add_group_forces(state, out, fields_out, group)``, the
two at once from one evaluation, which is then used instead); a model without
them is fast as a whole (evaluated every inner step: always correct, never cheaper). A
model may also re-choose its split about the current state in ``prepare_split(state)``
(the sum unchanged), which :meth:`RESPA.update_forces` calls.
External loads are fast (cheap, and they may depend on time). Conditions act as in
velocity Verlet at every inner step (displacements after each drift, velocities after each
kick), grips record their reactions from the total force at the end of the outer step,
the failure criteria are applied once per outer step after both groups have been
evaluated at its end positions (force, then failure from the same positions: the LAMMPS
order of velocity Verlet). A thermostat acts on the outer step (its half steps around it).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from upscale.engine.integrators import StableEstimate

__all__ = ["RESPA", "GROUPS"]

#: the force groups of the split, in the order of their time scales
GROUPS = ("fast", "slow")


class RESPA(StableEstimate):
    """r-RESPA (impulse) multiple time stepping (module docstring).

    Parameters
    ----------
    outer_dt : float
        Outer time step Dt (the slow forces' step), in the scene's time unit.
    inner : int
        Number n of inner steps per outer step (the fast forces' step is Dt / n).

    ``dt`` is the inner step Dt / n, the step the engine's blow-up guard measures motion
    against (a particle crossing a spacing in one step) and the stable estimate refers
    to; ``outer_dt`` the time one :meth:`step` advances (``sim.run(k)``: k outer steps).
    thermostat : NoseHoover, NoseHooverChain or Langevin, optional
        :mod:`upscale.engine.thermostats`, its half steps around the outer step.
    force : bool
        Allow an inner step above the stable estimate of the models that give one.
    """

    name = "r-respa"

    def __init__(self, outer_dt: float, inner: int = 1, *, thermostat=None,
                 force: bool = False):
        if not (outer_dt is not None and np.isfinite(outer_dt) and outer_dt > 0):
            raise ValueError(f"outer time step must be positive, got {outer_dt!r}")
        if not (isinstance(inner, (int, np.integer)) and inner >= 1):
            raise ValueError(f"inner={inner!r}; valid: an integer number of inner steps >= 1")
        self.outer_dt = float(outer_dt)
        self.inner = int(inner)
        self.dt = self.outer_dt / self.inner
        self.thermostat = thermostat
        self.force = bool(force)
        self.estimate = None
        self._F = None  # {group: (N,3)} constrained dofs zeroed
        self._R = None  # {group: (N,3)} the group's force on the constrained dofs
        self._G = None  # {group: {field: (N,k)}}
        self._have = False

    # ------------------------------------------------------------------ set-up
    def prepare(self, sim) -> None:
        """Check the inner step against the stable estimate (if the models give one) and
        allocate the group forces."""
        self._check_step(sim, self.dt, "inner time step")
        n = sim.system.n
        if self._F is None or self._F["fast"].shape[0] != n:
            self._F = {g: np.zeros((n, 3)) for g in GROUPS}
            self._R = {g: np.zeros((n, 3)) for g in GROUPS}
            self._G = {g: {k: np.zeros_like(v) for k, v in sim.G.items()} for g in GROUPS}
            self._have = False
        if self.thermostat is not None:
            self.thermostat.prepare(sim)

    def checkpoint_arrays(self) -> dict:
        """The group forces of the last step and the thermostat's variables."""
        d = {} if self.thermostat is None else \
            {f"thermostat_{k}": v for k, v in self.thermostat.checkpoint_arrays().items()}
        if self._have:
            for g in GROUPS:
                d[f"F_{g}"] = self._F[g]
                d[f"R_{g}"] = self._R[g]
                d.update({f"G_{g}__{k}": v for k, v in self._G[g].items()})
        return d

    def restore_arrays(self, d: dict) -> None:
        if self.thermostat is not None:
            self.thermostat.restore_arrays({k[len("thermostat_"):]: v for k, v in d.items()
                                            if k.startswith("thermostat_")})
        if all(f"F_{g}" in d for g in GROUPS):
            for g in GROUPS:
                self._F[g][...] = d[f"F_{g}"]
                self._R[g][...] = d[f"R_{g}"]
                for k in self._G[g]:
                    self._G[g][k][...] = d[f"G_{g}__{k}"]
            self._have = True

    # ------------------------------------------------------------------ forces
    def _group_forces(self, sim, group: str) -> None:
        """The group's forces on the current state into ``_F[group]`` (constrained dofs
        zeroed, their part in ``_R[group]``) and ``_G[group]``."""
        st = sim.state
        F, G = self._F[group], self._G[group]
        F[...] = 0.0
        for v in G.values():
            v[...] = 0.0
        vol = sim.system.volume[:, None]
        fast = group == "fast"
        for m in sim.models:
            split = getattr(m, "add_group_force", None)
            density = m.force_kind == "density"
            if split is None and not fast:
                continue
            both = getattr(m, "add_group_forces", None)
            if both is not None and not density:
                both(st, F, G, group)
                continue
            tmp = np.zeros_like(F) if density else F
            if split is None:
                m.add_force(st, tmp)
            else:
                split(st, tmp, group)
            if density:
                F += tmp * vol
            if G:
                fsplit = getattr(m, "add_group_field_force", None)
                fn = getattr(m, "add_field_force", None) if fsplit is None else fsplit
                if fn is not None and (fsplit is not None or fast):
                    tg = {k: np.zeros_like(v) for k, v in G.items()} if density else G
                    if fsplit is None:
                        fn(st, tg)
                    else:
                        fn(st, tg, group)
                    if density:
                        for k, v in tg.items():
                            G[k] += v * vol
        if fast and getattr(sim, "_loads", True):
            F += sim.external_forces()
        _split_constrained(F, sim.constrained, self._R[group])
        for k, mask in sim.field_constrained.items():
            _zero_where(G[k], mask)

    def _finish(self, sim) -> int:
        """Both groups at the end positions: the total into ``sim.F`` / ``sim.G`` /
        ``sim.reactions``, the grips' reactions, then the failure criteria (bonds broken)."""
        from upscale.engine.conditions import Grip

        np.add(self._F["fast"], self._F["slow"], out=sim.F)
        np.add(self._R["fast"], self._R["slow"], out=sim.reactions)
        for k in sim.G:
            np.add(self._G["fast"][k], self._G["slow"][k], out=sim.G[k])
        grips = [c for c in sim.conditions if isinstance(c, Grip)]
        if grips:
            Ftot = sim.F + sim.reactions
            for g in grips:
                g.record(Ftot, sim.state.t)
        broken = 0
        if sim.failure:
            for m in sim.models:
                if m.needs.failure:
                    broken += int(m.break_bonds(sim.state))
            sim.broken_total += broken
        return broken

    def update_forces(self, sim) -> int:
        """Both groups' forces on the current state (call after changing a model outside a
        step, e.g. its links or dead loads: the stored forces would be stale), with the
        failure criteria; sets ``sim.F`` etc. as :meth:`Simulation.update_forces`."""
        for m in sim.models:
            ps = getattr(m, "prepare_split", None)
            if ps is not None:
                ps(sim.state)
        for g in GROUPS:
            self._group_forces(sim, g)
        self._have = True
        return self._finish(sim)

    # ------------------------------------------------------------------ the step
    def _kick(self, sim, group: str, h: float) -> None:
        from upscale.engine.kernels import kick

        st = sim.state
        kick(st.v, self._F[group], sim.inv_mass_n, h)
        for k, inv in sim.field_inv_inertia.items():
            r = sim.field_specs[k].span  # the rows that carry the field
            w, g, iv = st.field_v[k][r], self._G[group][k][r], inv[r]
            if w.shape[1] == 3 and iv.dtype == np.float64:
                kick(w, g, iv, h)
            else:
                w += h * g * iv[:, None]

    def step(self, sim) -> int:
        """Advance ``sim.state`` by one outer step; returns the number of bonds broken."""
        from upscale.engine.kernels import drift

        if not self._have:
            self.update_forces(sim)
        st, Dt, n = sim.state, self.outer_dt, self.inner
        h = Dt / n
        fields = sim.field_specs
        if self.thermostat is not None:
            self.thermostat.begin(sim, Dt)
        self._kick(sim, "slow", 0.5 * Dt)
        t0 = st.t
        for k in range(n):
            self._kick(sim, "fast", 0.5 * h)
            sim.apply_velocity(st.t + 0.5 * h)
            drift(st.y, st.v, h)
            for f in fields:
                st.fields[f][fields[f].span] += h * st.field_v[f][fields[f].span]
            st.t = t0 + (k + 1) * h
            sim.apply_displacement(st.t, h)
            self._group_forces(sim, "fast")
            self._kick(sim, "fast", 0.5 * h)
            sim.apply_velocity(st.t)
        st.t = t0 + Dt
        st.step += 1
        self._group_forces(sim, "slow")
        broken = self._finish(sim)
        self._kick(sim, "slow", 0.5 * Dt)
        sim.apply_velocity(st.t)
        if self.thermostat is not None:
            self.thermostat.end(sim, Dt)
        return broken

    def describe(self) -> dict:
        return {"integrator": self.name, "outer_dt": self.outer_dt, "inner": self.inner,
                "inner_dt": self.dt,
                "thermostat": None if self.thermostat is None else self.thermostat.describe()}


@njit(cache=True)
def _split_constrained(F_nc, mask_nc, R_nc):
    """R = F * mask (the group's force on the constrained dofs), then F = 0 there (one
    pass for ``np.multiply(F, mask, out=R)`` and ``np.copyto(F, 0, where=mask)``)."""
    for i in range(F_nc.shape[0]):
        for k in range(F_nc.shape[1]):
            if mask_nc[i, k]:
                R_nc[i, k] = F_nc[i, k] * 1.0
                F_nc[i, k] = 0.0
            else:
                R_nc[i, k] = F_nc[i, k] * 0.0


@njit(cache=True)
def _zero_where(a_nk, mask_nk):
    """a[mask] = 0."""
    for i in range(a_nk.shape[0]):
        for k in range(a_nk.shape[1]):
            if mask_nk[i, k]:
                a_nk[i, k] = 0.0
