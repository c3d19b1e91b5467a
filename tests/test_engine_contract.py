"""The engine's contract: system validation, CSR families, bond state, model registry."""
import numpy as np
import pytest

from upscale import models
from upscale.engine import (ParticleSystem, State, bonds_crossing_segment, build_family,
                            cubic_lattice, damage, square_lattice)
from upscale.models.base import Model, Needs


def brute_pairs(x, delta):
    d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2)
    i, j = np.nonzero((d <= delta) & (d > 0))
    return set(zip(i.tolist(), j.tolist()))


def test_family_matches_brute_force_and_is_symmetric():
    rng = np.random.default_rng(0)
    x = rng.random((150, 3))
    sys = ParticleSystem(x, 1e-3, 1.0, spacing=0.05)
    fam = build_family(sys, 0.25)
    got = set(zip(fam.owner.tolist(), fam.neighbors.tolist()))
    assert got == brute_pairs(x, 0.25)
    assert fam.offsets[0] == 0 and fam.offsets[-1] == fam.nb
    np.testing.assert_allclose(fam.xi, x[fam.neighbors] - x[fam.owner])
    np.testing.assert_allclose(fam.length, np.linalg.norm(fam.xi, axis=1))
    assert np.array_equal(fam.owner[fam.reverse], fam.neighbors)
    assert np.array_equal(fam.reverse[fam.reverse], np.arange(fam.nb))


def test_lammps_partial_volume_factor():
    sys = cubic_lattice(9, 9, 9, 1.0)
    fam = build_family(sys, 3.0002, partial_volume="lammps")
    beta = fam.volume_factor
    r = fam.length
    edge = np.abs(r - 3.0002) <= 0.5
    np.testing.assert_allclose(beta[edge], (3.0002 + 0.5 - r[edge]) / 1.0)
    assert np.all(beta[~edge] == 1.0) and r.max() <= 3.0002


def test_bad_input_one_line_errors():
    with pytest.raises(ValueError, match="not finite"):
        ParticleSystem([[0, 0, 0], [np.nan, 0, 0]], 1.0)
    with pytest.raises(ValueError, match="volume must be positive: particle 1 has volume -1"):
        ParticleSystem([[0, 0, 0], [1, 0, 0]], [1.0, -1.0])
    sys = cubic_lattice(3, 3, 3, 1.0)
    with pytest.raises(ValueError, match="horizon 0.5 is not larger than the particle spacing 1"):
        build_family(sys, 0.5)
    with pytest.raises(ValueError, match="region 'grip' selects no particle"):
        sys.select(box=((10, None, None), (None, None, None)), name="grip")
    with pytest.raises(ValueError, match="unknown model 'nope'; valid: .*lps.*pmb"):
        models.get("nope")


def test_crack_removal_and_damage():
    sys = square_lattice(10, 10, 1.0)
    fam = build_family(sys, 2.01)
    cut = bonds_crossing_segment(sys.x0, (-1, 4.5), (4.5, 4.5))
    fam2 = fam.remove_bonds(cut(fam.owner, fam.neighbors, fam.xi))
    assert fam2.nb < fam.nb
    y = sys.x0[:, 1]
    crossing = (y[fam2.owner] - 4.5) * (y[fam2.neighbors] - 4.5) < 0
    xm = 0.5 * (sys.x0[fam2.owner, 0] + sys.x0[fam2.neighbors, 0])
    assert not np.any(crossing & (xm < 4.0))
    intact = fam2.all_intact()
    assert np.all(damage(fam2, intact) == 0)
    intact[fam2.offsets[0]:fam2.offsets[1]] = False
    mu = damage(fam2, intact)
    assert mu[0] == 1.0 and mu[1:].max() < 1.0


class Spring(Model):
    """Minimal dummy model: every bond a linear spring (force density)."""

    name = "dummy-spring"
    needs = Needs(pairs=True, energy=True)

    def add_force(self, state, out):
        f = self.family
        d = state.y[f.neighbors] - state.y[f.owner]
        r = np.linalg.norm(d, axis=1)
        fb = ((r - f.length) / r * state.intact)[:, None] * d * self.system.volume[f.neighbors, None]
        np.add.at(out, f.owner, fb)


def test_dummy_model_through_the_interface():
    sys = cubic_lattice(4, 4, 4, 1.0)
    fam = build_family(sys, 1.5)
    m = Spring()
    m.prepare(sys, fam)
    st = State.reference(sys.x0, fam.nb)
    assert np.all(m.force(st) == 0)
    st.y += np.random.default_rng(1).normal(scale=0.01, size=st.y.shape)
    f = m.particle_force(st)
    assert abs(f.sum(axis=0)).max() < 1e-12
    assert m.residual(st).shape == (3 * sys.n,)


def test_registry_register_and_create():
    class Tmp(Model):
        name = "tmp-test"
    models.register("tmp-test", Tmp)
    assert models.get("TMP-test") is Tmp
    assert "tmp-test" in models.names()
    assert isinstance(models.create("tmp-test"), Tmp)


def test_numerical_tangent_is_symmetric_stiffness():
    from upscale.models.bond_based import PMB

    sys = square_lattice(5, 5, 1e-3)
    fam = build_family(sys, 2.01e-3)
    m = PMB(E=1e9)
    m.prepare(sys, fam)
    st = State.reference(sys.x0, fam.nb)
    K = m.tangent(st).toarray()
    assert np.abs(K - K.T).max() < 1e-6 * np.abs(K).max()
    du = np.random.default_rng(0).normal(scale=1e-9, size=st.y.shape)
    du[:, 2] = 0
    F0 = m.residual(st)
    st.y += du
    dF = m.residual(st) - F0
    np.testing.assert_allclose(-K @ du.ravel(), dF, rtol=1e-4, atol=1e-6 * np.abs(dF).max())


def test_lps_surface_correction_option():
    from upscale.models.state_based import LPS

    sys = square_lattice(12, 12, 1e-3)
    fam = build_family(sys, 3.015e-3)
    st = State.reference(sys.x0, fam.nb)
    st.y[:, 0] += 1e-3 * sys.x0[:, 1]  # simple shear
    W = {}
    for sc in (False, True):
        m = LPS(E=1e9, nu=0.3, surface_correction=sc)
        m.prepare(sys, fam)
        W[sc] = m.energy_density(st)
    Wb = 0.5 * (1e9 / 2.6) * 1e-6
    assert abs(W[True][0] / Wb - 1) < abs(W[False][0] / Wb - 1)
