"""Validation cases: every comparison against a reference and every benchmark.

Run ``python -m validation --list`` to see them, ``python -m validation CASE [--quick]`` to
run one. A case lives in a module of :mod:`validation.cases` and registers itself with
:func:`validation.registry.case`.
"""
