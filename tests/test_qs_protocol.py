"""Protocol keywords of the quasi-static LAMMPS runner reach LAMMPS; bad ones fail early."""
import inspect

import pytest

from upscale.build import swcnt

pytestmark = pytest.mark.lammps


class _Recorder:
    """A LAMMPS handle that records every command it is given."""

    def __init__(self, lmp, log):
        self._lmp, self._log = lmp, log

    def command(self, cmd):
        self._log.append(cmd)
        return self._lmp.command(cmd)

    def commands_list(self, cmds):
        self._log.extend(cmds)
        return self._lmp.commands_list(cmds)

    def __getattr__(self, name):
        return getattr(self._lmp, name)


@pytest.fixture
def recorded(monkeypatch):
    from upscale.experiments.lammps import quasistatic as tension

    log = []
    setup = tension._setup

    def recording_setup(*a, **k):
        lmp, types = setup(*a, **k)
        return _Recorder(lmp, log), types

    monkeypatch.setattr(tension, "_setup", recording_setup)
    return log


def test_protocol_keywords_reach_lammps_and_the_record(recorded):
    from upscale.experiments.lammps.tension import quasi_static_tension

    # fmax_tol 0: every strain step runs all its damped cycles, so each keyword is used
    res = quasi_static_tension(swcnt(10, 10, 10.0), strain_step=0.01, max_strain=0.02,
                               fmax_tol=0.0, damped_style="fire", damped_dmax=0.01,
                               damped_timestep_ps=0.0005, damped_steps=50, damped_cycles=2,
                               line_search="backtrack")
    d = res["protocol_detail"]
    assert (d["damped_style"], d["damped_dmax_A"], d["damped_timestep_ps"], d["damped_steps"],
            d["damped_cycles"], d["line_search"], d["fmax_tol_eV_per_A"]) == \
        ("fire", 0.01, 0.0005, 50, 2, "backtrack", 0.0)
    assert "fire" in d["minimize"] and "backtrack" in d["minimize"]
    assert res["curve"]["damped_md_cycles"] == [2, 2, 2]
    for cmd in ("min_style fire", "min_modify dmax 0.01", "timestep 0.0005",
                "min_modify line backtrack", "minimize 0.0 0.001 50 500"):
        assert cmd in recorded, cmd
    assert "min_style quickmin" not in recorded
    # the stress is a converged quantity: the same as with the stored protocol
    ref = quasi_static_tension(swcnt(10, 10, 10.0), strain_step=0.01, max_strain=0.02)
    assert res["curve"]["stress_GPa"][1:] == pytest.approx(ref["curve"]["stress_GPa"][1:],
                                                           rel=1e-4)


def test_cg_only_runs_no_damped_dynamics(recorded):
    from upscale.experiments.lammps.tension import quasi_static_tension

    res = quasi_static_tension(swcnt(10, 10, 10.0), strain_step=0.01, max_strain=0.02,
                               fmax_tol=0.0, damped_cycles=0)
    assert res["curve"]["damped_md_cycles"] == [0, 0, 0]
    assert res["protocol_detail"]["damped_cycles"] == 0
    assert "CG only" in res["protocol_detail"]["minimize"]
    assert not [c for c in recorded if c.startswith(("min_style quickmin", "min_style fire"))]


def test_defaults_are_the_stored_protocol():
    from upscale.experiments.lammps.tension import quasi_static_tension

    p = inspect.signature(quasi_static_tension).parameters
    assert {k: p[k].default for k in ("strain_step", "fmax_tol", "damped_style", "damped_dmax",
                                      "damped_timestep_ps", "damped_steps", "damped_cycles",
                                      "line_search")} == {
        "strain_step": 0.005, "fmax_tol": 1e-4, "damped_style": "quickmin",
        "damped_dmax": 0.02, "damped_timestep_ps": 0.001, "damped_steps": 5000,
        "damped_cycles": 3, "line_search": "quadratic"}


@pytest.mark.parametrize("kw, bad, valid", [
    ({"damped_style": "verlet"}, "'verlet'", "quickmin, fire"),
    ({"line_search": "golden"}, "'golden'", "quadratic, backtrack, forcezero"),
    ({"damped_cycles": -1}, "-1", "integer >= 0"),
    ({"damped_cycles": 1.5}, "1.5", "integer >= 0"),
    ({"damped_steps": 0}, "0", "integer >= 1"),
    ({"damped_dmax": 0.0}, "0.0", "> 0"),
    ({"damped_timestep_ps": float("nan")}, "nan", "> 0"),
    ({"fmax_tol": -1e-4}, "-0.0001", ">= 0"),
])
def test_bad_protocol_one_line_error(kw, bad, valid):
    from upscale.experiments.lammps.tension import quasi_static_tension

    with pytest.raises(ValueError) as ei:
        quasi_static_tension(swcnt(10, 10, 10.0), **kw)
    msg = str(ei.value)
    name = next(iter(kw))
    assert "\n" not in msg and msg.startswith(f"{name}={bad};") and valid in msg
