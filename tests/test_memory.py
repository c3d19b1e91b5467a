"""What the families and the pair models keep (``upscale.engine.memory``): the counter
itself, and the per-bond storage of PMB, LPS, Ti-PD, NOSB and CPD against issue 53's
target (at most 16 bytes per directed bond besides the bond state)."""
import types

import numpy as np
import pytest

from upscale.engine import State, build_family, square_lattice
from upscale.engine.memory import bytes_per_bond, kept_nbytes


def test_counter_charges_each_buffer_once_and_skips_excluded():
    a = np.zeros(1000)
    shared = np.zeros(50)
    obj = types.SimpleNamespace(a=a, view=a[10:20], pair=(a.reshape(10, 100), np.ones(3, np.int32)),
                                d={"x": shared}, own=types.SimpleNamespace(b=np.zeros(7, np.uint8)))
    assert kept_nbytes(obj) == 8000 + 12 + 400 + 7
    assert kept_nbytes(obj, exclude=(types.SimpleNamespace(s=shared),)) == 8000 + 12 + 7


@pytest.mark.parametrize("name", ["pmb", "lps", "tipd", "nosb", "cpd"])
def test_pair_models_keep_at_most_16_bytes_per_bond(name):
    from upscale.models.bond_based import PMB
    from upscale.models.correspondence import Correspondence
    from upscale.models.cpd import CPD
    from upscale.models.state_based import LPS
    from upscale.models.tipd import TiPD

    E, nu, spacing = 70e9, 1.0 / 3.0, 1e-3
    s = square_lattice(30, 30, spacing, thickness=spacing)
    horizon = 3.015 * spacing
    fam = build_family(s, horizon)
    m = {"pmb": lambda: PMB(E=E, nu=nu, Gc=8.0), "lps": lambda: LPS(E=E, nu=nu, Gc=8.0),
         "tipd": lambda: TiPD(E=E, nu=nu), "nosb": lambda: Correspondence(E=E, nu=nu),
         "cpd": lambda: CPD(horizon=horizon, dim=2, E=E, nu=nu)}[name]()
    m.prepare(s, fam)
    st = State.reference(s.x0, fam.nb)
    m.init_state(st)
    m.force(st)
    b = bytes_per_bond(s, fam, [m], st)
    assert b["state"] == 1.0                     # the engine's bool per bond
    assert b["bond"] <= 16.0, b
    # the family alone: row pointers and 32-bit partners
    assert fam.neighbors.dtype == np.int32 and fam.nbytes() == fam.offsets.nbytes + 4 * fam.nb
