"""LAMMPS runners (upscale.experiments.lammps): tiny runs, consistency of the result record,
bad input; the protocol entry point run() for tension, compression and torsion."""
import dataclasses
import inspect
import json
import math
from pathlib import Path

import numpy as np
import pytest

from potentials import lammps_runtime
from upscale.build import swcnt
from upscale.io import write_json

pytestmark = pytest.mark.lammps


@pytest.fixture(scope="module")
def qs_result():
    from upscale.experiments.lammps.tension import quasi_static_tension

    tube = swcnt(10, 10, 10.0)  # 4 unit cells, 160 atoms
    return quasi_static_tension(tube, "tersoff:BNC.tersoff", strain_step=0.01, max_strain=0.03,
                                ftol=1e-10, relax_ftol=1e-10)


def test_quasi_static_record_is_consistent(qs_result, tmp_path):
    res = qs_result
    p = write_json(tmp_path / "r.json", res)
    back = json.loads(p.read_text())
    c = back["curve"]
    assert c["strain"] == pytest.approx([0.0, 0.01, 0.02, 0.03])
    assert len(c["stress_GPa"]) == len(c["energy_eV"]) == len(c["Lz_A"]) == 4
    # relaxed to zero axial stress: ~0 at zero strain (a 100 GPa scale curve)
    assert abs(back["zero_strain_stress_GPa"]) < 1e-3
    assert np.all(np.diff(c["stress_GPa"]) > 0)
    L0 = back["relaxation"]["L0_A"]
    assert np.allclose(c["Lz_A"], L0 * (1 + np.array(c["strain"])), rtol=1e-9)
    # provenance: the step-cutoff file and its checksum, the LAMMPS version
    pot = back["potential"]
    assert pot["cutoff"] == "step" and pot["source_file"] == "BNC.tersoff"
    from upscale.experiments.lammps.potential import cache_dir
    f = cache_dir() / "potentials" / pot["file"]
    assert lammps_runtime.file_sha256(f) == pot["file_sha256"]
    assert back["lammps_version"] == lammps_runtime.lammps_version()
    assert back["stress_convention"]["wall_thickness_A"] == 3.4
    for k in ("youngs_modulus_TPa", "strength_GPa", "strain_at_peak", "failure_strain",
              "wall_s", "date_utc"):
        assert k in back
    assert 0.7 < back["youngs_modulus_TPa"] < 1.3  # graphene-like wall, t = 3.4 Å


def test_virial_stress_equals_energy_derivative(qs_result):
    """sigma = -pzz V / (2 pi R t L) must equal (1/A) dE/dL from the minimised energies."""
    c = qs_result["curve"]
    R = qs_result["stress_convention"]["radius_A"]
    A = 2 * math.pi * R * 3.4
    E, L, s = (np.array(c[k]) for k in ("energy_eV", "Lz_A", "stress_GPa"))
    # the secant dE/dL over an interval is the mean stress over it (times A); the trapezoid
    # mean of the end stresses differs from it by -(1/12) of the second difference
    s_fd = np.diff(E) / np.diff(L) / A * 160.21766208
    d2 = s[:-2] - 2 * s[1:-1] + s[2:]
    d2 = np.concatenate([d2[:1], d2])  # one per interval (nearest interior estimate)
    s_mean = 0.5 * (s[1:] + s[:-1]) - d2 / 12.0
    assert np.allclose(s_fd, s_mean, rtol=1e-3)
    # and the plain trapezoid is already within 1 %
    assert np.allclose(s_fd, 0.5 * (s[1:] + s[:-1]), rtol=1e-2)


def test_step_cutoff_file_keeps_outer_cutoff():
    from upscale.experiments.lammps.potential import _write_step_tersoff, resolve_potential

    pot = resolve_potential("BNC.tersoff", cutoff="step")
    std = resolve_potential("BNC.tersoff", cutoff="standard")

    def entries(path):
        words, out = [], []
        for line in open(path):
            words += line.split("#", 1)[0].split()
            if len(words) == 17:
                out.append(words)
                words = []
        return out

    a, b = entries(std.file), entries(pot.file)
    assert len(a) == len(b) > 0
    for ea, eb in zip(a, b):
        assert ea[:3] == eb[:3]
        assert float(eb[14]) == pytest.approx(1e-5)
        assert float(eb[13]) + float(eb[14]) == pytest.approx(float(ea[13]) + float(ea[14]),
                                                               abs=1e-12)
    # the private fallback writes the same numbers as the file in use
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory() as d:
        c = entries(_write_step_tersoff(std.file, Path(d) / "x.tersoff"))
    assert np.allclose([[float(v) for v in e[3:]] for e in c],
                       [[float(v) for v in e[3:]] for e in b], rtol=1e-15, atol=0)


def test_dynamic_tiny_run_pulls_in_tension():
    from upscale.experiments.lammps.tension import dynamic_tension

    tube = swcnt(5, 5, 40.0)
    res = dynamic_tension(tube, "tersoff:BNC.tersoff", grip=12.0, speed=1.0, temperature=1.0,
                          max_strain=0.02, sample_every=50)
    e = np.array(res["curve"]["strain"])
    s = np.array(res["curve"]["stress_GPa"])
    assert len(e) >= 3 and np.all(np.diff(e) > 0)
    assert s[-1] > 5.0  # tensile reaction on the grips at ~2 % strain
    # the extensometer (marks inside the gauge) follows the grip strain: 1.06, 0.92, 0.89,
    # 0.89 of it on this 16 Å gauge
    x = np.array(res["curve"]["extensometer_strain"])
    assert len(x) == len(e) and np.all(np.diff(x) > 0) and 0.8 < x[-1] / e[-1] < 1.2
    assert res["strain_at_peak_ext"] in x and res["youngs_modulus_ext_TPa"] > 0
    assert res["protocol_detail"]["timestep_ps"] == 0.001
    assert res["aborted"] is None


def test_dynamic_pull_rounds_repeat_the_pull_from_the_set_up_state():
    # timing rounds of a race: the result is the first round's, each later round the same
    # pull on a new instance of the opened tube (the same curve before fracture, here to
    # 1e-9), with the other code's turn between rounds
    from upscale.experiments.lammps.tension import dynamic_tension

    tube = swcnt(5, 5, 40.0)
    kw = dict(grip=12.0, speed=1.0, temperature=1.0, max_strain=0.02, sample_every=50)
    one = dynamic_tension(tube, "tersoff:BNC.tersoff", **kw)
    turns = []
    three = dynamic_tension(tube, "tersoff:BNC.tersoff", pull_rounds=3,
                            between_rounds=turns.append, **kw)
    assert turns == [0, 1]
    assert three["curve"] == one["curve"] and len(three["pull_rounds"]) == 3
    assert len(one["pull_rounds"]) == 1 and one["pull_rounds_extra_wall_s"] == 0.0
    assert three["pull_rounds_extra_wall_s"] >= sum(r["dynamics_s"]
                                                    for r in three["pull_rounds"][1:])
    assert one["pull_rounds"][0]["dynamics_s"] == one["timing_s"]["dynamics"]
    for r in three["pull_rounds"]:
        assert r["steps"] == one["timing_s"]["steps"] and r["dynamics_s"] > 0
        assert r["strength_GPa"] == pytest.approx(one["strength_GPa"], rel=1e-9)
    with pytest.raises(ValueError, match="pull_rounds=0; valid: an integer >= 1"):
        dynamic_tension(tube, "tersoff:BNC.tersoff", pull_rounds=0, **kw)


def test_dynamic_run_stops_when_the_box_grows_past_the_limit():
    # the guard against an atom thrown off the tube: here the box merely stretches past a
    # limit ~8 % above the open tube's volume, and the run stops there, recorded
    from upscale.experiments.lammps.tension import dynamic_tension

    tube = swcnt(5, 5, 80.0)
    full = dynamic_tension(tube, "tersoff:BNC.tersoff", grip=12.0, temperature=1.0,
                           max_strain=0.2)
    res = dynamic_tension(tube, "tersoff:BNC.tersoff", grip=12.0, temperature=1.0,
                          max_strain=0.2, max_box_volume=5000.0)
    ab = res["aborted"]
    assert full["aborted"] is None and ab is not None
    assert ab["box_volume_A3"] > 5000.0 and ab["step"] % 10 == 0 and ab["strain"] < 0.2
    n = len(res["curve"]["strain"])
    assert 3 <= n < len(full["curve"]["strain"])
    assert res["curve"]["stress_GPa"] == full["curve"]["stress_GPa"][:n]  # same run until then


def test_two_mpi_ranks_give_the_same_curve(qs_result):
    from upscale.experiments.lammps.tension import quasi_static_tension

    res = quasi_static_tension(swcnt(10, 10, 10.0), "tersoff:BNC.tersoff", strain_step=0.01,
                               max_strain=0.03, ftol=1e-10, relax_ftol=1e-10, nprocs=2)
    assert res["nprocs"] == 2
    assert np.allclose(res["curve"]["stress_GPa"][1:], qs_result["curve"]["stress_GPa"][1:],
                       rtol=1e-8)


def test_restart_resumes_after_the_last_saved_step(qs_result, tmp_path):
    """A run stopped after its second step (max_strain 0.015) and given the same restart
    folder with the full max_strain goes on from step 4; its curve, dump frames and
    relaxation are the uninterrupted run's (to round-off: the neighbour lists are rebuilt
    on resume). A folder of another structure is refused."""
    from upscale.experiments.lammps.tension import quasi_static_tension

    kw = dict(strain_step=0.01, ftol=1e-10, relax_ftol=1e-10, restart=tmp_path / "rs",
              dump=tmp_path / "d.dump")
    tube = swcnt(10, 10, 10.0)
    part = quasi_static_tension(tube, "tersoff:BNC.tersoff", max_strain=0.025, **kw)
    assert len(part["curve"]["strain"]) == 3
    res = quasi_static_tension(tube, "tersoff:BNC.tersoff", max_strain=0.03, **kw)
    ref = qs_result["curve"]
    assert res["curve"]["strain"] == ref["strain"]
    assert np.allclose(res["curve"]["stress_GPa"], ref["stress_GPa"], rtol=1e-9, atol=1e-9)
    assert res["relaxation"]["L0_A"] == qs_result["relaxation"]["L0_A"]
    assert (tmp_path / "d.dump").read_text().count("ITEM: TIMESTEP") == 4  # eps 0 .. 0.03
    assert res["cost"]["segments"] == 2 and res["cost"]["cpu_s"] > 0
    with pytest.raises(ValueError, match="holds another run"):
        quasi_static_tension(swcnt(10, 10, 12.5), "tersoff:BNC.tersoff", max_strain=0.025, **kw)


def test_bad_input_one_line_errors(monkeypatch):
    from upscale.experiments.lammps.potential import resolve_potential
    from upscale.experiments.lammps.tension import quasi_static_tension

    with pytest.raises(FileNotFoundError, match="does not exist") as ei:
        resolve_potential("tersoff:NoSuch.tersoff")
    assert "\n" not in str(ei.value)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        resolve_potential("/no/such/dir/C.tersoff")
    with pytest.raises(ValueError, match="step cutoff"):
        resolve_potential("rebo", cutoff="step")
    with pytest.raises(ValueError, match="cutoff"):
        resolve_potential("BNC.tersoff", cutoff="smooth")
    tube = swcnt(10, 10, 10.0)
    flat = tube.copy()
    flat.pbc = False
    with pytest.raises(ValueError, match="periodic along z"):
        quasi_static_tension(flat)
    with pytest.raises(ValueError, match="strain_step"):
        quasi_static_tension(tube, strain_step=0.0)

    def unavailable(*a, **k):
        raise lammps_runtime.LammpsUnavailable("LAMMPS is not importable (ImportError: test)")

    monkeypatch.setattr(lammps_runtime, "new_lammps", unavailable)
    with pytest.raises(lammps_runtime.LammpsUnavailable, match="not importable") as ei:
        quasi_static_tension(tube)
    assert "\n" not in str(ei.value)


def test_bundle_hybrid_is_tersoff_within_tubes_plus_lj_between():
    """pair_style hybrid: energy = sum of each tube alone + 12-6 LJ over inter-tube pairs."""
    from scipy.spatial.distance import cdist

    from upscale.build import bundle
    from upscale.experiments.lammps.potential import (LJ_CUTOFF, LJ_EPSILON_EV, LJ_SIGMA,
                                                      resolve_potential)
    from upscale.experiments.lammps.setup import new_instance as _setup

    b = bundle(5, 5, 10.0, ntubes=3, gap=3.0)
    pot = resolve_potential("BNC.tersoff")

    def energy(atoms):
        lmp, _ = _setup(atoms, pot, "s s p")
        lmp.command("run 0")
        e = lmp.get_thermo("pe")
        lmp.close()
        return e

    mol = b.arrays["mol-id"]
    e_sep = 0.0
    for k in (1, 2, 3):
        t = b[mol == k]
        del t.arrays["mol-id"]
        e_sep += energy(t)
    Lz = b.cell[2, 2]
    e_lj = 0.0
    for i in (1, 2, 3):
        for j in range(i + 1, 4):
            xi, xj = b.positions[mol == i], b.positions[mol == j]
            for shift in (-Lz, 0.0, Lz):
                r = cdist(xi, xj + [0, 0, shift]).ravel()
                r = r[r < LJ_CUTOFF]
                e_lj += np.sum(4 * LJ_EPSILON_EV * ((LJ_SIGMA / r) ** 12 - (LJ_SIGMA / r) ** 6))
    assert e_lj < 0  # walls 3 Å apart attract
    assert energy(b) == pytest.approx(e_sep + e_lj, rel=1e-10, abs=1e-8)


@pytest.mark.parametrize("spec", ["rebo", "airebo"])
def test_rebo_and_airebo_run_with_standard_cutoff(spec):
    from upscale.experiments.lammps.tension import quasi_static_tension

    r = quasi_static_tension(swcnt(10, 10, 10.0), spec, cutoff="standard", strain_step=0.01,
                             max_strain=0.02)
    s = r["curve"]["stress_GPa"]
    assert abs(s[0]) < 1e-3 and 0 < s[1] < s[2]
    assert r["potential"]["cutoff"] == "standard"
    assert r["potential"]["file"] == ("CH.rebo" if spec == "rebo" else "CH.airebo")


def test_static_grip_stiffness_small_tube():
    """The dynamic protocol's grips, statically: a 40 Å (10,10) tube with 10 Å grips pulled
    by 0.25 % of its gauge; the tube between them carries ~1 TPa (its periodic modulus is
    0.98), and k = F / separation agrees with the modulus over the gauge."""
    from upscale.experiments.lammps.tension import static_grip_stiffness

    r = static_grip_stiffness(swcnt(10, 10, 40.0), "tersoff:BNC.tersoff", grip=10.0)
    assert 0.85 < r["modulus_TPa"] < 1.15
    area = 2 * math.pi * r["relaxation"]["radius_relaxed_A"] * 3.4
    E = r["k_eV_per_A2"] * r["gauge_length_A"] / area * 160.21766208 / 1000.0
    assert E == pytest.approx(r["modulus_TPa"], rel=1e-9)
    assert r["gauge_length_A"] == pytest.approx(40.0 - 20.0, abs=2.5)
    assert r["max_residual_force_eV_per_A"] < 1e-3
    with pytest.raises(ValueError, match="strain=0.2"):
        static_grip_stiffness(swcnt(10, 10, 40.0), strain=0.2)


# ---------------------------------------------------------------------- the cache folder
def test_cache_dir_is_a_user_folder_overridable_by_the_environment(monkeypatch, tmp_path):
    from upscale.experiments.lammps import cache_dir, default_dump_dir
    from upscale.experiments.lammps import potential

    root = Path(__file__).resolve().parents[1]
    monkeypatch.delenv("UPSCALE_CACHE", raising=False)
    assert not cache_dir().resolve().is_relative_to(root)
    monkeypatch.setenv("UPSCALE_CACHE", str(tmp_path / "c"))
    assert cache_dir() == tmp_path / "c" and potential.cache_dir is cache_dir
    assert default_dump_dir() == tmp_path / "c" / "dumps"
    pot = potential.resolve_potential("BNC.tersoff")  # the step file is written there
    assert pot.file.parent == tmp_path / "c" / "potentials" and pot.file.is_file()


# ------------------------------------------------------------- run(atoms, protocol object)
@pytest.fixture(scope="module")
def short_tube():
    return swcnt(5, 5, 30.0)  # 240 atoms


def test_run_compression_mirrors_tension(short_tube):
    """Compression through the cell: strains -k step, stress negative and growing in
    magnitude, its small-strain slope within 5 % of the tension modulus of the same tube
    (1.010 against 0.988 TPa over 0-0.5 %: the curve is slightly concave)."""
    from upscale.experiments.lammps import run
    from upscale.experiments.protocols import QuasiStatic

    kw = dict(step=0.0025, maximum=0.005)
    c = run(short_tube, QuasiStatic(load="compression", **kw), fit_max_strain=0.005)
    t = run(short_tube, QuasiStatic(load="tension", **kw), fit_max_strain=0.005)
    cc = c["curve"]
    assert cc["load"] == pytest.approx([0.0, -0.0025, -0.005]) == cc["strain"]
    assert cc["response"] == cc["stress_GPa"]
    s = np.array(cc["response"])
    assert abs(s[0]) < 1e-3 and np.all(s[1:] < 0) and np.all(np.diff(s) < 0)
    assert c["kind"] == "lammps-compression" and t["kind"] == "lammps-tension"
    assert c["youngs_modulus_TPa"] == pytest.approx(t["youngs_modulus_TPa"], rel=0.05)
    assert c["figures"]["youngs_TPa"] == pytest.approx(c["youngs_modulus_TPa"], rel=1e-9)
    assert c["strength_GPa"] == s.min() and c["strain_at_peak"] == -0.005
    assert not c["failed"]
    L0 = c["relaxation"]["L0_A"]
    assert np.allclose(cc["Lz_A"], L0 * (1 + np.array(cc["strain"])), rtol=1e-9)
    assert c["protocol"] == dataclasses.asdict(QuasiStatic(load="compression", **kw))
    assert c["protocol_name"] == "quasi-static" and c["protocol_detail"]["load"] == "compression"
    for k in ("lammps_version", "potential", "wall_s", "date_utc"):
        assert k in c


def test_run_torsion_torque_is_linear_with_the_sign_of_the_twist(short_tube):
    """A 30 Å (5,5) tube, 5 Å grips, twisted 1 degree per step: the torque the top grip
    applies grows linearly with the twist (2.24 eV per degree, within 0.1 % over 3
    degrees), the bottom grip balances it, the opposite twist gives the opposite torque,
    and the thin-wall shear modulus is graphene's (0.42 TPa)."""
    from upscale.experiments.lammps import quasi_static_torsion, run
    from upscale.experiments.protocols import QuasiStatic

    p = QuasiStatic(load="torsion", periodic=False, grip=5.0, step=1.0, maximum=3.0)
    r = run(short_tube, p)
    c = r["curve"]
    assert c["load"] == c["twist_deg"] == [0.0, 1.0, 2.0, 3.0]
    T = np.array(c["response"])
    assert c["response"] == c["torque_eV"] and abs(T[0]) < 1e-6
    assert np.all(T[1:] > 0)
    assert np.allclose(T[1:] / np.array(c["load"][1:]), T[1], rtol=1e-3)
    assert np.allclose(c["torque_bottom_eV"], T, atol=1e-6)  # the grips balance
    assert max(c["fmax_eV_per_A"]) < 1e-4
    assert 0.35 < r["shear_modulus_TPa"] < 0.5
    assert r["kind"] == "lammps-torsion" and r["figures"]["peak_torque_eV"] == T[-1]
    assert r["protocol"]["load"] == "torsion" and r["protocol"]["grip"] == 5.0
    neg = quasi_static_torsion(short_tube, grip=5.0, twist_step=-1.0, max_twist=1.5)
    assert neg["curve"]["twist_deg"] == [0.0, -1.0]
    assert neg["curve"]["torque_eV"][1] == pytest.approx(-T[1], rel=1e-3)


def test_run_rejects_what_it_does_not_run(short_tube):
    from upscale.experiments.lammps import run
    from upscale.experiments.protocols import Dynamic, QuasiStatic

    with pytest.raises(ValueError, match="torsion' on a periodic tube"):
        QuasiStatic(load="torsion", periodic=True)  # the protocol object refuses it
    with pytest.raises(ValueError, match="strain_step: fixed by the protocol"):
        run(short_tube, QuasiStatic(), strain_step=0.01)
    with pytest.raises(NotImplementedError, match="periodic=False"):
        run(short_tube, QuasiStatic(load="compression", periodic=False, grip=5.0))
    with pytest.raises(NotImplementedError, match="dynamic tension only"):
        run(short_tube, Dynamic(load="torsion", grip=5.0))
    with pytest.raises(TypeError, match="QuasiStatic or Dynamic"):
        run(short_tube, "quasi-static")


def test_run_maps_the_protocols_onto_the_runners(monkeypatch, short_tube):
    """Which runner keyword each protocol field becomes (no LAMMPS run): the default
    QuasiStatic is the stored references' quasi-static protocol (step 0.5 %, up to 40 %,
    one step after the first 5 % drop), Dynamic's dt (fs) the runner's timestep (ps)."""
    from upscale.experiments.lammps import dynamic, quasistatic, run
    from upscale.experiments.protocols import Dynamic, QuasiStatic, StopRule

    seen = {}

    def fake(name):
        def f(atoms, potential, **kw):
            seen[name] = kw
            return {"protocol": "x", "protocol_detail": {},
                    "curve": {"strain": [0.0, 0.01, 0.02], "stress_GPa": [0.0, 10.0, 20.0]}}
        return f

    p = inspect.signature(quasistatic.quasi_static_tension).parameters
    monkeypatch.setattr(quasistatic, "quasi_static_tension", fake("qs"))
    monkeypatch.setattr(dynamic, "dynamic_tension", fake("dyn"))
    run(short_tube, QuasiStatic(), ftol=1e-9)
    assert seen["qs"] == {"load": "tension", "strain_step": 0.005, "max_strain": 0.40,
                          "after_failure": 1, "failure_drop": 0.05, "ftol": 1e-9}
    # the same values as the runner's defaults, with which the references were made
    assert {k: p[k].default for k in seen["qs"] if k != "ftol"} == {
        k: v for k, v in seen["qs"].items() if k != "ftol"}
    r = run(short_tube, Dynamic(speed=2.0, grip=12.0, dt=0.5, temperature=1.0, tau=0.2,
                                sample_every=50, maximum=0.1, seed=7,
                                stop=StopRule(drop=0.1, below=0.3)))
    assert seen["dyn"] == {"grip": 12.0, "speed": 2.0, "timestep": 0.0005,
                           "temperature": 1.0, "tdamp": 0.2, "sample_every": 50, "seed": 7,
                           "max_strain": 0.1, "failure_drop": 0.1, "stop_below": 0.3}
    assert r["curve"]["load"] == [0.0, 0.01, 0.02] and r["protocol_name"] == "x"
    assert r["protocol"]["speed"] == 2.0 and r["figures"]["youngs_TPa"] == pytest.approx(1.0)
