"""The extensometer strain of the dynamic tension runs (upscale.analysis.stress.Extensometer),
shared by the coarse runner and the LAMMPS one."""
import numpy as np
import pytest

from upscale.analysis.stress import Extensometer, extensometer_metrics


def _uniform(z0, eps, c=3.7, shift=-0.41):
    """A uniform axial stretch by eps about c, plus a rigid shift."""
    return c + (1.0 + eps) * (z0 - c) + shift


@pytest.mark.parametrize("eps", [0.0, 1e-4, 0.02, 0.3])
def test_extensometer_uniform_stretch_is_exact_dcbr_weights(eps):
    """Any weights (coarse particles' atom counts), any window: a uniform stretch by eps
    reads eps to 1e-12 whatever lies outside the window (here a wild displacement)."""
    rng = np.random.default_rng(7)
    z0 = rng.uniform(0.0, 150.0, 3000)
    w = np.where(rng.random(3000) < 0.3, 1.0, rng.uniform(0.0, 8.0, 3000))
    lo, hi = Extensometer.window(50.0, 100.0)
    assert (lo, hi) == (62.5, 87.5)
    ext = Extensometer(z0, lo, hi, weights=w)
    z = _uniform(z0, eps)
    out = (z0 < lo) | (z0 > hi)
    z[out] += rng.normal(0.0, 5.0, out.sum())  # grips, boundary layers: not measured
    assert abs(ext.strain(z) - eps) < 1e-12
    # a local jump inside the window is measured (the flaw between the marks)
    z2 = z.copy()
    z2[z0 > ext.zbar] += 0.1
    assert ext.strain(z2) > eps + 1e-3


@pytest.mark.lammps
def test_lammps_extensometer_commands_read_a_uniform_stretch():
    """The LAMMPS form (fix store/state + atom variable + compute reduce) of the same
    extensometer reads a uniform stretch of a short tube to 1e-12 and counts its atoms."""
    from upscale.build import swcnt
    from upscale.experiments.lammps.potential import resolve_potential
    from upscale.experiments.lammps.setup import extensometer_commands
    from upscale.experiments.lammps.setup import gather_positions as _positions
    from upscale.experiments.lammps.setup import new_instance as _setup

    tube = swcnt(5, 5, 30.0)
    lmp, _ = _setup(tube, resolve_potential("tersoff:BNC.tersoff", "step"), "s s s",
                    box=tube.cell.lengths().copy())
    try:
        x = _positions(lmp, len(tube))
        ext = Extensometer(x[:, 2], *Extensometer.window(x[:, 2].min() + 5, x[:, 2].max() - 5))
        lmp.commands_list(extensometer_commands(ext))
        eps = 0.0371
        x2 = x.copy()
        x2[:, 2] = _uniform(x[:, 2], eps, c=11.0, shift=0.2)
        lmp.scatter_atoms("x", 1, 3, np.ctypeslib.as_ctypes(x2.ravel()))
        lmp.commands_list(["thermo_style custom step v_exteps v_extn", "run 0"])
        th = dict(lmp.last_thermo())
    finally:
        lmp.close()
    assert int(round(th["v_extn"])) == ext.n > 0
    assert abs(th["v_exteps"] - eps) < 1e-12
    assert abs(ext.strain(x2[:, 2]) - eps) < 1e-12


def test_extensometer_metrics_and_bad_input():
    e = np.linspace(0.002, 0.1, 26)
    x = 0.9 * e  # the marks see 90 % of the grip strain
    s = 1000.0 * x * np.where(e < 0.08, 1.0, 0.5)
    m = extensometer_metrics(e, x, s, strain_at_peak=float(e[19]))
    assert m["youngs_modulus_ext_TPa"] == pytest.approx(1.0, rel=1e-12)
    assert m["strain_at_peak_ext"] == pytest.approx(0.9 * e[19], rel=1e-15)
    for call, word in ((lambda: extensometer_metrics(e, x, s, 0.5), "strain_at_peak=0.5"),
                       (lambda: Extensometer(e, 0.2, 0.1), "lo=0.2"),
                       (lambda: Extensometer(e, 0.5, 0.9), "holds 0 points"),
                       (lambda: Extensometer.window(1.0, 0.0), "zb=1.0")):
        with pytest.raises(ValueError) as err:
            call()
        assert word in str(err.value) and "valid" in str(err.value)
        assert "\n" not in str(err.value)


def test_dcbr_dynamic_extensometer_vs_grip_strain():
    """A short coarse pull: the strain on the marks follows the grip strain. On the 150 Å
    vacancy references LAMMPS's marks read 4-5 % more than its grips (the vacancy between
    the marks weighs more in their slope than in the grip strain; E_ext < E_grip); the
    coarse tube, whose clamped grips are as stiff as LAMMPS's (within 4.3 %), does the same: here 1.12 on a 40 Å gauge with a
    10 Å atomistic band (0.92 before the grips were clamped, when they were 7-23 % too
    compliant)."""
    from upscale.models.dcbr_defect import DCBRDefectTube
    from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension

    m = DCBRDefectTube(6, 6, 60.0, vacancy=4, coarsening=2.0, r_atomistic=5.0, region="band")
    res = dynamic_tension(m, grip=10.0, speed=2.0, max_strain=0.025, sample=40)
    e = np.array(res["curve"]["strain"])
    x = np.array(res["curve"]["extensometer_strain"])
    assert len(x) == len(e) and np.all(np.diff(x) > 0)
    # the ratio rings by ~10 % with the short gauge's axial standing wave: its least-squares
    # value over the run
    ratio = float(x @ e / (e @ e))
    assert 1.0 < ratio < 1.2, x / e
    assert res["youngs_modulus_ext_TPa"] < res["youngs_modulus_TPa"]
    assert res["strain_at_peak_ext"] in x
    lo, hi = res["extensometer"]["window_A"]
    assert hi - lo == pytest.approx(0.5 * res["gauge_length_A"])
