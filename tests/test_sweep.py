"""The sweep machinery (upscale.experiments.sweep) on a LocalCluster with trivial scenes.

The scenes below are module-level functions of this module, so the sweep can name them
(``test_sweep:square``); the shared cluster runs its workers as threads of this process,
which starts in well under a second and imports nothing new; one test starts the default
LocalCluster of worker processes (a few seconds).
"""
import csv
import json
import socket

import pytest

from upscale.experiments import sweep

CALLS = []  # (x, seed) of every square() call in this process, to count what really ran


def square(x: float, seed: int = 0, offset: float = 0.0) -> dict:
    """A trivial scene: x^2 + offset + seed / 1000, and a private key that must be dropped."""
    CALLS.append((x, seed))
    return {"y": x * x + offset + seed / 1000.0, "nested": {"x_twice": 2 * x},
            "_private": object()}


def fails_at_three(x: float, seed: int = 0) -> dict:
    """Raises for x == 3, else returns x."""
    if x == 3.0:
        raise RuntimeError(f"deliberate failure at x={x}")
    return {"y": x}


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                     dashboard_address="127.0.0.1:0", scheduler_kwargs={"dashboard": False},
                     silence_logs=40)
    yield c
    c.close()


def _spec(tmp_path, **kw):
    spec = {"scene": "test_sweep:square", "output": str(tmp_path / "out"),
            "grid": {"x": [1.0, 2.0, 3]}, "seeds": [0, 7], "plot": {"x": "x",
                                                                   "metrics": ["y"]}}
    spec.update(kw)
    return spec


def _csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_small_sweep_table_and_plot(tmp_path, cluster):
    CALLS.clear()
    rep = sweep.run_sweep(_spec(tmp_path), scheduler=cluster.scheduler_address,
                          progress=False)
    assert rep["planned"] == 6 and len(rep["executed"]) == 6 and not rep["failed"]
    assert sorted(CALLS) == sorted((x, s) for x in (1.0, 2.0, 3.0) for s in (0, 7))
    rows = _csv(rep["table"])
    assert [r["status"] for r in rows] == ["ok"] * 6
    for r in rows:  # parameters as columns, results beside them
        x, s = float(r["x"]), int(r["seed"])
        assert float(r["y"]) == x * x + s / 1000.0
        assert float(r["nested.x_twice"]) == 2 * x
        assert "_private" not in r
    assert rows[4]["x"] == "3.0"  # the int 3 is coerced to the declared float
    assert (tmp_path / "out" / "plots" / "y_vs_x.png").stat().st_size > 1000
    rec = json.loads((tmp_path / "out" / "runs" / rows[0]["run_id"] / "result.json")
                     .read_text())
    assert rec["params"] == {"x": 1.0, "seed": 0} and rec["status"] == "ok"


def test_restart_skips_finished_and_redoes_missing(tmp_path, cluster):
    spec = _spec(tmp_path)
    first = sweep.run_sweep(spec, scheduler=cluster.scheduler_address, progress=False)
    # a killed sweep: one result never written (in flight), and a temporary file left over
    lost = first["executed"][2]
    res = tmp_path / "out" / "runs" / lost / "result.json"
    res.unlink()
    (res.parent / ".result.json.x.tmp").write_text("{half")
    kept = {p: p.stat().st_mtime_ns for p in (tmp_path / "out" / "runs").glob("*/result.json")}
    CALLS.clear()
    again = sweep.run_sweep(spec, scheduler=cluster.scheduler_address, progress=False)
    assert again["executed"] == [lost] and len(CALLS) == 1
    assert len(again["skipped"]) == 5
    assert all(p.stat().st_mtime_ns == t for p, t in kept.items())  # nothing rewritten
    def strip(rows):  # the redone run's wall time differs; nothing else may
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]

    assert strip(_csv(again["table"])) == strip(_csv(first["table"]))


def test_failure_recorded_and_others_complete(tmp_path, cluster):
    spec = _spec(tmp_path, scene="test_sweep:fails_at_three", plot={})
    rep = sweep.run_sweep(spec, scheduler=cluster.scheduler_address, progress=False)
    rows = _csv(rep["table"])
    bad = [r for r in rows if r["status"] == "error"]
    assert len(bad) == 2 and {r["x"] for r in bad} == {"3.0"}
    assert all(r["status"] == "ok" for r in rows if r["x"] != "3.0")
    assert bad[0]["error"] == "RuntimeError: deliberate failure at x=3.0"
    rec = json.loads((tmp_path / "out" / "runs" / bad[0]["run_id"] / "result.json")
                     .read_text())
    assert "in fails_at_three" in rec["traceback"]
    assert sorted(rep["failed"]) == sorted(r["run_id"] for r in bad)
    # a restart does not retry a recorded failure unless asked to
    again = sweep.run_sweep(spec, scheduler=cluster.scheduler_address, progress=False)
    assert again["executed"] == []
    retry = sweep.run_sweep(spec, scheduler=cluster.scheduler_address, progress=False,
                            retry_failed=True)
    assert sorted(retry["executed"]) == sorted(r["run_id"] for r in bad)


def test_default_local_cluster_from_a_toml_file(tmp_path):
    """The LocalCluster that run_sweep starts (and closes) itself, from a TOML spec."""
    f = tmp_path / "s.toml"
    f.write_text(f'scene = "test_sweep:square"\noutput = "{tmp_path / "o"}"\nrepeats = 2\n'
                 'seed_start = 10\n[params]\noffset = 0.5\n[grid]\nx = [1.5]\n'
                 '[run]\nworkers = 1\nprocesses = false\n')
    rep = sweep.run_sweep(f, progress=False)
    rows = _csv(rep["table"])
    assert [(r["seed"], float(r["y"])) for r in rows] == [("10", 2.76), ("11", 2.761)]
    assert rep["workers"] == 1


def test_yaml_spec(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(f"scene: test_sweep:square\noutput: {tmp_path / 'o'}\ngrid:\n  x: [1, 2]\n")
    spec = sweep.load_spec(f)
    assert spec.runs == [{"x": 1.0}, {"x": 2.0}] and spec.seed_param is None


def test_run_identity_depends_on_scene_params_and_code():
    a = sweep.run_id("m:f", {"x": 1.0}, "v1")
    assert a == sweep.run_id("m:f", {"x": 1.0}, "v1")
    assert len({a, sweep.run_id("m:g", {"x": 1.0}, "v1"), sweep.run_id("m:f", {"x": 2.0}, "v1"),
                sweep.run_id("m:f", {"x": 1.0}, "v2")}) == 4


@pytest.mark.parametrize("change, message", [
    ({"scene": "no-such-scene"}, "scene 'no-such-scene': unknown"),
    ({"scene": "test_sweep:nope"}, "cannot import 'test_sweep:nope'"),
    ({"grid": {"z": [1.0]}}, "parameter 'z': unknown to scene 'test_sweep:square'"),
    ({"grid": {"x": ["a", 2.0]}}, "parameter x='a' (str) of scene 'test_sweep:square'; "
                                  "valid: float"),
    ({"grid": {"x": [True]}}, "parameter x=True (bool)"),
    ({"grid": {"x": 1.0}}, "grid x = 1.0; valid: a non-empty list"),
    ({"seeds": [1, 1]}, "repeat a seed"),
    ({"params": {"offset": 1.0}, "grid": {"offset": [2.0], "x": [1.0]}}, "given twice"),
    ({"colour": "red"}, "unknown key(s) colour"),
    ({"grid": {}, "seeds": [0]}, "needs parameter(s) x"),
])
def test_bad_spec_one_line_error(tmp_path, change, message):
    with pytest.raises(ValueError) as err:
        sweep.run_sweep(_spec(tmp_path, **change), progress=False)
    assert message in str(err.value) and "\n" not in str(err.value)
    assert not (tmp_path / "out").exists()  # nothing written


def test_unreachable_scheduler(tmp_path):
    with socket.socket() as s:  # a loopback port with nothing listening on it
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    addr = f"tcp://127.0.0.1:{port}"
    with pytest.raises(ValueError) as err:
        sweep.run_sweep(_spec(tmp_path), scheduler=addr, timeout=0.5, progress=False)
    assert f"scheduler '{addr}' unreachable within 0.5 s" in str(err.value)
    assert "\n" not in str(err.value)
    assert not (tmp_path / "out").exists()  # nothing written


def test_folder_of_another_spec_is_refused(tmp_path, cluster):
    sweep.run_sweep(_spec(tmp_path), scheduler=cluster.scheduler_address, progress=False)
    before = {p: p.read_bytes() for p in (tmp_path / "out").rglob("*") if p.is_file()}
    with pytest.raises(ValueError) as err:
        sweep.run_sweep(_spec(tmp_path, seeds=[0, 8]), scheduler=cluster.scheduler_address,
                        progress=False)
    assert "holds a different sweep" in str(err.value) and "\n" not in str(err.value)
    after = {p: p.read_bytes() for p in (tmp_path / "out").rglob("*") if p.is_file()}
    assert after == before
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not a sweep's folder"):
        sweep.run_sweep(_spec(tmp_path, output=str(tmp_path / "other")), progress=False)
    assert [p.name for p in (tmp_path / "other").iterdir()] == ["notes.txt"]


def test_cli_one_line_error_and_exit_code(tmp_path, capsys):
    from upscale.cli import main

    f = tmp_path / "s.toml"
    f.write_text(f'scene = "test_sweep:square"\noutput = "{tmp_path / "o"}"\n'
                 '[grid]\nx = ["one"]\n')
    assert main(["sweep", str(f), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("upscale sweep: error: parameter x='one'") and "\n" not in err
    assert main(["sweep", str(tmp_path / "missing.toml")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_execute_sets_numba_threads_and_records_the_error_line():
    rec = sweep.execute("test_sweep:square", {"x": 2.0}, numba_threads=1)
    assert rec["status"] == "ok" and rec["result"] == {"y": 4.0, "nested": {"x_twice": 4.0}}
    assert rec["numba_threads"] == 1
    rec = sweep.execute("test_sweep:fails_at_three", {"x": 3.0})
    assert rec["status"] == "error" and rec["error"].startswith("RuntimeError: deliberate")
    rec = sweep.execute("test_sweep:not_a_dict", {})
    assert rec["status"] == "error" and "returned a list" in rec["error"]


def not_a_dict() -> list:
    """A broken scene: returns a list."""
    return [1.0]


def test_plot_x_must_be_a_parameter(tmp_path):
    with pytest.raises(ValueError, match="plot x = 'seedz'; valid: a parameter"):
        sweep.load_spec(_spec(tmp_path, plot={"x": "seedz", "metrics": ["y"]}))


def test_sweep_machinery_does_not_import_validation():
    """Layering: upscale.experiments must not need validation (a fresh interpreter)."""
    import subprocess
    import sys

    code = ("import sys, upscale.experiments.sweep as s; s.load_spec({'scene': 'tension', "
            "'output': 'x', 'grid': {'length': [30.0]}}); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'validation'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"


def test_local_cluster_of_processes_sets_numba_threads(tmp_path):
    """The default LocalCluster (worker processes): each worker's numba is capped at
    cores // workers through its environment, and the task uses that many threads."""
    import os

    rep = sweep.run_sweep(_spec(tmp_path, seeds=[0], grid={"x": [1.0, 2.0]}, plot={}),
                          workers=2, progress=False)
    recs = [json.loads(p.read_text()) for p in (tmp_path / "out" / "runs").glob("*/result.json")]
    assert len(recs) == 2 and all(r["status"] == "ok" for r in recs)
    want = max(1, (os.cpu_count() or 1) // 2)
    assert rep["numba_threads"] == want and all(r["numba_threads"] == want for r in recs)
    assert all(r["pid"] != os.getpid() for r in recs)  # ran in the worker processes


def nap(seconds: float = 1.0, seed: int = 0) -> dict:
    """A scene that takes its time: sleeps, returns the seed."""
    import time

    time.sleep(seconds)
    return {"seed_back": seed}


@pytest.mark.slow
def test_sigkill_of_the_command_and_restart(tmp_path):
    """``upscale sweep`` killed (SIGKILL, its process group) midway, then restarted: the
    finished runs' files are untouched, the rest run, and no process of the group is left."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    root = Path(sweep.__file__).resolve().parents[2]
    f = tmp_path / "s.toml"
    f.write_text(f'scene = "test_sweep:nap"\noutput = "{tmp_path / "o"}"\nrepeats = 8\n'
                 '[params]\nseconds = 1.0\n[run]\nworkers = 2\n')
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), str(Path(__file__).parent)])}
    cmd = [sys.executable, "-m", "upscale.cli", "sweep", str(f), "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    runs = tmp_path / "o" / "runs"
    while proc.poll() is None and len(list(runs.glob("*/result.json"))) < 3:
        time.sleep(0.05)
    assert proc.poll() is None, "the sweep ended before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    before = {p: p.stat().st_mtime_ns for p in runs.glob("*/result.json")}
    assert 3 <= len(before) < 8
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
    assert f"8 runs: {len(before)} already done, {8 - len(before)} run now, 0 failed" in out
    assert all(p.stat().st_mtime_ns == t for p, t in before.items())
    rows = _csv(tmp_path / "o" / "results.csv")
    assert sorted(int(r["seed_back"]) for r in rows) == list(range(8))
    with pytest.raises(ProcessLookupError):
        os.killpg(proc.pid, 0)
