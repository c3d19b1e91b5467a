"""The ASE calculator of the coarse tube model: forces and axial force as the relaxed
energy's gradient (finite differences), the rows as Atoms, bad input."""
import numpy as np
import pytest

from upscale.build import swcnt, vacancy
from upscale.calculators import DCBRCalculator, dcbr_atoms
from upscale.models.dcbr.model import DCBRModel


def _atoms(model, seed=0):
    a = dcbr_atoms(model)
    a.calc = DCBRCalculator(model)
    a.positions += 0.02 * np.random.default_rng(seed).standard_normal(a.positions.shape)
    return a


def _fd_force(a, j, k, h=1e-5):
    p = a.get_positions()
    p[j, k] += h
    a.set_positions(p)
    ep = a.get_potential_energy()
    p[j, k] -= 2 * h
    a.set_positions(p)
    em = a.get_potential_energy()
    p[j, k] += h
    a.set_positions(p)
    return -(ep - em) / (2 * h)


def _fd_axial(a, h=1e-5):
    c = np.array(a.cell)
    e = []
    for s in (1.0, -1.0):
        c2 = c.copy()
        c2[2, 2] += s * h
        a.set_cell(c2, scale_atoms=False)
        e.append(a.get_potential_energy())
    a.set_cell(c, scale_atoms=False)
    return (e[0] - e[1]) / (2 * h)


def test_forces_of_a_tube_with_a_divacancy_are_the_relaxed_energy_gradient():
    """Rows of particles and of free atoms (the region around the divacancy), the shifts
    relaxed at every configuration, the ghost-force load on."""
    m = DCBRModel(vacancy(swcnt(6, 6, 40.0), n=2), 2.0, r_atomistic=4.0)
    a = _atoms(m)
    rows = a.info["rows"]
    assert rows["atoms"] > 0 and rows["particles"] + rows["atoms"] == len(a) == m.n
    np.testing.assert_allclose(a.get_masses()[rows["particles"]:], 12.011, rtol=1e-3)
    F = a.get_forces()
    assert np.abs(F).max() > 1.0  # (off equilibrium: the check is not trivial)
    nd = rows["particles"]
    for j in (0, nd // 2, nd, len(a) - 1):
        for k in range(3):
            assert abs(F[j, k] - _fd_force(a, j, k)) < 1e-6 * max(1.0, abs(F[j, k]))


def test_axial_force_is_the_energy_derivative_along_the_period():
    """dE*/dL at fixed rows, on a pristine tube and on a coupled one without the ghost-force
    load (with it, the load is prepared for each period and not differentiated)."""
    for atoms, kw in ((swcnt(6, 6, 40.0), {}),
                      (vacancy(swcnt(6, 6, 40.0), n=2), dict(r_atomistic=4.0, ghost=False))):
        a = _atoms(DCBRModel(atoms, 2.0, **kw))
        a.get_potential_energy()
        fL = a.calc.axial_force
        assert abs(fL) > 1.0
        assert abs(fL - _fd_axial(a)) < 1e-6 * abs(fL)


def test_bad_input():
    m = DCBRModel(swcnt(6, 6, 40.0), 2.0)
    a = dcbr_atoms(m)
    a.calc = DCBRCalculator(m)
    del a[0]
    with pytest.raises(ValueError, match=r"the Atoms have \d+ rows; valid: the model's \d+"):
        a.get_potential_energy()
    with pytest.raises(ValueError, match="shifts='inertial'; valid: a DCBRModel with shifts="):
        DCBRCalculator(DCBRModel(swcnt(6, 6, 40.0), 2.0, shifts="inertial"))
