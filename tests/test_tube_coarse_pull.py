"""The dynamic pull of any open tube on DCBRModel (``upscale.experiments.scenes.
tube_coarse_pull``) and the open tube's ghost-force load (``upscale.models.dcbr.ghost``).

References: the uniform lattice (closed-form equilibrium of a pristine lattice), the old
validated dynamic tube (``dcbr_dynamic.dynamic_tension``), the stored LAMMPS dynamic run
(``data/reference/dyn_10-10_pristine.json``), and the run itself uninterrupted (resume)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from upscale.build import swcnt
from upscale.defects import apply_defects
from upscale.engine.state import State
from upscale.experiments.scenes.tube_coarse_pull import (coarse_dynamic_tension, open_tube,
                                                          setup_open_tube)
from upscale.models.dcbr.ghost import uniform_lattice
from upscale.models.dcbr.model import FIELD, DCBRModel

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("stretch", [1.0, 1.03])
def test_open_tube_ghost_load_removes_the_interface_forces(stretch):
    """An open (6,6) tube with a monovacancy (its region, and the ends' regions) on the
    uniform lattice at axial stretch lam_z (lam_t and the shift relaxed): without the load
    the rows at the regions' interfaces and the ends feel ghost forces up to 5 eV/Å; with
    the load of that stretch (``state.extra["dcbr.ghost"]``) every row more than 7 Å from
    the vacancy's empty site is force-free (the uniform lattice is an equilibrium) to
    1e-5 eV/Å (what is left, 6e-6, is the twin's in-plane net load over the atoms the tube
    lacks, spread over every row so the load has no net in-plane force; at 5-7 Å the
    vacancy's own forces, a few meV/Å), and held rows keep the set-up stretch's load."""
    atoms = open_tube(apply_defects(swcnt(6, 6, length=60.0), "v1@0.5@0"))
    m = DCBRModel(atoms, 2.0, r_atomistic=6.0, failure=False, stability=False)
    m.hold_internal(True)
    assert m.coupling is not None and m.ghost is None
    st = State.reference(m.x0, 0)
    m.init_state(st)
    st.extra["dcbr.ghost"] = np.array([1.0, 1.0])
    m.energy(st)  # (builds the twin)
    tw = m.ghost.twin_tube
    lam_z = stretch * 1.0
    lt, sh = uniform_lattice(tw.cell, tw.P_f, lam_z)
    y, d = m.ghost.tube_uniform_state(lt, lam_z, sh)
    assert np.isfinite(y).all()
    st.y[...] = y
    st.extra[FIELD][...] = d
    st.extra.pop("dcbr.ghost")
    f0 = m.force(st)
    st.extra["dcbr.ghost"] = np.array([lam_z, lam_z])
    f1 = m.force(st)
    vac = [x for x in m.defects if x.kind == "v1"][0]
    far = np.linalg.norm(y - vac.site_positions.mean(axis=0), axis=1) > 7.0
    print(f"lam_z {lam_z}: max |F| far from the vacancy {np.abs(f0[far]).max():.3f} eV/Å "
          f"without the load, {np.abs(f1[far]).max():.2e} with it")
    assert np.abs(f0[far]).max() > 1.0
    assert np.abs(f1[far]).max() < 1e-5
    assert np.abs(f1[~far]).max() > 0.1  # (the vacancy's own forces stay)
    # held rows (whole rings, as a grip's): their load is the set-up stretch's, the others'
    # unchanged but for the in-plane mean the load removes over every row (the rows' plane
    # centroid sits off the axis by the vacancy: 1.4e-4 eV/Å here)
    hold = (y - m.tube.centre) @ m.tube.axis < 10.0
    st.extra["dcbr.ghost"] = np.array([lam_z, 1.0])
    st.extra["dcbr.ghost_hold"] = hold
    f2 = m.force(st)
    np.testing.assert_allclose(f2[far & ~hold], f1[far & ~hold], rtol=0, atol=5e-4)
    if stretch != 1.0:
        assert np.abs(f2[hold]).max() > 1e-3


def _old_short(steps):
    from upscale.experiments.scenes.dcbr_dynamic import dynamic_tension
    from upscale.experiments.scenes.tube_tension import dynamic_scene

    ref = json.loads((ROOT / "data/reference/dyn_10-10_pristine.json").read_text())
    model, dyn = dynamic_scene(10, 10, 150, 2, ref, vacancy=False, grips="bands")
    dyn.pop("grips")
    dyn["planes"] = None  # (the planes ``grip`` inside the end atoms, as the new scene's)
    return dynamic_tension(model, temperature=0.0, max_strain=(steps - 50) * 2e-3 / 50.97, **dyn)


def test_short_pull_at_zero_kelvin_is_the_old_dynamic_tube():
    """The pristine (10,10) 150 Å K=2 tube of the old dynamic scene (atomistic bands across
    the grip planes, 1 Å/ps per grip, 0 K): the new pull's set-up (gauge, radius) within
    0.05 %, and its first four 100-step stress samples within 3 % of the old's (the
    particle grids differ: the old tube opened from its periodic cell, the new one built
    from the finite atoms with atomistic ends; the grip's standing wave rings in both)."""
    old = _old_short(400)
    new = coarse_dynamic_tension(swcnt(10, 10, length=150.0), 2.0, temperature=0.0,
                                 max_steps=400)
    so, sn = np.array(old["curve"]["stress_GPa"][:4]), np.array(new["curve"]["stress_GPa"])
    print("old", so, "\nnew", sn, "\nrel", sn / so - 1)
    assert len(sn) == 4 and len(so) == 4
    np.testing.assert_allclose(new["curve"]["strain"], old["curve"]["strain"][:4], rtol=5e-4)
    assert abs(new["gauge_length_A"] / old["gauge_length_A"] - 1) < 5e-4
    assert abs(new["radius_relaxed_A"] / old["radius_relaxed_A"] - 1) < 5e-4
    np.testing.assert_allclose(sn, so, rtol=0.03)


def _small(tmp=None, **kw):
    atoms = apply_defects(swcnt(6, 6, length=80.0), "v1@0.5@0")
    base = dict(grip=15.0, r_atomistic=5.0, speed=10.0, sample=25, seed=3,
                fit_max_strain=0.03)
    return atoms, base | kw


def test_checkpoint_resume_is_bit_identical_across_region_growth():
    """A (6,6) 80 Å tube with a monovacancy at 10 K whose region grows where a coarse link
    passes 0.9 of the link rule (``grow``; switches at steps 500, 525, 550): 560 steps
    straight, and 520 steps with a checkpoint every 20 (the last one after the first
    switch, on the grown model) then resumed to 560: the same samples, switches, positions
    and damage bit for bit (the links, shifts, region, ghost load and thermostat in the
    checkpoint; the resumed call given another seed, which only a fresh start would use);
    the strain of the last sample is the grips' 2 v t / gauge at its block's middle."""
    atoms, kw = _small(grow=0.9)
    st = setup_open_tube(atoms, 2.0, grip=15.0, r_atomistic=5.0)
    a = coarse_dynamic_tension(atoms, 2.0, setup=st, max_steps=560, **kw)
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        ck = Path(d) / "ck.npz"
        part = coarse_dynamic_tension(atoms, 2.0, setup=st, max_steps=520, checkpoint=ck,
                                      checkpoint_every=20, **kw)
        assert ck.is_file() and [s["step"] for s in part["switches"]] == [500]
        b = coarse_dynamic_tension(atoms, 2.0, setup=st, max_steps=560, checkpoint=ck,
                                   checkpoint_every=20, resume=True, **(kw | {"seed": 99}))
    assert a["steps"] == b["steps"] == 560
    assert [s["step"] for s in a["switches"]] == [500, 525, 550]
    assert a["switches"] == b["switches"]
    assert a["curve"] == b["curve"]
    np.testing.assert_array_equal(a["positions"], b["positions"])
    np.testing.assert_array_equal(a["damage"], b["damage"])
    assert a["curve"]["strain"][-1] == pytest.approx(2 * 0.01 * 537.5 / st["gauge"], rel=1e-12)
    for s in a["switches"]:  # momentum conserved by the switch (switch.py's correction)
        assert np.abs(s["momentum_change"]).max() < 1e-9


@pytest.mark.slow
def test_pristine_pull_to_failure_against_lammps():
    """The pristine (10,10) 150 Å K=2 tube at 10 K, seed 1, to failure: strength within 5 %,
    modulus within 3 %, strain at peak within 10 % of the stored LAMMPS dynamic run (one
    seed each side; ``dcbr-seeds`` compares means)."""
    ref = json.loads((ROOT / "data/reference/dyn_10-10_pristine.json").read_text())
    r = coarse_dynamic_tension(swcnt(10, 10, length=150.0), 2.0, seed=1)
    err = {k: 100 * (r[k] / ref[k] - 1) for k in ("strength_GPa", "youngs_modulus_TPa",
                                                  "strain_at_peak")}
    print(err)
    assert r["failed"] and r["blowup_after_failure"] is None
    assert abs(err["strength_GPa"]) < 5 and abs(err["youngs_modulus_TPa"]) < 3
    assert abs(err["strain_at_peak"]) < 10


@pytest.mark.slow
def test_tube_with_four_kinds_of_defects_fails_at_a_defect():
    """A (10,10) 250 Å tube with v1, v2, v4 and a Stone-Wales defect in the gauge, 10 K:
    each defect found (kind) with its region, the pull runs to failure without blow-up, and
    the first damage and the crack (rows with damage >= 0.5 at the end) lie within
    2 r_atomistic (axially) of one of the defects."""
    atoms = apply_defects(swcnt(10, 10, length=250.0), "v1@0.3@0,sw@0.6@90,v2@0.45@180,"
                          "v4@0.72@270")
    r = coarse_dynamic_tension(atoms, 2.0, seed=1)
    kinds = sorted(k for k in r["describe"]["defects"] if k != "edge")
    print(r["first_damage"], r["crack"], r.get("strength_GPa"), r.get("strain_at_peak"))
    assert kinds == ["sw", "v1", "v2", "v4"]
    assert r["failed"] and r["blowup_after_failure"] is None
    for where in (r["first_damage"], r["crack"]):
        assert where is not None and where["distance_A"] < 2 * 8.0
