"""The front rule's tip factor beta on an imposed mode-I field against the model's own solved field.

lattice_tip_factor imposes the exact K_I tip displacement on every particle and averages the
gain's stress over r_s at the crack-front particles (field="imposed"). In a fracture run the
field near the tip is the model's solution, in which the bond penalty c_s also acts: with
field="solved" a disc of radius R_DISC about the tip is driven by the exact field on its
outer ring (one horizon thick) and relaxed. beta solved / beta imposed is the factor by which
the criterion's K at first failure differs from K_Ic when the imposed beta is used:
K_fail / K_Ic = beta_imposed / beta_solved.
Usage: beta_solved.py DX[,DX...] [R_S [M [R_DISC]]]   (metres; defaults R_S 1e-3, M 3, R_DISC 12 R_S)

Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import sys

from upscale.models.unified import lattice_tip_factor

dxs = [float(v) for v in sys.argv[1].split(",")]
r_s = float(sys.argv[2]) if len(sys.argv) > 2 else 1e-3
m = float(sys.argv[3]) if len(sys.argv) > 3 else 3.0
R_disc = float(sys.argv[4]) if len(sys.argv) > 4 else 12 * r_s

print(f"r_s {r_s * 1e3:g} mm, m {m:g}, disc radius {R_disc * 1e3:g} mm, plane stress E 3.75e9 nu 0.35")
print(" dx mm  r_s/dx  beta imposed  beta solved c_s=0  c_s=1   K_fail/K_Ic c_s=0  c_s=1")
for dx in dxs:
    h = m * dx * (1 + 1e-9)
    kw = dict(growth="front", radius=R_disc)
    b_imp = lattice_tip_factor(r_s, dx, h, **kw)[0]
    b0, b1 = (lattice_tip_factor(r_s, dx, h, field="solved", stabilisation=c, **kw)[0] for c in (0.0, 1.0))
    print(f"{dx * 1e3:6.3f}  {r_s / dx:6.2f}  {b_imp:12.5f}  {b0:17.5f}  {b1:6.5f}  {b_imp / b0:18.4f}  {b_imp / b1:6.4f}",
          flush=True)
