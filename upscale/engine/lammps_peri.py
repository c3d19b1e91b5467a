"""LAMMPS PERI package as a reference: the same body run by ``pair_style peri/pmb`` and
``peri/lps`` through LAMMPS's Python module.

Conventions of LAMMPS PERI (read from pair_peri_pmb.cpp, pair_peri_lps.cpp, pair_peri.cpp,
fix_peri_neigh.cpp, compute_damage_atom.cpp) and how the engine matches them:

* ``atom_style peri``: the per-atom mass is the *density*, ``vfrac`` the volume, and ``f``
  the force density (N/m^3); ``fix nve`` integrates ``a = f / density``.
* bonds (fix PERI_NEIGH) are created once, at the set-up of the first ``run``, from the
  positions *then*, for pairs with ``r^2 <= cut^2``; their lengths ``r0`` are fixed.
  Engine: ``build_family(..., partial_volume="lammps")`` on the same positions.
* edge partial volume: ``V_j`` times ``(delta + lc/2 - r0)/lc`` when
  ``|r0 - delta| <= lc/2`` (lc = lattice constant). Engine: ``partial_volume="lammps"``.
* peri/pmb: ``f_i += -(c V_j beta s / r) (x_i - x_j)``, ``s = (r - r0)/r0`` with
  ``|r - r0| < 2.2204e-16`` taken as 0. Engine: the PMB model (``upscale.models.bond_based``)
  with ``c=``, evaluated as ``c V_j beta (1/r0 - 1/r)`` (one division less; no NEAR_ZERO
  test, which only matters for |dr| < 2.2e-16 m, i.e. never at these scales): the two
  agree to round-off (~1e-15 relative).
* peri/lps: influence ``omega = 1/|xi|`` (from ``x0``); weighted volume ``m`` computed once
  from all bonds (never updated when bonds break); ``theta_i = 3/m_i sum omega r0 dr V_j
  beta`` over intact bonds; force ``(3K - 5G)(theta_i/m_i + theta_j/m_j) omega r0 +
  15 G (1/m_i + 1/m_j) omega dr``, times ``V_j beta``. Engine: :class:`LPS` with ``K, G``.
* failure: inside the force loop, *after* a bond's force is added, the bond breaks if
  ``s > min(s0_i, s0_j)`` with ``s0`` from the previous step, ``s0_i = s00 - alpha
  min_j s_ij``; with ``alpha = 0`` that is ``s > s00`` - except that ``s0`` starts at
  DBL_MAX, so nothing breaks in the very first force evaluation of the first run.
  Engine: ``step_force`` breaks after the force, from the same positions; the first
  evaluation (at the reference state, where no stretch exceeds s00) breaks nothing either.
  ``alpha != 0`` (s0 depending on the previous step's smallest stretch) is not implemented.
* a LAMMPS defect worked around here: the bonds are built in ``FixPeriNeigh::setup``, which
  ``Verlet::setup`` calls *after* the set-up force evaluation, so in that first evaluation
  every atom has ``npartner = 0``, ``s0_new`` is never written, and ``s0 = s0_new`` copies
  uninitialised heap memory (``memory->create``, i.e. malloc) into ``atom->s0``. The next
  force evaluation then breaks every bond whose ``s0`` happens to be below its stretch
  (e.g. negative garbage at the reference state): the outcome depends on what the
  process's heap held before, i.e. on which code ran earlier (the test order).
  :meth:`LammpsPeri.create_bonds` therefore sets ``s0`` back to DBL_MAX, the value
  ``atom_style peri`` gives a new atom, right after the bond-building ``run 0``.
* short-range contact: pairs closer than ``min(0.9 r0, 1.35 lc)`` repel with
  ``15 c V_j (r - d)/delta`` (pmb) or ``15 (18 K / (pi delta^4)) V_j (r - d)/delta`` (lps)
  over LAMMPS's ordinary neighbour list. Engine: :class:`LammpsContact` over a family.
* damage (compute damage/atom): ``1 - sum_{intact} V_j / sum_{all} V_j``.

A pre-crack: LAMMPS has no command to cut bonds, so the block is given three atom types,
1 = bulk, 2 = below the crack plane and 3 = above it (within the crack's extent and one
horizon of the plane); ``pair_coeff 2 3`` gets a cut-off below the spacing, so no 2-3 bond
is ever created. The engine removes the same bonds with ``Family.remove_bonds``. For
peri/pmb the 2-3 contact stiffness is kept equal to the bulk one by scaling its ``c``
with its cut-off; peri/lps computes its contact constant from ``cut^4`` and cannot be
matched for 2-3 pairs (the crack must not close: the comparison counts contacts).
"""
from __future__ import annotations

import numpy as np

__all__ = ["LammpsPeri", "LAMMPS_EXAMPLE"]


class LammpsPeri:
    """A LAMMPS PERI run on a simple-cubic block.

    Parameters
    ----------
    style : {"pmb", "lps"}
    counts : (nx, ny, nz)
        Lattice cells; LAMMPS creates the sc lattice points in ``region block 0 nx 0 ny 0
        nz`` (``boundary s s s``).
    lc : float
        Lattice constant (m).
    horizon : float
    density : float
    params : dict
        pmb: ``c``; lps: ``K``, ``G``. Both: ``s00`` (critical stretch), ``alpha`` (0).
    crack : (x_end, y_plane) or None
        Pre-crack in the plane y = y_plane for x < x_end (through z), made with atom types.
    """

    def __init__(self, style: str, counts, lc: float, horizon: float, density: float,
                 params: dict, crack=None, dt: float = 1e-7, neighbor_skin: float | None = None,
                 log: str | None = None):
        from potentials.lammps_runtime import new_lammps

        if style not in ("pmb", "lps"):
            raise ValueError(f"unknown LAMMPS peri style {style!r}; valid: 'pmb', 'lps'")
        self.style = style
        self.lc, self.horizon, self.density = float(lc), float(horizon), float(density)
        self.params = dict(params)
        self.crack = crack
        self.lmp = lmp = new_lammps(log=log)
        nx, ny, nz = (int(c) for c in counts)
        skin = neighbor_skin if neighbor_skin is not None else 0.3 * lc
        ntypes = 3 if crack is not None else 1
        cmds = [
            "units si", "dimension 3", "boundary s s s", "atom_style peri",
            "atom_modify map array", f"lattice sc {lc!r}",
            f"region box block 0 {nx} 0 {ny} 0 {nz}", f"create_box {ntypes} box",
            "create_atoms 1 region box",
            f"neighbor {skin!r} bin", "neigh_modify every 1 delay 0 check yes",
        ]
        for c in cmds:
            lmp.command(c)
        x = self.positions()
        if crack is not None:
            x_end, y_plane = crack
            near = (x[:, 0] < x_end) & (np.abs(x[:, 1] - y_plane) <= horizon)
            below = np.flatnonzero(near & (x[:, 1] < y_plane)) + 1
            above = np.flatnonzero(near & (x[:, 1] > y_plane)) + 1
            if np.any(near & (x[:, 1] == y_plane)):
                raise ValueError("the crack plane must not pass through lattice points")
            for ids, t in ((below, 2), (above, 3)):
                for chunk in np.array_split(ids, max(1, len(ids) // 500)):
                    if len(chunk):
                        lmp.command(f"group tmp id {' '.join(map(str, chunk))}")
                        lmp.command(f"set group tmp type {t}")
                        lmp.command("group tmp delete")
        s00 = float(self.params["s00"])
        alpha = float(self.params.get("alpha", 0.0))
        cut23 = 0.5 * lc
        if style == "pmb":
            c = float(self.params["c"])
            lmp.command("pair_style peri/pmb")
            lmp.command(f"pair_coeff * * {c!r} {horizon!r} {s00!r} {alpha!r}")
            if crack is not None:  # contact constant 15 c/cut kept equal to the bulk one
                lmp.command(f"pair_coeff 2 3 {c * cut23 / horizon!r} {cut23!r} {s00!r} {alpha!r}")
        else:
            K, G = float(self.params["K"]), float(self.params["G"])
            lmp.command("pair_style peri/lps")
            lmp.command(f"pair_coeff * * {K!r} {G!r} {horizon!r} {s00!r} {alpha!r}")
            if crack is not None:
                lmp.command(f"pair_coeff 2 3 {K!r} {G!r} {cut23!r} {s00!r} {alpha!r}")
        lmp.command(f"set group all density {density!r}")
        lmp.command(f"set group all volume {lc ** 3!r}")
        lmp.command("velocity all set 0.0 0.0 0.0")
        lmp.command("compute dmg all damage/atom")
        lmp.command("fix 1 all nve")
        lmp.command(f"timestep {dt!r}")
        self.n = lmp.get_natoms()
        self._bonded = False

    # ------------------------------------------------------------------ data access
    def positions(self) -> np.ndarray:
        """Positions ordered by atom id (N, 3)."""
        n = self.lmp.get_natoms()
        return np.array(self.lmp.gather_atoms("x", 1, 3)[:], dtype=np.float64).reshape(n, 3)

    def velocities(self) -> np.ndarray:
        return np.array(self.lmp.gather_atoms("v", 1, 3)[:], dtype=np.float64).reshape(self.n, 3)

    def forces(self) -> np.ndarray:
        """Force densities ``f`` (N/m^3) ordered by atom id (N, 3)."""
        return np.array(self.lmp.gather_atoms("f", 1, 3)[:], dtype=np.float64).reshape(self.n, 3)

    def damage(self) -> np.ndarray:
        """compute damage/atom, ordered by atom id (N,)."""
        self.lmp.command("run 0 post no")
        return np.array(self.lmp.gather("c_dmg", 1, 1)[:], dtype=np.float64) \
            if hasattr(self.lmp, "gather") else self._damage_fallback()

    def _damage_fallback(self):
        ids = np.array(self.lmp.numpy.extract_atom("id"), dtype=np.int64)[: self.n]
        d = np.array(self.lmp.numpy.extract_compute("dmg", 1, 1))[: self.n]
        out = np.empty(self.n)
        out[ids - 1] = d
        return out

    def types(self) -> np.ndarray:
        return np.array(self.lmp.gather_atoms("type", 0, 1)[:], dtype=np.int64)

    def set_positions(self, x: np.ndarray) -> None:
        import ctypes

        flat = np.ascontiguousarray(x, dtype=np.float64).ravel()
        self.lmp.scatter_atoms("x", 1, 3, flat.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))

    def set_velocities(self, v: np.ndarray) -> None:
        import ctypes

        flat = np.ascontiguousarray(v, dtype=np.float64).ravel()
        self.lmp.scatter_atoms("v", 1, 3, flat.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))

    # ------------------------------------------------------------------ running
    def create_bonds(self) -> None:
        """``run 0`` on the reference positions: fix PERI_NEIGH builds the bonds.

        Afterwards ``s0`` is reset to DBL_MAX on every atom: that ``run 0`` leaves it
        uninitialised (see the module docstring), which would break arbitrary bonds in the
        next force evaluation, depending on the process's heap contents.
        """
        if not self._bonded:
            self.lmp.command("run 0 post no")
            self.set_s0(np.full(self.n, np.finfo(np.float64).max))
            self._bonded = True

    def s0(self) -> np.ndarray:
        """Per-atom critical stretch ``s0`` for the next force evaluation, by atom id (N,)."""
        return np.array(self.lmp.gather_atoms("s0", 1, 1)[:], dtype=np.float64)

    def set_s0(self, s0: np.ndarray) -> None:
        """Set the per-atom ``s0`` (N,), ordered by atom id."""
        import ctypes

        flat = np.ascontiguousarray(s0, dtype=np.float64).ravel()
        if flat.shape != (self.n,):
            raise ValueError(f"s0 has {flat.size} values; expected one per atom ({self.n})")
        self.lmp.scatter_atoms("s0", 1, 1, flat.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))

    def force_on(self, x: np.ndarray) -> np.ndarray:
        """Force densities on positions ``x`` (bonds from the reference; ``run 0``)."""
        self.create_bonds()
        self.set_positions(x)
        self.lmp.command("run 0 post no")
        return self.forces()

    def run(self, steps: int) -> None:
        self.create_bonds()
        self.lmp.command(f"run {int(steps)} post no")

    def set_volumes(self, vol: np.ndarray) -> None:
        """Mutates LAMMPS's per-atom ``vfrac``: the particle volumes (N,) (m^3)."""
        import ctypes

        flat = np.ascontiguousarray(vol, dtype=np.float64)
        self.lmp.scatter_atoms("vfrac", 1, 1, flat.ctypes.data_as(ctypes.POINTER(ctypes.c_double)))

    def close(self) -> None:
        self.lmp.close()


#: material of the comparisons: the parameters of LAMMPS's examples/peri (glass-like),
#: critical stretch s00 = 5e-4 with alpha = 0
LAMMPS_EXAMPLE = {"lc": 5e-4, "horizon": 0.0015001, "density": 2200.0, "c": 1.6863e22,
                  "K": 14.9e9, "G": 8.94e9, "s00": 5e-4, "dt": 1e-7}
