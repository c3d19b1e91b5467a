"""Non-diagonal mass (upscale.engine.mass): Rayleigh beam dispersion, a mode's frequency
under velocity Verlet with the mass matrix, energy conservation, bad input."""
import numpy as np
import pytest
import scipy.sparse as sp

from upscale.engine.mass import ConsistentMass, edge_coupling


def test_rayleigh_dispersion_matches_closed_form():
    """omega^2 = D(k)/M(k) of the EB beam with the rotary mass tends to the Rayleigh beam
    EI k^4/(rho (A + I k^2)); at k h = 1 the rotary inertia is 8.3 % of omega^2."""
    from upscale.experiments.scenes.tridyn import rayleigh_dispersion

    r = rayleigh_dispersion(ratio=1)
    assert r["rel_err_max"] < 1e-4
    assert r["eb_over_rayleigh"][-1] == pytest.approx(1 + 1 / 12, rel=1e-12)


def test_mass_matrix_verlet_mode_frequency_and_energy():
    """A sine mode of the supported chain oscillates at sqrt(D(k)/M(k)) (to the time
    step's error) with the mass matrix, 1.6 % below the lumped-mass frequency; NVE drift
    stays small."""
    from upscale.experiments.scenes.tridyn import beam_nve, rayleigh_mode

    r = rayleigh_mode(rotary=True, periods=2.0)
    lumped = rayleigh_mode(rotary=False, periods=2.0)
    assert r["measured_over_discrete"] == pytest.approx(1.0, abs=1e-5)
    assert lumped["measured_over_discrete"] == pytest.approx(1.0, abs=1e-5)
    assert 0.97 < r["omega_measured"] / lumped["omega_measured"] < 0.99
    assert beam_nve(theory="eb", rotary=True, height=0.05, steps=2000)["rel_drift"] < 1e-4


def test_mass_bad_input():
    x = np.arange(4.0)
    with pytest.raises(ValueError, match=">= 0"):
        edge_coupling(x, [[0, 1]], [-1.0])
    with pytest.raises(ValueError, match="symmetric"):
        ConsistentMass(sp.csr_matrix(np.triu(np.ones((4, 4)))))
    with pytest.raises(ValueError, match="component"):
        ConsistentMass(sp.csr_matrix((4, 4)), component=3)
