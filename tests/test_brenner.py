"""Brenner 1990 (REBO-I): derivatives against finite differences, invariants, the
conjugation table, closed-form lattice constants, bad input."""
import numpy as np
import pytest
from ase import Atoms
from ase.build import bulk, nanotube

from potentials.brenner import Brenner, brenner_parameters, conjugation_table
from potentials.brenner_kernels import conj_switch, tricubic_hermite
from potentials.calculator import OverlappingAtomsError


# -- structures -------------------------------------------------------------------------
def rect_graphene(a=2.46, nx=3, ny=2, vacuum=10.0):
    """Graphene in an orthogonal cell (4 atoms per a x sqrt(3) a), periodic in x, y."""
    b = a / np.sqrt(3.0)
    pos = [[0, 0, 0], [a / 2, b / 2, 0], [a / 2, 3 * b / 2, 0], [0, 2 * b, 0]]
    at = Atoms("C4", positions=pos, cell=[a, 3 * b, 2 * vacuum], pbc=[True, True, False])
    at = at.repeat((nx, ny, 1))
    at.positions[:, 2] += vacuum
    return at


def remove_cluster(atoms, n=4, centre=0):
    """Remove ``n`` connected atoms: ``centre`` and its nearest neighbours (by distance)."""
    d = atoms.get_distances(centre, range(len(atoms)), mic=True)
    out = atoms.copy()
    del out[list(np.argsort(d)[:n])]
    return out


def tube_with_vacancy(n=6, m=6, length=4, seed=3, rattle=0.03):
    t = nanotube(n, m, length=length)
    t = remove_cluster(t, 4, centre=len(t) // 2)
    t.rattle(rattle, seed=seed)
    return t


def structures():
    g = rect_graphene(nx=3, ny=2)
    g.rattle(0.05, seed=1)
    d = bulk("C", "diamond", a=3.57, cubic=True)
    d.rattle(0.05, seed=2)
    t = tube_with_vacancy()
    # stretched sheet with a vacancy: bonds in the switching region, non-integer N, N_conj
    s = rect_graphene(a=2.46 * 1.22, nx=3, ny=2)
    s = remove_cluster(s, 4, centre=5)
    s.rattle(0.04, seed=4)
    return {"graphene": g, "diamond": d, "tube_vacancy": t, "stretched_vacancy": s}


STRUCTS = structures()


def fd_forces(atoms, calc, h=1e-5):
    x0 = atoms.positions.copy()
    F = np.zeros_like(x0)
    a = atoms.copy()
    a.calc = calc
    for i in range(len(a)):
        for c in range(3):
            e = []
            for s in (1, -1):
                x = x0.copy()
                x[i, c] += s * h
                a.positions = x
                e.append(a.get_potential_energy())
            F[i, c] = -(e[0] - e[1]) / (2 * h)
    return F


def fd_virial(atoms, calc, h=1e-6):
    """W = -dE/d(eps) under x -> (1 + eps) x of positions and cell."""
    W = np.zeros((3, 3))
    for al in range(3):
        for be in range(3):
            e = []
            for s in (1, -1):
                eps = np.eye(3)
                eps[al, be] += s * h
                a = atoms.copy()
                a.positions = atoms.positions @ eps.T
                a.cell = atoms.cell.array @ eps.T
                a.calc = calc
                e.append(a.get_potential_energy())
            W[al, be] = -(e[0] - e[1]) / (2 * h)
    return W


# -- derivatives --------------------------------------------------------------------------
@pytest.mark.parametrize("pset", ["I", "II"])
@pytest.mark.parametrize("name", list(STRUCTS))
def test_forces_and_virial_vs_finite_differences(name, pset):
    atoms = STRUCTS[name].copy()
    calc = Brenner(parameters=pset, conjugation=True)
    atoms.calc = calc
    F = atoms.get_forces()
    W = calc.get_virial()
    Ffd = fd_forces(atoms, Brenner(parameters=pset, conjugation=True))
    Wfd = fd_virial(atoms, Brenner(parameters=pset, conjugation=True))
    assert np.abs(F - Ffd).max() <= 1e-6 * np.abs(F).max()
    assert np.abs(W - Wfd).max() <= 1e-6 * np.abs(W).max()
    # W^T contracted with the transposed deformation: the virial is symmetric
    assert np.allclose(W, W.T, atol=1e-9 * np.abs(W).max())


def test_conjugation_term_is_active_where_expected():
    """F vanishes in perfect sp2/sp3 carbon and at integer coordinations of rattled
    lattices, but not at a vacancy or in the switching region."""
    for name, expect_zero in [("graphene", True), ("tube_vacancy", False),
                              ("stretched_vacancy", False)]:
        a = STRUCTS[name]
        e1 = _energy(a, Brenner(conjugation=True))
        e0 = _energy(a, Brenner(conjugation=False))
        if expect_zero:
            assert e1 == pytest.approx(e0, abs=1e-12)
        else:
            assert abs(e1 - e0) > 1e-3


def _energy(atoms, calc):
    a = atoms.copy()
    a.calc = calc
    return a.get_potential_energy()


# -- invariants ---------------------------------------------------------------------------
def _perfect():
    return {"graphene": rect_graphene(nx=3, ny=2),
            "diamond": bulk("C", "diamond", a=3.57, cubic=True).repeat(2),
            "tube": nanotube(6, 6, length=3)}


@pytest.mark.parametrize("pset", ["I", "II"])
@pytest.mark.parametrize("name", ["graphene", "diamond", "tube"])
def test_perfect_lattice_zero_force_equal_energies(name, pset):
    a = _perfect()[name]
    a.calc = Brenner(parameters=pset)
    F = a.get_forces()
    e = a.get_potential_energies()
    if name == "tube":  # unrelaxed tube: equivalent atoms, equal radial force magnitudes
        assert np.ptp(np.linalg.norm(F, axis=1)) < 1e-10
        assert np.abs(F[:, 2]).max() < 1e-10
    else:
        assert np.abs(F).max() < 1e-10
    assert np.ptp(e) < 1e-10
    assert e.sum() == pytest.approx(a.get_potential_energy(), abs=1e-10)


@pytest.mark.parametrize("name", list(STRUCTS))
def test_forces_sum_to_zero_and_rigid_motion(name):
    a = STRUCTS[name].copy()
    a.calc = Brenner(parameters="I")
    E = a.get_potential_energy()
    assert np.abs(a.get_forces().sum(axis=0)).max() < 1e-10 * len(a)
    b = a.copy()
    b.calc = Brenner(parameters="I")
    b.translate([0.37, -1.1, 2.3])
    assert b.get_potential_energy() == pytest.approx(E, rel=1e-12)
    # a rigid rotation of positions and cell together (any pbc, tube included)
    c = a.copy()
    R = _rotation([1.0, 2.0, 0.5], 0.7)
    c.positions = a.positions @ R.T
    c.cell = a.cell.array @ R.T
    c.calc = Brenner(parameters="I")
    assert c.get_potential_energy() == pytest.approx(E, rel=1e-12)
    assert np.allclose(c.get_forces(), a.get_forces() @ R.T, atol=1e-9)


def _rotation(axis, angle):
    k = np.asarray(axis, float)
    k /= np.linalg.norm(k)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


# -- closed forms -------------------------------------------------------------------------
def closed_form(pset, z, cos_theta):
    """Bond length and energy per atom of a lattice of z equivalent bonds with angle theta:
    e = -D_e B^(S/(S-1)) z/2, r = r_e - ln B / (beta (sqrt(2S) - sqrt(2/S)))."""
    p = brenner_parameters(pset)
    G = p["a0"] * (1 + p["c0"] ** 2 / p["d0"] ** 2
                   - p["c0"] ** 2 / (p["d0"] ** 2 + (1 + cos_theta) ** 2))
    B = (1 + (z - 1) * G) ** (-p["delta"])
    S = p["S"]
    r = p["r_e"] - np.log(B) / (p["beta"] * (np.sqrt(2 * S) - np.sqrt(2 / S)))
    return r, -p["D_e"] * B ** (S / (S - 1)) * z / 2


@pytest.mark.parametrize("pset", ["I", "II"])
def test_lattices_at_closed_form_minimum(pset):
    r, e = closed_form(pset, 3, -0.5)
    g = rect_graphene(a=r * np.sqrt(3), nx=2, ny=1)
    g.calc = Brenner(parameters=pset)
    assert g.get_potential_energy() / len(g) == pytest.approx(e, rel=1e-13)
    assert np.abs(g.get_stress()[:2]).max() < 1e-12
    r, e = closed_form(pset, 4, -1.0 / 3.0)
    d = bulk("C", "diamond", a=4 * r / np.sqrt(3), cubic=True)
    d.calc = Brenner(parameters=pset)
    assert d.get_potential_energy() / len(d) == pytest.approx(e, rel=1e-13)
    assert np.abs(d.get_stress()).max() < 1e-12


# -- the conjugation table ----------------------------------------------------------------
@pytest.mark.parametrize("pset", ["I", "II"])
def test_tabulated_derivatives_are_central_differences(pset):
    F, Fx, Fy = conjugation_table(pset)
    nz = np.argwhere(Fx != 0)
    assert len(nz) == 8
    for a, b, c in nz:
        assert Fx[a, b, c] == pytest.approx((F[a + 1, b, c] - F[a - 1, b, c]) / 2, abs=1e-12)
    assert np.array_equal(F, F.transpose(1, 0, 2))
    assert np.array_equal(Fx, Fy.transpose(1, 0, 2))
    assert F[2, 2, 1] == 0.0 and np.all(F[3, 3] == 0.0)  # graphite / diamond


@pytest.mark.parametrize("pset", ["I", "II"])
def test_interpolation_exact_at_nodes_and_smooth(pset):
    F, Fx, Fy = conjugation_table(pset)
    for a in range(4):
        for b in range(4):
            for c in range(2):
                v, dx, dy, dz = tricubic_hermite(float(a), float(b), 1.0 + c, F, Fx, Fy)
                assert v == pytest.approx(F[a, b, c], abs=1e-15)
                assert dx == pytest.approx(Fx[a, b, c], abs=1e-14)
                assert dy == pytest.approx(Fy[a, b, c], abs=1e-14)
                assert dz == pytest.approx(0.0, abs=1e-14)
    rng = np.random.default_rng(0)
    h = 1e-6
    for _ in range(50):
        x, y = rng.uniform(0, 3, 2)
        z = rng.uniform(1, 2)
        v, dx, dy, dz = tricubic_hermite(x, y, z, F, Fx, Fy)
        num = [(tricubic_hermite(x + h, y, z, F, Fx, Fy)[0]
                - tricubic_hermite(x - h, y, z, F, Fx, Fy)[0]) / (2 * h),
               (tricubic_hermite(x, y + h, z, F, Fx, Fy)[0]
                - tricubic_hermite(x, y - h, z, F, Fx, Fy)[0]) / (2 * h),
               (tricubic_hermite(x, y, z + h, F, Fx, Fy)[0]
                - tricubic_hermite(x, y, z - h, F, Fx, Fy)[0]) / (2 * h)]
        assert np.allclose([dx, dy, dz], num, atol=1e-8)
    assert tricubic_hermite(4.2, 1.0, 7.0, F, Fx, Fy)[0] == pytest.approx(F[3, 1, 1])
    assert conj_switch(2.0) == (1.0, 0.0) and conj_switch(3.0) == (0.0, 0.0)


# -- options and bad input ----------------------------------------------------------------
def test_step_cutoff_changes_only_the_switching_region():
    a = STRUCTS["stretched_vacancy"]
    e_sw = _energy(a, Brenner())
    e_st = _energy(a, Brenner(step_cutoff=True))
    assert abs(e_sw - e_st) > 1e-2
    g = STRUCTS["graphene"]  # all bonds < R1 = 1.7: identical
    assert _energy(g, Brenner(step_cutoff=True)) == pytest.approx(_energy(g, Brenner()),
                                                                  rel=1e-14)


def test_bad_input():
    with pytest.raises(ValueError, match="unknown Brenner parameter set"):
        Brenner(parameters="III")
    a = rect_graphene()
    a[0].symbol = "Si"
    a.calc = Brenner()
    with pytest.raises(ValueError, match="carbon only; the atoms contain Si"):
        a.get_potential_energy()
    b = rect_graphene()
    b.positions[1] = b.positions[0] + [0.1, 0, 0]
    b.calc = Brenner()
    with pytest.raises(OverlappingAtomsError, match="overlap"):
        b.get_potential_energy()


def test_nanotube_without_vacuum_gives_virial_not_stress():
    from ase.calculators.calculator import PropertyNotImplementedError
    t = nanotube(6, 6, length=2)
    t.calc = Brenner()
    t.get_forces()
    assert t.calc.get_virial().shape == (3, 3)
    with pytest.raises(PropertyNotImplementedError):
        t.get_stress()


def test_parameters_keyword_and_set():
    c = Brenner(parameters="I")
    assert c.parameters["parameter_set"] == "I"
    a = STRUCTS["graphene"].copy()
    a.calc = c
    e1 = a.get_potential_energy()
    c.set(parameters="II")
    e2 = a.get_potential_energy()
    assert e2 == pytest.approx(_energy(a, Brenner(parameter_set="II")), rel=1e-14)
    assert abs(e1 - e2) > 1e-3
