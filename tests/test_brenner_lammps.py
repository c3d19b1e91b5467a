"""Brenner potential II equals LAMMPS ``pair_style tersoff`` with the equivalent line.

Brenner II has delta = 1/2, so its bond order (1 + zeta)^(-1/2) is LAMMPS tersoff's with
n = beta = 1; gamma = a0, c = c0, d = d0, costheta0 = -1, A, lambda1, B, lambda2 from
D_e, S, beta, r_e, and R, D the midpoint and half-width of [R1, R2] (see
:func:`potentials.brenner.lammps_tersoff_line`). The conjugation term F_ij is zero in these
structures (integer coordinations, graphitic or diamond), so ``conjugation=True`` is
compared as is; structures with bonds in the switching region are compared with
``conjugation=False``. Set I (delta = 0.80469) has no such LAMMPS form.
"""
import numpy as np
import pytest
from ase.build import bulk, nanotube
from ase.neighborlist import neighbor_list

from brenner_lj_lammps import lammps_reference
from potentials.brenner import Brenner, lammps_tersoff_line
from test_brenner import rect_graphene

pytestmark = pytest.mark.lammps


def _structures():
    t10 = nanotube(10, 10, length=3)
    t10.rattle(0.02, seed=11)
    g = rect_graphene(nx=4, ny=3)
    g.rattle(0.03, seed=12)
    d = bulk("C", "diamond", a=3.57, cubic=True).repeat(2)
    d.rattle(0.03, seed=13)
    t126 = nanotube(12, 6, length=1)
    t126.set_cell(t126.cell.array * [1, 1, 1.04], scale_atoms=True)  # 4 % axial strain
    t126.rattle(0.02, seed=14)
    # bonds in the switching region 1.7 < r < 2.0
    dsw = bulk("C", "diamond", a=3.57, cubic=True).repeat(2)
    dsw.rattle(0.06, seed=2)
    s = rect_graphene(a=2.46 * 1.22, nx=3, ny=2)
    s.rattle(0.03, seed=15)
    return {"tube_10_10": t10, "graphene": g, "diamond": d, "tube_12_6_strained": t126,
            "diamond_switching": dsw, "graphene_stretched": s}


STRUCTS = _structures()


def _max_bond(a):
    d = neighbor_list("d", a, 2.0)
    return d.max() if len(d) else 0.0


@pytest.fixture(scope="module")
def tersoff_files(tmp_path_factory):
    p = tmp_path_factory.mktemp("brenner_lmp")
    out = {}
    for step in (False, True):
        f = p / f"brennerII_step{int(step)}.tersoff"
        f.write_text("# Brenner 1990 potential II as a LAMMPS tersoff entry\n"
                     + lammps_tersoff_line("II", step_cutoff=step) + "\n")
        out[step] = str(f)
    return out


@pytest.mark.parametrize("step", [False, True])
@pytest.mark.parametrize("name", list(STRUCTS))
def test_brenner_II_equals_lammps_tersoff(name, step, tersoff_files):
    atoms = STRUCTS[name].copy()
    switching = _max_bond(atoms) > 1.7
    conj = not switching
    if name == "graphene_stretched" and not step:
        conj = False
    calc = Brenner(parameters="II", conjugation=conj, step_cutoff=step)
    atoms.calc = calc
    E = atoms.get_potential_energy()
    F = atoms.get_forces()
    W = calc.get_virial()
    El, Fl, Wl = lammps_reference(atoms, "tersoff", [f"* * {tersoff_files[step]} C"])
    assert abs(E - El) <= 1e-10 * abs(El)
    assert np.abs(F - Fl).max() <= 1e-8
    assert np.abs(W - Wl).max() <= 1e-8 * np.abs(Wl).max()


def test_set_I_has_no_tersoff_form():
    with pytest.raises(ValueError, match="cannot express"):
        lammps_tersoff_line("I")


def test_conjugation_is_zero_in_the_compared_structures():
    for name in ("tube_10_10", "graphene", "diamond", "tube_12_6_strained"):
        a = STRUCTS[name]
        assert _max_bond(a) < 1.7
        e = []
        for conj in (True, False):
            b = a.copy()
            b.calc = Brenner(parameters="II", conjugation=conj)
            e.append(b.get_potential_energy())
        assert e[0] == e[1]
