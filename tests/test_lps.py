"""State-based LPS: forces are the energy gradient, exact dilatation, elasticity (energy,
Poisson contraction of a bar) and the small LAMMPS peri/lps comparison."""
import numpy as np
import pytest

from upscale.engine import State, build_family, cubic_lattice, square_lattice
from upscale.models.state_based import LPS


@pytest.mark.parametrize("dim,plane", [(3, "stress"), (2, "stress"), (2, "strain")])
def test_force_is_minus_energy_gradient(dim, plane):
    sysm = cubic_lattice(5, 5, 5, 1e-3) if dim == 3 else square_lattice(9, 9, 1e-3, plane=plane)
    fam = build_family(sysm, 3.015e-3)
    m = LPS(E=70e9, nu=0.3)
    m.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    rng = np.random.default_rng(3)
    st.y += rng.normal(scale=1e-5, size=st.y.shape)
    if dim == 2:
        st.y[:, 2] = 0
    F = m.particle_force(st)
    assert np.abs(F.sum(axis=0)).max() < 1e-10 * np.abs(F).max()
    h = 1e-9
    for a, c in [(0, 0), (sysm.n // 2, 1), (sysm.n - 1, dim - 1)]:
        st.y[a, c] += h
        ep = m.energy(st)
        st.y[a, c] -= 2 * h
        em = m.energy(st)
        st.y[a, c] += h
        assert -(ep - em) / (2 * h) == pytest.approx(F[a, c], rel=1e-5, abs=1e-8 * np.abs(F).max())


def test_dilatation_is_exact_for_isotropic_stretch_everywhere():
    """m_i from each particle's own family: theta = 3 s even at corners (small strain)."""
    sysm = cubic_lattice(6, 6, 6, 1e-3)
    fam = build_family(sysm, 3.015e-3)
    m = LPS(E=70e9, nu=0.3)
    m.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    st.y[...] = sysm.x0 * (1 + 1e-6)
    np.testing.assert_allclose(m.dilatation(st), 3e-6, rtol=1e-6)


@pytest.mark.parametrize("dim,plane", [(3, "stress"), (2, "stress"), (2, "strain")])
def test_bulk_energy_of_stretch_matches_elasticity(dim, plane):
    from validation.cases.peridynamics import bulk_energy_error

    for d in ("isotropic stretch", "uniaxial stretch", "simple shear"):
        err = bulk_energy_error("lps", dim, m=4.015, partial_volume="linear", plane=plane, deformation=d)
        assert abs(err) < 0.01, (d, err)


def test_poisson_contraction_of_a_bar():
    from upscale.engine.kernels import set_threads
    from validation.cases.peridynamics import poisson_bar

    set_threads(1)
    r = poisson_bar(2, cells=(61, 21, 1))
    assert r["adr_converged"]
    assert abs(r["nu_rel_err"]) < 0.05, r


def test_lammps_moduli_round_trip():
    m = LPS(E=70e9, nu=0.3)
    m2 = LPS(K=m.K, G=m.G)
    assert m2.E == pytest.approx(70e9) and m2.nu == pytest.approx(0.3)
    with pytest.raises(ValueError, match="Poisson ratio"):
        LPS(E=1.0, nu=0.5)


@pytest.mark.lammps
def test_lps_matches_lammps_small():
    from upscale.engine.kernels import set_threads
    from upscale.engine.lammps_peri import compare

    set_threads(1)
    r = compare("lps", counts=(8, 8, 4), steps=200)
    assert r["force_rel_err"] < 1e-10
    assert r["disp_rel_err_200_steps"] < 1e-8
    assert r["broken_bonds_engine"] > 0 and r["broken_bonds_identical"]
    # well-posed: no bond came within 1000x the codes' stretch difference of s00, so
    # round-off cannot make the two break different bonds
    assert r["critical_stretch_margin_min"] > 1e3 * r["stretch_max_abs_diff_final"], r


@pytest.mark.lammps
@pytest.mark.parametrize("style", ["lps", "pmb"])
def test_lammps_bond_creation_leaves_defined_s0(style):
    """LAMMPS's bond-building run 0 leaves atom->s0 as uninitialised memory (the bonds do
    not exist yet in that force evaluation); create_bonds resets it to DBL_MAX, so the next
    evaluation at the reference state breaks nothing whatever the heap held."""
    from upscale.engine.lammps_peri import LAMMPS_EXAMPLE as p
    from upscale.engine.lammps_peri import LammpsPeri

    params = {"c": p["c"]} if style == "pmb" else {"K": p["K"], "G": p["G"]}
    lp = LammpsPeri(style, (6, 6, 3), p["lc"], p["horizon"], p["density"],
                    {**params, "s00": p["s00"]}, crack=(2.6 * p["lc"], 3.5 * p["lc"]))
    try:
        lp.create_bonds()
        assert np.all(lp.s0() == np.finfo(np.float64).max)
        assert lp.damage().max() == 0.0            # a run 0 at the reference: nothing breaks
        assert np.all(lp.s0() == p["s00"])         # and s0 = s00 - alpha * s with alpha = 0
    finally:
        lp.close()
