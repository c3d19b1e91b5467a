"""Ti-PD's optimised pair kernels (:mod:`upscale.models.tipd_kernels`) against a plain
reference written here from the equations (directed bonds, numpy, nothing shared with the
library but the family and the elastic tensor): the one-thread sweep and the multi-thread
passes, with the surface correction and without, uniform and non-uniform weights, broken
bonds, 2D and 3D."""
import dataclasses
import warnings

import numba as nb
import numpy as np
import pytest

from upscale.engine import ParticleSystem, State, build_family, cubic_lattice, square_lattice
from upscale.models.tipd import TiPD, induced_tensor

D_ANISO = np.array([[5.0, 3.0, 0.7], [3.0, 5.0, -0.4], [0.7, -0.4, 6.0]]) * 1e9


def reference_force(m, st):
    """Ti-PD (+ the surface correction when the model has it) force densities (N, 3) on the
    directed bonds, from the module docstring of :mod:`upscale.models.tipd`:
    ``b_i = sum_j intact V_j beta M(xi) eta + sum_j V_j beta (Q_i + Q_j) xi`` with
    ``M = A : xi xi / |xi|^3``, ``A`` the continuum induced tensor, ``Q_i = (Delta_i : H_i)
    K_i^-1``, ``H_i = sum_j w eta (x) xi K_i^-1``, ``Delta_i = C - S_i^lat``."""
    s, f, d = m.system, m.family, m.dim
    i, j = f.owner, f.neighbors
    xi = f.xi[:, :d]
    w = s.volume[j] * f.volume_factor
    h = f.horizon
    A = induced_tensor(m.C) / (np.pi * h ** 3 * s.thickness if d == 2 else np.pi * h ** 4)
    M = w[:, None, None] * np.einsum("pqab,ka,kb->kpq", A, xi, xi) / f.length[:, None, None] ** 3
    u = (st.y - s.x0)[:, :d]
    eta = u[j] - u[i]
    out = np.zeros((s.n, 3))
    np.add.at(out[:, :d], i, st.intact[:, None] * np.einsum("kpq,kq->kp", M, eta))
    if m.surface == "none":
        return out
    K = np.zeros((s.n, d, d))
    np.add.at(K, i, w[:, None, None] * np.einsum("ka,kb->kab", xi, xi))
    Kinv = np.linalg.inv(K)
    G = np.zeros((s.n, d, d))
    np.add.at(G, i, w[:, None, None] * np.einsum("kp,ka->kpa", eta, xi))
    H = np.einsum("npc,nca->npa", G, Kinv)
    S = np.zeros((s.n,) + (d,) * 4)
    np.add.at(S, i, 0.5 * np.einsum("kpq,ka,kb->kpaqb", M, xi, xi))
    Delta = m.C[None] - S
    Q = np.einsum("npcqb,nqb,nca->npa", Delta, H, Kinv)
    np.add.at(out[:, :d], i, w[:, None] * np.einsum("kpa,ka->kp", Q[i] + Q[j], xi))
    return out


def _body(dim, kind):
    if dim == 2:
        s = square_lattice(13, 10, 1e-3)
    else:
        s = cubic_lattice(7, 6, 5, 1e-3)
    pv = "linear" if kind == "partial_volume" else None
    if kind == "volumes":                  # non-uniform volumes: the weighted loops
        V = s.volume * (1.0 + 0.3 * np.random.default_rng(1).random(s.n))
        s = ParticleSystem(s.x0, V, 1.0, dim=dim, thickness=s.thickness, plane=s.plane,
                           spacing=s.spacing)
    f = build_family(s, 3.015e-3, partial_volume=pv)
    if kind == "asymmetric":               # beta differs between the two directions of some pairs
        beta = f.volume_factor
        beta[::5] *= 0.7
        f = dataclasses.replace(f, beta=beta)
    return s, f


def _state(s, f, broken):
    st = State.reference(s.x0, f.nb)
    st.y += np.random.default_rng(2).normal(scale=1e-6, size=st.y.shape)
    if s.dim == 2:
        st.y[:, 2] = 0.0
    if broken:
        st.intact[::7] = False             # one direction only for some pairs
    return st


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kind", ["lattice", "partial_volume", "volumes", "asymmetric"])
@pytest.mark.parametrize("surface", ["correspondence", "none"])
def test_pair_kernels_equal_the_reference(dim, kind, surface):
    s, f = _body(dim, kind)
    kw = {"C": D_ANISO} if dim == 2 else {"E": 70e9, "nu": 0.3}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = TiPD(**kw, surface=surface)
        m.prepare(s, f)
    assert m.bonds is not None
    assert m._uni == (kind in ("lattice", "partial_volume"))
    threads = nb.get_num_threads()
    try:
        for broken in (False, True):
            st = _state(s, f, broken)
            ref = reference_force(m, st)
            scale = np.abs(ref).max()
            for nt in sorted({1, min(2, nb.config.NUMBA_NUM_THREADS)}):
                nb.set_num_threads(nt)             # 1: the sweep; 2: the per-thread passes
                out = np.zeros_like(st.y)
                m.add_force(st, out)
                assert np.abs(out - ref).max() <= 1e-12 * scale, (broken, nt)
                # and it adds: a second call doubles the output
                m.add_force(st, out)
                assert np.abs(out - 2 * ref).max() <= 2e-12 * scale
    finally:
        nb.set_num_threads(threads)


@pytest.mark.parametrize("nx,ny", [(60, 8), (4, 12)])
def test_sweeps_with_rings_and_halos_equal_the_reference(nx, ny):
    """A body longer than twice the pairs' reach: the sweep's scratch is a ring of a few
    hundred rows; a body shorter than the reach: two threads' halos overlap the next
    block entirely. One and two threads, contiguous and strided output."""
    s = square_lattice(nx, ny, 1e-3)
    f = build_family(s, 3.015e-3)
    m = TiPD(C=D_ANISO)
    m.prepare(s, f)
    if nx == 60:
        assert m._ring < s.n and m._mask != np.uint64(0xFFFFFFFFFFFFFFFF)
    else:
        assert m._span > s.n // 2
    st = _state(s, f, False)
    ref = reference_force(m, st)
    scale = np.abs(ref).max()
    threads = nb.get_num_threads()
    try:
        for nt in sorted({1, min(2, nb.config.NUMBA_NUM_THREADS)}):
            nb.set_num_threads(nt)
            out = np.zeros_like(st.y)
            m.step_force(st, out)
            assert np.abs(out - ref).max() <= 1e-12 * scale
            big = np.zeros((s.n, 6))
            m.add_force(st, big[:, ::2])
            assert np.abs(big[:, ::2] - ref).max() <= 1e-12 * scale
            assert not big[:, 1::2].any()
    finally:
        nb.set_num_threads(threads)


def test_failure_on_the_pair_list_breaks_what_the_directed_loop_breaks():
    s, f = _body(2, "volumes")
    m = TiPD(C=D_ANISO, s0=2e-3)
    m.prepare(s, f)
    mb = TiPD(C=D_ANISO, s0=2e-3, kernel="bond")
    mb.prepare(s, f)
    st = _state(s, f, True)
    st.y += np.random.default_rng(5).normal(scale=3e-6, size=st.y.shape) * [1, 1, 0]
    res = []
    for mod in (m, mb):
        s2 = State.reference(s.x0, f.nb)
        s2.y[...] = st.y
        s2.intact[...] = st.intact
        out = np.zeros_like(st.y)
        k = mod.step_force(s2, out, failure=True)
        res.append((k, s2.intact.copy(), out))
    assert res[0][0] == res[1][0] > 0
    assert np.array_equal(res[0][1], res[1][1])
    assert np.abs(res[0][2] - res[1][2]).max() <= 1e-12 * np.abs(res[1][2]).max()


def test_memory_kept_per_bond_is_small():
    """The pair path keeps no per-directed-bond float array: the half list (partner, class,
    reverse index) and per-class / per-particle tables."""
    s, f = _body(2, "lattice")
    m = TiPD(C=D_ANISO)
    m.prepare(s, f)
    per_bond = [k for k, v in vars(m).items()
                if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] in (f.nb, f.nb // 2)]
    assert per_bond == ["_k_p"], per_bond
    assert m._tab.shape[0] < 200 and m._T_ckk.shape[0] < s.n
