"""Gain matrix G (seed 004 eqs. 6.1-6.6): affine exactness, surfaces, chain rule, bad input."""
import numpy as np
import pytest

from upscale.models.gain import build_gain

RNG = np.random.default_rng(7)


def _cloud(n=300, size=10.0):
    """A jittered cubic grid of about n points in a box of edge ``size``."""
    m = max(2, round(n ** (1 / 3)))
    g = (np.arange(m) + 0.5) * size / m
    x = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    return x + RNG.uniform(-0.3, 0.3, x.shape) * size / m


def _rot(axis, ang):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


AFFINE = {
    "stretch": np.diag([1.1, 0.95, 1.02]),
    "shear": np.array([[1, 0.2, 0], [0, 1, -0.1], [0.05, 0, 1.0]]),
    "rotation": _rot([1, 2, 3], 0.7),
    "general": np.eye(3) + 0.3 * np.random.default_rng(1).standard_normal((3, 3)),
}


@pytest.mark.parametrize("stabilised", [False, True])
@pytest.mark.parametrize("name", list(AFFINE))
def test_affine_field_gives_displacement_gradient(name, stabilised):
    x = _cloud()
    F = AFFINE[name]
    op = build_gain(x, 3.0, volume=RNG.uniform(0.5, 1.5, len(x)), stabilised=stabilised)
    u = x @ (F - np.eye(3)).T + np.array([0.3, -1.0, 2.0])
    G = op.gain(u)
    # exact at every particle (interior and boundary): G = F - I
    assert np.abs(G - (F - np.eye(3))).max() < 1e-12
    assert np.abs(op.deformation(x + u) - F).max() < 1e-12


def test_affine_periodic_cell():
    L = np.array([8.0, 9.0, 10.0])
    x = RNG.uniform(0, 1, (200, 3)) * L
    op = build_gain(x, 2.8, cell=L, pbc=(True, True, True))
    F = AFFINE["shear"]
    y = x @ F.T  # a periodic affine map: the cell's images follow through cell' = F L only for diagonal F
    Fd = np.diag([1.05, 0.97, 1.1])
    y = x @ Fd.T
    assert np.abs(op.deformation(y, cell=Fd.diagonal() * L) - Fd).max() < 1e-12
    assert np.abs(op.gain(y - x, cell=Fd.diagonal() * L) - (Fd - np.eye(3))).max() < 1e-12


def _cylinder(R=6.0, nt=24, nz=20, dz=1.3):
    th = 2 * np.pi * np.arange(nt) / nt
    z = dz * (np.arange(nz) + 0.5)
    T, Z = np.meshgrid(th, z, indexing="ij")
    x = np.column_stack([R * np.cos(T.ravel()), R * np.sin(T.ravel()), Z.ravel()])
    return x, T.ravel(), Z.ravel(), nz * dz


def test_surface_gain_on_cylinder_stretch_and_twist():
    R = 6.0
    x, th, z, L = _cylinder(R)
    op = build_gain(x, 3.2, surface=True, axis=[0, 0, 1], cell=[0, 0, L], pbc=(False, False, True))
    # frame: t1 = e_theta, t2 = e_z, normal = e_r
    er = np.column_stack([np.cos(th), np.sin(th), 0 * th])
    et = np.column_stack([-np.sin(th), np.cos(th), 0 * th])
    assert np.abs(op.normal - er).max() < 1e-12
    assert np.abs(op.frame[:, :, 0] - et).max() < 1e-12
    assert np.abs(op.frame[:, :, 1] - [0, 0, 1]).max() < 1e-12
    # symmetric family: the reference chords fit the tangent frame exactly
    assert np.abs(op.F0 - op.frame).max() < 1e-12
    # uniform radial lam_t and axial lam_z stretch: exact
    lt, lz = 0.97, 1.08
    y = x * [lt, lt, lz]
    F = op.deformation(y, cell=[0, 0, lz * L])
    assert np.abs(F[:, :, 0] - lt * et).max() < 1e-12
    assert np.abs(F[:, :, 1] - np.array([0, 0, lz])).max() < 1e-12
    # uniform twist theta -> theta + k z (not periodic: a long open tube, interior particles):
    # the shear of the surface metric, C_tz = R k, is recovered to O((h/R)^2)
    kt = 0.01  # rad / length
    errs = []
    for nt, nz, dz, h in [(24, 40, 1.3, 3.2), (48, 80, 0.65, 1.6)]:
        x2, th2, z2, L2 = _cylinder(R, nt=nt, nz=nz, dz=dz)
        op2 = build_gain(x2, h, surface=True, axis=[0, 0, 1])
        y2 = np.column_stack([R * np.cos(th2 + kt * z2), R * np.sin(th2 + kt * z2), z2])
        F2 = op2.deformation(y2)
        inner = (z2 > 4) & (z2 < L2 - 4)
        C = np.einsum("nia,nib->nab", F2, F2)[inner]
        errs.append(np.abs(C[:, 0, 1] / (R * kt) - 1).max())
        assert np.abs(C[:, 0, 0] - 1).max() < 2e-4 and np.abs(C[:, 1, 1] - 1 - (R * kt) ** 2).max() < 2e-4
    assert errs[0] < 0.02
    assert 3.5 < errs[0] / errs[1] < 4.5  # second-order convergence in h


def test_rigid_motion_gives_unit_metric():
    x, th, z, L = _cylinder()
    op = build_gain(x, 3.2, surface=True, axis=[0, 0, 1])
    Q = _rot([0.3, -1, 0.4], 1.1)
    F = op.deformation(x @ Q.T + [1.0, 2.0, 3.0])
    C = np.einsum("nia,nib->nab", F, F)
    C0 = np.einsum("nia,nib->nab", op.F0, op.F0)
    assert np.abs(C - C0).max() < 1e-12


def test_chain_rule_forces_match_finite_differences():
    x = _cloud(80, 6.0)
    op = build_gain(x, 2.5, stabilised=True)
    W = RNG.standard_normal((3, 3))

    def energy(y):
        F = op.deformation(y)
        return 0.5 * np.sum((F - np.eye(3)) ** 2 * W[None]) + np.sum(np.einsum("nij,nij->n", F, F) ** 2) * 1e-2

    def P_of(y):
        F = op.deformation(y)
        tr = np.einsum("nij,nij->n", F, F)
        return (F - np.eye(3)) * W[None] + 4e-2 * tr[:, None, None] * F

    y = x + 0.05 * RNG.standard_normal(x.shape)
    f = op.forces(P_of(y))
    h = 1e-6
    for j, d in [(0, 0), (5, 2), (40, 1)]:
        yp, ym = y.copy(), y.copy()
        yp[j, d] += h
        ym[j, d] -= h
        fd = -(energy(yp) - energy(ym)) / (2 * h)
        assert abs(fd - f[j, d]) < 1e-6 * max(1, abs(fd))
    assert np.abs(f.sum(0)).max() < 1e-9  # translation invariance: forces sum to zero


def test_too_few_neighbours_names_the_particle():
    x = _cloud(50, 10.0)
    x[17] = [100.0, 100.0, 100.0]  # isolated
    with pytest.raises(ValueError, match="particle 17"):
        build_gain(x, 4.5)
    line = np.column_stack([np.arange(10.0), 0 * np.arange(10.0), 0 * np.arange(10.0)])
    with pytest.raises(ValueError, match="particle 0 has 2 neighbours"):
        build_gain(line, 2.5)
    g = np.arange(6.0)
    plane = np.array(np.meshgrid(g, g, [0.0], indexing="ij")).reshape(3, -1).T
    with pytest.raises(ValueError, match="particle 0: .* singular Upsilon"):
        build_gain(plane, 2.5)  # coplanar: the 3D gain is singular, the surface gain is not
    assert build_gain(plane, 2.5, surface=True).k == 2
    with pytest.raises(ValueError, match="influence radius"):
        build_gain(line, -1.0)
