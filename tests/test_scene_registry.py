"""Every scene of the registry: its command line is its signature (same defaults, every
parameter an option), and the package exposes it as ``experiments.NAME``."""
import argparse
import inspect

import pytest

from upscale import experiments
from upscale.experiments import registry


@pytest.mark.parametrize("name", registry.names())
def test_command_line_defaults_are_the_signature_defaults(name):
    func = registry.get(name)
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    p = registry.add_scene_parser(sub, name)
    defaults = vars(p.parse_args([]))
    for pname, par in inspect.signature(func).parameters.items():
        if pname == "progress" or par.kind in (par.VAR_KEYWORD, par.VAR_POSITIONAL):
            continue
        assert pname in defaults, f"{name}: parameter {pname} has no option"
        want = None if par.default is par.empty else par.default
        assert defaults[pname] == want, f"{name} --{pname}: {defaults[pname]!r} != {want!r}"
    assert getattr(experiments, name.replace("-", "_")) is func


def test_unknown_scene_names_the_valid_ones():
    with pytest.raises(ValueError, match="unknown scene 'nope'; valid: .*tension"):
        registry.get("nope")
    with pytest.raises(AttributeError, match="scenes: "):
        experiments.nope  # noqa: B018


def test_the_recorded_command_parses_back_to_the_parameters():
    """meta["command"] reruns the scene: parsed by the command line it gives the same
    keyword arguments, an empty string and a False flag included."""
    import shlex

    from upscale.cli import build_parser
    from upscale.experiments.registry import scene_kwargs
    from upscale.experiments.result import command_line

    params = dict(chirality=(8, 0), length=60.0, defects="", model="atomistic",
                  reference=False, protocol="dynamic", seed=3, seeds=2, grip=10.0)
    words = shlex.split(command_line("tension", params))
    kw = scene_kwargs(build_parser().parse_args(words[1:]))
    for k, v in params.items():
        assert kw[k] == v, k
