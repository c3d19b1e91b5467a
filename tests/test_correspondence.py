"""Correspondence (NOSB, seed 001): the deformation gradient of an affine field is exact,
the force is minus the energy gradient for every law and stabilisation, the assembled
stiffness of the linear law is -dF/du, and the soft (near-zero-energy) modes of a free body
with and without stabilisation."""
import numpy as np
import pytest

from upscale.engine import State, build_family, cubic_lattice, square_lattice
from upscale.models import create
from upscale.models.base import numerical_tangent
from upscale.models.correspondence import Correspondence

CASES = [(law, stab) for law in ("linear", "svk", "neo-hookean") for stab in (None, "silling", "wan")]


def _body(dim, n=None, m=3.015):
    s = square_lattice(n or 8, n or 8, 1e-3) if dim == 2 else cubic_lattice(n or 5, n or 5, n or 5, 1e-3)
    return s, build_family(s, m * 1e-3)


@pytest.mark.parametrize("dim", [2, 3])
def test_affine_deformation_gradient_is_exact(dim):
    s, f = _body(dim)
    m = Correspondence(E=70e9, nu=0.3)
    m.prepare(s, f)
    H = np.random.default_rng(0).normal(size=(3, 3)) * 1e-2
    if dim == 2:
        H[2, :] = H[:, 2] = 0.0
    st = State.reference(s.x0, f.nb)
    st.y = s.x0 + s.x0 @ H.T + 0.3
    assert np.abs(m.deformation_gradient(st) - (np.eye(dim) + H[:dim, :dim])).max() < 1e-13


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("law,stab", CASES)
def test_force_is_minus_energy_gradient(dim, law, stab):
    s, f = _body(dim)
    m = Correspondence(E=70e9, nu=0.3, law=law, stabilisation=stab, angle=None)
    m.prepare(s, f)
    st = State.reference(s.x0, f.nb)
    st.y += np.random.default_rng(1).normal(size=s.x0.shape) * 1e-5
    if dim == 2:
        st.y[:, 2] = 0.0
    F = m.particle_force(st)
    assert np.abs(F.sum(axis=0)).max() < 1e-9 * np.abs(F).max()
    h = 1e-9
    for a, c in [(0, 0), (s.n // 2, 1), (s.n - 1, dim - 1)]:
        st.y[a, c] += h
        ep = m.energy(st)
        st.y[a, c] -= 2 * h
        em = m.energy(st)
        st.y[a, c] += h
        assert abs(-(ep - em) / (2 * h) - F[a, c]) < 1e-6 * np.abs(F).max()


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("stab", [None, "silling", "wan"])
def test_linear_stiffness_is_minus_dforce_du(dim, stab):
    s, f = _body(dim, 6 if dim == 2 else 4)
    D = np.array([[5.0, 3.0, 0.5], [3.0, 5.0, 0.2], [0.5, 0.2, 6.0]]) * 1e9
    m = Correspondence(D, stabilisation=stab) if dim == 2 else \
        Correspondence(E=70e9, nu=0.3, stabilisation=stab)
    m.prepare(s, f)
    st = State.reference(s.x0, f.nb)
    st.y += np.random.default_rng(2).normal(size=s.x0.shape) * 1e-6
    if dim == 2:
        st.y[:, 2] = 0.0
    K = m.tangent(st)
    assert abs(K - K.T).max() < 1e-12 * abs(K).max()
    assert abs(K - numerical_tangent(m, st)).max() < 1e-6 * abs(K).max()
    F = m.particle_force(st).ravel()
    assert np.abs(F + K @ (st.y - s.x0).ravel()).max() < 1e-11 * np.abs(F).max()


def _spectrum(m, s):
    K = m.tangent().toarray()
    free = np.zeros((s.n, 3), bool)
    free[:, :s.dim] = True
    return np.linalg.eigvalsh(K[free.ravel()][:, free.ravel()])


@pytest.mark.parametrize("dim,n", [(2, 10), (3, 5)])
def test_soft_modes_with_and_without_stabilisation(dim, n):
    """Rigid modes are the only exact zeros; the unstabilised model has more soft modes
    (eigenvalue below 1e-2 of its largest) than rigid ones, Wan's removes all of them and
    every stabilisation only stiffens (eigenvalues in ascending order do not decrease)."""
    s, f = _body(dim, n)
    ev = {}
    for st in (None, "silling", "wan"):
        m = Correspondence(E=70e9, nu=0.3, stabilisation=st)
        m.prepare(s, f)
        ev[st] = _spectrum(m, s)
    scale = ev[None].max()
    rigid = dim * (dim + 1) // 2
    for st, e in ev.items():
        assert (np.abs(e) < 1e-10 * scale).sum() == rigid, st
        assert e.min() > -1e-10 * scale
    soft = {st: int((e < 1e-2 * scale).sum()) - rigid for st, e in ev.items()}
    assert soft[None] > 0
    assert soft["wan"] == 0 and soft["silling"] == 0
    assert np.all(ev["silling"] >= ev[None] - 1e-9 * scale)
    assert np.all(ev["wan"] >= ev[None] - 1e-9 * scale)


def test_registered_and_bad_input():
    assert isinstance(create("nosb", E=1e9, nu=0.2), Correspondence)
    with pytest.raises(ValueError, match="unknown stabilisation 'hourglass'"):
        Correspondence(E=1e9, nu=0.2, stabilisation="hourglass")
    with pytest.raises(ValueError, match="unknown material law 'mooney'"):
        Correspondence(E=1e9, nu=0.2, law="mooney")
    with pytest.raises(ValueError, match="angle must be finite"):
        Correspondence(E=1e9, nu=0.2, angle=float("inf"))
    s = square_lattice(1, 8, 1e-3)      # a single column: families do not span 2D
    f = build_family(s, 2.01e-3)
    with pytest.raises(ValueError, match="shape tensor of particle 0 is singular"):
        Correspondence(E=1e9, nu=0.2).prepare(s, f)


def test_bond_associated_patch_symmetry_and_no_zero_energy_modes():
    import warnings as _w

    from upscale.engine import State, build_family, square_lattice
    from upscale.models.correspondence import Correspondence as _C

    s = square_lattice(20, 20, 1e-3)
    f = build_family(s, 3.015e-3)
    m = _C(E=70e9, nu=0.25, bond_associated=True)
    m.prepare(s, f)
    H = np.array([[1.0, 0.3], [-0.2, 0.5]]) * 1e-4
    st = State.reference(s.x0, f.nb)
    st.y[:, :2] += s.x0[:, :2] @ H.T
    eps = 0.5 * (H + H.T)
    w = 0.5 * np.einsum("pa,paqb,qb->", eps, m.C, eps)
    assert np.abs(m.energy_density(st) - w).max() <= 1e-9 * w       # every particle
    o = np.zeros_like(st.y)
    m.add_force(st, o)
    x = s.x0[:, :2]
    inner = np.all((x > 2 * f.horizon + 1e-9) & (x < x.max(0) - 2 * f.horizon - 1e-9), axis=1)
    assert inner.sum() > 0 and np.abs(o[inner]).max() <= 1e-10 * np.abs(o).max()
    K = m.tangent()
    assert abs(K - K.T).max() <= 1e-14 * abs(K).max()
    # small free body: only the 3 rigid modes are zero, none negative, and the softest
    # deformation mode is far stiffer than plain NOSB's near-zero-energy one
    s2 = square_lattice(8, 8, 1e-3)
    f2 = build_family(s2, 3.015e-3)
    counts = {}
    for ba in (False, True):
        m2 = _C(E=70e9, nu=0.25, bond_associated=ba)
        with _w.catch_warnings():
            _w.simplefilter("ignore")
            m2.prepare(s2, f2)
        Kd = m2.tangent().toarray()
        free = np.zeros((s2.n, 3), dtype=bool)
        free[:, :2] = True
        ev = np.linalg.eigvalsh(Kd[free.ravel()][:, free.ravel()])
        sc = np.abs(ev).max()
        counts[ba] = (int((np.abs(ev) <= 1e-8 * sc).sum()), int((ev < -1e-8 * sc).sum()), ev[3] / sc)
    assert counts[True][:2] == (3, 0)
    assert counts[True][2] > 10 * counts[False][2]


def test_bond_associated_bad_input():
    with pytest.raises(ValueError, match="bond-associated"):
        Correspondence(E=1e9, nu=0.2, bond_associated=True, law="svk")
    with pytest.raises(ValueError, match="ba_radius"):
        Correspondence(E=1e9, nu=0.2, bond_associated=True, ba_radius=0.0)
