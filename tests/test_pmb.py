"""Bond-based PMB: forces are the energy gradient, calibration against linear elasticity,
failure in LAMMPS's order, and the small LAMMPS peri/pmb comparison."""
import numpy as np
import pytest

from upscale.engine import State, build_family, cubic_lattice, square_lattice
from upscale.models import create, get
from upscale.models.bond_based import PMB, pmb_critical_stretch, pmb_micromodulus


@pytest.mark.parametrize("dim", [2, 3])
def test_force_is_minus_energy_gradient(dim, check_force_is_minus_energy_gradient):
    check_force_is_minus_energy_gradient(PMB(E=70e9), dim, seed=0)


def test_rigid_motion_costs_nothing():
    sysm = cubic_lattice(5, 5, 5, 1e-3)
    fam = build_family(sysm, 3.015e-3)
    m = PMB(E=70e9)
    m.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    c, s = np.cos(0.3), np.sin(0.3)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    st.y[...] = sysm.x0 * 1.001
    f_ref, e_ref = np.abs(m.force(st)).max(), m.energy(st)  # a 1e-3 stretch, for scale
    st.y[...] = sysm.x0 @ R.T + [1.0, 2.0, 3.0]
    assert np.abs(m.force(st)).max() < 1e-8 * f_ref  # round-off of |y| ~ 1 m against 1 mm bonds
    assert m.energy(st) < 1e-14 * e_ref


def test_micromodulus_classical_values():
    E, d, t = 1.0, 1.0, 1.0
    assert pmb_micromodulus(E, None, d, 3) == pytest.approx(12 * E / (np.pi * d ** 4))
    assert pmb_micromodulus(E, None, d, 2, thickness=t) == pytest.approx(9 * E / (np.pi * t * d ** 3))
    assert pmb_micromodulus(E, None, d, 2, thickness=t, plane="strain") == pytest.approx(
        48 * E / (5 * np.pi * t * d ** 3))
    # Silling & Askari 2005: s0 = sqrt(5 Gc / (9 K delta)), K = E/(3(1-2nu)) with nu = 1/4
    K = E / (3 * (1 - 0.5))
    c = pmb_micromodulus(E, None, d, 3)
    assert pmb_critical_stretch(2.0, c, d, 3) == pytest.approx(np.sqrt(5 * 2.0 / (9 * K * d)))
    # Ha & Bobaru 2010, plane stress: s0 = sqrt(4 pi Gc / (9 E delta))
    c2 = pmb_micromodulus(E, None, d, 2, thickness=t)
    assert pmb_critical_stretch(2.0, c2, d, 2, thickness=t) == pytest.approx(np.sqrt(4 * np.pi * 2.0 / (9 * E * d)))


def test_bond_breaks_after_its_force_counts():
    """LAMMPS order: the failing bond still contributes its force in that evaluation."""
    from upscale.engine import ParticleSystem

    sysm = ParticleSystem([[0, 0, 0], [1.0, 0, 0]], 1.0, 1.0, spacing=1.0)
    fam = build_family(sysm, 1.5)
    m = PMB(c=1.0, s0=0.1)
    m.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    st.y[1, 0] = 1.2  # s = 0.2 > s0
    out = np.zeros((2, 3))
    broken = m.step_force(st, out)
    assert broken == 2 and not st.intact.any()
    assert out[0, 0] == pytest.approx(0.2 * 1.0)  # c s V_j beta, towards particle 1
    out[:] = 0
    m.step_force(st, out)
    assert np.all(out == 0)


def test_no_failure_criterion_means_no_bond_checks():
    m = PMB(E=1e9)
    assert not m.needs.failure
    assert PMB(E=1e9, s0=0.01).needs.failure and PMB(E=1e9, Gc=10.0).needs.failure
    assert get("pmb") is PMB and isinstance(create("pmb", E=1.0), PMB)


def test_surface_correction_restores_edge_energy():
    sysm = square_lattice(15, 15, 1e-3)
    fam = build_family(sysm, 3.015e-3)
    st = State.reference(sysm.x0, fam.nb)
    st.y[...] = sysm.x0 * 1.001
    W = {}
    for sc in (False, True):
        m = PMB(E=70e9, surface_correction=sc)
        m.prepare(sysm, fam)
        W[sc] = m.energy_density(st)
    corner = 0
    centre = int(np.argmin(np.linalg.norm(sysm.x0 - sysm.x0.mean(axis=0), axis=1)))
    assert W[False][corner] < 0.6 * W[False][centre]
    assert W[True][corner] == pytest.approx(W[True][centre], rel=0.25)


@pytest.mark.lammps
def test_pmb_matches_lammps_small(check_matches_lammps_small):
    check_matches_lammps_small("pmb")


def test_one_dimensional_bar():
    """1D: c = 2E/(A delta^2); the lattice calibration makes W = E s^2 / 2 exact in the bulk,
    and a bar stretched then released keeps its momentum zero."""
    from upscale.engine import line_lattice

    sysm = line_lattice(41, 1e-3, area=2e-6)
    fam = build_family(sysm, 3.015e-3)
    m = PMB(E=70e9, calibration="lattice")
    m.prepare(sysm, fam)
    st = State.reference(sysm.x0, fam.nb)
    st.y[...] = sysm.x0 * 1.001
    assert m.energy_density(st)[20] == pytest.approx(0.5 * 70e9 * 1e-6, rel=1e-10)
    F = m.particle_force(st)
    assert abs(F.sum()) < 1e-9 * np.abs(F).max() and np.all(F[:, 1:] == 0)
