"""Tersoff: exact against LAMMPS ``pair_style tersoff`` with the same files, invariants,
central finite differences, the step cutoff, and bad input."""
import numpy as np
import pytest
from ase import Atoms
from ase.build import bulk, graphene, nanotube
from ase.calculators.calculator import PropertyNotImplementedError

from potentials.calculator import OverlappingAtomsError
from potentials.lammps_runtime import lammps_potential_path
from potentials.tersoff import (Tersoff, TersoffFileError, read_tersoff_file,
                                write_step_cutoff_file)
from upscale.experiments.lammps import errors as compare
from upscale.experiments.lammps import evaluate as lammps_evaluate
from upscale.experiments.lammps import evaluate_calculator as ours_evaluate
from upscale.experiments.lammps import tersoff_pair_lines as lammps_tersoff_lines


def tersoff_structures() -> dict:
    """The four test structures: a (10,10) tube, rattled graphene, diamond and a strained,
    rattled (12,6) tube (a few hundred atoms each)."""
    out = {}
    t = nanotube(10, 10, length=4, bond=1.42, vacuum=None)
    t.pbc = [False, False, True]
    out["tube(10,10)"] = t
    g = graphene(size=(6, 6, 1), a=2.46, vacuum=None)
    g.pbc = [True, True, False]
    g.rattle(0.05, seed=11)
    out["graphene rattled"] = g
    d = bulk("C", "diamond", a=3.5668, cubic=True).repeat((3, 3, 3))
    out["diamond"] = d
    s = nanotube(12, 6, length=1, bond=1.42)
    s.pbc = [False, False, True]
    s.set_cell(s.cell.array * [1.0, 1.0, 1.12], scale_atoms=True)  # 12 % axial strain
    s.rattle(0.08, seed=12)
    out["tube(12,6) strained rattled"] = s
    return out


CARBON_FILES = ["BNC.tersoff", "SiC.tersoff"]  # Lindsay-Broido 2010, Tersoff 1989 carbon
STRUCTURES = tersoff_structures()


def _check_exact(ours, ref, e_tol=1e-10, f_tol=1e-8, w_tol=1e-8):
    err = compare(ours, ref)
    assert err["energy_rel_err"] < e_tol, err
    assert err["force_max_abs_err_eV_per_A"] < f_tol, err
    assert err["virial_rel_err"] < w_tol, err
    assert err["energies_max_abs_err_eV"] < 1e-8, err
    return err


def _types(atoms, elements):
    return [elements.index(s) + 1 for s in atoms.get_chemical_symbols()]


# -- exactness against LAMMPS ---------------------------------------------------------------
@pytest.mark.lammps
@pytest.mark.parametrize("fname", CARBON_FILES)
@pytest.mark.parametrize("name", list(STRUCTURES))
def test_carbon_exact_vs_lammps(fname, name):
    atoms = STRUCTURES[name]
    ours = ours_evaluate(atoms, Tersoff.from_lammps(fname, elements=["C"]))
    ref = lammps_evaluate(atoms, lammps_tersoff_lines(lammps_potential_path(fname), ["C"]))
    _check_exact(ours, ref)


@pytest.mark.lammps
@pytest.mark.parametrize("fname", CARBON_FILES)
@pytest.mark.parametrize("name", list(STRUCTURES))
def test_step_cutoff_exact_vs_lammps_modified_file(fname, name, tmp_path):
    atoms = STRUCTURES[name]
    calc = Tersoff.from_lammps(fname, elements=["C"], step_cutoff=True)
    # no distance within the 2e-5 A band where LAMMPS's narrowed switching acts
    a = atoms.copy()
    a.calc = calc
    a.get_potential_energy()
    d = np.linalg.norm(calc.neighbour_list.bond_vectors(a.positions), axis=1)
    assert np.all(np.abs(d - 2.1) > 1e-4)
    f = write_step_cutoff_file(fname, tmp_path / f"{fname}.step")
    ours = ours_evaluate(atoms, calc)
    ref = lammps_evaluate(atoms, lammps_tersoff_lines(f, ["C"]))
    _check_exact(ours, ref)


def test_step_cutoff_changes_only_the_switching_region():
    smooth = Tersoff.from_lammps("BNC.tersoff", elements=["C"])
    step = Tersoff.from_lammps("BNC.tersoff", elements=["C"], step_cutoff=True)
    tube = STRUCTURES["tube(10,10)"]  # all bonds short: identical
    assert ours_evaluate(tube, smooth)["energy"] == pytest.approx(
        ours_evaluate(tube, step)["energy"], rel=1e-14)
    strained = STRUCTURES["tube(12,6) strained rattled"]  # bonds in [1.8, 2.1]: differ
    assert abs(ours_evaluate(strained, smooth)["energy"]
               - ours_evaluate(strained, step)["energy"]) > 1e-3
    # dimer: a step at R + D = 2.1 A
    for r, inside in [(2.0999, True), (2.1001, False)]:
        d = Atoms("C2", positions=[[0, 0, 0], [r, 0, 0]])
        d.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"], step_cutoff=True)
        assert (d.get_potential_energy() != 0.0) == inside
        assert (np.abs(d.get_forces()).max() > 0) == inside


def test_step_cutoff_file_keeps_outer_cutoff(tmp_path):
    f = write_step_cutoff_file("SiC.tersoff", tmp_path / "SiC.step.tersoff")
    old = read_tersoff_file("SiC.tersoff")
    new = read_tersoff_file(f)
    assert new.elements == old.elements
    np.testing.assert_allclose(new.raw[:, 10] + new.raw[:, 11], old.raw[:, 10] + old.raw[:, 11],
                               rtol=0, atol=1e-14)
    assert np.all(new.raw[:, 11] == 1e-5)
    keep = [i for i in range(14) if i not in (10, 11)]
    assert np.array_equal(new.raw[:, keep], old.raw[:, keep])


@pytest.mark.lammps
def test_multi_element_exact_vs_lammps():
    """SiC.tersoff with Si and C on rattled 3C-SiC, BNC.tersoff on a B/N/C sheet."""
    sic = bulk("SiC", "zincblende", a=4.36, cubic=True).repeat(2)
    sic.rattle(0.1, seed=3)
    bnc = graphene(formula="BN", size=(6, 6, 1), a=2.5, vacuum=None)
    bnc.pbc = [True, True, False]
    sym = np.array(bnc.get_chemical_symbols())
    sym[[0, 7, 20, 33]] = "C"
    bnc.set_chemical_symbols(sym)
    bnc.rattle(0.06, seed=4)
    for fname, atoms, elements in [("SiC.tersoff", sic, ["Si", "C"]),
                                   ("BNC.tersoff", bnc, ["B", "N", "C"])]:
        ours = ours_evaluate(atoms, Tersoff.from_lammps(fname, elements=elements))
        ref = lammps_evaluate(atoms, lammps_tersoff_lines(lammps_potential_path(fname),
                                                          elements),
                              types=_types(atoms, elements))
        _check_exact(ours, ref)


@pytest.mark.lammps
def test_asymptotic_bond_order_branches_vs_lammps():
    """Si.tersoff (Tersoff 1988 Si, n = 22.956, lambda3 != 0): beta*zeta spans all the
    branches of LAMMPS's b_ij (thresholds c1..c4 are 4.2, 1.9, 0.53, 0.24)."""
    si = bulk("Si", "diamond", a=5.43, cubic=True).repeat(2)
    si.rattle(0.25, seed=5)
    si.positions[:8] *= 0.93  # a denser corner: more neighbours, larger zeta
    calc = Tersoff.from_lammps("Si.tersoff", elements=["Si"])
    ours = ours_evaluate(si, calc)
    ref = lammps_evaluate(si, lammps_tersoff_lines(lammps_potential_path("Si.tersoff"), ["Si"]))
    _check_exact(ours, ref)
    hit = _bond_order_branches(si, calc)
    assert hit >= {"c1", "c2", "mid", "c3"}, hit


@pytest.mark.lammps
@pytest.mark.parametrize("fname", CARBON_FILES)
def test_dimer_and_chain_vs_lammps(fname):
    """zeta = 0 (a dimer: b_ij = 1 by LAMMPS's small-argument branch) and a bent chain whose
    end bonds sit in the switching region, in a box without periodicity."""
    a = Atoms("C2C3", positions=[[0, 0, 0], [1.3, 0, 0],
                                 [10, 0, 0], [11.4, 0.1, 0], [12.3, 1.8, 0.2]])
    ours = ours_evaluate(a, Tersoff.from_lammps(fname, elements=["C"]))
    ref = lammps_evaluate(a, lammps_tersoff_lines(lammps_potential_path(fname), ["C"]))
    _check_exact(ours, ref)


def _bond_order_branches(atoms, calc):
    """Which regimes of beta*zeta the bonds of ``atoms`` fall into (pure numpy zeta)."""
    from ase.neighborlist import neighbor_list

    p = calc.tersoff.entry("Si", "Si", "Si")
    cut = p["R"] + p["D"]
    i, j, D = neighbor_list("ijD", atoms, cut)
    n, beta = p["n"], p["beta"]
    c1 = (2 * n * 1e-16) ** (-1 / n)
    c2 = (2 * n * 1e-8) ** (-1 / n)
    out = set()
    r = np.linalg.norm(D, axis=1)
    for b in range(len(i)):
        ks = np.nonzero((i == i[b]) & (np.arange(len(i)) != b))[0]
        z = 0.0
        for k in ks:
            cs = D[b] @ D[k] / (r[b] * r[k])
            fc = (1.0 if r[k] < p["R"] - p["D"]
                  else 0.5 * (1 - np.sin(np.pi / 2 * (r[k] - p["R"]) / p["D"])))
            csq, dsq = p["c"] ** 2, p["d"] ** 2
            g = 1 + csq / dsq - csq / (dsq + (p["costheta0"] - cs) ** 2)
            z += fc * g * np.exp((p["lambda3"] * (r[b] - r[k])) ** 3)
        t = beta * z
        out.add("c1" if t > c1 else "c2" if t > c2 else "zero" if t < 1 / c1 else
                "c3" if t < 1 / c2 else "mid")
    return out


@pytest.mark.lammps
def test_general_triclinic_cell_vs_lammps():
    """A primitive fcc diamond cell (no vector along x): LAMMPS sees it rotated; energy,
    forces and virial are compared back in the frame of the atoms."""
    a = bulk("C", "diamond", a=3.6).repeat((3, 4, 3))
    a.rattle(0.07, seed=6)
    a.set_cell(a.cell.array @ [[1.0, 0.02, 0.0], [0.0, 1.0, 0.01], [0.03, 0.0, 1.0]],
               scale_atoms=True)
    ours = ours_evaluate(a, Tersoff.from_lammps("BNC.tersoff", elements=["C"]))
    ref = lammps_evaluate(a, lammps_tersoff_lines(lammps_potential_path("BNC.tersoff"), ["C"]))
    _check_exact(ours, ref)
    assert abs(ours["virial"][0, 1]) > 1e-3  # shear: off-diagonal terms are compared


SYNTHETIC = """\
# made-up numbers for C and Si, every triplet different: checks the (i j k) / (i j j) look-up
# entries may continue over lines, with comments anywhere
C C C 1 1.0 3.0 1.2 0.9 -0.2 0.9 0.7 2.2 430.0 1.95 0.15 3.5 1393.6
C C Si 3 1.1 1.5 1.3 0.8 -0.3 0.9 0.7 2.2 430.0   # continued
      2.00 0.20 3.5 1393.6
C Si C 1 0.9 2.0 1.0 1.0 0.1 1.1 0.5 2.1 400.0 1.95 0.15 3.4 1300.0
C Si Si 1 1.2 0.5 1.1 0.7 0.0 1.1 0.5 2.1 400.0 2.00 0.20 3.4 1300.0
Si C C 3 0.8 1.0 0.9 1.2 -0.5 1.3 0.6 2.0 380.0 2.00 0.20 3.4 1300.0
Si C Si 1 1.0 2.5 1.4 0.9 0.3 1.3 0.6 2.0 380.0 2.10 0.10 3.4 1300.0
Si Si C 3 1.3 0.7 1.5 1.1 -0.1 0.8 0.9 2.3 450.0 2.00 0.20 3.6 1500.0
Si Si Si 1 0.7 4.0 0.8 0.6 0.2 0.8 0.9 2.3 450.0 2.10 0.10 3.6 1500.0
"""


@pytest.mark.lammps
def test_synthetic_two_element_file_vs_lammps(tmp_path):
    f = tmp_path / "XY.tersoff"
    f.write_text(SYNTHETIC)
    a = bulk("C", "diamond", a=3.6, cubic=True).repeat((2, 2, 2))
    a.rattle(0.12, seed=9)
    a.numbers[np.random.default_rng(2).random(len(a)) < 0.4] = 14
    calc = Tersoff.from_lammps(f, elements=["C", "Si"])
    ours = ours_evaluate(a, calc)
    ref = lammps_evaluate(a, lammps_tersoff_lines(f, ["C", "Si"]), types=_types(a, ["C", "Si"]))
    _check_exact(ours, ref)


# -- invariants -----------------------------------------------------------------------------
@pytest.mark.parametrize("fname", CARBON_FILES)
def test_perfect_lattices(fname):
    """Equal per-atom energies and zero net force in diamond, a sheet and a tube; zero force
    on every atom of diamond."""
    diamond = bulk("C", "diamond", a=3.6, cubic=True).repeat(2)
    sheet = graphene(size=(3, 3, 1), vacuum=None)
    sheet.pbc = [True, True, False]
    tube = nanotube(8, 8, length=3)
    for a in (diamond, sheet, tube):
        a.calc = Tersoff.from_lammps(fname, elements=["C"])
        e = a.get_potential_energies()
        np.testing.assert_allclose(e, e.mean(), rtol=0, atol=1e-11)
        assert e.sum() == pytest.approx(a.get_potential_energy(), rel=1e-14)
        np.testing.assert_allclose(a.get_forces().sum(axis=0), 0, atol=1e-10)
    assert np.abs(diamond.get_forces()).max() < 1e-11


def test_zero_force_by_symmetry_in_tube_and_sheet():
    """Every atom of a perfect sheet or tube is equivalent: zero force in the sheet; in an
    ideal rolled (10,0) tube the same radial force on every atom and axial forces of equal
    size and opposite sign on the two sublattices (related by a C2 axis normal to the tube)."""
    g = graphene(size=(4, 4, 1), vacuum=None)
    g.pbc = [True, True, False]
    g.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"])
    assert np.abs(g.get_forces()).max() < 1e-11
    t = nanotube(10, 0, length=3)
    t.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"])
    f = t.get_forces()
    xy = t.positions[:, :2] - t.positions[:, :2].mean(axis=0)
    radial = np.sum(f[:, :2] * xy, axis=1) / np.linalg.norm(xy, axis=1)
    np.testing.assert_allclose(np.linalg.norm(f[:, :2], axis=1), np.abs(radial), atol=1e-11)
    np.testing.assert_allclose(radial, radial[0], atol=1e-11)
    np.testing.assert_allclose(np.abs(f[:, 2]), np.abs(f[0, 2]), atol=1e-11)
    assert abs(f[:, 2].sum()) < 1e-10


def test_rigid_motions_and_force_sum():
    a = STRUCTURES["tube(12,6) strained rattled"].copy()
    a.pbc = False  # a free cluster can be rotated arbitrarily
    a.cell = np.zeros((3, 3))
    a.calc = Tersoff.from_lammps("SiC.tersoff", elements=["C"])
    e0 = a.get_potential_energy()
    f0 = a.get_forces()
    np.testing.assert_allclose(f0.sum(axis=0), 0, atol=1e-10)
    # the torque vanishes for a free cluster
    np.testing.assert_allclose(np.cross(a.positions, f0).sum(axis=0), 0, atol=1e-9)
    b = a.copy()
    b.calc = Tersoff.from_lammps("SiC.tersoff", elements=["C"])
    b.positions += [3.3, -7.1, 100.2]
    assert b.get_potential_energy() == pytest.approx(e0, rel=1e-13)
    b.rotate(37.0, (1, 2, 0.5), center=(1, 2, 3))
    b.rotate(-121.0, "z")
    assert b.get_potential_energy() == pytest.approx(e0, rel=1e-13)
    # forces rotate with the atoms: compare |f|
    np.testing.assert_allclose(np.linalg.norm(b.get_forces(), axis=1),
                               np.linalg.norm(f0, axis=1), atol=1e-9)


# -- central finite differences -----------------------------------------------------------
@pytest.mark.parametrize("fname", CARBON_FILES + ["Si.tersoff"])
def test_forces_vs_finite_differences(fname):
    if fname == "Si.tersoff":
        a = bulk("Si", "diamond", a=5.43, cubic=True)
        a.rattle(0.2, seed=8)
        el = ["Si"]
    else:
        a = STRUCTURES["tube(12,6) strained rattled"].copy()  # bonds in the switching region
        el = ["C"]
    a.calc = Tersoff.from_lammps(fname, elements=el)
    f = a.get_forces()
    h = 1e-5
    rng = np.random.default_rng(0)
    for k in rng.choice(len(a), size=min(len(a), 8), replace=False):
        for c in range(3):
            b = a.copy()
            b.calc = Tersoff.from_lammps(fname, elements=el)
            b.positions[k, c] += h
            ep = b.get_potential_energy()
            b.positions[k, c] -= 2 * h
            em = b.get_potential_energy()
            fd = -(ep - em) / (2 * h)
            assert abs(fd - f[k, c]) < 1e-6 * max(1.0, abs(f[k, c])), (k, c, fd, f[k, c])


def test_stress_vs_strain_derivative():
    a = bulk("C", "diamond", a=3.55, cubic=True).repeat(2)
    a.rattle(0.05, seed=3)
    a.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"])
    s = a.get_stress(voigt=False)
    v = a.get_volume()
    h = 1e-6
    for p, q in [(0, 0), (1, 1), (0, 1), (1, 2)]:
        es = []
        for sign in (1, -1):
            b = a.copy()
            b.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"])
            eps = np.eye(3)
            eps[p, q] += 0.5 * sign * h
            eps[q, p] += 0.5 * sign * h
            b.set_cell(a.cell.array @ eps, scale_atoms=True)
            es.append(b.get_potential_energy())
        assert abs((es[0] - es[1]) / (2 * h) / v - s[p, q]) < 1e-6 * max(1e-3, abs(s[p, q]))


# -- ASE behaviour ---------------------------------------------------------------------------
def test_nanotube_without_vacuum_and_caller_atoms_untouched():
    t = nanotube(6, 6, length=2)  # cell with zero-length x, y vectors
    assert abs(t.cell.volume) == 0
    t.rattle(0.02, seed=1)
    x0 = t.positions.copy()
    t.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"])
    f = t.get_forces()
    assert np.array_equal(t.positions, x0)
    f[:] = 1.0
    assert not np.allclose(t.get_forces(), 1.0)
    with pytest.raises(PropertyNotImplementedError):
        t.get_stress()
    w = t.calc.get_virial()
    assert w.shape == (3, 3) and np.allclose(w, w.T, atol=1e-9)
    # with vacuum the cell has full rank: stress = -W / V
    tv = nanotube(6, 6, length=2, vacuum=5.0)
    tv.rattle(0.02, seed=1)
    tv.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"])
    assert tv.get_stress().shape == (6,)


def test_neighbour_list_reuse_within_skin_is_exact():
    a = STRUCTURES["tube(12,6) strained rattled"].copy()
    calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"], skin=0.5)
    a.calc = calc
    a.get_forces()
    builds = calc.neighbour_list.nbuilds
    a.positions += np.random.default_rng(1).normal(scale=0.03, size=a.positions.shape)
    f = a.get_forces()
    assert calc.neighbour_list.nbuilds == builds  # reused
    fresh = a.copy()
    fresh.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"])
    np.testing.assert_allclose(f, fresh.get_forces(), atol=1e-12)


def test_threads_give_same_result():
    a = bulk("C", "diamond", a=3.56, cubic=True).repeat(3)
    a.rattle(0.05, seed=2)
    out = []
    for nt in (1, 2, 3):
        c = Tersoff.from_lammps("BNC.tersoff", elements=["C"], nthreads=nt)
        out.append(ours_evaluate(a, c))
    for o in out[1:]:
        assert o["energy"] == pytest.approx(out[0]["energy"], rel=1e-13)
        np.testing.assert_allclose(o["forces"], out[0]["forces"], atol=1e-12)
        np.testing.assert_allclose(o["virial"], out[0]["virial"], atol=1e-10)


# -- bad input -------------------------------------------------------------------------------
def test_malformed_file_names_file_and_line(tmp_path):
    good = ("C C C 3.0 1.0 0.0 38049 4.3484 -.57058 .72751\n"
            " 1.5724e-7 2.2119 346.7 1.95 0.15 3.4879 1393.6\n")
    f = tmp_path / "bad.tersoff"
    f.write_text("# header\n\n" + good.replace("346.7", "346,7"))
    with pytest.raises(TersoffFileError, match=r"bad.tersoff:3: cannot read '346,7'"):
        read_tersoff_file(f)
    f.write_text("# header\n" + good + "C C Si 3.0 1.0 0.0 1 2 3 4 5 6 7 8 9 10 11 12\n")
    with pytest.raises(TersoffFileError, match=r"bad.tersoff:4: .*18"):
        read_tersoff_file(f)
    f.write_text(good + "C C Si 3.0 1.0\n")
    with pytest.raises(TersoffFileError, match=r"bad.tersoff:3: the file ends inside an entry"):
        read_tersoff_file(f)
    f.write_text(good.replace("0.15", "2.15"))
    with pytest.raises(TersoffFileError, match=r"bad.tersoff:1: .*D > R"):
        read_tersoff_file(f)
    f.write_text(good + good)
    with pytest.raises(TersoffFileError, match=r"bad.tersoff:3: duplicate entry C C C"):
        read_tersoff_file(f)


def test_missing_element_and_missing_entry(tmp_path):
    with pytest.raises(ValueError, match=r"element Si not in BNC.tersoff; it has B, C, N"):
        Tersoff.from_lammps("BNC.tersoff", elements=["C", "Si"])
    f = tmp_path / "partial.tersoff"
    f.write_text((lammps_potential_path("SiC.tersoff").read_text()).split("Si  C   Si")[0])
    with pytest.raises(TersoffFileError, match=r"no entry Si C Si"):
        read_tersoff_file(f, ["Si", "C"])
    with pytest.raises(FileNotFoundError, match="not shipped with LAMMPS"):
        Tersoff.from_lammps("nonexistent.tersoff")


def test_atoms_with_element_not_in_calculator():
    a = bulk("Si", "diamond", a=5.43)
    a.calc = Tersoff.from_lammps("SiC.tersoff", elements=["C"])
    with pytest.raises(ValueError, match=r"contain Si, which this Tersoff potential"):
        a.get_potential_energy()


def test_overlapping_atoms():
    a = nanotube(5, 5, length=2)
    a.positions[7] = a.positions[3] + [0.01, 0.0, 0.0]
    a.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"])
    with pytest.raises(OverlappingAtomsError, match=r"atoms 3 and 7 overlap: distance 0.01"):
        a.get_forces()


@pytest.mark.parametrize("n", [0.72751, 22.956])  # BNC.tersoff carbon, Si.tersoff
def test_bond_order_and_derivative_on_every_branch(n):
    """b_ij and db_ij/dzeta from the one kernel call: the same values as the separate
    functions on both sides of every threshold c1..c4 (bit for bit outside the full
    expression, where the derivative reuses b_ij: 1e-14 there), and, where the full
    expression is used, the closed form (1 + t^n)^(-1/(2n)) (t = beta zeta) and its
    derivative evaluated another way (exp / log1p) to 1e-14."""
    import math

    from potentials import tersoff_kernels as tk

    beta = 1.5724e-7 if n < 1 else 0.33675
    c1 = (2 * n * 1e-16) ** (-1 / n)
    c2 = (2 * n * 1e-8) ** (-1 / n)
    c3, c4 = 1 / c2, 1 / c1
    ts = sorted({c * f for c in (c1, c2, c3, c4) for f in (0.7, 1.3)} | {1.0, 0.05, 3.0})
    full = 0
    for t in ts:
        zeta = t / beta
        b, bd = tk.ters_bij_and_d(zeta, beta, n, c1, c2, c3, c4)
        assert b == tk.ters_bij(zeta, beta, n, c1, c2, c3, c4)
        bd_sep = tk.ters_bij_d(zeta, beta, n, c1, c2, c3, c4)
        if c3 <= t <= c2:  # the full expression
            full += 1
            assert abs(bd - bd_sep) <= 1e-14 * abs(bd_sep)
            tn = math.exp(n * math.log(t))
            b_ref = math.exp(-math.log1p(tn) / (2 * n))
            bd_ref = -0.5 * b_ref / (1 + tn) * tn / zeta
            assert abs(b - b_ref) <= 1e-14 * b_ref
            assert abs(bd - bd_ref) <= 1e-14 * abs(bd_ref)
        else:
            assert bd == bd_sep
    assert full >= 3
