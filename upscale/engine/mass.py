"""Non-diagonal (consistent) mass for one translation component, and velocity Verlet with it.

The engine's particles carry a lumped mass ``m_i``. Some models add kinetic energy that
couples neighbouring particles, e.g. the rotary inertia of an Euler-Bernoulli beam whose
section rotation is the slope ``w'`` (Rayleigh beam), ``T_rot = (1/2) int rho I (w_t')^2 dx``,
which on the chain is ``(1/2) sum_edges rho I (v_b - v_a)^2 / xi_ab``. The equation of
motion of that component c is then

    M a = F,     M = diag(m) + B,

``M`` (N x N, kg) sparse symmetric positive definite, ``B`` the model's coupling.
:class:`ConsistentMass` holds ``M`` and factorises it once (sparse LU of the free block:
prescribed and tied degrees of freedom keep zero acceleration, their rows and columns are
removed); :class:`MassMatrixVerlet` is velocity Verlet with ``a_c = M^-1 F_c`` for that
component and the lumped mass for the others. Since ``M >= diag(m)`` (B positive
semi-definite), ``lambda_max(M^-1 K) <= lambda_max(diag(m)^-1 K)``: the engine's lumped
stable-step estimate stays a valid (conservative) bound.

:func:`mass_symbol` is the plane-wave symbol ``M(k) = sum_n M_cn exp(i k (x_n - x_c))``
at a particle c far from the boundary: with the dynamical matrix ``D(k)`` of
:mod:`upscale.engine.dispersion` the branch is ``omega^2 = D(k) / M(k)``.
"""
from __future__ import annotations

import numpy as np

from upscale.engine.integrators import VelocityVerlet

__all__ = ["ConsistentMass", "MassMatrixVerlet", "mass_symbol", "edge_coupling"]


def edge_coupling(x, pairs, coef):
    """``B = sum_e coef_e (e_a - e_b)(e_a - e_b)^T`` (N x N, CSR) over the edges ``pairs``
    (E, 2) with ``coef`` (E,) >= 0 (kg): the mass of ``(1/2) sum_e coef_e (v_a - v_b)^2``."""
    import scipy.sparse as sp

    n = x.shape[0]
    a, b = np.asarray(pairs).T
    c = np.asarray(coef, float)
    if np.any(c < 0):
        raise ValueError("edge mass coefficients must be >= 0 (a positive semi-definite coupling)")
    rows = np.concatenate([a, b, a, b])
    cols = np.concatenate([a, b, b, a])
    vals = np.concatenate([c, c, -c, -c])
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))


class ConsistentMass:
    """Mass matrix ``M = diag(lumped) + coupling`` of translation component ``component``.

    Parameters
    ----------
    coupling : (N, N) sparse, symmetric positive semi-definite (kg)
        Added to the system's lumped masses.
    component : int
        Translation component (0, 1, 2) it applies to.
    """

    def __init__(self, coupling, component: int = 2):
        import scipy.sparse as sp

        if component not in (0, 1, 2):
            raise ValueError(f"mass component must be 0, 1 or 2, got {component!r}")
        B = sp.csr_matrix(coupling)
        if B.shape[0] != B.shape[1]:
            raise ValueError(f"mass coupling must be square, got shape {B.shape}")
        asym = abs(B - B.T).max() if B.nnz else 0.0
        if asym > 1e-12 * (abs(B).max() if B.nnz else 1.0):
            raise ValueError(f"mass coupling is not symmetric (max |B - B^T| = {asym:.3g})")
        self.B = B
        self.component = int(component)
        self._lu = None
        self._free = None

    def matrix(self, system):
        """The full ``M`` (N x N, CSR, kg)."""
        import scipy.sparse as sp

        if self.B.shape[0] != system.n:
            raise ValueError(f"mass coupling is {self.B.shape[0]} x {self.B.shape[0]}, the body "
                             f"has {system.n} particles")
        return (sp.diags(system.mass) + self.B).tocsr()

    def factorise(self, system, free) -> None:
        """Sparse LU of the free block ``M[free][:, free]`` (once)."""
        from scipy.sparse.linalg import splu

        self._free = np.flatnonzero(free)
        M = self.matrix(system)
        self._lu = splu(M[self._free][:, self._free].tocsc())

    def accel(self, F_c) -> np.ndarray:
        """``a = M^-1 F`` on the free degrees of freedom, zero on the others."""
        a = np.zeros_like(F_c)
        a[self._free] = self._lu.solve(np.ascontiguousarray(F_c[self._free]))
        return a

    def kinetic_energy(self, system, v_c) -> float:
        """``v.M v / 2`` (J) of the component's velocities (the lumped part included)."""
        return 0.5 * float(v_c @ (self.matrix(system) @ v_c))


class MassMatrixVerlet(VelocityVerlet):
    """Velocity Verlet with a consistent mass for one translation component.

    Same order as :class:`~upscale.engine.integrators.VelocityVerlet` (kick-drift-kick);
    the kicks of ``mass.component`` use ``M^-1 F`` (:class:`ConsistentMass`, factorised
    in :meth:`prepare` on the dofs that are not prescribed), the other components and the
    fields their diagonal inertia. ``extra_kinetic_energy(sim)`` is the coupling's part
    of the kinetic energy (``Simulation.kinetic_energy`` adds it).
    """

    name = "velocity-verlet-mass-matrix"

    def __init__(self, mass: ConsistentMass, dt: float | None = None, **kw):
        if kw.get("thermostat") is not None:
            raise ValueError("a thermostat with a mass matrix is not supported; valid: NVE")
        super().__init__(dt, **kw)
        self.mass = mass

    def prepare(self, sim) -> None:
        super().prepare(sim)
        self.mass.factorise(sim.system, ~sim.constrained[:, self.mass.component])

    def extra_kinetic_energy(self, sim) -> float:
        v = sim.state.v[:, self.mass.component]
        return 0.5 * float(v @ (self.mass.B @ v))

    def _kick(self, sim, h):
        from upscale.engine.kernels import kick

        st = sim.state
        c = self.mass.component
        vc = st.v[:, c].copy()
        kick(st.v, sim.F, sim.inv_mass_n, h)
        st.v[:, c] = vc + h * self.mass.accel(sim.F[:, c])
        if getattr(sim, "field_specs", None):
            for k, inv in sim.field_inv_inertia.items():
                st.field_v[k] += h * sim.G[k] * inv[:, None]

    def step(self, sim) -> int:
        from upscale.engine.kernels import drift

        st, dt = sim.state, self.dt
        self._kick(sim, 0.5 * dt)
        sim.apply_velocity(st.t + 0.5 * dt)
        drift(st.y, st.v, dt)
        for k in getattr(sim, "field_specs", {}) or {}:
            st.fields[k] += dt * st.field_v[k]
        st.t += dt
        st.step += 1
        sim.apply_displacement(st.t, dt)
        broken = sim.update_forces()
        self._kick(sim, 0.5 * dt)
        sim.apply_velocity(st.t)
        return broken


def mass_symbol(M, x, c: int, k) -> np.ndarray:
    """``M(k) = sum_n M[c, n] exp(i k.(x_n - x_c))`` (kg) for wave vectors ``k`` (K, d) or a
    scalar wavenumber (1D), from row c of the sparse mass matrix ``M``."""
    row = M.getrow(c)
    cols, vals = row.indices, row.data
    x = np.asarray(x, float)
    x = x[:, None] if x.ndim == 1 else x
    k = np.atleast_1d(np.asarray(k, float))
    kk = k[:, None] if k.ndim == 1 else k
    dxn = x[cols] - x[c]
    ph = np.exp(1j * (kk[:, :dxn.shape[1]] @ dxn.T))
    return ph @ vals
