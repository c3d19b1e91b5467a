"""The ``upscale plate`` scene and its command line: a crack grows from the pre-crack, a
damage map and a JSON result are written; bad input gives one line and writes nothing."""
import json
import subprocess
import sys

import pytest

from upscale.cli import main


def run_cli(*argv):
    return subprocess.run([sys.executable, "-m", "upscale.cli", *argv], capture_output=True, text=True,
                          timeout=600)


def test_plate_small_run_writes_result_and_png(tmp_path, capsys):
    out = tmp_path / "plate"
    assert main(["plate", "--n", "40", "--out", str(out), "--quiet", "--threads", "1"]) == 0
    r = json.loads((out / "plate.json").read_text())["result"]
    assert r["particles"] == 1600 and r["precrack_bonds"] > 0
    assert r["broken_bonds_by_loading"] > 0
    assert r["crack_length_m"] > 0.01  # the crack grew beyond the 10 mm pre-crack
    png = (out / "damage.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert "crack length" in capsys.readouterr().out


def test_plate_resume_continues_from_checkpoint(tmp_path):
    out = tmp_path / "p"
    base = ["plate", "--n", "30", "--out", str(out), "--quiet", "--threads", "1", "--checkpoint-every", "10"]
    assert main([*base, "--t-end", "4e-6"]) == 0
    first = json.loads((out / "plate.json").read_text())["result"]
    assert main([*base, "--t-end", "8e-6", "--resume"]) == 0
    second = json.loads((out / "plate.json").read_text())["result"]
    assert second["resumed"] and second["steps"] > first["steps"]
    assert second["time_s"] == pytest.approx(8e-6, rel=0.1)


@pytest.mark.parametrize("argv,needle", [
    (["--model", "nope"], "unknown model 'nope'; valid: "),
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
    assert len(lines) == 1 and needle in lines[0], proc.stderr
    assert keep.read_text() == '{"old": true}\n'
    assert sorted(p.name for p in out.iterdir()) == ["plate.json"]
