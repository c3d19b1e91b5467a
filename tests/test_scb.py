"""SCB scene: bad input gives one-line errors naming the value; the geometry is the one of
seed 004 sec. 6.6."""
import numpy as np
import pytest

from upscale.experiments.scb import SCBScene


@pytest.mark.parametrize("kw,match", [
    ({"alpha_deg": 90.0}, "alpha"), ({"alpha_deg": -1.0}, "alpha"),
    ({"a_over_R": 1.0}, "a/R"), ({"a_over_R": 0.0}, "a/R"),
    ({"dx": 5e-3}, "too coarse"), ({"r_s": 0.0}, "r_s"), ({"r_s": -1e-3}, "r_s"),
    ({"supports": "glued"}, "supports"), ({"nu": 0.5}, "Poisson"),
])
def test_bad_input(kw, match):
    kw = {"alpha_deg": 0.0, "dx": 3e-3, **kw}
    alpha = kw.pop("alpha_deg")
    with pytest.raises(ValueError, match=match):
        SCBScene(alpha, **kw)


def test_geometry():
    sc = SCBScene(30.0, dx=3e-3)
    x = sc.system.x0
    assert np.all(x[:, 0] ** 2 + x[:, 1] ** 2 <= 0.05 ** 2) and np.all(x[:, 1] > 0)
    assert np.allclose(sc.tip, 0.015 * np.array([np.sin(np.radians(30)), np.cos(np.radians(30))]))
    # no intact bond crosses the pre-crack
    from upscale.engine import bonds_crossing_segment

    fam = sc.family
    assert not bonds_crossing_segment(x, (0, 0), sc.tip)(fam.owner, fam.neighbors, fam.xi).any()
    # patches: 3 dx boxes at the load point and at x = +-S
    assert np.all(np.abs(x[sc.load, 0]) <= 1.5 * 3e-3 + 1e-12)
    assert np.all(np.abs(np.abs(x[sc.support, 0]) - 0.43 * 0.05) <= 1.5 * 3e-3 + 1e-12)
    assert sc.fixed[sc.support, 1].all() and not sc.fixed[sc.support, 0].any()   # rollers
