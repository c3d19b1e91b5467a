"""The open coarse tube with its atomistic region as an engine model (by composition).

:class:`DCBRDefectTubeModel` wraps a :class:`~upscale.models.dcbr_defect.DCBRDefectTube`
(with a vacancy, or pristine: ``vacancy=0``, e.g. the banded tube of
:func:`upscale.experiments.scenes.dcbr_dynamic.pristine_grip_tube`) for the engine's
:class:`~upscale.engine.simulation.Simulation`, alone or as one body of an
:func:`~upscale.engine.bodies.assemble`-d scene.

Rows of the engine's state (``n = N + nf``):

* ``[0, N)``: the N coarse particles in the tube's order. The non-slave ones are unknowns;
  a slave particle (the tube's ``slave_idx``) interpolates free atoms,
  y_s = sum_a Phi_sa (x_a - X_a) + X_s (the tube's ``Phi``), which the engine carries out
  by :class:`~upscale.engine.fields.Tie` conditions (:meth:`DCBRDefectTubeModel.conditions`);
  the model reads the unknown rows only and folds a slave's force into its atoms.
* ``[N, N + nf)``: the free atoms of the atomistic region (the tube's ``free_idx`` order).

The sublattice shifts delta (N, 3) are the field :data:`FIELD` (Å) with inertia (the
reduced mass of a particle's two sublattices, m_C max(w_c, N_c/2) / 4,
:meth:`~upscale.models.dcbr_defect.DCBRDefectTube.masses`); the atom rows carry the field
too (it has one row per engine row) and hold it at zero. Forces are per row
(``force_kind = "particle"``, eV/Å); masses and the shift inertia are given in amu divided
by ``unit`` (default :data:`upscale.constants.ACC_EV_A_AMU_IN_A_FS2`), so that with eV/Å
forces the accelerations are in Å/fs^2 and time steps in fs.

Energy and forces: :meth:`DCBRDefectTube.energy_and_gradient` at the tube's unknowns and
shifts and the cell length ``Lz`` (an open tube's fixed cell), with the tube's ghost-force
correction (:meth:`DCBRDefectTubeModel.store_ghost` after the scene has refreshed it). The
failure rules (the coarse link rule, optionally the lattice-stability rule) are applied by
:meth:`DCBRDefectTubeModel.break_links` (the dynamic scene: every sample), or in every force
evaluation with ``failure=True``.

History in ``state.extra`` (so a checkpoint carries it and a resumed run continues bit for
bit): the links (``dcbr.intact``, ``dcbr.alive``), each particle's last good map
(``dcbr.fs_last``), the ghost-force dead load (``dcbr.ghost.*``) and the positions at which
the atomistic Verlet list was built (``dcbr.nl_x``: the list is rebuilt there on resume, so
the rebuilds fall on the same steps; its partners are sorted, so the forces do not depend on
where it was built).

Atoms for interactions between bodies (:meth:`DCBRDefectTubeModel.atoms`,
:meth:`DCBRDefectTubeModel.atom_forces`): every atom of the tube, the free ones as they
are and the others reconstructed from their carriers' uniform maps (as the pad atoms,
:meth:`DCBRDefectTube.atom_map`); forces on them map back exactly (the chain rule through
the maps and G) to generalised forces on the rows and the shift field.
"""
from __future__ import annotations

import numpy as np

from upscale.constants import ACC_EV_A_AMU_IN_A_FS2, CARBON_MASS_AMU
# (the kernels at module level: an import statement in a method costs microseconds per call,
# and the fast group's methods run thousands of times per simulated ps)
from upscale.models import dcbr_coupling_kernels as CK

__all__ = ["DCBRDefectTubeModel", "FIELD", "STATIC"]

#: the name of the sublattice-shift field
FIELD = "dcbr.delta"
#: the particles' shifts as a minimiser's internal field (:meth:`DCBRDefectTubeModel.static_shifts`)
STATIC = "dcbr.delta.static"

_GHOST = ("y", "d", "gy", "gd")

#: the force splits by name (``DCBRDefectTubeModel(split=...)``): the flags each sets
SPLITS = {"coarse": {"fast_interface": False, "fast_ghost": False},
          "atoms-free": {"fast_interface": True, "fast_ghost": True},
          "interface": {"fast_interface": True, "fast_ghost": False},
          "ghost": {"fast_interface": False, "fast_ghost": True}}

#: the split of the single-tube dynamic scenes under multiple time stepping
#: (:func:`upscale.experiments.scenes.dcbr_dynamic.dynamic_tension`, ``bench-dcbr-seed``,
#: ``dcbr-stability``): the ghost-force dead load in the fast group. The dead load acts on
#: the atoms in cylindrical components, so its direction turns with every vibrating atom;
#: applied as an impulse once per outer step it is what makes the energy of the ``"coarse"``
#: split drift at a 5 fs outer step, while the interface particles' lattice energy, also
#: felt by the atoms, does not. Moving only the dead load costs one more evaluation of it
#: per inner step; the interface particles' energy would cost a share of the coarse part.
MTS_SPLIT = "ghost"


class _Energy:
    """A force group's energy (eV), evaluated on the first ``float()``: the time loop reads
    the groups' forces at every step and their energies only when it reports."""

    __slots__ = ("_parts", "_value")

    def __init__(self, fn, *args):
        self._parts, self._value = (fn, args), None

    def __float__(self) -> float:
        if self._value is None:
            fn, args = self._parts
            self._value, self._parts = float(fn(*args)), None
        return self._value


class DCBRDefectTubeModel:
    """A :class:`~upscale.models.dcbr_defect.DCBRDefectTube` as an engine model (module
    docstring).

    Parameters
    ----------
    tube : DCBRDefectTube
        Open or periodic; the model mutates its links on failure.
    y, delta : arrays, optional
        The tube's unknowns (non-slave particles, then free atoms; (nd + nf, 3)) and shifts
        (N, 3) of the initial state (default the reference lattice, zero shifts): the rows'
        positions of :meth:`system` and the shift field of :meth:`init_state`.
    Lz : float, optional
        Cell length the energy is called with (Å; default the tube's ``L``); an open tube's
        energy does not depend on it, but the ghost-force correction is keyed on it.
    failure : bool
        Apply the link rule (and ``stability``) in every force evaluation (default False:
        the scene calls :meth:`break_links`).
    stability : bool
        With the link rule, also the lattice-stability rule.
    unit : float
        Masses and inertia are amu / ``unit`` (default: Å/fs^2 per eV/(Å amu)).
    fast_interface, fast_ghost : bool
        The force split (:meth:`add_group_force`): with both, the slow group does not
        depend on the atoms at all. ``fast_interface`` moves the lattice energy and the
        hourglass links of the interface particles (the coarse particles with a slave in
        their G stencil, whose maps move with the atoms through the slaves) to the fast
        group; ``fast_ghost`` the ghost-force dead load (in cylindrical components, so not
        constant on a vibrating atom). Without them (default) those forces reach the atoms
        as impulses once per outer step. Both cost their terms at every inner step.
    split : str, optional
        The two flags by name (:data:`SPLITS`): ``"coarse"`` neither (every coarse force
        slow), ``"atoms-free"`` both, ``"interface"`` and ``"ghost"`` one each; given, it
        overrides them.
    """

    name = "dcbr-defect-tube"
    force_kind = "particle"

    def __init__(self, tube, *, y=None, delta=None, Lz: float | None = None,
                 failure: bool = False, stability: bool = False,
                 unit: float = ACC_EV_A_AMU_IN_A_FS2, fast_interface: bool = False,
                 fast_ghost: bool = False, split: str | None = None):
        from upscale.models.base import Needs
        from upscale.models.dcbr_defect import DCBRDefectTube

        if not isinstance(tube, DCBRDefectTube):
            raise ValueError(f"DCBRDefectTubeModel takes a DCBRDefectTube, got "
                             f"{type(tube).__name__}")
        if split is not None:
            if split not in SPLITS:
                raise ValueError(f"split={split!r}; valid: {', '.join(map(repr, SPLITS))}")
            fast_interface, fast_ghost = (SPLITS[split][k] for k in ("fast_interface",
                                                                   "fast_ghost"))
        if not (np.isfinite(unit) and unit > 0):
            raise ValueError(f"unit={unit!r}; valid: a positive mass unit factor")
        self.tube = tube
        self.N, self.nf, self.nd = int(tube.N), int(tube.nf), int(len(tube.dof_idx))
        self.n = self.N + self.nf
        self.y_rows = np.r_[tube.dof_idx, self.N + np.arange(self.nf)].astype(np.int64)
        self.atom_rows = self.N + np.arange(self.nf)
        self.unit = float(unit)
        self.Lz = float(tube.L if Lz is None else Lz)
        if not (np.isfinite(self.Lz) and self.Lz > 0):
            raise ValueError(f"Lz={Lz!r}; valid: a positive cell length (Å)")
        self.set_initial(tube.y_init if y is None else y,
                         np.zeros((self.N, 3)) if delta is None else delta)
        self.stability = bool(stability)
        self.needs = Needs(pairs=False, failure=bool(failure), energy=True)
        self._cache = None
        self._slow_cache = self._fast_cache = None
        self._split_ref = None  # the split's transfer (prepare_split)
        self._split_src = None
        self._sub = None  # the pads' carriers' G (_carriers)
        self._iface = None  # the interface particles' G (_interface)
        self.fast_interface = bool(fast_interface)
        self.fast_ghost = bool(fast_ghost)
        self._version = 0  # bumped when the links or the ghost-force correction change
        self._ghost_version = 0
        self._map = None
        self._synced = None
        self._nl_seen = (None, None)  # the Verlet reference last copied into the state
        self._static = False  # the shifts a minimiser's internal field (static_shifts)
        self.system_ = None

    # ------------------------------------------------------------------ rows and masses
    def set_initial(self, y, delta) -> None:
        """The initial unknowns (nd + nf, 3) and shifts (N, 3) (see the class)."""
        y = np.asarray(y, dtype=np.float64)
        delta = np.asarray(delta, dtype=np.float64)
        if y.shape != (self.nd + self.nf, 3) or delta.shape != (self.N, 3):
            raise ValueError(f"y {y.shape}, delta {delta.shape}; valid: y "
                             f"({self.nd + self.nf}, 3) (non-slave particles, then free "
                             f"atoms) and delta ({self.N}, 3)")
        self.y0, self.delta0 = y.copy(), delta.copy()

    def rows(self, y) -> np.ndarray:
        """Row positions (n, 3) from the tube's unknowns ``y``: every particle (slaves
        interpolated), then the free atoms."""
        return np.vstack([self.tube.particle_positions(y), np.asarray(y)[self.nd:]])

    def unknowns(self, state):
        """(y, delta): the tube's unknowns (a new array) and shifts (a view) of ``state``."""
        return CK.take_rows(state.y, self.y_rows), state.fields[FIELD][:self.N]

    def masses(self) -> np.ndarray:
        """Mass of every row (n,), amu / ``unit``: a particle m_C max(w_c, N_c/2) (slaves
        too, whose motion their atoms set), a free atom m_C."""
        t = self.tube
        w = np.maximum(t.natoms_n, 0.5 * t.nominal) * CARBON_MASS_AMU
        return np.r_[w, np.full(self.nf, CARBON_MASS_AMU)] / self.unit

    def fields(self) -> dict:
        """``{FIELD: FieldSpec(3, inertia)}``: a particle's shift has the reduced mass of
        its two sublattices (a quarter of its mass); the atom rows' (held at zero) unit."""
        from upscale.engine.fields import FieldSpec

        inertia = self.masses()
        inertia[:self.N] *= 0.25
        inertia[self.N:] = 1.0
        return {FIELD: FieldSpec(3, inertia, unit="Å")}

    def system(self):
        """A :class:`~upscale.engine.system.ParticleSystem` of the rows at the initial
        state (volume 1, density the row masses, spacing the bond length)."""
        from upscale.engine.system import ParticleSystem

        return ParticleSystem(self.rows(self.y0), 1.0, density=self.masses(),
                              spacing=float(self.tube.lattice.bond), units="atomic")

    def body(self, name: str = "tube"):
        """This model on its :meth:`system` as an :class:`~upscale.engine.bodies.Body`."""
        from upscale.engine.bodies import Body

        return Body(self.system(), None, [self], name)

    def conditions(self, n_total: int | None = None, offset: int = 0, *, field: str = FIELD,
                   held_shifts=None, prefix: str = "") -> list:
        """The conditions the rows need: the slave particles tied to their atoms
        (:class:`~upscale.engine.fields.Tie`, x, y, z) and the atom rows' shift held at
        zero (:class:`~upscale.engine.fields.FixedField`); ``held_shifts`` (N,) bool: the
        particles whose shifts are also held at their current value (a rigid grip's).
        In an assembly: ``n_total`` rows, this body's rows from ``offset``, its field
        ``"<body>/" + FIELD``; ``prefix`` names the regions."""
        from upscale.engine.conditions import Region
        from upscale.engine.fields import FixedField, Tie

        n = self.n if n_total is None else int(n_total)
        out = []
        t = self.tube
        if len(t.slave_idx):
            phi = t.Phi.tocsr()
            p = int(np.diff(phi.indptr).max())
            ms = np.full((len(t.slave_idx), p), offset + self.N, np.int64)
            ws = np.zeros((len(t.slave_idx), p))
            for k in range(len(t.slave_idx)):
                a, b = phi.indptr[k], phi.indptr[k + 1]
                ms[k, :b - a] = offset + self.N + phi.indices[a:b]
                ws[k, :b - a] = phi.data[a:b]
            mask = np.zeros(n, bool)
            mask[offset + t.slave_idx] = True
            reg = Region(f"{prefix}slave particles", mask)
            out += [Tie(reg, ms, ws, ("y", c)) for c in range(3)]
        hold = np.zeros(n, bool)
        hold[offset + self.atom_rows] = True
        if held_shifts is not None:
            hs = np.asarray(held_shifts, bool)
            if hs.shape != (self.N,):
                raise ValueError(f"held_shifts of shape {hs.shape}; valid: ({self.N},)")
            hold[offset + np.nonzero(hs)[0]] = True
        out.append(FixedField(Region(f"{prefix}held shifts", hold), field, (0, 1, 2), hold=True))
        return out

    # ------------------------------------------------------------------ the contract
    def prepare(self, system, family=None, **kw) -> None:
        if system.dim != 3:
            raise ValueError(f"the tube model needs a 3D body, got dim={system.dim}")
        if system.n != self.n:
            raise ValueError(f"the body has {system.n} rows, the tube model {self.n} (its "
                             f"{self.N} particles, then its {self.nf} free atoms); valid: "
                             "DCBRDefectTubeModel.system()")
        self.system_ = system

    def init_state(self, state) -> None:
        t = self.tube
        d = np.zeros((self.n, 3))
        d[:self.N] = self.delta0
        state.fields.setdefault(FIELD, d)
        state.field_v.setdefault(FIELD, np.zeros((self.n, 3)))
        ex = state.extra
        ex.setdefault("dcbr.intact", t.intact.copy())
        ex.setdefault("dcbr.alive", t.alive.copy())
        ex.setdefault("dcbr.fs_last", t.last_maps.copy())
        ref = t.neighbour_reference
        ex.setdefault("dcbr.nl_x", np.full((self.nf + len(t.pad_idx), 3), np.nan)
                      if ref is None else ref.copy())
        tw = t.twin
        if tw is not None:
            ref = tw.neighbour_reference
            ex.setdefault("dcbr.twin_nl_x", np.full((tw.nf + len(tw.pad_idx), 3), np.nan)
                          if ref is None else ref.copy())
        g = t.ghost_correction
        ex.setdefault("dcbr.ghost_version", np.array(self._ghost_version, np.int64))
        ex.setdefault("dcbr.ghost_on", np.array(g is not None))
        ex.setdefault("dcbr.ghost.Lz", np.array(np.nan if g is None else g["Lz"], np.float64))
        ex.setdefault("dcbr.ghost.dL", np.array(0.0 if g is None else g["dL"], np.float64))
        for k, shape in zip(_GHOST, ((self.nd + self.nf, 3), (self.N, 3)) * 2):
            ex.setdefault(f"dcbr.ghost.{k}", np.zeros(shape) if g is None else
                          np.array(g[k], np.float64, copy=True))

    def _sync(self, state) -> None:
        """Give the tube the state's history where it differs (a resumed state). The
        extras are the arrays this model writes in place; while they are the same objects
        as at the last sync, nothing else has changed them."""
        t, ex = self.tube, state.extra
        key = ex.get("dcbr.fs_last")
        if key is not None and key is self._synced:
            return
        self._synced = key
        li, la = ex.get("dcbr.intact"), ex.get("dcbr.alive")
        if li is not None and not (np.array_equal(li, t.intact) and np.array_equal(la, t.alive)):
            t.set_links(li, la)
            self._changed()
        fs = ex.get("dcbr.fs_last")
        if fs is not None and not np.array_equal(fs, t.last_maps):
            t.last_maps = fs
            self._cache = self._slow_cache = self._fast_cache = None
        gv = ex.get("dcbr.ghost_version")
        if gv is not None and int(gv) != self._ghost_version:
            t.ghost_correction = None if not bool(ex["dcbr.ghost_on"]) else {
                "Lz": float(ex["dcbr.ghost.Lz"]), "dL": float(ex["dcbr.ghost.dL"]),
                **{k: np.array(ex[f"dcbr.ghost.{k}"], copy=True) for k in _GHOST}}
            self._ghost_version = int(gv)
            self._changed()
        H = ex.get("dcbr.split.H")
        if H is not None and H is not self._split_src:  # a resumed state's split
            self._split_ref = {k: np.array(ex[f"dcbr.split.{k}"], copy=True)
                               for k in ("y", "d", "gy", "gd", "H")}
            self._split_src = H
            self._slow_cache = self._fast_cache = None
        for tube, key in ((t, "dcbr.nl_x"), (t.twin, "dcbr.twin_nl_x")):
            x = ex.get(key)
            if tube is None or x is None or not np.all(np.isfinite(x)):
                continue
            ref = tube.neighbour_reference
            if ref is None or not np.array_equal(ref, x):
                tube.rebuild_neighbours(x)
                self._cache = self._slow_cache = self._fast_cache = None

    def _changed(self) -> None:
        self._version += 1
        self._cache = self._slow_cache = self._fast_cache = None

    def _is_current(self, c, y, d) -> bool:
        """Whether cache entry ``c`` = (version, y, delta, value) holds for these links and
        this state."""
        return (c is not None and c[0] == self._version and c[1].shape == y.shape
                and c[2].shape == d.shape and CK.same(c[1], y) and CK.same(c[2], d))

    def _evaluate(self, state):
        """(E, dE/dy, dE/d delta, dE/dLz) at ``state``, from the cache while the links and
        the state's unknowns and shifts are those it was computed at (an energy, the forces
        and the shift gradient of one minimiser evaluation are one computation)."""
        self._sync(state)
        c = self._cache
        d = state.fields[FIELD][:self.N]
        if (c is not None and c[0] == self._version and c[2].shape == d.shape
                and CK.same_rows(c[1], state.y, self.y_rows) and CK.same(c[2], d)):
            return c[3]
        y = CK.take_rows(state.y, self.y_rows)
        t = self.tube
        E, gy, gd, dL = t.energy_and_gradient(y, d, self.Lz)
        ex = state.extra
        if "dcbr.fs_last" in ex:
            ex["dcbr.fs_last"][...] = t.last_maps
            ref, held = t.neighbour_reference, ex["dcbr.nl_x"]
            # a rebuilt Verlet list is a new array: copied into the state once
            if ref is not None and (ref is not self._nl_seen[0] or held is not self._nl_seen[1]):
                held[...] = ref
                self._nl_seen = (ref, held)
        out = (float(E), gy, gd, float(dL))
        self._cache = (self._version, y, np.array(d, copy=True), out)
        return out

    def add_force(self, state, out) -> None:
        """Adds -dE/dy to the unknown rows (a slave's part is in its atoms' rows)."""
        _sub_rows(out, self.y_rows, self._evaluate(state)[1])

    def add_field_force(self, state, out) -> None:
        """Adds -dE/d delta to the particle rows of the shift field."""
        out[FIELD][:self.N] -= self._evaluate(state)[2]

    # ------------------------------------------------------------------ force split
    def _coarse_eval(self, y, d):
        """(E_c, dE_c/dy, dE_c/d delta) of the coarse particles' lattice energy and
        hourglass term, sum_c w_c (e(C_c, delta_c) - e0) + W_stab (module docstring of
        :mod:`upscale.models.dcbr_defect`), with the ghost-force dead load, at unknowns
        ``y`` and shifts ``d``; a slave's part folded into its atoms as in the total. (The
        dead load is nearly constant: its constant part goes to the fast group with the
        transfer of :meth:`prepare_split`.) With ``fast_interface`` the sum runs over the
        particles other than the interface ones (:meth:`_rows_part`), which are fast."""
        t = self.tube
        d = np.ascontiguousarray(d, dtype=float)
        yp = self._particle_positions(y)
        it = self._interface()
        if it is None:
            E, _, P, gd, gys, _ = t._coarse_part(yp, d, self.Lz)
            gyp = gys - t.gain.forces(P)
        else:  # the interface particles are fast (:meth:`_fast_eval`): the rest only
            E, gyp, gd = self._rows_part(yp, d, it[1])
        if self.fast_ghost:
            return float(E), self._fold(y, gyp, None), gd
        return self._ghost_term(y, d, float(E), self._fold(y, gyp, None), gd)

    def _slow_eval(self, state):
        """(E_slow, dE_slow/dy, dE_slow/d delta): the coarse energy E_c less its transfer
        Q (:meth:`prepare_split`)."""
        self._sync(state)
        y, d = self.unknowns(state)
        c = self._slow_cache
        if self._is_current(c, y, d):
            return c[3]
        E, gy, gd = self._coarse_eval(y, d)
        q = self._transfer(y, d)
        if q is not None:
            E, gy, gd = E - q[0], gy - q[1], gd - q[2]
        self._store_history(state)
        out = (E, gy, gd)
        self._slow_cache = (self._version, y, np.array(d, copy=True), out)
        return out

    def _store_history(self, state) -> None:
        """The carriers' last maps and the Verlet list's positions into ``state.extra``
        (once per outer step, with the slow group: a checkpoint follows a whole step)."""
        t, ex = self.tube, state.extra
        if "dcbr.fs_last" in ex:
            ex["dcbr.fs_last"][...] = t.last_maps
            ref = t.neighbour_reference
            if ref is not None and not np.array_equal(ref, ex["dcbr.nl_x"]):
                ex["dcbr.nl_x"][...] = ref

    def _transfer(self, y, d):
        """(Q, dQ/dy, dQ/d delta) of the split's transfer, or None (:meth:`prepare_split`)."""
        r = self._split_ref
        if r is None:
            return None
        gq = np.empty((self.N, 3))
        Q = CK.transfer(np.ascontiguousarray(y, dtype=float), r["y"],
                        np.ascontiguousarray(d, dtype=float), r["d"], r["gy"], r["gd"], r["H"],
                        gq)
        return float(Q), r["gy"], gq

    def prepare_split(self, state, h: float = 1e-4) -> None:
        """Choose the force split about the current state (the engine's split contract,
        :mod:`upscale.engine.respa`; the total is unchanged). The sublattice shifts are the
        coarse energy's fastest motion (the optical mode of the two sublattices, the
        reduced mass a quarter of a particle's: about the atoms' own period), so the
        coarse energy's expansion to second order in the shifts, with its gradient in the
        positions,

            Q = g_y . (y - y_r) + g_d . (delta - delta_r)
                + 1/2 sum_c (delta_c - delta_rc)^T H_c (delta_c - delta_rc),

        (g_y, g_d its gradient at the reference r, H_c = d^2 E_c / d delta_c^2 its 3x3
        blocks, by forward differences of step ``h`` Å: e(C_c, delta_c) is a particle's
        own) moves to the fast group: E_slow = E_c - Q, E_fast = E_atoms + E_ghost + Q.
        What stays slow is the coarse energy's change of stiffness and the acoustic
        motion of the particles; the constant part of the slow forces, which would
        otherwise be applied as impulses once per outer step (on the atoms through the
        slaves), is applied at every inner step. Call it again as the state moves (the
        dynamic scene: every sample)."""
        self._sync(state)
        self._split_ref = None
        y, d = self.unknowns(state)
        d = np.array(d, copy=True)
        _, gy0, gd0 = self._coarse_eval(y, d)
        H = np.empty((self.N, 3, 3))
        for k in range(3):
            dp = d.copy()
            dp[:, k] += h
            H[:, :, k] = (self._coarse_eval(y, dp)[2] - gd0) / h
        H = 0.5 * (H + H.transpose(0, 2, 1))
        self._split_ref = {"y": y.copy(), "d": d, "gy": gy0, "gd": gd0, "H": H}
        for k, v in self._split_ref.items():  # (a checkpoint carries the split)
            state.extra[f"dcbr.split.{k}"] = v
        self._split_src = state.extra["dcbr.split.H"]
        self._slow_cache = self._fast_cache = None

    def _fold(self, y, gyp, gx):
        """dE/d(unknowns) (nd + nf, 3) from dE/d(particle positions) ``gyp`` (N, 3) and
        dE/d(free atoms) ``gx`` (nf, 3) or None: a slave's gradient goes to its atoms by
        Phi^T (y_s = Phi (x - X) + X_s)."""
        c = self._csr()
        gy = np.empty_like(y)
        CK.fold_gradient(np.ascontiguousarray(gyp, dtype=float),
                         np.zeros((0, 3)) if gx is None else np.ascontiguousarray(gx, dtype=float),
                         self.nd, c["dof"], c["slave"], c["pT"], c["iT"], c["dT"], gy)
        return gy

    def _csr(self):
        """The slaves' interpolation Phi and Phi^T as flat CSR arrays (for the kernels of
        :meth:`_particle_positions` and :meth:`_fold`), rebuilt when the tube's Phi is."""
        t = self.tube
        c = getattr(self, "_csr_cache", None)
        key = (t.Phi, t._PhiT, t.dof_idx, t.slave_idx, t.slave_off)
        if c is not None and all(a is b for a, b in zip(c["key"], key)):
            return c
        phi, phit = t.Phi.tocsr(), t._PhiT.tocsr()
        c = {"key": key,
             "dof": np.ascontiguousarray(t.dof_idx, dtype=np.int64),
             "slave": np.ascontiguousarray(t.slave_idx, dtype=np.int64),
             "p": np.ascontiguousarray(phi.indptr, dtype=np.int64),
             "i": np.ascontiguousarray(phi.indices, dtype=np.int64),
             "d": np.ascontiguousarray(phi.data, dtype=float),
             "pT": np.ascontiguousarray(phit.indptr, dtype=np.int64),
             "iT": np.ascontiguousarray(phit.indices, dtype=np.int64),
             "dT": np.ascontiguousarray(phit.data, dtype=float),
             "off": np.ascontiguousarray(np.reshape(t.slave_off, (-1, 3)), dtype=float)}
        self._csr_cache = c
        return c

    def _particle_positions(self, y):
        """:meth:`DCBRDefectTube.particle_positions` (the same numbers) in one kernel."""
        c = self._csr()
        yp = np.empty((self.N, 3))
        CK.particle_positions(np.ascontiguousarray(y, dtype=float), self.nd, c["dof"],
                              c["slave"], c["p"], c["i"], c["d"], c["off"], yp)
        return yp

    def _restricted_gain(self, rows):
        """G restricted to the rows ``rows`` (a :class:`~upscale.models.gain.GainOperator`
        of len(rows) particles whose stencils still index all N particles)."""
        import dataclasses  # noqa: PLC0415

        g = self.tube.gain
        cnt = np.diff(g.offsets)[rows]
        offs = np.zeros(len(rows) + 1, np.int64)
        np.cumsum(cnt, out=offs[1:])
        ent = (np.repeat(g.offsets[rows] - offs[:-1], cnt)
               + np.arange(offs[-1], dtype=np.int64))  # (each row's stencil entries)
        sel = {k: (None if getattr(g, k) is None else getattr(g, k)[rows])
               for k in ("F0", "frame", "normal", "n_family", "alive", "offset")}
        return dataclasses.replace(g, offsets=offs, neighbors=g.neighbors[ent],
                                   image=g.image[ent], coef=g.coef[ent],
                                   fit_beta=None if g.fit_beta is None else g.fit_beta[ent],
                                   **sel)

    def _carriers(self):
        """The pads' carriers as a G restricted to their rows (the fast group needs the maps
        of these particles only): (rows (nc,), each pad's carrier in them, the
        restricted :class:`~upscale.models.gain.GainOperator`); rebuilt with G."""
        t = self.tube
        g = t.gain
        if self._sub is not None and self._sub[0] is g:
            return self._sub[1]
        c = t._pad["c"]
        rows = np.unique(c)
        loc = np.ascontiguousarray(np.searchsorted(rows, c), dtype=np.int64)
        out = (rows, loc, self._restricted_gain(rows))
        self._sub = (g, out)
        return out

    def _interface(self):
        """The interface particles (``fast_interface``): the coarse particles with a slave
        particle in their G stencil, whose maps (and hourglass links) therefore move with
        the atoms. Returns None, or ``(iface, rest)``: each a tuple (rows (n,), G restricted
        to them (:meth:`_restricted_gain`), the hourglass links they own (a dict of the link
        arrays, or None)) for the interface particles and for all the others; rebuilt with
        G and the links."""
        t = self.tube
        g = t.gain
        if not self.fast_interface or not len(t.slave_idx):
            return None
        st = getattr(t, "_st", None)
        key = (g, st, None if st is None else st["w"])
        if self._iface is not None and all(a is b for a, b in zip(self._iface[0], key)):
            return self._iface[1]
        slave = np.zeros(self.N, bool)
        slave[t.slave_idx] = True
        owner = np.repeat(np.arange(self.N), np.diff(g.offsets))
        hit = np.zeros(self.N, bool)
        np.logical_or.at(hit, owner, slave[g.neighbors])
        hit = (hit | slave) & (t.natoms_n > 0)  # (a slave with atoms of its own: itself)
        out = None
        if hit.any():
            parts = []
            for sel in (hit, ~hit):
                rows = np.nonzero(sel)[0]
                links = None
                if st is not None and t.k_stab != 0.0 and len(st["c"]):
                    keep = sel[st["c"]]
                    if keep.any():
                        links = {k: np.ascontiguousarray(v[keep]) if isinstance(v, np.ndarray)
                                 and len(v) == len(keep) else v for k, v in st.items()}
                parts.append((rows, self._restricted_gain(rows), links))
            out = tuple(parts)
        self._iface = (key, out)
        return out

    def _rows_part(self, yp, d, part):
        """(E_r, dE_r/d(particle positions) (N,3), dE_r/d delta (N,3)) of the lattice energy
        and the hourglass links of the particles of ``part`` (one of :meth:`_interface`),
        sum_{c in part} w_c (e(C_c, delta_c) - e0) + W_stab,c: the kernels of the whole
        coarse part (:meth:`DCBRTube._coarse_part`) on these owners only, with G, the maps
        and G^T restricted to their rows, so that the interface part and the rest add up
        to the whole to round-off."""
        from upscale.models import dcbr_kernels as K  # noqa: PLC0415

        rows, sg, links = part
        t, N = self.tube, self.N
        lat = t.lattice
        F = sg.deformation(yp, np.array([0.0, 0.0, self.Lz]))
        nr = len(rows)
        P = np.empty((nr, 3, 2))
        gds = np.empty((nr, 3))
        S = np.ascontiguousarray(t.S[rows])
        E = K.coarse_energy(F, S, np.ascontiguousarray(d[rows]),
                            np.ascontiguousarray(t.natoms_n[rows]),
                            np.ascontiguousarray(t.alive[rows]), lat.s, lat.z, lat.sub, lat.R0,
                            lat.iA, lat.iB, lat.candA, lat.candB, t.p, t.e0, P, gds,
                            np.empty(nr), np.zeros((nr, 6)))
        if not t.relax_shift:
            gds[:] = 0.0
        gys = np.zeros((N, 3))
        if links is not None:
            ga = sg.alive if sg.alive is not None else np.ones(nr, bool)
            par_r = np.empty((nr, 3))
            Q3_r = np.empty((nr, 3, 3))
            CK.map_frames(F, S, ga, np.ascontiguousarray(t.alive[rows]), np.empty((nr, 3, 2)),
                          par_r, Q3_r, np.empty(nr, np.int8))
            par = np.zeros((N, 3))  # (the links index their owners among all N)
            Q3 = np.zeros((N, 3, 3))
            par[rows] = par_r
            Q3[rows] = Q3_r
            gQ3 = np.zeros((N, 3, 3))
            gpar = np.zeros((N, 3))
            Es, _ = CK.stab_links(np.ascontiguousarray(yp, dtype=float), float(self.Lz),
                                  links["c"], links["j"], links["imz"], links["w"], links["ds"],
                                  links["dz"], links["r0"], links["a"], links["s"], t.k_stab,
                                  lat.R0, par, Q3, gys, np.zeros(N), gQ3, gpar)
            CK.frame_adjoint(F, S, ga, par_r, Q3_r, np.ascontiguousarray(gQ3[rows]),
                             np.ascontiguousarray(gpar[rows]), P)
            E += Es
        gyp = gys - sg.forces(P, out=np.empty((N, 3)))
        gd = np.zeros((N, 3))
        gd[rows] = gds
        return float(E), gyp, gd

    def _fast_eval(self, state):
        """(E_fast, dE_fast/dy, dE_fast/d delta): the rest of the tube's energy, the free
        atoms' Tersoff site energies with the pad atoms on their carriers' maps,
        sum_a (E_a - e0), with the transfer of :meth:`prepare_split`. Computed without the
        particles' lattice energies: the carriers' maps (G on their rows only), the pads
        and the chain rule back through G^T are all it needs of the coarse part, so it
        is the cheap group."""
        self._sync(state)
        y, d = self.unknowns(state)
        c = self._fast_cache
        if self._is_current(c, y, d):
            return c[3]
        t, nd, nf, N = self.tube, self.nd, self.nf, self.N
        rows, loc, sg = self._carriers()
        nc = len(rows)
        dc = np.ascontiguousarray(d, dtype=float)
        ds = np.ascontiguousarray(dc[rows])
        yp = self._particle_positions(y)
        F = sg.deformation(yp, np.array([0.0, 0.0, self.Lz]))
        FS = np.empty((nc, 3, 2))
        par = np.empty((nc, 3))
        Q3 = np.empty((nc, 3, 3))
        flag = np.empty(nc, np.int8)
        S = t.S[rows]
        ga = sg.alive if sg.alive is not None else np.ones(nc, bool)
        CK.map_frames(F, S, ga, t.alive[rows], FS, par, Q3, flag)
        fsl = CK.keep_maps(FS, flag, rows, t._FS_last, np.empty((nc, 3, 2)))
        pd, R0 = t._pad, t.lattice.R0
        x = np.empty((nf + len(t.pad_idx), 3))
        x[:nf] = y[nd:]
        CK.pad_positions(np.ascontiguousarray(yp[rows]), ds, par, Q3, flag, fsl, loc,
                         pd["ds"], pd["dz"], pd["sig"], pd["r0"], R0, x[nf:])
        Ea, gx = t._atomistic(x)
        E = Ea - nf * t.e0
        gys = np.zeros((nc, 3))
        gds = np.zeros((nc, 3))
        gQ3 = np.zeros((nc, 3, 3))
        gpar = np.zeros((nc, 3))
        P = np.zeros((nc, 3, 2))
        CK.pad_backward(np.ascontiguousarray(gx[nf:]), ds, par, Q3, flag, fsl, loc,
                        pd["ds"], pd["dz"], pd["sig"], pd["r0"], R0, bool(t.relax_shift),
                        gys, gds, gQ3, gpar)
        CK.frame_adjoint(F, S, ga, par, Q3, gQ3, gpar, P)
        gyp = -sg.forces(P, out=np.empty((N, 3)))
        gyp[rows] += gys
        gd = np.zeros((N, 3))
        gd[rows] = gds
        it = self._interface()
        if it is not None:
            b = self._rows_part(yp, dc, it[0])
            E, gyp, gd = E + b[0], gyp + b[1], gd + b[2]
        gy = self._fold(y, gyp, gx[:nf])
        dcopy = np.array(d, copy=True)
        work = None
        if self.fast_ghost:  # its gradient now, its work when the energy is asked for
            gy, gd = t.ghost_load_gradient(y, self.Lz, gy, gd)
            work = (y, dcopy)
        q = self._transfer(y, dc)
        if q is not None:  # (gy, gd are this evaluation's own arrays: added in place)
            np.add(gy, q[1], out=gy)
            np.add(gd, q[2], out=gd)
        out = (_Energy(self._fast_energy, E, work, None if q is None else q[0]), gy, gd)
        self._fast_cache = (self._version, y, dcopy, out)
        return out

    def _fast_energy(self, E, work, q0) -> float:
        """E_fast from its parts (the order of :meth:`DCBRDefectTube.apply_ghost_load`,
        then the transfer): ``E`` the atoms' and interface part, ``work`` the (y, delta) of
        the dead load's work (None when it is slow), ``q0`` the transfer's energy."""
        if work is not None:
            E -= self.tube.ghost_load_work(work[0], work[1], self.Lz)
        if q0 is not None:
            E = E + q0
        return float(E)

    def _ghost_term(self, y, delta, E, gy, gd):
        """The ghost-force dead load of :meth:`DCBRDefectTube.energy_and_gradient` (in each
        row's cylindrical components about the rows' centroid) applied to (E, gy, gd)."""
        return self.tube.apply_ghost_load(y, delta, self.Lz, E, gy, gd)[:3]

    def _group(self, state, group):
        if group == "slow":
            return self._slow_eval(state)
        if group == "fast":
            return self._fast_eval(state)
        raise ValueError(f"force group {group!r}; valid: 'fast' or 'slow'")

    def add_group_force(self, state, out, group: str) -> None:
        """Adds the ``group``'s part of :meth:`add_force` (the engine's force-split
        contract, :mod:`upscale.engine.respa`): ``"slow"`` the particles' lattice energy
        and hourglass term, ``"fast"`` the atomistic region with its pads and the
        ghost-force dead load; the two add up to the total (the same energy, split)."""
        _sub_rows(out, self.y_rows, self._group(state, group)[1])

    def add_group_forces(self, state, out, fields_out, group: str) -> None:
        """:meth:`add_group_force` into ``out`` and :meth:`add_group_field_force` into
        ``fields_out`` (if it has the shift field) from one evaluation (the engine's
        split contract: one state check per group evaluation instead of two)."""
        _, gy, gd = self._group(state, group)
        _sub_rows(out, self.y_rows, gy)
        if FIELD in fields_out:
            fields_out[FIELD][:self.N] -= gd

    def add_group_field_force(self, state, out, group: str) -> None:
        """The ``group``'s part of :meth:`add_field_force` (the shifts)."""
        out[FIELD][:self.N] -= self._group(state, group)[2]

    def group_energy(self, state, group: str) -> float:
        """The ``group``'s part of :meth:`energy` (eV); the two add up to it."""
        return float(self._group(state, group)[0])

    def step_force(self, state, out, *, failure=True) -> int:
        self.add_force(state, out)
        return self.break_links(state) if failure else 0

    def break_bonds(self, state) -> int:
        return self.break_links(state)

    def break_links(self, state, stability: bool | None = None) -> int:
        """The tube's failure rules at the current state: the link rule
        (:meth:`DCBRDefectTube.update_links`), then, with ``stability`` (default the
        model's), the lattice-stability rule; returns the number of links (or particles)
        broken. The links go to ``state.extra``."""
        self._evaluate(state)  # the rules read the lattice state of this configuration
        t = self.tube
        nb = t.update_links()
        if self.stability if stability is None else stability:
            nb += t.check_stability()
        if nb:
            self._changed()
            ex = state.extra
            if "dcbr.intact" in ex:
                ex["dcbr.intact"][...] = t.intact
                ex["dcbr.alive"][...] = t.alive
        return int(nb)

    # ------------------------------------------------------------------ quasi-static hooks
    def set_cell(self, Lz: float) -> None:
        """The cell length the energy is called with (Å): the load of a periodic tube's
        quasi-static tension (the ghost-force correction is keyed on it: refresh it with
        the tube's ``prepare_step(Lz)`` and :meth:`store_ghost`)."""
        if not (np.isfinite(Lz) and Lz > 0):
            raise ValueError(f"Lz={Lz!r}; valid: a positive cell length (Å)")
        self.Lz = float(Lz)
        self._changed()

    def static_shifts(self, state, on: bool = True) -> None:
        """With ``on``, the particles' shifts are a massless internal field of the engine's
        minimisers (:class:`~upscale.engine.minimisers.LBFGS` minimises them with the
        positions, within +-the tube's ``shift_bound``), ``state.extra[STATIC]``: a view of
        the shift field's particle rows, so the field is what the minimiser moves. Off
        (default): the shifts are a field with inertia only (dynamics). Nothing without the
        tube's shift relaxation."""
        self._static = bool(on) and bool(self.tube.relax_shift)
        if self._static:
            v = state.fields[FIELD][:self.N]
            if not v.flags.c_contiguous:
                raise ValueError("the shift field is not C-contiguous; valid: the field of "
                                 "init_state")
            state.extra[STATIC] = v
        else:
            state.extra.pop(STATIC, None)

    @property
    def internal_fields(self) -> dict:
        """``{STATIC: (-b, b)}`` while :meth:`static_shifts` is on, else empty."""
        if not self._static:
            return {}
        b = self.tube.shift_bound
        return {STATIC: (-b, b)}

    def hold_internal(self, flag: bool) -> None:
        """(The shifts are never relaxed by the model itself: nothing to hold.)"""

    def internal_gradient(self, state) -> dict:
        """``{STATIC: dE/d delta (N, 3)}`` (eV/Å) at the state."""
        return {STATIC: self._evaluate(state)[2]}

    def cell_force(self, state) -> float:
        """dE/dLz (eV/Å) at the state: the axial force the periodic tube carries (with the
        ghost-force correction's term, :meth:`DCBRDefectTube.energy_and_gradient`)."""
        return self._evaluate(state)[3]

    def max_force(self, state) -> float:
        """Largest component of dE/d(unknowns) (eV/Å; the non-slave particles and the free
        atoms, held components too): the test of the tube's damped restarts
        (:meth:`DCBRDefectTube.minimise`)."""
        return float(np.abs(self._evaluate(state)[1]).max())

    def rotation_pins(self) -> np.ndarray:
        """(n, 3) bool over the rows: the components that hold the periodic tube's rigid turn
        about its axis (:meth:`DCBRDefectTube.rotation_pins`), for a minimiser's bounds."""
        rows = np.zeros((self.n, 3), bool)
        rows[self.y_rows] = self.tube.rotation_pins(None)
        return rows

    def damped_relax(self, state, fixed=None) -> None:
        """The tube's damped dynamics (:meth:`DCBRDefectTube.quickmin`, LAMMPS's quickmin
        settings) from the state, which it moves (rows, slaves interpolated, and shifts);
        ``fixed``: (n, 3) bool over the rows held (e.g. :meth:`rotation_pins`)."""
        self._sync(state)
        y, d = self.unknowns(state)
        fx = None if fixed is None else np.asarray(fixed, bool)[self.y_rows]
        y, d = self.tube.quickmin(y, np.array(d, copy=True), self.Lz, fixed=fx)
        state.y[...] = self.rows(y)
        state.fields[FIELD][:self.N] = d

    def break_links_in_turn(self, state) -> int:
        """The quasi-static driver's failure rules at the current state: the link rule
        (:meth:`DCBRDefectTube.update_links`) and, only where no link broke, the tube's
        lattice-stability rule (its ``check_stability(all_equal=True)``), on a fresh
        evaluation of this configuration; returns the number broken (links go to
        ``state.extra``)."""
        self._cache = None  # the rules read the lattice state of this very configuration
        self._evaluate(state)
        t = self.tube
        nb = t.update_links()
        if nb == 0:
            nb = t.check_stability(all_equal=True)
        if nb:
            self._changed()
            ex = state.extra
            if "dcbr.intact" in ex:
                ex["dcbr.intact"][...] = t.intact
                ex["dcbr.alive"][...] = t.alive
        return int(nb)

    def store_ghost(self, state) -> None:
        """The tube's current ghost-force correction (set by the scene: ``prepare_step``,
        ``prepare_sides``) into ``state.extra``; the next evaluation uses it."""
        g = self.tube.ghost_correction
        ex = state.extra
        self._ghost_version += 1
        ex["dcbr.ghost_version"][...] = self._ghost_version
        ex["dcbr.ghost_on"][...] = g is not None
        tw = self.tube.twin
        if tw is not None and tw.neighbour_reference is not None and "dcbr.twin_nl_x" in ex:
            ex["dcbr.twin_nl_x"][...] = tw.neighbour_reference  # (the twin's list, built at
            # the uniform states of the correction: its pairs' order is part of the result)
        if g is not None:
            ex["dcbr.ghost.Lz"][...] = g["Lz"]
            ex["dcbr.ghost.dL"][...] = g["dL"]
            for k in _GHOST:
                ex[f"dcbr.ghost.{k}"][...] = g[k]
        self._changed()

    def force(self, state):
        out = np.zeros_like(state.y)
        self.add_force(state, out)
        return out

    def energy(self, state) -> float:
        return self._evaluate(state)[0]

    def energy_density(self, state):
        return np.zeros(state.y.shape[0])

    def particle_damage(self, state) -> np.ndarray:
        """Rows' damage: a particle's mu = 1 - R/T of its links (seed 004 eq. 5.16), a free
        atom's 1 - bonds left / bonds at the start."""
        self._sync(state)
        y, d = self.unknowns(state)
        return np.r_[self.tube.damage, self.tube.atom_damage(y, d, self.Lz)]

    def stiffness_bound(self):
        """Per-row stiffness (n,) eV/Å^2 for the engine's stable step: R_i = lambda_max m_i,
        lambda_max the largest eigenvalue of M^-1 K at the initial state
        (:meth:`largest_eigenvalue`), so that the engine's max_i R_i / m_i is lambda_max
        and its step 2 / sqrt(lambda_max) (fs with the default ``unit``) is velocity
        Verlet's critical step of the motion linearised there, the rows and the shift
        field together. Not a Gershgorin row sum: that needs every entry of K, which the
        tube gives only as a gradient; the Lanczos value is the sharp one instead (a
        Gershgorin bound is above it). Computed once per set of links and initial state."""
        key = (self._version, self.y0.tobytes(), self.delta0.tobytes(), self.Lz)
        if getattr(self, "_bound", None) is None or self._bound[0] != key:
            self._bound = (key, self.largest_eigenvalue())
        return self._bound[1] * self.masses()

    def largest_eigenvalue(self, y=None, delta=None, *, tol: float = 1e-6,
                           h: float = 1e-5) -> float:
        """Largest eigenvalue lambda_max of M^-1 K (1/fs^2 with the default ``unit``) at
        unknowns ``y`` (nd + nf, 3) and shifts ``delta`` (N, 3) (default the initial
        state), K the Hessian of the tube's energy (with its ghost-force load) in the
        unknowns and the shifts, M the rows' masses and the shifts' inertia (:meth:`masses`,
        :meth:`fields`). Lanczos (ARPACK ``eigsh``, relative tolerance ``tol``) on the
        symmetric M^-1/2 K M^-1/2, its products by central differences of the gradient
        (largest displacement ``h`` Å). The slave rows, which the engine ties to their
        atoms, are not unknowns (their stiffness is in their atoms' rows). Velocity Verlet
        is stable for dt < 2 / sqrt(lambda_max) (linearised). The tube's history (its last
        maps, its Verlet list) is put back afterwards."""
        from scipy.sparse.linalg import LinearOperator, eigsh

        t = self.tube
        y = self.y0 if y is None else np.asarray(y, dtype=np.float64)
        d = self.delta0 if delta is None else np.asarray(delta, dtype=np.float64)
        if y.shape != (self.nd + self.nf, 3) or d.shape != (self.N, 3):
            raise ValueError(f"y {y.shape}, delta {d.shape}; valid: y ({self.nd + self.nf}, 3) "
                             f"and delta ({self.N}, 3)")
        if not (tol > 0 and h > 0):
            raise ValueError(f"tol={tol!r}, h={h!r}; valid: both > 0")
        m = self.masses()
        s = 1.0 / np.sqrt(np.r_[np.repeat(m[self.y_rows], 3), np.repeat(0.25 * m[:self.N], 3)])
        ny, n = y.size, y.size + d.size
        fs = t.last_maps.copy()
        ref = t.neighbour_reference
        ref = None if ref is None else ref.copy()

        def grad(z):
            _, gy, gd, _ = t.energy_and_gradient(y + z[:ny].reshape(y.shape),
                                                 d + z[ny:].reshape(d.shape), self.Lz)
            return np.r_[gy.ravel(), gd.ravel()]

        def product(v):
            p = s * np.ravel(v)
            c = h / max(float(np.abs(p).max()), 1e-300)
            return s * (grad(c * p) - grad(-c * p)) / (2.0 * c)

        try:
            grad(np.zeros(n))  # a first Verlet list is built at the state itself
            v0 = np.random.default_rng(0).standard_normal(n)
            lam = eigsh(LinearOperator((n, n), matvec=product, dtype=np.float64), k=1,
                        which="LA", tol=tol, v0=v0, return_eigenvectors=False)[0]
        finally:
            t.last_maps = fs
            if ref is not None:
                t.rebuild_neighbours(ref)
            self._cache = self._slow_cache = self._fast_cache = None
        return float(lam)

    def describe(self) -> dict:
        t = self.tube
        return {"model": self.name, "chirality": [t.lattice.n, t.lattice.m],
                "coarsening": t.coarsening, "particles": t.N, "free_atoms": t.nf,
                "atoms": t.n_atoms, "vacancy_atoms": int(t.removed.sum()),
                "potential": t.potential, "cutoff": t.cutoff, "periodic": bool(t.periodic),
                "cell_length_A": self.Lz}

    # ------------------------------------------------------------------ atoms
    def atoms(self, state):
        """Every atom of the tube at ``state``: (positions (n_atoms, 3) Å, index into the
        tube's ``X_atoms``); the free atoms are their rows, the others reconstructed from
        their carriers' maps (:meth:`DCBRDefectTube.mapped_atoms`). The map table is built
        at the first call from the tube's G (build it again with :meth:`reset_atom_map`
        after opening or clamping the tube)."""
        self._sync(state)
        t = self.tube
        if self._map is None:
            self._map = t.atom_map()
        y, d = self.unknowns(state)
        x = np.vstack([y[self.nd:], t.mapped_atoms(y, d, self.Lz, self._map)])
        return x, np.r_[t.free_idx, self._map["atoms"]]

    def reset_atom_map(self) -> None:
        self._map = None

    def atom_forces(self, state, f):
        """Forces ``f`` (n_atoms, 3) on the atoms of :meth:`atoms` (same order) as
        generalised forces: (on the rows (n, 3), on the shift field (n, 3)) to add to the
        model's own (the chain rule through the maps and G; slave rows get none, their
        part is on their atoms)."""
        f = np.asarray(f, dtype=np.float64)
        nm = 0 if self._map is None else len(self._map["c"])
        if self._map is None or f.shape != (self.nf + nm, 3):
            raise ValueError(f"forces of shape {f.shape}; valid: ({self.nf} + mapped atoms, 3), "
                             "the rows of atoms(state) (call it first)")
        self._sync(state)
        y, d = self.unknowns(state)
        gy, gd = self.tube.mapped_atom_gradient(y, d, self.Lz, self._map, -f[self.nf:])
        F = np.zeros((self.n, 3))
        F[self.y_rows] = -gy
        F[self.atom_rows] += f[:self.nf]
        G = np.zeros((self.n, 3))
        G[:self.N] = -gd
        return F, G


def _sub_rows(out, rows, g):
    """out[rows] -= g (:func:`~upscale.models.dcbr_coupling_kernels.sub_rows`)."""
    CK.sub_rows(out, rows, np.ascontiguousarray(g, dtype=float))


def _register():
    from upscale.models import register

    register("dcbr-defect-tube", DCBRDefectTubeModel)


_register()
