"""The alpha = 30 deg crack path of `upscale scb` runs against the experimental path of Ayatollahi
et al. (2006) (data/experiments/scb_path_alpha30_ayatollahi2006.json): horizontal offsets at the
experiment's heights and an overlay plot next to each scb.json.
Usage: path30.py OUTDIR [...]   (each OUTDIR written by `upscale scb --alpha 30 ... --out OUTDIR`)

Run from the repository root with PYTHONPATH=$PWD (diagnostic behind validation/results/scb.md)."""
import json
import sys
from pathlib import Path

import numpy as np

from validation.cases.scb import path_offset, path_png

for d in map(Path, sys.argv[1:]):
    r = json.loads((d / "scb.json").read_text())
    dx = r["scene"]["dx_m"]
    pts = np.asarray(r["crack_path_m"])
    y, xe, xm, off = path_offset(pts, dx)
    mean, mx = np.nanmean(np.abs(off)) * 1e3, np.nanmax(np.abs(off)) * 1e3
    path_png(d / "scb_path_vs_experiment.png", None, None, pts,
             f"alpha = 30 deg, dx = {dx * 1e3:g} mm: mean |offset| {mean:.2f} mm")
    print(json.dumps({"dir": str(d), "dx_mm": dx * 1e3, "path_points": len(pts), "heights": int(np.isfinite(off).sum()),
                      "of": len(off), "offset_mm_mean": round(mean, 3), "offset_mm_max": round(mx, 3),
                      "y_mm": [round(v * 1e3, 1) for v in y], "offset_mm": [round(v * 1e3, 2) for v in off]}))
