"""Thermostats for velocity Verlet, each acting on a region (default: every particle).

``VelocityVerlet(dt, thermostat=...)`` calls ``thermostat.begin(sim, dt)`` before its first
half-kick and ``thermostat.end(sim, dt)`` after its second one. Only the free degrees of
freedom of the region are thermostatted (a prescribed velocity stays prescribed); their
number is ``N_f``. The kinetic temperature of the region is

    T_kin = 2 K / (N_f k_B),     K = sum_{i in region, free c} m_i v_ic^2 / 2.          (1)

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
    velocity Verlet step, thermostat masses ``Q_1 = N_f k_B T tau^2``,
    ``Q_j = k_B T tau^2``. Conserved:

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
:class:`ThermostatGroup`
    Several thermostats on disjoint regions, each with its own variable (e.g. one per body
    of an assembly: bodies of different models, whose heat capacities and heating differ,
    each held at the temperature, where one thermostat on all of them would hold only
    their mean).
"""
from __future__ import annotations

import json

import numpy as np

__all__ = ["Langevin", "NoseHooverChain", "NoseHoover", "ThermostatGroup",
           "kinetic_temperature"]


def _region_dofs(sim, region):
    """(N, 3) bool: the free dofs of ``region`` (a Region, an (N,) bool mask or None)."""
    n = sim.system.n
    if region is None:
        mask = np.ones(n, bool)
    else:
        mask = np.asarray(getattr(region, "mask", region), dtype=bool)
        if mask.shape != (n,):
            raise ValueError(f"thermostat region has shape {mask.shape}; valid: ({n},) or a Region "
                             "of this body")
        if not mask.any():
            raise ValueError("thermostat region selects no particle")
    dof = np.repeat(mask[:, None], 3, axis=1) & ~sim.constrained
    if sim.system.dim < 3:
        dof[:, sim.system.dim:] = False
    if not dof.any():
        raise ValueError("thermostat region has no free degree of freedom")
    return dof


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
    return 2.0 * K / (dof.sum() * (K_B_SI if k_B is None else k_B))


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

    def begin(self, sim, dt) -> None:
        pass

    def end(self, sim, dt) -> None:
        """Mutates ``sim.state.v``: the Ornstein-Uhlenbeck step on the region's free dofs."""
        c = np.exp(-self.gamma * dt)
        v = sim.state.v.reshape(-1)
        xi = self.rng.standard_normal(self.idx.size)
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
    """Nose-Hoover chain on a region (module docstring).

    Parameters
    ----------
    temperature : float
        K (> 0).
    tau : float
        Relaxation time (time unit of the scene).
    region : Region or (N,) bool, optional
    chain : int
        Chain length M (1 = plain Nose-Hoover).
    k_B : float, optional
        Boltzmann constant in the scene's units (default SI, J/K).
    """

    name = "nose-hoover-chain"

    def __init__(self, temperature: float, tau: float, *, region=None, chain: int = 3,
                 k_B: float | None = None):
        from upscale.constants import K_B_SI

        _check(temperature, "tau", tau)
        if not temperature > 0:
            raise ValueError(f"Nose-Hoover needs temperature > 0 K, got {temperature!r}")
        if int(chain) < 1:
            raise ValueError(f"chain length must be >= 1, got {chain!r}")
        self.T, self.tau, self.region, self.M = float(temperature), float(tau), region, int(chain)
        self.k_B = K_B_SI if k_B is None else float(k_B)
        self.eta = np.zeros(self.M)
        self.p = np.zeros(self.M)   # thermostat velocities d eta / dt

    def prepare(self, sim) -> None:
        self.dof = _region_dofs(sim, self.region)
        self.nf = int(self.dof.sum())
        kT = self.k_B * self.T
        self.Q = np.full(self.M, kT * self.tau ** 2)
        self.Q[0] *= self.nf
        self.m = sim.system.mass[:, None]

    def _half(self, sim, h) -> None:
        """Mutates the chain and ``sim.state.v`` (region dofs): a chain step of h = dt/2."""
        v = sim.state.v
        kT = self.k_B * self.T
        K2 = float(np.sum(self.m * v * v * self.dof))   # 2 x kinetic energy
        M, p, Q = self.M, self.p, self.Q
        h2, h4 = 0.5 * h, 0.25 * h

        def G(j, K2):
            return ((K2 - self.nf * kT) if j == 0 else (Q[j - 1] * p[j - 1] ** 2 - kT)) / Q[j]

        p[M - 1] += h2 * G(M - 1, K2)
        for j in range(M - 2, -1, -1):
            e = np.exp(-h4 * p[j + 1])
            p[j] = (p[j] * e + h2 * G(j, K2)) * e
        s = np.exp(-h * p[0])
        v[self.dof] *= s
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
        return {"thermostat": self.name, "temperature_K": self.T, "tau": self.tau,
                "chain": self.M}


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
        comps = np.atleast_1d(np.asarray(components, dtype=np.int64))
        if comps.size == 0 or comps.min() < 0 or comps.max() > 2 or len(set(comps)) != comps.size:
            raise ValueError(f"components={components!r}; valid: a subset of (0, 1, 2)")
        if ndf is not None and not int(ndf) > 0:
            raise ValueError(f"ndf={ndf!r}; valid: a positive number of degrees of freedom")
        self.T, self.tau, self.region = float(temperature), float(tau), region
        self.components, self.field_names = comps, tuple(str(f) for f in fields)
        self.field_region, self._ndf = field_region, ndf
        self.k_B = K_B_SI if k_B is None else float(k_B)
        self.xi = 0.0

    def prepare(self, sim) -> None:
        dof = _region_dofs(sim, self.region)
        keep = np.zeros(3, bool)
        keep[self.components] = True
        self.dof = dof & keep[None, :]
        self.m = sim.system.mass[:, None]
        n = sim.system.n
        fr = np.ones(n, bool) if self.field_region is None else \
            np.asarray(getattr(self.field_region, "mask", self.field_region), dtype=bool)
        if fr.shape != (n,):
            raise ValueError(f"field_region of shape {fr.shape}; valid: ({n},) or a Region")
        specs = getattr(sim, "field_specs", {})
        missing = [f for f in self.field_names if f not in specs]
        if missing:
            raise ValueError(f"thermostat fields {missing}; valid: the simulation's fields "
                             f"{sorted(specs)}")
        # per field: the rows of field_region that carry it (FieldSpec.rows; elsewhere a
        # field is at rest), as a slice where they are contiguous (one body's rows)
        self.frows = {f: _rows(np.flatnonzero(fr), specs[f].span, n) for f in self.field_names}
        self.finert = {f: (specs[f].inertia * sim.system.volume)[self.frows[f], None]
                       for f in self.field_names}
        nfield = sum(int((~sim.field_constrained[f][self.frows[f]]).sum())
                     for f in self.field_names)
        self.nf = int(self._ndf) if self._ndf is not None else int(self.dof.sum()) + nfield
        self.idx = np.flatnonzero(self.dof.ravel())  # the thermostatted translation dofs
        self.m_idx = np.repeat(sim.system.mass, 3)[self.idx]

    def temperature(self, sim) -> float:
        """Eq. (1) on the thermostat's dofs (K)."""
        vi = sim.state.v.reshape(-1)[self.idx]
        K2 = float(np.dot(self.m_idx * vi, vi))
        for f in self.field_names:
            fv = sim.state.field_v[f][self.frows[f]]
            K2 += float(np.sum(self.finert[f] * fv * fv))
        return K2 / (self.nf * self.k_B)

    def _half(self, sim, dt) -> None:
        """Mutates xi and the thermostatted rates: eq. (3) with h = dt/2."""
        self.xi += 0.5 * dt * (self.temperature(sim) / self.T - 1.0) / self.tau ** 2
        s = float(np.exp(-0.5 * dt * self.xi))
        v = sim.state.v.reshape(-1)
        if not np.shares_memory(v, sim.state.v):  # (a non-contiguous velocity array)
            raise ValueError("the state's velocities must be one contiguous array")
        v[self.idx] *= s
        for f in self.field_names:
            sim.state.field_v[f][self.frows[f]] *= s

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
