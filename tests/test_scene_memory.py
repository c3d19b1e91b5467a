"""Memory per bond in the scenes' ``Result.meta`` (issue on heavy scenes, item 2)."""
import numpy as np

from upscale import experiments
from upscale.engine import bonds_crossing_segment
from upscale.experiments.registry import QUICK
from upscale.experiments.scenes.plate import CRACK, PlateScene


def test_plate_reports_its_bonds_and_bytes_per_bond():
    r = experiments.plate(**QUICK["plate"])
    mem = r.meta["memory"]
    assert mem["bonds"] == r.figures["bonds"]
    b = mem["bytes_per_bond"]
    # the PMB family and model keep 32-bit partners and per-particle factors only; the
    # state is one byte of `intact` per bond (issue target: at most 16 plus the state)
    assert b["bond"] + b["particle"] <= 16.0 and b["state"] == 1.0
    assert 0.0 < mem["peak_rss_GB"] <= r.meta["peak_rss_GB"]


def test_plate_precrack_by_blocks_equals_the_whole_family_test():
    sc = PlateScene(40, model="pmb")
    f = sc.family
    whole = bonds_crossing_segment(sc.system.x0, (-CRACK / 2, 0.0), (CRACK / 2, 0.0))(
        f.owner, f.neighbors, f.xi)
    assert whole.any() and np.array_equal(whole, sc.precrack)


def test_a_plate_that_does_not_fit_is_refused_before_it_builds(monkeypatch):
    import pytest

    from upscale.engine import memory

    monkeypatch.setattr(memory, "available_gb", lambda: 1.0)
    with pytest.raises(MemoryError, match=r"n=20000 .* needs about 538 GB .* 1 GB available; "
                                          r"the largest that fits: n=862"):
        PlateScene(20000, model="pmb")


def test_lattice_bonds_counts_the_points_within_the_horizon():
    from upscale.engine.memory import lattice_bonds

    assert lattice_bonds(3.015, 2) == 28 and lattice_bonds(1.0, 2) == 4
    assert lattice_bonds(1.0, 3) == 6 and lattice_bonds(1.5, 3) == 18


def test_an_scb_that_does_not_fit_is_refused_before_it_builds(monkeypatch):
    import pytest

    from upscale.engine import memory
    from upscale.experiments.scenes.scb import SCBScene

    monkeypatch.setattr(memory, "available_gb", lambda: 4.0)
    with pytest.raises(MemoryError, match=r"dx=0.0001 m \(392728 particles\) needs about 14.1 GB"
                                          r".* the largest that fits: dx=0.000188 m"):
        SCBScene(0.0, dx=1e-4)


def test_a_branching_plate_that_does_not_fit_is_refused_before_it_builds(monkeypatch):
    import pytest

    from upscale.engine import memory
    from upscale.experiments.scenes.tipd_branching import simulate

    monkeypatch.setattr(memory, "available_gb", lambda: 2.0)
    with pytest.raises(MemoryError, match=r"3200 x 1280 particles\) needs about 4.59 GB"):
        simulate("tipd", dx=3.125e-5)
