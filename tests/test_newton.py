"""Newton-Raphson: quadratic convergence, equilibrium, bad input, singular tangent."""
import numpy as np
import pytest

from upscale.engine import newton
from upscale.engine.families import build_family
from upscale.engine.state import State
from upscale.engine.system import square_lattice
from upscale.models.cpd import CPD


def _bar(nx=24, ny=6, nu=0.4):
    s = square_lattice(nx, ny, 1e-3, thickness=1e-3)
    m = CPD(horizon=2.01e-3, dim=2, E=1e9, nu=nu)
    fam = build_family(s, 2.01e-3)
    m.prepare(s, fam)
    return s, m, State.reference(s.x0, fam.nb)


def test_quadratic_convergence_and_equilibrium_large_stretch():
    s, m, st = _bar()
    x = s.x0
    left = x[:, 0] < 1.5e-3
    right = x[:, 0] > x[:, 0].max() - 1.5e-3
    fixed = np.zeros((s.n, 3), bool)
    fixed[left] = True
    fixed[right, 0] = True
    ub = np.zeros((s.n, 3))
    ub[right, 0] = 0.05 * x[:, 0].max()          # 5 % stretch: geometrically non-linear
    res = newton.solve(m, st, fixed=fixed, u_prescribed=ub, steps=2, tol=1e-11)
    assert res.converged
    for step in res.steps:
        r = step.residual_norms
        assert r[-1] <= 1e-11 * step.scale
        order = newton.convergence_order(r)
        assert order is not None and order > 1.6, r
    F = m.particle_force(st)
    assert np.abs(F[~fixed.any(axis=1), :2]).max() < 1e-9 * np.abs(F).max()
    # reactions balance: left and right resultants equal and opposite
    assert res.reaction[left, 0].sum() == pytest.approx(-res.reaction[right, 0].sum(), rel=1e-8)


def test_force_controlled_matches_residual_zero():
    s, m, st = _bar(12, 4)
    x = s.x0
    left = x[:, 0] < 1.5e-3
    right = x[:, 0] > x[:, 0].max() - 0.5e-3
    f = np.zeros((s.n, 3))
    f[right, 0] = 1.0
    res = newton.solve(m, st, fixed=left, f_ext=f)
    assert res.converged
    R = m.particle_force(st) + f
    assert np.abs(R[~left, :2]).max() < 1e-8


def test_bad_input_and_singular():
    s, m, st = _bar(8, 3)
    with pytest.raises(ValueError, match="steps must be >= 1"):
        newton.solve(m, st, steps=0)
    with pytest.raises(ValueError, match="u_prescribed must have shape"):
        newton.solve(m, st, fixed=np.ones(s.n, bool), u_prescribed=np.zeros((2, 3)))
    f = np.zeros((s.n, 3))
    f[0, 0] = 1.0
    with pytest.raises(newton.NewtonError, match="rigid-body|singular"):
        newton.solve(m, st, f_ext=f)                 # nothing fixed: singular tangent


def test_generic_model_with_numerical_tangent():
    """The solver only uses the Model hooks: B's PMB (finite-difference tangent) converges."""
    from upscale import models

    s = square_lattice(6, 3, 1e-3, thickness=1e-3)
    fam = build_family(s, 2.015e-3)
    m = models.create("pmb", E=1e9, nu=1 / 3)
    m.prepare(s, fam)
    st = State.reference(s.x0, fam.nb)
    left = s.x0[:, 0] < 0.5e-3
    f = np.zeros((s.n, 3))
    f[s.x0[:, 0] > s.x0[:, 0].max() - 0.5e-3, 0] = 1.0
    res = newton.solve(m, st, fixed=left, f_ext=f)
    assert res.converged
    assert np.abs((m.particle_force(st) + f)[~left, :2]).max() < 1e-8
