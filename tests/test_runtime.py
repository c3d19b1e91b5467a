"""The package's runtime plumbing: LAMMPS loads without environment variables, results are
written atomically."""
import json

import pytest

from potentials.lammps_runtime import LammpsUnavailable, lammps_module, new_lammps
from upscale.io import versions, write_json


def test_lammps_imports_without_environment():
    mod = lammps_module()
    lmp = new_lammps()
    try:
        assert lmp.version() > 20200000
        for pkg in ("MANYBODY", "PERI"):
            assert lmp.has_package(pkg), pkg
    finally:
        lmp.close()
    assert mod is lammps_module()


def test_atomic_json_keeps_old_file_on_failure(tmp_path):
    p = tmp_path / "r.json"
    write_json(p, {"a": 1})

    class Bad:
        pass

    with pytest.raises(TypeError):
        write_json(p, {"a": Bad()})
    assert json.loads(p.read_text()) == {"a": 1}
    assert [q.name for q in tmp_path.iterdir()] == ["r.json"]


def test_versions_name_the_processor():
    """A timing's provenance names the processor (two machines of one 'x86_64' differ 1.5x)."""
    import os
    import platform

    v = versions()
    assert v["cpu_count"] == os.cpu_count()
    if os.path.exists("/proc/cpuinfo") and platform.machine() == "x86_64":
        assert " (family " in v["cpu"] and " model " in v["cpu"]


def test_lammps_error_type_is_runtime_error():
    assert issubclass(LammpsUnavailable, RuntimeError)
