"""Neighbour list against ASE's own (an independent implementation), the rebuild rule, and
the shared calculator plumbing on a minimal pair potential."""
import numpy as np
import pytest
from ase import Atoms
from ase.build import bulk, graphene, nanotube
from ase.calculators.calculator import PropertyNotImplementedError
from ase.neighborlist import neighbor_list as ase_neighbor_list

from potentials.calculator import OverlappingAtomsError, PotentialCalculator
from potentials.neighbours import NeighbourList, complete_cell, neighbour_list


def _as_set(atoms, rc, half=False):
    f, j, s = neighbour_list(atoms.positions, atoms.cell.array, atoms.pbc, rc, half=half)
    i = np.repeat(np.arange(len(atoms)), np.diff(f))
    return set(zip(i.tolist(), j.tolist(), map(tuple, s.tolist())))


def _ase_set(atoms, rc, half=False):
    i, j, s = ase_neighbor_list("ijS", atoms, rc)
    out = set(zip(i.tolist(), j.tolist(), map(tuple, s.tolist())))
    if half:
        out = {(a, b, t) for (a, b, t) in out if a < b or (a == b and t > (0, 0, 0))}
    return out


def _structures():
    t = nanotube(10, 10, length=3)  # zero-length x, y cell vectors, periodic along z
    yield "tube(10,10)", t, 2.4
    t = t.copy()
    t.rattle(0.1, seed=1)
    t.positions += 17.3  # far outside the cell: the list must not care
    yield "tube rattled shifted", t, 6.0
    yield "tube(12,6) one period", nanotube(12, 6, length=1), 2.4
    d = bulk("C", "diamond", a=3.57)  # 2-atom cell, cutoff larger than the cell
    yield "diamond primitive", d, 7.0
    d = d.repeat((2, 3, 1))
    d.rattle(0.05, seed=3)
    d.positions -= 11.1
    yield "diamond rattled", d, 2.4
    g = graphene(size=(3, 3, 1))
    g.pbc = [True, True, False]
    g.rattle(0.05, seed=2)
    yield "graphene (zero z vector)", g, 5.0
    c = nanotube(6, 0, length=2)
    c.pbc = False
    c.cell = np.zeros((3, 3))
    yield "free cluster", c, 2.4
    tri = bulk("Cu", "fcc", a=3.6).repeat((3, 2, 2))
    tri.rattle(0.1, seed=5)
    yield "fcc triclinic", tri, 5.0
    mixed = bulk("C", "diamond", a=3.57, cubic=True).repeat((2, 1, 2))
    mixed.pbc = [True, False, True]
    yield "slab pbc xz", mixed, 3.0


@pytest.mark.parametrize("half", [False, True])
def test_same_pairs_as_ase(half):
    for name, atoms, rc in _structures():
        mine = _as_set(atoms, rc, half)
        ref = _ase_set(atoms, rc, half)
        assert mine == ref, (name, len(mine), len(ref))
        assert len(mine) > 0, name


def test_bond_vectors_and_distances():
    a = nanotube(8, 0, length=2)
    a.rattle(0.05, seed=7)
    nl = NeighbourList(2.0, skin=0.4)
    nl.build(a.positions, a.cell.array, a.pbc)
    r = nl.bond_vectors(a.positions)
    i, j, s = nl.pairs()
    ref = a.positions[j] - a.positions[i] + s @ a.cell.array
    np.testing.assert_allclose(r, ref, atol=1e-12)
    d_ase = np.sort(ase_neighbor_list("d", a, 2.4))
    np.testing.assert_allclose(np.sort(np.linalg.norm(r, axis=1)), d_ase, atol=1e-12)


def test_rebuild_rule():
    a = bulk("C", "diamond", a=3.57, cubic=True).repeat(2)
    nl = NeighbourList(2.0, skin=0.4)
    assert nl.update(a.positions, a.cell.array, a.pbc)
    x = a.positions.copy()
    x[3] += [0.19, 0.0, 0.0]  # less than skin / 2: keep
    assert not nl.update(x, a.cell.array, a.pbc)
    x[3] += [0.02, 0.0, 0.0]  # more than skin / 2 in total: rebuild
    assert nl.update(x, a.cell.array, a.pbc)
    assert not nl.update(x, a.cell.array, a.pbc)
    assert nl.update(x, a.cell.array * 1.001, a.pbc)  # cell changed
    assert nl.update(x, a.cell.array * 1.001, [True, True, False])  # pbc changed
    assert nl.update(x[:-1], a.cell.array * 1.001, [True, True, False])  # number changed
    assert nl.nbuilds == 5


def test_list_stays_valid_within_skin():
    """Pairs within the cutoff after moves smaller than skin/2 are all in the old list."""
    a = bulk("C", "diamond", a=3.57, cubic=True).repeat(2)
    a.rattle(0.03, seed=0)
    rc, skin = 2.0, 0.5
    nl = NeighbourList(rc, skin=skin)
    nl.build(a.positions, a.cell.array, a.pbc)
    rng = np.random.default_rng(1)
    for _ in range(5):
        b = a.copy()
        step = rng.normal(size=b.positions.shape)
        step *= 0.249 / np.linalg.norm(step, axis=1)[:, None]
        b.positions += step
        assert not nl.needs_rebuild(b.positions, b.cell.array, b.pbc)
        d = np.linalg.norm(nl.bond_vectors(b.positions), axis=1)
        i, j, s = nl.pairs()
        kept = {(p, q, tuple(t)) for p, q, t, dd in zip(i, j, s.tolist(), d) if dd < rc}
        assert kept == _ase_set(b, rc)


def test_bad_cells():
    with pytest.raises(ValueError, match="cell vector 0 has zero length"):
        complete_cell(np.zeros((3, 3)), [True, False, False])
    with pytest.raises(ValueError, match="linearly dependent"):
        complete_cell([[1, 0, 0], [2, 0, 0], [0, 0, 1]], [True, True, False])
    c = complete_cell(nanotube(5, 5, length=1).cell.array, [False, False, True])
    assert abs(np.linalg.det(c)) > 0
    with pytest.raises(ValueError, match="non-finite"):
        neighbour_list([[0, 0, 0], [np.nan, 0, 0]], np.zeros((3, 3)), [False] * 3, 2.0)


# -- the calculator base class on a minimal pair potential ---------------------------------
class _Morse(PotentialCalculator):
    """E = sum_pairs D (1 - exp(-a (r - r0)))^2 - D, truncated at rc (a test dummy)."""

    cutoff = 3.0
    half_list = True

    def compute(self, atoms, nl):
        r = nl.bond_vectors(atoms.positions)
        i, j, _ = nl.pairs()
        d = np.linalg.norm(r, axis=1)
        m = d < self.cutoff
        i, j, r, d = i[m], j[m], r[m], d[m]
        e = np.exp(-1.8 * (d - 1.4))
        eb = (1 - e) ** 2 - 1
        de = 2 * (1 - e) * 1.8 * e
        g = (de / d)[:, None] * r  # dE/dr_ij
        n = len(atoms)
        f = np.zeros((n, 3))
        np.add.at(f, i, g)
        np.add.at(f, j, -g)
        en = np.zeros(n)
        np.add.at(en, i, 0.5 * eb)
        np.add.at(en, j, 0.5 * eb)
        return eb.sum(), en, f, -r.T @ g


def test_calculator_plumbing():
    a = nanotube(6, 0, length=2)  # rank-deficient cell
    a.rattle(0.05, seed=4)
    x0 = a.positions.copy()
    a.calc = _Morse()
    f = a.get_forces()
    assert np.array_equal(a.positions, x0)
    f[:] = 0.0  # handing out a copy: mutating it changes nothing inside
    assert np.abs(a.get_forces()).max() > 0
    np.testing.assert_allclose(a.get_forces().sum(axis=0), 0, atol=1e-12)
    assert np.isclose(a.get_potential_energies().sum(), a.get_potential_energy())
    with pytest.raises(PropertyNotImplementedError, match="full rank"):
        a.get_stress()
    assert a.calc.get_virial().shape == (3, 3)
    # forces against central differences
    e0 = a.get_potential_energy()
    h = 1e-5
    for k, c in [(0, 0), (5, 2), (17, 1)]:
        b = a.copy()
        b.calc = _Morse()
        b.positions[k, c] += h
        ep = b.get_potential_energy()
        b.positions[k, c] -= 2 * h
        em = b.get_potential_energy()
        assert abs(-(ep - em) / (2 * h) - a.get_forces()[k, c]) < 1e-6
    assert np.isfinite(e0)


def test_stress_matches_strain_derivative():
    a = bulk("C", "diamond", a=3.6).repeat((2, 2, 1))
    a.rattle(0.05, seed=2)
    a.calc = _Morse()
    s = a.get_stress(voigt=False)
    v = a.get_volume()
    h = 1e-6
    for p, q in [(0, 0), (1, 2), (2, 0)]:
        out = []
        for sign in (1, -1):
            b = a.copy()
            b.calc = _Morse()
            eps = np.eye(3)
            eps[p, q] += sign * h * 0.5
            eps[q, p] += sign * h * 0.5
            b.set_cell(a.cell.array @ eps, scale_atoms=True)
            out.append(b.get_potential_energy())
        assert abs((out[0] - out[1]) / (2 * h) / v - s[p, q]) < 1e-7


def test_overlap_error_names_atoms():
    a = Atoms("C3", positions=[[0, 0, 0], [1.4, 0, 0], [1.45, 0.05, 0]])
    a.calc = _Morse()
    with pytest.raises(OverlappingAtomsError, match=r"atoms 1 and 2 overlap: distance 0.07071"):
        a.get_potential_energy()


def test_exclusion_is_symmetric_whatever_the_callable_returns():
    """An ``exclude`` callable that drops only one direction of a bond (as a segment test
    can, for a bond through the segment's end point, where the crossing parameter is exactly
    0 or 1 from one end only) still gives a symmetric family: both directions go. It used to
    raise 'family is not symmetric'."""
    from upscale.engine import bonds_crossing_segment, build_family, square_lattice

    sysm = square_lattice(12, 12, 1.0)
    x = sysm.x0
    cut = bonds_crossing_segment(x, (x[:, 0].min() - 0.5, 0.0), (0.0, 0.0))

    def one_way(i, j, xi):
        return cut(i, j, xi) & (i < j)

    fam = build_family(sysm, 3.015, exclude=one_way)
    ref = build_family(sysm, 3.015, exclude=cut)
    assert np.array_equal(fam.owner[fam.reverse], fam.neighbors)
    assert np.array_equal(fam.offsets, ref.offsets) and np.array_equal(fam.neighbors, ref.neighbors)
    assert fam.nb < build_family(sysm, 3.015).nb


def test_overlap_found_between_rebuilds():
    """An overlap that appears while the list is not rebuilt (every move < skin / 2) is
    still caught, with the message of the exact check; a move that keeps the distance above
    ``min_distance`` passes although the bound ``d_0 - 2 u`` alone would not clear it."""
    a = Atoms("C3", positions=[[0, 0, 0], [1.4, 0, 0], [0, 1.4, 0]])
    a.calc = _Morse(min_distance=1.2)  # skin 0.3: no rebuild while every move < 0.15
    a.get_potential_energy()
    nl = a.calc.neighbour_list
    a.positions[1, 0] -= 0.01  # bound 1.4 - 0.02 clears 1.2
    a.get_potential_energy()
    a.positions[1, 0] -= 0.11  # d = 1.28, bound 1.16 < 1.2: exact check, passes
    a.get_potential_energy()
    a.positions[0, 0] += 0.12  # d = 1.16
    with pytest.raises(OverlappingAtomsError, match=r"atoms 0 and 1 overlap: distance 1.16 "):
        a.get_potential_energy()
    assert nl.nbuilds == 1 and a.calc.neighbour_list is nl


def test_overlap_bound_matches_exact_check_on_a_random_walk():
    """Along a random walk without rebuilds, the calculator raises exactly when the
    smallest listed distance (computed here directly) is below ``min_distance``."""
    from potentials.neighbours import min_bond_distance

    a = bulk("C", "diamond", a=3.5668, cubic=True).repeat(2)
    x0 = a.positions.copy()
    rng = np.random.default_rng(3)
    # small steps take the bound's shortcut, large ones (|u| < 0.3 = skin / 2) the exact pass
    walk = [x0 + rng.uniform(-h, h, x0.shape) for h in [0.01, 0.17] * 20]
    lists = neighbour_list(x0, a.cell.array, a.pbc, _Morse.cutoff + 0.6, half=True)
    d = [min_bond_distance(x, a.cell.array, *lists)[0] for x in walk]
    dmin = float(np.median(d))
    calc = _Morse(min_distance=dmin, skin=0.6)
    a.calc = calc
    a.get_potential_energy()
    nl = calc.neighbour_list
    for x, dx in zip(walk, d):
        b = a.copy()
        b.positions = x
        b.calc = calc
        if dx < dmin:
            with pytest.raises(OverlappingAtomsError):
                b.get_potential_energy()
        else:
            b.get_potential_energy()
    assert nl.nbuilds == 1 and 0 < sum(dx < dmin for dx in d) < 40


def test_change_detection_as_ase():
    """compare_atoms finds the same changes as ASE's, at its tolerance (1e-15 absolute)."""
    from ase.calculators.calculator import compare_atoms as ase_compare

    from potentials.calculator import compare_atoms

    a = bulk("Si", "diamond", a=5.43, cubic=True)
    cases = []
    for dx in (0.0, 5e-16, 2e-15, 1e-3, np.inf, np.nan):
        b = a.copy()
        b.positions[3, 1] += dx
        cases.append(b)
    b = a.copy()
    b.numbers[2] = 6
    cases.append(b)
    b = a.copy()
    b.set_initial_charges(np.zeros(len(a)))
    cases.append(b)
    b = a.copy()
    b.cell[0, 0] += 1e-9
    cases.append(b)
    b = a.copy()
    b.pbc = [True, False, True]
    cases.append(b)
    inf = a.copy()
    inf.positions[0, 0] = np.inf
    cases.append((inf, inf.copy()))
    for c in cases:
        x, y = c if isinstance(c, tuple) else (a, c)
        assert sorted(compare_atoms(x, y)) == sorted(ase_compare(x, y)), c
    assert compare_atoms(None, a) == ase_compare(None, a)
