"""Tersoff potential as LAMMPS ``pair_style tersoff`` computes it, from LAMMPS ``.tersoff``
files read as they are.

    atoms.calc = Tersoff.from_lammps("BNC.tersoff", elements=["C"])   # Lindsay-Broido carbon
    atoms.calc = Tersoff.from_lammps("SiC.tersoff", elements=["C"])   # Tersoff 1989 carbon
    atoms.calc = Tersoff.from_lammps("BNC.tersoff", step_cutoff=True)

The equations, the parameter look-up ("i j k" for a triplet, "i j j" for the two-body
terms) and LAMMPS's numerical branches are in :mod:`potentials.tersoff_kernels`.

Step cutoff. ``step_cutoff=True`` replaces the switching function f_C by a step at the outer
cutoff R + D (the usual fix of the spurious stiffening of stretched bonds in the switching
region). LAMMPS is given the same potential by :func:`write_step_cutoff_file`, which writes
the file with every entry's (R, D) replaced by (R + D - 1e-5, 1e-5): the outer cutoff is
unchanged, and the two agree exactly while no distance lies within 2e-5 Angstrom of it.

A file is parsed like LAMMPS does it: ``#`` starts a comment, blank lines are skipped, an
entry is 17 words (3 elements and 14 numbers: m, gamma, lambda3, c, d, costheta0 = h, n,
beta, lambda2, B, R, D, lambda1, A) and may continue over several lines.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numba
import numpy as np
from ase.data import atomic_numbers, chemical_symbols

from potentials import tersoff_kernels as tk
from potentials.calculator import PotentialCalculator

__all__ = ["TersoffParameters", "Tersoff", "read_tersoff_file", "resolve_potential_file",
           "write_step_cutoff_file", "STEP_CUTOFF_D", "NAMES", "INDEX"]

#: the switching width written into LAMMPS files for the step cutoff (Angstrom)
STEP_CUTOFF_D = 1.0e-5

NAMES = ("m", "gamma", "lambda3", "c", "d", "costheta0", "n", "beta", "lambda2", "B", "R",
         "D", "lambda1", "A")
#: column of each parameter in a parameter row (``INDEX["R"] == 10``)
INDEX = {name: i for i, name in enumerate(NAMES)}


class TersoffFileError(ValueError):
    """A malformed ``.tersoff`` file; the message names the file and the line."""


def resolve_potential_file(name_or_path) -> Path:
    """A path to an existing file: the path itself, or a file shipped with LAMMPS."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    if p.parent == Path("."):
        from potentials.lammps_runtime import lammps_potential_path

        return lammps_potential_path(p.name)
    raise FileNotFoundError(f"no Tersoff potential file {str(name_or_path)!r}")


@dataclasses.dataclass(frozen=True)
class _Entry:
    elements: tuple[str, str, str]
    values: tuple[float, ...]  # the 14 numbers in file order
    line: int  # line number where the entry starts (1-based)


def _parse(path: Path) -> list[_Entry]:
    entries: list[_Entry] = []
    words: list[str] = []
    start = 0
    with open(path, "r", encoding="utf-8", errors="replace") as fh:
        lines = fh.read().splitlines()
    for lineno, raw in enumerate(lines, start=1):
        text = raw.split("#", 1)[0]
        new = text.split()
        if not new:
            continue
        if not words:
            start = lineno
        words += new
        if len(words) < 17:
            continue
        if len(words) > 17:
            raise TersoffFileError(
                f"{path}:{start}: a Tersoff entry has 17 words (3 elements and 14 numbers); "
                f"lines {start}-{lineno} hold {len(words)}")
        values = []
        for w in words[3:]:
            try:
                values.append(float(w))
            except ValueError:
                raise TersoffFileError(
                    f"{path}:{start}: cannot read {w!r} as a number in the entry "
                    f"{' '.join(words[:3])} (lines {start}-{lineno})") from None
        _check_values(path, start, words[:3], values)
        entries.append(_Entry(tuple(words[:3]), tuple(values), start))
        words = []
    if words:
        raise TersoffFileError(
            f"{path}:{start}: the file ends inside an entry ({len(words)} of 17 words)")
    return entries


def _check_values(path, line, elems, v) -> None:
    p = dict(zip(NAMES, v))
    bad = [k for k in ("c", "d", "n", "beta", "lambda2", "B", "R", "D", "lambda1", "A",
                       "gamma") if p[k] < 0]
    if bad:
        raise TersoffFileError(f"{path}:{line}: entry {' '.join(elems)}: negative {', '.join(bad)}")
    if p["D"] > p["R"]:
        raise TersoffFileError(f"{path}:{line}: entry {' '.join(elems)}: D > R")
    if p["m"] not in (1.0, 3.0):
        raise TersoffFileError(f"{path}:{line}: entry {' '.join(elems)}: m must be 1 or 3, "
                               f"got {p['m']:g}")


@dataclasses.dataclass
class TersoffParameters:
    """The entries of a Tersoff file for a set of elements, ready for the kernel.

    Attributes
    ----------
    elements : list of str
        Element names; atom type ``t`` is ``elements[t]``.
    raw : (n_entries, 14) float
        The file's numbers in file order (see :data:`NAMES`).
    e2p : (nel, nel, nel) int64
        Row of ``raw`` (and of :attr:`table`) for the triplet (i, j, k).
    source : str
        Where the numbers came from.
    step_cutoff : bool
        Whether f_C is a step at R + D.
    """

    elements: list[str]
    raw: np.ndarray
    e2p: np.ndarray
    source: str = ""
    step_cutoff: bool = False

    @property
    def table(self) -> np.ndarray:
        """Parameter table of the kernel (columns ``tersoff_kernels.IDX_*``)."""
        raw = self.raw.copy()
        if self.step_cutoff:
            raw[:, 10] = raw[:, 10] + raw[:, 11]  # R -> R + D
            raw[:, 11] = 0.0  # D -> 0: f_C = 1 for r < R + D
        return tk.derived_columns(raw)

    @property
    def cutoff(self) -> float:
        """Largest R + D (Angstrom)."""
        return float(np.max(self.raw[:, 10] + self.raw[:, 11]))

    def entry(self, i: str, j: str, k: str) -> dict:
        """The 14 numbers of the entry "i j k" by name."""
        e = self.elements
        return dict(zip(NAMES, self.raw[self.e2p[e.index(i), e.index(j), e.index(k)]]))

    def with_step_cutoff(self, on: bool = True) -> "TersoffParameters":
        return dataclasses.replace(self, step_cutoff=on)


def read_tersoff_file(name_or_path, elements=None) -> TersoffParameters:
    """Read a LAMMPS ``.tersoff`` file for the given elements (default: all in the file).

    Raises
    ------
    TersoffFileError
        Malformed file (the message names file and line), duplicate or missing entries.
    ValueError
        An element is not in the file (the message lists those that are).
    """
    path = resolve_potential_file(name_or_path)
    entries = _parse(path)
    available = []
    for e in entries:
        for el in e.elements:
            if el not in available:
                available.append(el)
    if elements is None:
        elements = available
    elements = [str(e) for e in elements]
    if len(set(elements)) != len(elements):
        raise ValueError(f"elements listed twice: {elements}")
    missing = [e for e in elements if e not in available]
    if missing:
        raise ValueError(f"element{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                         f"not in {path.name}; it has {', '.join(sorted(available))}")
    nel = len(elements)
    e2p = -np.ones((nel, nel, nel), np.int64)
    rows = []
    for e in entries:
        if not all(el in elements for el in e.elements):
            continue  # like LAMMPS: an entry is used only if all three elements are mapped
        i, j, k = (elements.index(el) for el in e.elements)
        if e2p[i, j, k] >= 0:
            raise TersoffFileError(f"{path}:{e.line}: duplicate entry {' '.join(e.elements)}")
        e2p[i, j, k] = len(rows)
        rows.append(e.values)
    for i in range(nel):
        for j in range(nel):
            for k in range(nel):
                if e2p[i, j, k] < 0:
                    raise TersoffFileError(
                        f"{path}: no entry {elements[i]} {elements[j]} {elements[k]} "
                        f"(every triplet of {', '.join(elements)} is needed)")
    return TersoffParameters(elements, np.array(rows, dtype=float), e2p, source=str(path))


def write_step_cutoff_file(src, dst, D: float = STEP_CUTOFF_D) -> Path:
    """Write a copy of a ``.tersoff`` file for LAMMPS with the step cutoff.

    Every entry keeps its outer cutoff R + D and gets the switching width ``D`` (default
    1e-5 Angstrom): (R, D) -> (R + D - 1e-5, 1e-5). All entries of ``src`` are written, one
    per line, with 17 significant digits (the numbers are reproduced exactly).
    """
    src = resolve_potential_file(src)
    entries = _parse(src)
    out = [f"# {src.name} with the switching region of f_C narrowed to D = {D:g} Angstrom",
           "# (outer cutoff R + D unchanged): written by potentials.tersoff."
           "write_step_cutoff_file",
           "# element1 element2 element3 m gamma lambda3 c d costheta0 n beta lambda2 B R D"
           " lambda1 A"]
    for e in entries:
        v = list(e.values)
        outer = v[10] + v[11]
        v[10], v[11] = outer - D, D
        out.append(" ".join(e.elements) + " " + " ".join(repr(float(x)) for x in v))
    dst = Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.{os.getpid()}.tmp")
    tmp.write_text("\n".join(out) + "\n")
    os.replace(tmp, dst)
    return dst


class Tersoff(PotentialCalculator):
    """ASE calculator of the Tersoff potential in LAMMPS's form (see module docstring).

    Parameters
    ----------
    parameters : TersoffParameters
    step_cutoff : bool, optional
        Override ``parameters.step_cutoff``.
    skin, min_distance : float
        See :class:`~potentials.calculator.PotentialCalculator`.
    nthreads : int or None
        numba threads for the kernel (default: numba's current setting).

    Source: J. Tersoff, Phys. Rev. B 37, 6991 (1988) and 39, 5566 (1989); the form and
    numerics of LAMMPS ``pair_style tersoff`` (doc page ``pair_tersoff``).
    """

    def __init__(self, parameters: TersoffParameters, step_cutoff: bool | None = None,
                 nthreads: int | None = None, **kwargs):
        super().__init__(**kwargs)
        if step_cutoff is not None:
            parameters = parameters.with_step_cutoff(bool(step_cutoff))
        self.tersoff = parameters
        self.cutoff = parameters.cutoff
        self.nthreads = nthreads
        self._P = parameters.table
        self._e2p = np.ascontiguousarray(parameters.e2p, dtype=np.int64)
        self._symbol_to_type = {s: t for t, s in enumerate(parameters.elements)}
        self._types = self._numbers = None

    #: the kernel allocates its outputs afresh on every call
    compute_returns_new_arrays = True

    @property
    def table(self) -> np.ndarray:
        """Parameter table (rows of :data:`NAMES`) the kernels take as ``P``."""
        return self._P

    @property
    def e2p(self) -> np.ndarray:
        """Element-triplet to parameter-row map the kernels take as ``e2p``."""
        return self._e2p

    @classmethod
    def from_lammps(cls, name_or_path, elements=None, step_cutoff: bool = False, **kwargs):
        """From a LAMMPS ``.tersoff`` file: a path, or the name of a file shipped with
        LAMMPS (``"BNC.tersoff"``, ``"SiC.tersoff"``). ``elements`` defaults to all."""
        return cls(read_tersoff_file(name_or_path, elements), step_cutoff=step_cutoff,
                   **kwargs)

    def __repr__(self):
        src = Path(self.tersoff.source).name
        return (f"Tersoff({src!r}, elements={self.tersoff.elements}, "
                f"step_cutoff={self.tersoff.step_cutoff})")

    def types(self, atoms) -> np.ndarray:
        """Element index of each atom (raises for an element the calculator lacks)."""
        numbers = atoms.numbers
        if self._types is not None and np.array_equal(numbers, self._numbers):
            return self._types
        table = np.full(max(119, int(numbers.max(initial=0)) + 1), -1, np.int64)
        for s, t in self._symbol_to_type.items():
            if s in atomic_numbers:
                table[atomic_numbers[s]] = t
        types = table[numbers]
        if np.any(types < 0):
            bad = sorted({chemical_symbols[z] for z in numbers[types < 0]})
            raise ValueError(
                f"the atoms contain {', '.join(bad)}, which this Tersoff potential "
                f"({Path(self.tersoff.source).name}: {', '.join(self.tersoff.elements)}) "
                "does not have")
        self._numbers = numbers.copy()
        self._types = types
        return types

    def check_atoms(self, atoms) -> None:
        self.types(atoms)

    def compute(self, atoms, nl):
        nt = self.nthreads or numba.get_num_threads()
        return tk.tersoff(np.ascontiguousarray(atoms.positions, dtype=float),
                          np.ascontiguousarray(atoms.cell.array, dtype=float), nl.first_n,
                          nl.j_b, nl.shift_bc, self._types, self._e2p, self._P,
                          float(self.cutoff), int(nt))
