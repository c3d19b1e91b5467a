"""Builders: atom counts, geometry and periodic bond networks against closed-form facts."""
import math

import numpy as np
import pytest
from ase.neighborlist import neighbor_list

from upscale.build import bundle, chirality, graphene, swcnt, vacancy

TUBES = [(10, 10), (17, 0), (12, 6), (6, 5), (9, 0)]


def _radii(atoms):
    xc, yc = atoms.info["axis_xy"]
    return np.hypot(atoms.positions[:, 0] - xc, atoms.positions[:, 1] - yc)


@pytest.mark.parametrize("n,m", TUBES)
def test_chirality_facts_closed_form(n, m):
    ch = chirality(n, m)
    q = n * n + n * m + m * m
    dR = math.gcd(2 * n + m, 2 * m + n)
    a = 1.42 * math.sqrt(3)
    assert ch.atoms_per_cell == 4 * q // dR
    assert ch.radius == pytest.approx(a * math.sqrt(q) / (2 * math.pi), rel=1e-12)
    assert ch.cell_length == pytest.approx(math.sqrt(3) * a * math.sqrt(q) / dR, rel=1e-12)
    assert ch.chiral_angle_deg == pytest.approx(math.degrees(math.atan(math.sqrt(3) * m / (2 * n + m))))


def test_known_values():
    # (10,10): 40 atoms per cell, T = a = 2.4595 Å, R = 6.78 Å, armchair 30 deg
    ch = chirality(10, 10)
    assert (ch.atoms_per_cell, ch.d_R) == (40, 30)
    assert ch.cell_length == pytest.approx(2.45951, abs=1e-5)
    assert ch.radius == pytest.approx(6.780, abs=1e-3)
    assert ch.chiral_angle_deg == pytest.approx(30.0)
    z = chirality(17, 0)
    assert (z.atoms_per_cell, z.chiral_angle_deg) == (68, 0.0)
    assert z.cell_length == pytest.approx(3 * 1.42)


@pytest.mark.parametrize("n,m", TUBES)
def test_swcnt_counts_radius_and_periodic_network(n, m):
    ch = chirality(n, m)
    atoms = swcnt(n, m, length=max(25.0, 2 * ch.cell_length))
    nc = atoms.info["ncells"]
    assert len(atoms) == nc * ch.atoms_per_cell
    assert atoms.cell[2, 2] == pytest.approx(nc * ch.cell_length)
    assert abs(np.linalg.det(atoms.cell.array)) > 0  # full rank
    assert tuple(atoms.pbc) == (False, False, True)
    assert np.allclose(_radii(atoms), ch.radius, atol=1e-9)
    assert atoms.positions[:, 2].min() >= 0 and atoms.positions[:, 2].max() < atoms.cell[2, 2]
    i, j, d = neighbor_list("ijd", atoms, 1.7)
    assert np.all(np.bincount(i, minlength=len(atoms)) == 3)
    # rolled-up bonds are chords of the flat 1.42 Å bonds: slightly shorter, never longer
    assert d.max() <= 1.42 + 1e-9 and d.min() > 1.40
    # no second neighbours below 2.3 Å
    i2, _ = neighbor_list("ij", atoms, 2.3)
    assert len(i2) == len(i)


def test_length_rounding_and_errors():
    ch = chirality(10, 10)
    a = swcnt(10, 10, length=100.0)
    assert a.info["ncells"] == round(100.0 / ch.cell_length)
    with pytest.raises(ValueError, match="shorter than two unit cells"):
        swcnt(10, 10, length=1.5 * ch.cell_length)
    for bad in [(0, 0), (-1, 5), (5, -2)]:
        with pytest.raises(ValueError, match="chira"):
            swcnt(*bad, length=50.0)
    with pytest.raises(ValueError, match="integer"):
        swcnt(10.5, 3, length=50.0)
    with pytest.raises(ValueError, match="length"):
        swcnt(10, 10, length=-5.0)


def test_bundle_geometry_vdw_and_seed():
    b = bundle(10, 10, 20.0)
    R = chirality(10, 10).radius
    mol = b.arrays["mol-id"]
    assert sorted(np.unique(mol)) == list(range(1, 8))
    assert np.all(np.bincount(mol)[1:] == len(b) // 7)
    assert np.array_equal(b.get_tags(), mol)
    centres = np.array(b.info["tube_centres"])
    d = np.linalg.norm(centres[1:] - centres[0], axis=1)
    assert np.allclose(d, 2 * R + 3.4)
    # outer neighbours on a hexagon: adjacent outer tubes are also 2R + gap apart
    assert np.allclose(np.linalg.norm(centres[1:] - np.roll(centres[1:], 1, axis=0), axis=1),
                       2 * R + 3.4)
    # closest atoms of different tubes are ~ the gap apart (walls are polygons, so >= gap)
    from scipy.spatial import cKDTree
    t0 = cKDTree(b.positions[mol == 1])
    dmin = t0.query(b.positions[mol == 2])[0].min()
    assert 3.3 < dmin < 3.6
    s = bundle(10, 10, 20.0, spacing="seed")
    cs = np.array(s.info["tube_centres"])
    assert np.allclose(np.linalg.norm(cs[1:] - cs[0], axis=1), 2.2 * R)
    with pytest.raises(ValueError, match="ntubes"):
        bundle(10, 10, 20.0, ntubes=8)
    with pytest.raises(ValueError, match="spacing"):
        bundle(10, 10, 20.0, spacing="tight")


def test_vacancy_default_point_and_errors():
    t = swcnt(10, 10, 50.0)
    n0, x0 = len(t), t.positions.copy()
    v = vacancy(t, n=4)
    assert len(v) == len(t) - 4
    xc, yc = t.info["axis_xy"]
    at = np.array(v.info["vacancy"]["at"])
    assert at[0] == pytest.approx(xc + t.info["radius"]) and at[1] == pytest.approx(yc)
    assert at[2] == pytest.approx(t.positions[:, 2].min() + t.info["length"] / 2)
    removed = v.info["vacancy"]["removed"]
    # the removed atoms are the 4 nearest to the point
    r = np.linalg.norm(t.positions - at, axis=1)
    assert set(removed) == set(np.argsort(r)[:4])
    # a connected cluster: 3 bonds among 4 atoms at least
    i, j = neighbor_list("ij", t[removed], 1.6)
    assert len(i) // 2 >= 3
    assert len(t) == n0 and np.array_equal(t.positions, x0)  # input untouched
    with pytest.raises(ValueError, match="vacancy n"):
        vacancy(t, n=len(t) + 1)
    with pytest.raises(ValueError, match="vacancy n"):
        vacancy(t, n=0)
    with pytest.raises(ValueError, match="at="):
        vacancy(graphene(2, 2))
    # bundle: default vacancy on the central tube
    b = vacancy(bundle(10, 10, 20.0))
    assert np.all(np.isin(b.info["vacancy"]["removed"], np.arange(len(b) // 7 + 1)))


def test_graphene_network():
    g = graphene(4, 6)
    assert len(g) == 4 * 4 * 6
    i, j, d = neighbor_list("ijd", g, 1.6)
    assert np.all(np.bincount(i) == 3)
    assert np.allclose(d, 1.42)
    assert abs(np.linalg.det(g.cell.array)) > 0
    with pytest.raises(ValueError, match="nx"):
        graphene(0, 3)
