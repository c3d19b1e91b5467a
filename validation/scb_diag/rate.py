"""Explicit SCB runs against the quasi-static one: where the explicit peak comes from.
Usage: rate.py DX R_S TIMES RISES [ALPHA]   (TIMES: comma list of loading times to 1 mm in s;
RISES: comma list of velocity rise times as fractions of the loading time, 0 = velocity jump)

Per run: P_c and its error against the quasi-static peak, the first broken bond (time, patch
displacement, load) against the quasi-static first-break load, the vibration of the load about
the quasi-static elastic line k d before the first break (k from the first quasi-static
equilibrium), and the peak's displacement. Every step is sampled (every = 1).
Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import json
import sys

import numpy as np

from upscale.experiments.scenes.scb import SCBScene, run_scb

dx, r_s = float(sys.argv[1]), float(sys.argv[2])
times = [float(v) for v in sys.argv[3].split(",")]
rises = [float(v) for v in sys.argv[4].split(",")]
alpha = float(sys.argv[5]) if len(sys.argv) > 5 else 0.0
qs = run_scb(alpha, dx=dx, r_s=r_s, stop_fraction=0.5)
c = qs["curve"]
d, P, br = np.array(c["displacement_m"]), np.array(c["load_N"]), np.array(c["broken"])
k = P[0] / d[0]
i1 = int(np.argmax(br > 0))
kp = int(np.argmax(P))
print(json.dumps({"qs_P_c_kN": P[kp] / 1e3, "qs_d_at_P_c_mm": d[kp] * 1e3, "k_N_per_mm": k * 1e-3,
                  "qs_first_break_load_kN": P[i1 - 1] / 1e3 if i1 > 0 else None,
                  "qs_first_break_d_mm": d[i1] * 1e3, "qs_bonds_broken_before_peak": int(br[:kp + 1].sum()),
                  "qs_curve_near_peak": [(round(a * 1e3, 5), round(b / 1e3, 5), int(n))
                                         for a, b, n in zip(d[max(0, i1 - 2):kp + 3], P[max(0, i1 - 2):kp + 3],
                                                            br[max(0, i1 - 2):kp + 3])]}), flush=True)
for T in times:
    for fr in rises:
        sc = SCBScene(alpha, dx=dx, r_s=r_s)
        t, dd, PP, st, info = sc.explicit(T, 1e-3, every=1, rise=fr * T)
        j = int(np.argmax(PP))
        fb = info["first_break"]
        pre = (t < fb[0]) if fb else np.ones(t.size, bool)
        pre &= dd > 0.3 * (fb[1] if fb else dd.max())
        vib = float(np.max(np.abs(PP[pre] / (k * dd[pre]) - 1))) if pre.any() else None
        print(json.dumps({"T_ms": T * 1e3, "rise_frac": fr, "P_c_kN": PP[j] / 1e3,
                          "err_pct": 100 * (PP[j] / P[kp] - 1), "d_at_P_c_mm": dd[j] * 1e3,
                          "first_break_t_ms": fb[0] * 1e3 if fb else None,
                          "first_break_d_mm": fb[1] * 1e3 if fb else None,
                          "first_break_load_kN": fb[2] / 1e3 if fb else None,
                          "first_break_err_pct": 100 * (fb[2] / P[i1 - 1] - 1) if fb and i1 > 0 else None,
                          "vibration_pre_break_pct": None if vib is None else 100 * vib,
                          "steps": info["steps"], "dt_s": info["dt_s"], "wall_s": info["wall_s"]}), flush=True)
