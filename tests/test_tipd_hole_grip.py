"""Grip layers of the plate-with-hole scene: width in horizons, default by model."""
import numpy as np
import pytest

from upscale.experiments.scenes.tipd_hole import L_PLATE, hole, hole_body


@pytest.mark.parametrize("grip, rows", [(1.0, 3), (2.0, 6)])
def test_grip_rows(grip, rows):
    dx = 2e-3
    s, lg, rg = hole_body(dx, 3.0, grip=grip)
    xl = np.unique(np.round(s.x0[lg, 0] / dx, 6))
    assert xl.size == rows and np.isclose(xl.min() * dx, -L_PLATE / 2 - (rows - 0.5) * dx)
    assert lg.sum() == rg.sum()


def test_grip_bad_width():
    with pytest.raises(ValueError, match="grip"):
        hole_body(2e-3, 3.0, grip=0.5)


def test_grip_default_follows_surface_correction():
    a = hole("tipd", material="iso", dx=5e-3, surface="none")
    b = hole("tipd", material="iso", dx=5e-3, surface="correspondence")
    assert a["grip_horizons"] == 1.0 and b["grip_horizons"] == 2.0
    assert b["particles"] > a["particles"]
