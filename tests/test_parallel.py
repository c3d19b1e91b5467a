"""One simulation over MPI ranks (upscale.engine.parallel): the decomposition, the rows a
rank builds and the halo lists in one process (the default tier), and, in the MPI tier
(``-m mpi``, ``make test-mpi``), the pre-cracked plates on 1, 2 and 4 ranks under
``mpiexec`` (spawned by this process; skipped when no ``mpiexec`` is found or when this
process was itself started by ``mpiexec``), one thread per rank. The tests that run inside
an ``mpiexec -n 2`` world are in ``test_parallel_mpi.py``."""
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from upscale.engine import build_family, square_lattice
from upscale.engine.families import Family
from upscale.engine.parallel import balance, build_local, halo_depth, rcb
from upscale.engine.families import FamilyRecipe, bonds_crossing_segment, build_family_rows
from upscale.engine.parallel.comm import LAUNCHER_VARS, launched_by_mpi
from upscale.engine.parallel.halo import build_local_rows

HERE = Path(__file__).parent
RUNNER = HERE / "parallel_plate_run.py"
MPIEXEC = shutil.which("mpiexec", path=str(Path(sys.executable).parent)) or shutil.which("mpiexec")
# spawned MPI runs: the MPI tier, from a process not started by mpiexec itself
needs_mpi = pytest.mark.skipif(MPIEXEC is None or launched_by_mpi(),
                               reason="no mpiexec found, or already under mpiexec")


class FakeComm:
    """Rank ``rank`` of ``size`` in one process (the send lists stay empty; ``allgather``
    answers ``gathered``, what the ranks would have sent)."""

    def __init__(self, rank, size, gathered=None):
        self.rank, self.size, self.gathered = rank, size, gathered

    def alltoall(self, objs):
        return [np.zeros(0, dtype=np.int64) for _ in objs]

    def allgather(self, obj):
        return self.gathered


def _plate_family(n=24):
    system = square_lattice(n, n, 1e-3, thickness=1e-3, density=1.0, centered=True)
    return system, build_family(system, 3.015e-3)


def test_rcb_splits_into_balanced_nonempty_parts():
    system, fam = _plate_family()
    w = fam.counts + 1.0
    for parts in (1, 2, 3, 4, 7):
        part = rcb(system.x0, w, parts)
        assert np.array_equal(part, rcb(system.x0, w, parts))  # the same on every rank
        assert set(np.unique(part)) == set(range(parts))
        assert balance(part, w, parts) < 1.05


def test_rcb_refuses_more_ranks_than_particles():
    with pytest.raises(ValueError, match="5 MPI ranks for 4 particles"):
        rcb(np.zeros((4, 3)), np.ones(4), 5)


@pytest.mark.parametrize("depth", [1, 2])
def test_local_rows_are_the_global_rows(depth):
    system, fam = _plate_family()
    size = 4
    part = rcb(system.x0, fam.counts + 1.0, size)
    owner = fam.owner
    seen = np.zeros(fam.nb, dtype=np.int64)
    for r in range(size):
        loc = build_local(FakeComm(r, size), fam.offsets, fam.neighbors, part, depth)
        assert np.all(np.diff(loc.gid) > 0)
        lfam = Family(loc.offsets, loc.neighbors, system.x0[loc.gid], fam.horizon, fam.spacing)
        lfam.reverse  # raises unless symmetric
        # every owned particle's row is its whole global row, in the global order
        for i in np.flatnonzero(loc.owned)[::7]:
            g = loc.gid[i]
            rows = loc.gid[loc.neighbors[loc.offsets[i]:loc.offsets[i + 1]]]
            assert np.array_equal(rows, fam.neighbors[fam.offsets[g]:fam.offsets[g + 1]])
        assert np.array_equal(owner[loc.bond_gid], loc.gid[lfam.owner])
        assert np.all(part[loc.gid[loc.owned]] == r)
        seen[loc.bond_gid[loc.owned_bonds]] += 1
        halo = sum(rows.size for _, rows in loc.recv)
        assert halo == int(np.count_nonzero(~loc.owned))
    assert np.all(seen == 1)  # each bond decided on exactly one owner


@pytest.mark.parametrize("pv", [None, "linear"])
def test_family_rows_of_a_subset_are_the_whole_familys_rows(pv):
    system, _ = _plate_family()
    cut = bonds_crossing_segment(system.x0, (-5e-3, 0.0), (5e-3, 0.0))
    fam = build_family(system, 3.015e-3, partial_volume=pv, exclude=cut)
    rng = np.random.default_rng(1)
    for rows in (np.arange(fam.n), np.sort(rng.choice(fam.n, 37, replace=False)),
                 np.array([0]), np.array([], dtype=np.int64)):
        counts, nbr = build_family_rows(system, 3.015e-3, rows, partial_volume=pv, exclude=cut)
        assert np.array_equal(counts, fam.counts[rows])
        want = [fam.neighbors[fam.offsets[r]:fam.offsets[r + 1]] for r in rows]
        assert np.array_equal(nbr, np.concatenate(want) if want else np.zeros(0))
    with pytest.raises(ValueError, match="sorted and unique"):
        build_family_rows(system, 3.015e-3, np.array([3, 2]))


@pytest.mark.parametrize("depth", [1, 2])
def test_rows_a_rank_builds_alone_are_its_part_of_the_whole_family(depth):
    system, _ = _plate_family()
    cut = bonds_crossing_segment(system.x0, (-5e-3, 0.0), (5e-3, 0.0))
    recipe = FamilyRecipe(system, 3.015e-3, exclude=cut)
    fam = recipe.build()
    size = 4
    part = rcb(system.x0, fam.counts + 1.0, size)
    gathered = [(np.flatnonzero(part == p), fam.counts[part == p]) for p in range(size)]
    for r in range(size):
        want = build_local(FakeComm(r, size), fam.offsets, fam.neighbors, part, depth)
        got = build_local_rows(FakeComm(r, size, gathered), recipe, part, depth)
        for k in ("gid", "owned", "offsets", "neighbors", "bond_gid"):
            assert np.array_equal(getattr(got, k), getattr(want, k)), k
        assert got.nb_global == fam.nb and got.n_global == fam.n


def test_recipe_builds_the_family_and_its_broken_bonds():
    from upscale import models
    from upscale.engine import Simulation

    system, _ = _plate_family()
    cut = bonds_crossing_segment(system.x0, (-5e-3, 0.0), (5e-3, 0.0))
    recipe = FamilyRecipe(system, 3.015e-3, broken=cut)
    fam = build_family(system, 3.015e-3)
    sim = Simulation(system, recipe, models.create("pmb", E=1e9))
    assert np.array_equal(sim.family.neighbors, fam.neighbors)
    want = ~cut(fam.owner, fam.neighbors, fam.xi)
    assert not want.all() and np.array_equal(sim.state.intact, want)


def test_started_by_a_launcher_without_mpi_one_line_on_rank0_only():
    code = ("import sys; sys.modules['mpi4py'] = None\n"
            "from upscale.engine.parallel import world\nworld()")
    for rank in (0, 1):
        env = {**_env(), "PMI_SIZE": "2", "PMI_RANK": str(rank)}
        r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                           text=True, timeout=120)
        assert r.returncode != 0
        lines = r.stderr.strip().splitlines()
        if rank == 0:
            assert len(lines) == 1 and "mpi4py is not importable" in lines[0], r.stderr
        else:
            assert lines == [], r.stderr


def test_halo_depth_of_the_models():
    from upscale import models

    assert halo_depth(models.create("pmb", E=1e9)) == 1
    assert halo_depth(models.create("pmb", E=1e9, surface_correction=True)) == 2
    assert halo_depth(models.create("lps", E=1e9, nu=0.25)) == 2

    assert halo_depth(models.create("tipd", E=1e9, nu=0.3, s0=0.01)) == 1
    with pytest.raises(ValueError, match="Ti-PD with surface correction"):
        halo_depth(models.create("tipd", E=1e9, nu=0.3, surface="correspondence"))

    assert halo_depth(models.create("nosb", E=1e9, nu=0.25, stabilisation="silling")) == 2
    with pytest.raises(ValueError, match="bond-associated correspondence"):
        halo_depth(models.create("nosb", E=1e9, nu=0.25, bond_associated=True))
    cpd = dict(horizon=3e-3, dim=2, E=1e9, nu=0.34, plane="stress")
    assert halo_depth(models.create("cpd", **cpd, calibration="continuum")) == 2
    with pytest.raises(ValueError, match="calibration='discrete'.*interior particle"):
        halo_depth(models.create("cpd", **cpd))
    with pytest.raises(ValueError, match="CPD with surface correction"):
        halo_depth(models.create("cpd", **cpd, calibration="continuum", surface_correction=True))
    assert halo_depth(models.create("unified")) == 2
    with pytest.raises(ValueError, match="unified model with bond failure.*bond states"):
        halo_depth(models.create("unified", r_s=1e-3, G_c=100.0))

    class Other:
        name = "tridyn-eb"

    for name, why in (("tridyn-eb", "rotations are fields"), ("dcbr", "coarse tube runs on one"),
                      ("dcbr-defect-tube", "coarse tube"), ("peri-x", "does not know the halo")):
        Other.name = name
        with pytest.raises(ValueError, match=f"'{name}' cannot run on several MPI ranks "
                                             f"yet.*{why}"):
            halo_depth(Other())


# ---------------------------------------------------------------- under mpiexec
def _env():
    env = {k: v for k, v in os.environ.items() if k not in LAUNCHER_VARS}
    env["NUMBA_NUM_THREADS"] = "1"
    return env


def _run(ranks, *args, timeout=600, **kw):
    cmd = [sys.executable, *map(str, args)]
    if ranks > 1:
        cmd = [MPIEXEC, "-n", str(ranks), *cmd]
    return subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=timeout, **kw)


N_PLATE, STEPS = 30, 1000
#: the killed run's steps: long enough that the kill, at most 0.5 s after the second
#: checkpoint, lands before the end on a quiet machine too (1,000 steps take about 0.2 s)
KILL_STEPS = 20 * STEPS


@pytest.fixture(scope="module")
def serial_plates(tmp_path_factory):
    d = tmp_path_factory.mktemp("serial")
    out = {}
    for model in ("pmb", "lps", "tipd"):
        f = d / f"{model}.npz"
        r = _run(1, RUNNER, model, N_PLATE, STEPS, f)
        assert r.returncode == 0, r.stderr
        out[model] = dict(np.load(f))
    return out


@pytest.mark.mpi
@needs_mpi
@pytest.mark.parametrize("model,ranks", [("pmb", 2), ("pmb", 4), ("lps", 2), ("lps", 4),
                                         ("tipd", 2)])
def test_plate_on_ranks_is_bit_identical_to_serial(model, ranks, serial_plates, tmp_path):
    ref = serial_plates[model]
    assert int(ref["broken"]) > ref["intact"].size // 20  # the crack ran: bonds broke
    f = tmp_path / "par.npz"
    r = _run(ranks, RUNNER, model, N_PLATE, STEPS, f)
    assert r.returncode == 0, r.stderr
    got = dict(np.load(f))
    assert int(got["ranks"]) == ranks and bool(got["agree"])
    # one thread per rank keeps every particle's sum order: the same bits
    assert np.array_equal(got["u"], ref["u"])
    assert np.array_equal(got["intact"], ref["intact"])
    assert got["energy"] == pytest.approx(ref["energy"], rel=1e-12)
    assert got["ke"] == pytest.approx(ref["ke"], rel=1e-12)


@pytest.mark.mpi
@needs_mpi
def test_restart_after_sigkill_on_two_ranks_is_bit_identical(tmp_path):
    full = tmp_path / "full.npz"
    assert _run(2, RUNNER, "pmb", N_PLATE, KILL_STEPS, full).returncode == 0
    work = tmp_path / "work"
    work.mkdir()
    cmd = [MPIEXEC, "-n", "2", sys.executable, str(RUNNER), "pmb", str(N_PLATE), str(KILL_STEPS),
           str(tmp_path / "killed.npz"), str(work), "40"]
    p = subprocess.Popen(cmd, env=_env(), start_new_session=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not list(work.glob("*.prev.npz")) and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(random.uniform(0.0, 0.5))
    os.killpg(p.pid, signal.SIGKILL)   # the whole process group: launcher and ranks
    p.wait()
    assert not (tmp_path / "killed.npz").exists(), "the run finished before the kill"
    resumed = tmp_path / "resumed.npz"
    r = _run(2, RUNNER, "pmb", N_PLATE, KILL_STEPS, resumed, work, 40)
    assert r.returncode == 0, r.stderr
    a, b = np.load(full), np.load(resumed)
    assert np.array_equal(a["u"], b["u"]) and np.array_equal(a["intact"], b["intact"])
    # another rank count refuses the files, naming the way out
    r = _run(4, RUNNER, "pmb", N_PLATE, KILL_STEPS, tmp_path / "x.npz", work, 40)
    assert r.returncode != 0 and "was written on 2 MPI ranks" in r.stderr
    r = _run(1, RUNNER, "pmb", N_PLATE, KILL_STEPS, tmp_path / "x.npz", work, 40)
    assert r.returncode != 0 and "upscale.engine.parallel.convert" in r.stderr


def _cli(ranks, *args, **kw):
    """``mpiexec -n RANKS python -m upscale.cli ARGS`` (the ``upscale`` script's entry)."""
    return _run(ranks, "-m", "upscale.cli", *args, **kw)


@pytest.mark.mpi
@needs_mpi
def test_cli_plate_on_two_ranks(tmp_path):
    r = _cli(2, "plate", "--n", 20, "--t-end", "1e-6", "--quiet", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    fig = json.loads((tmp_path / "plate.json").read_text())["figures"]
    assert fig["mpi_ranks"] == 2 and fig["particles"] == 400
    assert r.stdout.count("mpi_ranks") == 1          # one table, from rank 0
    r = _cli(2, "plate", "--n", 20, "--t-end", "-1", "--out", tmp_path)
    assert r.returncode == 2 and r.stderr.count("error:") == 1, r.stderr
    r = _cli(2, "tension", "--chirality", "5,5", "--out", tmp_path)   # one process only
    assert r.returncode == 2 and r.stderr.count("runs on one MPI rank") == 1, r.stderr


@pytest.mark.mpi
@needs_mpi
def test_blow_up_on_two_ranks_stops_every_rank_with_the_diagnosis(tmp_path):
    r = _cli(2, "plate", "--n", 20, "--dt", "1.7e-6", "--force-dt", "--t-end", "1e-3", "--quiet",
             "--out", tmp_path,
             timeout=300)
    assert r.returncode != 0
    assert "blew up at step" in r.stderr and "on rank" in r.stderr


@pytest.mark.mpi
@needs_mpi
def test_output_on_two_ranks_gathered_extxyz_and_pvtu(tmp_path):
    args = ("plate", "--n", 20, "--t-end", "2e-6", "--every", 2, "--quiet")
    for ranks in (1, 2):
        r = _cli(ranks, *args, "--workdir", tmp_path / f"w{ranks}", "--out", tmp_path / f"o{ranks}")
        assert r.returncode == 0, r.stderr
    w1, w2 = tmp_path / "w1", tmp_path / "w2"
    # the gathered trajectory is the serial one, byte for byte (same bits, same order)
    assert (w1 / "traj.extxyz").read_bytes() == (w2 / "traj.extxyz").read_bytes()
    a = json.loads((w1 / "summary.json").read_text())["frames"]
    b = json.loads((w2 / "summary.json").read_text())["frames"]
    assert [f["broken_bonds"] for f in a] == [f["broken_bonds"] for f in b]
    pvtu = (w2 / "vtk" / "frame_000004.pvtu").read_text()
    assert pvtu.count("<Piece ") == 2 and 'Name="damage"' in pvtu
    import meshio

    pieces = [meshio.read(w2 / "vtk" / f"frame_000004_{r}.vtu") for r in (0, 1)]
    whole = meshio.read(w1 / "vtk" / "frame_000004.vtu")
    assert sum(p.points.shape[0] for p in pieces) == whole.points.shape[0]
    got = np.concatenate([p.point_data["damage"] for p in pieces])
    assert np.array_equal(np.sort(got), np.sort(whole.point_data["damage"]))


@pytest.mark.mpi
@needs_mpi
def test_checkpoints_of_two_ranks_merged_resume_on_four_and_on_one(tmp_path):
    ref = tmp_path / "ref.npz"
    assert _run(1, RUNNER, "pmb", N_PLATE, STEPS, ref).returncode == 0
    work = tmp_path / "w"
    work.mkdir()
    r = _run(2, RUNNER, "pmb", N_PLATE, STEPS // 2, tmp_path / "half.npz", work, 100)
    assert r.returncode == 0, r.stderr
    from upscale.engine.parallel.convert import main as convert

    assert convert([str(work / "checkpoint.npz"), "--ranks", "2"]) == 0
    for ranks in (4, 1):
        w = tmp_path / f"w{ranks}"
        shutil.copytree(work, w)
        out = tmp_path / f"r{ranks}.npz"
        r = _run(ranks, RUNNER, "pmb", N_PLATE, STEPS, out, w, 100)
        assert r.returncode == 0, r.stderr
        a, b = np.load(ref), np.load(out)
        assert np.array_equal(a["u"], b["u"]) and np.array_equal(a["intact"], b["intact"])


@pytest.mark.mpi
@needs_mpi
def test_refused_under_mpiexec_one_line_on_rank0_every_rank_exits():
    code = "from upscale.engine import newton\nnewton.dirichlet(None)"
    r = _run(2, "-c", code, timeout=120)
    assert r.returncode != 0
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: an implicit solve"), r.stderr
    lean = "from parallel_plate_run import lean_plate\nlean_plate(20, 'pmb', object())"
    r = _run(2, "-c", lean, timeout=120, cwd=HERE)
    lines = r.stderr.strip().splitlines()
    assert r.returncode != 0 and len(lines) == 1 and "with object runs on one rank" in lines[0], \
        r.stderr


def test_scaling_model_halo_speedup_and_crossover():
    from upscale.engine.parallel import scaling as S

    const = S.fit(n_particles=40000, bonds=1_100_000, s_per_step_1rank=0.01,
                  halo_rows_2ranks=600, packing_s_2ranks=1.2e-5, rows_moved_2ranks=1200,
                  halo_bonds_2ranks=3600)
    assert const["halo_width_rows"] == pytest.approx(3.0)           # 600 rows over 200
    assert const["t_row_s"] == pytest.approx(2e-8)
    assert S._halo(100.0, 2, 3.0) == (pytest.approx(16 ** 2 - 10 ** 2), 8)   # the shell
    rows = S.strong(1e6, const, dim=2)
    assert rows[0]["ranks"] == 1 and rows[0]["speedup"] == 1.0 and rows[-1]["ranks"] == 1000
    assert all(b["total_s"] < a["total_s"] for a, b in zip(rows, rows[1:]))
    assert all(0 < r["efficiency"] <= 1.0 for r in rows)
    a = dict(S.ASSUMED)
    n = S.crossover(const, dim=3, a=a)
    t = S.step_time(n, 1000, const, dim=3, a=a)
    assert t["exchange_s"] + t["allreduce_s"] == pytest.approx(t["compute_owned_s"], rel=1e-6)
    slow = {**a, "latency_s": 10 * a["latency_s"]}                 # a slower network
    assert S.crossover(const, dim=3, a=slow) > n
    weak = S.weak(1e5, const, dim=3, a=a)
    assert weak[0]["efficiency"] == 1.0 and weak[-1]["efficiency"] < weak[1]["efficiency"] <= 1.0
