"""The per-step kernels of the coarse tube's fast group and the engine's conditions give
the numbers of the numpy expressions they replace (the same to the last bit, so a run is
unchanged): numpy's pairwise sum, the ties and held fields, the rigid grip, the split's
constrained dofs, and the tube model's row glue (unknowns, the slaves' interpolation and
its transpose, the split's transfer) and with them its group forces."""
import numpy as np
import pytest

from upscale.engine.conditions import Grip, Region
from upscale.engine.fields import FixedField, Tie, pairwise_sum
from upscale.engine.integrators import VelocityVerlet
from upscale.engine.respa import _split_constrained, _zero_where
from upscale.engine.simulation import Simulation
from upscale.models import dcbr_coupling_kernels as CK
from upscale.models.dcbr_defect import DCBRDefectTube
from upscale.models.dcbr_engine import FIELD, DCBRDefectTubeModel


def _wide(rng, shape):
    """Random numbers over ten decades (so a different summation order shows)."""
    return rng.standard_normal(shape) * 10.0 ** rng.uniform(-5, 5, shape)


def test_pairwise_sum_is_numpys():
    rng = np.random.default_rng(0)
    for n in list(range(0, 300)) + [1000, 4097, 7278]:
        a = _wide(rng, n)
        assert pairwise_sum(a, n) == np.sum(a), n
    for p in (1, 2, 3, 7, 8, 9, 10, 13, 17, 40):  # a row sum of a (k, p) array (axis=1)
        A = _wide(rng, (60, p))
        assert np.array_equal(np.sum(A, axis=1), [pairwise_sum(r, p) for r in A]), p


class _State:
    def __init__(self, rng, n):
        self.x0 = rng.standard_normal((n, 3))
        self.y = self.x0 + _wide(rng, (n, 3)) * 1e-3
        self.v = _wide(rng, (n, 3))
        self.fields = {"f": _wide(rng, (n, 2))}
        self.field_v = {"f": _wide(rng, (n, 2))}


@pytest.mark.parametrize("p", [1, 3, 7, 8, 10, 13])
def test_tie_is_the_numpy_expression(p):
    rng = np.random.default_rng(p)
    n, ng = 200, 30
    st = _State(rng, n)
    mask = np.zeros(n, bool)
    mask[rng.choice(n, ng, replace=False)] = True
    reg = Region("ghosts", mask)
    others = np.nonzero(~mask)[0]
    m = rng.choice(others, (ng, p))
    w = _wide(rng, (ng, p))
    g = reg.index
    for target in (("y", 0), ("y", 2), ("f", 1)):
        ref = _State(np.random.default_rng(p), n)  # the same numbers
        kind, c = target
        if kind == "y":  # the numpy expression the kernel replaces
            um = ref.y[m, c] - ref.x0[m, c]
            ref.y[g, c] = ref.x0[g, c] + np.sum(w * um, axis=1)
            ref.v[g, c] = np.sum(w * ref.v[m, c], axis=1)
        else:
            f, fv = ref.fields[kind], ref.field_v[kind]
            f[g, c] = np.sum(w * f[m, c], axis=1)
            fv[g, c] = np.sum(w * fv[m, c], axis=1)
        st = _State(np.random.default_rng(p), n)
        Tie(reg, m, w, target).apply(st, 0.0)
        assert np.array_equal(st.y, ref.y) and np.array_equal(st.v, ref.v)
        assert np.array_equal(st.fields["f"], ref.fields["f"])
        assert np.array_equal(st.field_v["f"], ref.field_v["f"])


def test_fixed_field_and_rigid_grip_are_the_numpy_expressions():
    rng = np.random.default_rng(3)
    n = 50
    mask = rng.random(n) < 0.3
    reg = Region("r", mask)
    idx = reg.index
    for hold, comps in ((False, (1,)), (True, (0, 1))):
        st, ref = _State(np.random.default_rng(4), n), _State(np.random.default_rng(4), n)
        FixedField(reg, "f", comps, 0.5, hold=hold).apply(st, 0.0)
        if not hold:
            ref.fields["f"][np.ix_(idx, comps)] = 0.5
        ref.field_v["f"][np.ix_(idx, comps)] = 0.0
        assert np.array_equal(st.fields["f"], ref.fields["f"])
        assert np.array_equal(st.field_v["f"], ref.field_v["f"])
    vel, u0, t, dt = np.array([0.1, -0.2, 0.3]), np.array([0.01, 0.0, -0.02]), 7.3, 0.9
    st, ref = _State(np.random.default_rng(5), n), _State(np.random.default_rng(5), n)
    Grip(reg, velocity=vel, u0=u0).apply(st, t, dt)
    u = u0 + vel * t
    ref.y[idx] = ref.x0[idx] + u
    ref.v[idx] = (u - (u0 + vel * (t - dt))) / dt
    assert np.array_equal(st.y, ref.y) and np.array_equal(st.v, ref.v)


def test_split_constrained_is_the_numpy_expression():
    rng = np.random.default_rng(6)
    F = _wide(rng, (40, 3))
    F[3, 1] = -F[3, 1] if F[3, 1] > 0 else F[3, 1]  # a negative one on a free dof: -0.0
    mask = rng.random((40, 3)) < 0.4
    mask[3, 1] = False
    R0, F0 = np.empty_like(F), F.copy()
    np.multiply(F0, mask, out=R0)
    np.copyto(F0, 0.0, where=mask)
    R1, F1 = np.empty_like(F), F.copy()
    _split_constrained(F1, mask, R1)
    assert np.array_equal(F0, F1) and np.array_equal(R0, R1)
    assert np.array_equal(np.signbit(R0), np.signbit(R1))
    G0, G1 = F.copy(), F.copy()
    G0[mask] = 0.0
    _zero_where(G1, mask)
    assert np.array_equal(G0, G1)


@pytest.fixture(scope="module", params=["band", "disc"])
def model(request):
    t = DCBRDefectTube(10, 10, 40.0, coarsening=2.0, vacancy=4, r_atomistic=5.0,
                       region=request.param)
    rng = np.random.default_rng(0)
    lt, lz, sh = t.uniform_lattice(1.01)
    y, d, Lz = t.uniform_state(lt, lz, sh)
    t.prepare_step(Lz)
    y = y + 0.02 * rng.standard_normal(y.shape)
    d = d + 0.01 * rng.standard_normal(d.shape)
    return DCBRDefectTubeModel(t, y=y, delta=d, Lz=Lz)


def _old_fold(m, y, gyp, gx):
    t, nd = m.tube, m.nd
    gy = np.empty_like(y)
    gy[:nd] = gyp[t.dof_idx]
    gy[nd:] = 0.0 if gx is None else gx
    if len(t.slave_idx):
        gy[nd:] += t._PhiT @ gyp[t.slave_idx]
    return gy


def _old_transfer(m, y, d):
    r = m._split_ref
    dd = d - r["d"]
    Hd = np.einsum("nij,nj->ni", r["H"], dd)
    Q = float(np.sum(r["gy"] * (y - r["y"])) + np.sum(r["gd"] * dd) + 0.5 * np.sum(dd * Hd))
    return Q, r["gy"], r["gd"] + Hd


def test_row_glue_is_the_numpy_expressions(model):
    m, t = model, model.tube
    assert len(t.slave_idx) > 0
    sim = Simulation(m.system(), None, m, m.conditions(), VelocityVerlet(1.0, force=True))
    st = sim.state
    y, d = m.unknowns(st)
    assert np.array_equal(y, st.y[m.y_rows])
    assert np.array_equal(m._particle_positions(y), t.particle_positions(y))
    rng = np.random.default_rng(1)
    gyp, gx = _wide(rng, (m.N, 3)), _wide(rng, (m.nf, 3))
    assert np.array_equal(m._fold(y, gyp, gx), _old_fold(m, y, gyp, gx))
    assert np.array_equal(m._fold(y, gyp, None), _old_fold(m, y, gyp, None))
    out, ref = _wide(rng, st.y.shape), None
    ref = out.copy()
    g = _wide(rng, (len(m.y_rows), 3))
    ref[m.y_rows] -= g
    CK.sub_rows(out, m.y_rows, g)
    assert np.array_equal(out, ref)
    m.prepare_split(st)
    st.y[m.y_rows] += 0.01 * rng.standard_normal((len(m.y_rows), 3))
    st.fields[FIELD][:m.N] -= 0.003 * rng.standard_normal((m.N, 3))
    y, d = m.unknowns(st)
    q, q0 = m._transfer(y, np.ascontiguousarray(d)), _old_transfer(m, y, d)
    assert q[0] == q0[0] and q[1] is q0[1] and np.array_equal(q[2], q0[2])


def test_group_forces_equal_the_numpy_path(model, monkeypatch):
    """Both groups' forces, shift forces and energies with the kernels equal those of the
    numpy glue (the old _fold and _transfer, scipy's Phi products, fancy indexing) at a
    perturbed state with the split's transfer: the same to 1e-13 of the largest force (in
    fact bit for bit)."""
    m = model
    sim = Simulation(m.system(), None, m, m.conditions(), VelocityVerlet(1.0, force=True))
    st = sim.state
    m.prepare_split(st)
    st.y[m.y_rows] += 0.01 * np.random.default_rng(2).standard_normal((len(m.y_rows), 3))
    st.fields[FIELD][:m.N] += 0.002

    def groups():
        m._changed()
        out = {}
        for g in ("fast", "slow"):
            F = np.zeros_like(st.y)
            G = {FIELD: np.zeros_like(st.y)}
            m.add_group_force(st, F, g)
            m.add_group_field_force(st, G, g)
            out[g] = (F, G[FIELD], m.group_energy(st, g))
        return out

    new = groups()
    with monkeypatch.context() as mp:
        mp.setattr(m, "_fold", lambda y, gyp, gx: _old_fold(m, y, gyp, gx))
        mp.setattr(m, "_transfer", lambda y, d: _old_transfer(m, y, d))
        mp.setattr(m, "_particle_positions", m.tube.particle_positions)
        mp.setattr(m, "unknowns", lambda s: (s.y[m.y_rows], s.fields[FIELD][:m.N]))
        old = groups()
    for g in ("fast", "slow"):
        scale = np.abs(old[g][0]).max()
        assert scale > 1e-3
        assert np.abs(new[g][0] - old[g][0]).max() <= 1e-13 * scale
        assert np.abs(new[g][1] - old[g][1]).max() <= 1e-13 * max(np.abs(old[g][1]).max(), 1.0)
        assert new[g][2] == pytest.approx(old[g][2], rel=1e-13, abs=1e-12)
        assert np.array_equal(new[g][0], old[g][0]) and np.array_equal(new[g][1], old[g][1])
