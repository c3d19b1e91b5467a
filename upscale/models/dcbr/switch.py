"""Regions that follow the crack: coarse particles replaced by their atoms mid-run.

Issue 51 item 3; reading notes ``adaptive-coupling.md`` sec. 3-4. Where a coarse link
approaches its failure rule (the bond it stands for, in the mapped lattice of either end,
longer than ``fraction`` x the cutoff R + D: :func:`.failure.link_rule`), the particles at
its ends give their atoms to the atomistic region (:func:`flagged_particles`).
:func:`switch` builds the model with the grown region (:meth:`.model.DCBRModel.grown`:
the coupling, pads, slave fits and the ghost-force load rebuilt) and maps the state:

* rows that stay (particles, atoms already free) keep position and velocity;
* a new atom a takes the position of its carrier c's uniform map with its shift
  (:func:`.coupling.carried_positions`: x_a = y_c + Q3_c (h_a + r0_a), the map that gave c
  its lattice energy, so at 0 K under uniform strain it sits exactly on the lattice) and the
  carrier's velocity v_c (the F-dot term is not added);
* momentum: a particle's mass is m_C max(w_c, N_c/2), not the atoms it stands for, so the
  new rows' momentum differs; a uniform velocity correction on the new atoms makes it equal
  exactly (to round-off), and the change before correction is logged;
* the links (``dcbr.intact``, ``dcbr.alive``) and shifts carry over (the same particles
  and family), the last good maps too; with ``shifts="inertial"`` the rows' shift field
  keeps the value and rate of the particles that stay rows.

Each switch returns a :class:`SwitchLog`: the particles switched, the atoms added, the
energy change per added atom, the momentum change (before and after the correction) and
the largest force on a new atom. The model never drives a run: a scene calls
:func:`switch` between steps and continues on a new Simulation with the new model and
state (the engine's Simulation has a fixed number of rows).

Units: eV, Å, amu / ``unit`` (velocities in Å per the model's time unit).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from upscale.engine import State
from upscale.models.dcbr.coupling import atom_geometry, carried_positions, carriers
from upscale.models.dcbr.failure import link_rule
from upscale.models.dcbr.model import FIELD

__all__ = ["SwitchLog", "flagged_particles", "switch"]


@dataclasses.dataclass
class SwitchLog:
    """What one switch did (module docstring)."""

    particles: np.ndarray
    atoms_added: int
    energy_before_eV: float
    energy_after_eV: float
    energy_change_per_atom_eV: float
    momentum_change_before_correction: np.ndarray
    momentum_change: np.ndarray
    max_new_atom_force_eV_A: float

    def as_dict(self) -> dict:
        return {"particles": self.particles.tolist(), "atoms_added": self.atoms_added,
                "energy_change_per_atom_eV": self.energy_change_per_atom_eV,
                "momentum_change_before_correction":
                    self.momentum_change_before_correction.tolist(),
                "momentum_change": self.momentum_change.tolist(),
                "max_new_atom_force_eV_A": self.max_new_atom_force_eV_A}


def flagged_particles(model, state, fraction: float = 0.8) -> np.ndarray:
    """(N,) bool: the coarse particles at either end of an intact link whose bond is longer
    than ``fraction`` x the cutoff in the mapped lattice of an end (not yet atomistic)."""
    model.energy(state)  # the lattice states of this configuration
    t = model.tube
    over = link_rule(t, model.lattice_states, fraction) & t.gain.intact_b
    out = np.zeros(t.N, bool)
    out[t.gain.owner_b[over]] = True
    out[t.gain.j_b[over]] = True
    if model.coupling is not None:
        out &= ~model.coupling.inside
    return out


def _rows(model):
    """(non-slave particle indices, free atom indices into the structure)."""
    c = model.coupling
    if c is None:
        return np.arange(model.tube.N), np.zeros(0, np.int64)
    return c.dof_idx, c.free_idx


def _particles(model, y, v):
    """All particles' positions and velocities (N, 3) from the rows (slaves interpolated)."""
    c = model.coupling
    if c is None:
        return y, v
    nd = len(c.dof_idx)
    vp = np.empty((model.tube.N, 3))
    vp[c.dof_idx] = v[:nd]
    if len(c.slave_idx):
        vp[c.slave_idx] = c.Phi @ v[nd:]
    return c.particle_positions(y, model.Lz), vp


def switch(model, state, particles):
    """(new model, new State, :class:`SwitchLog`): ``particles`` (N,) bool of ``model``
    replaced by their atoms at ``state`` (module docstring)."""
    particles = np.asarray(particles, bool)
    if not particles.any():
        raise ValueError("switch of no particle; valid: a mask with at least one particle")
    E0 = model.energy(state)
    new = model.grown(particles)
    new.hold_internal(model.held)
    t = model.tube
    dof_o, free_o = _rows(model)
    dof_n, free_n = _rows(new)
    yp, vp = _particles(model, state.y, state.v)
    delta = state.extra[FIELD]
    pos_o = {int(a): k for k, a in enumerate(free_o)}
    nd_o = len(dof_o)
    old_row = np.array([pos_o.get(int(a), -1) for a in free_n], np.int64)
    fresh = np.flatnonzero(old_row < 0)
    ids, X, th, z, sub, _ = atom_geometry(t, model.structure.tubes[0], model.structure.positions)
    loc = np.searchsorted(ids, free_n[fresh]) if len(fresh) else np.zeros(0, np.int64)
    car = carriers(t, dof_o, X[loc], th[loc], z[loc], sub[loc])
    xa = carried_positions(t, car, yp, delta, model.Lz, state.extra.get("dcbr.fs_last"))
    y = np.vstack([yp[dof_n], np.zeros((len(free_n), 3))])
    v = np.vstack([vp[dof_n], np.zeros((len(free_n), 3))])
    kept = np.flatnonzero(old_row >= 0)
    y[len(dof_n) + kept] = state.y[nd_o + old_row[kept]]
    v[len(dof_n) + kept] = state.v[nd_o + old_row[kept]]
    y[len(dof_n) + fresh] = xa
    v[len(dof_n) + fresh] = vp[car[0]]
    m_o, m_n = model.masses(), new.masses()
    P0 = m_o @ state.v
    dP_raw = m_n @ v - P0
    if len(fresh):
        v[len(dof_n) + fresh] -= dP_raw / m_n[len(dof_n) + fresh].sum()
    st = State(new.x0, y, v, state.intact.copy(), state.t, state.step,
               {k: np.array(a, copy=True) for k, a in state.extra.items()})
    if model.shifts == "inertial":  # the rows' shift field: the particles that stay keep
        # value and rate, a slave that becomes a row its relaxed shift at rest
        fd, fv = np.zeros((new.n, 3)), np.zeros((new.n, 3))
        fd[:len(dof_n)] = delta[dof_n]
        row = {int(p): k for k, p in enumerate(dof_o)}
        for k, p in enumerate(dof_n):
            if int(p) in row:
                fv[k] = state.field_v[FIELD][row[int(p)]]
        st.fields[FIELD], st.field_v[FIELD] = fd, fv
    st.extra.pop("dcbr.fs_last", None)
    st.extra.pop("dcbr.inside", None)  # the grown region (init_state writes it)
    if model.coupling is not None and "dcbr.fs_last" in state.extra:
        st.extra["dcbr.fs_last"] = np.array(state.extra["dcbr.fs_last"], copy=True)
    new.init_state(st)
    E1 = new.energy(st)
    f = new.force(st)[len(dof_n) + fresh]
    log = SwitchLog(np.flatnonzero(particles), int(len(fresh)), float(E0), float(E1),
                    float((E1 - E0) / max(len(fresh), 1)), dP_raw, m_n @ v - P0,
                    float(np.linalg.norm(f, axis=1).max(initial=0.0)))
    return new, st, log
