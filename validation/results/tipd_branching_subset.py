"""The branching runs that missed the dx / dx/2 (fixed horizon) agreement, rerun with the
scene's coalescence bookkeeping:
``python validation/results/tipd_branching_subset.py OUT.json [coarse|fine|both|quarter] [KEY,...|all] [linear|lammps|none]``.

Each variant at dx = 0.5 mm (m = 3) and dx/2 (m = 6, the traction on the same 0.5 mm layer),
as in ``python -m validation tipd-branching --refine fixed-delta``; ``quarter`` is dx/4
(m = 12, the same horizon and loaded layer: one more step of the fixed-horizon refinement).
KEY (e.g. ``pmb_12MPa``, ``tipd_osb_24MPa``) picks variants; default all four (the last,
``tipd_tipd_24MPa``, is the pair that misses with the partial-volume rule). The last
argument is the partial-volume rule (default linear, the scene's; the stored
``tipd_branching_subset_{coarse,fine}.json`` were made with none)."""
import json
import sys
import time

import numpy as np

from upscale.experiments.scenes.tipd_branching import branching

VARIANTS = [("tipd", "osb", 24e6), ("tipd", "osb", 12e6), ("pmb", "tipd", 12e6), ("tipd", "tipd", 24e6)]
DX = 5e-4


def _key(mod, crit, sig):
    return f"{mod}{'_' + crit if mod == 'tipd' else ''}_{sig / 1e6:g}MPa"


def main(out, which="both", keys=None, partial_volume="linear"):
    res = []
    grids = {"coarse": [(DX, 3.0, None)], "fine": [(DX / 2, 6.0, DX)], "quarter": [(DX / 4, 12.0, DX)],
             "both": [(DX, 3.0, None), (DX / 2, 6.0, DX)]}[which]
    chosen = [v for v in VARIANTS if keys is None or _key(*v) in keys]
    if not chosen:
        raise SystemExit(f"no variant among {keys}; valid: {[_key(*v) for v in VARIANTS]}")
    for mod, crit, sig in chosen:
        for h, m, lw in grids:
            c0 = time.process_time()
            r = branching(mod, stress=sig, dx=h, m=m, critical=crit, load_width=lw,
                          partial_volume=None if partial_volume == "none" else partial_volume)
            keep = {k: r[k] for k in ("model", "critical", "stress_Pa", "dx_m", "horizon_m", "s0",
                                      "v_max_over_cR", "v_max_with_coalescence_over_cR", "v_mean_over_cR",
                                      "branching_t_s", "branching_x_m", "branch_angle_deg",
                                      "branch_origin_x_m", "asymmetry_fraction",
                                      "damaged_off_crack", "coalescence", "steps")}
            keep["cpu_s"] = time.process_time() - c0
            keep["critical"] = keep["critical"] if mod == "tipd" else None
            keep["tip_t_s"], keep["tip_x_m"] = r["tip_t_s"], r["tip_x_m"]
            res.append(keep)
            print(json.dumps({k: v for k, v in keep.items() if k not in ("tip_t_s", "tip_x_m", "coalescence")}),
                  flush=True)
            print("  coalescence:", [(round(c["t_s"] * 1e6, 2), c["particles"], c["advances_tip"],
                                      [round(v * 1e3, 2) for v in c["x_m"]], [round(v * 1e3, 2) for v in c["y_m"]])
                                     for c in r["coalescence"]], flush=True)
            with open(out, "w") as fh:
                json.dump(res, fh, default=float)


if __name__ == "__main__":
    np.seterr(all="ignore")
    main(sys.argv[1] if len(sys.argv) > 1 else "tipd_branching_subset.json",
         sys.argv[2] if len(sys.argv) > 2 else "both",
         sys.argv[3].split(",") if len(sys.argv) > 3 and sys.argv[3] != "all" else None,
         sys.argv[4] if len(sys.argv) > 4 else "linear")
