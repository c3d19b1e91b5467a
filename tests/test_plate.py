"""The ``upscale plate`` scene and its command line: a crack grows from the pre-crack, a
damage map and a JSON result are written; bad input gives one line and writes nothing."""
import subprocess
import sys

import pytest

from upscale.cli import main
from upscale.experiments.result import Result


def run_cli(*argv):
    return subprocess.run([sys.executable, "-m", "upscale.cli", *argv], capture_output=True, text=True,
                          timeout=600)


def test_plate_small_run_writes_result_and_png(tmp_path, capsys):
    out = tmp_path / "plate"
    assert main(["plate", "--n", "40", "--out", str(out), "--quiet", "--threads", "1"]) == 0
    r = Result.from_json(out / "plate.json")
    f = r.figures
    assert f["particles"] == 1600 and f["precrack_bonds"] > 0
    assert f["broken_bonds_by_loading"] > 0
    assert f["crack_length_m"] > 0.01  # the crack grew beyond the 10 mm pre-crack
    assert r.fields["damage"].shape == (1600,) and r.fields["x0"].shape == (1600, 3)
    assert r.curves["history/crack_length_mm"][-1] == pytest.approx(1e3 * f["crack_length_m"])
    png = (out / "plate.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert "crack_length_m" in capsys.readouterr().out


def test_plate_resume_continues_from_checkpoint(tmp_path):
    out = tmp_path / "p"
    base = ["plate", "--n", "30", "--out", str(out), "--workdir", str(out), "--quiet", "--threads", "1",
            "--checkpoint-every", "10"]
    assert main([*base, "--t-end", "4e-6"]) == 0
    first = Result.from_json(out / "plate.json").figures
    assert (out / "checkpoint.npz").is_file()
    assert main([*base, "--t-end", "8e-6", "--resume"]) == 0
    second = Result.from_json(out / "plate.json").figures
    assert second["resumed"] and second["steps"] > first["steps"]
    assert second["time_s"] == pytest.approx(8e-6, rel=0.1)


@pytest.mark.parametrize("argv,needle", [
    (["--model", "nope"], "invalid choice: 'nope' (choose from 'pmb', 'lps')"),
    (["--resume"], "resume needs a workdir"),
    (["--horizon", "0.5"], "horizon"),
    (["--dt", "1.0"], "exceeds the stable estimate"),
    (["--n", "3"], "at least 10 particles"),
])
def test_bad_input_one_line_and_nothing_overwritten(tmp_path, argv, needle):
    out = tmp_path / "plate"
    out.mkdir()
    keep = out / "plate.json"
    keep.write_text('{"old": true}\n')
    proc = run_cli("plate", "--n", "20", "--out", str(out), "--quiet", *argv)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    if argv[0] == "--model":          # argparse's choices: the usage line, then the error
        lines = lines[-1:]
    assert len(lines) == 1 and needle in lines[0], proc.stderr
    assert keep.read_text() == '{"old": true}\n'
    assert sorted(p.name for p in out.iterdir()) == ["plate.json"]
