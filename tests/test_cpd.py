"""CPD: tangent vs finite differences, energy gradient, patch test, calibration, units,
bad input, skipped work."""
import numpy as np
import pytest

from upscale.engine.families import build_family
from upscale.engine.state import State
from upscale.engine.system import ParticleSystem, cubic_lattice, square_lattice
from upscale.models import cpd
from upscale.models.cpd import CPD

RNG = np.random.default_rng(7)


def _setup(s, model, pv=None):
    fam = build_family(s, model.horizon, partial_volume=pv)
    model.prepare(s, fam)
    st = State.reference(s.x0, fam.nb)
    return fam, st


def _fd_tangent_err(s, model, amp=0.05):
    fam, st = _setup(s, model)
    st.y += amp * s.spacing * RNG.standard_normal(st.y.shape)
    if s.dim == 2:
        st.y[:, 2] = 0.0
    K = model.tangent(st).toarray()
    y0 = st.y.copy()
    h = 1e-6 * s.spacing
    dofs = [3 * a + c for a in range(s.n) for c in range(s.dim)]
    Kfd = np.zeros((3 * s.n, len(dofs)))
    for col, d in enumerate(dofs):
        a, c = divmod(d, 3)
        st.y[a, c] = y0[a, c] + h
        fp = model.residual(st)
        st.y[a, c] = y0[a, c] - h
        fm = model.residual(st)
        st.y[a, c] = y0[a, c]
        Kfd[:, col] = -(fp - fm) / (2 * h)
    Kd = K[np.ix_(dofs, dofs)]
    return np.abs(Kd - Kfd[dofs]).max() / np.abs(Kd).max(), np.abs(Kd - Kd.T).max() / np.abs(Kd).max()


@pytest.mark.parametrize("case", ["2d-C1", "2d-C2", "3d-C1", "3d-C2", "3d-C3", "3d-all-uniform"])
def test_tangent_matches_central_differences(case):
    if case == "3d-all-uniform":     # the seed's quadrature V_k = V_H^k / N_k, all three types
        s = cubic_lattice(3, 3, 3, 1e-3)
        err, asym = _fd_tangent_err(s, CPD(horizon=1.5e-3, dim=3, C1=1e15, C2=1e27, C3=1e40,
                                           quadrature="uniform"))
        assert err < 1e-6 and asym < 1e-12
        return
    dim, which = case.split("-")
    C = {"C1": dict(C1=1e15), "C2": dict(C2=1e27), "C3": dict(C3=1e40)}[which]
    if dim == "2d":
        s, delta = square_lattice(5, 5, 1e-3, thickness=1e-3), 2.01e-3
    else:
        s, delta = cubic_lattice(3, 3, 3, 1e-3), 1.5e-3
    err, asym = _fd_tangent_err(s, CPD(horizon=delta, dim=int(dim[0]), **C))
    assert err < 1e-6
    assert asym < 1e-12


def test_forces_are_energy_gradient_and_conserve_momentum():
    s = cubic_lattice(3, 3, 3, 1e-3)
    model = CPD(horizon=1.5e-3, dim=3, C1=1e15, C2=1e27, C3=1e40)
    fam, st = _setup(s, model)
    st.y += 0.05e-3 * RNG.standard_normal(st.y.shape)
    F = model.particle_force(st)
    d = RNG.standard_normal(st.y.shape)
    y0, h = st.y.copy(), 1e-9
    st.y = y0 + h * d
    ep = model.energy(st)
    st.y = y0 - h * d
    em = model.energy(st)
    st.y = y0
    assert (ep - em) / (2 * h) == pytest.approx(-np.sum(F * d), rel=1e-6)
    scale = np.abs(F).max()
    assert np.abs(F.sum(axis=0)).max() < 1e-10 * scale * s.n               # linear momentum
    assert np.abs(np.cross(st.y, F).sum(axis=0)).max() < 1e-10 * scale * s.n * 3e-3  # angular


@pytest.mark.parametrize("dim", [2, 3])
def test_patch_test_homogeneous_deformation_zero_interior_residual(dim):
    if dim == 2:
        s = square_lattice(11, 11, 1e-3, thickness=1e-3)
        model = CPD(horizon=2.01e-3, dim=2, E=1e9, nu=0.45)
    else:
        s = cubic_lattice(7, 7, 7, 1e-3)
        model = CPD(horizon=1.5e-3, dim=3, E=1e9, nu=0.3, mode="C1C3")
    fam, st = _setup(s, model)
    H = 1e-3 * RNG.standard_normal((3, 3))
    if dim == 2:
        H[2, :] = H[:, 2] = 0
    st.y = s.x0 @ (np.eye(3) + H).T              # y = (I + H) x
    F = model.particle_force(st)
    c = s.x0.mean(axis=0)
    reach = 2 * fam.length.max() + 1e-9
    lo, hi = s.x0.min(axis=0), s.x0.max(axis=0)
    interior = np.all((s.x0[:, :dim] - lo[:dim] > reach) & (hi[:dim] - s.x0[:, :dim] > reach), axis=1)
    assert interior.sum() >= 1
    boundary_scale = np.abs(F).max()
    assert boundary_scale > 0
    assert np.abs(F[interior]).max() < 1e-9 * boundary_scale


def test_calibration_energy_density_2d_interior():
    """Plane stress nu = 0.4 and 0.6, delta = 4 dx: energy density within 2 %."""
    for nu in (0.4, 0.6):
        s = square_lattice(11, 11, 1e-3, thickness=1e-3)
        model = CPD(horizon=4e-3, dim=2, E=1e9, nu=nu)
        fam = build_family(s, 4e-3, partial_volume="linear")
        c = int(np.argmin(np.linalg.norm(s.x0 - s.x0.mean(axis=0), axis=1)))
        model.prepare(s, fam, centres=[c])
        lam, mu = cpd.lame(1e9, nu, 2, "stress")
        for _ in range(4):
            g = RNG.standard_normal((3, 3))
            g[2, :] = g[:, 2] = 0
            eps = 1e-6 * (g + g.T) / 2
            st = State.reference(s.x0, fam.nb)
            st.y = s.x0 + s.x0 @ eps.T
            W = model.energy_density(st)[c]
            ref = 0.5 * lam * np.trace(eps) ** 2 + mu * np.sum(eps * eps)
            assert W == pytest.approx(ref, rel=0.02)


def test_continuum_coefficients_against_numerical_integration():
    """The analytic lambda_k, mu_k (module docstring) against Monte-Carlo integrals of the
    linearised energies over the ball (independent of the lattice code)."""
    rng = np.random.default_rng(3)
    d = 1.0
    n = 400_000

    def ball(k):
        v = rng.standard_normal((k, 3))
        v /= np.linalg.norm(v, axis=1)[:, None]
        return v * d * rng.random(k)[:, None] ** (1 / 3)

    eps = np.diag([1.0, 0.0, 0.0])          # uniaxial: psi = (lam/2 + mu) for unit strain
    Vb = 4 / 3 * np.pi * d ** 3
    a, b = ball(n), ball(n)
    L = np.linalg.norm(a, axis=1)
    s1 = np.einsum("ij,jk,ik->i", a, eps, a) / L ** 2
    psi1 = 0.5 * Vb * np.mean(0.5 * L * s1 ** 2)
    A = np.cross(a, b)
    An = np.linalg.norm(A, axis=1)
    N = A / An[:, None]
    s2 = np.trace(eps) - np.einsum("ij,jk,ik->i", N, eps, N)
    psi2 = Vb ** 2 / 3 * np.mean(0.5 * An * s2 ** 2)
    k = cpd.modulus_coefficients(d, 3)
    assert psi1 == pytest.approx(k["l1"] / 2 + k["m1"], rel=0.01)
    assert psi2 == pytest.approx(k["l2"] / 2 + k["m2"], rel=0.01)


def test_units_energy_density_independent_of_length_unit():
    """The same body in metres and in millimetres (lengths x k, E x k^-3 with energy in J,
    k = 1e3), constants from the same E, nu: the energy density must scale exactly by
    k^-3 -- catches wrong powers of V_H in the effective volumes or the calibration."""
    k = 1e3
    out = []
    for scale in (1.0, k):
        s = cubic_lattice(5, 5, 5, 1e-3 * scale)
        m = CPD(horizon=2.01e-3 * scale, dim=3, E=1e9 / scale ** 3, nu=0.35, mode="C1C3",
                calibration="continuum")
        fam, st = _setup(s, m)
        st.y = s.x0 * (1 + 1e-4)
        out.append(m.energy_density(st))
    assert np.allclose(out[1], out[0] / k ** 3, rtol=1e-9)
    assert out[0][62] > 0


def test_member_pattern_covers_the_centre_sets():
    from upscale.engine import multibody

    s = cubic_lattice(5, 5, 5, 1e-3)
    fam = build_family(s, 1.5e-3)
    m = CPD(horizon=1.5e-3, dim=3, C1=1e15, C2=1e27)
    m.prepare(s, fam, centres=[62])
    st = State.reference(s.x0, fam.nb)
    st.y = s.x0 * 1.01
    K_sub = m.tangent(st).toarray()
    m_full = CPD(horizon=1.5e-3, dim=3, C1=1e15, C2=1e27)
    m_full.prepare(s, fam)
    m_full.w = tuple(np.where(np.arange(s.n) == 62, w, 0.0) for w in m_full.w)
    with pytest.raises(ValueError, match="another CPD model"):
        m_full.tangent(st)                    # st carries the subset model's set states
    st2 = State.reference(s.x0, fam.nb)
    st2.y = st.y.copy()
    K_full = m_full.tangent(st2).toarray()
    assert np.allclose(K_sub, K_full, rtol=0, atol=1e-12 * np.abs(K_full).max())
    assert multibody.member_pattern(fam, [62])[1].size < multibody.block_pattern(s.x0, 3.1e-3)[1].size


def test_skip_work_when_constants_zero():
    m = CPD(horizon=2.01e-3, dim=3, E=1e9, nu=0.25)
    assert m.C[1] == 0 and m.C[2] == 0
    assert not m.needs.triplets and not m.needs.quadruplets
    s = cubic_lattice(4, 4, 4, 1e-3)
    _setup(s, m)
    assert m.triplets is None and m.quadruplets is None
    m2 = CPD(horizon=2.01e-3, dim=3, E=1e9, nu=0.3, mode="C1C2")
    assert m2.needs.triplets and not m2.needs.quadruplets


def test_bad_input_one_line_errors():
    with pytest.raises(ValueError, match=r"nu=0.2 outside .*\[0.25, 0.5\)"):
        CPD(horizon=1.0, dim=3, E=1e9, nu=0.2)
    with pytest.raises(ValueError, match=r"\[0.333333, 1\)"):
        CPD(horizon=1.0, dim=2, E=1e9, nu=0.3, plane="stress")
    with pytest.raises(ValueError, match=r"\[0.25, 0.428571\]"):
        CPD(horizon=1.0, dim=3, E=1e9, nu=0.45, mode="C1C2")
    with pytest.raises(ValueError, match=r"C2=-1.0 .* valid range \[0, inf\) J/m\^11"):
        CPD(horizon=1.0, dim=3, C1=1.0, C2=-1.0)
    with pytest.raises(ValueError, match="no three-neighbour interaction in 2D"):
        CPD(horizon=1.0, dim=2, C3=1.0)
    # a single-layer 3D plate: no non-coplanar neighbour triple
    s2 = square_lattice(5, 5, 1.0)
    s = ParticleSystem(s2.x0, 1.0, dim=3, spacing=1.0)
    m = CPD(horizon=1.5, dim=3, C1=1.0, C3=1.0)
    with pytest.raises(ValueError, match="too small for three-neighbour"):
        m.prepare(s, build_family(s, 1.5))
    for msg in ("nu=0.2",):
        try:
            CPD(horizon=1.0, dim=3, E=1e9, nu=0.2)
        except ValueError as e:
            assert "\n" not in str(e)


def test_damage_breaks_all_three_types():
    s = cubic_lattice(3, 3, 3, 1e-3)
    m = CPD(horizon=1.5e-3, dim=3, C1=1e15, C2=1e27, C3=1e40, s1c=0.01)
    fam, st = _setup(s, m)
    m.init_state(st)
    st.y = s.x0 * 1.05          # 5 % stretch everywhere: every set exceeds its s_c
    m.break_bonds(st)
    d = m.damage(st)
    assert np.allclose(d["pairs"], 1) and np.allclose(d["triplets"], 1) and np.allclose(d["quadruplets"], 1)
    assert np.abs(m.particle_force(st)).max() == 0.0


def test_explicit_dynamics_on_engine_velocity_verlet():
    """CPD through the engine's Simulation + VelocityVerlet (force method, stable-step bound):
    momentum conserved, the energy error of the symplectic scheme shrinks like dt^2."""
    from upscale.engine import Simulation
    from upscale.engine.integrators import VelocityVerlet

    s = square_lattice(8, 8, 1e-3, thickness=1e-3, density=1000.0)
    fam = build_family(s, 2.01e-3)
    spread = []
    for safety in (0.4, 0.2):
        m = CPD(horizon=fam.horizon, dim=2, E=1e9, nu=0.45)
        sim = Simulation(s, fam, [m], integrator=VelocityVerlet(safety=safety))
        assert m.triplets is not None and m.quadruplets is None
        sim.state.v[:, :2] = 0.1 * np.random.default_rng(0).standard_normal((s.n, 2))
        sim.state.v -= sim.state.v.mean(axis=0)
        sim.prepare()
        e0 = sim.kinetic_energy() + sim.energy()
        nsteps = int(round(100 * 0.4 / safety))
        es = []
        for _ in range(nsteps):
            sim.run(1)
            es.append(sim.kinetic_energy() + sim.energy())
        spread.append((max(es) - min(es)) / e0)
        p = (s.mass[:, None] * sim.state.v).sum(axis=0)
        assert np.abs(p).max() < 1e-12 * np.abs(s.mass[:, None] * sim.state.v).sum()
    assert 2.5 < spread[0] / spread[1] < 5.5


def test_continuum_calibration_matches_literature_C1C3():
    """Ekiz, Steinmann & Javili (2022), Mech. Mater. 104417: C1 = 30 mu/(pi delta^4),
    C2 = 0, C3 = 32 (lambda - mu)/(pi^4 delta^12) -- our independent derivation, mode C1C3."""
    E, nu, d = 70e9, 0.33, 2.5e-3
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    C = cpd.calibrate(E, nu, d, 3, mode="C1C3")
    assert C[0] == pytest.approx(30 * mu / (np.pi * d ** 4), rel=1e-12)
    assert C[1] == 0.0
    assert C[2] == pytest.approx(32 * (lam - mu) / (np.pi ** 4 * d ** 12), rel=1e-12)


def test_surface_correction_factors_and_consistency():
    s = square_lattice(9, 9, 1e-3, thickness=1e-3)
    m = CPD(horizon=2.01e-3, dim=2, E=1e9, nu=0.45, surface_correction=True)
    fam, st = _setup(s, m)
    c0 = m.interior_particle()
    g1 = m.correction[0]
    assert np.allclose(g1[c0], 1.0) and (g1[0] > 1.2).all()          # corner: missing bonds
    assert np.allclose(m.g[0][fam.owner == c0], 1.0)
    # the factors are constants: forces remain the exact gradient, tangent consistent
    err, asym = _fd_tangent_err(square_lattice(5, 5, 1e-3, thickness=1e-3),
                                CPD(horizon=2.01e-3, dim=2, E=1e9, nu=0.45, surface_correction=True))
    assert err < 1e-6 and asym < 1e-12
