"""The uniform lattice of the coarse tube (the ghost-force twin's state) found to round-off:
:func:`upscale.engine.array_minimisers.newton` against BFGS, which stops short of gtol."""
import numpy as np
import pytest

from upscale.engine.array_minimisers import bfgs, newton
from upscale.models.dcbr_defect import DCBRDefectTube


@pytest.fixture(scope="module")
def tube():
    return DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)


def _grad(tube, lt, lz, sh, free_lz):
    g = tube.lattice.energy(np.array([lt, 0.0, lz, *sh]), tube.p)[1]
    return np.r_[g[0], g[2], g[3:]] if free_lz else np.r_[g[0], g[3:]]


@pytest.mark.parametrize("lam_z", [None, 1.0, 1.05, 1.12])
def test_uniform_lattice_gradient_at_round_off(tube, lam_z):
    lt, lz, sh = tube.uniform_lattice(lam_z)
    assert np.abs(_grad(tube, lt, lz, sh, lam_z is None)).max() < 1e-12
    if lam_z is not None:
        assert lz == lam_z


def test_newton_beats_bfgs_and_reports_failure(tube):
    """On the stretched lattice BFGS ends above gtol ("precision loss"); Newton reaches it in
    a few iterations. A function without a minimum ends unsuccessful."""
    lat, p = tube.lattice, tube.p

    def fun(v):
        e, g = lat.energy(np.array([v[0], 0.0, 1.05, v[1], v[2], v[3]]), p)
        return e, np.array([g[0], g[3], g[4], g[5]])
    x0 = np.array([1.0, 0, 0, 0])
    rn, rb = newton(fun, x0, gtol=1e-12), bfgs(fun, x0, gtol=1e-12, max_iter=500)
    assert rn.converged and rn.iterations <= 8
    assert np.abs(fun(rn.x)[1]).max() <= 1e-12 < np.abs(fun(rb.x)[1]).max()
    assert np.abs(rn.x - rb.x).max() < 1e-8  # the same minimum
    r = newton(lambda v: (-float(v @ v), -2.0 * v), np.array([0.3, -0.2]), gtol=1e-12)
    assert not r.converged and "positive definite" in r.message
