"""Dynamic tension of the coarse tube with a vacancy (the LAMMPS references' dynamic protocol).

:func:`dynamic_tension` follows ``validation.lammps.tension.dynamic_tension`` step for step,
on a :class:`~upscale.models.dcbr_defect.DCBRDefectTube`:

1. the tube on the zero-stress uniform lattice (L0; LAMMPS relaxes the periodic tube with
   its vacancy, which changes L0 by ~2e-4 here, and an open tube's length relaxes anyway);
2. the axial periodicity is removed (G is rebuilt without links across the cell boundary)
   and the open tube is minimised once (R = mean atom radius after it);
3. end grips of ``grip`` Å (the particles whose relaxed z is within ``grip`` of either end)
   move rigidly apart at ``speed`` Å/ps each; the rest starts with the linear axial velocity
   ramp between the grip speeds; velocity Verlet, ``dt`` fs;
4. strain = grip separation change / gauge, the initial distance between the innermost grip
   rows of particles (with particles 5-10 Å apart this differs from L0 - 2 grip by up to a
   spacing; LAMMPS's gauge is the same distance between its grip atoms); stress = mean of the
   two grips' reaction forces (sum of -dE/dz over each grip's particles, averaged over each
   ``sample``-step block) over 2 pi R t; the run stops when the stress has fallen below 20 %
   of its maximum after failure, or at ``max_strain``.

Masses: a free atom 12.011 amu; a particle carries m_C max(w_c, N_c/2) (its atoms, at least
half its nominal share, so that interface particles with few atoms do not set a tiny stable
step); the sublattice shift of a particle is a dynamic unknown with the reduced mass of the
two sublattices, m_C max(w_c, N_c/2) / 4 (the optical mode). Differences from the LAMMPS
runs, stated: no thermostat (0 K instead of 10 K Nose-Hoover on x, y), the ghost-force
correction is refreshed every ``sample`` steps at the current strain (a dead load in
between), and the coarse failure rules are the link rule only (checked every ``sample``
steps; the lattice-stability rule needs a Hessian and the coarse region stays far below its
~24 % instability strain when the vacancy fails).
"""
from __future__ import annotations

import math
import time

import numpy as np

from upscale.models.dcbr import EV_PER_A3_IN_GPA, WALL_THICKNESS

__all__ = ["dynamic_tension", "CARBON_MASS"]

CARBON_MASS = 12.011  # amu


def _acc_unit() -> float:
    """eV/(Å amu) in Å/fs^2: 1.602176634e-19 J / (1e-10 m 1.66053906660e-27 kg) in m/s^2,
    times 1e-20 (Å/fs^2 per m/s^2)."""
    return 1.602176634e-19 / (1e-10 * 1.66053906660e-27) * 1e-20


def dynamic_tension(model, grip: float = 50.0, speed: float = 1.0, dt: float = 1.0,
                    max_strain: float = 0.3, sample: int = 100, fit_max_strain: float = 0.02,
                    progress=None, gtol: float = 1e-4) -> dict:
    """Dynamic tension of an open coarse tube with end grips (module docstring).

    Returns a dict like the LAMMPS runner's: ``curve`` (strain, stress_GPa, time_ps),
    the curve metrics, ``L0_A``, ``radius_relaxed_A``, ``dof``, ``wall_s``, the final
    unknowns (``positions``, ``delta``) and ``damage``.
    """
    from upscale.analysis.stress import curve_metrics  # noqa: PLC0415

    if not (grip > 0 and speed > 0 and dt > 0 and 0 < max_strain <= 1 and sample >= 1):
        raise ValueError(f"grip={grip}, speed={speed}, dt={dt}, max_strain={max_strain}, "
                         f"sample={sample}; valid: all > 0, max_strain <= 1, sample >= 1")
    t0 = time.perf_counter()
    acc = _acc_unit()
    # the zero-stress uniform lattice (an open tube relaxes its own length, so the periodic
    # zero-stress iteration of the quasi-static scene is not needed), then the tube is
    # opened (G without links across the cell boundary) and minimised once
    lt, lz, sh = model.uniform_lattice(None)
    y, d, L0 = model.uniform_state(lt, lz, sh)
    free_len = L0 - 2 * grip
    if free_len <= 0:
        raise ValueError(f"grip={grip} Å leaves no free length in a {L0:.1f} Å tube; "
                         f"valid: grip < {L0 / 2:.1f}")
    model.periodic = False
    model._build_gain(None)
    model.prepare_step(L0)
    y, d, _, _, _, _ = model.minimise(y, d, L0, gtol=gtol)
    R = model.radius(y, d)
    area = 2 * math.pi * R * WALL_THICKNESS
    t_relax = time.perf_counter() - t0
    nd = len(model.dof_idx)
    z = y[:, 2]
    zlo, zhi = model.particle_positions(y)[:, 2].min(), model.particle_positions(y)[:, 2].max()
    bottom = np.zeros(len(y), bool)
    top = np.zeros(len(y), bool)
    bottom[:nd] = z[:nd] < zlo + grip
    top[:nd] = z[:nd] > zhi - grip
    if model.nf and (np.any(z[nd:] < zlo + grip) or np.any(z[nd:] > zhi - grip)):
        raise ValueError("the atomistic region reaches into a grip; valid: a longer tube or "
                         "shorter grips")
    grips = bottom | top
    # the gauge: between the innermost grip rows (the material that deforms; LAMMPS's gauge
    # is likewise the distance between its innermost grip atoms)
    gauge = float(z[top].min() - z[bottom].max())
    w = np.maximum(model.natoms_n[model.dof_idx], 0.5 * model.nominal)
    mass = np.concatenate([w, np.ones(model.nf)]) * CARBON_MASS
    mass_d = np.maximum(model.natoms_n, 0.5 * model.nominal) * CARBON_MASS / 4.0
    vz = 1e-3 * speed  # Å/fs
    v = np.zeros_like(y)
    zc = 0.5 * (zlo + zhi)
    v[:, 2] = np.clip((z - zc) / (0.5 * (zhi - zlo) - grip), -1, 1) * vz
    v[bottom, 2], v[top, 2] = -vz, vz
    vd = np.zeros_like(d)
    movable = ~grips

    def forces(y, d, strain):
        _, gy, gd, _ = model.energy_and_gradient(y, d, L0)
        return gy, gd

    gy, gd = forces(y, d, 0.0)
    strains, stresses, times = [], [], []
    blk = []
    step = 0
    smax, failed = 0.0, False
    first = None
    sep0 = 2 * vz  # separation rate
    while True:
        # velocity Verlet (grips move at constant velocity)
        a = -gy / mass[:, None] * acc
        ad = -gd / mass_d[:, None] * acc
        y = y + v * dt
        y[movable] += 0.5 * a[movable] * dt * dt
        d = d + vd * dt + 0.5 * ad * dt * dt
        step += 1
        strain = sep0 * step * dt / gauge
        gy2, gd2 = forces(y, d, strain)
        a2 = -gy2 / mass[:, None] * acc
        v[movable] += 0.5 * (a[movable] + a2[movable]) * dt
        vd += 0.5 * (ad - gd2 / mass_d[:, None] * acc) * dt
        gy, gd = gy2, gd2
        # reaction of the grips: the tube pulls the top grip down and the bottom one up
        blk.append(0.5 * (gy[top, 2].sum() - gy[bottom, 2].sum()))
        if not np.all(np.isfinite(y)):
            raise FloatingPointError(f"dynamic tension blew up at step {step} (strain "
                                     f"{strain:.4f}); last good stress {stresses[-1:]}")
        if step % sample == 0:
            s = float(np.mean(blk)) / area * EV_PER_A3_IN_GPA
            blk = []
            strains.append(strain)
            stresses.append(s)
            times.append(step * dt * 1e-3)
            smax = max(smax, s)
            if progress is not None:
                progress(strain, s)
            if first is None and model.nf:
                mu = model.atom_damage(y, d, L0)
                if mu.max() > 0:  # where the first bonds broke, on the unrolled wall
                    xf = y[nd:][mu > 0]
                    c = model.particle_positions(y)[:, :2].mean(axis=0)
                    th = np.arctan2(xf[:, 1] - c[1], xf[:, 0] - c[0])
                    dth = np.angle(np.mean(np.exp(1j * (th - model.vacancy_theta_z[0]))))
                    zv = model.vacancy_theta_z[1] * L0 / model.L  # on the relaxed tube
                    zmid = 0.5 * (zlo + zhi) - 0.5 * (model.x0[:, 2].min() + model.x0[:, 2].max()) \
                        * L0 / model.L
                    first = {"strain": strain, "n_atoms": int((mu > 0).sum()),
                             "distance_to_vacancy_A": float(np.hypot(
                                 R * dth, xf[:, 2].mean() - (zv + zmid)))}
            if model.update_links():
                gy, gd = forces(y, d, strain)
            model.prepare_step(L0 * (1 + strain))
            model._ghost["Lz"] = float(L0)  # the open tube's energy is called with L0
            gy, gd = forces(y, d, strain)
            if s < 0.95 * smax:
                failed = True
            if (failed and s < 0.2 * smax) or strain >= max_strain:
                break
    res = {"model": "dcbr-defect", "protocol": "dynamic", "chirality":
           [model.lattice.n, model.lattice.m], "coarsening": model.coarsening,
           "particles": model.N, "dof": model.dof, "atoms": model.n_atoms, "L0_A": float(L0),
           "radius_relaxed_A": R, "area_A2": area, "grip_A": grip, "speed_A_per_ps": speed,
           "dt_fs": dt, "steps": step, "free_length_A": free_len, "gauge_length_A": gauge,
           "curve": {"strain": strains, "stress_GPa": stresses, "time_ps": times}}
    res.update(curve_metrics(strains, stresses, fit_max_strain=fit_max_strain))
    res["first_damage"] = first
    res["positions"], res["delta"] = y, d
    res["damage"] = model.damage
    res["wall_s"] = time.perf_counter() - t0
    res["setup_relax_s"] = t_relax  # build excluded (the caller times it)
    res["dynamics_s"] = res["wall_s"] - t_relax
    return res
