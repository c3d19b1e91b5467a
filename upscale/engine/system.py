"""The particle system: reference positions, volumes, densities and material ids.

Array suffixes used throughout the engine: ``_n`` per particle, ``_b`` per bond (one entry
per *directed* bond i->j of a family), ``_c`` Cartesian component. Positions are always
stored with three components; a 2D body lives in the plane z = 0 and a 1D body on the
x axis.

Units are whatever the scene uses, consistently; continuum scenes use SI (m, kg, s, Pa).
In 2D the particle ``volume`` is its area times the plate ``thickness`` (m^3), so force
densities stay in N/m^3 and masses ``density * volume`` in kg in every dimension.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["ParticleSystem", "cubic_lattice", "square_lattice", "line_lattice", "box_mask"]


def _fmt(v) -> str:
    return np.format_float_positional(float(v), precision=6, trim="-") if np.isfinite(v) else str(v)


#: unit system -> (time unit, energy unit), the labels of the engine's messages
UNITS = {"si": ("s", "J"), "atomic": ("fs", "eV")}


class ParticleSystem:
    """A body of particles in its reference configuration.

    Parameters
    ----------
    x0 : array (N, 3) or (N, dim)
        Reference positions. Missing components are filled with zeros (2D: z = 0).
    volume : float or array (N,)
        Particle volumes (m^3; in 2D area x thickness). Must be positive.
    density : float or array (N,)
        Mass density (kg/m^3). Must be positive. Particle mass is ``density * volume``.
    material : array (N,) of int, optional
        Material id per particle (default all 0).
    dim : {1, 2, 3}
        Spatial dimension of the model.
    thickness : float, optional
        Plate thickness for 2D bodies (m). Required for ``dim == 2`` (default: 1.0 with a
        ``volume`` that already includes it).
    plane : {"stress", "strain"}
        2D idealisation used by the models' calibration.
    spacing : float, optional
        Nominal particle spacing (lattice constant). Used for the horizon check and the
        partial-volume factors; estimated from nearest-neighbour distances if omitted.
    units : {"si", "atomic"}
        The unit system the arrays are in, used only to label times and energies in
        messages: ``"si"`` (m, kg, s, J; default) or ``"atomic"`` (Å, fs, eV, the mass in
        eV fs^2/Å^2: the atomistic and coarse tube scenes).

    Raises
    ------
    ValueError
        One line naming the offending value: NaN/inf positions, non-positive volume or
        density, wrong shapes, bad ``dim`` or ``plane``.
    """

    def __init__(self, x0, volume, density=1.0, material=None, *, dim: int = 3,
                 thickness: float | None = None, plane: str = "stress",
                 spacing: float | None = None, units: str = "si"):
        if units not in UNITS:
            raise ValueError(f"units={units!r}; valid: " + " or ".join(map(repr, UNITS)))
        self.units = units
        self.time_unit, self.energy_unit = UNITS[units]
        if dim not in (1, 2, 3):
            raise ValueError(f"dim must be 1, 2 or 3, got {dim!r}")
        if plane not in ("stress", "strain"):
            raise ValueError(f"plane must be 'stress' or 'strain', got {plane!r}")
        x = np.asarray(x0, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] not in (1, 2, 3) or x.shape[0] == 0:
            raise ValueError(f"positions must have shape (N, 3) with N > 0, got {x.shape}")
        if x.shape[1] < 3:
            x = np.hstack([x, np.zeros((x.shape[0], 3 - x.shape[1]))])
        bad = ~np.isfinite(x).all(axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"position of particle {i} is not finite: {x[i].tolist()} "
                             f"({int(bad.sum())} non-finite positions in all)")
        n = x.shape[0]
        self.x0 = np.ascontiguousarray(x)
        self.volume = self._per_particle(volume, n, "volume")
        self.density = self._per_particle(density, n, "density")
        if material is None:
            self.material = np.zeros(n, dtype=np.int32)
        else:
            m = np.asarray(material)
            if m.shape != (n,):
                raise ValueError(f"material must have shape ({n},), got {m.shape}")
            self.material = m.astype(np.int32)
        self.dim = int(dim)
        if thickness is not None and not (np.isfinite(thickness) and thickness > 0):
            raise ValueError(f"thickness must be positive, got {_fmt(thickness)}")
        self.thickness = float(thickness) if thickness is not None else (1.0 if dim == 2 else None)
        self.plane = plane
        if spacing is not None and not (np.isfinite(spacing) and spacing > 0):
            raise ValueError(f"spacing must be positive, got {_fmt(spacing)}")
        self._spacing = float(spacing) if spacing is not None else None

    @staticmethod
    def _per_particle(value, n, name):
        a = np.asarray(value, dtype=np.float64)
        if a.ndim == 0:
            a = np.full(n, float(a))
        if a.shape != (n,):
            raise ValueError(f"{name} must be a scalar or have shape ({n},), got {a.shape}")
        bad = ~(np.isfinite(a) & (a > 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{name} must be positive: particle {i} has {name} {_fmt(a[i])}")
        return np.ascontiguousarray(a)

    # ------------------------------------------------------------------ properties
    @property
    def n(self) -> int:
        """Number of particles."""
        return self.x0.shape[0]

    def __len__(self) -> int:
        return self.n

    @property
    def mass(self) -> np.ndarray:
        """Particle masses ``density * volume`` (N,)."""
        return self.density * self.volume

    @property
    def spacing(self) -> float:
        """Nominal spacing: the given one, else the median nearest-neighbour distance."""
        if self._spacing is None:
            if self.n < 2:
                self._spacing = float(self.volume[0] ** (1.0 / 3.0))
            else:
                from scipy.spatial import cKDTree

                d, _ = cKDTree(self.x0).query(self.x0, k=2)
                self._spacing = float(np.median(d[:, 1]))
        return self._spacing

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners of the reference bounding box."""
        return self.x0.min(axis=0), self.x0.max(axis=0)

    def select(self, where=None, *, box=None, name: str = "region") -> np.ndarray:
        """Boolean mask (N,) of the particles in a region.

        ``where`` is a predicate ``f(x0) -> bool array`` on the (N, 3) reference positions;
        ``box`` is ``(lo, hi)`` with 3-vectors (``None`` or +-inf components mean
        unbounded), inclusive. Both may be given (intersection).

        Raises ``ValueError`` if the region selects no particle.
        """
        mask = np.ones(self.n, dtype=bool)
        if where is not None:
            m = np.asarray(where(self.x0), dtype=bool)
            if m.shape != (self.n,):
                raise ValueError(f"region {name!r}: predicate returned shape {m.shape}, "
                                 f"expected ({self.n},)")
            mask &= m
        if box is not None:
            mask &= box_mask(self.x0, *box)
        if not mask.any():
            lo, hi = self.bounds()
            desc = f"box {tuple(np.asarray(box[0], dtype=object))}-{tuple(np.asarray(box[1], dtype=object))}" \
                if box is not None else "its predicate"
            raise ValueError(f"region {name!r} selects no particle ({desc}; body spans "
                             f"{lo.round(12).tolist()} to {hi.round(12).tolist()})")
        return mask

    def __repr__(self) -> str:
        return (f"ParticleSystem(n={self.n}, dim={self.dim}, spacing={self.spacing:.4g}, "
                f"thickness={self.thickness}, plane={self.plane!r})")


def box_mask(x: np.ndarray, lo, hi) -> np.ndarray:
    """Mask of points with ``lo <= x <= hi`` component-wise (``None`` = unbounded)."""
    lo = np.array([-np.inf if v is None else v for v in np.broadcast_to(np.asarray(lo, dtype=object), (3,))],
                  dtype=np.float64)
    hi = np.array([np.inf if v is None else v for v in np.broadcast_to(np.asarray(hi, dtype=object), (3,))],
                  dtype=np.float64)
    return np.all((x >= lo) & (x <= hi), axis=1)


def _grid(counts, spacing, origin):
    axes = [origin[k] + spacing * np.arange(c, dtype=np.float64) for k, c in enumerate(counts)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


def cubic_lattice(nx: int, ny: int, nz: int, spacing: float, *, density=1.0,
                  origin=(0.0, 0.0, 0.0), centered: bool = False) -> ParticleSystem:
    """A 3D simple-cubic block of ``nx*ny*nz`` particles, volume ``spacing**3`` each.

    Particles sit at ``origin + spacing * (i, j, k)``; with ``centered`` the block is
    shifted so that its centre of cells is at the origin (cells span
    ``[-n*h/2, n*h/2]``).
    """
    counts = (int(nx), int(ny), int(nz))
    if min(counts) < 1:
        raise ValueError(f"lattice counts must be >= 1, got {counts}")
    h = float(spacing)
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"spacing must be positive, got {_fmt(h)}")
    o = np.asarray(origin, dtype=np.float64)
    if centered:
        o = o - 0.5 * h * (np.asarray(counts) - 1)
    x = _grid(counts, h, o)
    return ParticleSystem(x, h ** 3, density, dim=3, spacing=h)


def square_lattice(nx: int, ny: int, spacing: float, *, thickness: float | None = None,
                   density=1.0, plane: str = "stress", origin=(0.0, 0.0),
                   centered: bool = False) -> ParticleSystem:
    """A 2D square plate of ``nx*ny`` particles in z = 0.

    Each particle has area ``spacing**2`` and volume ``spacing**2 * thickness``
    (``thickness`` defaults to ``spacing``).
    """
    counts = (int(nx), int(ny))
    if min(counts) < 1:
        raise ValueError(f"lattice counts must be >= 1, got {counts}")
    h = float(spacing)
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"spacing must be positive, got {_fmt(h)}")
    t = h if thickness is None else float(thickness)
    o = np.asarray(origin, dtype=np.float64)
    if centered:
        o = o - 0.5 * h * (np.asarray(counts) - 1)
    x = _grid(counts, h, o)
    return ParticleSystem(x, h * h * t, density, dim=2, thickness=t, plane=plane, spacing=h)


def line_lattice(nx: int, spacing: float, *, area: float = 1.0, density=1.0,
                 origin: float = 0.0) -> ParticleSystem:
    """A 1D bar of ``nx`` particles on the x axis, volume ``spacing * area`` each."""
    h = float(spacing)
    if not (np.isfinite(h) and h > 0):
        raise ValueError(f"spacing must be positive, got {_fmt(h)}")
    if int(nx) < 1:
        raise ValueError(f"lattice count must be >= 1, got {nx}")
    x = origin + h * np.arange(int(nx), dtype=np.float64)
    return ParticleSystem(x[:, None], h * area, density, dim=1, spacing=h)


Predicate = Callable[[np.ndarray], np.ndarray]
