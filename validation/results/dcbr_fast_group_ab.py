"""In-process A/B of the per-inner-step glue of the bench-dcbr-seed tube (clamped grips,
8 Å band, at a perturbed uniform state with the split's transfer): the numpy expressions
the kernels replaced (Tie / FixedField fancy indexing, scipy's Phi products, the old fold
and transfer of tests/test_dcbr_fast_group.py, two evaluations per group, the constrained
dofs by masks) against the kernels, alternated three times, best of five per item (µs per
call). Usage: dcbr_fast_group_ab.py N M K (from the repository root, PYTHONPATH=$PWD
NUMBA_NUM_THREADS=1; figures in validation/results/engine.md)."""
import sys
import time
import unittest.mock as um

import numpy as np

import tests.test_dcbr_fast_group as T
import upscale.engine.respa as RR
from upscale.engine import fields as FL
from upscale.engine.respa import RESPA
from upscale.engine.simulation import Simulation
from upscale.models.dcbr_engine import FIELD, DCBRDefectTubeModel
from validation.cases.dcbr import dynamic_scene, lammps_reference_or_run
from validation.cases.references import DYN_LENGTH

n, m_, K = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
ref = lammps_reference_or_run(n, m_, DYN_LENGTH, vacancy=True, protocol="dynamic")
tube, _ = dynamic_scene(n, m_, DYN_LENGTH, K, ref, grips="clamped", region="band",
                        r_atomistic=8.0)
lt, lz, sh = tube.uniform_lattice(1.0)
y, d, Lz = tube.uniform_state(lt, lz, sh)
tube.prepare_step(Lz)
y = y + 0.01 * np.random.default_rng(0).standard_normal(y.shape)
m = DCBRDefectTubeModel(tube, y=y, delta=d, Lz=Lz)
integ = RESPA(5.0, 5, force=True)
sim = Simulation(m.system(), None, m, m.conditions(), integ)
st = sim.state
m.prepare_split(st)
integ.prepare(sim)


def old_tie(self, state, t, dt=None):
    _, c = self.target
    g, mm, w = self.region.index, self.masters, self.weights
    um_ = state.y[mm, c] - state.x0[mm, c]
    state.y[g, c] = state.x0[g, c] + np.sum(w * um_, axis=1)
    state.v[g, c] = np.sum(w * state.v[mm, c], axis=1)


def old_ff(self, state, t, dt=None):
    state.field_v[self.field][np.ix_(self.region.index, self.field_components)] = 0.0


def old_split(F, mask, R):
    np.multiply(F, mask, out=R)
    np.copyto(F, 0.0, where=mask)


def old_zero(a, mask):
    a[mask] = 0.0


new = (FL.Tie.apply, FL.FixedField.apply, RR._split_constrained, RR._zero_where)


def bench(fn, reps):
    best = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(reps):
            fn()
        best.append((time.perf_counter() - t0) / reps)
    return min(best) * 1e6


def fast():
    m._fast_cache = None
    integ._group_forces(sim, "fast")


def slow():
    m._slow_cache = None
    integ._group_forces(sim, "slow")


x = np.vstack(tube.atom_positions(m.unknowns(st)[0], st.fields[FIELD][:m.N], Lz))
for rep in range(3):
    for ver in ("numpy", "kernels"):
        patches = []
        if ver == "numpy":
            FL.Tie.apply, FL.FixedField.apply = old_tie, old_ff
            RR._split_constrained, RR._zero_where = old_split, old_zero
            m.add_group_forces = None
            patches = [um.patch.object(m, "_fold", lambda y, g, gx: T._old_fold(m, y, g, gx)),
                       um.patch.object(m, "_transfer", lambda y, d: T._old_transfer(m, y, d)),
                       um.patch.object(m, "_particle_positions", tube.particle_positions),
                       um.patch.object(m, "unknowns",
                                       lambda s: (s.y[m.y_rows], s.fields[FIELD][:m.N]))]
            for p in patches:
                p.start()
        r = {"conditions": bench(lambda: sim.apply_displacement(st.t, 1.0), 300),
             "fast group": bench(fast, 60), "slow group": bench(slow, 30),
             "Tersoff alone": bench(lambda: tube._atomistic(x), 60)}
        for p in patches:
            p.stop()
        if ver == "numpy":
            del m.add_group_forces
            FL.Tie.apply, FL.FixedField.apply, RR._split_constrained, RR._zero_where = new
        print(rep, ver, {k: round(v, 1) for k, v in r.items()}, flush=True)
print("free atoms", m.nf, "pad atoms", len(tube.pad_idx))
