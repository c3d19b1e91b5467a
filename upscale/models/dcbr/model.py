"""``DCBRModel``: the coarse (DCBR) tube as an ordinary engine model, built from atoms.

Seed 004 sec. 5.3.1, eqs. 5.13-5.16: coarse particles carry the tube's Tersoff lattice
through their gain G (discrete Cauchy-Born rule); the energy is

    E(y; delta, L) = sum_c N_c (e(C_c, delta_c) - e0) + W_stab,

e the Tersoff energy per atom of the particle's lattice mapped uniformly by its surface
metric C_c = S_c F_c^T F_c S_c with the sublattice shift delta_c (:mod:`.kernels`,
:mod:`.cell`), W_stab the hourglass control (:mod:`.hourglass`), L the period of a
periodic tube. Built from an ``ase.Atoms`` (a tube of :func:`upscale.build.swcnt`, with or
without the defects of :mod:`upscale.build`, or read from a file): the tube is registered
(:func:`.structure.register`: axis, chirality, lattice map), its defects found
(:func:`.defects.find_defects`) and the atomistic regions around them
(:func:`.regions.atomistic_regions`, ``model.regions``) are kept as atoms; the particles
are placed by :class:`.tube.CoarseTube`.

The sublattice shifts delta (N, 3) Å are massless: relaxed at every configuration
(E*(y) = min_delta E, forces -dE/dy at the relaxed shifts, the envelope theorem), warm
started from ``state.extra["dcbr.delta"]``; while a minimiser holds them
(:meth:`hold_internal`) they are its unknowns (``internal_fields``). The links' state
(``dcbr.intact``, ``dcbr.alive``) lives in ``state.extra`` too, so a checkpoint carries
it. Failure: the coarse link rule (:mod:`.failure`) and the lattice-stability rule
(:mod:`.stability`) in :meth:`break_bonds`.

Engine contract (``upscale.models.base.Model``): ``force_kind = "particle"`` (eV/Å per
particle), ``needs = Needs(pairs=False, failure=..., energy=True)``; optional hooks
``internal_fields``, ``internal_gradient``, ``hold_internal`` (massless internal fields of
``upscale.engine.minimisers``), ``particle_damage`` (``sim.damage()``), ``cell_force``
and ``set_cell`` (a periodic tube's length as the load). The model never drives a run:
:meth:`system` gives the body (masses N_c m_C in amu / ``unit``).

With atomistic regions (a defect, or a user selection) the rows are the non-slave
particles then the free atoms, coupled by :mod:`.coupling`, with the ghost-force dead load
of :mod:`.ghost` (a periodic tube at its period; an open one at the axial stretch and with
the held rows that ``state.extra["dcbr.ghost"]``, ``"dcbr.ghost_hold"`` ask for, the grips'
strain of a pull: :meth:`_sync_ghost`); :meth:`grown` and :mod:`.switch` grow the region
where links near failure (the scene continues on a new Simulation). With atoms, the
unheld shifts are relaxed by L-BFGS-B over all of them at every force call (the pads
couple them): right for quasi-static runs; for dynamics ``shifts="inertial"`` makes them a
field with inertia (:meth:`fields`). Not here yet (issue 51): the clamped coarse grips of
an open tube (the old ``clamp_grips``), several tubes.

Units: eV, Å, amu / ``unit`` (default Å/fs^2 per eV/(Å amu): time in fs).
"""
from __future__ import annotations

import numpy as np

from upscale.constants import ACC_EV_A_AMU_IN_A_FS2, CARBON_MASS_AMU
from upscale.models.base import Model, Needs
from upscale.models.dcbr.cell import tersoff_row
from upscale.models.dcbr.coupling import Coupling
from upscale.models.dcbr.defects import find_defects
from upscale.models.dcbr.failure import link_rule
from upscale.models.dcbr.ghost import GhostLoad
from upscale.models.dcbr.regions import atomistic_regions
from upscale.models.dcbr.stability import LatticeStability, check_stability
from upscale.models.dcbr.structure import register
from upscale.models.dcbr.tube import CoarseTube

__all__ = ["DCBRModel", "FIELD"]

#: the sublattice shifts in ``state.extra`` (N, 3), Å
FIELD = "dcbr.delta"


def _check(name, value, ok, valid):
    if not ok:
        raise ValueError(f"{name}={value!r}; valid: {valid}")


class DCBRModel(Model):
    """Coarse DCBR model of one carbon nanotube (module docstring).

    Parameters
    ----------
    atoms : ase.Atoms
        One carbon tube, periodic along z or finite (its defects are found).
    coarsening : float
        K = particle spacing / lattice constant sqrt(3) a_cc (>= 1).
    chirality : (n, m), optional
        A hint for the registration (never required).
    horizon_factor : float
        Influence radius of G / the larger particle spacing (> 1; 1.5: the 3x3 stencil).
    potential : str
        LAMMPS ``.tersoff`` file (step cutoff at R + D, as the references).
    hourglass : float
        Hourglass stiffness as a fraction of the lattice's (0 = off; default 0.1).
    r_atomistic : float
        Radius (Å) of the atomistic region around each defect (``model.regions``).
    select : callable, bool mask or atom indices, optional
        Atoms kept atomistic besides (:func:`.regions.selected_atoms`; selecting nothing
        is an error).
    shifts : {"relaxed", "inertial"}
        The sublattice shifts massless and relaxed at every configuration (quasi-static
        runs), or a field ``state.fields["dcbr.delta"]`` of the particle rows with the
        reduced mass of two sublattices (dynamics, as the validated dynamic tube).
    atomistic_particles : (N,) bool, optional
        Particles whose atoms are made atomistic besides the regions' (a grown region:
        :func:`.switch.switch`).
    ghost : bool
        With atomistic regions: the ghost-force dead load of the pristine twin
        (:mod:`.ghost`); on a periodic tube prepared by :meth:`set_cell` for each period
        (and at the tube's own period here), on a finite one at the stretch the state's
        extras ask for (:meth:`_sync_ghost`; none asked, none applied).
    shift_gtol : float
        Tolerance of the shift relaxation, max |dE/d delta| per particle, eV/Å.
    failure : bool
        Apply the failure rules in the engine's force evaluations.
    stability : bool
        With the link rule, the lattice-stability rule (:mod:`.stability`) when no link
        broke.
    unit : float
        Masses are amu / ``unit``.
    """

    name = "dcbr"
    force_kind = "particle"

    def __init__(self, atoms, coarsening: float = 2.0, *, chirality=None,
                 horizon_factor: float = 1.5, potential: str = "BNC.tersoff",
                 hourglass: float = 0.1, r_atomistic: float = 8.0, select=None,
                 ghost: bool = True, shift_gtol: float = 1e-10,
                 failure: bool = True, stability: bool = True,
                 unit: float = ACC_EV_A_AMU_IN_A_FS2, atomistic_particles=None,
                 shifts: str = "relaxed"):
        _check("coarsening", coarsening, np.isfinite(coarsening) and coarsening >= 1.0,
               "a number >= 1 (1 = one particle per lattice constant)")
        _check("horizon_factor", horizon_factor,
               np.isfinite(horizon_factor) and horizon_factor > 1.0, "a number > 1")
        _check("shift_gtol", shift_gtol, np.isfinite(shift_gtol) and shift_gtol > 0, "> 0")
        _check("unit", unit, np.isfinite(unit) and unit > 0, "a positive mass unit factor")
        self.params = dict(coarsening=coarsening, chirality=chirality,
                           horizon_factor=horizon_factor, potential=potential,
                           hourglass=hourglass, r_atomistic=r_atomistic, select=select,
                           ghost=ghost, shift_gtol=shift_gtol, failure=failure,
                           stability=stability, unit=unit, shifts=shifts)
        _check("shifts", shifts, shifts in ("relaxed", "inertial"), "'relaxed' (massless, "
               "relaxed at every configuration) or 'inertial' (a field with inertia)")
        self.shifts = shifts
        self.atoms = atoms
        self.structure = register(atoms, chirality)
        if len(self.structure.tubes) != 1:
            raise ValueError(f"the structure holds {len(self.structure.tubes)} tubes; valid: "
                             "one tube (bundles are not built yet)")
        tube = self.structure.tubes[0]
        if tube.periodic and abs(abs(tube.axis[2]) - 1.0) > 1e-9:
            raise ValueError(f"periodic tube along {np.round(tube.axis, 6).tolist()}; valid: "
                             "periodic along z (the cell's third vector)")
        self.defects = find_defects(self.structure)
        self.regions = atomistic_regions(self.structure, self.defects, r_atomistic, select)
        cut = float(tersoff_row(potential)[10])
        if tube.length < 2 * cut:
            raise ValueError(f"tube length {tube.length:.3f} Å; valid: at least two cutoffs of "
                             f"the potential ({2 * cut:.2f} Å)")
        more = None if atomistic_particles is None else np.asarray(atomistic_particles, bool)
        coupled = self.regions.mask.any() or (more is not None and more.any())
        n_sites = int(tube.lattice.expected.sum()) if coupled else len(tube.atoms)
        self.tube = CoarseTube(tube, n_sites, coarsening, horizon_factor, potential, hourglass,
                               self.structure.positions[tube.atoms])
        t = self.tube
        if more is not None and more.shape != (t.N,):
            raise ValueError(f"atomistic_particles of shape {more.shape}; valid: ({t.N},) bool")
        self.coupling = self.ghost = None
        if coupled:
            self.coupling = Coupling(t, tube, self.structure.positions, self.regions.mask,
                                     potential, more_inside=more)
            if ghost and t.periodic:
                build = dict(coarsening=coarsening, horizon_factor=horizon_factor,
                             potential=potential, hourglass=hourglass)
                self.ghost = GhostLoad(self.coupling, tube, self.structure.positions, build,
                                       potential)
        self.Lz = t.L if t.periodic else None
        self.stability = None
        if stability:
            n, m = tube.chirality
            self.stability = LatticeStability(n, m, t.P_f, t.bond)
        self.shift_gtol = float(shift_gtol)
        self.unit = float(unit)
        if self.ghost is not None:
            self.ghost.prepare(self.Lz)
        self.needs = Needs(pairs=False, failure=bool(failure), energy=True)
        self.cell = None
        self._held = False
        self._cache = None
        self._carried_map = None
        self._ghost_key = None
        self._ghost_build = dict(coarsening=coarsening, horizon_factor=horizon_factor,
                                 potential=potential, hourglass=hourglass) \
            if (ghost and coupled and not t.periodic) else None

    # ------------------------------------------------------------------ the body
    @property
    def x0(self) -> np.ndarray:
        """Reference positions of the rows (n, 3), Å: the particles, or with atomistic
        regions the non-slave particles then the free atoms (:mod:`.coupling`)."""
        return self.tube.x0 if self.coupling is None else self.coupling.y_ref

    @property
    def n(self) -> int:
        """Rows of the engine's state."""
        return len(self.x0)

    def masses(self) -> np.ndarray:
        """(n,) amu / ``unit``: a particle m_C max(w_c, N_c / 2) (its weight, at least half
        its nominal atoms), an atom m_C."""
        t, c = self.tube, self.coupling
        if c is None:
            return t.natoms_n * CARBON_MASS_AMU / self.unit
        w = np.maximum(t.natoms_n, 0.5 * c.nominal)[c.dof_idx]
        return np.r_[w, np.ones(c.nf)] * CARBON_MASS_AMU / self.unit

    def system(self):
        """The particles as a :class:`~upscale.engine.system.ParticleSystem` (volume 1,
        density the masses, spacing a_cc, atomic units)."""
        from upscale.engine.system import ParticleSystem  # noqa: PLC0415

        return ParticleSystem(self.x0, 1.0, density=self.masses(), spacing=self.tube.bond,
                              units="atomic")

    # ------------------------------------------------------------------ the contract
    def prepare(self, system, family=None, **kw) -> None:
        if system.dim != 3 or system.n != self.n:
            raise ValueError(f"the body has {system.n} rows in {system.dim}D; valid: the "
                             f"model's {self.n} rows in 3D (DCBRModel.system())")
        self.system = system

    def _carried(self):
        """(structure ids (K,), coarse (K,) bool: carried by a particle's map, the
        carriers' tuple of :func:`.coupling.carriers` for the coarse ones), built once."""
        if self._carried_map is None:
            from upscale.models.dcbr.coupling import atom_geometry, carriers  # noqa: PLC0415

            t, c = self.tube, self.coupling
            ids, X, th, z, sub, _ = atom_geometry(t, self.structure.tubes[0],
                                                  self.structure.positions)
            dof = np.arange(t.N) if c is None else c.dof_idx
            coarse = np.ones(len(ids), bool) if c is None else ~np.isin(ids, c.free_idx)
            self._carried_map = (ids, coarse, carriers(t, dof, X[coarse], th[coarse],
                                                       z[coarse], sub[coarse]))
        return self._carried_map

    def _state_shifts(self, state) -> np.ndarray:
        """(N, 3) the shifts of ``state``: ``extra["dcbr.delta"]``, the particle rows' from
        the field with ``shifts="inertial"`` (the two agree after every evaluation)."""
        d = state.extra[FIELD]
        fd = state.fields.get(FIELD) if self.shifts == "inertial" else None
        if fd is None:
            return d
        dof = self._dof()
        d = np.array(d, dtype=float, copy=True)
        d[dof] = fd[:len(dof)]
        return d

    def atom_positions(self, state) -> np.ndarray:
        """(K, 3) Å: every atom of the structure at ``state``, the free ones as they are,
        the others on their carriers' uniform maps with the shifts (:mod:`.pads`; the
        nearest non-slave particle carries each):

            x_a = y_c + Q3_c (h_a(delta_c) + r0_a)     (eq. of :mod:`.pads`).

        For pictures, for comparing with an atomistic run and for interactions with other
        bodies (:meth:`atom_forces` pulls forces on these atoms back); at the reference
        state they are the input atoms."""
        from upscale.models.dcbr.coupling import carried_positions  # noqa: PLC0415

        t, c = self.tube, self.coupling
        ids, coarse, car = self._carried()
        y = np.asarray(state.y, float)
        yp = y if c is None else c.particle_positions(y, self.Lz)
        out = np.array(self.structure.positions, dtype=float, copy=True)
        xa = carried_positions(t, car, yp, self._state_shifts(state), self.Lz,
                               state.extra.get("dcbr.fs_last"))
        if t.periodic:  # the image nearest the input atom (a carrier may sit across z = 0)
            k = np.round(((xa - out[ids[coarse]]) @ t.axis) / self.Lz)
            xa -= np.outer(k * self.Lz, t.axis)
        out[ids[coarse]] = xa
        if c is not None:
            out[c.free_idx] = y[len(c.dof_idx):]
        return out

    def atom_forces(self, state, f) -> tuple:
        """Forces ``f`` (K, 3) eV/Å on the atoms of :meth:`atom_positions` pulled back
        exactly to the rows and the shifts (the chain rule through the map):

            F_i = sum_a (dx_a/dy_i)^T f_a,    G_c = sum_a (dx_a/d delta_c)^T f_a,

        through the carriers' maps x_a(y_c, Q3_c, lam_c, delta_c) (:func:`.pads.
        pad_backward`), the frames' dependence on F_c (:func:`.maps.frame_adjoint`), F_c's
        on the particles through G, and a slave particle's position on its free atoms
        (y_s = X_s + Phi (x - X)). A carrier whose frame is its last good map (failed)
        passes no frame term. Returns (F (n, 3) on the rows, G (n, 3) on the shift field's
        rows: the particle rows', zero on atom rows), eV/Å. With ``shifts="relaxed"`` the
        shifts relaxed for the tube's own energy do not make G vanish: a caller coupling
        other energies to the atoms must then relax the shifts for the sum."""
        from upscale.models.dcbr.maps import frame_adjoint, frame_of, map_frames  # noqa: PLC0415
        from upscale.models.dcbr.pads import pad_backward  # noqa: PLC0415

        t, c = self.tube, self.coupling
        ids, coarse, (ca, ds, dz, sig, r0) = self._carried()
        f = np.asarray(f, dtype=float)
        if f.shape != (len(self.structure.positions), 3):
            raise ValueError(f"atom forces of shape {f.shape}; valid: "
                             f"({len(self.structure.positions)}, 3), one row per atom")
        y = np.asarray(state.y, float)
        yp = np.ascontiguousarray(y if c is None else c.particle_positions(y, self.Lz))
        F = t.gain.deformation(yp, self.Lz)
        par, Q3 = np.empty((t.N, 3)), np.empty((t.N, 3, 3))
        map_frames(F, t.gain.S, t.gain.alive, par, Q3)
        own = np.ones(t.N, bool)
        fs = state.extra.get("dcbr.fs_last")
        if fs is not None:  # as carried_positions: a failed carrier on its last good map
            own = t.alive & t.gain.alive
            for k in np.flatnonzero(~own):
                frame_of(fs[k], par[k], Q3[k])
        gyp, gd = np.zeros((t.N, 3)), np.zeros((t.N, 3))
        gQ3, gpar, P = np.zeros((t.N, 3, 3)), np.zeros((t.N, 3)), np.zeros_like(F)
        pad_backward(np.ascontiguousarray(-f[ids[coarse]]),
                     np.ascontiguousarray(self._state_shifts(state)), par, Q3, own, ca, ds,
                     dz, sig, r0, t.cell.R0, gyp, gd, gQ3, gpar)
        frame_adjoint(F, t.gain.S, t.gain.alive, par, Q3, gQ3, gpar, P)
        gyp -= t.gain.forces(P)
        dof = self._dof()
        Fr, Gr = np.zeros((self.n, 3)), np.zeros((self.n, 3))
        Fr[:len(dof)] = -gyp[dof]
        Gr[:len(dof)] = -gd[dof]
        if c is not None:
            Fr[len(dof):] = f[c.free_idx]
            if len(c.slave_idx):
                Fr[len(dof):] -= c.PhiT @ gyp[c.slave_idx]
        return Fr, Gr

    def grown(self, particles) -> "DCBRModel":
        """A new model of the same atoms whose region also holds the atoms of ``particles``
        (N,) bool (its period set to this one's)."""
        inside = np.asarray(particles, bool).copy()
        if self.coupling is not None:
            inside |= self.coupling.inside
        new = DCBRModel(self.atoms, atomistic_particles=inside, **self.params)
        if self.Lz is not None:
            new.set_cell(self.Lz)
        return new

    def init_state(self, state) -> None:
        if self.coupling is not None:
            state.extra.setdefault("dcbr.fs_last", self.coupling.fs_last.copy())
            # the region (its particles) travels with a checkpoint: a resumed run rebuilds
            # the model with DCBRModel(atoms, atomistic_particles=state.extra["dcbr.inside"])
            state.extra.setdefault("dcbr.inside", self.coupling.inside.copy())
        state.extra.setdefault(FIELD, np.zeros((self.tube.N, 3)))
        state.extra.setdefault("dcbr.intact", self.tube.gain.intact_b.copy())
        state.extra.setdefault("dcbr.alive", self.tube.alive.copy())

    def set_cell(self, Lz: float) -> None:
        """The period (Å) of a periodic tube: the load of a tension scene (mutates)."""
        if self.Lz is None:
            raise ValueError("set_cell on a finite tube; valid: a tube periodic along z")
        _check("Lz", Lz, np.isfinite(Lz) and Lz > 0, "a positive length (Å)")
        self.Lz = float(Lz)
        self._cache = None
        if self.ghost is not None:
            self.ghost.prepare(self.Lz)

    @property
    def stretch_ghost(self) -> bool:
        """True when this (finite, coupled) tube applies the ghost-force load the state's
        extras ask for (:meth:`_sync_ghost`)."""
        return self._ghost_build is not None

    def _sync_ghost(self, state) -> None:
        """A finite tube's ghost-force dead load as the state asks for it (the scene's
        store: ``state.extra["dcbr.ghost"]`` = (lam_z, lam_hold), ``"dcbr.ghost_hold"``
        (n,) the rows held at lam_hold; none: no load), so that a checkpoint carries it and
        a resumed run prepares the same load (:meth:`.ghost.GhostLoad.prepare_stretch`)."""
        if self._ghost_build is None:
            return
        g = state.extra.get("dcbr.ghost")
        h = state.extra.get("dcbr.ghost_hold")
        key = None if g is None else (float(g[0]), float(g[1]),
                                      None if h is None else np.asarray(h, bool).tobytes())
        if key == self._ghost_key:
            return
        self._cache = None
        self._ghost_key = key
        if key is None:
            if self.ghost is not None:
                self.ghost.load = None
            return
        if self.ghost is None:
            self.ghost = GhostLoad(self.coupling, self.structure.tubes[0],
                                   self.structure.positions, self._ghost_build,
                                   self.params["potential"])
        self.ghost.prepare_stretch(key[0], None if h is None else np.asarray(h, bool), key[1])

    def _sync_links(self, state) -> None:
        t = self.tube
        li, la = state.extra.get("dcbr.intact"), state.extra.get("dcbr.alive")
        if li is not None and not (np.array_equal(li, t.gain.intact_b)
                                   and np.array_equal(la, t.alive)):
            t.rebuild(li, la)
            self._cache = None

    def evaluate(self, y, delta, L=None):
        """(E eV, dE/dy (n,3), dE/d delta (N,3), dE/dL eV/Å) at given shifts (no
        relaxation); L the period (default the model's)."""
        L = self.Lz if L is None else L
        d = np.ascontiguousarray(delta)
        if self.coupling is None:
            E, gy, gd, gL, q, e = self.tube.evaluate(y, d, L)
        else:
            E, gy, gd, gL, q = self.coupling.evaluate(y, d, L)
            e = self.coupling.e_n
            if self.ghost is not None and self.ghost.active(L):
                E, gy, gd, dL = self.ghost.apply(np.asarray(y, float), d, E, gy, gd)
                gL += dL
        self._q_n, self._e_n = q, e
        return E, gy, gd, gL

    def _relax(self, y, d) -> None:
        """Relax the shifts ``d`` (mutated) at rows ``y``: each particle's lattice alone
        (Newton, :meth:`.tube.CoarseTube.relax_shifts`), then, with atoms, the whole coupled
        energy (the pads follow their carriers' shifts) by the engine's L-BFGS-B."""
        t = self.tube
        yp = y if self.coupling is None else self.coupling.particle_positions(y, self.Lz)
        t.relax_shifts(yp, d, self.Lz, self.shift_gtol)
        if self.coupling is None:
            return
        from upscale.engine.array_minimisers import lbfgs_b  # noqa: PLC0415

        def fun(v):
            E, _, gd, _ = self.evaluate(y, v.reshape(-1, 3))
            return E, gd.ravel()

        b = t.shift_bound
        r = lbfgs_b(fun, d.ravel().copy(), -b, b, gtol=self.shift_gtol, max_iter=500,
                    memory=10, ftol=1e-15, maxfun=2000)
        d[...] = r.x.reshape(-1, 3)

    def _evaluate(self, state):
        self._sync_links(state)
        self._sync_ghost(state)
        if self.coupling is not None and "dcbr.fs_last" in state.extra:
            self.coupling.fs_last = state.extra["dcbr.fs_last"]  # (kept in the state)
        if self.cell is not None:
            self.set_cell(float(self.cell(state.t)))
        y = np.ascontiguousarray(state.y, dtype=float)
        d = state.extra[FIELD]
        fd = state.fields.get(FIELD) if self.shifts == "inertial" else None
        c = self._cache
        if (c is not None and c[0] == self.Lz and c[1] == self._held
                and np.array_equal(c[2], y) and np.array_equal(c[3], d)
                and (fd is None or np.array_equal(c[5], fd))):
            return c[4]
        if fd is not None:
            self._inertial_shifts(y, d, fd)
        elif not self._held:
            self._relax(y, d)
        out = self.evaluate(y, d, self.Lz)
        self._cache = (self.Lz, self._held, y.copy(), d.copy(), out,
                       None if fd is None else fd.copy())
        return out

    def _dof(self) -> np.ndarray:
        """The particles that are rows (all, or the coupling's non-slave ones)."""
        return np.arange(self.tube.N) if self.coupling is None else self.coupling.dof_idx

    def _inertial_shifts(self, y, d, fd) -> None:
        """``d`` (N, 3, mutated) from the shift field of the rows (``shifts="inertial"``);
        the slave particles' shifts, on no row and in no pad's map, relaxed each alone."""
        dof = self._dof()
        d[dof] = fd[:len(dof)]
        if self.coupling is not None and len(self.coupling.slave_idx):
            mask = np.zeros(self.tube.N, bool)
            mask[self.coupling.slave_idx] = True
            yp = self.coupling.particle_positions(y, self.Lz)
            self.tube.relax_shifts(yp, d, self.Lz, self.shift_gtol, mask)

    def fields(self) -> dict:
        """``{"dcbr.delta": FieldSpec(3, inertia)}`` with ``shifts="inertial"`` (the
        particle rows' shifts, the reduced mass of two sublattices: a quarter of the row's
        mass; atom rows carry no shift), else none."""
        if self.shifts != "inertial":
            return {}
        from upscale.engine.fields import FieldSpec  # noqa: PLC0415

        nd = len(self._dof())
        inertia = np.r_[0.25 * self.masses()[:nd], np.ones(self.n - nd)]
        return {FIELD: FieldSpec(3, inertia, unit="Å", rows=slice(0, nd))}

    def add_field_force(self, state, out) -> None:
        """Adds -dE/d delta of the particle rows to ``out["dcbr.delta"]``."""
        if self.shifts == "inertial":
            dof = self._dof()
            out[FIELD][:len(dof)] -= self._evaluate(state)[2][dof]

    def add_force(self, state, out) -> None:
        out -= self._evaluate(state)[1]

    def energy(self, state) -> float:
        return float(self._evaluate(state)[0])

    def energy_density(self, state) -> np.ndarray:
        """(n,) energy per row (eV): a particle's w_c (e_c - e0) plus its hourglass links,
        an atom's site energy minus e0 (a slave particle's share is not on a row)."""
        self._evaluate(state)
        t, c = self.tube, self.coupling
        e = np.where(t.alive, t.natoms_n * (self._e_n - t.e0), 0.0) + t.hourglass.w_n
        return e if c is None else np.r_[e[c.dof_idx], c.e_atoms - t.e0]

    def cell_force(self, state) -> float:
        """dE/dL (eV/Å): the axial force a periodic tube carries."""
        return float(self._evaluate(state)[3])

    @property
    def internal_fields(self) -> dict:
        """The shifts as a minimiser's massless field (``shifts="relaxed"``)."""
        b = self.tube.shift_bound
        return {FIELD: (-b, b)} if self.shifts == "relaxed" else {}

    @property
    def lattice_states(self) -> np.ndarray:
        """(N, 6) each particle's q = (lam_t, gam, lam_z, shift) of the last evaluation."""
        return self._q_n

    @property
    def held(self) -> bool:
        """True while a minimiser holds the shifts (:meth:`hold_internal`)."""
        return self._held

    def hold_internal(self, flag: bool) -> None:
        """While held the shifts are a minimiser's unknowns; else relaxed at every call."""
        self._held = bool(flag)

    def internal_gradient(self, state) -> dict:
        return {FIELD: self._evaluate(state)[2]}

    def break_bonds(self, state) -> int:
        """The failure rules at the current state: the coarse link rule
        (:func:`.failure.link_rule`), and if no link broke the lattice-stability rule
        (:func:`.stability.check_stability`: on a coarse tube every particle in the failing
        one's state fails with it; with atoms only particles carrying at least half their
        nominal atoms are tested). The links' state in ``state.extra`` is updated. Returns
        the number of links broken (or of particles failed)."""
        self._evaluate(state)
        t = self.tube
        over = link_rule(t, self._q_n) & t.gain.intact_b
        nb, alive = int(over.sum()), t.alive
        if nb == 0 and self.stability is not None:
            cand = np.ones(t.N, bool) if self.coupling is None else \
                t.natoms_n >= 0.5 * self.coupling.nominal
            failed = check_stability(t, self.stability, self._e_n, self._q_n, cand,
                                     all_equal=self.coupling is None)
            nb = int(failed.sum())
            over = failed[t.gain.owner_b] | failed[t.gain.j_b]
            alive = t.alive & ~failed
        if nb:
            t.rebuild(t.gain.intact_b & ~over, alive)
            self._cache = None
            if "dcbr.intact" in state.extra:
                state.extra["dcbr.intact"] = t.gain.intact_b.copy()
                state.extra["dcbr.alive"] = t.alive.copy()
        return nb

    def particle_damage(self, state) -> np.ndarray:
        """(n,) damage per row: a particle's mu = 1 - (intact links) / (links at the start)
        (seed 004 eq. 5.16), a free atom's 1 - (bonds left) / (bonds at the start) (< 2.0 Å
        at the start, broken beyond 2.1 Å: :func:`upscale.models.tersoff.atom_damage`)."""
        from upscale.models.tersoff import atom_damage, initial_bonds  # noqa: PLC0415

        self._sync_links(state)
        t, c = self.tube, self.coupling
        R = np.bincount(t.gain.owner_b[t.gain.intact_b], minlength=t.N)
        mu = 1.0 - R / np.maximum(t.n_links0, 1)
        if c is None:
            return mu
        if getattr(self, "_bonds0", None) is None:
            self._bonds0 = initial_bonds(c.Xf)
        return np.r_[mu[c.dof_idx], atom_damage(state.y[len(c.dof_idx):], self._bonds0)]

    def stiffness_bound(self):
        return None

    def describe(self) -> dict:
        t, c = self.tube, self.coupling
        n, m = self.structure.tubes[0].chirality
        return {"model": self.name, "chirality": [int(n), int(m)], "coarsening": t.coarsening,
                "particles": t.N, "atoms": t.n_atoms, "periodic": t.periodic,
                "hourglass": t.hourglass.fraction,
                "defects": [d.kind for d in self.defects],
                "regions": len(self.regions.regions),
                "free_atoms": 0 if c is None else c.nf,
                "slave_particles": 0 if c is None else len(c.slave_idx),
                "ghost_load": self.ghost is not None, "cell_length_A": self.Lz}
