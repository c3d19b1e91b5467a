"""The lattice-stability rule's periodic piece, mapped by a particle's q, is the particle
lattice itself: the same energy per atom as the cell (:class:`upscale.models.dcbr.cell.
TubeCell`), at the relaxed uniform state no force on its atoms and a stable Hessian, for
tubes whose ASE atom order starts the 2-colouring on either sublattice ((10,5) and (7,13)
on B: with the labels swapped the piece sat off the cell's energy and equilibrium, and the
rule called a stable (10,5) lattice unstable)."""
import numpy as np
import pytest

from upscale.constants import CARBON_MASS_AMU
from upscale.engine.simulation import Simulation
from upscale.engine.system import ParticleSystem
from upscale.models.dcbr.cell import TubeCell, tersoff_row
from upscale.models.dcbr.ghost import uniform_lattice
from upscale.models.dcbr.stability import LatticeStability
from upscale.models.tersoff import TersoffModel


@pytest.mark.parametrize("nm", [(10, 5), (7, 13), (12, 6), (10, 10)])
def test_mapped_piece_is_the_cell_lattice_at_equilibrium(nm):
    P = tersoff_row()
    cell, rule = TubeCell.build(*nm), LatticeStability(*nm, P)
    lam_z = 1.09
    lt, sh = uniform_lattice(cell, P, lam_z)
    q = np.array([lt, 0.0, lam_z, *sh])
    x = rule.positions(q)
    model = TersoffModel("BNC.tersoff", period_z=lam_z * rule.Lz)
    sim = Simulation(ParticleSystem(x, 1.0, CARBON_MASS_AMU, spacing=1.42, units="atomic"),
                     None, model)
    e_cell, _ = cell.energy(q, P)
    assert model.energy(sim.state) / len(x) == pytest.approx(e_cell, abs=1e-9)
    f = np.zeros_like(x)
    model.add_force(sim.state, f)
    assert np.abs(f).max() < 1e-6
    assert rule.stable(q)
