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

from upscale.constants import EV_PER_A3_IN_GPA, WALL_THICKNESS_A

__all__ = ["WALL_THICKNESS", "EV_PER_A3_IN_GPA", "BAR_IN_GPA", "wall_area",
           "stress_from_pressure", "stress_from_force", "curve_metrics", "Extensometer",
           "EXTENSOMETER_MARGIN", "extensometer_metrics"]

WALL_THICKNESS = WALL_THICKNESS_A   # Å (upscale.constants)
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


def _slope(x, y) -> float:
    """Least-squares slope (with intercept) of y against x."""
    return float(np.polyfit(x, y, 1)[0])


def _fit_window(e, fit_max_strain):
    """The modulus fit's points: ``0 <= strain <= fit_max_strain`` (at least 2)."""
    sel = (e >= -1e-12) & (e <= fit_max_strain + 1e-12)
    if sel.sum() < 2:
        raise ValueError(f"fewer than 2 points with 0 <= strain <= {fit_max_strain}; "
                         "use finer strain steps or a larger fit_max_strain")
    return sel


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
    sel = _fit_window(e, fit_max_strain)
    E = _slope(e[sel], s[sel])  # GPa
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


EXTENSOMETER_MARGIN = 0.25  # of the gauge, at each end: the marks halfway between grip and centre


class Extensometer:
    """Strain measured on gauge marks inside the specimen, as a tensile test's extensometer.

    The grip strain of the dynamic protocol (grip separation change / gauge) includes the
    compliance of the material next to the grips; in the coarse model that boundary layer
    is 7-23 % more compliant than LAMMPS's (the centred gain stencil next to a rigid grip),
    so the two codes' grip strains differ by a boundary artefact. The extensometer measures
    the strain of the material between two marks instead:

        eps_ext = sum_i w_i (z0_i - zbar) u_i / sum_i w_i (z0_i - zbar)^2,  u_i = z_i - z0_i,

    the weighted least-squares slope of the axial displacement u against the reference axial
    position z0 over the points with ``lo <= z0 <= hi`` (``zbar`` their weighted mean z0);
    the reference is the configuration at the start of the pull. It is linear in u, exact for
    a uniform stretch (u = eps (z0 - c) gives eps), and blind to rigid motion. Written as a
    weighted mean of the local strain u'(z), its weight is proportional to the weighted
    count of points beyond z times their mean distance from zbar: largest at the centre of
    the window and zero at and outside the marks, so nothing beyond the marks (the grips and
    their boundary layers) enters. Weights: 1 per atom (LAMMPS, the coarse model's free
    atoms) or a coarse particle's atom count, so that both codes weigh the same material.

    Window (:meth:`window`): the marks are ``EXTENSOMETER_MARGIN`` = 1/4 of the gauge inside
    each grip plane, halfway between the grip planes and the centre of the gauge, as far
    from both as one window allows: ~12.5 Å on the 50 Å gauges of the 150 Å tubes, i.e.
    more than two particle rows past the coarse grips' boundary layer (about one row
    spacing, <= 5 Å at coarsening 4) and, for the vacancy tubes, just outside the coarse
    model's atomistic band with its pad (8 + 3.5 Å around the vacancy). The vacancy itself
    lies between the marks, as the flaw of a specimen lies between an extensometer's knife
    edges: its extra compliance belongs to the measured material and is atomistic in both
    codes.
    """

    def __init__(self, z0, lo: float, hi: float, weights=None):
        z0 = np.asarray(z0, dtype=float)
        if z0.ndim != 1:
            raise ValueError(f"z0 has shape {z0.shape}; valid: 1-D reference axial positions")
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
            raise ValueError(f"extensometer window lo={lo!r}, hi={hi!r}; valid: finite, lo < hi")
        w = np.ones_like(z0) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != z0.shape or np.any(w < 0):
            raise ValueError(f"weights of shape {w.shape} (min {w.min() if w.size else 0}); "
                             f"valid: shape {z0.shape}, all >= 0")
        self.lo, self.hi = float(lo), float(hi)
        self.idx = np.nonzero((z0 >= lo) & (z0 <= hi) & (w > 0))[0]
        zs, ws = z0[self.idx], w[self.idx]
        if len(np.unique(zs)) < 2:
            raise ValueError(f"the window [{lo:.3f}, {hi:.3f}] Å holds {len(zs)} points at "
                             f"{len(np.unique(zs))} distinct z; valid: a window holding "
                             "points at two or more axial positions")
        self.n = len(self.idx)
        self.weight = float(ws.sum())
        self.zbar = float(np.sum(ws * zs) / self.weight)
        self.szz = float(np.sum(ws * (zs - self.zbar) ** 2))
        self.z0 = zs
        self.coef = ws * (zs - self.zbar) / self.szz

    @staticmethod
    def window(zb: float, zt: float, margin: float = EXTENSOMETER_MARGIN) -> tuple[float, float]:
        """The marks ``(zb + margin g, zt - margin g)``, g = zt - zb (grip planes zb < zt)."""
        if not (zt > zb and 0 <= margin < 0.5):
            raise ValueError(f"grip planes zb={zb!r}, zt={zt!r}, margin={margin!r}; valid: "
                             "zt > zb and 0 <= margin < 0.5 (a fraction of the gauge)")
        g = zt - zb
        return zb + margin * g, zt - margin * g

    def strain(self, z) -> float:
        """eps_ext for current axial positions ``z`` (same points and order as ``z0``)."""
        return float(self.coef @ (np.asarray(z, dtype=float)[self.idx] - self.z0))

    def describe(self) -> dict:
        """The window and its points, for the result's record."""
        return {"window_A": [self.lo, self.hi], "points": int(self.n),
                "weight_atoms": self.weight, "margin_of_gauge": EXTENSOMETER_MARGIN,
                "definition": "weighted least-squares slope of u_z against z0 over the "
                              "points with z0 between the marks (z0: positions at the start "
                              "of the pull), each stress sample's block mean"}


def extensometer_metrics(strain, ext_strain, stress, strain_at_peak: float,
                         fit_max_strain: float = 0.02) -> dict:
    """The modulus and strain at peak of a curve on the extensometer strain.

    ``youngs_modulus_ext_TPa``: :func:`curve_metrics`'s fit rule (least-squares line through
    the points with ``0 <= strain <= fit_max_strain``) with the extensometer strain as
    strain; ``strain_at_peak_ext``: the extensometer strain of the strength sample, the
    sample whose (grip) ``strain`` equals ``strain_at_peak`` (strength itself is unchanged:
    same stress samples)."""
    e = np.asarray(strain, dtype=float)
    x = np.asarray(ext_strain, dtype=float)
    s = np.asarray(stress, dtype=float)
    if not (e.shape == x.shape == s.shape and e.ndim == 1):
        raise ValueError(f"strain, ext_strain, stress have shapes {e.shape}, {x.shape}, "
                         f"{s.shape}; valid: 1-D of equal length")
    ipk = np.nonzero(e == strain_at_peak)[0]
    if len(ipk) == 0:
        raise ValueError(f"strain_at_peak={strain_at_peak!r} is not a strain of the curve; "
                         "valid: the value curve_metrics returned for it")
    sel = _fit_window(x, fit_max_strain)
    return {"youngs_modulus_ext_TPa": _slope(x[sel], s[sel]) / 1000.0,
            "strain_at_peak_ext": float(x[ipk[0]])}
