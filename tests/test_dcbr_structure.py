"""Structure recognition of the coarse model package (upscale.models.dcbr: structure,
lattice, defects, regions): tubes, chirality, lattice map, defects and atomistic regions
registered from the atoms alone.

Oracles nobody here wrote into the registration: ``ase.build.nanotube`` (chirality, ideal
radius and bond), the defect builders' own records (``upscale.defects``: kind and place of
every defect they made), the bundle builder's ``mol-id`` and tube centres, and brute-force
minimum-image distances for the regions.
"""
import math

import numpy as np
import pytest
from ase import Atoms
from ase.build import bulk, graphene, nanotube

from upscale.build import bundle, swcnt
from upscale.defects import apply_defects
from upscale.models.dcbr.defects import find_defects
from upscale.models.dcbr.regions import atomistic_regions
from upscale.models.dcbr.structure import register

TUBES = {"armchair": (10, 10), "zigzag": (17, 0), "chiral": (12, 6), "chiral-mirror": (6, 12)}
ALL_KINDS = "v1@0.1@0,v2@0.3@90,v4@0.5@180,sw@0.7@270,adatom@0.9@45"


def strained_noisy(atoms, stretch=0.03, noise=0.05, seed=0):
    """Axial stretch (the cell too) and Gaussian noise of ``noise`` Å per coordinate."""
    out = atoms.copy()
    out.positions[:, 2] *= 1.0 + stretch
    out.cell[2, 2] *= 1.0 + stretch
    out.positions += np.random.default_rng(seed).normal(0.0, noise, out.positions.shape)
    out.info["length"] = out.cell[2, 2]
    return out


def wall_place(atoms, point):
    """(z, azimuth rad) of a Cartesian point about a swcnt tube's axis."""
    xc, yc = atoms.info["axis_xy"]
    return point[2], math.atan2(point[1] - yc, point[0] - xc)


def assert_matches_records(atoms, found, tol=1.5):
    """Each builder record has one found defect of its kind within ``tol`` Å along the axis
    and round the wall (minimum image along the period), and nothing else is found."""
    L, R = atoms.cell[2, 2], atoms.info["radius"]
    recs = atoms.info.get("defects", [])
    assert len(found) == len(recs), [(d.kind, d.z) for d in found]
    for rec in recs:
        z, phi = wall_place(atoms, rec["at"])
        dz = np.array([d.z for d in found]) - z
        dz -= L * np.round(dz / L)
        dphi = np.radians([d.azimuth_deg for d in found]) - phi
        arc = R * np.abs((dphi + np.pi) % (2 * np.pi) - np.pi)
        near = [d.kind for d, a, b in zip(found, np.abs(dz), arc) if a < tol and b < tol]
        assert near == [rec["kind"]], (rec["kind"], rec["zfrac"], rec["angle_deg"], near)


@pytest.mark.parametrize("nm", [(10, 10), (17, 0), (0, 9), (12, 6), (6, 12), (10, 5), (5, 10),
                                (9, 1), (1, 9), (8, 3), (11, 7)])
def test_chirality_radius_bond_of_ase_nanotubes(nm):
    """ASE's own builder: (n, m) exactly with its handedness ((m, n) is the mirror image;
    a zigzag (0, n) is (n, 0)), the rolled-up radius and the 1.42 Å bond."""
    n, m = nm
    tube = register(nanotube(n, m, length=4)).tubes[0]
    assert tube.chirality == ((n + m, 0) if n * m == 0 else (n, m))
    assert sum(tube.votes.values()) > 0 and len(tube.votes) == 1
    a = math.sqrt(3) * 1.42
    assert tube.radius == pytest.approx(a * math.sqrt(n * n + n * m + m * m) / (2 * math.pi),
                                        rel=1e-9)
    assert tube.bond == pytest.approx(1.42, rel=1e-9)
    assert tube.periodic and tube.lattice.quality()["on_site_fraction"] == 1.0
    assert len(tube.lattice.empty_sites) == 0


@pytest.mark.parametrize("name", list(TUBES))
def test_pristine_strained_noisy_tube_has_no_defect(name):
    """3 % stretch and 0.05 Å noise: exact chirality, every atom on its own site, no defect."""
    atoms = strained_noisy(swcnt(*TUBES[name], length=100.0))
    s = register(atoms)
    tube = s.tubes[0]
    assert tube.chirality == TUBES[name]
    assert tube.quality()["circuit_agreement"] == 1.0
    assert tube.lattice.quality()["on_site_fraction"] == 1.0
    assert np.unique(tube.lattice.site).size == len(atoms)
    assert tube.lattice.distance.max() < 0.4  # 0.05 Å noise per coordinate
    sub = np.empty(len(atoms), dtype=int)
    sub[tube.atoms] = tube.lattice.sublattice
    g = s.graph
    assert (sub[g.sources] != sub[g.indices]).all()  # every bond joins the two sublattices
    assert find_defects(s) == []


@pytest.mark.parametrize("noisy", [False, True])
@pytest.mark.parametrize("name", list(TUBES))
def test_every_defect_kind_found_at_its_place(name, noisy):
    """v1, v2, v4, Stone–Wales and adatom on one tube: each found once, of its kind, at the
    builder's place (within 1.5 Å along the axis and round the wall)."""
    atoms = apply_defects(swcnt(*TUBES[name], length=120.0), ALL_KINDS)
    if noisy:
        atoms = strained_noisy(atoms, seed=1)
        for rec in atoms.info["defects"]:
            rec["at"] = [rec["at"][0], rec["at"][1], rec["at"][2] * 1.03]
    s = register(atoms)
    assert s.tubes[0].chirality == TUBES[name]
    assert_matches_records(atoms, find_defects(s))


def test_stone_wales_and_reconstructed_divacancy_with_all_atoms_threefold():
    """Coordination is blind to 55-77 and 5-8-5; the rings see them."""
    sw = apply_defects(swcnt(10, 10, length=40.0), "sw@0.5@0")
    v2 = apply_defects(swcnt(10, 10, length=40.0), "v2@0.5@0")
    rec = v2.info["defects"][0]
    dangling = np.array(rec["atoms"])
    removed = np.array(rec["removed_positions"])
    pos = v2.positions
    for r in removed:  # the two neighbours of each removed atom bond across it: 5-8-5
        pair = dangling[np.argsort(np.linalg.norm(pos[dangling] - r, axis=1))[:2]]
        mid = pos[pair].mean(axis=0)
        for i in pair:
            pos[i] = mid + (pos[i] - mid) * 1.55 / np.linalg.norm(pos[pair[0]] - pos[pair[1]])
    v2.positions = pos
    for atoms, kind, rings in ((sw, "sw", {5: 2, 7: 2}), (v2, "v2", {5: 2, 8: 1})):
        s = register(atoms)
        assert (s.graph.coordination == 3).all()
        (d,) = find_defects(s)
        assert (d.kind, d.rings) == (kind, rings)


def test_twenty_defects_on_a_micrometre_tube_and_the_regions():
    """(10, 10), 1 µm, 162,640 atoms, 20 defects of the four kinds at random places: all
    found at their place and kind (the lattice fit does not drift over 4,000 cells)."""
    rng = np.random.default_rng(3)
    z = np.sort(rng.uniform(0.02, 0.98, 20))
    spec = ",".join(f"{k}@{f:.4f}@{a:.1f}" for k, f, a in
                    zip(["v1", "v2", "v4", "sw"] * 5, z, rng.uniform(0, 360, 20)))
    atoms = apply_defects(swcnt(10, 10, length=10000.0), spec)
    s = register(atoms)
    assert s.tubes[0].chirality == (10, 10)
    found = find_defects(s)
    assert_matches_records(atoms, found)
    regions = atomistic_regions(s, found, 10.0)
    assert sorted(k for r in regions.regions for k in r.defects) == list(range(20))


def _brute_region(atoms, found, r_a):
    """Atoms within r_a of a defect core, minimum image along z (independent of k-d trees)."""
    L = atoms.cell[2, 2]
    core = [atoms.positions[d.atoms] for d in found] + [d.site_positions for d in found]
    core = np.vstack([c for c in core if len(c)])
    d = atoms.positions[:, None, :] - core[None, :, :]
    d[..., 2] -= L * np.round(d[..., 2] / L)
    return (np.linalg.norm(d, axis=2) <= r_a).any(axis=1)


def test_regions_are_the_atoms_near_defects_and_merge_across_the_periodic_boundary():
    atoms = apply_defects(swcnt(10, 10, length=120.0), "v1@0.03@0,v2@0.95@10,sw@0.5@180")
    s = register(atoms)
    found = find_defects(s)
    assert [d.kind for d in found] == ["v1", "sw", "v2"]
    wide = atomistic_regions(s, found, 6.0)
    assert np.array_equal(wide.mask, _brute_region(atoms, found, 6.0))
    assert sorted(r.defects for r in wide.regions) == [(0, 2), (1,)]
    narrow = atomistic_regions(s, found, 1.0)
    assert sorted(r.defects for r in narrow.regions) == [(0,), (1,), (2,)]


def test_user_selected_region_and_a_selector_that_selects_nothing():
    atoms = swcnt(10, 10, length=40.0)
    s = register(atoms)
    grip = atomistic_regions(s, [], 5.0, select=lambda p: p[:, 2] < 5.0)
    assert np.array_equal(grip.mask, atoms.positions[:, 2] < 5.0)
    assert len(grip.regions) == 1 and grip.regions[0].selected
    assert atomistic_regions(s, [], 5.0, select=[0, 1, 2]).mask.sum() == 3
    with pytest.raises(ValueError, match="selects no atom"):
        atomistic_regions(s, [], 5.0, select=lambda p: p[:, 2] > 1e6)
    with pytest.raises(ValueError, match="shape"):
        atomistic_regions(s, [], 5.0, select=np.ones(3, dtype=bool))
    with pytest.raises(ValueError, match="r_atomistic"):
        atomistic_regions(s, [], -1.0)


def test_bundle_and_multiwall_split_into_their_tubes():
    b = bundle(10, 10, length=40.0, ntubes=7)
    s = register(b)
    assert [t.chirality for t in s.tubes] == [(10, 10)] * 7
    for t in s.tubes:
        (mol,) = np.unique(b.arrays["mol-id"][t.atoms])
        assert len(t.atoms) == (b.arrays["mol-id"] == mol).sum()
        assert np.allclose(t.centre[:2], b.info["tube_centres"][mol - 1], atol=1e-6)
    mw = nanotube(5, 5, length=6)
    mw.extend(nanotube(10, 10, length=6))
    assert sorted(t.chirality for t in register(mw).tubes) == [(5, 5), (10, 10)]


def test_finite_tube_in_any_orientation():
    """Open ends (pbc off), axis turned off every Cartesian direction: axis, chirality, the
    divacancy, and the two rims as edges."""
    atoms = apply_defects(swcnt(12, 6, length=80.0), "v2@0.5@30")
    atoms.pbc = False
    atoms.rotate(90, "y", center=(0, 0, 0))
    atoms.rotate(20, "z")
    s = register(atoms)
    tube = s.tubes[0]
    assert not tube.periodic and tube.chirality == (12, 6)
    want = np.array([math.cos(math.radians(20)), math.sin(math.radians(20)), 0.0])
    assert abs(np.dot(tube.axis, want)) == pytest.approx(1.0, abs=1e-9)
    assert sorted(d.kind for d in find_defects(s)) == ["edge", "edge", "v2"]


def test_chirality_hint_is_used_and_checked():
    atoms = swcnt(12, 6, length=60.0)
    assert register(atoms, chirality=(12, 6)).tubes[0].chirality == (12, 6)
    assert register(swcnt(17, 0, length=30.0), chirality=(0, 17)).tubes[0].chirality == (17, 0)
    with pytest.raises(ValueError, match=r"hint \(6, 12\) disagrees"):
        register(atoms, chirality=(6, 12))


def _overlapping():
    a = swcnt(10, 10, length=30.0)
    b = a.copy()
    b.positions[:, 0] += 9.0
    a.extend(b)
    return a


def _nitrogen():
    a = swcnt(10, 10, length=30.0)
    a.symbols[3] = "N"
    return a


def _flake():
    g = graphene(size=(6, 6, 1), vacuum=5.0)
    g.pbc = False
    return g


@pytest.mark.parametrize("make, match", [
    (_nitrogen, "element"),
    (lambda: graphene(size=(6, 6, 1), vacuum=5.0), "two periodic directions"),
    (_flake, "flat"),
    (lambda: bulk("C", "diamond", a=3.57).repeat(3), "two periodic directions"),
    (lambda: Atoms("C2", positions=[[0, 0, 0], [0, 0, 1.4]]), "no nanotube"),
    (lambda: nanotube(10, 10, length=1), "shorter than two bond cutoffs"),
    (_overlapping, "overlap"),
    (lambda: "tube.xyz", "ase.Atoms"),
])
def test_bad_input_is_one_line_value_error(make, match):
    with pytest.raises(ValueError, match=match) as err:
        register(make())
    assert "\n" not in str(err.value)


def test_a_lammps_data_file_in_a_fully_periodic_box(tmp_path):
    """Any file ASE reads: a LAMMPS data file (pbc on in all three directions)."""
    from ase.io import read, write

    atoms = apply_defects(swcnt(12, 6, length=100.0), "v1@0.2@0,sw@0.6@100")
    atoms.pbc = True
    write(tmp_path / "tube.data", atoms, format="lammps-data", masses=True)
    back = read(tmp_path / "tube.data", format="lammps-data")
    s = register(back)
    assert s.tubes[0].chirality == (12, 6)
    assert_matches_records(atoms, find_defects(s))


def test_an_unbonded_atom_over_the_wall_is_an_adatom_of_that_tube():
    from upscale.defects import adatom

    atoms = adatom(swcnt(10, 10, length=40.0), 0.5, 30.0, height=2.5)  # 2.6 Å from its hosts
    s = register(atoms)
    assert s.graph.coordination[-1] == 0 and s.tube_of_atom[-1] == 0
    (d,) = find_defects(s)
    assert d.kind == "adatom" and list(d.atoms) == [len(atoms) - 1]
    with pytest.raises(ValueError, match="from the nearest tube wall"):
        far = atoms.copy()
        far.positions[-1, :2] += 30.0
        register(far)


@pytest.mark.parametrize("name", ["armchair", "chiral"])
def test_defects_on_the_periodic_boundary_are_found_whole(name):
    """A 4-vacancy and a Stone–Wales defect straddling z = 0 = L: one defect each, not two
    halves."""
    atoms = apply_defects(swcnt(*TUBES[name], length=60.0), "v4@0.0@0,sw@1.0@150")
    assert_matches_records(atoms, find_defects(register(atoms)))
