"""Where the coarse set-up's time goes, and which criterion its minimiser really meets.

``upscale.models.dcbr_dynamic.open_tube_with_grips`` on the seed-scale vacancy tubes of
``bench-dcbr-seed`` ((50,50) coarsening 3, (30,60) coarsening 4, clamped grips), with every
L-BFGS-B call of ``DCBRTube.minimise`` recorded (wall time, iterations, evaluations,
scipy's stopping message, and at the returned state: the largest gradient component over
the free positions, over the projected shift gradient, and the ``max_force_eV_A`` the
model reports, which includes the components the set-up holds fixed). The rest of the
set-up time is the damped-dynamics cycles of ``DCBRDefectTube.minimise``
(``step_crossing="damped"``), which run while that reported value exceeds 1e-4 eV/Å.

    cd /work/wt/sNN && PYTHONPATH=$PWD NUMBA_NUM_THREADS=1 python \
        validation/results/coarse_setup_profile.py [out.json]
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np


def main(out_path="validation/results/coarse_setup_profile.json"):
    import upscale.models.dcbr as dcbr
    from upscale.io import versions, write_json
    from upscale.models import dcbr_dynamic as dd
    from validation.cases.dcbr import dynamic_scene, lammps_reference_or_run
    from validation.cases.references import DYN_LENGTH

    base = dcbr.DCBRTube.minimise
    calls = []

    def recorded(self, y, delta, Lz, relax_box=False, gtol=1e-6, maxiter=5000, fixed=None):
        t = time.perf_counter()
        out = base(self, y, delta, Lz, relax_box, gtol, maxiter, fixed)
        wall = time.perf_counter() - t
        _, gy, gd, _ = self.energy_and_gradient(out[0], out[1], Lz)
        free = np.ones_like(gy, bool) if fixed is None else ~np.asarray(fixed, bool)
        b, d = self.shift_bound, out[1]
        gdp = np.where(((d <= -b) & (gd > 0)) | ((d >= b) & (gd < 0)), 0.0, gd)
        info = out[4]
        calls.append({"wall_s": wall, "gtol": gtol, "nit": info["nit"], "nfev": info["nfev"],
                      "message": info["message"],
                      "max_free_position_gradient_eV_per_A": float(np.abs(gy[free]).max()),
                      "max_projected_shift_gradient_eV_per_A": float(np.abs(gdp).max()),
                      "reported_max_force_eV_per_A": info["max_force_eV_A"]})
        return out

    dcbr.DCBRTube.minimise = recorded
    rows = []
    try:
        for n, m, K in ((50, 50, 3.0), (30, 60, 4.0)):
            calls.clear()
            ref = lammps_reference_or_run(n, m, DYN_LENGTH, vacancy=True, protocol="dynamic")
            model, dyn = dynamic_scene(n, m, DYN_LENGTH, K, ref, grips="clamped")
            t = time.perf_counter()
            dd.open_tube_with_grips(model, dyn["grip"], 1e-4, clamp=dyn.get("clamp"),
                                    planes=dyn.get("planes"),
                                    gauge_planes=dyn.get("gauge_planes"))
            wall = time.perf_counter() - t
            lbfgs = sum(c["wall_s"] for c in calls)
            rows.append({"tube": f"({n},{m})", "K": K, "setup_s": wall, "lbfgs_s": lbfgs,
                         "other_s": wall - lbfgs, "lbfgs_calls": list(calls),
                         "load_avg": list(os.getloadavg())})
            print(f"({n},{m}) K{K:g}: set-up {wall:.1f} s, of which L-BFGS-B {lbfgs:.1f} s "
                  f"({len(calls)} calls)", flush=True)
    finally:
        dcbr.DCBRTube.minimise = base
    write_json(out_path, {"rows": rows, "versions": versions()})
    return rows


if __name__ == "__main__":
    main(*sys.argv[1:])
