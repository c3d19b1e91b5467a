"""The mixed bundle's one thermostat: a Nose-Hoover chain on the temperature of the atoms
its rows stand for.

The LAMMPS references thermostat every free atom of the seven tubes with one ``fix nvt``
on their x, y velocities (``compute temp/partial 1 1 0``): its temperature is the mean
over 2 n_free dofs of seven alike tubes. A coarse tube carries the same atoms on fewer
explicit dofs (its free particle rows and atoms, x and y, and its particles' free shifts),
so the chain counting them as they are has about 0.63 of the reference's N_f, and the heat
a crack releases in the atomistic tube raises the thermostat's temperature, hence the
friction that follows, d p_1/dt = (T/T_0 - 1) / tau^2, 1.6 times as much as in LAMMPS
(a slower, more damped collapse of the crack). Here each tube k's kinetic energy counts
with the weight

    s_k = n_k^rep / n_k,   n_k^rep = 2 (atoms of tube k between the grip planes),
    n_k = 2 (free rows of tube k) + 3 (its free shifts)                          (1)

(s = 1 on an atomistic tube), and N_f = sum_k n_k^rep, so that

    T = sum_k s_k 2 K_k / (N_f k_B)                                              (2)

is the mean temperature of the represented atoms when each tube's explicit dofs hold
that of its atoms: at equilibrium the same thermostat as the unweighted chain, after a
crack the same rise of T per unit of heat as the reference's. The chain, its masses
Q_1 = N_f k_B T tau^2, Q_j = k_B T tau^2, and the scaling of all the rates by one factor
are :class:`~upscale.engine.thermostats.NoseHooverChain`'s (one process: the weighted
sum is not reduced over MPI ranks).
"""
from __future__ import annotations

import numpy as np

from upscale.constants import K_B_EV
from upscale.engine.thermostats import NoseHooverChain

__all__ = ["represented_weights", "chain"]


def represented_weights(scene, state, free, free_shifts, planes):
    """Eq. (1) on ``scene`` (a BundleScene) at ``state`` (assembled; the coarse tubes'
    atoms from their maps): ``free`` (n,) bool the thermostatted rows, ``free_shifts``
    {tube index: assembled rows of its free shifts}, ``planes`` (zb, zt) the grip planes,
    Å. Returns (row weights (n,), N_f, per tube [n_k, n_k^rep])."""
    asm = scene.assembly
    w = np.ones(asm.system.n)
    ndf, per = 0, []
    coarse = {k: bm for k, bm, _ in scene.coarse_models()}
    for k, b in enumerate(scene.bodies):
        rows = asm.rows(b.name)
        nk = 2 * int(free[rows].sum()) + 3 * len(free_shifts.get(k, ()))
        rep = nk
        if k in coarse:
            bm = coarse[k]
            z = bm.model.atom_positions(bm.sub(state))[:, 2]
            rep = 2 * int(((z > planes[0]) & (z < planes[1])).sum())
            w[rows] = rep / nk
        ndf += rep
        per.append([nk, rep])
    return w, ndf, per


def chain(scene, state, free, free_shifts, planes, temperature, tau_fs, chain_length,
          fields, field_region):
    """The bundle's chain on eq. (2): a :class:`~upscale.engine.thermostats.NoseHooverChain`
    with the row weights of eq. (1) and N_f = sum_k n_k^rep, on the free rows' x, y
    velocities and the coarse tubes' free shifts (``fields`` on ``field_region``), damping
    ``tau_fs``."""
    w, ndf, _ = represented_weights(scene, state, free, free_shifts, planes)
    return NoseHooverChain(temperature, tau_fs, region=free, chain=chain_length,
                           components=(0, 1), fields=fields, field_region=field_region,
                           weights=w, ndf=ndf, k_B=K_B_EV)
