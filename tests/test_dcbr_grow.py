"""The atomistic region grown about the crack: a state carried from a disc to the band
(:meth:`DCBRDefectTube.carry_state`) and a dynamic run that switches region
(:func:`upscale.experiments.scenes.dcbr_dynamic.dynamic_tension`, ``grow``)."""
import numpy as np
import pytest

from upscale.models.dcbr_defect import DCBRDefectTube
from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension

SMALL = dict(grip=10.0, speed=10.0, max_strain=0.3, sample=20, seed=7)


@pytest.fixture(scope="module")
def pair():
    disc = DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4, r_atomistic=4.0, region="disc")
    band = DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)
    assert disc.nf < band.nf
    return disc, band


def test_a_uniform_state_carries_to_the_larger_regions_uniform_state(pair):
    """Stretched, shifted and turned uniformly, the atoms that become free sit where the
    band's own uniform state has them: the carriers' maps are exact on a uniform lattice."""
    disc, band = pair
    args = (1.012, 1.031, np.array([0.011, 0.02, -0.013]))
    yd, dd, Lz = disc.uniform_state(*args)
    yb, db = band.carry_state(disc, yd, dd, Lz=Lz)
    yb_ref, db_ref, _ = band.uniform_state(*args)
    assert yb.shape == yb_ref.shape
    assert np.abs(yb - yb_ref).max() < 1e-9
    assert np.array_equal(db, dd) and np.allclose(db, db_ref)


def test_carried_rates(pair):
    """A rigid translation carries as itself, and a uniform stretch rate as the rate of
    the band's own uniform state."""
    disc, band = pair
    sh = np.zeros(3)
    yd, dd, Lz = disc.uniform_state(1.0, 1.02, sh)
    u = np.array([0.003, -0.002, 0.005])
    _, _, vb, vdb = band.carry_state(disc, yd, dd, np.tile(u, (len(yd), 1)),
                                     np.zeros_like(dd), Lz=Lz)
    assert np.abs(vb - u).max() < 1e-9 and not vdb.any()
    e = 1e-4  # d/dlam_z of the uniform states, both tubes (the cell grows with them)
    vd = (disc.uniform_state(1.0, 1.02 + e, sh)[0] - disc.uniform_state(1.0, 1.02 - e, sh)[0]) / (2 * e)
    ref = (band.uniform_state(1.0, 1.02 + e, sh)[0] - band.uniform_state(1.0, 1.02 - e, sh)[0]) / (2 * e)
    _, _, vb, _ = band.carry_state(disc, yd, dd, vd, np.zeros_like(dd), Lz=Lz)
    assert np.abs(vb - ref).max() < 1e-9 * np.abs(ref).max()


def test_carry_state_bad_input(pair):
    disc, band = pair
    yb, db, Lz = band.uniform_state(1.0, 1.0, np.zeros(3))
    with pytest.raises(ValueError, match="not inside"):
        disc.carry_state(band, yb, db, Lz=Lz)
    other = DCBRDefectTube(5, 5, 60.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)
    yd, dd, _ = disc.uniform_state(1.0, 1.0, np.zeros(3))
    with pytest.raises(ValueError, match="same lattice"):
        other.carry_state(disc, yd, dd)


def _small(region_grows: bool):
    disc = DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4, r_atomistic=4.0, region="disc")
    kw = {"grow": DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=4, r_atomistic=5.0)} \
        if region_grows else {}
    return dynamic_tension(disc, **SMALL, **kw)


def test_grown_run_is_the_disc_run_until_the_crack_starts():
    """Up to the sample at which the disc's first bond breaks the run is the disc's own, bit
    for bit; there it moves to the band (which holds the crack's path) and goes on to
    failure; the first damage is the switch's sample."""
    a, b = _small(False), _small(True)
    g = b["grown_at"]
    assert a["grown_at"] is None and g is not None
    assert b["region_free_atoms"][0] < b["region_free_atoms"][1]
    k = int(np.searchsorted(b["curve"]["time_ps"], g["time_ps"])) + 1  # samples up to it
    for key in ("stress_GPa", "extensometer_strain"):
        assert np.array_equal(a["curve"][key][:k], b["curve"][key][:k])
    assert b["first_damage"]["strain"] == g["strain"]
    assert b["positions"].shape[0] > a["positions"].shape[0]
    s = np.asarray(b["curve"]["stress_GPa"])
    assert abs(s[k] - s[k - 1]) < 0.1 * s[k - 1]  # no jump at the switch
    assert s[-1] < 0.2 * s.max()  # failed and ran to the end


def test_grow_bad_input(pair):
    disc, band = pair
    pristine = DCBRDefectTube(6, 6, 60.0, coarsening=2.0, vacancy=0)
    with pytest.raises(ValueError, match="same lattice and vacancy"):
        dynamic_tension(pristine, grow=band, **SMALL)


def test_killed_after_the_switch_resumes_bit_for_bit(tmp_path):
    """Killed after the region grew (the second simulation's checkpoint) and resumed."""
    from upscale.experiments.kill_resume import dcbr_vacancy_kill_resume

    seed = int(np.random.SeedSequence().entropy % 2**32)
    r = dcbr_vacancy_kill_resume(tmp_path, tube="small-grow", every=50, seed=seed,
                                 after_growth=True)
    assert r["grown_at_step"] is not None and r["killed_at_step"] > r["grown_at_step"], r
    assert r["bit_identical"], (seed, r)


def test_scene_grow_needs_clamped_grips():
    from upscale.experiments.scenes.tube_tension import dynamic_scene

    with pytest.raises(ValueError, match="grow='band' with grips='bands'"):
        dynamic_scene(6, 6, 60.0, 2.0, {}, grips="bands", grow="band")
