"""Discrete dispersion relation of any linear model on the engine, from its force routine.

For a translation-invariant linear operator the force on degree of freedom a of a
particle c far from the boundary, under the plane wave ``q_b(x) = exp(i k.(x - x_c))`` in
degree of freedom b, is ``F_a(c) = -D_ab(k)`` with the dynamical matrix
``D_ab(k) = sum_n K_ab(c, n) exp(i k.(x_n - x_c))``. Real evaluations per degree of freedom
(cosine and sine waves) give it::

    D_ab(k) = -(F_a[cos] + i F_a[sin]),

(the cosine evaluated as ``(cos - 1) + 1``, the uniform field on its own, so that the
differences of a long wave keep their digits), and the frequencies are
``omega^2 = eig(M_c^-1 D(k))`` with the inertia ``M_c`` of each
degree of freedom of particle c (mass, or field inertia times volume). Because the matrix
comes from the models' own force routines (``Simulation.internal_forces`` and the field
forces of :mod:`upscale.engine.fields`), the result tests the code, not a formula. The
body only has to be larger than twice the models' influence radius around ``c``.
"""
from __future__ import annotations

import numpy as np

from upscale.engine.fields import dof_layout, generalised_forces, influence_radius, \
    mass_vector, set_dof

__all__ = ["dynamical_matrix", "dispersion", "centre_particle"]


def centre_particle(sim) -> int:
    """The particle nearest the body's centre; it must be farther than the models'
    influence radius from every edge."""
    x0 = sim.system.x0
    d = sim.system.dim
    lo, hi = x0[:, :d].min(axis=0), x0[:, :d].max(axis=0)
    c = int(np.argmin(np.sum((x0[:, :d] - 0.5 * (lo + hi)) ** 2, axis=1)))
    R = influence_radius(sim)
    margin = float(np.min(np.minimum(x0[c, :d] - lo, hi - x0[c, :d])))
    if margin <= R:
        raise ValueError(f"body too small for a dispersion probe: the centre is {margin:.4g} m "
                         f"from an edge, the influence radius is {R:.4g} m; valid: a body "
                         f"wider than 2 x {R:.4g} m")
    return c


def dynamical_matrix(sim, k, centre: int | None = None, *, amplitude: float = 1.0,
                     dofs=None) -> np.ndarray:
    """``D(k)`` (ndof, ndof) complex, generalised force per unit amplitude on particle
    ``centre`` (N per m, N per rad, N m per rad ...), ``k`` a wave vector (1/m; scalar for
    a wave along x). ``amplitude`` of the probing waves (small for a model that is linear
    only about the reference, e.g. bond-based PD: the result is its linearisation);
    ``dofs`` a subset of :func:`~upscale.engine.fields.dof_layout` (default all)."""
    st = sim.state
    c = centre_particle(sim) if centre is None else int(centre)
    kv = np.zeros(3)
    kv[: np.size(k)] = np.atleast_1d(k)
    phase = (sim.system.x0 - sim.system.x0[c]) @ kv
    full = dof_layout(sim)
    lay = full if dofs is None else [tuple(d) for d in dofs]
    rows = [full.index(d) for d in lay]
    nd = len(lay)
    saved = st.copy()
    D = np.zeros((nd, nd), complex)
    try:
        for key in full:
            set_dof(st, key, 0.0)
        F0 = generalised_forces(sim)[c, rows]
        for b, key in enumerate(lay):
            # cos = (cos - 1) + 1: the long-wave differences of cos - 1 = -2 sin^2(phase/2)
            # carry no cancellation; the uniform field's response is evaluated on its own
            set_dof(st, key, -2.0 * amplitude * np.sin(0.5 * phase) ** 2)
            Fc = generalised_forces(sim)[c, rows] - F0
            set_dof(st, key, np.full(phase.shape, amplitude))
            F1 = generalised_forces(sim)[c, rows] - F0
            set_dof(st, key, amplitude * np.sin(phase))
            Fs = generalised_forces(sim)[c, rows] - F0
            set_dof(st, key, 0.0)
            D[:, b] = -((Fc + F1) + 1j * Fs) / amplitude
    finally:
        st.y[...] = saved.y
        for name in st.fields:
            st.fields[name][...] = saved.fields[name]
    return D


def dispersion(sim, ks, centre: int | None = None, *, amplitude: float = 1.0,
               dofs=None) -> dict:
    """Frequencies of every branch for the wave vectors ``ks`` (nk,) or (nk, dim).

    Returns ``{"k": ks, "omega2": (nk, ndof) complex, sorted by real part, "D": (nk, ndof,
    ndof), "mass": (ndof,), "dofs": layout}``; for a symmetric (energy-consistent) operator
    ``D`` is Hermitian and ``omega2`` real."""
    c = centre_particle(sim) if centre is None else int(centre)
    full = dof_layout(sim)
    lay = full if dofs is None else [tuple(d) for d in dofs]
    m = mass_vector(sim).reshape(sim.system.n, len(full))[c, [full.index(d) for d in lay]]
    Ds, w2 = [], []
    for k in ks:
        D = dynamical_matrix(sim, k, c, amplitude=amplitude, dofs=lay)
        ev = np.linalg.eigvals(D / m[:, None])
        Ds.append(D)
        w2.append(ev[np.argsort(ev.real)])
    return {"k": np.asarray(ks), "omega2": np.array(w2), "D": np.array(Ds), "mass": m,
            "dofs": lay}
