"""Ti-PD (seed 003): the induced tensor against the paper's (47), the lattice moment of the
discrete calibration, equivalence with PMB at D12 = D66, zero interior force for a linear
field, the assembled stiffness (symmetric, = -dF/du, = corrected Appendix A), energy,
critical stretches, the indefiniteness warning and bad input."""
import warnings

import numpy as np
import pytest

from upscale.engine import State, build_family, cubic_lattice, square_lattice
from upscale.models import create
from upscale.models.bond_based import PMB, pmb_critical_stretch, pmb_micromodulus
from upscale.models.tipd import (IndefiniteWarning, TiPD, appendix_a_stiffness, appendix_b_stiffness,
                                 induced_tensor,
                                 isotropic_voigt, orthotropic_voigt_2d, paper_induced_voigt_2d,
                                 tipd_critical_stretch, voigt_to_tensor)

D_ANISO = np.array([[5.0, 3.0, 0.7], [3.0, 5.0, -0.4], [0.7, -0.4, 6.0]]) * 1e9


def _body(dim, n=None):
    if dim == 2:
        s = square_lattice(n or 12, n or 12, 1e-3)
    else:
        s = cubic_lattice(n or 7, n or 7, n or 7, 1e-3)
    return s, build_family(s, 3.015e-3)


def _perturbed(s, f, scale=1e-6, seed=0):
    st = State.reference(s.x0, f.nb)
    st.y += np.random.default_rng(seed).normal(scale=scale, size=st.y.shape)
    if s.dim == 2:
        st.y[:, 2] = 0.0
    return st


def test_compact_induced_tensor_is_the_papers_47():
    Dh = induced_tensor(voigt_to_tensor(D_ANISO))
    V = np.array([[Dh[0, 0, 0, 0], Dh[0, 0, 1, 1], Dh[0, 0, 0, 1]],
                  [Dh[1, 1, 0, 0], Dh[1, 1, 1, 1], Dh[1, 1, 0, 1]],
                  [Dh[0, 1, 0, 0], Dh[0, 1, 1, 1], Dh[0, 1, 0, 1]]])
    # (47)'s last column multiplies 2 lambda_12, so it is the tensor's (a, b) = (0, 1) entry
    assert np.allclose(V, paper_induced_voigt_2d(D_ANISO), rtol=1e-14, atol=0)


@pytest.mark.parametrize("dim", [2, 3])
def test_discrete_calibration_lattice_moment_is_S(dim):
    s, f = _body(dim)
    C = D_ANISO if dim == 2 else isotropic_voigt(200e9, 0.3, 3)
    m = TiPD(C, calibration="discrete", angle=0.3, warn=False, surface="none")
    m.prepare(s, f)
    L = m.lattice_moment()
    assert np.abs(L - m.S).max() <= 1e-12 * np.abs(m.S).max()
    # the continuum calibration misses it by the lattice quadrature error (per cent)
    mc = TiPD(C, calibration="continuum", angle=0.3, warn=False)
    mc.prepare(s, f)
    assert np.abs(mc.lattice_moment() - mc.S).max() > 1e-3 * np.abs(mc.S).max()


@pytest.mark.parametrize("dim,plane,nu", [(2, "stress", 1 / 3), (2, "strain", 0.25), (3, "stress", 0.25)])
def test_d12_equal_d66_is_pmb(dim, plane, nu):
    """With D12 = D66 the Ti-PD force equals PMB's linearised force (same c, same weights)
    to round-off, and the small-displacement PMB force to O(strain)."""
    s = square_lattice(12, 12, 1e-3, plane=plane) if dim == 2 else cubic_lattice(7, 7, 7, 1e-3)
    f = build_family(s, 3.015e-3)
    m = TiPD(E=70e9, nu=nu, surface="none")          # the paper's model
    m.prepare(s, f)
    p = PMB(E=70e9, nu=nu)
    p.prepare(s, f)
    st = _perturbed(s, f)
    u = st.y - s.x0
    xi, L = f.xi, f.length
    eta = u[f.neighbors] - u[f.owner]
    fb = (p.c * p.w_b / L ** 3 * np.einsum("kc,kc->k", xi, eta))[:, None] * xi
    Fp = np.zeros_like(u)
    np.add.at(Fp, f.owner, fb)
    Ft = m.force(st)
    assert np.abs(Ft - Fp).max() <= 1e-12 * np.abs(Fp).max()
    # the nonlinear PMB kernel: central difference in the amplitude removes the even terms
    # (strain ~1e-5: truncation ~1e-10, cancellation ~1e-11)
    st2 = State.reference(s.x0, f.nb)
    st2.y[...] = s.x0 + 1e-2 * u
    fplus = p.force(st2)
    st2.y[...] = s.x0 - 1e-2 * u
    fminus = p.force(st2)
    assert np.abs(Ft - 50.0 * (fplus - fminus)).max() <= 1e-8 * np.abs(Ft).max()


@pytest.mark.parametrize("dim", [2, 3])
def test_linear_field_gives_zero_interior_force(dim):
    s, f = _body(dim, 12 if dim == 2 else 9)
    C = D_ANISO if dim == 2 else isotropic_voigt(200e9, 0.2, 3)
    m = TiPD(C, calibration="discrete", angle=0.7, warn=False, surface="none")
    m.prepare(s, f)
    H = np.random.default_rng(3).normal(size=(3, 3)) * 1e-3
    if dim == 2:
        H[2, :] = H[:, 2] = 0.0
    st = State.reference(s.x0, f.nb)
    st.y += s.x0 @ H.T + 1e-4
    F = m.force(st)
    full = f.counts == f.counts.max()
    assert full.sum() > 0
    assert np.abs(F[full]).max() <= 1e-12 * np.abs(F).max()
    assert np.abs(F[~full]).max() > 1e-3 * np.abs(F).max()   # the surface is not in balance


@pytest.mark.parametrize("dim", [2, 3])
def test_stiffness_symmetric_and_minus_dforce_du(dim):
    s, f = _body(dim, 8 if dim == 2 else 5)
    C = D_ANISO if dim == 2 else isotropic_voigt(200e9, 0.2, 3)
    m = TiPD(C, angle=0.4, warn=False)
    m.prepare(s, f)
    st = _perturbed(s, f)
    K = m.tangent(st)
    assert abs(K - K.T).max() <= 1e-14 * abs(K).max()
    Kn = m.__class__.__mro__[1].tangent(m, st)     # base class: central finite differences
    assert abs(K - Kn).max() <= 1e-6 * abs(K).max()
    F = m.particle_force(st).ravel()
    assert np.abs(F + K @ (st.y - s.x0).ravel()).max() <= 1e-12 * np.abs(F).max()


def test_stiffness_is_corrected_appendix_a():
    s, f = _body(2, 10)
    m = TiPD(D_ANISO, surface="none")
    m.prepare(s, f)
    K = m.tangent()
    perm = np.empty(2 * s.n, dtype=int)
    perm[0::2] = 3 * np.arange(s.n)
    perm[1::2] = 3 * np.arange(s.n) + 1
    K2 = K.tocsr()[perm][:, perm]
    V = s.volume[0]
    A = appendix_a_stiffness(s, f, D_ANISO)
    assert abs(K2 + V * A).max() <= 1e-13 * abs(K2).max()
    A_lit = appendix_a_stiffness(s, f, D_ANISO, literal=True)
    assert abs(K2 + V * A_lit).max() > 1e-2 * abs(K2).max()   # the printed typos matter


def test_stiffness_is_corrected_appendix_b():
    """Fully anisotropic 3D material (all 21 constants): the assembled stiffness is -V A with
    A of Appendix B corrected (the dz^2 restored), not as printed."""
    s, f = _body(3, 5)
    B = np.random.default_rng(3).normal(size=(6, 6))
    m = TiPD(B @ B.T * 1e9 + np.eye(6) * 5e9, surface="none", warn=False)
    m.prepare(s, f)
    K = m.tangent().tocsr()
    V = s.volume[0]
    assert abs(K + V * appendix_b_stiffness(s, f, m.C)).max() <= 1e-13 * abs(K).max()
    assert abs(K + V * appendix_b_stiffness(s, f, m.C, literal=True)).max() > 1e-2 * abs(K).max()
    with pytest.raises(ValueError, match="3D elastic tensor"):
        appendix_b_stiffness(s, f, np.eye(6))


@pytest.mark.parametrize("dim", [2, 3])
def test_force_is_minus_energy_gradient(dim, check_force_is_minus_energy_gradient):
    C = D_ANISO if dim == 2 else isotropic_voigt(200e9, 0.2, 3)
    check_force_is_minus_energy_gradient(TiPD(C, angle=0.2, warn=False), dim, seed=1)


def test_rigid_rotation_energy_only_when_d12_differs_from_d66():
    s, f = _body(2, 10)
    th = 1e-4
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    energies = {}
    for nu in (1 / 3, 0.2):
        m = TiPD(E=70e9, nu=nu, surface="none")
        m.prepare(s, f)
        st = State.reference(s.x0, f.nb)
        st.y[...] = s.x0 @ R.T
        e_rot = m.energy(st)
        st.y[...] = s.x0 * (1 + th)
        energies[nu] = e_rot / m.energy(st)
    assert energies[1 / 3] < 1e-6
    assert energies[0.2] > 1e-2


@pytest.mark.parametrize("dim,plane,nu,bad", [(2, "stress", 0.3, False), (2, "stress", 0.35, True),
                                              (2, "strain", 0.24, False), (2, "strain", 0.26, True),
                                              (3, "stress", 0.24, False), (3, "stress", 0.26, True)])
def test_indefiniteness_warning(dim, plane, nu, bad):
    s = square_lattice(6, 6, 1e-3, plane=plane) if dim == 2 else cubic_lattice(5, 5, 5, 1e-3)
    f = build_family(s, 2.01e-3)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        m = TiPD(E=70e9, nu=nu, surface="none")
        m.prepare(s, f)
    hit = [x for x in w if issubclass(x.category, IndefiniteWarning)]
    assert bool(hit) == bad
    if bad:
        msg = str(hit[0].message)
        assert "D12" in msg and "D66" in msg and "nu >" in msg


def test_critical_stretches_reduce_to_bond_based():
    E, G0, d = 72e9, 135.0, 7.5e-3
    # (61): nu = 1/3 in 2D, (95): nu = 1/4 in 3D are the bond-based values
    c2 = pmb_micromodulus(E, None, d, 2, thickness=1.0)
    assert tipd_critical_stretch(G0, E, 1 / 3, d, 2) == pytest.approx(
        pmb_critical_stretch(G0, c2, d, 2, thickness=1.0), rel=1e-14)
    assert tipd_critical_stretch(G0, E, 1 / 3, d, 2) == pytest.approx(np.sqrt(4 * np.pi * G0 / (9 * E * d)))
    c3 = pmb_micromodulus(E, None, d, 3)
    assert tipd_critical_stretch(G0, E, 0.25, d, 3) == pytest.approx(pmb_critical_stretch(G0, c3, d, 3), rel=1e-14)
    assert tipd_critical_stretch(G0, E, 0.25, d, 3) == pytest.approx(np.sqrt(5 * G0 / (6 * E * d)))
    # the second form of (62) equals its first
    nu = 0.22
    G = E / (2 * (1 + nu))
    s62 = np.sqrt(9 * np.pi ** 2 * (1 + nu) * (1 - nu) * G0 / ((8 * (3 * nu - 1) + 27 * np.pi * (1 - nu)) * E * d))
    assert tipd_critical_stretch(G0, E, nu, d, 2, rule="osb") == pytest.approx(s62, rel=1e-14)
    # (60) for any nu from the model's own bond stiffness (anisotropic path, isotropic C)
    s, f = _body(2, 6)
    m_iso = TiPD(E=E, nu=nu, G0=G0)
    m_gen = TiPD(isotropic_voigt(E, nu, 2), G0=G0)
    for m in (m_iso, m_gen):
        m.prepare(s, f)
    assert m_gen.s0 == pytest.approx(m_iso.s0, rel=1e-10)


def test_bonds_break_and_damage():
    s, f = _body(2, 10)
    m = TiPD(E=70e9, nu=0.25, s0=1e-3)
    m.prepare(s, f)
    st = State.reference(s.x0, f.nb)
    st.y[:, 0] = s.x0[:, 0] * (1 + 2e-3)
    out = np.zeros_like(st.y)
    broken = m.step_force(st, out)
    s_b = (np.linalg.norm(st.y[f.neighbors] - st.y[f.owner], axis=1) - f.length) / f.length
    assert broken == int((s_b > 1e-3).sum()) > 0
    assert not st.intact[s_b > 1e-3].any() and st.intact[s_b <= 1e-3].all()


def test_registered_and_bad_input():
    assert isinstance(create("tipd", E=1e9, nu=0.2), TiPD)
    with pytest.raises(ValueError, match="not positive definite"):
        TiPD(np.array([[1.0, 2.0, 0], [2.0, 1.0, 0], [0, 0, 1.0]]))
    with pytest.raises(ValueError, match="angle must be finite"):
        TiPD(D_ANISO, angle=float("nan"))
    with pytest.raises(ValueError, match="outside the material's range"):
        orthotropic_voigt_2d(1e9, 100e9, 1e9, 0.5)
    s, f = _body(2, 6)
    m = TiPD(E=1e9, nu=1.2)
    with pytest.raises(ValueError, match="Poisson ratio 1.2 outside"):
        m.prepare(s, f)
    with pytest.raises(ValueError, match="unknown calibration"):
        TiPD(E=1e9, nu=0.2, calibration="lattice")


def test_default_surface_correction_follows_failure():
    """Elastic Ti-PD gets the surface correction by default, Ti-PD with a failure criterion
    the paper's model; the indefiniteness warning is about the uncorrected model."""
    assert TiPD(E=70e9, nu=0.2).surface == "correspondence"
    assert TiPD(E=70e9, nu=0.2, G0=10.0).surface == "none"
    assert TiPD(E=70e9, nu=0.2, s0=1e-3).surface == "none"
    s = square_lattice(6, 6, 1e-3)
    f = build_family(s, 2.01e-3)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        TiPD(E=70e9, nu=0.4).prepare(s, f)
    assert not [x for x in w if issubclass(x.category, IndefiniteWarning)]
