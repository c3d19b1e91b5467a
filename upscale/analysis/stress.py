"""Axial stress of tubes with the wall-thickness convention, and stress–strain curve metrics.

Convention (DESIGN.md "Units"): a tube's load-bearing area is its wall, a cylinder shell of
mean radius R and thickness t = 3.4 Å, ``A = 2 pi R t``; a bundle of ``ntubes`` tubes has
``ntubes * A``. Two routes to the axial force F of a periodic tube or a gripped one:

* From the virial (periodic cell of length L along z, positions at a minimum or averaged):
  the energy change under a homogeneous axial strain is ``dE/d eps_zz = -p_zz V`` (the
  ``zz`` virial with the sign LAMMPS uses, ``p_zz = (sum_i m v_z^2 + sum r_z f_z) / V``),
  and ``eps_zz = dL / L``, so the axial force is ``F = dE/dL = -p_zz V / L`` and

      sigma = F / (ntubes 2 pi R t) = -p_zz V / (ntubes 2 pi R t L).

  ``V`` is whatever volume the code used to turn the virial into ``p_zz`` (the box volume,
  vacuum included): ``p_zz V`` is the virial itself, independent of the box.
* From a reaction force F on a grip: ``sigma = F / (ntubes 2 pi R t)``.

Units: LAMMPS ``metal`` pressure in bar (1 bar = 1e-4 GPa), forces in eV/Å
(1 eV/Å^3 = 160.21766 GPa).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["WALL_THICKNESS", "EV_PER_A3_IN_GPA", "BAR_IN_GPA", "wall_area",
           "stress_from_pressure", "stress_from_force", "curve_metrics"]

WALL_THICKNESS = 3.4           # Å
EV_PER_A3_IN_GPA = 160.21766208
BAR_IN_GPA = 1e-4


def wall_area(radius: float, thickness: float = WALL_THICKNESS, ntubes: int = 1) -> float:
    """Load-bearing wall area ``ntubes * 2 pi R t``, Å^2."""
    if not (radius > 0 and thickness > 0 and ntubes >= 1):
        raise ValueError(f"wall_area(radius={radius}, thickness={thickness}, ntubes={ntubes}); "
                         "valid: positive radius and thickness, ntubes >= 1")
    return ntubes * 2.0 * math.pi * radius * thickness


def stress_from_pressure(pzz_bar, volume, length, radius, thickness=WALL_THICKNESS,
                         ntubes=1):
    """Axial tube stress in GPa from LAMMPS ``pzz`` (bar), box volume (Å^3), cell length
    along the axis (Å) and tube radius (Å): ``-pzz V / (ntubes 2 pi R t L)``."""
    A = wall_area(radius, thickness, ntubes)
    return -np.asarray(pzz_bar) * np.asarray(volume) / (A * np.asarray(length)) * BAR_IN_GPA


def stress_from_force(force_ev_per_a, radius, thickness=WALL_THICKNESS, ntubes=1):
    """Axial tube stress in GPa from an axial force in eV/Å: ``F / (ntubes 2 pi R t)``."""
    return np.asarray(force_ev_per_a) / wall_area(radius, thickness, ntubes) * EV_PER_A3_IN_GPA


def curve_metrics(strain, stress, fit_max_strain: float = 0.02, drop: float = 0.05,
                  plateau_fraction: float = 0.05, failure_from_strain: float | None = None
                  ) -> dict:
    """Young's modulus, strength and failure strain of a tensile stress–strain curve.

    Parameters
    ----------
    strain, stress : (n,) array_like
        Engineering strain (dimensionless) and stress in GPa, strain increasing.
    fit_max_strain : float
        Young's modulus is the slope of a least-squares line (with intercept) through all
        points with ``0 <= strain <= fit_max_strain``.
    drop : float
        Failure is the first point whose stress is below ``(1 - drop)`` times the running
        maximum; strength is that maximum, reached at ``strain_at_peak``; ``failure_strain``
        is the strain of the dropping point.
    failure_from_strain : float, optional
        Only drops at or after this strain count as failure (e.g. the strain of the first
        broken bond, when the signal rings before it); earlier dips are not failure.
    plateau_fraction : float
        Cutoff-artefact check: if, before failure, the tangent modulus falls below
        ``plateau_fraction * E`` in magnitude at a stress above half the maximum before
        failure, and the stress later rises by more than ``drop`` above the
        stress where that happened, the curve "stiffens after a plateau" (the switching
        function of a standard Tersoff/REBO cutoff). Then ``strength_GPa`` is the plateau
        stress, ``rise_after_plateau`` is True and ``max_stress_before_failure_GPa`` keeps the
        later maximum, reported but never taken as strength.

    Returns
    -------
    dict
        ``youngs_modulus_TPa``, ``youngs_fit_max_strain``, ``strength_GPa``,
        ``strain_at_peak``, ``failure_strain`` (None if no drop), ``failed``,
        ``rise_after_plateau``, ``max_stress_before_failure_GPa``, and the maximum of the
        whole curve ``max_stress_overall_GPa`` at ``strain_at_max_stress_overall`` (a bundle
        whose outer tubes carry more load after the central one failed).
    """
    e = np.asarray(strain, dtype=float)
    s = np.asarray(stress, dtype=float)
    if e.ndim != 1 or e.shape != s.shape or len(e) < 3:
        raise ValueError(f"strain and stress must be 1-D of equal length >= 3, got shapes "
                         f"{e.shape} and {s.shape}")
    sel = (e >= -1e-12) & (e <= fit_max_strain + 1e-12)
    if sel.sum() < 2:
        raise ValueError(f"fewer than 2 points with 0 <= strain <= {fit_max_strain}; "
                         "use finer strain steps or a larger fit_max_strain")
    E = float(np.polyfit(e[sel], s[sel], 1)[0])  # GPa
    run_max = np.maximum.accumulate(s)
    late = e >= failure_from_strain - 1e-12 if failure_from_strain is not None else True
    dropped = np.nonzero((s < (1.0 - drop) * run_max) & (run_max > 0) & late)[0]
    ifail = int(dropped[0]) if len(dropped) else None
    upto = ifail if ifail is not None else len(s)
    ipeak = int(np.argmax(s[:upto]))
    out = {"youngs_modulus_TPa": E / 1000.0, "youngs_fit_max_strain": fit_max_strain,
           "max_stress_overall_GPa": float(s.max()),
           "strain_at_max_stress_overall": float(e[int(np.argmax(s))]),
           "max_stress_before_failure_GPa": float(s[ipeak]),
           "strength_GPa": float(s[ipeak]), "strain_at_peak": float(e[ipeak]),
           "failure_strain": float(e[ifail]) if ifail is not None else None,
           "failed": ifail is not None, "rise_after_plateau": False,
           "failure_criterion": f"first stress drop > {100 * drop:g}% below the running max"
                                + (f" at or after strain {failure_from_strain:.4g}"
                                   if failure_from_strain is not None else "")}
    # plateau-then-rise (cutoff artefact) check on the tangent modulus before failure
    if upto >= 3 and E > 0:
        tangent = np.diff(s[:upto]) / np.diff(e[:upto])
        # flat: |tangent| small (a dip of a few % has a steep negative tangent instead)
        low = ((np.abs(tangent) < plateau_fraction * E) & (e[1:upto] > fit_max_strain)
               & (s[:upto - 1] > 0.5 * s[:upto].max()))  # a plateau at high stress
        flat = np.nonzero(low)[0]
        if len(flat):
            k = int(flat[0])          # plateau starts at point k
            if s[k + 1:upto].max(initial=-np.inf) > (1.0 + drop) * s[k]:
                ip = int(np.argmax(s[:k + 1]))
                out.update(rise_after_plateau=True, strength_GPa=float(s[ip]),
                           strain_at_peak=float(e[ip]))
    return out
