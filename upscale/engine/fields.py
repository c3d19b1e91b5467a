"""Generalised degrees of freedom: per-particle fields with their own inertia.

Beyond the three translations ``state.y``, a model may carry **fields**: named arrays
``state.fields[name]`` of shape (N, k) with velocities ``state.field_v[name]`` (rotations
of tridynamic beams and plates, seed 004 ch. 3-4). A model declares them in
``fields() -> {name: FieldSpec}``; its generalised force densities are added by
``add_field_force(state, out)`` (``out[name]`` (N, k), in the model's ``force_kind``
units: N/m^3 per unit of the field's conjugate for densities). The equation of motion of a
field component is

    I_i  d^2 phi_i / dt^2 = g_i ,

``I_i`` the field's inertia density (``FieldSpec.inertia``; for the rotation of a beam
``rho I/A`` in kg/m, i.e. kg m^2 per m^3) and ``g_i`` the generalised force density
(moment per unit volume, N m / m^3).

Which translations a model acts on is ``model.translations`` (default all three); the
static and dispersion tools restrict themselves to those.

Conditions on fields: :class:`FixedField` (prescribed zero value and rate of some
components), :class:`Tie` (a ghost particle's translation or field component slaved to a
linear combination of other particles' values: mirror images for simply supported or
clamped supports, extrapolation for free ends). Ties and fixed fields are kinematic: the
integrator overwrites them after every drift and gives them zero generalised force.

Static solve of linear models: :func:`operator` assembles the generalised stiffness
``K = -dF/dq`` by probing the models' force routines (exact for linear models, the
response of one probe is attributed to the only perturbed particle within the models'
influence radius), :func:`solve_static` eliminates fixed and tied degrees of freedom
(``q = P q_free``; the rows of ghosts are dropped, as a mirror image carries no equation of
its own) and solves ``K_red q_free = f`` with a sparse LU, which does not need ``K``
symmetric. :func:`critical_dt` is the sharp explicit step ``2/sqrt(lambda_max(M^-1 K))``
of the same reduced operator.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from numba import njit

from upscale.engine.conditions import Displacement, Region

__all__ = ["FieldSpec", "collect_fields", "FixedField", "Tie", "init_fields", "dof_layout", "set_dof",
           "generalised_forces", "operator", "reduction", "solve_static", "critical_dt",
           "field_stiffness_over_inertia", "kinetic_energy", "field_kinetic_energy"]


@dataclasses.dataclass
class FieldSpec:
    """A per-particle field with inertia.

    Attributes
    ----------
    ncomp : int
        Components per particle.
    inertia : float or (N,) ndarray
        Inertia density (field acceleration = generalised force density / inertia).
    unit : str
        Unit of the field (for result files).
    rows : slice, optional
        The rows that carry the field (e.g. one body's of an assembly,
        :mod:`upscale.engine.bodies`); on the other rows it has no force and stays at
        rest, so the integrators and thermostats pass over ``rows`` only. None: every row.
    """

    ncomp: int
    inertia: object
    unit: str = "rad"
    rows: object = None

    @property
    def span(self) -> slice:
        """``rows``, or every row (``slice(None)``)."""
        return slice(None) if self.rows is None else self.rows


def collect_fields(models, n: int) -> dict:
    """Merge the models' field declarations: ``{name: FieldSpec}`` with (N,) inertia.

    Two models declaring the same field must agree on ``ncomp``; their inertias must be equal
    (a field has one inertia)."""
    out: dict[str, FieldSpec] = {}
    for m in models:
        decl = m.fields() if hasattr(m, "fields") and callable(m.fields) else {}
        for name, spec in decl.items():
            inertia = np.broadcast_to(np.asarray(spec.inertia, dtype=np.float64), (n,)).copy()
            if not (np.isfinite(inertia).all() and (inertia > 0).all()):
                raise ValueError(f"field {name!r}: inertia must be positive, got min "
                                 f"{float(inertia.min()):.4g}")
            if name in out:
                if out[name].ncomp != spec.ncomp or not np.allclose(out[name].inertia, inertia):
                    raise ValueError(f"field {name!r} declared twice with different "
                                     f"components or inertia")
                continue
            out[name] = FieldSpec(int(spec.ncomp), inertia, spec.unit,
                                  getattr(spec, "rows", None))
    return out


def init_fields(state, specs: dict) -> None:
    """Add zero arrays for every declared field missing from ``state``."""
    n = state.y.shape[0]
    for name, spec in specs.items():
        if name not in state.fields:
            state.fields[name] = np.zeros((n, spec.ncomp))
        if name not in state.field_v:
            state.field_v[name] = np.zeros((n, spec.ncomp))


# --------------------------------------------------------------------------- conditions
class FixedField(Displacement):
    """Zero value and rate of components ``components`` of field ``field`` on a region
    (a clamped rotation). Does not constrain translations. ``hold=True``: the components
    keep whatever value they have (only their rate is zeroed), e.g. a sublattice shift
    held at its set-up value by a rigid grip."""

    def __init__(self, region: Region, field: str, components=(0,), value=0.0, *,
                 hold: bool = False):
        super().__init__(region, 0.0, (0,))
        self.kinematic = False  # translations untouched
        self.field = str(field)
        self.field_components = np.atleast_1d(np.asarray(components, dtype=np.int64))
        self.field_value = float(value)
        self.hold = bool(hold)

    def apply(self, state, t, dt=None) -> None:
        idx, c = self.region.index, self.field_components
        if not self.hold:
            _set_block(state.fields[self.field], idx, c, self.field_value)
        _set_block(state.field_v[self.field], idx, c, 0.0)

    def constrains(self, field: str):
        return (self.region.index, self.field_components) if field == self.field else None

    def describe(self) -> dict:
        return {"type": "FixedField", "region": self.region.name, "field": self.field,
                "components": self.field_components.tolist(), "particles": self.region.size}


class Tie(Displacement):
    """Slave one degree of freedom of ghost particles to other particles:
    ``q_g = sum_p weights[g, p] q_{masters[g, p]}`` for ``target`` = ``("y", c)`` (the
    displacement component c) or ``(field, c)``.

    Mirror supports use one master per ghost with weight +-1; a free end's linear
    extrapolation uses two. The ghost's rate follows the masters' rates."""

    def __init__(self, region: Region, masters, weights, target):
        kind, comp = target
        super().__init__(region, 0.0, (int(comp),) if kind == "y" else (0,))
        if kind != "y":
            self.kinematic = False
        self.target = (str(kind), int(comp))
        self.masters = np.atleast_2d(np.asarray(masters, dtype=np.int64))
        self.weights = np.atleast_2d(np.asarray(weights, dtype=np.float64))
        if self.masters.shape != (region.size, self.weights.shape[1]) or \
                self.weights.shape != self.masters.shape:
            raise ValueError(f"tie on {region.name!r}: masters {self.masters.shape} and weights "
                             f"{self.weights.shape} must be ({region.size}, p)")
        if np.isin(self.masters, region.index).any():
            raise ValueError(f"tie on {region.name!r}: a ghost cannot be its own master")

    def apply(self, state, t, dt=None) -> None:
        """q_g = sum_p w_gp q_m (a displacement: u_g = sum_p w_gp u_m) and the same for the
        rates, in one kernel (:func:`_tie`; the sums in numpy's order, so the numbers are
        those of ``np.sum(w * q[m, c], axis=1)``)."""
        kind, c = self.target
        g, m, w = self.region.index, self.masters, self.weights
        if kind == "y":
            _tie(state.y, state.x0, True, g, m, w, c)
            _tie(state.v, state.x0, False, g, m, w, c)
        else:
            f, fv = state.fields[kind], state.field_v[kind]
            _tie(f, f, False, g, m, w, c)
            _tie(fv, fv, False, g, m, w, c)

    def constrains(self, field: str):
        kind, c = self.target
        return (self.region.index, np.array([c])) if kind == field else None

    def describe(self) -> dict:
        return {"type": "Tie", "region": self.region.name, "target": list(self.target),
                "particles": self.region.size, "masters_per_ghost": int(self.masters.shape[1])}


def field_constrained(n: int, specs: dict, conditions) -> dict:
    """``{field: (N, k) bool}``: the field components a condition prescribes."""
    out = {name: np.zeros((n, s.ncomp), dtype=bool) for name, s in specs.items()}
    for c in conditions:
        con = getattr(c, "constrains", None)
        if con is None:
            continue
        for name in out:
            r = con(name)
            if r is not None:
                out[name][np.ix_(r[0], r[1])] = True
    return out


# --------------------------------------------------------------------------- forces
def add_field_forces(sim, st, G: dict) -> None:
    """Add every model's generalised force densities times volume (per particle) to G
    (a per-particle model adds into G directly: its contract is to add)."""
    vol = sim.system.volume[:, None]
    for m in sim.models:
        fn = getattr(m, "add_field_force", None)
        if fn is None:
            continue
        if m.force_kind != "density":
            fn(st, G)
            continue
        tmp = {k: np.zeros_like(v) for k, v in G.items()}
        fn(st, tmp)
        for k, v in tmp.items():
            G[k] += v * vol


def field_stiffness_over_inertia(system, models, specs: dict) -> np.ndarray | None:
    """Gershgorin bound on the field rows of ``M^-1 K`` (N,) in 1/s^2 (max over fields),
    from the models' ``field_stiffness_bound() -> {name: (N,)}``; None if no field."""
    if not specs:
        return None
    lam = np.zeros(system.n)
    for name, spec in specs.items():
        r = np.zeros(system.n)
        for m in models:
            fb = getattr(m, "field_stiffness_bound", None)
            if fb is None:
                continue
            b = fb()
            if b is None:
                return None
            if name in b:
                r += b[name] if m.force_kind == "density" else b[name] / system.volume
        lam = np.maximum(lam, r / spec.inertia)
    return lam


def kinetic_energy(sim, mask=None) -> float:
    """Translational plus field kinetic energy (J) of the particles in ``mask`` (all if
    None)."""
    st = sim.state
    m = sim.system.mass if mask is None else sim.system.mass[mask]
    v = st.v if mask is None else st.v[mask]
    return 0.5 * float(np.sum(m[:, None] * v * v)) + field_kinetic_energy(sim, mask)


def field_kinetic_energy(sim, mask=None) -> float:
    """Kinetic energy (J) of the fields alone, ``sum_i I_i V_i |dphi_i/dt|^2 / 2`` over the
    particles in ``mask`` (all if None)."""
    st = sim.state
    ke = 0.0
    for name, spec in getattr(sim, "field_specs", {}).items():
        fv = st.field_v[name] if mask is None else st.field_v[name][mask]
        inert = spec.inertia * sim.system.volume
        inert = inert if mask is None else inert[mask]
        ke += 0.5 * float(np.sum(inert[:, None] * fv * fv))
    return ke


# --------------------------------------------------------------------------- linear tools
def dof_layout(sim) -> list:
    """Generalised degrees of freedom per particle: ``[("y", c) ...] + [(field, c) ...]``,
    translations restricted to those some model acts on (``model.translations``)."""
    trans = sorted({int(c) for m in sim.models for c in getattr(m, "translations", (0, 1, 2))})
    lay = [("y", c) for c in trans]
    for name, spec in getattr(sim, "field_specs", {}).items():
        lay += [(name, c) for c in range(spec.ncomp)]
    return lay


def _get(st, key):
    kind, c = key
    return (st.y[:, c] - st.x0[:, c]) if kind == "y" else st.fields[kind][:, c]


def set_dof(st, key, values) -> None:
    """Set one degree of freedom ``key = (kind, component)`` of every particle (mutates
    ``st``): a displacement component (``kind == "y"``: ``y = x0 + values``) or a field
    component."""
    kind, c = key
    if kind == "y":
        st.y[:, c] = st.x0[:, c] + values
    else:
        st.fields[kind][:, c] = values


def generalised_forces(sim) -> np.ndarray:
    """Internal generalised forces per particle (N, ndof) on the current state (no loads,
    no conditions applied), in the order of :func:`dof_layout`."""
    st = sim.state
    F = sim.internal_forces(failure=False)
    G = {k: np.zeros_like(v) for k, v in st.fields.items() if k in sim.field_specs}
    add_field_forces(sim, st, G)
    lay = dof_layout(sim)
    out = np.empty((sim.system.n, len(lay)))
    for a, (kind, c) in enumerate(lay):
        out[:, a] = F[:, c] if kind == "y" else G[kind][:, c]
    return out


def influence_radius(sim) -> float:
    """Largest distance at which a degree of freedom changes a force (models'
    ``influence_radius()``, default 2 horizons + 2 spacings)."""
    r = 0.0
    for m in sim.models:
        fn = getattr(m, "influence_radius", None)
        if fn is not None:
            r = max(r, float(fn()))
        elif sim.family is not None:
            r = max(r, 2 * sim.family.horizon + 2 * sim.system.spacing)
    return r


def _colours(x0, dim, R):
    """Colour particles so two of one colour are more than 2R apart."""
    s = R * (1 + 1e-9)
    cell = np.floor(x0[:, :dim] / s).astype(np.int64)
    cell -= cell.min(axis=0)
    base = np.zeros(x0.shape[0], dtype=np.int64)
    for d in range(dim):
        base = base * 3 + cell[:, d] % 3
    key = np.zeros(x0.shape[0], dtype=np.int64)
    dims = cell.max(axis=0) + 1
    for d in range(dim):
        key = key * dims[d] + cell[:, d]
    order = np.lexsort((np.arange(x0.shape[0]), key))
    rank = np.empty(x0.shape[0], dtype=np.int64)
    ks = key[order]
    start = np.r_[0, np.flatnonzero(np.diff(ks)) + 1]
    counts = np.diff(np.r_[start, ks.size])
    rank[order] = np.arange(ks.size) - np.repeat(start, counts)
    return base * (rank.max() + 1) + rank


def operator(sim):
    """Generalised stiffness ``K = -dF/dq`` (scipy.sparse csr, (N ndof, N ndof), rows and
    columns ``particle * ndof + a``) of linear models, by probing the force routines about
    the reference state (the state is restored)."""
    import scipy.sparse as sp
    from scipy.spatial import cKDTree

    st = sim.state
    saved = st.copy()
    lay = dof_layout(sim)
    nd, n = len(lay), sim.system.n
    x0 = sim.system.x0
    R = influence_radius(sim)
    colour = _colours(x0, sim.system.dim, R)
    tree = cKDTree(x0)
    near = tree.query_ball_point(x0, R * (1 + 1e-9))
    rows, cols, vals = [], [], []
    try:
        for a in lay:
            set_dof(st, a, 0.0)
        st.fields.update({k: np.zeros_like(v) for k, v in st.fields.items()})
        F0 = generalised_forces(sim)
        for col in np.unique(colour):
            probe = np.flatnonzero(colour == col)
            owner = np.full(n, -1, dtype=np.int64)
            for b in probe:
                owner[near[b]] = b
            resp = np.flatnonzero(owner >= 0)
            for a, key in enumerate(lay):
                e = np.zeros(n)
                e[probe] = 1.0
                set_dof(st, key, e)
                dF = generalised_forces(sim) - F0
                set_dof(st, key, 0.0)
                blk = -dF[resp]
                r_i, r_a = np.nonzero(blk)
                rows.append(resp[r_i] * nd + r_a)
                cols.append(owner[resp[r_i]] * nd + a)
                vals.append(blk[r_i, r_a])
    finally:
        st.y[...] = saved.y
        st.v[...] = saved.v
        for k in st.fields:
            st.fields[k][...] = saved.fields[k]
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(n * nd, n * nd))


def reduction(sim):
    """``(P, free, fixed_mask)``: ``q_full = P q_free`` for the fixed (zero) and tied
    degrees of freedom of ``sim.conditions``; ``free`` are the indices of the remaining
    degrees of freedom in the full vector. Prescribed non-zero displacements are not
    supported here (use the dynamic solvers)."""
    import scipy.sparse as sp

    lay = dof_layout(sim)
    nd, n = len(lay), sim.system.n
    index = {k: a for a, k in enumerate(lay)}
    fixed = np.zeros(n * nd, dtype=bool)
    tied = {}
    for c in sim.conditions:
        if isinstance(c, Tie):
            a = index.get(c.target)
            if a is None:
                continue
            for g, ms, ws in zip(c.region.index, c.masters, c.weights):
                tied[g * nd + a] = [(m * nd + a, w) for m, w in zip(ms, ws)]
        elif isinstance(c, FixedField):
            for comp in c.field_components:
                a = index.get((c.field, int(comp)))
                if a is not None:
                    fixed[c.region.index * nd + a] = True
        elif c.kinematic:
            for comp in c.components:
                a = index.get(("y", int(comp)))
                if a is not None:
                    fixed[c.region.index * nd + a] = True
    ghost = np.zeros(n * nd, dtype=bool)
    ghost[list(tied)] = True
    free = np.flatnonzero(~fixed & ~ghost)
    pos = np.full(n * nd, -1, dtype=np.int64)
    pos[free] = np.arange(free.size)
    r, cc, v = list(free), list(range(free.size)), [1.0] * free.size

    def expand(d, w, depth=0):
        if depth > 8:
            raise ValueError("ties nest too deeply (a ghost's master is a ghost of a ghost ...)")
        if fixed[d]:
            return []
        if d in tied:
            out = []
            for m, wm in tied[d]:
                out += expand(m, w * wm, depth + 1)
            return out
        return [(pos[d], w)]

    for g in tied:
        for p, w in expand(g, 1.0):
            r.append(g)
            cc.append(p)
            v.append(w)
    P = sp.csr_matrix((v, (r, cc)), shape=(n * nd, free.size))
    return P, free, fixed


def external_vector(sim) -> np.ndarray:
    """External loads (``Force``/``BodyForce`` conditions) as a generalised vector."""
    lay = dof_layout(sim)
    F = sim.external_forces()
    out = np.zeros((sim.system.n, len(lay)))
    for a, (kind, c) in enumerate(lay):
        if kind == "y":
            out[:, a] = F[:, c]
    return out.ravel()


def solve_static(sim, K=None) -> dict:
    """Static equilibrium of linear models under the loads: ``K_red q = P^T``-free rows of
    ``f``, sparse LU (``scipy.sparse.linalg.spsolve``, not assuming symmetry). Writes the
    solution into ``sim.state`` (ties applied). Returns the relative residual of the full
    force routine at the solution and the operator's asymmetry ``|K - K^T| / |K|``."""
    import scipy.sparse.linalg as spla

    if K is None:
        K = operator(sim)
    P, free, _ = reduction(sim)
    Kr = (K @ P)[free].tocsc()
    f = external_vector(sim)
    q = spla.spsolve(Kr, f[free])
    full = P @ q
    lay = dof_layout(sim)
    n, nd = sim.system.n, len(lay)
    st = sim.state
    Q = full.reshape(n, nd)
    for a, key in enumerate(lay):
        set_dof(st, key, Q[:, a])
    st.v[...] = 0.0
    Fint = generalised_forces(sim).ravel()
    res = Fint[free] + f[free]
    asym = spla.norm(K - K.T) / max(spla.norm(K), 1e-300)
    return {"residual": float(np.linalg.norm(res) / max(np.linalg.norm(f[free]), 1e-300)),
            "asymmetry": float(asym), "free_dofs": int(free.size)}


def mass_vector(sim) -> np.ndarray:
    """Inertia of every generalised degree of freedom (N ndof,) (kg, kg m^2)."""
    lay = dof_layout(sim)
    out = np.empty((sim.system.n, len(lay)))
    for a, (kind, c) in enumerate(lay):
        out[:, a] = sim.system.mass if kind == "y" else \
            sim.field_specs[kind].inertia * sim.system.volume
    return out.ravel()


def critical_dt(sim, K=None) -> float:
    """Sharp velocity-Verlet stability limit ``2/sqrt(lambda_max)`` of ``M^-1 K_red``
    (free degrees of freedom; ghosts follow their masters, as in a run)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    if K is None:
        K = operator(sim)
    P, free, _ = reduction(sim)
    Kr = (K @ P)[free]
    minv = sp.diags(1.0 / mass_vector(sim)[free])
    A = (minv @ Kr).tocsr()
    if A.shape[0] < 400:
        lam = np.linalg.eigvals(A.toarray())
    else:
        lam = spla.eigs(A, k=3, which="LM", return_eigenvectors=False, tol=1e-10)
    lmax = float(np.max(np.abs(lam)))
    return 2.0 / np.sqrt(lmax)


# --------------------------------------------------------------------------- kernels
@njit(cache=True)
def pairwise_sum(a, n):
    """sum a[0:n] in numpy's pairwise order (``np.add.reduce`` of a contiguous run: eight
    accumulators over blocks of at most 128, halves above), so a kernel's sums equal
    numpy's bit for bit."""
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[i]
        return res
    if n <= 128:
        r0, r1, r2, r3 = a[0], a[1], a[2], a[3]
        r4, r5, r6, r7 = a[4], a[5], a[6], a[7]
        i = 8
        stop = n - n % 8
        while i < stop:
            r0 += a[i]
            r1 += a[i + 1]
            r2 += a[i + 2]
            r3 += a[i + 3]
            r4 += a[i + 4]
            r5 += a[i + 5]
            r6 += a[i + 6]
            r7 += a[i + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return pairwise_sum(a, n2) + pairwise_sum(a[n2:], n - n2)


@njit(cache=True)
def _tie(q_nk, q0_nk, relative, g_i, m_ip, w_ip, c):
    """Column ``c`` of ghost rows ``g_i``: q_g = sum_p w_gp q_m (``relative``: about the
    reference ``q0_nk``, q_g = q0_g + sum_p w_gp (q_m - q0_m)), m = ``m_ip[g, p]``."""
    p = m_ip.shape[1]
    buf = np.empty(p)
    for i in range(g_i.shape[0]):
        for k in range(p):
            j = m_ip[i, k]
            if relative:
                buf[k] = w_ip[i, k] * (q_nk[j, c] - q0_nk[j, c])
            else:
                buf[k] = w_ip[i, k] * q_nk[j, c]
        s = pairwise_sum(buf, p)
        if relative:
            q_nk[g_i[i], c] = q0_nk[g_i[i], c] + s
        else:
            q_nk[g_i[i], c] = s


@njit(cache=True)
def _set_block(a_nk, idx_i, comps, value):
    """a[idx, comps] = value (the block ``np.ix_(idx, comps)``)."""
    for i in range(idx_i.shape[0]):
        for k in range(comps.shape[0]):
            a_nk[idx_i[i], comps[k]] = value
