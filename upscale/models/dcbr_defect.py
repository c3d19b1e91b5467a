"""DCBR tube with an atomistic region around a defect (the arrangement refined to the lattice).

Seed 004 sec. 5.3 suggests a particle arrangement that is finer near a defect, down to the
lattice itself, and coarse away from it. :class:`DCBRDefectTube` does exactly that for the
4-atom vacancy: inside a disc of radius ``r_atomistic`` (on the unrolled wall) around the
vacancy every atom is a degree of freedom with its own Tersoff site energy; outside, the
coarse particles of :class:`~upscale.models.dcbr.DCBRTube` carry the lattice through G.
It is an energy-based concurrent coupling (in the spirit of the quasicontinuum method):

    E = sum_{a free} (E_a - e0) + sum_c w_c (e(C_c, delta_c) - e0) + W_stab

* **Free atoms**: E_a is the LAMMPS-form Tersoff site energy of atom a (the terms of its own
  bonds, :func:`potentials.tersoff_kernels.tersoff_range` on the free atoms only), so the free
  region is the atomistic model itself. With ``whole_cells`` (default) the region is made of
  whole particle cells: every particle whose cell (its Voronoi share of the atoms) has an
  atom within ``r_atomistic`` of the vacancy, or a removed atom, gives all its atoms to the
  region and every other particle keeps all of its, so each particle is either atomistic or
  coarse and the region holds at least every atom within ``r_atomistic``. Without it the free atoms are those with ``r < r_atomistic`` and
  particles cut by the boundary keep a part of their atoms, with a G whose stencil can
  reach across the defect: such particles stiffen the vacancy's neighbourhood and delay
  failure.
* **Pad atoms** (non-free atoms within ``pad`` Å of a free atom, default 3.5 Å > the 2.1 Å
  cutoff plus margin; without ``whole_cells``, within ``pad`` of the region's boundary): the neighbours free atoms need. They are not unknowns: each follows
  the coarse map of its nearest carrying particle c, the same uniform cylindrical map (with
  the sublattice shift for B atoms) that gives c its lattice energy,

      x_a = y_c + Q3_c (h_a + r0_a),  h_a = (rho sin phi, lam_z dz + sigma d_z, rho cos phi - lam_t R0),
      phi = (lam_t ds + gam dz + sigma d_s) / (lam_t R0),  rho = lam_t R0 + sigma d_rho,

  (ds, dz) its reference arc and axial offset from c, sigma = 1 on sublattice B, Q3_c the
  deformed local frame (:meth:`DCBRTube._stab_local`), r0_a the reference residual (zero on a
  symmetric family). Forces on pad atoms go to c's position, shift and (through G) to c's
  neighbours by the chain rule through the map, exact (the carrier's map and frame computed
  once per call and shared with its hourglass links, :mod:`upscale.models.dcbr_coupling_kernels`;
  ``method="numpy"``: the reference with complex-step derivatives).
  The free atoms' pair list is a Verlet list (skin ``nl_skin``, default :data:`NL_SKIN`)
  rebuilt only when an atom (free or pad) has moved more than half the skin.
* **Particle weights**: w_c = N_c - g_c (clipped to [0, N_c]; 0 when all its atoms are
  explicit), g_c the number of free or removed atoms among those nearest particle c (Voronoi
  on the unrolled wall, pristine tube), so the coarse energy counts only the atoms not
  represented explicitly (the total differs from the exact count by the rounding of the
  particles inside the region; reported as ``atom_count_error``).
* **Slave particles**: a particle with f_c >= 1/2 lies mostly inside the atomistic region.
  Left free it would be a cheap handle by which its neighbours could relax their G, a soft
  spot; instead its displacement interpolates those of the 10 free atoms of sublattice A
  nearest it (weighted quadratic fit in the unrolled coordinates, its arc terms those of the
  cylinder so that rigid motions are reproduced exactly), so G next to the region follows
  the atoms.
* The hourglass penalty of each link is scaled by its owner's w_c / N_c.

In a uniform strain the pad atoms sit exactly on the uniform map, so the free atoms feel
the perfect lattice; what is not exact is the balance at the interface (the classic
energy-based coupling's ghost forces, up to 1-3 eV/Å, :meth:`ghost_forces`). They are removed
by a dead load taken from a pristine twin at the load step's uniform state
(:meth:`prepare_step`; per side of the region in dynamics, :meth:`prepare_sides`), applied in
cylindrical components about the rows' centroid so that a rigid turn or shift of the tube
costs nothing (:meth:`energy_and_gradient`); the periodic tube's turn is pinned by two
particles (:meth:`rotation_pins`).

Failure: free atoms break their own bonds through the potential (step cutoff at R + D =
2.1 Å); coarse particles keep the two rules of :mod:`upscale.models.dcbr` (the lattice
stability rule is applied to particles that carry at least half their atoms). The damage
of an atom is mu = 1 - (bonds left)/(bonds at the start) (< 2.0 Å at start, broken beyond
2.1 Å, the references' rule); of a particle, eq. 5.16 on its links.

The step cutoff and minimisation (``step_crossing``, :meth:`minimise`): with the step the
energy jumps where a pair crosses 2.1 Å, so a gradient minimiser stops with a pair held at
the step and a force left on it. The LAMMPS references' quasi-static protocol then runs
damped dynamics (``quickmin``), which feels only forces and goes through, and CG again.
``"damped"`` (default) does the same here (:meth:`quickmin`, LAMMPS's settings: 1 fs,
0.02 Å per step at most, 5000 steps, up to 3 cycles while a force component exceeds
1e-4 eV/Å). ``"energy"`` crosses only where that lowers the re-minimised energy; with it
the vacancy tube fails far too late, because the pair across the vacancy that LAMMPS's
damped step pulls into a bond is uphill in energy, while the tube then fails downhill one
step later (the sensitivity of the strength to LAMMPS's damped-dynamics settings is in
data/reference/qs_protocol_sensitivity.json). ``"force"`` and ``"always"`` move single pairs
across. The iterations are the engine's (:mod:`upscale.engine.minimisers`: ``lbfgs_b``,
``quick_min_blocks``, ``restarted``, ``first_lower``, ``zero_cell_force``); the tube gives
the energy, its gradient and the trial starts.
"""
from __future__ import annotations

import math

import numpy as np

from potentials.tersoff import INDEX as TI
from upscale.constants import ACC_EV_A_AMU_IN_A_FS2, CARBON_MASS_AMU
from upscale.models import dcbr_coupling_kernels as CK
from upscale.engine.array_minimisers import (bfgs, first_lower, newton, quick_min_blocks,
                                             restarted, zero_cell_force)
from upscale.models.dcbr import DCBRTube, TubeMinimum, uniform_map_frame

CARBON_MASS = CARBON_MASS_AMU  # amu
ACC_UNIT = ACC_EV_A_AMU_IN_A_FS2  # eV/(Å amu) in Å/fs^2
#: skin (Å) of the atomistic region's Verlet list. The list reaches cutoff + skin =
#: 2.4 Å with the 2.1 Å cutoff of BNC.tersoff, short of the wall's second-neighbour shell
#: (sqrt(3) x 1.45 = 2.5 Å), so it holds the first neighbours only; a 1 Å skin (3.1 Å)
#: also held the second and third shells (4x the pairs), which the kernel's short-list
#: pass must read and skip at every call: 0.3 Å costs about 15 % less per call on the
#: seed-scale bands before failure, its extra rebuilds included; after failure the list is
#: rebuilt at most calls whatever the skin.
NL_SKIN = 0.3

__all__ = ["DCBRDefectTube"]


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


class DCBRDefectTube(DCBRTube):
    """Periodic (n, m) DCBR tube with a vacancy and an atomistic region around it.

    Parameters (besides those of :class:`~upscale.models.dcbr.DCBRTube`)
    ----------
    vacancy : int
        Atoms removed at the seed's point (``upscale.build.vacancy``, the references' rule);
        0 keeps the tube pristine (the atomistic region is then a plain refinement, used to
        measure the coupling's own error).
    r_atomistic : float
        Radius (Å, on the unrolled wall) of the atomistic region around the vacancy: the
        half-width of a ``"band"``, the radius of a ``"disc"``, the axial semi-axis of an
        ``"ellipse"``.
    region : {"band", "disc", "ellipse"}
        The region's shape on the unrolled wall about the vacancy: all around the tube
        (default), a disc, or an ellipse with semi-axes ``r_atomistic`` (axial) and
        ``r_arc`` (around the circumference, Å); rounded out to whole cells with
        ``whole_cells``. A crack across the axis needs its path atomistic beyond the
        vacancy's neighbourhood (at the coarse edge it is arrested), hence the ellipse.
    r_arc : float, optional
        The circumferential semi-axis of ``region="ellipse"`` (Å).
    pad : float
        Width (Å) of the band of slaved pad atoms outside it (> cutoff 2.1 Å).
    whole_cells : bool
        The region is made of whole particle cells (module docstring; default True).
    band_z : sequence of float, optional
        Centres (reference z, Å) of further atomistic bands of half-width ``r_atomistic``,
        all around the tube, placed where the protocol, not a defect, needs the lattice
        itself: the dynamic scene puts one across each grip plane
        (:func:`upscale.experiments.scenes.dcbr_dynamic.grip_band_tube`), where LAMMPS's held atoms
        meet the free ones. With a vacancy the region is the union of its own (band or disc)
        and these bands; with ``vacancy=0`` (``region="band"`` only) it is the bands alone and
        ``vacancy_theta_z`` is (0, tube centre), the plane that splits the ghost-force
        correction's two sides.
    """

    def __init__(self, n: int, m: int, length: float, coarsening: float = 2.0,
                 vacancy: int = 4, r_atomistic: float = 8.0, pad: float = 3.5,
                 region: str = "band", step_crossing: str = "damped", whole_cells: bool = True,
                 band_z=None, r_arc: float | None = None,
                 _twin_of: "DCBRDefectTube | None" = None, **kw):
        super().__init__(n, m, length, coarsening, **kw)
        if step_crossing not in ("energy", "always", "force", "damped"):
            raise ValueError(f"step_crossing={step_crossing!r}; valid: 'damped' (while a "
                             "force stays, damped dynamics then L-BFGS again, LAMMPS's "
                             "quick-min fallback), 'force' (a pair held at "
                             "the step cutoff crosses it when the force on it points across, "
                             "as in MD and damped dynamics), 'energy' (a pair held at "
                             "the step cutoff crosses it when that lowers the energy) or 'always' "
                             "(it crosses, as damped dynamics would)")
        self.step_crossing = step_crossing
        if region not in ("band", "disc", "ellipse"):
            raise ValueError(f"region={region!r}; valid: 'band' (|z - z_vacancy| < r_atomistic, "
                             "all around the tube), 'disc' (distance on the wall < r_atomistic) "
                             "or 'ellipse' (semi-axes r_atomistic along the axis, r_arc around)")
        if (region == "ellipse") != (r_arc is not None) or \
                (r_arc is not None and not (np.isfinite(r_arc) and r_arc > 0)):
            raise ValueError(f"r_arc={r_arc!r} with region={region!r}; valid: a semi-axis > 0 Å "
                             "along the circumference with region='ellipse' (only then)")
        self.region = region
        self.r_arc = None if r_arc is None else float(r_arc)
        self._kw = dict(kw, vacancy=vacancy, r_atomistic=r_atomistic, pad=pad, region=region,
                        whole_cells=whole_cells, r_arc=self.r_arc)
        from potentials.neighbours import neighbour_list  # noqa: PLC0415
        from potentials.tersoff import Tersoff  # noqa: PLC0415
        from upscale.build import swcnt  # noqa: PLC0415
        from upscale.build import vacancy as make_vacancy  # noqa: PLC0415

        if not (isinstance(vacancy, (int, np.integer)) and 0 <= vacancy <= 20):
            raise ValueError(f"vacancy={vacancy!r}; valid: an integer number of atoms 0..20")
        if band_z is not None and (len(band_z) == 0 or (not vacancy and region != "band")):
            raise ValueError(f"band_z={band_z!r} with vacancy={vacancy!r}, region={region!r}; "
                             "valid: one or more band centres (with vacancy=0: region='band')")
        if not (r_atomistic > 0 and np.isfinite(r_atomistic)):
            raise ValueError(f"r_atomistic={r_atomistic!r}; valid: a radius > 0 Å")
        cut = float(self.p_standard[TI['R']] + self.p_standard[TI['D']])
        if not pad > cut:
            raise ValueError(f"pad={pad!r} Å; valid: wider than the potential cutoff {cut:g} Å")
        atoms = swcnt(n, m, length, bond=self.lattice.bond)
        if abs(atoms.info["length"] - self.L) > 1e-6:
            raise RuntimeError("swcnt and DCBRTube disagree on the tube length")
        cx, cy = atoms.info["axis_xy"]
        X = atoms.get_positions() - [cx, cy, 0.0]
        nat = len(X)
        R0 = self.lattice.R0
        th = np.arctan2(X[:, 1], X[:, 0])
        # sublattice of every atom: 2-colour the bond graph, then match the lattice's A star
        first, jb, _ = neighbour_list(atoms.positions, atoms.cell.array, atoms.pbc, 1.1 * 1.42)
        col = -np.ones(nat, int)
        col[0] = 0
        front = [0]
        while front:
            nxt = []
            for a in front:
                for b in jb[first[a]:first[a + 1]]:
                    if col[b] < 0:
                        col[b] = 1 - col[a]
                        nxt.append(b)
            front = nxt
        lat = self.lattice
        starA = np.column_stack([lat.s[lat.bondsA], lat.z[lat.bondsA]])
        a0 = 0
        nb0 = jb[first[a0]:first[a0 + 1]]
        d = np.column_stack([R0 * _wrap(th[nb0] - th[a0]),
                             (X[nb0, 2] - X[a0, 2] + self.L / 2) % self.L - self.L / 2])
        plus = max(np.min(np.linalg.norm(starA - v, axis=1)) for v in d)
        minus = max(np.min(np.linalg.norm(starA + v, axis=1)) for v in d)
        if min(plus, minus) > 0.05:
            raise RuntimeError("cannot match the atoms' sublattices to the lattice patch")
        sub = col if plus < minus else 1 - col
        # the vacancy (the references' rule) and its centre
        removed = np.zeros(nat, bool)
        vac_atoms = np.zeros(nat, bool)  # atoms the slave fit must not use (twin: the vacancy)
        if _twin_of is not None:  # the pristine twin of a defect tube: same centre and region
            thc, zc = _twin_of.vacancy_theta_z
            vac_atoms = _twin_of.removed.copy()
        elif vacancy:
            vac = make_vacancy(atoms, n=int(vacancy))
            removed[vac.info["vacancy"]["removed"]] = True
            zc = np.mean(X[removed, 2])
            thc = np.angle(np.mean(np.exp(1j * th[removed])))
            vac_atoms = removed
        else:
            zc = atoms.positions[:, 2].min() + 0.5 * self.L
            thc = 0.0
        self.vacancy_theta_z = (float(thc), float(zc))
        if _twin_of is not None:
            band_z = _twin_of.band_z
        self.band_z = None if band_z is None else tuple(float(b) for b in band_z)
        s_rel = R0 * _wrap(th - thc)
        z_rel = X[:, 2] - zc
        if region == "disc":  # distance on the unrolled wall
            r = np.hypot(s_rel, z_rel)
        elif region == "ellipse":  # elliptic distance, r_atomistic on the boundary
            r = np.hypot(s_rel * (r_atomistic / self.r_arc), z_rel)
        else:
            r = np.abs(z_rel)
        if self.band_z is not None:  # distance to the nearest band's centre
            if min(self.band_z) < X[:, 2].min() or max(self.band_z) > X[:, 2].max():
                raise ValueError(f"band_z={band_z!r}; valid: centres inside the tube "
                                 f"({X[:, 2].min():.1f} to {X[:, 2].max():.1f} Å)")
            cz = np.asarray(self.band_z)
            zb_rel = X[:, 2] - cz[np.argmin(np.abs(X[:, 2][:, None] - cz[None, :]), axis=1)]
            has_vac = bool(vacancy) or (_twin_of is not None and _twin_of.removed.any())
            if has_vac:  # the union of the vacancy's region and the bands
                z_rel = np.where(np.abs(zb_rel) < r, zb_rel, z_rel)
                r = np.minimum(r, np.abs(zb_rel))
            else:
                z_rel = zb_rel
                r = np.abs(z_rel)
        # Voronoi share of every atom of the pristine tube among the particles
        ds_p = R0 * _wrap(th[:, None] - self.theta[None, :])
        dz_p = X[:, 2][:, None] - self.x0[None, :, 2]
        dz_p -= self.L * np.round(dz_p / self.L)
        owner = np.argmin(ds_p ** 2 + dz_p ** 2, axis=1)
        if whole_cells:  # a particle with any atom inside r_atomistic (or a removed atom)
            # gives up all its atoms, the others keep all of theirs: the region is the disc
            # or band rounded out to whole cells
            inside = np.zeros(self.N, bool)
            inside[owner[(r < r_atomistic) | removed | vac_atoms]] = True
            free = inside[owner] & ~removed
        else:
            free = (r < r_atomistic) & ~removed
        reach = float(np.abs(z_rel[free | removed]).max(initial=0.0)) + pad
        zr = X[free | removed, 2]
        if (self.band_z is None and (zc - reach < 0 or zc + reach > self.L)) or \
                (self.band_z is not None and (zr.min() - pad < 0 or zr.max() + pad > self.L)):
            raise ValueError(f"r_atomistic={r_atomistic} Å: the atomistic region and its pad "
                             f"reach {reach:.1f} Å from the vacancy, beyond the tube's ends "
                             f"(length {self.L:.1f} Å); valid: a smaller r_atomistic or a "
                             "longer tube")
        tot = np.bincount(owner, minlength=self.N)
        gone = np.bincount(owner, weights=(free | removed).astype(float), minlength=self.N)
        f = gone / np.maximum(tot, 1)
        nominal = self.n_atoms / self.N
        self.nominal = nominal
        # the atoms a particle gives up are the free/removed ones nearest it; a particle all
        # of whose atoms are explicit carries none
        self.natoms_n = np.where(gone >= tot, 0.0, np.clip(nominal - gone, 0.0, nominal))
        # make the count exact: all carrying particles scale by one factor (the rounding of
        # the particles whose atoms are all explicit is a few atoms; a common factor keeps the
        # weights uniform away from the region, so no spurious force appears there)
        target = float((~removed).sum() - free.sum())
        self.natoms_n *= target / self.natoms_n.sum()
        nominal = self.nominal = float(self.natoms_n.max())
        self.atom_count_error = float(self.natoms_n.sum() - target)
        slave = f >= 0.5
        self.is_slave = slave
        self.dof_idx = np.nonzero(~slave)[0]
        self.slave_idx = np.nonzero(slave)[0]
        self.free_idx = np.nonzero(free)[0]
        self.nf = len(self.free_idx)
        Xf = X[self.free_idx]
        # slave particles: weighted linear fit of the nearest free A atoms (unrolled coords)
        fA = np.nonzero((sub[self.free_idx] == 0) & ~vac_atoms[self.free_idx])[0]
        rows, cols, vals, ref_off = [], [], [], []
        for k, c in enumerate(self.slave_idx):
            dsf = R0 * _wrap(th[self.free_idx[fA]] - self.theta[c])
            dzf = Xf[fA, 2] - self.x0[c, 2]
            dist = np.hypot(dsf, dzf)
            order = np.argsort(dist)
            if len(order) < 10:
                raise ValueError(f"slave particle {c} has {len(order)} free atoms to follow "
                                 "(10 needed); valid: a larger r_atomistic")
            # weighted quadratic fit (weights 1 / (1 + d^2)) of the nearest A atoms, the row
            # giving the value at (0, 0); if the 10 nearest cannot fix all six terms (two
            # straight rows of A atoms next to a slave of a zigzag tube), more atoms are
            # taken, and failing that the fit is linear. The arc terms are those of the
            # cylinder (R0 sin p, 2 R0^2 (1 - cos p), p = s / R0, ~ s and s^2), so the fit
            # reproduces the atoms' reference positions and hence any rigid motion exactly
            # (with s and s^2 a half turn of the tube moved the coupled energy by ~0.02-0.06 eV)
            for nn, ncol in ((10, 6), (14, 6), (20, 6), (10, 3)):
                near = order[:nn]
                a_, b_ = dsf[near], dzf[near]
                sa = R0 * np.sin(a_ / R0)
                A = np.column_stack([np.ones(len(near)), sa, b_,
                                     2.0 * R0 * R0 * (1.0 - np.cos(a_ / R0)), sa * b_,
                                     b_ * b_])[:, :ncol]
                Aw = A * (1.0 / (1.0 + dist[near] ** 2))[:, None]
                M = A.T @ Aw
                if np.linalg.cond(M) < 1e10:
                    break
            else:
                raise ValueError(f"slave particle {c}: its nearest free atoms are degenerate "
                                 "for a linear fit; valid: a larger r_atomistic")
            phi = np.linalg.solve(M, Aw.T)[0]
            rows += [k] * len(near)
            cols += list(fA[near])
            vals += list(phi)
            self_ref = Xf[fA[near]]
            ref_off.append(self.x0[c] - phi @ self_ref)
        from scipy.sparse import csr_matrix  # noqa: PLC0415
        self.Phi = csr_matrix((vals, (rows, cols)), shape=(len(self.slave_idx), self.nf))
        self._PhiT = self.Phi.T.tocsr()
        # y_e = X_e + sum phi (x_a - X_a): the fit interpolates displacements
        self.slave_off = np.array(ref_off).reshape(-1, 3)
        # pad atoms and the carrying particle each follows (nearest non-slave particle)
        if whole_cells:  # the non-free atoms within pad of a free atom
            from scipy.spatial import cKDTree  # noqa: PLC0415

            near = cKDTree(X[free]).query(X, distance_upper_bound=pad)[0] < pad
            pad_m = (~free) & (~removed) & near
        else:
            pad_m = (~free) & (~removed) & (r < r_atomistic + pad)
        self.pad_idx = np.nonzero(pad_m)[0]
        carry = self.dof_idx
        dsc = R0 * _wrap(th[self.pad_idx][:, None] - self.theta[carry][None, :])
        dzc = X[self.pad_idx, 2][:, None] - self.x0[carry][None, :, 2]
        dzc -= self.L * np.round(dzc / self.L)
        k = np.argmin(dsc ** 2 + dzc ** 2, axis=1)
        npad = len(self.pad_idx)
        self._pad = {"c": carry[k], "ds": dsc[np.arange(npad), k], "dz": dzc[np.arange(npad), k],
                     "sig": sub[self.pad_idx].astype(float), "r0": np.zeros((npad, 3))}
        F0 = self.gain.deformation(self.x0, self.gain.cell)
        self._FS_last = np.einsum("nia,nab->nib", F0, self.S)
        Q3, h = self._pad_local(F0, np.zeros((self.N, 3)))
        dX = X[self.pad_idx] - self.x0[self._pad["c"]]
        dX[:, 2] -= self.L * np.round(dX[:, 2] / self.L)
        self._pad["r0"] = np.ascontiguousarray(np.einsum("eia,ei->ea", Q3, dX) - h)
        self._pad["c"] = np.ascontiguousarray(self._pad["c"], dtype=np.int64)
        self.X_atoms, self.sub_atoms, self.removed = X, sub, removed
        self.Xf = Xf
        # atomistic potential on the cluster (free atoms first)
        step = self.cutoff == "step"
        name = self.potential.split(":", 1)[1] if self.potential.startswith("tersoff:") \
            else self.potential
        tf = Tersoff.from_lammps(name, ["C"], step_cutoff=step)
        self._tP, self._te2p, self._tcut = tf.table, tf.e2p, float(tf.cutoff)
        self._types = np.zeros(self.nf + npad, np.int64)
        self._cell0 = np.zeros((3, 3))
        self._nl = None  # Verlet list of the atomistic region (:meth:`_neighbours`)
        self.nl_skin = NL_SKIN
        # bonds of the free atoms at the start (< 2.0 Å), for the atoms' damage index
        fl, jl, _ = neighbour_list(np.vstack([Xf, X[self.pad_idx]]), np.zeros((3, 3)),
                                   (False, False, False), 2.0)
        ii = np.repeat(np.arange(self.nf + npad), np.diff(fl))
        keep = ii < self.nf
        self._bonds0 = np.column_stack([ii[keep], jl[keep]]).astype(np.int64)
        self.y_init = np.vstack([self.x0[self.dof_idx], Xf])
        self.dof = 3 * (len(self.dof_idx) + self.nf)
        # the stability rule only tests particles carrying at least half their atoms
        self.stability_mask = self.natoms_n >= 0.5 * nominal
        self._stab_scale()
        self._ghost = None
        # ghost forces are those of the pristine tube with the same region (its twin): taken
        # from the defect tube itself they would also cancel the vacancy's own forces
        self._twin = None
        if _twin_of is None:  # (also without a vacancy: the twin stays periodic when the
            # tube is opened for dynamic tension, and the correction needs the periodic one)
            self._twin = DCBRDefectTube(n, m, length, coarsening, _twin_of=self, **self._kw_all(kw))
            tw = self._twin
            if not (np.array_equal(tw.dof_idx, self.dof_idx)
                    and np.allclose(tw.natoms_n, self.natoms_n)):
                raise RuntimeError("the pristine twin's particles differ from the tube's")
            pos = {a: k for k, a in enumerate(tw.free_idx)}
            self._twin_rows = np.array([pos[a] for a in self.free_idx], np.int64)

    @DCBRTube.method.setter
    def method(self, value: str):
        DCBRTube.method.fset(self, value)
        if getattr(self, "_twin", None) is not None:  # the twin gives the ghost forces
            self._twin.method = value

    def _kw_all(self, kw):
        return dict(kw, vacancy=0, r_atomistic=self._kw["r_atomistic"], pad=self._kw["pad"],
                    region=self.region, whole_cells=self._kw["whole_cells"], r_arc=self.r_arc)

    # ------------------------------------------------------------------ pieces
    def _stab_scale(self):
        st = self._st
        st["w"] = st["w"] * (self.natoms_n[st["c"]] / self.nominal)

    def _build_gain(self, intact):
        super()._build_gain(intact)
        if hasattr(self, "nominal"):
            self._stab_scale()

    def _pad_local(self, F, delta):
        """Q3 (npad,3,3) of each pad atom's carrier and its local offset h (npad,3), for real
        or complex F (N,3,2) and delta (N,3)."""
        pd, S, R0 = self._pad, self.S, self.lattice.R0
        c = pd["c"]
        FS = np.einsum("nia,nab->nib", F[c], S[c])
        C0 = np.einsum("nia,nib->nab", FS.real, FS.real)
        dead = ~self.alive[c] | (C0[:, 0, 0] < 1e-6) | \
            (C0[:, 0, 0] * C0[:, 1, 1] - C0[:, 0, 1] ** 2 < 1e-9)
        if dead.any():  # a failed carrier has no G: its pads keep its last map (no jump)
            FS = FS.copy()
            FS[dead] = self._FS_last[c[dead]]
        lt, gm, lz, Q3 = uniform_map_frame(FS)
        sig = pd["sig"]
        dl = delta[c]
        rp = lt * R0
        rho = rp + sig * dl[:, 0]
        phi = (lt * pd["ds"] + gm * pd["dz"] + sig * dl[:, 1]) / rp
        h = np.stack([rho * np.sin(phi), lz * pd["dz"] + sig * dl[:, 2], rho * np.cos(phi) - rp],
                     axis=1)
        return Q3, h

    def _pad_positions(self, yp, F, delta):
        Q3, h = self._pad_local(F, delta)
        return yp[self._pad["c"]] + np.einsum("eia,ea->ei", Q3, h + self._pad["r0"])

    def particle_positions(self, y):
        """All N particle positions from the unknowns y = [non-slave particles; free atoms]."""
        yp = np.empty((self.N, 3))
        yp[self.dof_idx] = y[:len(self.dof_idx)]
        if len(self.slave_idx):
            yp[self.slave_idx] = self.Phi @ y[len(self.dof_idx):] + self.slave_off
        return yp

    def atom_positions(self, y, delta, Lz):
        """(free atoms (nf,3), pad atoms (npad,3)) for unknowns y, shifts delta, cell Lz."""
        yp = self.particle_positions(y)
        F = self.gain.deformation(yp, np.array([0.0, 0.0, Lz]))
        return y[len(self.dof_idx):], self._pad_positions(yp, F, delta)

    def _neighbours(self, x):
        """Verlet list (CSR over the rows of x, rows only for the free atoms) of the pairs
        within cutoff + ``nl_skin``, rebuilt when some atom has moved more than half the
        skin since the last build (so every pair within the cutoff is in it; the Tersoff
        kernel skips the pairs beyond the cutoff itself), each row's partners in index
        order, so that the forces do not depend on the skin or on when the list was built.
        Raises FloatingPointError for a non-finite position."""
        nl = self._nl
        if nl is not None and nl["x"].shape == x.shape:
            d2, bad = CK.max_displacement2(x, nl["x"])
        else:
            d2, bad = CK.max_displacement2(x, x)
            d2 = math.inf
        if bad >= 0:
            raise FloatingPointError(f"atom {bad} of the atomistic region has a non-finite "
                                     f"position {x[bad].tolist()}")
        if d2 <= (0.5 * self.nl_skin) ** 2 and nl["skin"] == self.nl_skin:
            return nl
        # rows of the free atoms only (the kernel visits no other), each row's partners in
        # index order: the kernel then sums in the same order whatever the skin and
        # whenever the list was rebuilt
        fl, jl = CK.cluster_pairs(x, self.nf, self._tcut + self.nl_skin)
        self._nl = nl = {"x": x.copy(), "fl": fl, "jl": jl, "skin": self.nl_skin,
                         "sh": np.zeros((len(jl), 3), np.int32), "builds": 0 if nl is None
                         else nl["builds"] + 1}
        return nl

    def _atomistic(self, x):
        """Site energies of the free atoms (the first nf rows of x) and -forces on all rows."""
        if self.method == "numpy":
            return self._atomistic_numpy(x)
        from potentials import tersoff_kernels as tk  # noqa: PLC0415

        x = np.ascontiguousarray(x, dtype=float)
        nl = self._neighbours(x)
        f = np.zeros_like(x)
        e_n = np.zeros(len(x))
        W = np.zeros((3, 3))
        E = tk.tersoff_range(0, self.nf, x, self._cell0, nl["fl"], nl["jl"], nl["sh"], self._types,
                      self._te2p, self._tP, self._tcut ** 2, f, e_n, W)
        self._e_atoms = e_n[:self.nf]
        return float(E), -f

    def _atomistic_numpy(self, x):
        """Reference of :meth:`_atomistic`: a new k-d tree pair list at every call."""
        from scipy.spatial import cKDTree  # noqa: PLC0415

        from potentials import tersoff_kernels as tk  # noqa: PLC0415

        if not np.all(np.isfinite(x)):
            bad = int(np.nonzero(~np.all(np.isfinite(x), axis=1))[0][0])
            raise FloatingPointError(f"atom {bad} of the atomistic region has a non-finite "
                                     f"position {x[bad].tolist()}")
        cell = np.zeros((3, 3))
        # a small open cluster: a k-d tree pair search is cheaper than the cell-list builder
        pr = cKDTree(x).query_pairs(self._tcut, output_type="ndarray")
        ii = np.concatenate([pr[:, 0], pr[:, 1]])
        jj = np.concatenate([pr[:, 1], pr[:, 0]])
        order = np.lexsort((jj, ii))
        jl = jj[order].astype(np.int32)
        fl = np.zeros(len(x) + 1, np.int64)
        np.cumsum(np.bincount(ii, minlength=len(x)), out=fl[1:])
        sh = np.zeros((len(jl), 3), np.int32)
        f = np.zeros_like(x)
        e_n = np.zeros(len(x))
        W = np.zeros((3, 3))
        E = tk.tersoff_range(0, self.nf, np.ascontiguousarray(x), cell, fl, jl, sh, self._types,
                      self._te2p, self._tP, self._tcut ** 2, f, e_n, W)
        self._e_atoms = e_n[:self.nf]
        return float(E), -f

    # ------------------------------------------------------------------ energy
    def _raw_energy_and_gradient(self, y, delta, Lz):
        if self.method == "numpy":
            return self._raw_energy_and_gradient_numpy(y, delta, Lz)
        g = self.gain
        nd = len(self.dof_idx)
        y = np.asarray(y, float)
        delta = np.ascontiguousarray(delta, dtype=float)
        yp = self.particle_positions(y)
        E, F, P, gd, gyp, dLs = self._coarse_part(yp, delta, Lz)
        FS, par, Q3, flag = self._frames
        ok = flag > 0
        self._FS_last[ok] = FS[ok]  # the map a carrier's pads keep if it fails
        # atomistic part: free atoms + pad atoms slaved to their carriers
        pd = self._pad
        R0 = self.lattice.R0
        x = np.empty((self.nf + len(self.pad_idx), 3))
        x[:self.nf] = y[nd:]
        CK.pad_positions(yp, delta, par, Q3, flag, self._FS_last, pd["c"], pd["ds"], pd["dz"],
                         pd["sig"], pd["r0"], R0, x[self.nf:])
        Ea, gx = self._atomistic(x)
        E += Ea - self.nf * self.e0
        gQ3 = np.zeros((self.N, 3, 3))
        gpar = np.zeros((self.N, 3))
        CK.pad_backward(np.ascontiguousarray(gx[self.nf:]), delta, par, Q3, flag, self._FS_last,
                        pd["c"], pd["ds"], pd["dz"], pd["sig"], pd["r0"], R0,
                        bool(self.relax_shift), gyp, gd, gQ3, gpar)
        CK.frame_adjoint(F, self.S, g.alive, par, Q3, gQ3, gpar, P)
        gyp = gyp - g.forces(P)
        dL = g.cell_derivative(P)[2] + dLs
        gy = np.empty_like(y)
        gy[:nd] = gyp[self.dof_idx]
        gy[nd:] = gx[:self.nf]
        if len(self.slave_idx):
            gy[nd:] += self._PhiT @ gyp[self.slave_idx]
        self._e_n = self._e_lat_n + self._w_stab_n / np.maximum(self.natoms_n, 1e-12)
        return E, gy, gd, dL

    def _raw_energy_and_gradient_numpy(self, y, delta, Lz):
        """Reference of :meth:`_raw_energy_and_gradient` (numpy arrays, complex-step
        derivatives of the pad map)."""
        g = self.gain
        nd = len(self.dof_idx)
        y = np.asarray(y, float)
        yp = self.particle_positions(y)
        E, F, P, gd, gyp, dLs = self._coarse_part(yp, delta, Lz)
        FS = np.einsum("nia,nab->nib", F, self.S)
        C0 = np.einsum("nia,nib->nab", FS, FS)
        ok = self.alive & (C0[:, 0, 0] > 1e-6) & \
            (C0[:, 0, 0] * C0[:, 1, 1] - C0[:, 0, 1] ** 2 > 1e-9)
        self._FS_last[ok] = FS[ok]  # the map a carrier's pads keep if it fails
        # atomistic part: free atoms + pad atoms slaved to their carriers
        xf = y[nd:]
        xpad = self._pad_positions(yp, F, delta)
        Ea, gx = self._atomistic(np.vstack([xf, xpad]))
        E += Ea - self.nf * self.e0
        gxf, gpad = gx[:self.nf], gx[self.nf:]
        c = self._pad["c"]
        np.add.at(gyp, c, gpad)
        eps = 1e-30
        Pp = np.zeros((self.N, 3, 2))
        Fc = F.astype(complex)
        dc = delta.astype(complex)
        for i in range(3):
            for a in range(2):
                Fc.imag[:] = 0.0
                Fc.imag[:, i, a] = eps
                dx = self._pad_positions(yp, Fc, dc).imag / eps
                np.add.at(Pp[:, i, a], c, np.einsum("ei,ei->e", gpad, dx))
        Fc.imag[:] = 0.0
        if self.relax_shift:
            for k in range(3):
                dc.imag[:] = 0.0
                dc.imag[:, k] = eps
                dx = self._pad_positions(yp, Fc, dc).imag / eps
                np.add.at(gd[:, k], c, np.einsum("ei,ei->e", gpad, dx))
        P += Pp
        gyp = gyp - g.forces(P)
        dL = g.cell_derivative(P)[2] + dLs
        gy = np.empty_like(y)
        gy[:nd] = gyp[self.dof_idx]
        gy[nd:] = gxf
        if len(self.slave_idx):
            gy[nd:] += self.Phi.T @ gyp[self.slave_idx]
        self._e_n = self._e_lat_n + self._w_stab_n / np.maximum(self.natoms_n, 1e-12)
        return E, gy, gd, dL

    def energy_and_gradient(self, y, delta, Lz):
        """Coupled energy with the ghost-force correction of the current load step (if set by
        :meth:`prepare_step`): E' = E - g . (x - x_u), g = dE/dx at the uniform state x_u,
        with g and x - x_u taken in each row's cylindrical components about the tube's axis
        (radial, arc, axial; the shifts are local already): a Cartesian dead load is not
        invariant under a rigid turn about the axis (its energy goes as -A cos(phi), A the sum
        of radial load times radius), and the minimiser turned some tubes by 180 deg to lower
        it, leaving the loads on the wrong atoms; the cylindrical form is the same at the
        uniform state (the patch test is unchanged) and does not see the turn."""
        E, gy, gd, dL = self._raw_energy_and_gradient(y, delta, Lz)
        E, gy, gd, on = self.apply_ghost_load(y, delta, Lz, E, gy, gd)
        if on:
            dL = dL + self._ghost["dL"]
        return E, gy, gd, dL

    def apply_ghost_load(self, y, delta, Lz, E, gy, gd):
        """The ghost-force dead load of :meth:`energy_and_gradient` applied to an energy E
        (eV) and its gradients ``gy`` (Ny, 3) and ``gd`` (N, 3) at (y, delta, Lz): returns
        ``(E', gy', gd', applied)``, unchanged (and ``applied`` False) when no load is set
        for this cell length. E' = E - W (:meth:`ghost_load_work`), the gradients those of
        :meth:`ghost_load_gradient`."""
        a = self._ghost_load(Lz)
        if a is None:
            return E, gy, gd, False
        E -= self._ghost_work(a, y, delta)
        gy, gd = self._ghost_gradient(a, y, gy, gd)
        return E, gy, gd, True

    def ghost_load_work(self, y, delta, Lz) -> float:
        """W (eV), the dead load's work at (y, delta, Lz), 0.0 without a load for this cell
        length: sum over rows of g_r (rho - rho_u) + g_t rho_u (theta - theta_u) + g_z
        (z - z_u), plus sum g_delta . (delta - delta_u), the load's components g taken at
        the uniform state u (:meth:`apply_ghost_load` subtracts it from the energy)."""
        a = self._ghost_load(Lz)
        return 0.0 if a is None else self._ghost_work(a, y, delta)

    def ghost_load_gradient(self, y, Lz, gy, gd):
        """``(gy', gd')``: the gradients of :meth:`apply_ghost_load` without its energy (the
        same arrays, bit for bit), for a force loop that never reads the energy: the work's
        angle needs an arctan2, a complex mean and a branch cut per row, about 40 % of the
        load's cost on a 1,818-row tube."""
        a = self._ghost_load(Lz)
        return (gy, gd) if a is None else self._ghost_gradient(a, y, gy, gd)

    def _ghost_load(self, Lz):
        """The dead load's components for cell length ``Lz`` (None without one): gr,
        gt rho_u, gz (Ny,) and g_delta (N, 3) in each row's cylindrical frame at the uniform
        state (taken once per load), zero on failed particles (a dead load on a particle
        with no energy left is unbounded below: the minimiser pushed such particles away
        without end, the energy of a (10,10) K = 4 tube fell by 900 eV in one step)."""
        gc = self._ghost
        if gc is None or not abs(gc["Lz"] - Lz) < 1e-12 * Lz:
            return None
        if "gr" not in gc:  # the load's cylindrical components at the uniform state
            yu, g = gc["y"], gc["gy"]
            xu = yu[:, :2] - yu[:, :2].mean(axis=0)
            thu = np.arctan2(xu[:, 1], xu[:, 0])
            c, s_ = np.cos(thu), np.sin(thu)
            rhou = np.hypot(xu[:, 0], xu[:, 1])
            gt = -g[:, 0] * s_ + g[:, 1] * c
            gc.update(thu=thu, rhou=rhou, gr=g[:, 0] * c + g[:, 1] * s_, gt=gt,
                      gtr=gt * rhou, gz=np.ascontiguousarray(g[:, 2]))
        gr, gt, rt, gdl = gc["gr"], gc["gtr"], gc["gz"], gc["gd"]
        if not self.alive.all():
            on = np.r_[self.alive[self.dof_idx].astype(float), np.ones(len(gr) - len(self.dof_idx))]
            gr, gt, rt = gr * on, gt * on, rt * on
            gdl = gdl * self.alive[:, None]
        return gc, gr, gt, rt, gdl

    @staticmethod
    def _ghost_work(a, y, delta) -> float:
        gc, gr, gt, rt, gdl = a
        # each row's offset from the rows' centroid (so that a sideways shift is free too)
        xc = y[:, :2] - y[:, :2].mean(axis=0)
        rho = np.hypot(xc[:, 0], xc[:, 1])
        th = np.arctan2(xc[:, 1], xc[:, 0])
        # arc angle change, on the branch of the rows' mean turn (so that all rows agree
        # on it, even at a half turn; locally it is th - thu, the branch only picks 2 pi k)
        turn = float(np.angle(np.mean(np.exp(1j * (th - gc["thu"])))))
        dth = turn + (th - gc["thu"] - turn + np.pi) % (2 * np.pi) - np.pi
        return float(np.sum(gr * (rho - gc["rhou"]) + gt * dth + rt * (y[:, 2] - gc["y"][:, 2]))
                     + np.sum(gdl * (delta - gc["d"])))

    @staticmethod
    def _ghost_gradient(a, y, gy, gd):
        """(gy + dW/dy, gd - g_delta) as new arrays (:func:`~upscale.models.
        dcbr_coupling_kernels.ghost_gradient`)."""
        _, gr, gt, rt, gdl = a
        gy_out, gd_out = np.empty(gy.shape), np.empty(gd.shape)
        CK.ghost_gradient(np.ascontiguousarray(y, dtype=float), gr, gt, rt,
                          np.ascontiguousarray(gy, dtype=float), np.ascontiguousarray(gd, dtype=float),
                          np.ascontiguousarray(gdl, dtype=float), gy_out, gd_out)
        return gy_out, gd_out

    # ------------------------------------------------------------------ uniform states
    def uniform_lattice(self, lam_z=None):
        """(lam_t, lam_z, shift) of the lattice relaxed at axial stretch ``lam_z`` (gam = 0,
        lam_t and the sublattice shift minimised), or at zero stress when ``lam_z`` is None.

        Newton's method from the reference lattice (:func:`upscale.engine.array_minimisers.newton`:
        four iterations to a gradient of ~1e-14 eV, 0.5 ms), BFGS only if it fails. BFGS at
        gtol 1e-12 stopped on precision loss with gradients up to 2e-8 (the lattice
        parameters 3e-10 off) after 14-99 evaluations, 2-9 ms; the dynamic scenes call
        this twice per ghost-force refresh."""
        lat, p = self.lattice, self.p
        if lam_z is None:
            def fun(v):
                e, g = lat.energy(np.array([v[0], 0.0, v[1], v[2], v[3], v[4]]), p)
                return e, np.array([g[0], g[2], g[3], g[4], g[5]])
            x0 = np.array([1.0, 1.0, 0, 0, 0])
        else:
            def fun(v):
                e, g = lat.energy(np.array([v[0], 0.0, lam_z, v[1], v[2], v[3]]), p)
                return e, np.array([g[0], g[3], g[4], g[5]])
            x0 = np.array([1.0, 0, 0, 0])
        r = newton(fun, x0, gtol=1e-12)
        if not r.converged:
            r = bfgs(fun, x0, gtol=1e-12, max_iter=500)
        if lam_z is None:
            return float(r.x[0]), float(r.x[1]), r.x[2:].copy()
        return float(r.x[0]), float(lam_z), r.x[1:].copy()

    def uniform_state(self, lam_t, lam_z, shift):
        """Unknowns y, shifts delta and cell Lz of the whole tube on the uniform map."""
        R0 = self.lattice.R0
        nd = len(self.dof_idx)
        y = np.empty((nd + self.nf, 3))
        th = self.theta[self.dof_idx]
        y[:nd] = np.column_stack([lam_t * R0 * np.cos(th), lam_t * R0 * np.sin(th),
                                  lam_z * self.x0[self.dof_idx, 2]])
        sub = self.sub_atoms[self.free_idx]
        tha = np.arctan2(self.Xf[:, 1], self.Xf[:, 0]) + sub * shift[1] / (lam_t * R0)
        rho = lam_t * R0 + sub * shift[0]
        y[nd:] = np.column_stack([rho * np.cos(tha), rho * np.sin(tha),
                                  lam_z * self.Xf[:, 2] + sub * shift[2]])
        return y, np.tile(np.asarray(shift, float), (self.N, 1)), lam_z * self.L

    def clamped_uniform_state(self, y, lam_z, lam0):
        """The uniform state ``y`` (:meth:`uniform_state` at axial stretch ``lam_z``) of a
        tube held by clamped grips (:meth:`clamp_grips`): the grips' particles put back where
        the grips took hold (``clamp``'s reference positions; the lattice's at stretch
        ``lam0`` when none were given) and moved rigidly with their planes, (lam_z - lam0) z_plane.
        Returns (y, held, low): the grips' rows among the unknown particles, and which of
        them belong to the lower grip."""
        z_lo, z_hi, rigid = self.clamp[0], self.clamp[1], np.asarray(self.clamp[2], bool)
        nd = len(self.dof_idx)
        held = rigid[self.dof_idx]
        low = self.x0[self.dof_idx, 2] < 0.5 * (z_lo + z_hi)
        if len(self.clamp) > 3:
            yr = np.asarray(self.clamp[3], float)[self.dof_idx]
        else:
            yr = self.uniform_state(*self.uniform_lattice(lam0))[0][:nd]
        y = np.array(y, dtype=float, copy=True)
        y[:nd][held] = yr[held]
        y[:nd, 2][held] += (lam_z - lam0) * np.where(low, z_lo, z_hi)[held]
        return y, held, low

    def prepare_step(self, Lz):
        """Ghost-force correction for the load step at cell length ``Lz``: the gradient of the
        coupled energy at the uniform, relaxed state of the pristine lattice at that stretch
        is subtracted as a dead load (Shenoy et al., J. Mech. Phys. Solids 47, 611 (1999)),
        so a pristine tube stays exactly uniform and the coupling adds no force of its own.
        With clamped grips and a clamped twin (:meth:`clamp_grips` with ``Lz0``) the uniform
        state is :meth:`clamped_uniform_state` (the grips rigid), and the grips' rows take as
        dead load what the twin's grips carry beyond the uniform tube's tension
        T = N / L de/dlam_z, so that they carry T there (the patch test at the grips)."""
        tw = self._twin if self._twin is not None else self
        nd = len(self.dof_idx)
        rows = np.r_[np.arange(nd), nd + self._twin_rows] if self._twin is not None else \
            np.arange(nd + self.nf)

        def state(lam_z):
            y, d, _ = tw.uniform_state(*tw.uniform_lattice(lam_z))
            return y[rows], d

        lt, lz, sh = tw.uniform_lattice(Lz / self.L)
        y, d, _ = tw.uniform_state(lt, lz, sh)
        self._ghost = None
        clamped = tw is not self and getattr(tw, "clamp", None) is not None and \
            not tw.periodic and hasattr(self, "_clamp_Lz0")
        if clamped:  # the gauge uniform, the grips rigid (their planes' displacement)
            y, held, low = tw.clamped_uniform_state(y, lz, self._clamp_Lz0 / self.L)
        _, gy, gd, _ = tw._raw_energy_and_gradient(y, d, Lz)
        if clamped:  # the grips' reaction at the uniform state is the uniform tube's tension
            # T = (N / L) de/dlam_z: what the pristine twin's grips carry beyond it is the
            # coupling's (a ghost force on the grips), so it is the held rows' dead load
            _, ge = tw.lattice.energy(np.array([lt, 0.0, lz, *sh]), tw.p)
            T = self.n_atoms / self.L * float(ge[2])
            for side, sign in ((held & low, -1.0), (held & ~low, 1.0)):
                k = np.nonzero(side)[0]
                gy[k, 2] -= sign * T / len(k)
        y, gy = y[rows], gy[rows]
        if clamped:  # (the open tube's cell is fixed: no dL)
            dL = 0.0
        else:  # d/dLz of the dead-load term along the uniform path (central difference of x_u)
            h = 1e-6 * Lz
            yp, dp = state((Lz + h) / self.L)
            ym, dm = state((Lz - h) / self.L)
            dL = float(np.sum(gy * (yp - ym)) + np.sum(gd * (dp - dm))) / (2 * h)
        self._ghost = {"Lz": float(Lz), "y": y, "d": d, "gy": gy, "gd": gd, "dL": dL}
        return {"max_particle_force_eV_A": float(np.abs(gy[:len(self.dof_idx)]).max()),
                "max_atom_force_eV_A": float(np.abs(gy[len(self.dof_idx):]).max()),
                "max_shift_force_eV_A": float(np.abs(gd).max())}

    def prepare_sides(self, Lz_lo: float, Lz_hi: float, Lz_key: float):
        """Ghost-force correction with each side of the region at its own stretch.

        The dead load of :meth:`prepare_step` assumes the whole tube is at one uniform
        stretch. In dynamic tension that holds until the tube breaks; after, each half
        relaxes while the grips keep moving, and a correction taken at the grips' strain
        would push ~1-3 eV/Å of spurious load into the interface. Here the rows below the
        vacancy (reference z) take the correction at cell length ``Lz_lo`` and those above
        at ``Lz_hi`` (each the stretch measured on that side); the energy is then called
        with ``Lz_key`` (the open tube's fixed cell)."""
        zc = self.vacancy_theta_z[1]
        lo_y = np.r_[self.x0[self.dof_idx, 2], self.Xf[:, 2]] < zc
        lo_d = self.x0[:, 2] < zc
        parts = []
        for Lz in (Lz_lo, Lz_hi):
            self.prepare_step(Lz)
            parts.append(self._ghost)
        a, b = parts
        g = {"Lz": float(Lz_key), "dL": 0.0}
        for k, rows in (("y", lo_y), ("gy", lo_y), ("d", lo_d), ("gd", lo_d)):
            g[k] = np.where(rows[:, None], a[k], b[k])
        self._ghost = g

    def minimise(self, y, delta, Lz, relax_box=False, gtol=1e-6, maxiter=5000,
                 fixed=None) -> TubeMinimum:
        """As :meth:`DCBRTube.minimise`, with two additions: ``relax_box`` finds the zero-stress
        cell length (:meth:`_relax_zero_stress`), and pairs held at the step cutoff go across
        it per ``step_crossing`` (module docstring: damped dynamics by default, or
        :meth:`_cross_steps`), then the energy is minimised again (the restarts of
        :func:`upscale.engine.array_minimisers.restarted`). Returns a :class:`TubeMinimum`."""
        if relax_box:
            return self._relax_zero_stress(gtol, maxiter)
        if fixed is None and self.periodic:
            fixed = self.rotation_pins(y)

        def lbfgs(y_, d_):
            return DCBRTube.minimise(self, y_, d_, Lz, relax_box=False, gtol=gtol,
                                     maxiter=maxiter, fixed=fixed)

        out = lbfgs(y, delta)
        if self.step_crossing == "damped":
            # the LAMMPS references' quasi-static protocol: while a force component above
            # 1e-4 eV/Å is left (a pair held at the step), damped dynamics, which feels the
            # forces only and so goes through the step, then L-BFGS again; at most 3 cycles
            out, n = restarted(out, lambda o: lbfgs(*self.quickmin(o.y, o.delta, Lz, fixed=fixed)),
                               done=lambda o: o.max_force <= 1e-4, max_restarts=3)
            out.info["damped_cycles"] = n
            return out
        done = set()  # pairs crossed in this call do not cross back (no ping-pong)
        out, n = restarted(out, lambda o: self._cross_steps(o, Lz, gtol, maxiter, fixed=fixed,
                                                            done=done),
                           done=lambda o: (o.max_force <= 10 * gtol
                                           and self.step_crossing != "always"),
                           max_restarts=50)
        out.info["step_crossings"] = n
        return out

    def clamp_grips(self, z_lo: float, z_hi: float, rigid, y_ref=None, Lz0=None):
        """Rigid grips for the open tube: planes z_lo < z_hi (reference z, Å), ``rigid`` (N,)
        the particles held.

        G is fitted against the axial coordinate clamped at the planes, a held particle
        counting as sitting at its plane (:func:`upscale.models.gain.build_gain`, ``clamp``):
        the held particles deep in a grip have G fixed, those next to the gauge (an edge:
        a link to a particle that is not held) stand for the material between the plane
        and the gauge (``grip_edges`` (N,) bool: those edges with a positive weight), and the
        gauge's particles see its strain exactly. The weights are the
        gauge's length shares: along each column of particles (one theta), every gauge
        particle and edge (at its plane) gets the part of the gauge nearer to it than to
        its neighbours in the column, times the particle's atoms per unit length; a held
        particle that is not an edge keeps its weight (its G does not change, so it adds
        no energy); then the weights of the particles fitted about themselves (edges and
        first free rows) are corrected so that the uniform gauge is an equilibrium
        (:meth:`_balanced_grip_weights`; same total). ``y_ref`` (N, 3): the particles'
        positions when the grips take hold (G is linearised about them; default the
        reference lattice). The open tube's G is rebuilt here (the weights need its
        coefficients). ``Lz0``: the cell length at which the grips take hold; given, the
        pristine twin that gives the ghost forces is opened and clamped alike, linearised
        about its uniform lattice at that stretch (:meth:`prepare_step`;
        ``upscale.experiments.scenes.dcbr_dynamic`` docstring, "Ghost forces with clamped grips")."""
        rigid = np.asarray(rigid, dtype=bool)
        if not (z_lo < z_hi and rigid.shape == (self.N,) and not self.periodic):
            raise ValueError(f"grip planes z_lo={z_lo}, z_hi={z_hi}, rigid {rigid.shape}, "
                             f"periodic={self.periodic}; valid: z_lo < z_hi, rigid of shape "
                             f"({self.N},), an open tube (periodic False)")
        if not hasattr(self, "_natoms_unclamped"):
            self._natoms_unclamped = self.natoms_n.copy()
        g = self.gain
        edge = np.zeros(self.N, bool)
        np.logical_or.at(edge, g.pair_i, rigid[g.pair_i] & ~rigid[g.pair_j])
        z = self.x0[:, 2]
        low = z < 0.5 * (z_lo + z_hi)
        zf = np.where(rigid, np.where(low, z_lo, z_hi), z)  # the fit coordinate
        h = self.spacing[1]
        share = np.ones(self.N)  # length share / h
        for col in np.unique(np.round(self.theta, 9)):
            idx = np.nonzero(np.isclose(self.theta, col, atol=1e-9))[0]
            nodes = idx[~rigid[idx] | edge[idx]]
            # one edge per plane and column: the one nearest the gauge
            for side in (low, ~low):
                e = nodes[edge[nodes] & side[nodes]]
                if len(e) > 1:
                    drop = e[np.argsort(np.abs(z[e] - np.where(side[e], z_lo, z_hi)))[1:]]
                    share[drop] = 0.0
                    nodes = np.setdiff1d(nodes, drop)
            nodes = nodes[np.argsort(zf[nodes])]
            zn = zf[nodes]
            mids = 0.5 * (zn[1:] + zn[:-1])
            lo = np.r_[z_lo, mids]
            hi = np.r_[mids, z_hi]
            share[nodes] = np.clip(hi, z_lo, z_hi) - np.clip(lo, z_lo, z_hi)
            share[nodes] /= h
        share[rigid & ~edge] = 1.0
        self.natoms_n = self._natoms_unclamped * share
        self.clamp = (float(z_lo), float(z_hi), rigid) if y_ref is None else \
            (float(z_lo), float(z_hi), rigid, np.asarray(y_ref, float))
        self._build_gain(None)  # the clamped G, whose coefficients the weights balance
        self.natoms_n = self._balanced_grip_weights(self.natoms_n)
        self._build_gain(None)
        # the edges that carry energy: their W(F_c, delta_c) is the gauge material's between
        # the plane and the first free row (free atoms in LAMMPS, whose sublattices relax)
        self.grip_edges = rigid & edge & (self.natoms_n > 0)
        tw = getattr(self, "_twin", None)
        if tw is not None and Lz0 is not None:  # the ghost forces' twin: opened and clamped
            # alike, linearised about its own uniform lattice at the set-up stretch
            tw.periodic = False
            tw.clamp = None
            tw._build_gain(None)
            yu, _, _ = tw.uniform_state(*tw.uniform_lattice(float(Lz0) / self.L))
            tw.clamp_grips(z_lo, z_hi, rigid, tw.particle_positions(yu))
            self._clamp_Lz0 = float(Lz0)

    def _balanced_grip_weights(self, w):
        """Weights of the particles next to the grip planes such that a gauge stretched
        uniformly between the grips is in equilibrium (the patch test of the energy sum).

        The clamped G gives every particle exactly the strain of a uniform gauge (its fit),
        but E = sum_c w_c W(F_c) is a quadrature of the strain energy, and a uniform state is
        only an equilibrium when every free particle j has sum_c w_c a_cj = 0 (a_cj: the
        coefficient of y_j in G_c; P = dW/dF is then the same per atom in every term, and
        f_j = -P sum_c w_c a_cj). Away from the planes the families are symmetric and the
        sum vanishes term by term; next to a plane the families fitted about their own
        particle (the grip edges and the first free rows) are not, and with the gauge's
        length shares as weights the first free row is pulled into the gauge, statically and
        more so under load, until the link rule breaks the grip's edge before the gauge
        (``dcbr-grip-stiffness``).

        The weights of the particles whose families are fitted about themselves (the set U,
        pad-atom carriers excluded) are therefore solved from sum_c w_c a_cj = 0 (both
        tangent components) at every free particle j in their families, the smallest change
        from the length shares ``w`` (least squares); every other particle counts with a full
        particle's atoms (``nominal``; at the atomistic region's interface the atoms and the
        ghost-force correction carry the rest of the uniform state's balance). The total
        weight, i.e. the energy of the uniform gauge, is then fixed by the grips' motion
        alone (with every free j balanced, sum_c w_c G_c depends on the grips' rows only),
        and it equals the length shares' total (to round-off), so the static grip
        stiffness of the uniform field is unchanged; what changes is that the field stays
        uniform. Each plane is solved on its own. Where the atomistic region's pad reaches
        the rows next to a plane (a gauge that is mostly atomistic: (6,6), 40 Å, 8 Å grips,
        5 Å band, coarsening 2) the system can have no positive solution; that plane then
        keeps the length shares (the region's atoms, not coarse rows, fill its gauge), and
        ``grip_weights_balanced`` (bottom, top) records which planes were balanced."""
        g = self.gain
        rigid = np.asarray(self.clamp[2], bool)
        ce = np.repeat(np.arange(self.N), np.diff(g.offsets))
        carrier = np.zeros(self.N, bool)
        carrier[self._pad["c"]] = True
        own = np.zeros(self.N, bool)
        own[ce[g.neighbors == ce]] = True  # the families fitted about their own particle
        own &= g.alive & ~carrier
        weff = np.where(own, w, self.nominal)
        b = np.zeros((self.N, 2))  # sum_c w_c a_cj with the length shares
        np.add.at(b, g.neighbors, weff[ce, None] * g.coef)
        low = self.x0[:, 2] < 0.5 * (self.clamp[0] + self.clamp[1])
        out = w.copy()
        self.grip_weights_balanced = []
        for side in (low, ~low):  # each plane on its own
            inU = own & side
            U = np.nonzero(inU)[0]
            J = np.unique(g.neighbors[inU[ce] & ~rigid[g.neighbors]])
            if len(U) == 0 or len(J) == 0:
                self.grip_weights_balanced.append(True)
                continue
            col = np.full(self.N, -1)
            col[U] = np.arange(len(U))
            row = np.full(self.N, -1)
            row[J] = np.arange(len(J))
            e = np.nonzero(inU[ce] & (row[g.neighbors] >= 0))[0]
            A = np.zeros((2, len(J), len(U)))
            for k in range(2):
                np.add.at(A[k], (row[g.neighbors[e]], col[ce[e]]), g.coef[e, k])
            A = A.reshape(2 * len(J), len(U))
            rhs = -b[J].T.reshape(-1)
            dw = np.linalg.lstsq(A, rhs, rcond=None)[0]
            res = float(np.abs(A @ dw - rhs).max())
            ok = bool(np.all(w[U] + dw > 0) and res <= 1e-8 * self.nominal)
            if ok:
                out[U] += dw
            self.grip_weights_balanced.append(ok)
        return out

    def masses(self):
        """(masses of the unknowns y (particles not slaved, then free atoms), masses of the
        shifts), amu: 12.011 per atom; a particle m_C max(w_c, N_c/2) (its atoms, at least
        half its nominal share, so that interface particles with few atoms do not set a tiny
        stable step); a shift the reduced mass of its two sublattices, a quarter of that."""
        w = np.maximum(self.natoms_n, 0.5 * self.nominal) * CARBON_MASS
        return np.concatenate([w[self.dof_idx], np.full(self.nf, CARBON_MASS)]), w / 4.0

    def quickmin(self, y, delta, Lz, steps: int = 5000, dt: float = 1.0, dmax: float = 0.02,
                  ftol: float = 1e-3, fixed=None):
        """Damped dynamics as LAMMPS's ``min_style quickmin``
        (:func:`upscale.engine.array_minimisers.quick_min_blocks` on the positions and the shifts):
        the velocity projected on the force (zeroed when it points uphill), ``dt`` fs, no
        unknown moving more than ``dmax`` Å per step, until the force vector's 2-norm is
        below ``ftol`` eV/Å or after ``steps`` steps; the shifts stay within
        +-``shift_bound``. Masses (:meth:`masses`): 12.011 amu per atom, a particle's carried
        atoms (at least half its share), a shift the reduced mass of its pair of sublattices
        (as the dynamic scene). Returns (y, delta)."""
        m, md = self.masses()
        hold = np.zeros_like(y, bool) if fixed is None else np.asarray(fixed, bool)

        def forces(x):
            _, gy, gd, _ = self.energy_and_gradient(x[0], x[1], Lz)
            fy, fd = -gy, -gd
            fy[hold] = 0.0
            return [fy, fd]

        r = quick_min_blocks(forces, [y, delta], [m[:, None], md[:, None]], dt=dt, steps=steps,
                             max_step=dmax, ftol=ftol, bounds=[None, self.shift_bound],
                             acc=ACC_UNIT)
        return r.x[0], r.x[1]

    def rotation_pins(self, y):
        """Mask holding the rigid turn about the axis (a zero mode of the periodic tube, which
        the minimiser otherwise wanders along, as far as 140 deg): the arc-wise component of
        two carrying particles at opposite sides of the row farthest from the vacancy, the
        ones whose arc direction is closest to x or y (that Cartesian component is held)."""
        nd = len(self.dof_idx)
        zc = self.vacancy_theta_z[1]
        dz = np.abs((self.x0[self.dof_idx, 2] - zc + 0.5 * self.L) % self.L - 0.5 * self.L)
        ring = np.nonzero(dz > dz.max() - 1e-6)[0]
        th = self.theta[self.dof_idx[ring]]
        fixed = np.zeros((len(y) if y is not None else nd + self.nf, 3), bool)
        # the arc direction at theta is (-sin, cos): hold y where |sin| is smallest, x where
        # |cos| is, on two particles about half a turn apart
        score_y, score_x = np.abs(np.sin(th)), np.abs(np.cos(th))
        a = int(np.argmin(np.minimum(score_y, score_x)))
        opp = np.abs(np.angle(np.exp(1j * (th - th[a] - np.pi))))
        b = int(np.argmin(opp))
        for k in (a, b):
            fixed[ring[k], 1 if score_y[k] <= score_x[k] else 0] = True
        return fixed

    def _relax_zero_stress(self, gtol, maxiter, tol=1e-4):
        """Zero axial stress: start from the pristine lattice's zero-stress length, then a
        secant iteration on the cell length (:func:`upscale.engine.array_minimisers.zero_cell_force`;
        positions minimised with each length's correction, the positions scaled along z with
        the length) until |dE/dLz| < ``tol`` eV/Å."""
        lt, lz, sh = self.uniform_lattice(None)
        y, delta, Lz = self.uniform_state(lt, lz, sh)
        cur = {"y": y, "delta": delta, "Lz": Lz}

        def relax(L):
            if L != cur["Lz"]:
                cur["y"] = cur["y"].copy()
                cur["y"][:, 2] *= L / cur["Lz"]
                cur["Lz"] = L
            self.prepare_step(L)
            o = self.minimise(cur["y"], cur["delta"], L, gtol=gtol, maxiter=maxiter)
            cur["y"], cur["delta"] = o.y, o.delta
            return o, o.cell_force

        out, Lz, n = zero_cell_force(relax, Lz, tol=tol, max_iter=12, first_step=1e-4)
        out.Lz = Lz
        out.info["zero_stress_iterations"] = n
        return out

    def _cross_steps(self, out, Lz, gtol, maxiter, window: float = 2e-3, fixed=None,
                     done=None):
        """Try the minima on the other side of the step cutoff for pairs held at it.

        With the step cutoff a pair's energy jumps where its distance crosses R + D, so a
        gradient minimiser stops with the pair held at the step, a minimum of the
        discontinuous energy with a force left on it (the LAMMPS runners meet the same and
        fall back on damped dynamics, which does not feel the step and goes through). For
        each pair within ``window`` Å of the step (a free atom in it), largest force first,
        the pair is moved to ``window`` Å on the other side (the free atoms share the move)
        and the energy minimised again; the first such minimum below the current one is
        returned (None if there is none)."""
        from scipy.spatial import cKDTree  # noqa: PLC0415

        y, delta, E0 = out.y, out.delta, out.energy
        nd = len(self.dof_idx)
        x = np.vstack(self.atom_positions(y, delta, Lz))
        rc = self._tcut
        pr = cKDTree(x).query_pairs(rc + window, output_type="ndarray")
        if len(pr) == 0:
            return None
        dv = x[pr[:, 1]] - x[pr[:, 0]]
        r = np.linalg.norm(dv, axis=1)
        near = (np.abs(r - rc) < window) & ((pr[:, 0] < self.nf) | (pr[:, 1] < self.nf))
        if not near.any():
            return None
        # largest push across the step first: -dE/dr for a pair inside (held bond pulled
        # apart), +dE/dr for one outside (pair pushed together); the free atoms' gradient
        # (pad atoms follow their carriers: none of their own)
        gy = self.energy_and_gradient(y, delta, Lz)[1]
        ga = np.zeros((len(x), 3))
        ga[:self.nf] = gy[nd:]
        pn, rn, vn = pr[near], r[near], dv[near]
        dEdr = np.einsum("ij,ij->i", ga[pn[:, 1]] - ga[pn[:, 0]], vn) / rn
        push = np.where(rn < rc, -dEdr, dEdr)
        order = np.argsort(-push)
        done = set() if done is None else done

        def across(a, b, rr, v):  # the unknowns with pair (a, b) moved across the step
            move = ((rc - window if rr >= rc - 1e-5 else rc + window) - rr) * v / rr
            yt = y.copy()  # move: the change of x_b - x_a, shared by the free atoms
            if a < self.nf and b < self.nf:
                yt[nd + a] -= 0.5 * move
                yt[nd + b] += 0.5 * move
            elif a < self.nf:
                yt[nd + a] -= move
            else:
                yt[nd + b] += move
            return yt

        if self.step_crossing == "force":
            # the pair the force pushes across hardest goes through, whatever the energy
            # does: MD and damped dynamics (LAMMPS's quickmin fallback) feel no barrier at
            # the step, only the force on either side of it
            for i in order:
                key = (int(pn[i, 0]), int(pn[i, 1]))
                if push[i] <= 10 * gtol or key in done:
                    continue
                done.add(key)
                yt = across(*key, rn[i], vn[i])
                return DCBRTube.minimise(self, yt, delta, Lz, gtol=gtol, maxiter=maxiter,
                                         fixed=fixed)
            return None
        starts = (across(a, b, rr, v)
                  for (a, b), rr, v in list(zip(pn[order], rn[order], vn[order]))[:4])
        return first_lower(starts, lambda yt: DCBRTube.minimise(self, yt, delta, Lz, gtol=gtol,
                                                                 maxiter=maxiter, fixed=fixed),
                           lambda r: r.energy, E0 - 1e-6,
                           accept_any=self.step_crossing == "always")

    # ------------------------------------------------------------------ failure and output
    def update_links(self):
        """The link rule of the base class, with the slave particles' own mapped bonds left
        out: a slave stands for atoms that are explicit (its weight is at most half its
        share, often zero), so its lattice state, and above all its sublattice shift, which
        then has next to no stiffness, says nothing about a bond (thermal drift of their
        shifts breaks links next to the region early). Links to a slave still break on the
        carrying particle's mapped bond. The same holds for a particle that carries no atoms
        at all (at coarsening 1 a few cells of the particle Voronoi tiling hold no atom,
        anywhere along the tube; weights before any grip clamp): its shift has no stiffness
        and drifts with its thermal velocity, so its own mapped bonds are left out as well
        (coarsening 1 only: coarsening 2-4 have no empty particle)."""
        a = self.alive
        masked = a & ~self.is_slave & (getattr(self, "_natoms_unclamped", self.natoms_n) > 0)
        self.alive = masked
        try:
            return super().update_links()
        finally:
            if self.alive is masked:  # nothing broke (no rebuild): the mask goes
                self.alive = a

    def check_stability(self, all_equal: bool = False):
        """The lattice-stability rule of the base class on particles carrying >= 1/2 of their
        atoms (``all_equal`` is ignored: the state is not uniform)."""
        if self.stability is None:
            return 0
        saved = self._e_lat_n.copy()
        self._e_lat_n = np.where(self.stability_mask, saved, -np.inf)
        try:
            return super().check_stability(all_equal=False)
        finally:
            self._e_lat_n = saved

    def radius(self, y, delta):
        """Mean distance of the atoms (free ones, and those the particles carry) from the
        tube's centroid axis (the tube is free to translate sideways, and a defect's forces
        can make the minimiser drift in it)."""
        yp = self.particle_positions(y)
        xf = y[len(self.dof_idx):]
        w = self.natoms_n
        c = (np.sum(w[:, None] * yp[:, :2], axis=0) + xf[:, :2].sum(axis=0)) / (w.sum() + self.nf)
        rho = np.hypot(yp[:, 0] - c[0], yp[:, 1] - c[1]) + 0.5 * delta[:, 0]
        rho_a = np.hypot(xf[:, 0] - c[0], xf[:, 1] - c[1])
        # the mean over all atoms: a particle stands for its w_c atoms (A and B, B d_rho out)
        return float((np.sum(w * rho) + rho_a.sum()) / (w.sum() + self.nf))

    def atom_damage(self, y, delta, Lz, break_cutoff: float = 2.1):
        """Damage index of the free atoms: 1 - bonds left / bonds at the start."""
        xf, xpad = self.atom_positions(y, delta, Lz)
        x = np.vstack([xf, xpad])
        b = self._bonds0
        L = np.linalg.norm(x[b[:, 1]] - x[b[:, 0]], axis=1)
        tot = np.bincount(b[:, 0], minlength=self.nf)
        ok = np.bincount(b[:, 0], weights=(L <= break_cutoff).astype(float), minlength=self.nf)
        return 1.0 - ok / np.maximum(tot, 1)

    def ghost_forces(self, strain: float = 0.0):
        """Largest gradient component (eV/Å) of the *uncorrected* coupled energy at the
        uniform, relaxed state of the pristine lattice at ``strain`` (from zero stress):
        zero for an exact coupling, the interface imbalance otherwise."""
        lt0, lz0, _ = self.uniform_lattice(None)
        Lz = self.L * lz0 * (1.0 + strain)
        saved = self._ghost
        try:
            return self.prepare_step(Lz)
        finally:
            self._ghost = saved

    # ------------------------------------------------------------------ mapped atoms, state
    def atom_map(self, atoms=None) -> dict:
        """The table that reconstructs atoms of the lattice from the coarse particles.

        ``atoms``: indices into ``X_atoms`` (default every atom that is neither free nor
        removed). Each follows the uniform map of its nearest carrying (non-slave) particle
        c, as the pad atoms do (module docstring): x_a = y_c + Q3_c (h_a + r0_a), with its
        reference arc and axial offsets from c, its sublattice and the reference residual
        r0_a taken at the current G (nearest carrier across the cell boundary only on a
        periodic tube). Returns ``{"atoms", "c", "ds", "dz", "sig", "r0"}`` (arrays over the
        mapped atoms) for :meth:`mapped_atoms` and :meth:`mapped_atom_gradient`."""
        X, R0 = self.X_atoms, self.lattice.R0
        if atoms is None:
            free = np.zeros(len(X), bool)
            free[self.free_idx] = True
            atoms = np.nonzero(~free & ~self.removed)[0]
        atoms = np.asarray(atoms, dtype=np.int64)
        if atoms.ndim != 1 or (len(atoms) and (atoms.min() < 0 or atoms.max() >= len(X))):
            raise ValueError(f"atoms of shape {atoms.shape}; valid: indices 0..{len(X) - 1} "
                             "into X_atoms")
        carry = self.dof_idx
        th = np.arctan2(X[atoms, 1], X[atoms, 0])
        dsc = R0 * _wrap(th[:, None] - self.theta[carry][None, :])
        dzc = X[atoms, 2][:, None] - self.x0[carry][None, :, 2]
        if self.periodic:
            dzc -= self.L * np.round(dzc / self.L)
        k = np.argmin(dsc ** 2 + dzc ** 2, axis=1)
        na = len(atoms)
        c = np.ascontiguousarray(carry[k], dtype=np.int64)
        ds, dz = dsc[np.arange(na), k], dzc[np.arange(na), k]
        sig = self.sub_atoms[atoms].astype(float)
        F0 = self.gain.deformation(self.x0, self.gain.cell)
        FS = np.einsum("nia,nab->nib", F0[c], self.S[c])
        lt, gm, lz, Q3 = uniform_map_frame(FS)
        rp = lt * R0
        phi = (lt * ds + gm * dz) / rp
        h = np.stack([rp * np.sin(phi), lz * dz, rp * np.cos(phi) - rp], axis=1)
        dX = X[atoms] - self.x0[c]
        if self.periodic:
            dX[:, 2] -= self.L * np.round(dX[:, 2] / self.L)
        r0 = np.ascontiguousarray(np.einsum("eia,ei->ea", Q3, dX) - h)
        return {"atoms": atoms, "c": c, "ds": np.ascontiguousarray(ds),
                "dz": np.ascontiguousarray(dz), "sig": np.ascontiguousarray(sig), "r0": r0}

    def _map_state(self, y, Lz):
        yp = self.particle_positions(y)
        F = self.gain.deformation(yp, np.array([0.0, 0.0, Lz]))
        return yp, F, self._map_frames(F)

    def mapped_atoms(self, y, delta, Lz, table) -> np.ndarray:
        """Positions (k, 3) of the atoms of ``table`` (:meth:`atom_map`) at unknowns y,
        shifts delta (N, 3), cell Lz (a failed carrier's atoms keep its last good map)."""
        yp, _, (_, par, Q3, flag) = self._map_state(y, Lz)
        out = np.empty((len(table["c"]), 3))
        CK.pad_positions(yp, np.ascontiguousarray(delta, dtype=float), par, Q3, flag,
                         self._FS_last, table["c"], table["ds"], table["dz"], table["sig"],
                         table["r0"], self.lattice.R0, out)
        return out

    def mapped_atom_gradient(self, y, delta, Lz, table, g):
        """Chain rule of :meth:`mapped_atoms`: a gradient ``g`` = dE/dx (k, 3) on the mapped
        atoms pulled back to (dE/dy (rows of y), dE/d delta (N, 3)): to each carrier's
        position, shift and frame, and through G to the particles of its family; a slave
        particle's part goes to the free atoms it interpolates."""
        g = np.ascontiguousarray(g, dtype=float)
        if g.shape != (len(table["c"]), 3):
            raise ValueError(f"gradient of shape {g.shape}; valid: ({len(table['c'])}, 3), "
                             "one row per mapped atom")
        delta = np.ascontiguousarray(delta, dtype=float)
        yp, F, (_, par, Q3, flag) = self._map_state(y, Lz)
        N = self.N
        gyp, gd = np.zeros((N, 3)), np.zeros((N, 3))
        gQ3, gpar, P = np.zeros((N, 3, 3)), np.zeros((N, 3)), np.zeros((N, 3, 2))
        CK.pad_backward(g, delta, par, Q3, flag, self._FS_last, table["c"], table["ds"],
                        table["dz"], table["sig"], table["r0"], self.lattice.R0,
                        bool(self.relax_shift), gyp, gd, gQ3, gpar)
        CK.frame_adjoint(np.ascontiguousarray(F), self.S, self.gain.alive, par, Q3, gQ3,
                         gpar, P)
        gyp = gyp - self.gain.forces(P)
        nd = len(self.dof_idx)
        gy = np.zeros((nd + self.nf, 3))
        gy[:nd] = gyp[self.dof_idx]
        if len(self.slave_idx):
            gy[nd:] += self._PhiT @ gyp[self.slave_idx]
        return gy, gd

    def carry_state(self, other: "DCBRDefectTube", y, delta, v=None, vdelta=None,
                    Lz: float | None = None, h: float = 1e-3):
        """This tube's unknowns continuing the state of ``other``, a tube of the same lattice
        whose atomistic region lies inside this one's (the region grown about the crack:
        :func:`upscale.experiments.scenes.dcbr_dynamic.dynamic_tension`, ``grow``).

        Particles that stay coarse keep their positions, velocities and shifts; the atoms
        that become free take the positions ``other`` gives them through their carriers'
        maps (:meth:`mapped_atoms`, the pad atoms' rule) and the velocities of those maps,
        x'_a = (x_a(y + h v, delta + h w) - x_a(y - h v, delta - h w)) / 2h (central
        difference, error O(h^2 |v|^3), with ``h`` fs); atoms free in both keep theirs.
        The map carries the coarse state's deformation and sublattice shift, not the
        atoms' own thermal motion (the coarse model has none), so the new atoms start at
        the local lattice with the local flow. Also copied: the links (broken links stay
        broken) and the carriers' last good maps.

        Parameters: ``y`` (nd_other + nf_other, 3) and ``delta`` (N, 3) of ``other``;
        ``v``, ``vdelta`` their rates (optional); ``Lz`` the cell length the energy is
        called with (default ``other.L``). Returns ``(y, delta)``, or ``(y, delta, v,
        vdelta)`` with ``v``: this tube's unknowns (nd + nf, 3) and shifts (N, 3); the
        shift rates of this tube's slave particles are zero (as at a run's start)."""
        if not (isinstance(other, DCBRDefectTube) and other.N == self.N
                and len(other.X_atoms) == len(self.X_atoms)
                and np.array_equal(other.removed, self.removed)
                and np.allclose(other.X_atoms, self.X_atoms, rtol=0, atol=1e-9)):
            raise ValueError("carry_state needs a tube of the same lattice and vacancy; got "
                             f"{getattr(other, 'N', None)} particles, this one {self.N}")
        free_o = np.zeros(len(self.X_atoms), bool)
        free_o[other.free_idx] = True
        if not (np.all(np.isin(other.free_idx, self.free_idx))
                and np.all(np.isin(self.dof_idx, other.dof_idx))):
            raise ValueError("carry_state: the other tube's atomistic region is not inside "
                             "this one's; valid: a region that contains it (e.g. the band "
                             "about a disc)")
        y = np.asarray(y, dtype=float)
        delta = np.ascontiguousarray(delta, dtype=float)
        Lz = float(other.L if Lz is None else Lz)
        ndo = len(other.dof_idx)
        rank = np.full(len(self.X_atoms), -1, np.int64)
        rank[other.free_idx] = np.arange(other.nf)
        kept = rank[self.free_idx] >= 0
        new = self.free_idx[~kept]
        table = other.atom_map(new)

        def unknowns(y_, d_):
            yn = np.empty((len(self.dof_idx) + self.nf, 3))
            yn[:len(self.dof_idx)] = other.particle_positions(y_)[self.dof_idx]
            xa = yn[len(self.dof_idx):]
            xa[kept] = y_[ndo:][rank[self.free_idx[kept]]]
            xa[~kept] = other.mapped_atoms(y_, d_, Lz, table)
            return yn
        yn, dn = unknowns(y, delta), delta.copy()
        self.set_links(other.intact, other.alive)
        self._FS_last[...] = other._FS_last
        if v is None:
            return yn, dn
        v = np.asarray(v, dtype=float)
        vd = np.zeros_like(delta) if vdelta is None else np.asarray(vdelta, dtype=float)
        vn = (unknowns(y + h * v, np.ascontiguousarray(delta + h * vd))
              - unknowns(y - h * v, np.ascontiguousarray(delta - h * vd))) / (2 * h)
        # the exact rates where they are unknowns of both (the map's difference is not)
        vp = np.zeros((self.N, 3))
        vp[other.dof_idx] = v[:ndo]
        vn[:len(self.dof_idx)] = vp[self.dof_idx]
        vn[len(self.dof_idx):][kept] = v[ndo:][rank[self.free_idx[kept]]]
        vdn = vd.copy()
        vdn[self.slave_idx] = 0.0
        return yn, dn, vn, vdn

    @property
    def ghost_correction(self) -> dict | None:
        """The ghost-force dead load of the current load step (:meth:`prepare_step`,
        :meth:`prepare_sides`): ``{"Lz", "y", "d", "gy", "gd", "dL"}``; settable (a
        resumed run puts back the one it was interrupted with)."""
        return self._ghost

    @ghost_correction.setter
    def ghost_correction(self, g):
        self._ghost = None if g is None else {k: g[k] for k in ("Lz", "y", "d", "gy", "gd", "dL")}

    @property
    def last_maps(self) -> np.ndarray:
        """(N, 3, 2) each particle's last good surface map FS (the map a failed carrier's
        pad atoms keep); history of the run, settable."""
        return self._FS_last

    @last_maps.setter
    def last_maps(self, fs):
        self._FS_last[...] = fs

    @property
    def neighbour_reference(self) -> np.ndarray | None:
        """Positions (free and pad atoms) at which the atomistic region's Verlet list was
        last built (None before the first evaluation)."""
        return None if self._nl is None else self._nl["x"]

    @property
    def twin(self) -> "DCBRDefectTube | None":
        """The pristine twin whose gradient gives the ghost-force correction (None for a
        twin itself)."""
        return self._twin

    def rebuild_neighbours(self, x) -> None:
        """Build the Verlet list at positions ``x`` (free then pad atoms): a resumed run
        rebuilds the list where it was built before, so the rebuilds fall on the same steps
        (the forces do not depend on where the list was built, :meth:`_neighbours`)."""
        self._nl = None
        self._neighbours(np.ascontiguousarray(x, dtype=float))

    def summary(self) -> dict:
        return {"particles": int(self.N), "slave_particles": int(len(self.slave_idx)),
                "free_atoms": int(self.nf), "pad_atoms": int(len(self.pad_idx)),
                "removed_atoms": int(self.removed.sum()), "dof": int(self.dof),
                "atom_count_error": self.atom_count_error,
                "vacancy_theta_z": list(self.vacancy_theta_z),
                "band_z": None if self.band_z is None else list(self.band_z)}
