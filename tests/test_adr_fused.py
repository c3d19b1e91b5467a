"""The fused ADR takes the same iterates as the engine's ADR."""
import numpy as np

from upscale.engine import Simulation, build_family, square_lattice
from upscale.engine.adr import FusedAdaptiveDynamicRelaxation
from upscale.engine.conditions import Displacement, Fixed, region
from upscale.engine.integrators import AdaptiveDynamicRelaxation
from upscale.models.tipd import TiPD


def _sim():
    s = square_lattice(16, 8, 1e-3)
    f = build_family(s, 3.015e-3)
    conds = [Fixed(region(s, "l", box=((None, None, None), (0.5e-3, None, None)))),
             Displacement(region(s, "r", box=((14.5e-3, None, None), (None, None, None))), [1e-6, 2e-7, 0])]
    return Simulation(s, f, [TiPD(E=70e9, nu=0.25, surface="none")], conditions=conds)


def test_fused_adr_matches_engine_adr():
    """Same iterates to round-off over 20 steps (later the damping's sums, added in another
    order, let round-off grow), and the same converged state after 300."""
    for steps, tol in ((20, 1e-12), (300, 1e-9)):
        a, b = _sim(), _sim()
        ra = a.relax(AdaptiveDynamicRelaxation(tol=0.0, max_steps=steps))
        rb = b.relax(FusedAdaptiveDynamicRelaxation(tol=0.0, max_steps=steps))
        assert ra["iterations"] == rb["iterations"] == steps
        ua, ub = a.state.y - a.system.x0, b.state.y - b.system.x0
        # floor: a few ulps of the positions (y ~ 1.5e-2 m) from which u is taken
        ulp = 8 * np.finfo(float).eps * np.abs(a.system.x0).max()
        assert np.abs(ua - ub).max() <= tol * np.abs(ua).max() + ulp


def test_fused_adr_converges():
    a = _sim()
    r = a.relax(FusedAdaptiveDynamicRelaxation(tol=1e-6, max_steps=20000))
    assert r["converged"]
