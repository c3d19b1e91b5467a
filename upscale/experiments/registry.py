"""The scenes by name, and their command line made from their signatures.

Every scene is a plain function of its parameters returning a
:class:`~upscale.experiments.result.Result` (:data:`SCENES`: name -> ``module:function``,
imported on first use). The command line (``upscale NAME ...``), the sweeps and the
validation cases call these functions and nothing else, so the library's signature is the
one place a default lives: :func:`add_scene_parser` turns a signature into options
(``foo_bar=1.0`` -> ``--foo-bar FLOAT``; ``bool`` -> ``--flag / --no-flag``; a
``Literal[...]`` -> choices; ``tuple`` -> a comma list; help from the numpydoc
``Parameters`` section), so ``--help`` shows the validated defaults.

One vocabulary on every scene: ``--out DIR`` (default ``out/NAME``), ``--quiet``,
``--threads N``; where the scene takes them, ``--seed``, ``--checkpoint-every``,
``--resume``; a scene with a ``structure`` argument reads ``--structure FILE`` with ASE;
a scene with a ``model`` argument takes ``--compare MODEL`` (the same scene with the
reference model, the table of relative errors, both on one plot).
"""
from __future__ import annotations

import argparse
import importlib
import inspect
import re
import sys
import typing
from pathlib import Path

__all__ = ["SCENES", "QUICK", "get", "names", "add_scene_parser", "run_from_args",
           "REMOVED_FLAGS", "argv_of"]

#: scene name -> "module:function"
SCENES: dict[str, str] = {
    "tension": "upscale.experiments.scenes.tube:tension",
    "plate": "upscale.experiments.scenes.plate:plate",
    "cpd": "upscale.experiments.scenes.cpd_bar:cpd",
    "beam": "upscale.experiments.scenes.tridyn_scenes:beam",
    "plate-bending": "upscale.experiments.scenes.tridyn_scenes:plate_bending_scene",
    "dispersion": "upscale.experiments.scenes.tridyn_scenes:dispersion",
    "tipd": "upscale.experiments.scenes.tipd:tipd",
    "scb": "upscale.experiments.scenes.scb:scb",
    "bundle": "upscale.experiments.scenes.bundle_scene:bundle",
}

#: each scene's quick variant: keyword arguments that run it in seconds (tests, the report's
#: quick runs, a first try from the shell)
QUICK: dict[str, dict] = {
    "tension": dict(chirality=(5, 5), length=25.0, model="atomistic", maximum=0.02),
    "plate": dict(model="lps", n=20, t_end=6e-6, quick=True),
    "cpd": dict(scene="cantilever", dim=2, dx=2e-3, ratio=2.0),
    "beam": dict(theory="timoshenko", support="cantilever", n=20, ratios=(1.0, 2.0),
                 shear_integration="bond"),
    "plate-bending": dict(n=(8,), thickness=0.05),
    "dispersion": dict(model="tridyn-timoshenko", compare_text=True),
    "tipd": dict(case="mms", dx=(0.05, 0.025)),
    "scb": dict(alpha=0.0, dx=3e-3, r_s=6e-3, growth="free"),
    "bundle": dict(chirality=(10, 10), length=60.0, ntubes=2, grip=15.0, max_strain=0.012),
}

#: flags of the old command lines -> what replaces them (one line each)
REMOVED_FLAGS: dict[str, str] = {
    "--outdir": "use --out DIR",
    "--engine": "the engine is the only driver now: drop --engine",
    "--scene-loop": "the scene's own loop was removed: every run is on the engine",
}

_COMMON = ("out", "quiet", "threads")


def names() -> list[str]:
    return sorted(SCENES)


def get(name: str):
    """The scene function registered under ``name`` (``-`` or ``_`` alike).

    Raises ``ValueError`` naming the valid scenes."""
    key = str(name).replace("_", "-")
    if key not in SCENES:
        raise ValueError(f"unknown scene {name!r}; valid: {', '.join(names())}")
    module, func = SCENES[key].split(":")
    return getattr(importlib.import_module(module), func)


# --------------------------------------------------------------------- argparse from signatures
def _param_help(doc: str | None) -> dict[str, str]:
    """``name -> first sentence`` from a numpydoc ``Parameters`` section."""
    if not doc:
        return {}
    text = inspect.cleandoc(doc)
    m = re.search(r"^Parameters\n-+\n(.*?)(?:\n\n[A-Z][a-z]+\n-+\n|\Z)", text, re.S | re.M)
    if not m:
        return {}
    out, name, lines = {}, None, []
    for line in m.group(1).splitlines():
        head = re.match(r"^(\w+)(?:\s*,\s*\w+)*\s*:", line)
        if head and not line.startswith(" "):
            if name:
                out[name] = " ".join(lines)
            name, lines = head.group(1), []
        elif name and line.strip():
            lines.append(line.strip())
    if name:
        out[name] = " ".join(lines)
    return {k: v.replace("%", "%%") for k, v in out.items()}


def _unwrap_optional(tp):
    if typing.get_origin(tp) in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _comma_list(elem, n=None):
    def parse(text: str):
        items = [s for s in str(text).split(",") if s.strip()]
        if n is not None and len(items) != n:
            raise argparse.ArgumentTypeError(f"{text!r}: {n} comma-separated values expected")
        try:
            return tuple(elem(s) for s in items)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: comma-separated {elem.__name__} "
                                             "values expected") from None
    return parse


def _option_kwargs(p: inspect.Parameter, tp, helptext: str) -> dict:
    default = p.default
    kw: dict = {"default": default, "help": f"{helptext} (default: {default})".strip()}
    tp = _unwrap_optional(tp)
    origin = typing.get_origin(tp)
    if tp is bool:
        kw["action"] = argparse.BooleanOptionalAction
    elif origin is typing.Literal:
        kw["choices"] = list(typing.get_args(tp))
        kw["type"] = type(kw["choices"][0])
    elif origin in (tuple, list):
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        elem = args[0] if args else str
        n = None if (Ellipsis in typing.get_args(tp) or origin is list) else len(args)
        kw["type"] = _comma_list(elem, n)
        kw["metavar"] = "A,B" if n == 2 else "LIST"
    elif tp in (int, float, str):
        kw["type"] = tp
    elif tp is Path:
        kw["type"] = Path
    else:
        kw["type"] = str
    return kw


def add_scene_parser(sub, name: str) -> argparse.ArgumentParser:
    """Add the sub-command ``name`` to ``sub`` from the scene function's signature."""
    func = get(name)
    doc = inspect.getdoc(func) or ""
    summary = doc.split("\n\n")[0].replace("\n", " ")
    p = sub.add_parser(name, help=summary.replace("%", "%%"),
                       description=summary.replace("%", "%%"))
    sig = inspect.signature(func, eval_str=True)
    helps = _param_help(doc)
    for pname, par in sig.parameters.items():
        if pname in ("progress",) or par.kind in (par.VAR_KEYWORD, par.VAR_POSITIONAL):
            continue
        if pname == "structure":
            p.add_argument("--structure", type=Path, default=None,
                           help="a structure file ASE reads (extxyz, LAMMPS data, ...); "
                           + helps.get(pname, ""))
            continue
        default = par.default if par.default is not par.empty else None
        par = par.replace(default=default)
        p.add_argument("--" + pname.replace("_", "-"), dest=pname,
                       **_option_kwargs(par, par.annotation, helps.get(pname, "")))
    p.add_argument("--out", type=Path, default=Path("out") / name,
                   help="folder for the JSON, CSV and PNG (default: out/%(prog)s)".replace(
                       "%(prog)s", name))
    p.add_argument("--quiet", action="store_true", help="no progress, only the table")
    p.add_argument("--threads", type=int, default=None, help="numba threads (default: all)")
    if "model" in sig.parameters:
        p.add_argument("--compare", default=None, metavar="MODEL",
                       help="run the same scene with MODEL as the reference and print the "
                       "relative errors (e.g. lammps)")
    p.set_defaults(_scene=name)
    return p


def scene_kwargs(args: argparse.Namespace) -> dict:
    """The scene function's keyword arguments from parsed options (``--structure`` read
    with ASE)."""
    func = get(args._scene)
    sig = inspect.signature(func)
    kw = {k: getattr(args, k) for k in sig.parameters if hasattr(args, k)}
    if "structure" in kw and kw["structure"] is not None:
        from ase.io import read

        path = Path(kw["structure"])
        if not path.is_file():
            raise ValueError(f"--structure {path}: no such file")
        kw["structure"] = read(path)
    if "progress" in sig.parameters:
        kw["progress"] = not args.quiet
    return kw


def run_from_args(args: argparse.Namespace):
    """Run the scene of parsed ``args``: the scene function, then its JSON, CSV and PNG in
    ``--out`` and the figures (or the comparison) on stdout. Returns the Result."""
    from upscale.io import text_table

    out = Path(args.out)
    _check_writable(out)
    if args.threads:
        from upscale.engine.kernels import set_threads

        set_threads(args.threads)
    func = get(args._scene)
    kw = scene_kwargs(args)
    res = func(**kw)
    stem = args._scene.replace("-", "_")
    res.to_json(out / f"{stem}.json")
    res.to_csv(out)
    ref = None
    if getattr(args, "compare", None):
        try:
            ref = func(**{**kw, "model": args.compare})
        except LookupError as exc:  # a reference the user chose not to compute now
            print(f"no comparison: {exc}", file=sys.stderr)
    if ref is not None:
        ref.to_json(out / f"{stem}_{args.compare}.json")
        print(res.compare(ref))
    else:
        print(text_table([{"figure": k, "value": v} for k, v in res.figures.items()],
                         ["figure", "value"], ".6g"))
    res.plot(out / f"{stem}.png", other=ref)
    if not args.quiet:
        print(f"wrote {out}/{stem}.json, .png and CSV", file=sys.stderr)
    return res


def argv_of(name: str, kwargs: dict) -> list[str]:
    """The command line (without ``upscale``) that calls scene ``name`` with ``kwargs``:
    the inverse of :func:`scene_kwargs` for the option types of :func:`add_scene_parser`."""
    out = [name]
    for k, v in kwargs.items():
        opt = "--" + k.replace("_", "-")
        if isinstance(v, bool):
            out.append(opt if v else "--no-" + k.replace("_", "-"))
        elif isinstance(v, (tuple, list)):
            out.append(f"{opt}={','.join(repr(x) for x in v)}")
        else:
            out.append(f"{opt}={v}" if isinstance(v, str) else f"{opt}={v!r}")
    return out


def _check_writable(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".upscale-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ValueError(f"--out {out}: cannot write there ({exc.strerror})") from None
