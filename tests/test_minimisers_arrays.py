"""The array-level minimisers of :mod:`upscale.engine.minimisers` against closed forms."""
from __future__ import annotations

import numpy as np
import pytest

from upscale.engine.array_minimisers import (ArrayMinimum, bfgs, first_lower, lbfgs_b,
                                             quick_min_blocks, restarted, zero_cell_force)


def rosenbrock(x):
    a, b = x[:-1], x[1:]
    e = float(np.sum(100.0 * (b - a * a) ** 2 + (1 - a) ** 2))
    g = np.zeros_like(x)
    g[:-1] += -400.0 * a * (b - a * a) - 2.0 * (1 - a)
    g[1:] += 200.0 * (b - a * a)
    return e, g


def test_lbfgs_b_reaches_rosenbrock_minimum():
    r = lbfgs_b(rosenbrock, np.full(6, -1.2), gtol=1e-10, max_iter=2000, memory=10)
    assert isinstance(r, ArrayMinimum) and r.converged
    assert np.allclose(r.x, 1.0, atol=1e-6)


def test_lbfgs_b_active_bound_is_the_constrained_minimum():
    # min (x - 2)^2 + (y + 1)^2 on x <= 1, y >= 0: (1, 0) with both bounds active
    def f(x):
        return float((x[0] - 2) ** 2 + (x[1] + 1) ** 2), np.array([2 * (x[0] - 2), 2 * (x[1] + 1)])

    r = lbfgs_b(f, np.array([0.0, 0.5]), [-np.inf, 0.0], [1.0, np.inf], gtol=1e-12, max_iter=100)
    assert np.allclose(r.x, [1.0, 0.0], atol=1e-12)
    assert r.energy == pytest.approx(2.0, abs=1e-12)


def test_lbfgs_b_gives_points_off_the_domain_an_infinite_energy():
    # E = x^4 - x with nan where x > 1 (the minimum 0.63 lies inside): the line search steps
    # past x = 1, gets an infinite energy and backs off; the result is a finite point of the
    # domain with its own energy (scipy may stop there before gtol: callers check the gradient)
    calls = []

    def f(x):
        calls.append(float(x[0]))
        if x[0] > 1.0:
            return float("nan"), np.array([float("nan")])
        return float(x[0] ** 4 - x[0]), np.array([4 * x[0] ** 3 - 1])

    r = lbfgs_b(f, np.array([-3.0]), gtol=1e-9, max_iter=100, memory=3)
    assert any(c > 1.0 for c in calls)
    assert np.isfinite(r.energy) and r.x[0] <= 1.0
    assert r.energy == pytest.approx(r.x[0] ** 4 - r.x[0], abs=1e-14)


def test_bad_bounds_are_one_line_errors():
    with pytest.raises(ValueError, match="lower bound"):
        lbfgs_b(rosenbrock, np.zeros(2), [1.0, 0.0], [0.0, 1.0], gtol=1e-6, max_iter=10)
    with pytest.raises(ValueError, match="dt="):
        quick_min_blocks(lambda x: x, [np.zeros(2)], [np.ones(2)], dt=0.0, steps=10,
                         max_step=0.1, ftol=1e-6)


def test_bfgs_quadratic():
    A = np.array([[3.0, 1.0], [1.0, 2.0]])
    b = np.array([1.0, -1.0])
    r = bfgs(lambda x: (0.5 * x @ A @ x - b @ x, A @ x - b), np.zeros(2), gtol=1e-12, max_iter=100)
    assert np.allclose(r.x, np.linalg.solve(A, b), atol=1e-10)


def test_quick_min_blocks_relaxes_two_blocks_and_keeps_the_bound():
    # E = 1/2 k |x - a|^2 + 1/2 k2 |d - c|^2 with d clipped to [-0.3, 0.3]: x -> a, d -> 0.3
    a = np.array([[0.5, -0.2, 0.1]])
    c = np.array([[0.8, 0.1, -0.1]])

    def forces(x):
        return [-(x[0] - a), -2.0 * (x[1] - c)]

    r = quick_min_blocks(forces, [np.zeros((1, 3)), np.zeros((1, 3))],
                         [np.ones((1, 1)), np.ones((1, 1))], dt=0.1, steps=20000,
                         max_step=0.05, ftol=1e-9, bounds=[None, 0.3])
    assert np.allclose(r.x[0], a, atol=1e-7)
    assert r.x[1][0, 0] == pytest.approx(0.3, abs=1e-12)  # held at its bound
    assert np.allclose(r.x[1][0, 1:], c[0, 1:], atol=1e-7)
    assert not r.converged  # the bound leaves a force: |F| does not reach ftol


def test_zero_cell_force_secant_on_a_quadratic():
    # E(L) = 1/2 k (L - 7.3)^2: exact after the first secant step
    out, L, n = zero_cell_force(lambda L: (L, 4.0 * (L - 7.3)), 7.0, tol=1e-10)
    assert L == pytest.approx(7.3, abs=1e-10) and out == L and n <= 4


def test_restarted_and_first_lower():
    res, n = restarted(10, lambda r: r - 3 if r > 2 else None, done=lambda r: r < 0,
                       max_restarts=50)
    assert (res, n) == (1, 3)  # 10 -> 7 -> 4 -> 1, then no restart
    res, n = restarted(10, lambda r: r - 3, done=lambda r: r < 0, max_restarts=2)
    assert (res, n) == (4, 2)
    assert first_lower([3, 1, 0], lambda s: s * 2, lambda r: r, 2.5) == 2
    assert first_lower([3, 4], lambda s: s * 2, lambda r: r, 2.5) is None
    assert first_lower([3, 4], lambda s: s * 2, lambda r: r, 2.5, accept_any=True) == 6
