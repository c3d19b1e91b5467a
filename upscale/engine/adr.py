"""Adaptive dynamic relaxation with its per-step vector work in numba kernels.

The algorithm is exactly :class:`upscale.engine.integrators.AdaptiveDynamicRelaxation`
(Kilic & Madenci 2010: fictitious density ``Lambda_i = dt^2 R_i / 4`` from the models'
Gershgorin bounds, damping ``c = 2 sqrt(u.K1 u / u.u)`` from the local diagonal stiffness
``K1 = -(F - F_prev) / (Lambda dt v)``, capped at ``1.9/dt``); here the damping sums, the
velocity update and the position update run as two fused passes over flat arrays instead of
some twenty NumPy array operations per step, which dominate the step of a bond-based model.

Units: as the simulation's (forces N per particle, positions m).
"""
from __future__ import annotations

import numba as nb
import numpy as np

from upscale.engine.integrators import AdaptiveDynamicRelaxation

__all__ = ["FusedAdaptiveDynamicRelaxation"]


@nb.njit(cache=True)
def _damping_sums(F_nc, Fprev_nc, v_nc, lam_n, free_nc, y_nc, x0_nc, R_nc, dt):
    """(u.K1 u, u.u, |F_free|^2, |reactions|^2) of one step; K1 as in the module docstring
    (zero on prescribed dofs), u.u over all dofs, as the engine's ADR."""
    num = 0.0
    den = 0.0
    f2 = 0.0
    r2 = 0.0
    n = F_nc.shape[0]
    for i in range(n):
        for c in range(3):
            r = R_nc[i, c]
            r2 += r * r
            u = y_nc[i, c] - x0_nc[i, c]
            den += u * u                  # over every dof, prescribed ones included
            if not free_nc[i, c]:
                continue
            f = F_nc[i, c]
            f2 += f * f
            v = v_nc[i, c]
            if v != 0.0:
                num += u * u * (-(f - Fprev_nc[i, c]) / (lam_n[i] * dt * v))
    return num, den, f2, r2


@nb.njit(cache=True)
def _update(F_nc, Fprev_nc, v_nc, lam_n, free_nc, y_nc, cdt, dt, drift):
    """Mutates v (velocity update), F_prev (= F on free dofs) and, if ``drift``, y (by
    dt v)."""
    n = F_nc.shape[0]
    a = (2.0 - cdt) / (2.0 + cdt)
    b = 2.0 * dt / (2.0 + cdt)
    for i in range(n):
        il = 1.0 / lam_n[i]
        for c in range(3):
            if free_nc[i, c]:
                f = F_nc[i, c]
                v = a * v_nc[i, c] + b * f * il
                v_nc[i, c] = v
                Fprev_nc[i, c] = f
                if drift:
                    y_nc[i, c] += dt * v
            else:
                Fprev_nc[i, c] = 0.0


class FusedAdaptiveDynamicRelaxation(AdaptiveDynamicRelaxation):
    """:class:`~upscale.engine.integrators.AdaptiveDynamicRelaxation` with fused kernels
    (same parameters, same iterates up to round-off;
    ``sim.relax(FusedAdaptiveDynamicRelaxation())``).

    Runs on several MPI ranks (the ADR of ``sim.relax()`` there): the damping sums and
    norms are sums over each rank's owned particles added over the ranks, so the iterates
    equal the serial ones up to the order of those sums (round-off)."""

    name = "adr-fused"

    def run(self, sim, progress: bool = False) -> dict:
        """Relax ``sim``; the result also gives the CPU time of the set-up (stiffness
        bounds, fictitious masses), ``setup_cpu_s``, apart from the iterations'."""
        import time

        c0 = time.process_time()
        st = sim.state
        R = np.zeros(sim.system.n)
        for m in sim.models:
            r = m.stiffness_bound()
            if r is None:
                raise ValueError(f"model {m.name!r} gives no stiffness bound; ADR needs one")
            R += r * (sim.system.volume if m.force_kind == "density" else 1.0)
        dt = self.dt
        lam = 0.25 * dt * dt * R
        lam = np.ascontiguousarray(np.where(lam > 0, lam, 1.0))
        free = np.ascontiguousarray(~sim.constrained)
        sim.apply_displacement(st.t, None)
        sim.update_forces()
        F = sim.F
        v = np.where(free, 0.5 * dt * F / lam[:, None], 0.0)
        Fprev = np.where(free, F, 0.0)
        st.y += dt * v
        part = getattr(sim, "part", None)  # several MPI ranks: sums over the owned rows
        own = None if part is None else np.flatnonzero(part.owned)
        fext = float(np.linalg.norm(sim.F_ext)) if part is None else \
            float(np.sqrt(part.sum(float(np.sum(sim.F_ext[own] ** 2)))))
        setup = time.process_time() - c0
        res = np.inf
        it = 0
        for it in range(1, self.max_steps + 1):
            sim.apply_displacement(st.t, None)
            sim.update_forces()
            if part is None:
                num, den, f2, r2 = _damping_sums(sim.F, Fprev, v, lam, free, st.y, st.x0,
                                                 sim.reactions, dt)
            else:  # the owned rows' sums, added over the ranks (rank order)
                num, den, f2, r2 = part.sum(np.array(_damping_sums(
                    sim.F[own], Fprev[own], v[own], lam[own], free[own], st.y[own],
                    st.x0[own], sim.reactions[own], dt)))
            c = 2.0 * np.sqrt(num / den) if den > 0 and num > 0 else 0.0
            c = min(c, 1.9 / dt)
            scale = max(np.sqrt(r2), fext, 1e-300)
            res = float(np.sqrt(f2)) / scale
            if res < self.tol:
                # converged on this configuration: do not drift further
                break
            _update(sim.F, Fprev, v, lam, free, st.y, c * dt, dt, it < self.max_steps)
        st.v[...] = 0.0
        return {"iterations": it, "residual": res, "converged": bool(res < self.tol),
                "setup_cpu_s": setup}
