"""The layering of the code base, read from the import statements of every module (AST).

    potentials  <-  upscale.engine  <-  upscale.models  <-  upscale.experiments  <-  validation

A module may import from its own layer and the layers to its left, never to its right;
``upscale`` as a whole never imports ``validation``, no test imports it, and no case module
imports another. The LAMMPS backend (``upscale.experiments.lammps``) sits beside the engine
under the scenes: it may import ``potentials``, ``upscale.engine``/``models``/``analysis``
and the protocols, never ``validation`` nor the scenes that use it. Imports inside functions count the
same as module-level ones (a lazy import is still a dependency). Across modules only public
names are imported: no ``from a.b import _private`` and no ``a._private`` module, so a
module's private names can change without breaking another. Nor does a module read or call
another's private attributes: ``obj._name`` only where the module itself defines ``_name``
(a method, an attribute it assigns, a keyword it sets), on itself or on ``super()``.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("potentials", "upscale", "validation")

# (importing module prefix, forbidden imported prefixes)
RULES = [
    ("potentials", ("upscale", "validation")),
    ("upscale.engine", ("upscale.models", "upscale.experiments", "validation")),
    ("upscale.models", ("upscale.experiments", "validation")),
    ("upscale.experiments.lammps", ("validation", "upscale.experiments.scenes")),
    ("upscale", ("validation",)),
]


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules():
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            yield _module_name(p), p


def imports(path: Path, module: str):
    """``(line, imported module, imported names)`` of every import in the file, relative
    imports resolved against ``module``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                out.append((node.lineno, a.name, ()))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                if not is_pkg:
                    base = base[:-1]
                base = base[:len(base) - (node.level - 1)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.append((node.lineno, name, tuple(a.name for a in node.names)))
    return out


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def layer_violations():
    bad = []
    for mod, path in _modules():
        for line, name, _ in imports(path, mod):
            for who, forbidden in RULES:
                if _under(mod, who) and any(_under(name, f) for f in forbidden):
                    bad.append(f"{path.relative_to(ROOT)}:{line}: {mod} imports {name}")
                    break
    return bad


def private_name_violations():
    """Imports of another module's private names (or private modules) of the project."""
    bad = []
    for mod, path in _modules():
        for line, name, names in imports(path, mod):
            if not any(_under(name, p) for p in PACKAGES):
                continue
            if name == mod:
                continue
            private_mod = [p for p in name.split(".") if p.startswith("_") and p != "__init__"]
            private_names = [n for n in names if n.startswith("_") and n != "__version__"]
            if private_mod or private_names:
                bad.append(f"{path.relative_to(ROOT)}:{line}: {mod} imports "
                           f"{name}{' ' + ', '.join(private_names) if private_names else ''}")
    return bad


def test_the_walker_sees_every_kind_of_import(tmp_path):
    """The walker itself: absolute, from-, relative and function-level imports are found."""
    pkg = tmp_path / "upscale" / "engine"
    pkg.mkdir(parents=True)
    (tmp_path / "upscale" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    f = pkg / "x.py"
    f.write_text("import upscale.models.base\nfrom ..models import dcbr\n"
                 "def g():\n    from validation.cases.dcbr import _crack\n")
    found = imports(f, "upscale.engine.x")
    assert [n for _, n, _ in found] == ["upscale.models.base", "upscale.models",
                                        "validation.cases.dcbr"]
    assert found[2][2] == ("_crack",)


def test_layers():
    """No module imports a layer to its right (the list names file:line and the import)."""
    bad = layer_violations()
    assert not bad, "layering violated:\n" + "\n".join(bad)


def test_the_lammps_backend_is_walked_and_imports_no_validation():
    """The LAMMPS runners live in ``upscale.experiments.lammps`` (not ``validation``), the
    walker sees every module of it, and none imports ``validation`` or a scene."""
    mods = {m: p for m, p in _modules() if _under(m, "upscale.experiments.lammps")}
    assert {"upscale.experiments.lammps", "upscale.experiments.lammps.tension",
            "upscale.experiments.lammps.potential", "upscale.experiments.lammps.mpi"} <= set(mods)
    assert not (ROOT / "validation" / "lammps").exists()
    names = {n for m, p in mods.items() for _, n, _ in imports(p, m)}
    assert not [n for n in names if _under(n, "validation")
                or _under(n, "upscale.experiments.scenes")]
    assert any(_under(n, "potentials") for n in names)


#: the old coarse-tube stack, which reads its own classes' private state across modules;
#: issue 51 deletes it (these modules go, not the rule)
OLD_STACK = ("upscale/models/dcbr.py", "upscale/models/dcbr_defect.py",
             "upscale/models/dcbr_engine.py", "upscale/experiments/scenes/dcbr_dynamic.py",
             "validation/cases/tube.py")


def _own_private_names(tree) -> set:
    """Private names a module defines: functions, classes, names and attributes it assigns
    (class attributes too), keywords it passes (``set_defaults(_x=...)``) and argparse
    destinations (``dest="_x"``)."""
    own = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            own.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            own.add(node.attr)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            own.add(node.id)
        elif isinstance(node, ast.keyword) and node.arg:
            own.add(node.arg)
            if node.arg == "dest" and isinstance(node.value, ast.Constant):
                own.add(str(node.value.value))
    return {n for n in own if n.startswith("_")}


def private_attribute_violations():
    """``obj._name`` reads or calls where the module does not define ``_name`` itself."""
    bad = []
    for _, path in _modules():
        rel = path.relative_to(ROOT).as_posix()
        if rel in OLD_STACK:
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        own = _own_private_names(tree)
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_")
                    and not node.attr.startswith("__") and node.attr not in own
                    and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))):
                bad.append(f"{rel}:{node.lineno}: {ast.unparse(node.value)}.{node.attr}")
    return bad


def test_no_module_reads_another_modules_private_attributes():
    bad = private_attribute_violations()
    assert not bad, "private attributes read across modules:\n" + "\n".join(bad)


def test_the_attribute_walker_sees_a_foreign_private_attribute(tmp_path):
    """The check is not vacuous: a module reading ``sim._loads`` is caught, one reading its
    own ``self._x`` or an attribute it assigns is not."""
    d = tmp_path / "upscale"
    d.mkdir()
    (d / "m.py").write_text("def f(sim, o):\n    o._mine = 1\n    return sim._loads, o._mine\n"
                            "class A:\n    def g(self):\n        return self._x\n")
    globals_ = globals()
    old_root, old_pk = globals_["ROOT"], globals_["PACKAGES"]
    globals_["ROOT"], globals_["PACKAGES"] = tmp_path, ("upscale",)
    try:
        found = private_attribute_violations()
    finally:
        globals_["ROOT"], globals_["PACKAGES"] = old_root, old_pk
    assert found == ["upscale/m.py:3: sim._loads"]


@pytest.mark.parametrize("pkg", ["validation", "upscale", "potentials"])
def test_only_public_names_across_modules(pkg):
    """Every module imports only public names of ``upscale`` and ``potentials``; within
    ``upscale`` and ``potentials`` no module takes another's private names either."""
    bad = [b for b in private_name_violations() if b.startswith(pkg + "/")
           and (pkg != "validation" or " imports upscale" in b or " imports potentials" in b)]
    assert not bad, "private names imported across modules:\n" + "\n".join(bad)


def test_no_test_imports_validation():
    """The tests test the library: none imports ``validation`` (a case's science is checked
    by running the case, ``python -m validation CASE``)."""
    bad = [f"{p.relative_to(ROOT)}:{line}: imports {name}"
           for p in sorted((ROOT / "tests").rglob("*.py"))
           for line, name, _ in imports(p, "tests." + p.stem) if _under(name, "validation")]
    assert not bad, "tests importing validation:\n" + "\n".join(bad)


def test_cases_import_no_other_case():
    """A validation case module calls the library, not another case module's helpers."""
    bad = [f"{p.relative_to(ROOT)}:{line}: {mod} imports {name}"
           for mod, p in _modules() if _under(mod, "validation.cases")
           for line, name, _ in imports(p, mod)
           if _under(name, "validation.cases") and name != mod]
    assert not bad, "cases importing other cases:\n" + "\n".join(bad)
