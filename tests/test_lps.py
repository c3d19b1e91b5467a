"""State-based LPS: forces are the energy gradient, exact dilatation, elasticity (energy,
Poisson contraction of a bar) and the small LAMMPS peri/lps comparison."""
import numpy as np
import pytest

from upscale.engine import State, build_family, cubic_lattice
from upscale.models.state_based import LPS


@pytest.mark.parametrize("dim,plane", [(3, "stress"), (2, "stress"), (2, "strain")])
def test_force_is_minus_energy_gradient(dim, plane, check_force_is_minus_energy_gradient):
    check_force_is_minus_energy_gradient(LPS(E=70e9, nu=0.3), dim, plane, seed=3)


def test_dilatation_is_exact_for_isotropic_stretch_everywhere():
    """m_i from each particle's own family: theta = 3 s even at corners (small strain)."""
    sysm = cubic_lattice(6, 6, 6, 1e-3)
    fam = build_family(sysm, 3.015e-3)
    m = LPS(E=70e9, nu=0.3)
    m.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    st.y[...] = sysm.x0 * (1 + 1e-6)
    np.testing.assert_allclose(m.dilatation(st), 3e-6, rtol=1e-6)


def test_lammps_moduli_round_trip():
    m = LPS(E=70e9, nu=0.3)
    m2 = LPS(K=m.K, G=m.G)
    assert m2.E == pytest.approx(70e9) and m2.nu == pytest.approx(0.3)
    with pytest.raises(ValueError, match="Poisson ratio"):
        LPS(E=1.0, nu=0.5)


@pytest.mark.lammps
def test_lps_matches_lammps_small(check_matches_lammps_small):
    check_matches_lammps_small("lps")


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
