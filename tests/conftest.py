"""Checks shared by the peridynamic model tests (test_pmb.py, test_lps.py), as fixtures
that return the check function."""
import numpy as np
import pytest

from upscale.engine import State, build_family, cubic_lattice, square_lattice


def _force_is_minus_energy_gradient(model, dim, plane="stress", seed=0):
    """Prepare ``model`` on a small lattice (5^3 cubic or 9x9 square, spacing 1 mm,
    horizon 3.015 mm), perturb every particle by N(0, 10 um) (2D: z stays 0), and assert
    that the total force vanishes and that three force components equal minus the central
    difference (h = 1 nm) of the total energy."""
    sysm = cubic_lattice(5, 5, 5, 1e-3) if dim == 3 else square_lattice(9, 9, 1e-3, plane=plane)
    fam = build_family(sysm, 3.015e-3)
    model.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    rng = np.random.default_rng(seed)
    st.y += rng.normal(scale=1e-5, size=st.y.shape)
    if dim == 2:
        st.y[:, 2] = 0.0
    F = model.particle_force(st)
    assert np.abs(F.sum(axis=0)).max() < 1e-10 * np.abs(F).max()
    h = 1e-9
    for a, c in [(0, 0), (sysm.n // 2, 1), (sysm.n - 1, dim - 1)]:
        st.y[a, c] += h
        ep = model.energy(st)
        st.y[a, c] -= 2 * h
        em = model.energy(st)
        st.y[a, c] += h
        assert -(ep - em) / (2 * h) == pytest.approx(F[a, c], rel=1e-5, abs=1e-8 * np.abs(F).max())


def _matches_lammps_small(style):
    """Engine vs LAMMPS peri/<style> on an 8x8x4 pre-cracked block, 200 steps, one thread:
    forces and displacements to round-off, the same bonds broken, and no bond so close to
    its critical stretch that round-off could decide whether it breaks."""
    from upscale.engine.kernels import set_threads
    from upscale.experiments.scenes.peri_lammps import compare

    set_threads(1)
    r = compare(style, counts=(8, 8, 4), steps=200)
    assert r["force_rel_err"] < 1e-10
    assert r["disp_rel_err_200_steps"] < 1e-8
    assert r["broken_bonds_engine"] > 0 and r["broken_bonds_identical"]
    assert r["critical_stretch_margin_min"] > 1e3 * r["stretch_max_abs_diff_final"], r


@pytest.fixture
def check_force_is_minus_energy_gradient():
    """``check(model, dim, plane="stress", seed=0)``: see _force_is_minus_energy_gradient."""
    return _force_is_minus_energy_gradient


@pytest.fixture
def check_matches_lammps_small():
    """``check(style)`` with style "pmb" or "lps": see _matches_lammps_small."""
    return _matches_lammps_small


@pytest.fixture(scope="module")
def one_numba_thread():
    """Scene calls on one numba thread, as the command line's ``--threads 1`` (sums in the
    same order, figures equal to the last digit); the setting restored after the module."""
    from upscale.engine.kernels import set_threads

    before = set_threads(None)
    set_threads(1)
    yield
    set_threads(before)
