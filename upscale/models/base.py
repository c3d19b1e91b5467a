"""The model interface every model of the project implements.

A model is created from material parameters, told the body once (:meth:`Model.prepare`),
then asked for forces on a :class:`~upscale.engine.state.State`. It declares what it needs
in :attr:`Model.needs` so the engine skips the rest.

Force convention
----------------
``force_kind = "density"`` (peridynamic models): :meth:`Model.add_force` *adds* the force
density ``b_i`` (N/m^3) of every particle to ``out``; the force on particle i is
``b_i * V_i`` and its acceleration ``b_i / rho_i``. For bond-based PD
``b_i = sum_j f(eta, xi) V_j beta_ij``; each bond's partner volume ``V_j`` times the
partial-volume factor ``beta_ij`` (``family.volume_factor``) weights it.

``force_kind = "particle"`` (e.g. gain-matrix/DCBR or atomistic models): ``add_force``
adds the force per particle ``F_i`` (N, or eV/A in atomistic units); mass is
``density * volume``.

Energy: :meth:`Model.energy` is the total stored energy (J = sum_i W_i V_i for density
models). Residual/tangent hooks for the Newton-Raphson solver (``engine/newton.py``):
``residual`` is the internal force per particle ``F_int`` flattened to (3N,), the
``tangent`` is the stiffness ``K = -dF_int/dy`` as a ``scipy.sparse`` (3N, 3N) matrix, so
a static step solves ``K du = F_ext + F_int``.
"""
from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["Needs", "Model", "numerical_tangent", "check_positive"]


def check_positive(**kw) -> None:
    """One-line ValueError for the first given parameter that is not a finite positive
    number (None = not given, skipped)."""
    for k, v in kw.items():
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ValueError(f"{k} must be positive, got {v!r}")


@dataclasses.dataclass(frozen=True)
class Needs:
    """What a model asks of the engine. The engine does nothing no model asks for.

    pairs
        the pair family (CSR) within the horizon
    triplets, quadruplets
        higher families built on demand from the pair family (``engine/multibody.py``)
    failure
        the model has a bond-failure criterion: the engine calls ``break_bonds`` (or the
        fused ``step_force``) and tracks damage; otherwise bonds never break
    energy
        the model can compute a stored energy (``energy``); it is still only evaluated when
        an output or diagnostic asks for it
    tangent
        the model provides an analytic ``tangent`` (else Newton falls back to
        :func:`numerical_tangent`)
    """

    pairs: bool = True
    triplets: bool = False
    quadruplets: bool = False
    failure: bool = False
    energy: bool = False
    tangent: bool = False


class Model:
    """Base class of every model. Subclasses set ``name``, ``needs`` and ``force_kind``
    and implement :meth:`add_force` (and optionally the rest).

    Attributes set by :meth:`prepare`: ``system``, ``family`` (and ``triplets`` /
    ``quadruplets`` when the model needs them).
    """

    name: str = "model"
    needs: Needs = Needs()
    force_kind: str = "density"

    system = None
    family = None
    triplets = None
    quadruplets = None

    # ------------------------------------------------------------------ set-up
    def prepare(self, system, family, *, triplets=None, quadruplets=None) -> None:
        """Bind the model to a body and its families; build what the model needs
        (e.g. weighted volumes, shape tensors). Called once before the first force."""
        if self.needs.pairs and family is None:
            raise ValueError(f"model {self.name!r} needs a pair family; build one with "
                             "upscale.engine.build_family(system, horizon)")
        self.system = system
        self.family = family
        self.triplets = triplets
        self.quadruplets = quadruplets

    def init_state(self, state) -> None:
        """Put the model's history variables into ``state.extra`` (default: none)."""

    # ------------------------------------------------------------------ forces
    def add_force(self, state, out: np.ndarray) -> None:
        """Add this model's force (density, or per particle; see ``force_kind``) on the
        current positions ``state.y`` and bonds ``state.intact`` to ``out`` (N, 3)."""
        raise NotImplementedError(f"model {self.name!r} does not implement add_force")

    def break_bonds(self, state) -> int:
        """Mutates ``state.intact``: apply the failure criterion to the current positions.
        Returns the number of directed bonds broken. Default: no failure."""
        return 0

    def step_force(self, state, out: np.ndarray, *, failure: bool = True) -> int:
        """One force evaluation of a time step: add forces, then (if ``failure``) break
        bonds from the same positions (LAMMPS order: a bond that fails in this evaluation
        still contributed its force). Models may fuse the two passes."""
        self.add_force(state, out)
        if failure and self.needs.failure:
            return self.break_bonds(state)
        return 0

    def force(self, state) -> np.ndarray:
        """This model's force array alone (a new (N, 3) array)."""
        out = np.zeros_like(state.y)
        self.add_force(state, out)
        return out

    # ------------------------------------------------------------------ energy
    def energy_density(self, state) -> np.ndarray:
        """Stored energy density W_i (J/m^3) per particle (N,)."""
        raise NotImplementedError(f"model {self.name!r} has no energy")

    def energy(self, state) -> float:
        """Total stored energy (J): ``sum_i W_i V_i``."""
        return float(np.dot(self.energy_density(state), self.system.volume))

    # ------------------------------------------------------------------ static solve hooks
    def particle_force(self, state) -> np.ndarray:
        """Internal force per particle F_int (N, 3) (N)."""
        f = self.force(state)
        if self.force_kind == "density":
            f *= self.system.volume[:, None]
        return f

    def residual(self, state) -> np.ndarray:
        """Internal force per particle, flattened (3N,): ``F_int`` (see module docstring)."""
        return self.particle_force(state).ravel()

    def tangent(self, state):
        """Stiffness ``K = -dF_int/dy`` as scipy.sparse (3N, 3N). Default: central finite
        differences on the family's sparsity pattern (slow; for tests and small bodies)."""
        return numerical_tangent(self, state)

    # ------------------------------------------------------------------ stability
    def stiffness_bound(self) -> np.ndarray | None:
        """Gershgorin bound per particle (N,) on the row sums of |d(force)/dy| at the
        reference state, in the units of ``force_kind`` per metre (N/m^4 for densities,
        N/m per particle). The engine's stable step is ``2 sqrt(rho_i / sum R_i)``
        (densities) or ``2 sqrt(m_i / sum R_i)``; None if the model gives no bound."""
        return None

    def stable_dt(self) -> float | None:
        """Stable time step estimate of this model alone for velocity Verlet (None if
        unknown): ``min_i 2 sqrt(rho_i / R_i)`` from :meth:`stiffness_bound`."""
        r = self.stiffness_bound()
        if r is None or self.system is None:
            return None
        inertia = self.system.density if self.force_kind == "density" else self.system.mass
        with np.errstate(divide="ignore"):
            dt = 2.0 * np.sqrt(inertia / r)
        return float(np.min(dt))

    def describe(self) -> dict:
        """Parameters for result files (JSON-serialisable)."""
        return {"model": self.name}

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in self.describe().items() if k != "model")
        return f"{type(self).__name__}({params})"


def numerical_tangent(model: Model, state, eps: float | None = None):
    """Central-difference stiffness ``K = -dF_int/dy`` (scipy.sparse.csr_matrix (3N, 3N)).

    Perturbs one coordinate at a time (6N force evaluations); for tests and small systems.
    """
    import scipy.sparse as sp

    y0 = state.y.copy()
    n = y0.shape[0]
    h = eps if eps is not None else 1e-6 * (model.system.spacing if model.system else 1.0)
    rows, cols, vals = [], [], []
    try:
        for a in range(n):
            for c in range(3):
                state.y[a, c] = y0[a, c] + h
                fp = model.particle_force(state)
                state.y[a, c] = y0[a, c] - h
                fm = model.particle_force(state)
                state.y[a, c] = y0[a, c]
                col = -(fp - fm).ravel() / (2 * h)
                nz = np.flatnonzero(col)
                rows.append(nz)
                cols.append(np.full(nz.size, 3 * a + c))
                vals.append(col[nz])
    finally:
        state.y[...] = y0
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(3 * n, 3 * n))
