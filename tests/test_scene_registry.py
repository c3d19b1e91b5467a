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
