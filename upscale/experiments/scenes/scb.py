"""``upscale scb``: mixed-mode fracture of a PMMA semi-circular bend specimen with the unified
gain-matrix model (seed 004 sec. 6.6).

==========================  ================================================================
specimen                    half disc R = 50 mm on the flat edge y = 0, thickness t = 5 mm,
                            plane stress; edge crack a = 0.3 R from (0, 0) at angle alpha to
                            the symmetry line (bonds crossing it removed)
supports / load             supports at x = +-S, S = 0.43 R; load at (0, R); each acts on a
                            3 dx x 3 dx patch of particles (the box of half width 1.5 dx)
boundary conditions         the load patch moves rigidly by (0, -lambda); the support patches
                            hold u_y = 0 (rollers, default) or u = 0 (``supports="pinned"``,
                            the literal u_x(+-S, 0) = 0 of eq. 6.40)
discretisation              square grid x, y = (i + 1/2) dx inside the half disc (15,700
                            particles at dx = 0.5 mm; the text's 16,366 is not a square grid
                            of this spacing), horizon delta = m dx (default m = 3)
material                    E = 3.75 GPa, nu = 0.35, rho = 1410 kg/m^3, K_Ic = 2.13 MPa sqrt(m)
                            (Table 6.1); G_c = K_Ic^2 / E
failure                     largest principal stress averaged over r_s (default), the bond
                            normal stress (``criterion="normal"``) or the particle energy
                            criterion (``criterion="energy"``), length r_s in metres
                            (``upscale.models.unified``); bonds with an end within
                            ``no_fail`` dx of a patch never break
loading                     quasi-static (``upscale.engine.quasistatic``): Newton equilibria,
                            bonds broken and the body re-equilibrated at the same load
==========================  ================================================================

:func:`scb` returns a :class:`~upscale.experiments.result.Result` (figures, the load-
displacement curve, the crack path, the damage per particle); :func:`run_scb` is the run
itself (with ``outdir``: ``scb.json``, ``scb_curve.png`` and ``scb_damage.png``, damage 6.41
with the broken-bond crack path, :func:`damage_png`).
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Literal

import numpy as np

from upscale.engine.memory import require_fit, run_memory
from upscale.experiments.result import Result, Timer, make_meta

__all__ = ["SCBScene", "run_scb", "scb", "calibrated_r_s", "PMMA", "crack_frame", "williams_fit"]

R_DEFAULT = 0.05
PMMA = {"E": 3.75e9, "nu": 0.35, "rho": 1410.0, "K_Ic": 2.13e6}


def crack_frame(alpha_deg):
    """Unit vectors (x', y') of the crack-tip frame: x' along the crack (mouth -> tip),
    y' = (cos alpha, -sin alpha) (the frame of ``validation.fem_scb``, K_II > 0)."""
    al = np.radians(alpha_deg)
    return np.array([np.sin(al), np.cos(al)]), np.array([np.cos(al), -np.sin(al)])


def williams_fit(rel, u, ex, ey, mu, kappa, r1, r2, n_terms=6):
    """Least-squares fit of the Williams expansion to a displacement field near a crack tip.

    ``rel`` (k, 2) positions relative to the tip (m), ``u`` (k, 2) displacements (m);
    ``ex`` along the crack (mouth -> tip), ``ey`` the normal of the tip frame of
    :func:`crack_frame` (a mirrored frame: the fit runs in the right-handed frame
    (ex, -ey) and K_II is returned with the sign of the mirrored frame). Points with
    r1 <= r <= r2 enter. Terms n = 0 .. n_terms - 1 of both modes (theta from the crack
    extension line, faces at +-pi):

        mode I:  2 mu u_1 = a_n r^(n/2) [(kappa + n/2 + (-1)^n) cos(n theta/2) - n/2 cos((n/2 - 2) theta)]
                 2 mu u_2 = a_n r^(n/2) [(kappa - n/2 - (-1)^n) sin(n theta/2) + n/2 sin((n/2 - 2) theta)]
        mode II: 2 mu u_1 = b_n r^(n/2) [(kappa + n/2 - (-1)^n) sin(n theta/2) - n/2 sin((n/2 - 2) theta)]
                 2 mu u_2 = b_n r^(n/2) [-(kappa - n/2 + (-1)^n) cos(n theta/2) - n/2 cos((n/2 - 2) theta)]

    K_I = a_1 sqrt(2 pi), K_II = -b_1 sqrt(2 pi) (sign of the mirrored frame, the one of
    ``validation.fem_scb``), T = 4 a_2 (the n = 2 mode-II term is a rigid rotation, n = 0
    translations). Returns (K_I, K_II, T) in the
    units of ``u`` times mu / sqrt(m).
    """
    e1, e2 = np.asarray(ex, float), -np.asarray(ey, float)
    x1, x2 = rel @ e1, rel @ e2
    r = np.hypot(x1, x2)
    th = np.arctan2(x2, x1)
    sel = (r >= r1) & (r <= r2)
    if sel.sum() < 4 * n_terms:
        raise ValueError(f"only {int(sel.sum())} points in the annulus {r1:g} <= r <= {r2:g} m; "
                         f"valid: at least {4 * n_terms} (widen the window or refine the spacing)")
    r, th = r[sel], th[sel]
    u1, u2 = u[sel] @ e1, u[sel] @ e2
    cols1, cols2 = [], []
    for n in range(n_terms):
        h = n / 2.0
        rn = r ** h / (2 * mu)
        sg = (-1.0) ** n
        cols1.append(rn * ((kappa + h + sg) * np.cos(h * th) - h * np.cos((h - 2) * th)))
        cols2.append(rn * ((kappa - h - sg) * np.sin(h * th) + h * np.sin((h - 2) * th)))
        cols1.append(rn * ((kappa + h - sg) * np.sin(h * th) - h * np.sin((h - 2) * th)))
        cols2.append(rn * (-(kappa - h + sg) * np.cos(h * th) - h * np.cos((h - 2) * th)))
    A = np.vstack([np.column_stack(cols1), np.column_stack(cols2)])
    keep = np.abs(A).max(axis=0) > 0
    coef = np.zeros(A.shape[1])
    scale = np.abs(A[:, keep]).max(axis=0)
    sol = np.linalg.lstsq(A[:, keep] / scale, np.concatenate([u1, u2]), rcond=None)[0] / scale
    coef[keep] = sol
    a1, b1, a2 = coef[2], coef[3], coef[4]
    return a1 * np.sqrt(2 * np.pi), -b1 * np.sqrt(2 * np.pi), 4 * a2


def default_growth(criterion: str) -> str:
    """The scenes' crack-growth rule for a failure ``criterion``: ``"front"`` for
    ``"principal"`` (the only criterion it is defined for), ``"free"`` otherwise."""
    return "front" if criterion == "principal" else "free"


#: fewest crack-length spacings a / dx for a converged fracture load (the paper's specimen at
#: dx = 1 mm: 1 -> 0.5 mm moves P_c by 2.9 / 6.5 / 0.1 % at alpha = 0 / 30 / 50 deg)
COARSE_A_OVER_DX = 15.0


#: peak memory per particle of a solve (GB): CHOLMOD's factor below 100,000 particles,
#: smoothed-aggregation multigrid above (``SCBScene.elastic``); the elastic runs at
#: dx = 0.5, 0.25 and 0.125 mm peaked at 62, 59 and 33 kB per particle
_PEAK_GB_CHOLMOD, _PEAK_GB_AMG, _AMG_FROM = 64e-6, 36e-6, 100_000


def _peak_gb(n: int) -> float:
    return n * (_PEAK_GB_CHOLMOD if n < _AMG_FROM else _PEAK_GB_AMG)


def _largest_n(gb: float) -> float:
    n = gb / _PEAK_GB_AMG
    return n if n >= _AMG_FROM else min(gb / _PEAK_GB_CHOLMOD, _AMG_FROM)


class SCBScene:
    """The SCB body, family, model and boundary conditions, built but not run.

    Parameters
    ----------
    alpha_deg : float
        Crack angle to the symmetry line, in [0, 90).
    dx : float
        Particle spacing (m).
    m : float
        Horizon over spacing.
    a_over_R, S_over_R : float
        Crack length and support half span over R; a/R in (0, 1), S/R in (0, 1).
    R, t : float
        Radius and thickness (m).
    r_s : float or None
        Length of the failure criterion (m); None: elastic only.
    supports : {"rollers", "pinned"}
    stabilisation : float
        Bond penalty c_s of the model (default 1: the non-affine part of every bond is
        resisted at about half the material's own stiffness). The gain operator's
        near-zero-energy modes are excited wherever the field is singular on the scale of
        the horizon -- the crack tip and the corners of the rigid patches -- and a weak
        penalty (0.1) leaves the body too soft there: a larger crack opening per load
        (K too high) and a larger compliance, the latter hidden when the rigid 3 x 3
        particle patches are compared with an FE model loaded on boundary segments.
    criterion : {"principal", "normal", "energy"}
        Failure rule of :class:`upscale.models.unified.UnifiedModel` (default: the largest
        principal stress averaged over r_s, a failing particle losing all its bonds).
    sequential : float
        Per round only the bonds within this fraction of the largest index break
        (default 0.99: the most loaded particle first, then re-equilibrium).
    tip_factor : {"solved", "lattice", "continuum"}
        beta of the critical stress (``UnifiedModel``): from the model's own solution (with
        this scene's c_s) of a disc driven by the mode-I tip field on its rim (default), from
        that field imposed on every particle of the lattice, or the continuum disc average.
        With the imposed field the first failure comes at K_I = 0.92 to 1.06 K_Ic for
        r_s / dx = 1 to 4 (c_s = 1), and P_c at alpha = 0 drifts by +4.5 % per halving of dx
        (1 -> 0.5 -> 0.25 mm); with the solved one -2.9 % then -1.4 %
        (``scb-convergence``).
    growth : {"front", "free"} or None
        Which particles may fail (``UnifiedModel``). None (default): :func:`default_growth`,
        ``"front"`` for the principal criterion -- only the crack front fails, so the crack
        advances from its tip and, with ``tip_factor="solved"``, P_c converges as the spacing
        falls at a fixed r_s (-1.4 / -3.2 / +1.4 % from 0.5 to 0.25 mm at 0 / 30 / 50 deg,
        against +11.9 % at 0 deg for ``"free"``; ``scb-convergence``) -- and
        ``"free"`` for the others.
        ``"free"`` is the seed's literal rule (any particle over the criterion fails).
    failure_energy : {"tensile", "total"}
    rcond : float
        Regularity threshold of a particle's Upsilon (``gain_coefficients``): a particle
        left with a nearly collinear family carries no stress (default 1e-2: such a
        sliver would otherwise be far stiffer than the reference and unstable in
        explicit runs).
    min_bonds : int
        A particle with fewer intact bonds carries no stress (default 6, a fifth of a
        full family at m = 3).
    no_fail : float
        Bonds with an end within this many dx of a patch box never break.
    force : {"energy", "printed"}
    gain_order : {1, 2}
        1: the centred (linear-fit) gain; 2: the quadratic-fit gain
        (:func:`upscale.models.gain.gain_coefficients_quadratic`), exact for quadratic
        fields at the faces and edges too.
    """

    def __init__(self, alpha_deg=0.0, *, dx=1e-3, m=3.0, a_over_R=0.3, S_over_R=0.43,
                 R=R_DEFAULT, t=5e-3, r_s=None, supports="rollers", stabilisation=1.0,
                 no_fail=3.0, force="energy", failure_energy="tensile", rcond=1e-2, min_bonds=6, E=PMMA["E"], nu=PMMA["nu"], K_Ic=PMMA["K_Ic"],
                 rho=PMMA["rho"], gain_order=1, criterion="principal", sequential=0.99,
                 tip_factor="solved", growth=None):
        from upscale.engine import ParticleSystem, bonds_crossing_segment, build_family
        from upscale.models.unified import UnifiedModel

        if not (0.0 <= alpha_deg < 90.0):
            raise ValueError(f"alpha={alpha_deg!r} deg; valid: 0 <= alpha < 90")
        if not (0.0 < a_over_R < 1.0):
            raise ValueError(f"a/R={a_over_R!r}; valid: 0 < a/R < 1")
        if not (0.0 < S_over_R < 1.0):
            raise ValueError(f"S/R={S_over_R!r}; valid: 0 < S/R < 1")
        if supports not in ("rollers", "pinned"):
            raise ValueError(f"supports={supports!r}; valid: 'rollers', 'pinned'")
        if r_s is not None and not (r_s > 0):
            raise ValueError(f"r_s={r_s!r} m; valid: r_s > 0")
        growth = default_growth(criterion) if growth is None else growth
        a, S = a_over_R * R, S_over_R * R
        if not (dx > 0) or dx > a / 5 or 3 * dx > min(S, R - S) / 2:
            raise ValueError(f"spacing dx={dx!r} m is too coarse for crack a={a:g} m and patches "
                             f"3 dx; valid: 0 < dx <= {min(a / 5, min(S, R - S) / 6):g} m")
        if r_s is not None and a / dx < COARSE_A_OVER_DX * (1 - 1e-9):
            import warnings

            warnings.warn(f"dx={dx:g} m leaves the crack a={a:g} m only {a / dx:.3g} spacings: fracture loads are "
                          f"not converged below a/dx = {COARSE_A_OVER_DX:g} (at a/dx = 7.5, dx = 2 mm, the mode-I "
                          f"P_c is 65 % above its 0.5 mm value: scb-convergence)", stacklevel=2)
        self.alpha_deg, self.dx, self.m, self.R, self.t = float(alpha_deg), float(dx), float(m), R, t
        self.a, self.S, self.supports = a, S, supports
        n = int(np.ceil(R / dx))
        g = (np.arange(-n, n) + 0.5) * dx
        X, Y = np.meshgrid(g, (np.arange(n) + 0.5) * dx, indexing="ij")
        inside = X ** 2 + Y ** 2 <= R * R
        x0 = np.column_stack([X[inside], Y[inside], np.zeros(inside.sum())])
        require_fit(_peak_gb(len(x0)), f"an SCB at dx={dx:g} m ({len(x0)} particles)",
                    lambda gb: f"dx={R * math.sqrt(math.pi / 2 / _largest_n(gb)):.3g} m")
        self.system = ParticleSystem(x0, dx * dx * t, rho, dim=2, thickness=t, plane="stress", spacing=dx)
        ex, ey = crack_frame(alpha_deg)
        self.tip = a * ex
        self.ex, self.ey = ex, ey
        fam = build_family(self.system, m * dx * (1 + 1e-9))
        cut = bonds_crossing_segment(x0, (0.0, 0.0), self.tip)(fam.owner, fam.neighbors, fam.xi)
        self.family = fam.remove_bonds(cut | cut[fam.reverse])
        x, y = x0[:, 0], x0[:, 1]
        h = 1.5 * dx * (1 + 1e-9)
        ytop = y[np.abs(x) <= h].max()
        self.load = (np.abs(x) <= h) & (y >= ytop - 3 * dx + 1e-9 * dx)
        self.support = (np.abs(np.abs(x) - S) <= h) & (y <= 3 * dx)
        near = np.zeros(len(x), bool)
        if no_fail > 0:
            # one box per patch: a box over both supports would span the ligament and the
            # crack tip (at dx = 3 mm it made every crack-front particle unbreakable)
            for msk in (self.load, self.support & (x < 0), self.support & (x > 0)):
                lo = x0[msk, :2].min(0) - no_fail * dx
                hi = x0[msk, :2].max(0) + no_fail * dx
                near |= np.all((x0[:, :2] >= lo) & (x0[:, :2] <= hi), axis=1)
        self.no_fail = near
        self.model = UnifiedModel(E=E, nu=nu, dim=2, plane="stress", stabilisation=stabilisation,
                                  K_Ic=K_Ic if r_s is not None else None, r_s=r_s,
                                  no_fail=near, force=force, failure_energy=failure_energy,
                                  rcond=rcond, min_bonds=min_bonds, gain_order=gain_order,
                                  criterion=criterion, sequential=sequential,
                                  tip_factor=tip_factor, growth=growth)
        self.model.prepare(self.system, self.family)
        self.fixed = np.zeros((self.system.n, 3), bool)
        self.fixed[self.load, :2] = True
        self.fixed[self.support, 1] = True
        if supports == "pinned":
            self.fixed[self.support, 0] = True
        self.u_dir = np.zeros((self.system.n, 3))
        self.u_dir[self.load, 1] = -1.0

    def state(self):
        from upscale.engine import State

        st = State.reference(self.system.x0, self.family.nb)
        return st

    # ------------------------------------------------------------------ elastic response
    def elastic(self, d=1e-5, preconditioner=None):
        """Elastic solve at load-patch displacement ``d`` (m): (state, P (N)).
        Preconditioner (``Equilibrium``): a sparse Cholesky factor below 100,000 particles
        (then the Newton steps converge in one or two CG iterations each), smoothed-
        aggregation multigrid above (its memory grows linearly with the size, a factor's
        faster)."""
        from upscale.engine.quasistatic import Equilibrium

        st = self.state()
        pc = preconditioner or ("cholmod" if self.system.n < 100_000 else "amg")
        reaction, _ = Equilibrium(self.model, self.fixed, preconditioner=pc).solve(st, d * self.u_dir)
        P = float(np.sum(reaction * self.u_dir))
        return st, P

    def stress_intensity(self, state, P, window=(0.2, 0.6), method="jump", n_terms=6):
        """K_I, K_II (Pa sqrt(m)) and Y_I, Y_II (6.30-6.31) from the displacement field,
        plane stress (kappa = (3 - nu) / (1 + nu)), over r / a in ``window``.

        ``method="jump"``: the crack-face displacement jump of the particle rows next to
        each face, K(r) = mu sqrt(2 pi / r) du / (kappa + 1), fitted as K + c r (the
        estimator of ``validation.fem_scb`` on this window).
        ``method="williams"``: a least-squares fit of the first ``n_terms`` orders of the
        Williams expansion (both modes, orders n = 0 .. n_terms - 1, rigid motions
        included) to the displacements of every particle in the annulus; it uses the whole
        near field instead of the two face rows (over-deterministic displacement method).
        """
        x0 = self.system.x0[:, :2]
        u = (state.y - self.system.x0)[:, :2]
        rel = x0 - self.tip
        along, across = rel @ self.ex, rel @ self.ey
        E, nu = self.model.E, self.model.nu
        mu = E / (2 * (1 + nu))
        kap = (3 - nu) / (1 + nu)
        Yf = 2 * self.R * self.t / (P * np.sqrt(np.pi * self.a))
        if method == "williams":
            KI, KII, T = williams_fit(rel, u, self.ex, self.ey, mu, kap, window[0] * self.a, window[1] * self.a,
                                      n_terms)
            return {"K_I": float(KI), "K_II": float(KII), "Y_I": float(KI * Yf), "Y_II": float(KII * Yf),
                    "T_star": float(T * 2 * self.R * self.t / P)}
        if method != "jump":
            raise ValueError(f"method={method!r}; valid: 'jump', 'williams'")
        face = (along < 0) & (np.abs(across) < self.dx) & (-along < self.a)
        r = np.linspace(window[0], window[1], 30) * self.a
        jumps = []
        for side in (across > 0, across < 0):
            sel = face & side
            rs = -along[sel]
            o = np.argsort(rs)
            jumps.append(np.vstack([np.interp(r, rs[o], u[sel, 0][o]), np.interp(r, rs[o], u[sel, 1][o])]))
        du = jumps[0] - jumps[1]
        fac = mu / (kap + 1) * np.sqrt(2 * np.pi / r)
        KI = np.polyfit(r, fac * (self.ey @ du), 1)[1]
        KII = np.polyfit(r, fac * (self.ex @ du), 1)[1]
        return {"K_I": float(KI), "K_II": float(KII), "Y_I": float(KI * Yf), "Y_II": float(KII * Yf)}

    # ------------------------------------------------------------------ fracture
    def fracture(self, *, u_max=None, d_lambda=None, progress=False, stop_fraction=0.2,
                 max_equilibria=3000):
        from upscale.engine.quasistatic import quasi_static_fracture

        st = self.state()
        u_max = 2e-3 if u_max is None else u_max
        d_lambda = 2e-4 if d_lambda is None else d_lambda
        curve = quasi_static_fracture(self.model, st, fixed=self.fixed, u_dir=self.u_dir,
                                      u_max=u_max, d_lambda=d_lambda, progress=progress,
                                      stop_fraction=stop_fraction, max_equilibria=max_equilibria)
        return st, curve

    def explicit(self, loading_time, u_end, *, every=10, stop_fraction=0.5, progress=False,
                 safety=0.4, rise=0.0):
        """Explicit dynamics (velocity Verlet, the engine's stable step) with the load patch
        driven at v = u_end / loading_time: (times (k,), displacement (k,), load (k,) N, state,
        run info). The load is the internal force on the load patch (along +y); the run stops
        when it falls below ``stop_fraction`` of its peak or when the patch reaches u_end.

        ``rise`` (s, default 0: the velocity jumps to v at t = 0): the patch velocity rises as
        v (1 - cos(pi t / rise)) / 2, so u = v [t - (rise / pi) sin(pi t / rise)] / 2 for t <
        rise and v (t - rise / 2) after. A velocity jump at t = 0 starts an undamped vibration
        of the specimen whose load amplitude is about k v / omega_1 (k the load-point stiffness,
        omega_1 the lowest mode the patch drives): relative to the load at the peak, 1 /
        (omega_1 t_c), t_c the time to the peak, so it falls only as 1 / loading time; a rise
        over several periods 2 pi / omega_1 leaves a residual vibration smaller by about
        1 / (omega_1 rise)^2 (the spectrum of the smoothed jump).

        ``info`` gains ``first_break`` = (t, displacement, load) of the first step that broke a
        bond (None if none broke)."""
        from upscale.engine import Simulation
        from upscale.engine.conditions import Displacement, Fixed, Region
        from upscale.engine.integrators import VelocityVerlet

        T = float(loading_time)
        if not T > 0:
            raise ValueError(f"loading_time={loading_time!r} s; valid: > 0")
        rise = float(rise)
        if not (0.0 <= rise <= T):
            raise ValueError(f"rise={rise!r} s; valid: 0 <= rise <= loading_time ({T:g} s)")
        v = u_end / T

        def u_of(t):
            if t < rise:
                return 0.5 * v * (t - rise / np.pi * np.sin(np.pi * t / rise))
            return min(v * (t - 0.5 * rise), u_end)

        load = Region("load", self.load)
        conds = [Displacement(load, value=lambda t: np.array([0.0, -u_of(t), 0.0]), components=(0, 1)),
                 Fixed(Region("support", self.support), components=(1,) if self.supports == "rollers" else (0, 1))]
        # breaking bonds shrinks a particle's family and stiffens its G: a step below the
        # reference estimate (``safety``) keeps the damaged state stable
        sim = Simulation(self.system, self.family, [self.model], conds, VelocityVerlet(safety=safety))
        rec_t, rec_d, rec_P = [], [], []
        first = []

        def cb(s):
            if not first and s.broken_total > 0:
                first.append((s.state.t, u_of(s.state.t), float(s.reactions[self.load, 1].sum())))
            if s.state.step % every:
                return False
            P = float(s.reactions[self.load, 1].sum())   # the body pushes the patch up
            rec_t.append(s.state.t)
            rec_d.append(u_of(s.state.t))
            rec_P.append(P)
            return max(rec_P) > 0 and P < stop_fraction * max(rec_P) and s.state.t > 0.1 * T

        sim.prepare()
        steps = int(np.ceil((T + 0.5 * rise) / sim.integrator.dt))
        info = sim.run(steps, callback=cb, progress=progress)
        info["first_break"] = first[0] if first else None
        return np.array(rec_t), np.array(rec_d), np.array(rec_P), sim.state, info

    def initiation_angle(self, curve, n_first=None):
        """Kink angle (deg) in the tip frame (positive toward +y', away from the load line)
        of the first broken bonds: the direction from the tip to the mean midpoint of the
        bonds broken in the first ``n_first`` (default: those within 3 delta of the tip)."""
        fam = self.family
        b = curve.first_broken
        if b.size == 0:
            return None
        mid = 0.5 * (self.system.x0[fam.owner[b], :2] + self.system.x0[fam.neighbors[b], :2])
        d = mid - self.tip
        dist = np.linalg.norm(d, axis=1)
        sel = dist <= 3 * self.m * self.dx if n_first is None else np.arange(b.size) < n_first
        if not sel.any():
            return None
        v = d[sel].mean(axis=0)
        return float(np.degrees(np.arctan2(v @ self.ey, v @ self.ex)))

    def crack_path(self, state, threshold=0.35):
        """Particles with damage >= ``threshold`` (x, y in m), sorted by distance from the tip."""
        from upscale.engine import damage

        mu = damage(self.family, state.intact)
        sel = mu >= threshold
        pts = self.system.x0[sel, :2]
        o = np.argsort(np.linalg.norm(pts - self.tip, axis=1))
        return pts[o], mu

    def describe(self) -> dict:
        return {"alpha_deg": self.alpha_deg, "dx_m": self.dx, "horizon_over_dx": self.m, "R_m": self.R,
                "t_m": self.t, "a_m": self.a, "S_m": self.S, "supports": self.supports,
                "particles": self.system.n, "bonds": self.family.nb // 2,
                "load_patch_particles": int(self.load.sum()),
                "support_patch_particles": int(self.support.sum()),
                "no_fail_particles": int(self.no_fail.sum()), "model": self.model.describe()}


def damage_png(path, scene, mu, title, path_pts=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = scene.system.x0
    fig, ax = plt.subplots(figsize=(7, 3.8))
    sc = ax.scatter(x[:, 0] * 1e3, x[:, 1] * 1e3, c=mu, s=(scene.dx * 2.6e3) ** 2, cmap="jet",
                    vmin=0, vmax=1, marker="s", linewidths=0)
    ax.plot([0, scene.tip[0] * 1e3], [0, scene.tip[1] * 1e3], "w-", lw=1)
    if path_pts is not None and len(path_pts):
        ax.plot(path_pts[:, 0] * 1e3, path_pts[:, 1] * 1e3, "k.", ms=1.5)
    ax.set_aspect("equal")
    ax.set_facecolor("0.85")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title)
    fig.colorbar(sc, ax=ax, label="damage (6.41)")
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)
    return Path(path)


def run_scb(alpha_deg=30.0, *, dx=1e-3, m=3.0, r_s=1e-3, supports="rollers", stabilisation=1.0,
            no_fail=3.0, force="energy", failure_energy="tensile", progress=False, outdir=None,
            a_over_R=0.3, S_over_R=0.43, u_max=None, d_lambda=None, stop_fraction=0.2,
            keep: bool = False, max_equilibria: int = 3000, criterion: str = "principal",
            sequential: float = 0.99, tip_factor: str = "solved", growth: str | None = None) -> dict:
    """Build and run the SCB fracture scene; returns a JSON-able result (and writes files
    under ``outdir`` when given); ``keep`` adds the scene, final state and damage under
    the keys ``_scene``, ``_state``, ``_damage`` (not JSON-able)."""
    t0 = time.perf_counter()
    sc = SCBScene(alpha_deg, dx=dx, m=m, r_s=r_s, supports=supports, stabilisation=stabilisation,
                  no_fail=no_fail, force=force, failure_energy=failure_energy, a_over_R=a_over_R,
                  S_over_R=S_over_R, criterion=criterion, sequential=sequential,
                  tip_factor=tip_factor, growth=growth)
    st, curve = sc.fracture(progress=progress, u_max=u_max, d_lambda=d_lambda, stop_fraction=stop_fraction,
                            max_equilibria=max_equilibria)
    pts, mu = sc.crack_path(st)
    P_c, d_c = curve.peak
    res = {"scene": sc.describe(), "P_c_N": P_c, "P_c_kN": P_c / 1e3, "displacement_at_P_c_m": d_c,
           "initiation_angle_deg": sc.initiation_angle(curve), "stop_fraction": stop_fraction,
           "broken_bonds": int((~st.intact).sum() // 2),
           "particles_without_stress": int((~sc.model.alive).sum()), "curve": curve.as_dict(),
           "crack_path_m": pts[:400].tolist(), "wall_s": time.perf_counter() - t0}
    if outdir is not None:
        from upscale.io import versions, write_json

        out = Path(outdir)
        out.mkdir(parents=True, exist_ok=True)
        res["versions"] = versions()
        write_json(out / "scb.json", res)
        damage_png(out / "scb_damage.png", sc, mu, f"SCB alpha = {alpha_deg:g} deg, dx = {dx * 1e3:g} mm", pts)
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5, 3.5))
        ax.plot(curve.displacement * 1e3, curve.load / 1e3, ".-", ms=2)
        ax.set_xlabel("load-point displacement (mm)")
        ax.set_ylabel("P (kN)")
        ax.set_title(f"SCB alpha = {alpha_deg:g} deg: P_c = {P_c / 1e3:.3f} kN")
        fig.tight_layout()
        fig.savefig(out / "scb_curve.png", dpi=150)
        plt.close(fig)
    if keep:
        res.update(_scene=sc, _state=st, _damage=mu)
    return res


def calibrated_r_s(criterion: str, dx: float) -> float:
    """The failure length r_s (m) of ``data/reference/scb_calibration.json``: for the energy
    criterion its r_s / dx times ``dx``, else the principal-stress r_s in metres."""
    import json

    from upscale.experiments.references import reference_file

    cal = reference_file("scb_calibration.json")
    if not cal.exists():
        raise FileNotFoundError(f"{cal} is missing; pass r_s")
    c = json.loads(cal.read_text())
    if criterion == "energy":
        return c["r_s_over_dx"] * dx            # that criterion's r_s scales with the spacing
    return c["principal"]["r_s_m"]              # a length in metres


def scb(*, alpha: float = 30.0, dx: float = 1e-3, m: float = 3.0, r_s: float | None = None,
        supports: Literal["rollers", "pinned"] = "rollers", stabilisation: float = 1.0,
        force: Literal["energy", "printed"] = "energy",
        criterion: Literal["principal", "normal", "energy"] = "principal",
        growth: Literal["front", "free"] | None = None,
        tip_factor: Literal["solved", "lattice", "continuum"] = "solved",
        stop_fraction: float = 0.5, progress: bool = False) -> Result:
    """Mixed-mode fracture of a PMMA semi-circular bend specimen (seed 004 6.6): load-
    displacement curve, fracture load P_c, initiation angle, crack path and damage.

    Parameters
    ----------
    alpha : float
        Crack angle to the symmetry line in degrees, in [0, 90).
    dx : float
        Particle spacing in m (1e-3: the calibrated one).
    m : float
        Horizon over spacing, delta / dx.
    r_s : float or None
        Failure length in m (None: the calibrated r_s of data/reference/scb_calibration.json; for the energy criterion its r_s / dx times dx).
    supports : {"rollers", "pinned"}
        Support patches hold u_y only (rollers) or u_x and u_y (pinned).
    stabilisation : float
        Bond penalty c_s of the unified model (dimensionless).
    force : {"energy", "printed"}
        Force of the unified model: from its energy or as printed in the seed.
    criterion : {"principal", "normal", "energy"}
        Failure rule: principal stress averaged over r_s, the averaged stress on each bond, or the particle energies of 6.28.
    growth : {"front", "free"} or None
        Which particles may fail: the crack front or any (None: front for the principal criterion, else free).
    tip_factor : {"solved", "lattice", "continuum"}
        beta of the critical stress: the model's own solution of a disc under the mode-I tip field, that field on the lattice, or the continuum disc average.
    stop_fraction : float
        Stop when the load falls below this fraction of its peak (0.5: P_c at the crack's first instability).
    progress : bool
        Show a progress bar.
    """
    if not (np.isfinite(dx) and dx > 0):
        raise ValueError(f"dx={dx!r} m; valid: a positive spacing")
    if not (np.isfinite(m) and m > 0):
        raise ValueError(f"m={m!r}; valid: a positive horizon over spacing")
    if not (0.0 < stop_fraction < 1.0):
        raise ValueError(f"stop_fraction={stop_fraction!r}; valid: 0 < stop_fraction < 1")
    params = dict(alpha=alpha, dx=dx, m=m, r_s=r_s, supports=supports,
                  stabilisation=stabilisation, force=force, criterion=criterion, growth=growth,
                  tip_factor=tip_factor, stop_fraction=stop_fraction)
    rs = calibrated_r_s(criterion, dx) if r_s is None else r_s
    with Timer() as timer:
        res = run_scb(alpha, dx=dx, m=m, r_s=rs, supports=supports, stabilisation=stabilisation,
                      force=force, progress=progress, stop_fraction=stop_fraction,
                      criterion=criterion, growth=growth, tip_factor=tip_factor, keep=True)
    sc, curve, desc = res["_scene"], res["curve"], res["scene"]
    ang = res["initiation_angle_deg"]
    figures = {"P_c_N": res["P_c_N"], "P_c_kN": res["P_c_kN"],
               "displacement_at_P_c_m": res["displacement_at_P_c_m"],
               "initiation_angle_deg": np.nan if ang is None else ang, "r_s_m": rs,
               "stop_fraction": stop_fraction, "broken_bonds": res["broken_bonds"],
               "particles_without_stress": res["particles_without_stress"],
               "equilibria": len(curve["load_N"]),
               **{k: v for k, v in desc.items() if k not in ("supports", "model")}}
    curves = {f"curve/{k}": curve[k] for k in ("displacement_m", "load_N", "broken",
                                               "newton_iterations", "index_max")}
    conventions = {
        "units": "SI (m, N); angles in degrees",
        "specimen": "half disc on the flat edge y = 0, load patch at (0, R) moved by (0, -lambda); "
                    "crack from (0, 0) at alpha to the symmetry line",
        "load": "P = the load patch's reaction along -y (positive in compression of the specimen)",
        "initiation_angle": "kink of the first broken bonds in the tip frame, positive toward "
                            "+y' (away from the load line); NaN: no bond broke",
        "damage": "6.41 (1 - intact/initial bonds); crack_path: particles with damage >= 0.35 "
                  "by distance from the tip (at most 400; meta crack_path_m, (x, y) pairs)",
    }
    meta = make_meta("scb", params, timer=timer, conventions=conventions,
                     plot={"curve": {"x": "displacement_m", "y": ["load_N"]}},
                     scene_description=desc, crack_path_m=res["crack_path_m"],
                     stop_reason=curve["stop_reason"],
                     time_split_s=curve["time_split_s"], run_wall_s=res["wall_s"],
                     memory=run_memory(sc.system, sc.family, [sc.model], res["_state"]))
    return Result(figures=figures, curves=curves,
                  fields={"x0": sc.system.x0, "damage": res["_damage"]}, meta=meta)
