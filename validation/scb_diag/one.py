"""One quasi-static SCB run per spec: P_c, initiation angle, solves, wall time, damage map.
Usage: one.py ALPHA,DX,R_S[,CRITERION[,SEQUENTIAL[,TIP_FACTOR]]] [...]  (criterion: principal (default), normal or energy; sequential default 0.99)

Run from the repository root with PYTHONPATH=$PWD (diagnostics behind validation/results/scb.md);
damage maps go to validation/out/scb_diag/."""
import json
import sys
from pathlib import Path

import numpy as np

from upscale.experiments.scenes.scb import damage_png, run_scb

out = Path("validation/out/scb_diag")
out.mkdir(parents=True, exist_ok=True)
for spec in sys.argv[1:]:
    parts = spec.split(",")
    al, dx, rs = map(float, parts[:3])
    crit = parts[3] if len(parts) > 3 else "principal"
    seq = float(parts[4]) if len(parts) > 4 else 0.99
    tf = parts[5] if len(parts) > 5 else "lattice"
    r = run_scb(al, dx=dx, r_s=rs, stop_fraction=0.5, max_equilibria=400, criterion=crit, keep=True,
                sequential=seq, tip_factor=tf)
    sc, mu = r.pop("_scene"), r.pop("_damage")
    r.pop("_state")
    c = r["curve"]
    tag = f"{al:g}_{dx * 1e3:g}mm_rs{rs * 1e3:g}_{crit}_seq{seq:g}_{tf}"
    pts = np.asarray(r["crack_path_m"]) if r["crack_path_m"] else None
    damage_png(out / f"damage_{tag}.png", sc, mu, f"alpha {al:g}, dx {dx * 1e3:g} mm, r_s {rs * 1e3:g} mm, "
               f"{crit}: P_c {r['P_c_kN']:.3f} kN", pts)
    row = {"alpha": al, "dx_mm": dx * 1e3, "r_s_mm": rs * 1e3, "criterion": crit, "P_c_kN": r["P_c_kN"],
           "d_at_P_c_mm": r["displacement_at_P_c_m"] * 1e3, "equilibria": len(c["load_N"]),
           "stop": c["stop_reason"], "wall_s": r["wall_s"], "newton_s": c["time_split_s"]["newton"],
           "failure_s": c["time_split_s"]["failure"], "init_deg": r["initiation_angle_deg"],
           "broken": r["broken_bonds"], "sequential": seq, "tip_factor": tf, "sigma_c_MPa": sc.model.describe().get("sigma_c_Pa", 0) / 1e6,
           "P_first_break_kN": next((c["load_N"][i - 1] / 1e3 for i, b in enumerate(c["broken"]) if b > 0), None)}
    print(json.dumps(row), flush=True)
