"""The front rule's tip factor beta on an imposed mode-I field against the model's own solved field.

lattice_tip_factor imposes the exact K_I tip displacement on every particle and averages the
gain's stress over r_s at the crack-front particles. In a fracture run the field near the tip
is the model's solution, in which the bond penalty c_s also acts. Here a disc of radius
R_DISC about the tip is driven by the exact K_I displacement on its outer ring (one horizon
thick) and relaxed (c_s = 0 and 1); beta from the solved field divided by the imposed one is
the factor by which the criterion's K at first failure differs from K_Ic: K_fail / K_Ic =
beta_imposed / beta_solved.
Usage: beta_solved.py DX[,DX...] [R_S [M [R_DISC]]]   (metres; defaults R_S 1e-3, M 3, R_DISC 12 R_S)

Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import sys

import numpy as np

from upscale.engine import ParticleSystem, bonds_crossing_segment, build_family
from upscale.engine.quasistatic import Equilibrium
from upscale.engine.state import State
from upscale.models.unified import UnifiedModel, _averaging_matrix, crack_front, front_pairs, lattice_tip_factor

E, NU = 3.75e9, 0.35
dxs = [float(v) for v in sys.argv[1].split(",")]
r_s = float(sys.argv[2]) if len(sys.argv) > 2 else 1e-3
m = float(sys.argv[3]) if len(sys.argv) > 3 else 3.0
R_disc = float(sys.argv[4]) if len(sys.argv) > 4 else 12 * r_s
mu, kap = E / (2 * (1 + NU)), (3 - NU) / (1 + NU)

print(f"r_s {r_s * 1e3:g} mm, m {m:g}, disc radius {R_disc * 1e3:g} mm, plane stress E {E:g} nu {NU:g}")
print(" dx mm  r_s/dx  particles  beta imposed  beta solved c_s=0  c_s=1   K_fail/K_Ic c_s=0  c_s=1")
for dx in dxs:
    h = m * dx * (1 + 1e-9)
    n = int(np.ceil(R_disc / dx))
    g = (np.arange(-n, n) + 0.5) * dx
    X, Y = np.meshgrid(g, g, indexing="ij")
    keep = X ** 2 + Y ** 2 <= R_disc ** 2
    x0 = np.column_stack([X[keep], Y[keep], np.zeros(keep.sum())])
    sysm = ParticleSystem(x0, dx * dx, 1.0, dim=2, thickness=1.0, plane="stress", spacing=dx)
    fam = build_family(sysm, h)
    cut = bonds_crossing_segment(x0, (-2 * R_disc, 0.0), (0.0, 0.0))(fam.owner, fam.neighbors, fam.xi)
    fam = fam.remove_bonds(cut | cut[fam.reverse])
    K = 1e-6 * E * np.sqrt(dx)
    r, th = np.hypot(x0[:, 0], x0[:, 1]), np.arctan2(x0[:, 1], x0[:, 0])
    f = K / (2 * mu) * np.sqrt(r / (2 * np.pi))
    u = np.zeros_like(x0)
    u[:, 0] = f * np.cos(th / 2) * (kap - 1 + 2 * np.sin(th / 2) ** 2)
    u[:, 1] = f * np.sin(th / 2) * (kap + 1 - 2 * np.cos(th / 2) ** 2)
    fixed = np.zeros((sysm.n, 3), bool)
    fixed[r > R_disc - h, :2] = True
    A = _averaging_matrix(x0[:, :2], sysm.volume, r_s)
    pairs = front_pairs(x0[:, :2], dx, fam.owner, fam.neighbors, sysm.n)
    out = []
    for c_s in (0.0, 1.0):
        model = UnifiedModel(E=E, nu=NU, plane="stress", stabilisation=c_s)
        model.prepare(sysm, fam)
        st = State.reference(x0, fam.nb)
        Equilibrium(model, fixed, preconditioner="lu", tol=1e-8, max_iter=60).solve(st, u)
        S = model.continuum_fields(st)[2]
        wv = model.alive.astype(float)
        Sb = (A @ (wv[:, None] * S.reshape(-1, 4))) / np.maximum(A @ wv, 1e-300)[:, None]
        s1 = np.linalg.eigvalsh(Sb.reshape(-1, 2, 2))[:, -1]
        near = (r <= r_s + h) & crack_front(pairs, np.ones(fam.nb, bool), model.alive, sysm.n)
        out.append(float(s1[near].max() * np.sqrt(r_s) / K))
    b_imp = lattice_tip_factor(r_s, dx, h, growth="front")[0]
    print(f"{dx * 1e3:6.3f}  {r_s / dx:6.2f}  {sysm.n:9d}  {b_imp:12.5f}  {out[0]:17.5f}  {out[1]:6.5f}"
          f"  {b_imp / out[0]:18.4f}  {b_imp / out[1]:6.4f}", flush=True)
