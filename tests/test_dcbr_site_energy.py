"""The DCBR lattice kernel's Tersoff site energy (``upscale.models.dcbr_kernels``) on every
branch of its three-body exponential, against the project's LAMMPS-form Tersoff kernel
(``potentials.tersoff_kernels``, itself checked against LAMMPS) and against central
differences of its own energy."""
import numpy as np
import pytest

from potentials import tersoff_kernels as tk
from potentials.neighbours import neighbour_list
from upscale.models import dcbr_kernels as K
from upscale.models.dcbr import tersoff_params

NAMES_M, NAMES_LAM3 = 0, 2  # positions of m and lambda3 in the 14 numbers


def _cluster(seed=3):
    """A strained 12-atom graphene flake with out-of-plane noise (every atom has 1-3
    neighbours inside the 2.1 Å cutoff)."""
    rng = np.random.default_rng(seed)
    a = 1.42
    x = []
    for i in range(3):
        for j in range(2):
            o = np.array([1.5 * a * i, np.sqrt(3) * a * (j + 0.5 * (i % 2)), 0.0])
            x += [o, o + [a, 0.0, 0.0]]
    x = np.array(x) * np.array([1.04, 0.98, 1.0])
    return x + 0.05 * rng.standard_normal(x.shape)


@pytest.mark.parametrize("m, lam3", [(3.0, 0.0), (3.0, 1.3), (1.0, 1.3)])
def test_site_energies_match_the_lammps_form_kernel_and_their_gradient(m, lam3):
    p = tersoff_params("tersoff:BNC.tersoff", "standard")
    p[NAMES_M], p[NAMES_LAM3] = m, lam3
    x = _cluster()
    n = len(x)
    cand = np.arange(n)
    e_sites, g = 0.0, np.zeros((n, 3))
    for i in range(n):
        e_sites += K.site_energy_grad(x, i, cand[cand != i], p, g)
    # the same potential through the LAMMPS-form kernel (one file entry, one element)
    P = tk.derived_columns(p[None, :])
    cut = float(P[0, tk.IDX_CUT])
    first, jb, sh = neighbour_list(x, np.eye(3) * 100.0, (False,) * 3, cut)[:3]
    E, _, f, _ = tk.tersoff(np.ascontiguousarray(x), np.eye(3) * 100.0, first, jb, sh,
                            np.zeros(n, np.int64), np.zeros((1, 1, 1), np.int64), P, cut, 1)
    assert e_sites == pytest.approx(E, rel=1e-12)
    assert np.abs(g + f).max() <= 1e-11 * np.abs(f).max()
    # central differences of the site energies
    h = 1e-6
    for a, c in [(0, 0), (5, 1), (7, 2), (11, 0)]:
        e = []
        for s in (h, -h):
            xs = x.copy()
            xs[a, c] += s
            e.append(sum(K.site_energy_grad(xs, i, cand[cand != i], p, np.zeros((n, 3)))
                         for i in range(n)))
        assert (e[0] - e[1]) / (2 * h) == pytest.approx(g[a, c], rel=1e-6, abs=1e-8)
