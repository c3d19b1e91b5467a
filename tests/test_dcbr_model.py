"""DCBRModel (upscale/models/dcbr/): the coarse tube built from atoms, on the engine.

References are never the new code itself: the validated coarse tube of the old modules
(``upscale.models.dcbr.TubeLattice``, ``DCBRTube``, ``DCBRTubeModel``, validated against
LAMMPS by the dcbr-seeds / dcbr-energy cases), the closed form of a uniformly strained
tube (the energy per atom of its two-atom helical cell), and central finite differences.
"""
import numpy as np
import pytest
from ase import Atoms

from upscale.build import graphene, swcnt
from upscale.defects import apply_defects
from upscale.engine import State
from upscale.models.dcbr import DCBRTube, DCBRTubeModel, TubeLattice, tersoff_params
from upscale.models.dcbr.cell import TubeCell, tersoff_row
from upscale.models.dcbr.model import FIELD, DCBRModel
from upscale.models.dcbr.structure import register
from upscale.models.dcbr.tube import CoarseTube

TUBES = [((10, 10), 100.0, 2.0), ((10, 10), 150.0, 3.0), ((17, 0), 100.0, 3.0),
         ((12, 6), 100.0, 2.0)]


def perturbed(x0, L, stretch=(1.01, 1.01, 1.03), noise=0.05, seed=1):
    """A strained, noisy configuration of reference positions x0 about z (periodic L)."""
    rng = np.random.default_rng(seed)
    return x0 * np.array(stretch) + noise * rng.standard_normal(x0.shape), L * stretch[2]


@pytest.mark.parametrize("nm", [(10, 10), (17, 0), (12, 6)])
def test_lattice_cell_is_the_old_one_on_the_one_tersoff(nm):
    """The particle lattice through potentials.tersoff_kernels against the old second
    Tersoff: the same patch, the same energy per atom bit for bit, the gradient to
    round-off (the b_ij derivative and f_C' are written differently)."""
    old, new = TubeLattice.build(*nm), TubeCell.build(*nm)
    assert np.array_equal(old.s, new.s_p) and np.array_equal(old.candB, new.candB)
    p_old, P_new = tersoff_params(), tersoff_row()
    for q in ([1, 0, 1, 0, 0, 0], [0.98, 0.03, 1.12, 0.01, -0.02, 0.03],
              [1.02, -0.05, 0.95, -0.03, 0.04, 0.0]):
        e_o, g_o = old.energy(np.array(q, float), p_old)
        e_n, g_n = new.energy(q, P_new)
        assert e_n == e_o
        np.testing.assert_allclose(g_n, g_o, rtol=0, atol=1e-13)


@pytest.mark.parametrize("nm,length,K", TUBES)
def test_coarse_energy_and_forces_are_the_old_tubes(nm, length, K):
    """Same particles, energy, forces, shift and cell gradients as the old DCBRTube at a
    strained noisy configuration with random shifts: to 1e-12 relative (sums in another
    order: the engine's family orders a row's links by index, the old one by image)."""
    atoms = swcnt(*nm, length=length)
    tube = register(atoms).tubes[0]
    for hg in (0.0, 0.1):
        old = DCBRTube(*nm, length, coarsening=K, stability=False, hourglass=hg)
        new = CoarseTube(tube, len(atoms), K, 1.5, "BNC.tersoff", hg)
        assert new.N == old.N and (new.n_theta, new.n_z) == (old.n_theta, old.n_z)
        np.testing.assert_allclose(new.x0 - new.centre, old.x0, rtol=0, atol=1e-12)
        if hg:
            # c_zz is a second difference of relaxed energies: 1e-9 apart between the old
            # BFGS and the new Newton relaxation; the term itself is compared with one k_s
            assert new.hourglass.k_stab == pytest.approx(old.k_stab, rel=1e-8)
            new.hourglass.k_stab = old.k_stab
        y, L = perturbed(old.x0, old.L)
        d = 0.02 * np.random.default_rng(2).standard_normal((old.N, 3))
        Eo, gyo, gdo, gLo = old.energy_and_gradient(y, d, L)
        En, gyn, gdn, gLn, _, _ = new.evaluate(y + new.centre, d, L)
        assert En == pytest.approx(Eo, rel=1e-12)
        np.testing.assert_allclose(gyn, gyo, rtol=0, atol=1e-12 * np.abs(gyo).max())
        np.testing.assert_allclose(gdn, gdo, rtol=0, atol=1e-12 * np.abs(gdo).max())
        assert gLn == pytest.approx(gLo, rel=1e-11)


def test_link_rule_breaks_the_old_tubes_links_and_g_is_refitted_alike():
    """A tube stretched 5 % with a 6 Å axial step across its middle: the link rule breaks
    the same links (owner, partner, image) as the old DCBRTube.update_links; with them
    out of G the same particles drop out and the energy and forces agree again."""
    from upscale.models.dcbr.failure import link_rule

    atoms = swcnt(10, 10, length=100.0)
    old = DCBRTube(10, 10, 100.0, coarsening=2.0, stability=False)
    new = CoarseTube(register(atoms).tubes[0], len(atoms), 2.0, 1.5, "BNC.tersoff", 0.1)
    new.hourglass.k_stab = old.k_stab
    y = old.x0.copy()
    y[:, 2] = 1.05 * (y[:, 2] + np.where(old.x0[:, 2] > old.L / 2, 6.0, 0.0))
    d, L = np.zeros((old.N, 3)), 1.05 * old.L + 6.0
    old.energy_and_gradient(y, d, L)
    assert old.update_links() > 100
    over = link_rule(new, new.evaluate(y + new.centre, d, L)[4])
    g = new.gain
    broken_old = set(zip(old.gain.pair_i[~old.intact].tolist(),
                         old.gain.pair_j[~old.intact].tolist(),
                         old.gain.pair_image[~old.intact][:, 2].tolist()))
    assert set(zip(g.owner_b[over].tolist(), g.j_b[over].tolist(),
                   g.k_b[over].astype(int).tolist())) == broken_old
    new.rebuild(g.intact_b & ~over, new.alive)
    assert np.array_equal(new.alive, old.alive) and (~new.alive).sum() > 0
    Eo, gyo, _, _ = old.energy_and_gradient(y, d, L)
    En, gyn = new.evaluate(y + new.centre, d, L)[:2]
    assert En == pytest.approx(Eo, rel=1e-11)
    np.testing.assert_allclose(gyn, gyo, rtol=0, atol=1e-11 * np.abs(gyo).max())


def test_model_on_the_engine_state_is_the_old_engine_model():
    """DCBRModel (shifts relaxed at every configuration) against DCBRTubeModel on the same
    engine state: energy, forces and the cell's axial force (the shifts relax to 1e-10
    eV/Å: the forces are compared to 1e-8 relative)."""
    atoms = swcnt(10, 10, length=100.0)
    new = DCBRModel(atoms, 2.0)
    tube = DCBRTube(10, 10, 100.0, coarsening=2.0, stability=False)
    new.tube.hourglass.k_stab = tube.k_stab
    old = DCBRTubeModel(tube, failure=False)
    y, L = perturbed(tube.x0, tube.L, noise=0.02)
    so, sn = State.reference(tube.x0, 0), State.reference(new.x0, 0)
    so.y[...], sn.y[...] = y, y + new.tube.centre
    old.init_state(so)
    new.init_state(sn)
    old.set_cell(L)
    new.set_cell(L)
    assert new.energy(sn) == pytest.approx(old.energy(so), rel=1e-10)
    fo, fn = old.force(so), new.force(sn)
    np.testing.assert_allclose(fn, fo, rtol=0, atol=1e-8 * np.abs(fo).max())
    assert new.cell_force(sn) == pytest.approx(old.cell_force(so), rel=1e-8)
    np.testing.assert_allclose(sn.extra[FIELD], so.extra["dcbr.delta"], atol=1e-8)


@pytest.mark.parametrize("nm", [(10, 10), (12, 6)])
def test_uniform_strain_energy_is_the_helical_cells(nm):
    """A periodic tube stretched uniformly (axial lam_z, radial lam_t) has, per atom, the
    energy of its own two-atom helical cell with the shift relaxed (closed form: the
    uniformly strained tube is that cell), e(lam_t, 0, lam_z) - e0."""
    atoms = swcnt(*nm, length=80.0)
    model = DCBRModel(atoms, 2.0)
    t = model.tube
    st = State.reference(model.x0, 0)
    model.init_state(st)
    for lam_t, lam_z in ((1.0, 1.05), (0.99, 1.1), (1.01, 0.97)):
        model.set_cell(t.L * lam_z)
        c = t.centre
        st.y[...] = c + (model.x0 - c) * np.array([lam_t, lam_t, lam_z])
        E = model.energy(st)
        e_cell, _ = TubeCell.build(*nm, t.bond).relaxed(lam_t, 0.0, lam_z, tersoff_row())
        assert E / t.n_atoms == pytest.approx(e_cell - t.e0, rel=1e-9, abs=1e-12)
        assert t.hourglass.w_n.sum() < 1e-20


def test_zero_force_on_the_relaxed_uniform_lattice_and_forces_sum_to_zero():
    """At the radius where the energy of the uniformly stretched periodic tube is
    stationary every particle force vanishes (by symmetry they are radial and equal); at any state
    the forces sum to zero (translation invariance, sum_b a_b = 0)."""
    from scipy.optimize import brentq

    model = DCBRModel(swcnt(10, 10, length=60.0), 2.0)
    t = model.tube
    st = State.reference(model.x0, 0)
    model.init_state(st)
    model.set_cell(1.04 * t.L)
    c = t.centre
    r = (model.x0 - c) * np.array([1.0, 1.0, 0.0])

    def dE_dlam(lam_t):  # the radial force's virial: dE/d lam_t of the uniform map
        st.y[...] = c + (model.x0 - c) * np.array([lam_t, lam_t, 1.04])
        return -float(np.sum(model.force(st) * r))

    lam = brentq(dE_dlam, 0.9, 1.05, xtol=1e-14)
    dE_dlam(lam)
    f = model.force(st)
    assert np.abs(f).max() < 1e-9
    y, L = perturbed(model.x0 - c, t.L)
    st.y[...] = y + c
    model.set_cell(L)
    f = model.force(st)
    assert np.abs(f).max() > 0.1
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-10 * np.abs(f).max() * t.N)


def test_gradients_against_finite_differences():
    """dE/dy, dE/d delta and dE/dL of the energy at fixed shifts against central
    differences (step 1e-5 Å), hourglass term included, a chiral tube."""
    model = DCBRModel(swcnt(12, 6, length=60.0), 2.0)
    t = model.tube
    y, L = perturbed(model.x0 - t.centre, t.L)
    y += t.centre
    d = 0.01 * np.random.default_rng(3).standard_normal((t.N, 3))
    E, gy, gd, gL = model.evaluate(y, d, L)
    h = 1e-5
    rng = np.random.default_rng(4)
    for arr, g in ((y, gy), (d, gd)):
        for _ in range(6):
            i, k = rng.integers(len(arr)), rng.integers(3)
            arr[i, k] += h
            Ep = model.evaluate(y, d, L)[0]
            arr[i, k] -= 2 * h
            Em = model.evaluate(y, d, L)[0]
            arr[i, k] += h
            assert (Ep - Em) / (2 * h) == pytest.approx(g[i, k], rel=1e-5, abs=1e-6)
    fd = (model.evaluate(y, d, L + h)[0] - model.evaluate(y, d, L - h)[0]) / (2 * h)
    assert fd == pytest.approx(gL, rel=1e-5)


def test_quasi_static_strain_steps_on_the_engine_minimiser():
    """Three strain steps of a periodic tube, each relaxed by the engine's L-BFGS-B with
    the shifts as its internal field: converged, energy and axial force rising, forces
    finite; then the link rule breaks nothing at 3 % strain."""
    from upscale.engine.minimisers import LBFGS
    from upscale.engine.simulation import Simulation

    model = DCBRModel(swcnt(10, 10, length=60.0), 3.0)
    sim = Simulation(model.system(), None, [model])
    E_prev, f_prev = -np.inf, -np.inf
    for strain in (0.01, 0.02, 0.03):
        model.set_cell(model.tube.L * (1 + strain))
        sim.state.y[:, 2] = model.x0[:, 2] * (1 + strain)
        r = sim.minimise(LBFGS(ftol=1e-6, max_iter=2000))
        assert r.converged
        E, fz = model.energy(sim.state), model.cell_force(sim.state)
        assert E > E_prev and fz > f_prev
        E_prev, f_prev = E, fz
    assert np.isfinite(sim.forces()).all() and model.break_bonds(sim.state) == 0
    assert sim.damage().max() == 0.0


def seed_vacancy_tube(nm, length, K):
    """The old defect tube (4-atom vacancy, 8 Å band) and the new model of the same atoms
    (the band given as a selection; the atoms moved so the axis is the old frame's z axis,
    so that distances that tie on the symmetric lattice are rounded as in the old frame)."""
    from upscale.build import vacancy
    from upscale.models.dcbr_defect import DCBRDefectTube

    old = DCBRDefectTube(*nm, length, coarsening=K, vacancy=4, r_atomistic=8.0,
                         stability=False)
    atoms = vacancy(swcnt(*nm, length=length), n=4)
    atoms.positions = atoms.positions - [*atoms.info["axis_xy"], 0.0]
    zc = atoms.info["vacancy"]["at"][2]
    band = np.abs(atoms.positions[:, 2] - zc) < 8.0
    new = DCBRModel(atoms, K, r_atomistic=0.0, select=band)
    new.tube.hourglass.k_stab = old.k_stab  # (compared above, 1e-8: its c_zz)
    return old, new


def assert_same_coupled_structure(old, new):
    c = new.coupling
    assert np.array_equal(c.dof_idx, old.dof_idx) and np.array_equal(c.slave_idx, old.slave_idx)
    assert c.nf == old.nf and len(c.pad_idx) == len(old.pad_idx)
    np.testing.assert_allclose(c.Xf - new.tube.centre, old.Xf, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(new.tube.natoms_n, old.natoms_n)


def assert_same_evaluation(old, new, y, d, L, rel=1e-11):
    Eo, gyo, gdo, gLo = old.energy_and_gradient(y, d, L)
    En, gyn, gdn, gLn = new.coupling.evaluate(y + new.tube.centre, d, L)[:4]
    assert En == pytest.approx(Eo, rel=rel)
    np.testing.assert_allclose(gyn, gyo, rtol=0, atol=rel * np.abs(gyo).max())
    np.testing.assert_allclose(gdn, gdo, rtol=0, atol=rel * np.abs(gdo).max())
    assert gLn == pytest.approx(gLo, rel=rel)


@pytest.mark.parametrize("nm,K", [((10, 10), 3.0), ((12, 6), 2.0)])
def test_coupled_vacancy_tube_is_the_old_defect_tube(nm, K):
    """The seed's 4-atom vacancy with its atomistic band: the same free atoms, slave
    particles, pads and weights as the old DCBRDefectTube, and the same energy and
    gradients (the coupling's, without the ghost-force load) at a strained noisy
    configuration with random shifts, to 1e-11 relative (sums in another order)."""
    old, new = seed_vacancy_tube(nm, 150.0, K)
    assert_same_coupled_structure(old, new)
    rng = np.random.default_rng(1)
    y = old.y_init * np.array([1.01, 1.01, 1.02]) + 0.02 * rng.standard_normal(old.y_init.shape)
    assert_same_evaluation(old, new, y, 0.01 * rng.standard_normal((old.N, 3)), 1.02 * old.L)


def test_coupled_tube_is_the_old_engine_model():
    """The old engine adapter (DCBRDefectTubeModel: rows = every particle then the free
    atoms, shifts a field) on an engine state against the new coupling at the same rows and
    shifts: energy and the forces on the non-slave particles and the atoms, to 1e-12."""
    from upscale.models.dcbr_engine import FIELD as OLD_FIELD
    from upscale.models.dcbr_engine import DCBRDefectTubeModel

    old, new = seed_vacancy_tube((12, 6), 150.0, 2.0)
    L = 1.02 * old.L
    om = DCBRDefectTubeModel(old, Lz=L)
    body = om.system()
    om.prepare(body)
    st = State.reference(body.x0, 0)
    om.init_state(st)
    rng = np.random.default_rng(1)
    y = old.y_init * np.array([1.01, 1.01, 1.02]) + 0.02 * rng.standard_normal(old.y_init.shape)
    st.y[...] = om.rows(y)
    st.fields[OLD_FIELD][:old.N] = 0.01 * rng.standard_normal((old.N, 3))
    E, gy = new.coupling.evaluate(y + new.tube.centre, st.fields[OLD_FIELD][:old.N], L)[:2]
    assert E == pytest.approx(om.energy(st), rel=1e-12)
    f = om.force(st)
    nd = len(old.dof_idx)
    np.testing.assert_allclose(-gy[:nd], f[old.dof_idx], rtol=0, atol=1e-12 * np.abs(f).max())
    np.testing.assert_allclose(-gy[nd:], f[old.N:], rtol=0, atol=1e-12 * np.abs(f).max())


@pytest.mark.parametrize("nm,K", [((10, 10), 2.0), ((17, 0), 3.0)])
def test_coupled_vacancy_tube_ties_and_uniform_states(nm, K):
    """Where pad atoms or slave fits tie between two equidistant particles (1e-14 Å apart
    on these lattices) the old and the new code may take different ones (both break the
    tie by round-off); the structure is the same, and at uniform states, where every
    carrier's map and every fit give the same positions, so is the energy."""
    old, new = seed_vacancy_tube(nm, 150.0, K)
    assert_same_coupled_structure(old, new)
    for lam_t, lam_z, shift in ((1.0, 1.0, 0.0), (0.99, 1.05, 0.01), (1.01, 0.98, -0.02)):
        y = old.y_init * np.array([lam_t, lam_t, lam_z])
        d = np.full((old.N, 3), shift)
        Eo = old.energy_and_gradient(y, d, lam_z * old.L)[0]
        En = new.coupling.evaluate(y + new.tube.centre, d, lam_z * old.L)[0]
        assert En == pytest.approx(Eo, rel=1e-12)


@pytest.mark.parametrize("nm,K", [((10, 10), 3.0), ((12, 6), 2.0)])
def test_ghost_force_load_is_the_old_tubes(nm, K):
    """The dead load of the pristine twin at 2 % strain (the old prepare_step): the same
    largest ghost forces (1e-11). The old tube applied it in cylindrical components about
    the rows' centroid, the new one turned with the rows (module docstring of
    ``upscale.models.dcbr.ghost``): on the segment from the load's uniform state u to a
    strained noisy configuration, the corrected energies differ at second order (the
    difference falls 4x when the distance to u halves) and the gradients at first order
    (2x), dE/d delta and dE/dL agree (1e-11, 1e-9)."""
    from upscale.models.dcbr.ghost import uniform_lattice

    old, new = seed_vacancy_tube(nm, 150.0, K)
    new.ghost.twin_tube.hourglass.k_stab = old.k_stab
    L = 1.02 * old.L
    io = old.prepare_step(L)
    new.set_cell(L)
    inn = new.ghost.prepare(L)
    for k in io:
        assert inn[k] == pytest.approx(io[k], rel=1e-11)
    t = new.tube
    lt, sh = uniform_lattice(t.cell, t.P_f, 1.02)
    yu, du = new.ghost.tube_uniform_state(lt, 1.02, sh)
    rng = np.random.default_rng(1)
    y = old.y_init * np.array([1.01, 1.01, 1.02]) + 0.02 * rng.standard_normal(old.y_init.shape)
    d = 0.01 * rng.standard_normal((old.N, 3))
    dE, dg = [], []
    for s in (1.0, 0.5, 0.25):
        ys, ds = yu + s * (y + t.centre - yu), du + s * (d - du)
        Eo, gyo, gdo, gLo = old.energy_and_gradient(ys - t.centre, ds, L)
        En, gyn, gdn, gLn = new.evaluate(ys, ds, L)
        dE.append(En - Eo)
        dg.append(np.abs(gyn - gyo).max())
        np.testing.assert_allclose(gdn, gdo, rtol=0, atol=1e-11 * np.abs(gdo).max())
        assert gLn == pytest.approx(gLo, rel=1e-9)
    assert abs(dE[0]) < 1e-3 * abs(Eo) and dg[0] < 2e-3 * np.abs(gyo).max()
    assert dE[1] / dE[0] == pytest.approx(0.25, abs=0.02)
    assert dE[2] / dE[1] == pytest.approx(0.25, abs=0.02)
    assert dg[1] / dg[0] == pytest.approx(0.5, abs=0.05)
    assert dg[2] / dg[1] == pytest.approx(0.5, abs=0.05)


def four_defect_model():
    atoms = apply_defects(swcnt(10, 10, length=150.0),
                          "v1@0.15@0,v2@0.4@90,v4@0.65@180,sw@0.88@270")
    return DCBRModel(atoms, 2.0, r_atomistic=6.0)


def test_structure_with_defects_of_four_kinds_has_a_region_at_each():
    """v1, v2, v4 and Stone-Wales on one tube: found, each inside an atomistic region whose
    atoms are free rows of the model; momentum conserved (the gradient sums to zero)."""
    model = four_defect_model()
    assert sorted(d.kind for d in model.defects) == ["sw", "v1", "v2", "v4"]
    assert len(model.regions.regions) == 4
    free = set(model.coupling.free_idx.tolist())
    for dfc in model.defects:
        assert set(dfc.atoms.tolist()) <= free
    rng = np.random.default_rng(0)
    t = model.tube
    y = t.centre + (model.x0 - t.centre) * [1.0, 1.0, 1.01] + 0.01 * rng.standard_normal(
        model.x0.shape)
    E, gy, gd, gL = model.evaluate(y, 0.005 * rng.standard_normal((t.N, 3)), 1.01 * t.L)
    assert np.isfinite(E) and np.abs(gy).max() > 0.1
    np.testing.assert_allclose(gy.sum(axis=0), 0.0, atol=1e-11 * np.abs(gy).max() * len(gy))


def test_coupled_gradients_against_finite_differences():
    """The four-defect tube: dE/dy of particles and atoms (through slaves and pads),
    dE/d delta and dE/dL against central differences (step 1e-5 Å)."""
    model = four_defect_model()
    t = model.tube
    rng = np.random.default_rng(5)
    y = t.centre + (model.x0 - t.centre) * [1.0, 1.0, 1.01] + 0.01 * rng.standard_normal(
        model.x0.shape)
    d = 0.005 * rng.standard_normal((t.N, 3))
    L = 1.01 * t.L
    E, gy, gd, gL = model.evaluate(y, d, L)
    h = 1e-5
    nd = len(model.coupling.dof_idx)
    slaves_pads = np.unique(np.r_[model.coupling.pad_c])
    rows = [rng.integers(nd), rng.integers(nd, len(y)), rng.integers(nd, len(y)),
            int(np.flatnonzero(np.isin(model.coupling.dof_idx, slaves_pads))[0])]
    for arr, g, idx in ((y, gy, rows), (d, gd, [int(slaves_pads[0]), rng.integers(t.N)])):
        for i in idx:
            for k in range(3):
                arr[i, k] += h
                Ep = model.evaluate(y, d, L)[0]
                arr[i, k] -= 2 * h
                Em = model.evaluate(y, d, L)[0]
                arr[i, k] += h
                assert (Ep - Em) / (2 * h) == pytest.approx(g[i, k], rel=1e-5, abs=2e-6)
    fd = (model.evaluate(y, d, L + h)[0] - model.evaluate(y, d, L - h)[0]) / (2 * h)
    assert fd == pytest.approx(gL, rel=1e-5)


@pytest.mark.slow
def test_coupled_tube_quasi_static_steps_on_the_engine():
    """The four-defect tube relaxed by the engine's L-BFGS-B (shifts as its internal
    field) at 2 and 4 % strain (past the 1.42 Å reference's own compression, about 1.4 %
    for BNC.tersoff): converged, the energy and axial force rise."""
    from upscale.engine.minimisers import LBFGS
    from upscale.engine.simulation import Simulation

    model = four_defect_model()
    sim = Simulation(model.system(), None, [model])
    c, L0 = model.tube.centre, model.tube.L
    out = []
    for strain in (0.02, 0.04):
        model.set_cell(L0 * (1 + strain))
        sim.state.y[:, 2] = c[2] + (model.x0[:, 2] - c[2]) * (1 + strain)
        r = sim.minimise(LBFGS(ftol=1e-4, max_iter=3000))
        assert r.converged
        out.append((model.energy(sim.state), model.cell_force(sim.state)))
    assert out[1][0] > out[0][0] and out[1][1] > out[0][1] > 0.0
    assert np.isfinite(sim.forces()).all()
    mu = sim.damage()  # per row: particles (no link broken here), then atoms (bonds)
    assert mu.shape == (model.n,) and mu[:len(model.coupling.dof_idx)].max() == 0.0
    assert 0.0 <= mu.min() and mu.max() <= 1.0


def test_bad_input_one_line_errors():
    tube = swcnt(10, 10, length=40.0)
    cases = [
        (graphene(6, 6), "a sheet, not a tube"),
        (Atoms("C2", positions=[[0, 0, 0], [0, 0, 1.42]]), "no nanotube"),
        (Atoms("Si" + "C" * (len(tube) - 1), positions=tube.positions, cell=tube.cell,
               pbc=tube.pbc), "Si.*valid: carbon"),
    ]
    for atoms, msg in cases:
        with pytest.raises(ValueError, match=msg):
            DCBRModel(atoms, 2.0)
    with pytest.raises(ValueError, match=r"coarsening=8 leaves 2 particle rows along the "
                       r"tube's 39.35 Å; valid: 1 <= coarsening <= 6.4"):
        DCBRModel(tube, 8.0)
    short = swcnt(10, 10, length=6.0)
    short.pbc = False
    del short[short.positions[:, 2] > 3.9]
    with pytest.raises(ValueError, match=r"3.69 Å long; valid: at least two bond cutoffs"):
        DCBRModel(short, 1.0)
    with pytest.raises(ValueError, match="coarsening=0.5; valid: a number >= 1"):
        DCBRModel(tube, 0.5)
    with pytest.raises(ValueError, match="selects no atom"):
        DCBRModel(tube, 2.0, select=lambda p: p[:, 2] > 1e6)
    with pytest.raises(ValueError, match="horizon_factor=1.0; valid: a number > 1"):
        DCBRModel(tube, 2.0, horizon_factor=1.0)
    with pytest.raises(ValueError, match="tubes; valid: one tube"):
        DCBRModel(swcnt(10, 10, length=40.0) + _shifted(swcnt(10, 10, length=40.0)), 2.0)


def _shifted(atoms):
    atoms = atoms.copy()
    atoms.positions[:, 0] += 20.0
    return atoms


def uniform_state(model, lam_z, seed=0):
    """A model's rows on the uniform relaxed lattice of axial stretch lam_z (its period
    set), shifts relaxed, random velocities; the shifts held (a minimiser's state)."""
    from upscale.models.dcbr.ghost import uniform_lattice

    t = model.tube
    model.set_cell(lam_z * t.L)
    lt, sh = uniform_lattice(t.cell, t.P_f, lam_z)
    if model.ghost is not None:
        y, _ = model.ghost.tube_uniform_state(lt, lam_z, sh)
    else:
        y = t.centre + (t.x0 - t.centre) * np.array([lt, lt, lam_z])
    st = State(model.x0, y, 1e-3 * np.random.default_rng(seed).standard_normal(y.shape),
               np.ones(0, bool))
    model.init_state(st)
    st.extra[FIELD][...] = sh
    model.hold_internal(True)
    return st


@pytest.mark.parametrize("start", ["coarse", "band"])
def test_switch_at_zero_kelvin_uniform_strain(start):
    """Particles replaced by their atoms on a uniformly stretched (4 %) periodic tube, from
    a coarse tube or growing a selected band: no energy jump (< 1e-10 eV per new atom), no
    force on any row (< 1e-9 eV/Å: the new atoms sit on their carriers' maps, the ghost
    load rebuilt), momentum equal after the correction (it differed before: particle
    masses are not the atoms' they stand for)."""
    from upscale.models.dcbr.switch import switch

    atoms = swcnt(10, 10, length=100.0) if start == "coarse" else swcnt(12, 6, length=100.0)
    zc = atoms.positions[:, 2].mean()
    select = None if start == "coarse" else np.abs(atoms.positions[:, 2] - zc) < 6.0
    model = DCBRModel(atoms, 2.0, select=select)
    st = uniform_state(model, 1.04)
    assert np.abs(model.force(st)).max() < 1e-9
    t = model.tube
    near = np.abs((t.x0 - t.centre) @ t.axis - zc) < 12.0
    if model.coupling is not None:
        near &= ~model.coupling.inside
    P0 = model.masses() @ st.v
    new, st2, log = switch(model, st, near)
    assert log.atoms_added >= 9 * near.sum()
    assert abs(log.energy_change_per_atom_eV) < 1e-10
    assert log.max_new_atom_force_eV_A < 1e-9 and np.abs(new.force(st2)).max() < 1e-9
    assert np.abs(log.momentum_change_before_correction).max() > 1e-3
    np.testing.assert_allclose(new.masses() @ st2.v, P0, rtol=0, atol=1e-12 * np.abs(P0).max()
                               + 1e-12)
    assert new.coupling.inside[near].all()
    # the region travels with the state: a model rebuilt from it is the same, bit for bit
    again = DCBRModel(atoms, atomistic_particles=st2.extra["dcbr.inside"], **model.params)
    again.set_cell(new.Lz)
    again.hold_internal(True)
    assert np.array_equal(again.x0, new.x0) and again.energy(st2) == new.energy(st2)
    assert np.array_equal(again.force(st2), new.force(st2))


def test_flagged_particles_and_a_run_after_the_switch():
    """No link nears failure at 10 % uniform strain; a 3 Å axial step across the middle
    flags the particles at the step (links whose bond passes 0.8 x 2.1 Å). Switched, the
    grown model relaxes on the engine's L-BFGS-B (no blow-up, converged)."""
    from upscale.engine.minimisers import LBFGS
    from upscale.engine.simulation import Simulation
    from upscale.models.dcbr.switch import flagged_particles, switch

    model = DCBRModel(swcnt(10, 10, length=80.0), 2.0)
    st = uniform_state(model, 1.10)
    assert not flagged_particles(model, st, 0.8).any()
    t = model.tube
    z = (t.x0 - t.centre) @ t.axis
    st.y[:, 2] += np.where(z > t.L / 2, 3.0, 0.0)
    flagged = flagged_particles(model, st, 0.8)
    assert flagged.any() and np.all(np.abs(z[flagged] - t.L / 2) < 2 * max(t.spacing))
    new, st2, log = switch(model, st, flagged)
    assert log.atoms_added > 0 and np.isfinite(log.energy_after_eV)
    sim = Simulation(new.system(), None, [new], state=st2)
    r = sim.minimise(LBFGS(ftol=1e-3, max_iter=3000))
    assert r.converged and np.isfinite(new.energy(sim.state))


def test_short_nve_run_conserves_energy():
    """200 velocity-Verlet steps of 1 fs of a periodic tube at 2 % strain, random
    velocities (shifts relaxed at every force): the total energy stays within 1e-3 of the
    kinetic energy, no drift, no blow-up."""
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.simulation import Simulation

    model = DCBRModel(swcnt(10, 10, length=80.0), 2.0, failure=False)
    model.set_cell(1.02 * model.tube.L)
    sim = Simulation(model.system(), None, [model], integrator=VelocityVerlet(dt=1.0, force=True))
    c = model.tube.centre
    sim.state.y[...] = c + (model.x0 - c) * np.array([1.0, 1.0, 1.02])
    v = 0.002 * np.random.default_rng(0).standard_normal(sim.state.y.shape)
    sim.state.v[...] = v - v.mean(axis=0)
    sim.update_forces()
    K0 = sim.kinetic_energy()
    E0 = sim.energy() + K0
    for _ in range(10):
        sim.run(20)
        assert abs(sim.energy() + sim.kinetic_energy() - E0) < 1e-3 * K0
    assert np.isfinite(sim.state.y).all()


def test_region_across_the_periodic_boundary():
    """A divacancy at the periodic boundary (its region on both ends of the cell, handled,
    not refused): momentum and central differences of dE/dy (atoms, a pad carrier) and
    dE/dL (atoms across the boundary, slaves that follow the images of their atoms); a
    pristine band across the boundary, ghost-corrected, is force-free at 3 % strain."""
    atoms = apply_defects(swcnt(10, 10, length=100.0), "v2@0.01@0,sw@0.5@90")
    model = DCBRModel(atoms, 2.0, r_atomistic=6.0)
    c, t = model.coupling, model.tube
    z = ((c.Xf - t.centre) @ t.axis) % t.L
    assert z.min() < 3.0 and z.max() > t.L - 3.0 and np.count_nonzero(c.kphi) > 0
    rng = np.random.default_rng(0)
    L = 1.01 * t.L
    y = t.centre + (model.x0 - t.centre) * [1.0, 1.0, 1.01] + 0.01 * rng.standard_normal(
        model.x0.shape)
    d = 0.005 * rng.standard_normal((t.N, 3))
    E, gy, gd, gL = model.evaluate(y, d, L)
    np.testing.assert_allclose(gy.sum(axis=0), 0.0, atol=1e-11 * np.abs(gy).max() * len(gy))
    h = 1e-5
    assert (model.evaluate(y, d, L + h)[0] - model.evaluate(y, d, L - h)[0]) / (2 * h) == \
        pytest.approx(gL, rel=1e-6)
    nd = len(c.dof_idx)
    edge = nd + int(np.argmin(z))
    for i in (edge, nd + int(np.argmax(z)), int(np.flatnonzero(np.isin(c.dof_idx, c.pad_c))[0])):
        for k in range(3):
            y[i, k] += h
            Ep = model.evaluate(y, d, L)[0]
            y[i, k] -= 2 * h
            Em = model.evaluate(y, d, L)[0]
            y[i, k] += h
            assert (Ep - Em) / (2 * h) == pytest.approx(gy[i, k], rel=1e-5, abs=2e-6)
    atoms = swcnt(12, 6, length=100.0)
    zz = atoms.positions[:, 2]
    band = DCBRModel(atoms, 2.0, select=(zz < 5.0) | (zz > atoms.info["length"] - 5.0))
    st = uniform_state(band, 1.03)
    assert np.abs(band.coupling.evaluate(st.y, st.extra[FIELD], band.Lz)[1]).max() > 0.3
    assert np.abs(band.force(st)).max() < 1e-9


def test_finite_tube_with_a_defect():
    """An open (12,6) tube with a monovacancy: the axis refined on the atoms (the particles
    on the atoms' wall), a rigid turn and shift cost nothing (1e-12 relative), momentum,
    and central differences of dE/dy."""
    atoms = apply_defects(swcnt(12, 6, length=120.0), "v1@0.5@0")
    atoms.pbc = False
    model = DCBRModel(atoms, 2.0, r_atomistic=6.0)
    t, c = model.tube, model.coupling
    assert not t.periodic and model.ghost is None and model.Lz is None
    assert np.abs(c.slave_off).max() < 1e-9
    rng = np.random.default_rng(0)
    y = model.x0 + 0.01 * rng.standard_normal(model.x0.shape)
    d = 0.005 * rng.standard_normal((t.N, 3))
    E, gy, gd, gL = model.evaluate(y, d)
    np.testing.assert_allclose(gy.sum(axis=0), 0.0, atol=1e-11 * np.abs(gy).max() * len(gy))
    a = 0.4
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    assert model.evaluate(y @ R.T + [1.0, 2.0, 3.0], d)[0] == pytest.approx(E, rel=1e-12)
    h = 1e-5
    for i in (0, len(y) - 1, int(rng.integers(len(y)))):
        for k in range(3):
            y[i, k] += h
            Ep = model.evaluate(y, d)[0]
            y[i, k] -= 2 * h
            Em = model.evaluate(y, d)[0]
            y[i, k] += h
            assert (Ep - Em) / (2 * h) == pytest.approx(gy[i, k], rel=1e-5, abs=2e-6)


def test_link_rule_on_the_coupled_tube():
    """A tube with a monovacancy and a 9 Å axial step beyond its region (no ghost load):
    the link rule breaks links (particles drop out, damage on particle rows), the region's
    pads keep their carriers' last maps, and afterwards the forces still sum to zero and
    match central differences."""
    atoms = apply_defects(swcnt(10, 10, length=150.0), "v1@0.3@0")
    model = DCBRModel(atoms, 2.0, r_atomistic=6.0, ghost=False)
    t, c = model.tube, model.coupling
    st = State(model.x0, model.x0.copy(), np.zeros_like(model.x0), np.ones(0, bool))
    model.init_state(st)
    z = (st.y - t.centre) @ t.axis
    st.y[:, 2] += np.where(z > model.defects[0].z + 12.0, 9.0, 0.0)
    model.set_cell(t.L + 9.0)
    model.hold_internal(True)
    assert model.break_bonds(st) > 0 and (~t.alive).any()
    nd = len(c.dof_idx)
    mu = model.particle_damage(st)
    assert mu[:nd].max() > 0.5 and not st.extra["dcbr.intact"].all()
    y, d = st.y.copy(), st.extra[FIELD].copy()
    E, gy, gd, gL = model.evaluate(y, d)
    assert np.isfinite(E)
    np.testing.assert_allclose(gy.sum(axis=0), 0.0, atol=1e-11 * np.abs(gy).max() * len(gy))
    h = 1e-5
    for i in (int(np.flatnonzero(mu[:nd] > 0)[-1]), nd + 5):
        for k in range(3):
            y[i, k] += h
            Ep = model.evaluate(y, d)[0]
            y[i, k] -= 2 * h
            Em = model.evaluate(y, d)[0]
            y[i, k] += h
            assert (Ep - Em) / (2 * h) == pytest.approx(gy[i, k], rel=1e-5, abs=2e-6)


@pytest.mark.parametrize("defects", ["", "v2@0.5@0"])
def test_atom_positions_reconstruct_the_tube(defects):
    """Every atom from the model's state: at the reference the input atoms (1e-12 Å); on
    the uniform relaxed lattice at 4 % stretch the closed-form uniform map of the input
    atoms, (lam_t R0 + s d_rho, theta + s d_s / (lam_t R0), lam_z z + s d_z) for sublattice
    s (1e-12 Å, modulo the period)."""
    from upscale.models.dcbr.coupling import atom_geometry

    atoms = swcnt(12, 6, length=120.0)
    if defects:
        atoms = apply_defects(atoms, defects)
    model = DCBRModel(atoms, 2.0, r_atomistic=6.0)
    st = State(model.x0, model.x0.copy(), np.zeros_like(model.x0), np.ones(0, bool))
    model.init_state(st)
    np.testing.assert_allclose(model.atom_positions(st), atoms.positions, rtol=0, atol=1e-12)
    st = uniform_state(model, 1.04)
    t = model.tube
    from upscale.models.dcbr.ghost import uniform_lattice

    lt, sh = uniform_lattice(t.cell, t.P_f, 1.04)
    ids, X, th, z, sub, _ = atom_geometry(t, model.structure.tubes[0], atoms.positions)
    rho, thn = lt * t.cell.R0 + sub * sh[0], th + sub * sh[1] / (lt * t.cell.R0)
    expect = t.centre + (rho * np.cos(thn))[:, None] * t.e1 + (rho * np.sin(thn))[:, None] \
        * t.e2 + (1.04 * z + sub * sh[2])[:, None] * t.axis
    dd = model.atom_positions(st)[ids] - expect
    dd[:, 2] -= model.Lz * np.round(dd[:, 2] / model.Lz)
    assert np.abs(dd).max() < 1e-12


@pytest.mark.parametrize("nm", [(10, 10), (17, 0)])
def test_lattice_stability_rule_is_the_old_one(nm):
    """The mapped periodic piece's smallest eigenvalue against the old LatticeStability on
    the relaxed uniform lattice at 5 to 30 % stretch (1e-9 relative: the same central
    differences on another sum order), the same stable/unstable decisions, both present."""
    from upscale.models.dcbr import LatticeStability as OldStability
    from upscale.models.dcbr.ghost import uniform_lattice
    from upscale.models.dcbr.stability import LatticeStability

    P = tersoff_row()
    old, new, cell = OldStability(*nm), LatticeStability(*nm, P), TubeCell.build(*nm)
    decisions = set()
    for lam_z in (1.05, 1.2, 1.3):
        lt, sh = uniform_lattice(cell, P, lam_z)
        q = np.array([lt, 0.0, lam_z, *sh])
        assert new.min_eigenvalue(q) == pytest.approx(old.min_eigenvalue(q), rel=1e-9)
        assert new.stable(q) == old.stable(q)
        decisions.add(new.stable(q))
    assert decisions == {True, False}


@pytest.mark.parametrize("lam_z", [1.2, 1.3])
def test_failure_rules_on_the_engine_state_are_the_old_models(lam_z):
    """DCBRModel.break_bonds against DCBRTubeModel.break_bonds on the relaxed uniform
    lattice: nothing fails at 20 %, every particle at 30 % (the lattice is unstable), the
    same links and particles."""
    from upscale.models.dcbr.ghost import uniform_lattice

    new = DCBRModel(swcnt(10, 10, length=100.0), 2.0)
    tube = DCBRTube(10, 10, 100.0, coarsening=2.0)
    old = DCBRTubeModel(tube)
    t = new.tube
    lt, sh = uniform_lattice(t.cell, t.P_f, lam_z)
    so, sn = State.reference(tube.x0, 0), State.reference(new.x0, 0)
    so.y[...] = tube.x0 * [lt, lt, lam_z]
    sn.y[...] = so.y + t.centre
    old.init_state(so)
    new.init_state(sn)
    old.set_cell(lam_z * tube.L)
    new.set_cell(lam_z * tube.L)
    assert new.break_bonds(sn) == old.break_bonds(so) == (0 if lam_z < 1.25 else t.N)
    assert np.array_equal(t.alive, tube.alive)
    assert np.array_equal(t.gain.intact_b, tube.intact)


def _tension_curve(model, body, centre, L0):
    """The axial force (eV/Å) at 1 % strain steps of a quasi-static pull (each step: scale,
    L-BFGS-B to 1e-5 eV/Å, break and re-minimise until nothing breaks) until it falls
    below half its peak."""
    from upscale.engine.minimisers import LBFGS
    from upscale.engine.simulation import Simulation

    sim = Simulation(body, None, [model])
    out = []
    for k in range(1, 40):
        model.set_cell(L0 * (1 + 0.01 * k))
        sim.state.y[:, 2] = centre[2] + (sim.state.y[:, 2] - centre[2]) * (1 + 0.01 * k) / (
            1 + 0.01 * (k - 1))
        for _ in range(50):
            sim.minimise(LBFGS(ftol=1e-5, max_iter=5000), raise_on_fail=False)
            if model.break_bonds(sim.state) == 0:
                break
        out.append(model.cell_force(sim.state))
        if max(out) > 0 and out[-1] < 0.5 * max(out):
            return np.array(out)
    return np.array(out)


@pytest.mark.slow
def test_quasi_static_tension_to_failure_is_the_old_engine_models():
    """A periodic (10,10) tube, K = 3, pulled quasi-statically to failure on the engine
    with DCBRTubeModel and with DCBRModel (same minimiser, same steps): the same force at
    every step to 1e-11 relative, the same failure step (25 %, the lattice-stability rule)."""
    from upscale.engine import ParticleSystem

    tube = DCBRTube(10, 10, 60.0, coarsening=3.0)
    body = ParticleSystem(tube.x0, 1.0, density=12.011, spacing=1.42, units="atomic")
    f_old = _tension_curve(DCBRTubeModel(tube), body, np.zeros(3), tube.L)
    new = DCBRModel(swcnt(10, 10, length=60.0), 3.0)
    new.tube.hourglass.k_stab = tube.k_stab
    f_new = _tension_curve(new, new.system(), new.tube.centre, new.tube.L)
    assert len(f_new) == len(f_old) and f_old.argmax() == f_new.argmax() == 24
    np.testing.assert_allclose(f_new, f_old, rtol=0, atol=1e-11 * f_old.max())


@pytest.mark.parametrize("select", [False, True])
def test_nve_with_inertial_shifts(select):
    """shifts="inertial": the particle rows' shifts a field with inertia (slaves' relaxed).
    200 velocity-Verlet steps of 0.5 fs of a periodic tube at 2 % strain, coarse or with an
    atomistic band (ghost load on): the total energy, the shifts' kinetic energy included,
    stays within 1e-3 of the kinetic energy; the shifts move."""
    from upscale.engine.integrators import VelocityVerlet
    from upscale.engine.simulation import Simulation

    atoms = swcnt(10, 10, length=100.0)
    zc = atoms.positions[:, 2].mean()
    band = np.abs(atoms.positions[:, 2] - zc) < 8.0 if select else None
    model = DCBRModel(atoms, 2.0, select=band, shifts="inertial", failure=False)
    assert model.internal_fields == {} and FIELD in model.fields()
    model.set_cell(1.02 * model.tube.L)
    sim = Simulation(model.system(), None, [model], integrator=VelocityVerlet(dt=0.5, force=True))
    c = model.tube.centre
    sim.state.y[...] = c + (model.x0 - c) * np.array([1.0, 1.0, 1.02])
    v = 0.002 * np.random.default_rng(0).standard_normal(sim.state.y.shape)
    sim.state.v[...] = v - v.mean(axis=0)
    sim.update_forces()
    K0 = sim.kinetic_energy()
    E0 = sim.energy() + K0
    for _ in range(10):
        sim.run(20)
        assert abs(sim.energy() + sim.kinetic_energy() - E0) < 1e-3 * K0
    assert np.abs(sim.state.fields[FIELD]).max() > 1e-3
