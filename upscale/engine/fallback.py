"""L-BFGS-B with damped dynamics where it stalls: the LAMMPS runner's minimisation.

A Tersoff potential with a step cut-off (f_C = 1 below R + D, 0 beyond) has an energy that
jumps when a bond crosses the cut-off, by the bond's own (negative) energy. A bond pulled
to the cut-off by the load therefore sits at a kink of the energy: no equilibrium exists
there (the force jumps), and an energy-decreasing minimiser (CG, L-BFGS-B) stops at the
kink with the bond held, a residual force left and the tube stronger than it is. Damped
dynamics follows the forces, not the energy: the bond is carried across the cut-off, as
in dynamics, and the structure relaxes beyond it. LAMMPS's runner therefore minimises as

    CG (ftol_cg); while fmax > accept: quickmin (<= steps, dt, dmax, ftol_qm) then CG,
    at most ``cycles`` times,

and :class:`LBFGSDamped` does the same on the engine with L-BFGS-B (:class:`LBFGS`) and
:class:`QuickMin`: the velocity projected on the force, zeroed when it points uphill
(LAMMPS ``min_style quickmin``). The damped style matters: FIRE, whose mixing keeps a
velocity component off the force and whose step grows tenfold, is left oscillating about
such a kink on the defective tubes where QuickMin crosses it.
"""
from __future__ import annotations

import time

from upscale.engine.minimisers import LBFGS, MinimiseResult, QuickMin

__all__ = ["LBFGSDamped"]


class LBFGSDamped:
    """L-BFGS-B, then (QuickMin, L-BFGS-B) while the largest force exceeds ``accept``, at
    most ``cycles`` times (module docstring).

    Parameters
    ----------
    ftol : float
        L-BFGS-B's force tolerance (force units of the scene).
    accept : float
        largest force left that ends the minimisation as converged (LAMMPS runner: 1e-4
        eV/Å).
    cycles : int
        damped-dynamics cycles at most.
    dt : float
        QuickMin's step (time units of the scene: 1 fs in LAMMPS's runner).
    max_step : float
        QuickMin's largest displacement per iteration (LAMMPS ``dmax``, 0.02 Å).
    damped_steps : int
        QuickMin's iterations per cycle (5,000).
    damped_ftol : float
        QuickMin's own force tolerance (1e-3), after which L-BFGS-B takes over again.
    max_iter, memory, maxls, energy_rtol
        L-BFGS-B's (:class:`LBFGS`).
    """

    name = "lbfgs+quickmin"

    def __init__(self, ftol: float = 1e-6, *, accept: float = 1e-4, cycles: int = 3,
                 dt: float, max_step: float = 0.02, damped_steps: int = 5_000,
                 damped_ftol: float = 1e-3, max_iter: int = 20_000, memory: int = 30,
                 maxls: int = 40, energy_rtol: float = 0.0):
        if not accept >= ftol > 0:
            raise ValueError(f"accept={accept!r}, ftol={ftol!r}; valid: accept >= ftol > 0")
        if int(cycles) < 0:
            raise ValueError(f"cycles={cycles!r}; valid: an integer >= 0")
        self.lbfgs = LBFGS(ftol=ftol, max_iter=max_iter, memory=memory, maxls=maxls,
                           energy_rtol=energy_rtol)
        self.damped = QuickMin(ftol=damped_ftol, max_iter=damped_steps, dt=dt,
                               max_step=max_step)
        self.accept, self.cycles = float(accept), int(cycles)
        self.runs = 0  # minimisations run (L-BFGS-B and QuickMin), over every call

    def minimise(self, sim, *, raise_on_fail: bool = False) -> MinimiseResult:
        """Relax ``sim.state`` (mutated); ``converged`` when the largest force left is at
        most ``accept``. ``raise_on_fail`` is accepted for the minimisers' signature and
        ignored: a kink left after every cycle is reported, not raised."""
        t0 = time.perf_counter()
        its = nf = 0
        r = None
        for cycle in range(self.cycles + 1):
            if cycle:
                d = self.damped.minimise(sim, raise_on_fail=False)
                its, nf, self.runs = its + d.iterations, nf + d.n_force, self.runs + 1
            r = self.lbfgs.minimise(sim, raise_on_fail=False)
            its, nf, self.runs = its + r.iterations, nf + r.n_force, self.runs + 1
            if r.converged or r.fmax <= self.accept:
                break
        ok = r.converged or r.fmax <= self.accept
        return MinimiseResult(self.name, ok, its, r.fmax, r.energy, nf,
                              time.perf_counter() - t0, r.message)
