"""The lattice tip factor of the principal criterion per (spacing, horizon, r_s): beta, the
distance ahead of the tip of the particle that fails first in a K-dominated mode-I field, and
sigma_c. Usage: beta.py DX,DELTA,R_S [...] (metres).
Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import json
import sys

import numpy as np

from upscale.models.unified import disc_average_factor, lattice_tip_factor

K_Ic = 2.13e6
b_c, p_c = disc_average_factor(2)
print(json.dumps({"continuum_beta": b_c, "continuum_p_over_r_s": p_c}))
for spec in sys.argv[1:]:
    dx, delta, r_s = map(float, spec.split(","))
    beta, p = lattice_tip_factor(r_s, dx, delta * (1 + 1e-9), rcond=1e-2, min_bonds=6)
    print(json.dumps({"dx_mm": dx * 1e3, "delta_mm": delta * 1e3, "m": delta / dx, "r_s_mm": r_s * 1e3,
                      "beta": beta, "beta_over_continuum": beta / b_c, "failing_particle_ahead_mm": p * r_s * 1e3,
                      "sigma_c_MPa": beta * K_Ic / np.sqrt(r_s) / 1e6}), flush=True)
