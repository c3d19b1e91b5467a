"""The coarse tube with the vacancy against the stored LAMMPS references (data/reference).

Each is one deterministic run (fixed thermal seed) of the validation case's comparison;
the bounds are the issue's targets (modulus 3 %, strength 5 %, strain at peak 10 %) where
the cases meet them, so a change that breaks the coupling (e.g. the dead load that turned
tubes over) fails here. The references are LAMMPS runs nobody here tuned against.
"""
import pytest

from upscale.experiments.scenes.tube_tension import run_tension_comparison


def _check(out):
    assert out["modulus_err_pct"] < 3.0, out["modulus_err_pct"]
    assert out["strength_err_pct"] < 5.0, out["strength_err_pct"]
    assert out["strain_at_peak_err_pct"] < 10.0, out["strain_at_peak_err_pct"]


def test_dynamic_17_0_vacancy_k2():
    """Dynamic tension (150 Å, grips at 1 Å/ps, 10 K), coarsening 2: the three targets (with
    the grips clamped: before, the coarse grips' extra compliance, static grip stiffness
    12.7 % below LAMMPS's for this tube and K, showed as -7.4 % in the modulus and +11.4 %
    in the strain at peak), the first bond breaking next to the vacancy, a crack across the
    tube, nothing thrown off."""
    out = run_tension_comparison(17, 0, 150.0, 2.0, vacancy=True, dynamic=True, plot=False,
                                 verbose=False)
    _check(out)
    assert out["crack_start_to_vacancy_A"] < 6.0
    assert 70.0 < out["crack_angle_deg"] <= 90.0
    assert out["ejected_atoms"] == 0


# one tube in the default run; the other two (about a minute each) with the slow checks
@pytest.mark.parametrize("n, m, k", [pytest.param(12, 6, 2.0, marks=pytest.mark.slow),
                                     pytest.param(17, 0, 3.0, marks=pytest.mark.slow),
                                     (10, 10, 2.0)])
def test_quasi_static_vacancy(n, m, k):
    """Quasi-static tension of the periodic 100 Å tube with the vacancy (0.5 % steps), with
    the references' damped-dynamics fallback at the step cutoff ((10,10): with energy
    minimisation alone the tube did not fail before 22 % strain, LAMMPS fails at 9 %)."""
    out = run_tension_comparison(n, m, 100.0, k, vacancy=True, plot=False, verbose=False)
    _check(out)
