"""The models that run on the engine, by name.

>>> from upscale import models
>>> pmb = models.create("pmb", E=192e9, nu=0.25, horizon=3e-4, dim=3)
>>> models.names()
['lps', 'pmb', ...]

A model module registers itself with one call at import time::

    from upscale.models import register
    register("cpd", CPDModel)

and :func:`get` finds it by name: first through the lazy table :data:`LAZY` (name ->
``(module, class)``, imported only when asked for), then, for a name it does not know, by
importing every module of this package once so their ``register`` calls run. An unknown
name raises a one-line ``ValueError`` listing the valid names.
"""
from __future__ import annotations

import importlib
import pkgutil

from upscale.models.base import Model, Needs  # noqa: F401  (re-exported)

__all__ = ["Model", "Needs", "register", "get", "create", "names", "LAZY"]

#: name -> (module, class name); imported on first use
LAZY: dict[str, tuple[str, str]] = {
    "pmb": ("upscale.models.bond_based", "PMB"),
    "lps": ("upscale.models.state_based", "LPS"),
}

_REGISTRY: dict[str, type] = {}
_discovered = False


def register(name: str, cls: type) -> type:
    """Register model class ``cls`` under ``name`` (lower case). Returns ``cls`` so it can
    also be used as ``register("x", X)`` at the bottom of a module. Re-registering the same
    class is harmless; a different class under a taken name is an error."""
    key = name.lower()
    old = _REGISTRY.get(key)
    if old is not None and old is not cls and old.__qualname__ != cls.__qualname__:
        raise ValueError(f"model name {name!r} already registered to {old.__module__}.{old.__qualname__}")
    _REGISTRY[key] = cls
    return cls


def _discover() -> None:
    global _discovered
    if _discovered:
        return
    _discovered = True
    import upscale.models as pkg

    for mod in pkgutil.iter_modules(pkg.__path__):
        if mod.name.startswith("_") or mod.name == "base":
            continue
        try:
            importlib.import_module(f"upscale.models.{mod.name}")
        except Exception:  # a broken sibling module must not hide the valid names
            continue


def names() -> list[str]:
    """All model names known (lazy table and registered), sorted."""
    _discover()
    return sorted(set(LAZY) | set(_REGISTRY))


def get(name: str) -> type:
    """The model class registered under ``name``.

    Raises
    ------
    ValueError
        ``unknown model 'x'; valid: lps, pmb, ...``
    """
    key = str(name).lower()
    if key in _REGISTRY:
        return _REGISTRY[key]
    if key in LAZY:
        module, cls = LAZY[key]
        c = getattr(importlib.import_module(module), cls)
        _REGISTRY.setdefault(key, c)
        return c
    _discover()
    if key in _REGISTRY:
        return _REGISTRY[key]
    raise ValueError(f"unknown model {name!r}; valid: {', '.join(names())}")


def create(name: str, **params) -> Model:
    """Instantiate the model registered under ``name`` with ``params``."""
    return get(name)(**params)
