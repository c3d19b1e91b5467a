"""Shifted-force Lennard-Jones: finite differences, smooth cutoff, molecule exclusion, and
equality with LAMMPS ``pair_style lj/smooth/linear``."""
import numpy as np
import pytest
from ase import Atoms
from ase.build import nanotube

from brenner_lj_lammps import lammps_reference
from potentials.lj import LJ_CARBON, LennardJones
from test_brenner import fd_forces, fd_virial


def two_tubes(gap=3.4, n=5, length=2, seed=0):
    """Two parallel (n, n) tubes along z, periodic along z, wall-to-wall distance ``gap``,
    molecule ids 0 and 1."""
    t = nanotube(n, n, length=length)
    R = np.linalg.norm(t.positions[:, :2], axis=1).mean()
    a = t.copy()
    b = t.copy()
    b.translate([2 * R + gap, 0, 0])
    out = a + b
    out.set_array("mol-id", np.repeat([0, 1], len(t)))
    out.rattle(0.05, seed=seed)
    return out


def random_cluster(n=30, box=12.0, seed=1, pbc=False):
    """``n`` atoms on a jittered simple-cubic grid filling a cube of side ``box`` (nearest
    distance > ~2.4 A, also across the periodic boundary)."""
    k = int(np.ceil(n ** (1 / 3)))
    h = box / k
    g = (np.stack(np.meshgrid(*[np.arange(k)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5)
    rng = np.random.default_rng(seed)
    pick = rng.permutation(len(g))[:n]
    pos = g[pick] * h + rng.uniform(-0.1, 0.1, (n, 3)) * h
    return Atoms(f"C{n}", positions=pos, cell=[box] * 3, pbc=pbc)


def test_forces_virial_vs_finite_differences():
    for atoms, kw in [(two_tubes(), {}), (random_cluster(pbc=True), {"rc": 8.0}),
                      (random_cluster(), {"params": "girifalco2000"})]:
        calc = LennardJones(**kw)
        atoms.calc = calc
        F = atoms.get_forces()
        W = calc.get_virial()
        Ffd = fd_forces(atoms, LennardJones(**kw), h=1e-4)
        Wfd = fd_virial(atoms, LennardJones(**kw), h=1e-5)
        assert np.abs(F - Ffd).max() <= 1e-6 * np.abs(F).max()
        assert np.abs(W - Wfd).max() <= 1e-6 * np.abs(W).max()
        assert np.abs(F.sum(axis=0)).max() < 1e-12 * len(atoms) * np.abs(F).max()


def test_smooth_at_cutoff_and_minimum():
    eps, sig = LJ_CARBON["airebo"]["epsilon"], LJ_CARBON["airebo"]["sigma"]
    rc = 3 * sig

    def pair(r):
        a = Atoms("C2", positions=[[0, 0, 0], [r, 0, 0]])
        a.calc = LennardJones()
        return a.get_potential_energy(), a.get_forces()[1, 0]

    for r in (rc - 1e-7, rc + 1e-7):
        e, f = pair(r)
        assert abs(e) < 1e-12 and abs(f) < 1e-9
    e, f = pair(2 ** (1 / 6) * sig)
    assert e == pytest.approx(-eps, rel=0.03)  # shifted force moves the well a little


def test_same_molecule_pairs_excluded():
    t = two_tubes()
    a = t.copy()
    a.calc = LennardJones()
    e_inter = a.get_potential_energy()
    b = t.copy()
    b.calc = LennardJones(exclude_same_mol=False)
    e_all = b.get_potential_energy()
    c = t.copy()
    del c.arrays["mol-id"]
    c.calc = LennardJones(mol=np.repeat([0, 1], len(t) // 2))
    assert c.get_potential_energy() == pytest.approx(e_inter, rel=1e-14)
    assert e_inter < 0 and abs(e_all - e_inter) > 1.0
    one = t[:len(t) // 2]
    one.calc = LennardJones()
    assert one.get_potential_energy() == 0.0


def test_bad_input():
    with pytest.raises(ValueError, match="unknown LJ carbon parameter set"):
        LennardJones(params="argon")
    a = random_cluster(n=4)
    a.calc = LennardJones(mol=[0, 1])
    with pytest.raises(ValueError, match="mol has 2 entries for 4 atoms"):
        a.get_potential_energy()


@pytest.mark.lammps
@pytest.mark.parametrize("case", ["bundle", "cluster_periodic", "cluster"])
def test_equals_lammps_lj_smooth_linear(case):
    if case == "bundle":
        atoms, mol = two_tubes(), None
        kw = {}
    elif case == "cluster_periodic":
        atoms, kw = random_cluster(n=40, box=12.0, pbc=True), {"rc": 8.5}
    else:
        atoms, kw = random_cluster(), {"params": "girifalco2000"}
    calc = LennardJones(**kw)
    atoms.calc = calc
    E = atoms.get_potential_energy()
    F = atoms.get_forces()
    W = calc.get_virial()
    eps, sig, rc = calc._eps, calc._sigma, calc.cutoff
    mol = atoms.arrays.get("mol-id")
    El, Fl, Wl = lammps_reference(atoms, f"lj/smooth/linear {rc!r}",
                                  [f"1 1 {eps!r} {sig!r}"],
                                  mol=None if mol is None else mol + 1,
                                  exclude_intra=mol is not None)
    assert abs(E - El) <= 1e-10 * abs(El)
    assert np.abs(F - Fl).max() <= 1e-10 * np.abs(Fl).max()
    assert np.abs(W - Wl).max() <= 1e-10 * np.abs(Wl).max()
