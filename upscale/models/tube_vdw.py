"""Van der Waals between the tubes of a bundle, through the atoms each body represents.

The 12-6 Lennard-Jones pair of LAMMPS ``pair_style lj/cut`` (plain truncation, no shift:
the bundle references' pair, :mod:`upscale.experiments.lammps.potential`)

    phi(r) = 4 eps [(sigma/r)^12 - (sigma/r)^6]   for r < rc,  0 beyond,            (1)

acts between the *atoms* of different bodies. Each body gives its atoms through an atom
map (``positions(state)`` (n_a, 3) Å, ``pull_back(state, f_atoms, out, field_out)``):

* :class:`AtomisticMap`: the body's particles are its atoms (identity; an atomistic tube);
* a coarse tube (:class:`~upscale.models.dcbr.model.DCBRModel`) reconstructs its atoms
  from its particles by its own lattice map (the map of its pad atoms: x_a = y_c +
  Q3_c (h_a + r0_a), seed 004 sec. 5.2; its free atoms as they are), and pulls the atoms'
  forces back to its rows and shifts by the chain rule through that map
  (:class:`CoarseTubeMap`);
* :class:`LumpedMap`: the integrated coarse-grained alternative in its simplest form, each
  particle a site of weight w_c (the atoms it carries) at its own position, the pair
  energy ``w_a w_b phi(r_ab)`` (kept to measure what the reconstruction buys).

Energy E = sum over pairs (a in body A, b in body B, A != B) of w_a w_b phi(r_ab); forces
-dE/dx on the atoms, pulled back by each map. The pair list (``scipy.spatial.cKDTree``
between the atoms of every two bodies whose atoms' bounding boxes come within
rc + skin: only pairs of different bodies, each once, sorted by the first atom) is rebuilt
when an atom has moved more than half the ``skin``. A coarse tube's reconstruction is kept while its rows, shifts and history
are unchanged (a tube held in a minimisation). Units: eV, Å; ``force_kind = "particle"``.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from upscale.models import register
from upscale.models.base import Model, Needs, check_positive

__all__ = ["TubeVdW", "AtomisticMap", "LumpedMap", "CoarseTubeMap", "lj_cut_pairs"]


@njit(cache=True)
def lj_cut_pairs(x, w, pi, pj, eps, sigma, rc, f):
    """Eq. (1) over the pairs ``(pi[p], pj[p])`` of atoms ``x`` (n, 3) with weights ``w``
    (n,): returns the energy (eV) and adds the forces (eV/Å) to ``f`` (n, 3)."""
    rc2 = rc * rc
    s2 = sigma * sigma
    e = 0.0
    for p in range(pi.shape[0]):
        a = pi[p]
        b = pj[p]
        dx = x[a, 0] - x[b, 0]
        dy = x[a, 1] - x[b, 1]
        dz = x[a, 2] - x[b, 2]
        r2 = dx * dx + dy * dy + dz * dz
        if r2 >= rc2:
            continue
        ww = w[a] * w[b]
        q = s2 / r2
        q6 = q * q * q
        e += ww * 4.0 * eps * (q6 * q6 - q6)
        # -dphi/dr / r = 24 eps (2 q12 - q6) / r^2
        g = ww * 24.0 * eps * (2.0 * q6 * q6 - q6) / r2
        f[a, 0] += g * dx
        f[a, 1] += g * dy
        f[a, 2] += g * dz
        f[b, 0] -= g * dx
        f[b, 1] -= g * dy
        f[b, 2] -= g * dz
    return e


class AtomisticMap:
    """The particles of ``rows`` (a slice of the assembled system) are atoms."""

    def __init__(self, rows: slice):
        self.rows = rows
        self.natoms = rows.stop - rows.start
        self.weights = np.ones(self.natoms)

    def positions(self, state) -> np.ndarray:
        return state.y[self.rows]

    def pull_back(self, state, f, out, field_out=None) -> None:
        out[self.rows] += f


class LumpedMap(AtomisticMap):
    """Each particle of ``rows`` a site of weight ``weights`` (atoms it stands for)."""

    def __init__(self, rows: slice, weights):
        super().__init__(rows)
        w = np.asarray(weights, dtype=float)
        if w.shape != (self.natoms,):
            raise ValueError(f"weights of shape {w.shape}; valid: ({self.natoms},)")
        self.weights = w


class CoarseTubeMap:
    """The atoms of a coarse tube reconstructed from its particles (module docstring).

    ``body_model`` is the tube's model in the assembly (an
    :class:`upscale.engine.bodies.BodyModel` wrapping a
    :class:`~upscale.models.dcbr.model.DCBRModel`): its atoms are
    :meth:`~upscale.models.dcbr.model.DCBRModel.atom_positions` (every atom of the tube, the
    free ones as they are, the others on their carriers' lattice maps) and forces on them
    map back by :meth:`~upscale.models.dcbr.model.DCBRModel.atom_forces` (the chain rule
    through those maps) to the tube's rows and to its shift field ``field`` (the assembled
    name, ``"<body>/dcbr.delta"``)."""

    def __init__(self, body_model, field: str | None = None):
        self.bm = body_model
        self.rows = body_model.rows
        self.natoms = len(body_model.model.structure.positions)
        self.weights = np.ones(self.natoms)
        self.field = field
        self._key = None
        self._x = None

    def _state_key(self, state):
        """What the atoms depend on: the tube's rows and shifts in ``state`` and its
        history (links, last good maps)."""
        d = (getattr(state, "fields", None) or {}).get(self.field)
        ex = self.bm.sub(state).extra
        return (state.y[self.rows], None if d is None else d[self.rows],
                ex.get("dcbr.delta"), ex.get("dcbr.fs_last"), ex.get("dcbr.intact"),
                ex.get("dcbr.alive"))

    def forget(self) -> None:
        """Drop the kept reconstruction (the next call reconstructs)."""
        self._key = None
        self._x = None

    def positions(self, state) -> np.ndarray:
        """(natoms, 3) Å; the last reconstruction again while nothing it depends on has
        changed (e.g. a tube held during a minimisation)."""
        key = self._state_key(state)
        k0 = self._key
        if k0 is not None and all((a is None and b is None) or
                                  (a is not None and b is not None and np.array_equal(a, b))
                                  for a, b in zip(k0, key)):
            return self._x
        x = self.bm.model.atom_positions(self.bm.sub(state))
        self._key = tuple(None if a is None else np.array(a, copy=True) for a in key)
        self._x = x
        return x

    def pull_back(self, state, f, out, field_out=None) -> None:
        """Adds the atoms' forces ``f`` pulled back to the tube's rows of ``out`` and, on
        ``field_out[field]`` = (rows, (n, 3) forces on the tube's shifts), to its field."""
        F, G = self.bm.model.atom_forces(self.bm.sub(state), f)
        out[self.rows] += F
        if field_out is not None and self.field is not None:
            cur = field_out.get(self.field)
            if cur is None:
                field_out[self.field] = (self.rows, np.array(G, dtype=float))
            else:
                cur[1][...] += G


class TubeVdW(Model):
    """Lennard-Jones (``lj/cut``) between the atoms of different bodies (module docstring).

    Parameters
    ----------
    maps : sequence
        One atom map per body (:class:`AtomisticMap`, :class:`CoarseTubeMap`,
        :class:`LumpedMap`).
    epsilon, sigma : float
        eV, Å (the references: 2.84 meV, 3.4 Å).
    rc : float, optional
        Cutoff, Å (default 3 sigma = 10.2 Å, the references').
    skin : float, optional
        Pair-list skin, Å (default 1.0).
    sites : sequence, optional
        Per body a second, cheaper representation (e.g. a :class:`LumpedMap`) or None;
        two bodies that both have one interact through it, every other pair through the
        atom maps.
    every : int, optional
        Forces recomputed every ``every`` time steps and held in between (default 1:
        every step). The held force is the pair force of the step it was computed at
        (a zero-order hold; the energy is always the current one).
    """

    name = "tube-vdw"
    needs = Needs(pairs=False, energy=True)
    force_kind = "particle"

    def __init__(self, maps, epsilon: float = 2.84e-3, sigma: float = 3.4, *,
                 rc: float | None = None, skin: float = 1.0, sites=None, every: int = 1):
        check_positive(epsilon=epsilon, sigma=sigma, rc=rc, skin=skin)
        self.maps = list(maps)
        nb = len(self.maps)
        if nb < 2:
            raise ValueError(f"tube-vdw acts between bodies; got {nb} atom map(s), "
                             "valid: two or more")
        sites = [None] * nb if sites is None else list(sites)
        if len(sites) != nb:
            raise ValueError(f"{len(sites)} site maps for {nb} bodies; valid: one per body "
                             "(None where the atoms are used)")
        self.site_maps = sites
        # representations: the atom maps (0..B-1), then the site maps; rep[a][b] is the
        # representation of body a in its pair with body b
        self.reps = list(self.maps) + [sm for sm in sites if sm is not None]
        site_rep = {}
        for k, sm in enumerate(sites):
            if sm is not None:
                site_rep[k] = nb + len(site_rep)
        self.rep_of = [[site_rep[a] if (a in site_rep and b in site_rep) else a
                        for b in range(nb)] for a in range(nb)]
        self.rep_body = list(range(nb)) + sorted(site_rep, key=site_rep.get)
        self.eps, self.sigma = float(epsilon), float(sigma)
        self.rc = float(rc) if rc is not None else 3.0 * self.sigma
        self.skin = float(skin)
        self.offsets = np.cumsum([0] + [m.natoms for m in self.reps])
        self.weights = np.concatenate([m.weights for m in self.reps])
        self._x_built = None
        self._cache = None
        self.nbuilds = 0
        if not (isinstance(every, (int, np.integer)) and every >= 1):
            raise ValueError(f"every={every!r}; valid: an integer >= 1 (time steps)")
        self.every = int(every)
        self._key = None

    def prepare(self, system, family=None, **kw) -> None:
        super().prepare(system, family, **kw)
        self._x_built = None
        self._cache = None

    # ------------------------------------------------------------------ atoms, pairs
    def atoms(self, state) -> np.ndarray:
        """(n, 3) every representation's points (the bodies' atoms in body order, then the
        site maps' sites), stacked."""
        return np.ascontiguousarray(np.vstack([m.positions(state) for m in self.reps]))

    def body_of_atom(self) -> np.ndarray:
        return np.repeat(np.asarray(self.rep_body), np.diff(self.offsets))

    def _pairs(self, x):
        if self._x_built is not None and self._x_built.shape == x.shape:
            d2 = np.max(np.sum((x - self._x_built) ** 2, axis=1))
            if d2 <= (0.5 * self.skin) ** 2:
                return self._pi, self._pj
        from scipy.spatial import cKDTree

        r = self.rc + self.skin
        o = self.offsets
        parts = [x[o[k]:o[k + 1]] for k in range(len(self.reps))]
        lo = [p.min(axis=0) if len(p) else np.full(3, np.inf) for p in parts]
        hi = [p.max(axis=0) if len(p) else np.full(3, -np.inf) for p in parts]
        trees = {}
        pi, pj = [], []
        nb = len(self.maps)
        for a in range(nb):
            for b in range(a + 1, nb):
                ra, rb = self.rep_of[a][b], self.rep_of[b][a]
                gap = np.maximum(0.0, np.maximum(lo[ra] - hi[rb], lo[rb] - hi[ra]))
                if np.linalg.norm(gap) > r:
                    continue
                for q in (ra, rb):
                    if q not in trees:
                        trees[q] = cKDTree(parts[q])
                m = trees[ra].sparse_distance_matrix(trees[rb], r, output_type="ndarray")
                i = m["i"].astype(np.int64) + o[ra]
                j = m["j"].astype(np.int64) + o[rb]
                order = np.lexsort((j, i))  # memory order: the kernel walks rows
                pi.append(i[order])
                pj.append(j[order])
        pi = np.concatenate(pi) if pi else np.zeros(0, np.int64)
        pj = np.concatenate(pj) if pj else np.zeros(0, np.int64)
        order = np.argsort(pi, kind="stable")  # memory order: the kernel walks rows
        self._pi, self._pj = pi[order], pj[order]
        self._x_built = x.copy()
        self.nbuilds += 1
        return self._pi, self._pj

    def pair_list(self, x=None) -> dict:
        """The current pair list (built for the points ``x`` (n, 3) if given, else the last
        evaluation's): ``{"i", "j"}`` int64, each pair once, sorted by ``i``."""
        if x is not None:
            self._pairs(np.ascontiguousarray(x, dtype=float))
        if self._x_built is None:
            raise RuntimeError("no pair list yet; evaluate a state or give x")
        return {"i": self._pi, "j": self._pj}

    def rebuild(self) -> None:
        """Forget the pair list (the next evaluation builds it)."""
        self._x_built = None
        self._cache = None

    def _same_state(self, state) -> bool:
        """True if ``state``'s positions and fields are those of the last evaluation."""
        k = self._key
        if k is None or k[0].shape != state.y.shape or not np.array_equal(k[0], state.y):
            return False
        f = getattr(state, "fields", {}) or {}
        return set(k[1]) == set(f) and all(np.array_equal(k[1][n], f[n]) for n in f)

    def evaluate(self, state):
        """``(energy eV, atom positions (n_a, 3), atom forces (n_a, 3) eV/Å)``."""
        if self._cache is not None and self._same_state(state):
            c = self._cache
            return c[1], c[0], c[2]
        x = self.atoms(state)
        c = self._cache
        if c is not None and c[0].shape == x.shape and np.array_equal(c[0], x):
            return c[1], x, c[2]
        pi, pj = self._pairs(x)
        f = np.zeros_like(x)
        e = lj_cut_pairs(x, self.weights, pi, pj, self.eps, self.sigma, self.rc, f)
        self._cache = (x.copy(), e, f)
        self._key = (state.y.copy(), {n: v.copy() for n, v in
                                      (getattr(state, "fields", {}) or {}).items()})
        return e, x, f

    def energy_between(self, state) -> np.ndarray:
        """(B, B) eV: the energy of every two bodies (upper triangle; the sum is E)."""
        e, x, _ = self.evaluate(state)
        pi, pj = self._pi, self._pj
        body = self.body_of_atom()
        B = len(self.maps)
        lo, hi = np.minimum(body[pi], body[pj]), np.maximum(body[pi], body[pj])
        out = np.zeros((B, B))
        for a in range(B):
            for b in range(a + 1, B):
                sel = (lo == a) & (hi == b)
                out[a, b] = lj_cut_pairs(x, self.weights, pi[sel], pj[sel], self.eps,
                                         self.sigma, self.rc, np.zeros_like(x))
        return out

    # ------------------------------------------------------------------ the engine's calls
    def atom_forces(self, state) -> np.ndarray:
        return self.evaluate(state)[2]

    def generalised_forces(self, state):
        """(forces on the particles (N, 3), {field: forces (N, 3)}): the atoms' forces
        pulled back by every map; kept while the atoms do not move."""
        F, G = self._generalised(state)
        full = {}
        for k, (r, v) in G.items():
            full[k] = np.zeros_like(state.y)
            full[k][r] = v
        return F, full

    def _generalised(self, state):
        """As :meth:`generalised_forces`, the field forces as {field: (rows, (n, 3))} on
        the rows of the tube that carries the field."""
        g = getattr(self, "_gcache", None)
        step = int(getattr(state, "step", 0))
        if g is not None and self.every > 1 and 0 <= step - g[3] < self.every:
            return g[1], g[2]  # held (see ``every``)
        e, x, f = self.evaluate(state)
        g = getattr(self, "_gcache", None)
        if g is not None and g[0] is self._cache:
            return g[1], g[2]
        F = np.zeros_like(state.y)
        G: dict = {}
        o = self.offsets
        for k, m in enumerate(self.reps):
            if np.any(f[o[k]:o[k + 1]]):
                m.pull_back(state, f[o[k]:o[k + 1]], F, G)
        self._gcache = (self._cache, F, G, step)
        return F, G

    def add_force(self, state, out) -> None:
        out += self._generalised(state)[0]

    def add_field_force(self, state, out) -> None:
        """Adds the coarse tubes' shift-field forces (the map's chain rule) to ``out``."""
        for k, (r, v) in self._generalised(state)[1].items():
            if k in out:
                out[k][r] += v

    def energy(self, state) -> float:
        return float(self.evaluate(state)[0])

    # the force split of multiple time stepping (upscale.engine.respa): the inter-tube
    # Lennard-Jones is slow. Its stiffness at the wall gap, 57 eps/sigma^2 ~ 0.014 eV/Å^2
    # per pair, is three orders below a C-C bond's (~30 eV/Å^2), so it is evaluated once
    # per outer step
    def add_group_force(self, state, out, group: str) -> None:
        if group == "slow":
            self.add_force(state, out)

    def add_group_field_force(self, state, out, group: str) -> None:
        if group == "slow":
            self.add_field_force(state, out)

    def group_energy(self, state, group: str) -> float:
        return self.energy(state) if group == "slow" else 0.0

    def energy_density(self, state):
        raise NotImplementedError("tube-vdw gives its energy as a whole (energy, "
                                  "energy_between), not per particle")

    def stiffness_bound(self):
        """None: the pair stiffness grows without bound at close approach; give ``dt``."""
        return None

    def describe(self) -> dict:
        return {"model": self.name, "pair": "lj/cut", "epsilon_eV": self.eps,
                "sigma_A": self.sigma, "rc_A": self.rc, "skin_A": self.skin,
                "maps": [type(m).__name__ for m in self.maps],
                "sites": [None if m is None else type(m).__name__ for m in self.site_maps]}


register("tube-vdw", TubeVdW)
