"""LAMMPS's full-atomistic (10,10) 7-tube vacancy bundle, the references' dynamic protocol and
seed, pulled to 16 % strain: wall and CPU time of the same run length as the engine runs."""
import json, os, time
from validation.cases.references import build_structure, _spec
from upscale.experiments.lammps.tension import dynamic_tension
spec = _spec("dynamic", 10, 10, True, 150.0, ntubes=7)
atoms = build_structure(spec)
l0 = os.getloadavg()
res = dynamic_tension(atoms, "tersoff:BNC.tersoff", cutoff="step", max_strain=0.16)
out = {k: res[k] for k in ("wall_s", "cpu_s", "timing_s", "strength_GPa", "youngs_modulus_TPa",
                           "strain_at_peak", "load_avg_end")}
out["load_avg_start"] = list(l0)
out["max_strain"] = 0.16
out["n_samples"] = len(res["curve"]["strain"])
json.dump(out, open("validation/out/lammps_timing_10-10_bundle7.json", "w"), indent=1)
print(out)
