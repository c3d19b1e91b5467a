"""The coarse link rule: a link of G breaks when the lattice bond it stands for has no
energy left.

A link (c, j) of G's family stands for the C-C bond of the particle lattice
(:class:`.cell.TubeCell`, bonds A0-bondsA) most aligned with the link's reference
direction in c's tangent coordinates (``CoarseTube.link_bond``). It breaks when, in the
mapped lattice of c or of j (their q = (lam_t, gam, lam_z, shift) of the last evaluation),
that bond is longer than the potential's outer cutoff R + D (2.1 Å for C-C in
BNC.tersoff): no parameter is fitted, the threshold is the molecular potential's. A broken
link leaves G (its row is refitted); a particle left with a singular fit drops out. This
is the rule of the validated coarse tube (``DCBRTube.update_links``, old module), which
``sim.damage()`` reports per particle as mu = 1 - R/T (seed 004 eq. 5.16).

Units: Å.
"""
from __future__ import annotations

import numpy as np

from upscale.models.dcbr import kernels as K

__all__ = ["link_rule", "mapped_bonds"]


def mapped_bonds(tube, q_n) -> np.ndarray:
    """Lengths (N, 3) Å of the three bonds A0-bondsA of each particle's mapped lattice."""
    c = tube.cell
    return K.mapped_bond_lengths(np.ascontiguousarray(q_n), c.s_p, c.z_p, c.sub_p, c.R0, c.iA,
                                 c.bondsA)


def link_rule(tube, q_n, fraction: float = 1.0) -> np.ndarray:
    """(nb,) bool: links whose bond, in the mapped lattice of an alive end, is longer than
    ``fraction`` x the outer cutoff R + D (``fraction`` < 1 flags links *approaching*
    failure, for an adaptive region)."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction={fraction!r}; valid: 0 < fraction <= 1")
    Lb = mapped_bonds(tube, q_n)
    g = tube.gain
    rcut = fraction * float(tube.P_std[10] + tube.P_std[11])
    owner = g.owner_b
    li = Lb[owner, tube.link_bond]
    lj = Lb[g.j_b, tube.link_bond]
    return ((li > rcut) & tube.alive[owner]) | ((lj > rcut) & tube.alive[g.j_b])
