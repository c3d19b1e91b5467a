"""Pure bending of a free 60 x 20 beam (exact plane-stress field imposed on 3-column ends): interior
error, end moment / EI kappa, energy of the exact field. Usage: bend.py C_S [M] [GAIN_ORDER]

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md)."""
# pure bending of a free-edged beam: the exact plane-stress field u_x = k x y, u_y = -k (x^2 + nu y^2)/2
# imposed on end blocks (3 columns); compare interior field and the end moment
import sys, numpy as np
from upscale.engine import State, build_family, square_lattice
from upscale.engine.quasistatic import Equilibrium
from upscale.models.unified import UnifiedModel
h = 1e-3; nx, ny = 60, 20
cs = float(sys.argv[1]); m = float(sys.argv[2]) if len(sys.argv) > 2 else 3.0
s = square_lattice(nx, ny, h, thickness=5e-3)
x = s.x0.copy(); x[:, 0] -= x[:, 0].mean(); x[:, 1] -= x[:, 1].mean()
fam = build_family(s, m * h * (1 + 1e-9))
go = int(sys.argv[3]) if len(sys.argv) > 3 else 1
mod = UnifiedModel(E=3.75e9, nu=0.35, stabilisation=cs, gain_order=go); mod.prepare(s, fam)
k = 1.0
nu = 0.35
ue = np.zeros_like(x); ue[:, 0] = k * x[:, 0] * x[:, 1] * 1e-3; ue[:, 1] = -k * (x[:, 0]**2 + nu * x[:, 1]**2) / 2 * 1e-3
xs = np.unique(np.round(s.x0[:, 0], 12))
ends = (s.x0[:, 0] <= xs[2] + 1e-12) | (s.x0[:, 0] >= xs[-3] - 1e-12)
fixed = np.zeros((s.n, 3), bool); fixed[ends, :2] = True
st = State.reference(s.x0, fam.nb)
R, _ = Equilibrium(mod, fixed, preconditioner="lu").solve(st, ue)
u = st.y - s.x0
inner = ~ends
print(f"c_s {cs} m {m}: interior max |u - u_exact| / max|u_exact| = {np.abs(u - ue)[inner, :2].max() / np.abs(ue[:, :2]).max():.4f}")
# moment at the right end: sum of reaction x * y
right = s.x0[:, 0] >= xs[-3] - 1e-12
M = -np.sum(R[right, 0] * x[right, 1])
# exact: M = E I k 1e-3 with I = t H^3/12
Hh = ny * h; I = 5e-3 * Hh**3 / 12
print(f"  end moment / (E I k) = {M / (3.75e9 * I * k * 1e-3):.4f}")
# strain energy vs exact
E_ex = 0.5 * 3.75e9 * I * (k*1e-3)**2 * (nx * h)
print(f"  energy / exact (whole beam length) = {mod.energy(st) / E_ex:.4f}; with u_exact everywhere: {(lambda st2: mod.energy(st2))(type(st)(**{**st.__dict__})) if False else 0}")
st2 = State.reference(s.x0, fam.nb); st2.y = s.x0 + ue
print(f"  energy of the exact field / exact = {mod.energy(st2) / E_ex:.4f}")
