"""Thermostats for velocity Verlet, each acting on a region (default: every particle).

``VelocityVerlet(dt, thermostat=...)`` calls ``thermostat.begin(sim, dt)`` before its first
half-kick and ``thermostat.end(sim, dt)`` after its second one. Only the free degrees of
freedom of the region are thermostatted (a prescribed velocity stays prescribed); their
number is ``N_f``. The kinetic temperature of the region is

    T_kin = 2 K / (N_f k_B),     K = sum_{i in region, free c} m_i v_ic^2 / 2.          (1)

Several MPI ranks (:mod:`upscale.engine.parallel`): the sums of (1) and N_f are over each
rank's owned particles, added over the ranks (Nose-Hoover's answer then equals the serial
one up to that order of the sum); :class:`Langevin` draws every rank the whole body's
numbers and keeps its own dofs', so its answer is the serial one bit for bit (at the
cost of one normal number per thermostatted dof of the body per rank and step).

Units: ``k_B`` in the scene's energy per kelvin: :data:`upscale.constants.K_B_SI` (J/K) for
SI scenes, :data:`upscale.constants.K_B_EV` (eV/K) for atomistic ones (eV, Å, amu and the
matching time unit, in which ``m v^2`` is an energy).

:class:`Langevin`
    After the second half-kick the Ornstein-Uhlenbeck step, exact for the friction and the
    noise over dt: ``v <- c v + sqrt((1 - c^2) k_B T / m) xi``, ``c = exp(-gamma dt)``,
    ``xi ~ N(0, 1)`` (the "O" of the splitting B A B O; Leimkuhler & Matthews,
    *Molecular Dynamics*, Springer 2015, sec. 7.3). The generator (PCG64 from ``seed``)
    is part of the checkpoint, so a resumed run draws the same numbers.
:class:`NoseHooverChain`
    Nose-Hoover chain of length M (G. J. Martyna, M. L. Klein, M. Tuckerman, J. Chem. Phys.
    97, 2635 (1992)), integrated by the Trotter factorisation of Martyna, Tuckerman, Tobias,
    Klein, Mol. Phys. 87, 1117 (1996): a half step of the chain before and after the
    velocity Verlet step (or the r-RESPA outer step), thermostat masses
    ``Q_1 = N_f k_B T tau^2``, ``Q_j = k_B T tau^2`` (LAMMPS ``fix nvt``, whose default
    chain is M = 3), on chosen components and fields as :class:`NoseHoover`. The second
    thermostat of the chain thermostats the first, so the first variable's own
    oscillation (the period ~ 2 pi tau / sqrt(2) of a single Nose-Hoover variable on a
    system far from ergodic) is damped. Conserved:

        H' = E_kin + E_pot + sum_j Q_j p_j^2 / 2 + N_f k_B T eta_1 + k_B T sum_{j>1} eta_j  (2)

    (:meth:`NoseHooverChain.conserved_extra` gives the thermostat's part).
:class:`NoseHoover`
    One Nose-Hoover variable xi (S. Nose, J. Chem. Phys. 81, 511 (1984); W. G. Hoover,
    Phys. Rev. A 31, 1695 (1985)) in explicit half steps of h = dt/2 before the first
    half-kick and after the second,

        xi <- xi + h (T_kin / T - 1) / tau^2,     v <- v exp(-h xi),                    (3)

    on chosen translation components and, optionally, on fields with inertia (their rates
    count in K with their inertia, eq. (1)). With ``components=(0, 1)`` it is LAMMPS's
    ``fix nvt`` with ``compute temp/partial 1 1 0`` (the temperature of x, y only: an
    axial stretching flow is not heat), in the single-variable form. ``ndf`` overrides
    the number of degrees of freedom in eq. (1) (as LAMMPS's ``compute_modify extra/dof``).
:class:`Quench`
    Damped dynamics to the nearest minimum (no temperature): after every step the power
    of the forces on the region's rates (translations and fields),
    ``P = sum F . v + sum_fields G . w``, decides: ``P < 0``, the rates are set to zero;
    else they are turned toward the force, ``u <- (1 - alpha) u + alpha |u| F / |F|`` over
    all of them together (u = (v, w), F = (F, G)), with ``alpha`` from ``alpha0`` shrinking
    by ``f_alpha`` after ``n_min`` steps downhill and reset on a zeroing: FIRE's mixing
    (Bitzek et al., Phys. Rev. Lett. 97, 170201 (2006)) at the integrator's fixed step.
    It moves whatever the integrator moves, so bodies whose kinematic ties (slaves,
    fields) a static minimiser does not carry relax with the rest.
:class:`ThermostatGroup`
    Several thermostats on disjoint regions, each with its own variable (e.g. one per body
    of an assembly: bodies of different models, whose heat capacities and heating differ,
    each held at the temperature, where one thermostat on all of them would hold only
    their mean).
"""
from __future__ import annotations

import json

import numpy as np

__all__ = ["Langevin", "NoseHooverChain", "NoseHoover", "ThermostatGroup", "Quench",
           "kinetic_temperature"]


def _region_dofs(sim, region):
    """(N, 3) bool: the free dofs of ``region`` (a Region, an (N,) bool mask or None)."""
    n = sim.system.n
    part = getattr(sim, "part", None)
    if region is None:
        mask = np.ones(n, bool)
    else:
        mask = np.asarray(getattr(region, "mask", region), dtype=bool)
        if part is not None and mask.shape == (part.local.n_global,):
            mask = mask[part.local.gid]  # a region of the whole body: this rank's rows
        if mask.shape != (n,):
            raise ValueError(f"thermostat region has shape {mask.shape}; valid: ({n},) or a Region "
                             "of this body")
        if not _gsum(sim, float(mask.any())):
            raise ValueError("thermostat region selects no particle")
    dof = np.repeat(mask[:, None], 3, axis=1) & ~sim.constrained  # (a halo row is held)
    if sim.system.dim < 3:
        dof[:, sim.system.dim:] = False
    if not _gsum(sim, float(dof.any())):
        raise ValueError("thermostat region has no free degree of freedom")
    return dof


def _gsum(sim, x):
    """``x`` summed over the MPI ranks of ``sim`` (itself on one process; collective)."""
    part = getattr(sim, "part", None)
    return x if part is None else part.sum(x)


def _rows(idx, span: slice, n: int):
    """The rows ``idx`` (sorted int array) within ``span``, as a slice if contiguous."""
    idx = idx[(idx >= (span.start or 0)) & (idx < (n if span.stop is None else span.stop))]
    if idx.size and int(idx[-1]) - int(idx[0]) + 1 == idx.size:
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def kinetic_temperature(sim, region=None, k_B: float | None = None) -> float:
    """Eq. (1) of the region's free dofs (K); ``k_B`` default SI."""
    from upscale.constants import K_B_SI

    dof = _region_dofs(sim, region)
    K = 0.5 * float(np.sum(sim.system.mass[:, None] * sim.state.v ** 2 * dof))
    K, nd = _gsum(sim, np.array([K, dof.sum()])) if getattr(sim, "part", None) else (K, dof.sum())
    return 2.0 * K / (nd * (K_B_SI if k_B is None else k_B))


def _check(temperature, name, value):
    if not (np.isfinite(temperature) and temperature >= 0):
        raise ValueError(f"temperature must be >= 0 K, got {temperature!r}")
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be positive, got {value!r}")


class Langevin:
    """Langevin thermostat on a region (module docstring).

    Parameters
    ----------
    temperature : float
        K.
    damping : float
        Friction rate gamma (1 / time unit of the scene).
    region : Region or (N,) bool, optional
    seed : int
    k_B : float, optional
        Boltzmann constant in the scene's units (default SI, J/K).
    """

    name = "langevin"

    def __init__(self, temperature: float, damping: float, *, region=None, seed: int = 0,
                 k_B: float | None = None):
        from upscale.constants import K_B_SI

        _check(temperature, "damping", damping)
        self.T, self.gamma, self.region = float(temperature), float(damping), region
        self.k_B = K_B_SI if k_B is None else float(k_B)
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)

    def prepare(self, sim) -> None:
        self.dof = _region_dofs(sim, self.region)
        self.idx = np.flatnonzero(self.dof.ravel())
        self.m = np.repeat(sim.system.mass, 3)[self.idx]
        self._draw, self._pick = self.idx.size, None
        part = getattr(sim, "part", None)
        if part is not None:  # every rank draws the whole body's numbers, keeps its own
            g = (3 * part.local.gid[self.idx // 3] + self.idx % 3).astype(np.int64)
            every = np.concatenate(part.comm.allgather(g))
            every.sort()
            self._draw, self._pick = every.size, np.searchsorted(every, g)

    def begin(self, sim, dt) -> None:
        pass

    def end(self, sim, dt) -> None:
        """Mutates ``sim.state.v``: the Ornstein-Uhlenbeck step on the region's free dofs."""
        c = np.exp(-self.gamma * dt)
        v = sim.state.v.reshape(-1)
        xi = self.rng.standard_normal(self._draw)
        if self._pick is not None:
            xi = xi[self._pick]
        v[self.idx] = c * v[self.idx] + np.sqrt((1.0 - c * c) * self.k_B * self.T / self.m) * xi

    def checkpoint_arrays(self) -> dict:
        s = json.dumps(self.rng.bit_generator.state).encode()
        return {"rng": np.frombuffer(s, dtype=np.uint8)}

    def restore_arrays(self, d: dict) -> None:
        if "rng" in d:
            self.rng.bit_generator.state = json.loads(bytes(d["rng"]).decode())

    def describe(self) -> dict:
        return {"thermostat": self.name, "temperature_K": self.T, "damping": self.gamma,
                "seed": self.seed, "dofs": int(self.idx.size) if hasattr(self, "idx") else None}


class NoseHooverChain:
    """Nose-Hoover chain on a region, on chosen components and fields (module docstring,
    eq. (2)).

    Parameters
    ----------
    temperature : float
        K (> 0).
    tau : float
        Relaxation time (time unit of the scene): ``Q_1 = N_f k_B T tau^2``,
        ``Q_j = k_B T tau^2`` (LAMMPS ``fix nvt`` with ``Tdamp = tau``).
    region : Region or (N,) bool, optional
        The particles whose translations are thermostatted (their free dofs on
        ``components``).
    chain : int
        Chain length M (default 3, LAMMPS's ``tchain``; 1 = a single Nose-Hoover variable
        in the same Trotter splitting).
    components, fields, field_region, ndf :
        As :class:`NoseHoover`: the translation components in eq. (1), fields with inertia
        whose rates count and are scaled too, and the number of degrees of freedom
        ``N_f`` (default: the free dofs it acts on).
    k_B : float, optional
        Boltzmann constant in the scene's units (default SI, J/K).
    weights : (N,) array, optional
        Per-row weight w_i of its kinetic energy in eq. (1): T = sum_i w_i m_i v_i^2 /
        (N_f k_B). A row standing for several atoms (a coarse particle, a coarse tube's
        rows) counts as they would, so with ``ndf`` the number of dofs represented the
        chain reads the temperature of the represented atoms (default: 1 everywhere).

    One half step (h = dt/2, at the start and at the end of the step), LAMMPS's
    ``nhc_temp_integrate`` with one sub-step: ``G_1 = (2K - N_f k_B T) / Q_1``,
    ``G_j = (Q_{j-1} p_{j-1}^2 - k_B T) / Q_j``; from the chain's end down,
    ``p_j <- (p_j e + (h/2) G_j) e`` with ``e = exp(-(h/4) p_{j+1})``; the rates scaled
    by ``exp(-h p_1)``, ``eta_j += h p_j``; then up the chain again with the new G.
    """

    name = "nose-hoover-chain"

    def __init__(self, temperature: float, tau: float, *, region=None, chain: int = 3,
                 components=(0, 1, 2), fields=(), field_region=None,
                 ndf: int | None = None, k_B: float | None = None, weights=None):
        from upscale.constants import K_B_SI

        _check(temperature, "tau", tau)
        if not temperature > 0:
            raise ValueError(f"Nose-Hoover needs temperature > 0 K, got {temperature!r}")
        if not (isinstance(chain, (int, np.integer)) and int(chain) >= 1):
            raise ValueError(f"chain length {chain!r}; valid: an integer >= 1")
        self.T, self.tau, self.region, self.M = float(temperature), float(tau), region, int(chain)
        self.components, self.field_names = _components(components), tuple(str(f) for f in fields)
        if ndf is not None and not int(ndf) > 0:
            raise ValueError(f"ndf={ndf!r}; valid: a positive number of degrees of freedom")
        self.field_region, self._ndf = field_region, ndf
        self.k_B = K_B_SI if k_B is None else float(k_B)
        self.weights = None if weights is None else np.asarray(weights, dtype=float)
        self.eta = np.zeros(self.M)
        self.p = np.zeros(self.M)   # thermostat velocities d eta / dt

    def prepare(self, sim) -> None:
        _prepare_dofs(self, sim)
        w = self.weights
        if w is not None:  # eq. (1) weighted: the weights folded into the masses it sums
            if w.shape != (sim.system.n,) or not np.all(np.isfinite(w) & (w > 0)):
                raise ValueError(f"weights of shape {w.shape}; valid: ({sim.system.n},) "
                                 "positive numbers")
            self.m_idx = self.m_idx * np.repeat(w, 3)[self.idx]
            self.finert = {f: a * w[self.frows[f]][:, None] for f, a in self.finert.items()}
        kT = self.k_B * self.T
        self.Q = np.full(self.M, kT * self.tau ** 2)
        self.Q[0] *= self.nf

    def temperature(self, sim) -> float:
        """Eq. (1) on the thermostat's dofs (K)."""
        return _twice_kinetic(self, sim) / (self.nf * self.k_B)

    def _half(self, sim, h) -> None:
        """Mutates the chain and the thermostatted rates: a chain step of h = dt/2."""
        kT = self.k_B * self.T
        K2 = _twice_kinetic(self, sim)
        M, p, Q = self.M, self.p, self.Q
        h2, h4 = 0.5 * h, 0.25 * h

        def G(j, K2):
            return ((K2 - self.nf * kT) if j == 0 else (Q[j - 1] * p[j - 1] ** 2 - kT)) / Q[j]

        p[M - 1] += h2 * G(M - 1, K2)
        for j in range(M - 2, -1, -1):
            e = np.exp(-h4 * p[j + 1])
            p[j] = (p[j] * e + h2 * G(j, K2)) * e
        s = float(np.exp(-h * p[0]))
        _scale_rates(self, sim, s)
        K2 *= s * s
        self.eta += h * p
        for j in range(M - 1):
            e = np.exp(-h4 * p[j + 1])
            p[j] = (p[j] * e + h2 * G(j, K2)) * e
        p[M - 1] += h2 * G(M - 1, K2)

    def begin(self, sim, dt) -> None:
        self._half(sim, 0.5 * dt)

    def end(self, sim, dt) -> None:
        self._half(sim, 0.5 * dt)

    def conserved_extra(self) -> float:
        """The thermostat's part of eq. (2) (energy units of the scene)."""
        kT = self.k_B * self.T
        return float(0.5 * np.sum(self.Q * self.p ** 2) + self.nf * kT * self.eta[0]
                     + kT * np.sum(self.eta[1:]))

    def checkpoint_arrays(self) -> dict:
        return {"eta": self.eta.copy(), "p": self.p.copy()}

    def restore_arrays(self, d: dict) -> None:
        if "eta" in d:
            self.eta[...] = d["eta"]
            self.p[...] = d["p"]

    def describe(self) -> dict:
        out = {"thermostat": self.name, "temperature_K": self.T, "tau": self.tau,
               "chain": self.M, "components": self.components.tolist(),
               "fields": list(self.field_names)}
        if self.weights is not None:
            out["weights"] = sorted({float(x) for x in self.weights})
        return out


def _components(components) -> np.ndarray:
    comps = np.atleast_1d(np.asarray(components, dtype=np.int64))
    if comps.size == 0 or comps.min() < 0 or comps.max() > 2 or len(set(comps)) != comps.size:
        raise ValueError(f"components={components!r}; valid: a subset of (0, 1, 2)")
    return comps


def _prepare_dofs(th, sim) -> None:
    """The Nose-Hoover thermostats' dofs on ``sim``: ``th.idx`` (flat indices of the
    thermostatted translation dofs), ``th.m_idx`` (their masses), ``th.frows`` /
    ``th.finert`` (per field: the rows it is thermostatted on, their inertia) and
    ``th.nf`` (N_f of eq. (1))."""
    dof = _region_dofs(sim, th.region)
    keep = np.zeros(3, bool)
    keep[th.components] = True
    th.dof = dof & keep[None, :]
    th.m = sim.system.mass[:, None]
    n = sim.system.n
    fr = np.ones(n, bool) if th.field_region is None else \
        np.asarray(getattr(th.field_region, "mask", th.field_region), dtype=bool)
    if fr.shape != (n,):
        raise ValueError(f"field_region of shape {fr.shape}; valid: ({n},) or a Region")
    specs = getattr(sim, "field_specs", {})
    missing = [f for f in th.field_names if f not in specs]
    if missing:
        raise ValueError(f"thermostat fields {missing}; valid: the simulation's fields "
                         f"{sorted(specs)}")
    # per field: the rows of field_region that carry it (FieldSpec.rows; elsewhere a
    # field is at rest), as a slice where they are contiguous (one body's rows)
    th.frows = {f: _rows(np.flatnonzero(fr), specs[f].span, n) for f in th.field_names}
    th.finert = {f: (specs[f].inertia * sim.system.volume)[th.frows[f], None]
                 for f in th.field_names}
    nfield = sum(int((~sim.field_constrained[f][th.frows[f]]).sum())
                 for f in th.field_names)
    th.nf = int(th._ndf) if th._ndf is not None else int(_gsum(sim, float(th.dof.sum()))) + nfield
    th.idx = np.flatnonzero(th.dof.ravel())  # the thermostatted translation dofs
    th.m_idx = np.repeat(sim.system.mass, 3)[th.idx]


def _scale_rates(th, sim, s: float) -> None:
    """Multiply the rates ``th`` thermostats (translations and fields) by ``s``, in place."""
    v = sim.state.v.reshape(-1)
    if not np.shares_memory(v, sim.state.v):  # (a non-contiguous velocity array)
        raise ValueError("the state's velocities must be one contiguous array")
    v[th.idx] *= s
    for f in th.field_names:
        sim.state.field_v[f][th.frows[f]] *= s


def _twice_kinetic(th, sim) -> float:
    """2 x the kinetic energy of the rates ``th`` thermostats (the dofs of
    :func:`_prepare_dofs`): translations and fields."""
    vi = sim.state.v.reshape(-1)[th.idx]
    K2 = float(np.dot(th.m_idx * vi, vi))
    for f in th.field_names:
        fv = sim.state.field_v[f][th.frows[f]]
        K2 += float(np.sum(th.finert[f] * fv * fv))
    return float(_gsum(sim, K2))  # several MPI ranks: the owned rows' sums added


class NoseHoover:
    """Single Nose-Hoover thermostat on a region, on chosen components and fields (module
    docstring, eq. (3)).

    Parameters
    ----------
    temperature : float
        K (> 0).
    tau : float
        Relaxation time (time unit of the scene).
    region : Region or (N,) bool, optional
        The particles whose translations are thermostatted (their free dofs on
        ``components``).
    components : subset of (0, 1, 2)
        Translation components in eq. (1) and scaled by (3).
    fields : sequence of str
        Fields with inertia (:mod:`upscale.engine.fields`) whose rates count in eq. (1) and
        are scaled too, on ``field_region`` (default every particle; components a condition
        prescribes are left out of the count).
    ndf : int, optional
        Degrees of freedom of eq. (1) (default: the free dofs it acts on).
    k_B : float, optional
        Boltzmann constant in the scene's units (default SI, J/K).
    """

    name = "nose-hoover"

    def __init__(self, temperature: float, tau: float, *, region=None, components=(0, 1, 2),
                 fields=(), field_region=None, ndf: int | None = None,
                 k_B: float | None = None):
        from upscale.constants import K_B_SI

        _check(temperature, "tau", tau)
        if not temperature > 0:
            raise ValueError(f"Nose-Hoover needs temperature > 0 K, got {temperature!r}")
        comps = _components(components)
        if ndf is not None and not int(ndf) > 0:
            raise ValueError(f"ndf={ndf!r}; valid: a positive number of degrees of freedom")
        self.T, self.tau, self.region = float(temperature), float(tau), region
        self.components, self.field_names = comps, tuple(str(f) for f in fields)
        self.field_region, self._ndf = field_region, ndf
        self.k_B = K_B_SI if k_B is None else float(k_B)
        self.xi = 0.0

    def prepare(self, sim) -> None:
        _prepare_dofs(self, sim)

    def temperature(self, sim) -> float:
        """Eq. (1) on the thermostat's dofs (K)."""
        return _twice_kinetic(self, sim) / (self.nf * self.k_B)

    def _half(self, sim, dt) -> None:
        """Mutates xi and the thermostatted rates: eq. (3) with h = dt/2."""
        self.xi += 0.5 * dt * (self.temperature(sim) / self.T - 1.0) / self.tau ** 2
        _scale_rates(self, sim, float(np.exp(-0.5 * dt * self.xi)))

    def begin(self, sim, dt) -> None:
        self._half(sim, dt)

    def end(self, sim, dt) -> None:
        self._half(sim, dt)

    def checkpoint_arrays(self) -> dict:
        return {"xi": np.float64(self.xi)}

    def restore_arrays(self, d: dict) -> None:
        if "xi" in d:
            self.xi = float(d["xi"])

    def describe(self) -> dict:
        return {"thermostat": self.name, "temperature_K": self.T, "tau": self.tau,
                "components": self.components.tolist(), "fields": list(self.field_names)}


class Quench:
    """The molecular-dynamics quench with FIRE's mixing on a region (module docstring).

    Parameters
    ----------
    region : Region or (N,) bool, optional
        The particles whose free translation dofs are quenched (default every particle).
    fields : sequence of str or None
        Fields with inertia quenched too (default: every field of the simulation), on
        ``field_region`` (default every particle).
    alpha0, f_alpha, n_min : FIRE's mixing constants (0.1, 0.99, 5); ``alpha0 = 0``: the
        plain quench (zeroing only).
    """

    name = "quench"

    def __init__(self, *, region=None, fields=None, field_region=None, alpha0: float = 0.1,
                 f_alpha: float = 0.99, n_min: int = 5):
        if not 0.0 <= alpha0 < 1.0:
            raise ValueError(f"alpha0={alpha0!r}; valid: 0 <= alpha0 < 1")
        self.region, self.field_region = region, field_region
        self.field_names = None if fields is None else tuple(str(f) for f in fields)
        self.alpha0, self.f_alpha, self.n_min = float(alpha0), float(f_alpha), int(n_min)
        self.alpha, self.n_pos = self.alpha0, 0
        self.zeroed = 0  # steps at which the rates were set to zero

    def prepare(self, sim) -> None:
        specs = getattr(sim, "field_specs", {})
        if self.field_names is None:
            self.field_names = tuple(specs)
        self.components, self._ndf = np.arange(3), None
        _prepare_dofs(self, sim)

    def begin(self, sim, dt) -> None:
        """Nothing at the start of a step: the quench acts only after the forces (``end``)."""

    def _parts(self, sim):
        """[(rates view, force)] of the region: the flat translation dofs, then each field."""
        v = sim.state.v.reshape(-1)
        if not np.shares_memory(v, sim.state.v):
            raise ValueError("the state's velocities must be one contiguous array")
        out = [(v, self.idx, sim.F.reshape(-1)[self.idx])]
        for f in self.field_names:
            r = self.frows[f]
            out.append((sim.state.field_v[f], r, sim.G[f][r]))
        return out

    def power(self, sim) -> float:
        """P of the module docstring (energy / time), from the forces of the last step."""
        return float(sum(np.sum(u[r] * F) for u, r, F in self._parts(sim)))

    def end(self, sim, dt) -> None:
        """Mutates the region's rates: zeroed if the power is negative, else mixed."""
        parts = self._parts(sim)
        P = float(sum(np.sum(u[r] * F) for u, r, F in parts))
        if P < 0.0:
            for u, r, _ in parts:
                u[r] = 0.0
            self.zeroed += 1
            self.alpha, self.n_pos = self.alpha0, 0
            return
        if self.alpha > 0.0:
            un = np.sqrt(sum(float(np.sum(u[r] * u[r])) for u, r, _ in parts))
            fn = np.sqrt(sum(float(np.sum(F * F)) for _, _, F in parts))
            if fn > 0.0:
                for u, r, F in parts:
                    u[r] = (1.0 - self.alpha) * u[r] + (self.alpha * un / fn) * F
            if self.n_pos > self.n_min:
                self.alpha *= self.f_alpha
        self.n_pos += 1

    def checkpoint_arrays(self) -> dict:
        return {"alpha": np.float64(self.alpha), "n_pos": np.int64(self.n_pos)}

    def restore_arrays(self, d: dict) -> None:
        if "alpha" in d:
            self.alpha, self.n_pos = float(d["alpha"]), int(d["n_pos"])

    def describe(self) -> dict:
        return {"thermostat": self.name, "fields": list(self.field_names or ()),
                "alpha0": self.alpha0}


class ThermostatGroup:
    """Thermostats on disjoint regions acting together (module docstring): each one's
    half steps in turn, in the given order.

    Parameters
    ----------
    thermostats : sequence
        :class:`NoseHoover`, :class:`NoseHooverChain` or :class:`Langevin`, on regions
        (and fields) that do not overlap.
    """

    name = "group"

    def __init__(self, thermostats):
        self.members = list(thermostats)
        if not self.members:
            raise ValueError("ThermostatGroup needs at least one thermostat")

    def prepare(self, sim) -> None:
        for t in self.members:
            t.prepare(sim)

    def begin(self, sim, dt) -> None:
        for t in self.members:
            t.begin(sim, dt)

    def end(self, sim, dt) -> None:
        for t in self.members:
            t.end(sim, dt)

    def checkpoint_arrays(self) -> dict:
        return {f"{k}_{key}": v for k, t in enumerate(self.members)
                for key, v in t.checkpoint_arrays().items()}

    def restore_arrays(self, d: dict) -> None:
        for k, t in enumerate(self.members):
            p = f"{k}_"
            t.restore_arrays({key[len(p):]: v for key, v in d.items() if key.startswith(p)})

    def describe(self) -> dict:
        return {"thermostat": self.name, "members": [t.describe() for t in self.members]}
