"""The Tersoff engine model: energy and forces equal the project's Tersoff calculator and
LAMMPS ``pair_style tersoff`` (same file, step cutoff), through the engine's body assembly."""
import numpy as np
import pytest
from ase import Atoms

from potentials.lammps_runtime import lammps_potential_path
from potentials.tersoff import Tersoff, write_step_cutoff_file
from upscale import models
from upscale.build import swcnt, vacancy
from upscale.engine.bodies import Body, assemble
from upscale.engine.state import State
from upscale.engine.system import ParticleSystem
from upscale.models.tersoff import TersoffModel, atom_damage, initial_bonds
from upscale.experiments.lammps import evaluate as lammps_evaluate
from upscale.experiments.lammps import tersoff_pair_lines as lammps_tersoff_lines


def _tube(seed=0):
    a = vacancy(swcnt(10, 10, 12.0), n=4)
    rng = np.random.default_rng(seed)
    x = a.get_positions() + rng.normal(scale=0.03, size=(len(a), 3))
    x[:, 2] *= 1.04  # stretched: bonds spread over 1.3-1.6 Å
    return x


def _model_eval(x):
    sys_ = ParticleSystem(x, 1.0, 12.011)
    m = TersoffModel("BNC.tersoff", step_cutoff=True)
    m.prepare(sys_, None)
    st = State.reference(x, 0)
    return m.energy(st), m.force(st), m.site_energies(st)


def test_registered():
    assert models.get("tersoff") is TersoffModel


def test_equals_project_calculator():
    x = _tube()
    e, f, en = _model_eval(x)
    a = Atoms("C" * len(x), positions=x, pbc=False)
    a.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"], step_cutoff=True)
    e_ref = a.get_potential_energy()
    assert abs(e - e_ref) <= 1e-12 * abs(e_ref)
    assert np.abs(f - a.get_forces()).max() <= 1e-12 * np.abs(f).max()
    assert abs(en.sum() - e) <= 1e-12 * abs(e)


@pytest.mark.lammps
def test_equals_lammps(tmp_path):
    x = _tube(1)
    e, f, en = _model_eval(x)
    a = Atoms("C" * len(x), positions=x + 20.0, cell=np.diag([60.0, 60.0, 60.0]), pbc=False)
    path = write_step_cutoff_file(lammps_potential_path("BNC.tersoff"), tmp_path / "s.tersoff")
    ref = lammps_evaluate(a, lammps_tersoff_lines(path, ["C"]))
    assert abs(e - ref["energy"]) <= 1e-10 * abs(ref["energy"])
    assert np.abs(f - ref["forces"]).max() <= 1e-10 * np.abs(ref["forces"]).max()
    assert np.abs(en - ref["energies"]).max() <= 1e-10 * np.abs(ref["energies"]).max()


def test_in_an_assembly_acts_within_each_body_only():
    x = _tube(2)
    e1, f1, _ = _model_eval(x)
    y = x.copy()
    y[:, 0] += 1.0  # overlapping copy: only a per-body model gives twice the energy
    bodies = [Body(ParticleSystem(p, 1.0, 12.011), None, [TersoffModel()], name=f"t{k}")
              for k, p in enumerate((x, y))]
    sc = assemble(bodies)
    for m in sc.models:
        m.prepare(sc.system)
    st = sc.reference_state()
    e = sum(m.energy(st) for m in sc.models)
    f = sum(m.force(st) for m in sc.models)
    assert abs(e - 2 * e1) <= 1e-12 * abs(e)
    assert np.abs(f[:len(x)] - f1).max() <= 1e-10


def test_forces_are_minus_gradient():
    x = _tube(3)
    sys_ = ParticleSystem(x, 1.0, 12.011)
    m = TersoffModel()
    m.prepare(sys_, None)
    st = State.reference(x, 0)
    f = m.force(st)
    h = 1e-6
    for i, c in ((0, 0), (17, 2), (101, 1)):
        st.y[i, c] += h
        ep = m.energy(st)
        st.y[i, c] -= 2 * h
        em = m.energy(st)
        st.y[i, c] += h
        assert abs(-(ep - em) / (2 * h) - f[i, c]) < 1e-6


def test_damage_counts_broken_bonds():
    x = swcnt(10, 10, 12.0).get_positions()
    b = initial_bonds(x)
    assert np.all(np.bincount(b.ravel()) <= 3)
    y = x.copy()
    y[y[:, 2] > 6.0, 2] += 1.0  # every axial bond across z = 6 stretched beyond 2.1 Å
    mu = atom_damage(y, b)
    assert mu.max() > 0.3 and mu.min() == 0.0
    assert np.all(atom_damage(x, b) == 0.0)


def test_bad_input():
    with pytest.raises(ValueError, match="skin"):
        TersoffModel(skin=-1.0)
    m = TersoffModel(types=[0, 1])
    with pytest.raises(ValueError, match="types"):
        m.prepare(ParticleSystem(np.zeros((3, 3)) + np.arange(3)[:, None], 1.0, 12.0), None)
