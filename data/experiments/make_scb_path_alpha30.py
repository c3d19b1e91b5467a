"""Writes data/experiments/scb_path_alpha30_ayatollahi2006.json from a clone of the public
repository floiseau/gcrack (Apache-2.0), file
examples/5_SCB_specimen_mixed_mode/reference/expe_beta_30.csv at commit 54a4794 (2024-08-06):
the experimental crack path of a PMMA SCB specimen with a 30 deg crack, digitised there from
Ayatollahi, Aliha and Hassani (2006). Usage: make_scb_path_alpha30.py PATH_TO_GCRACK_GIT_DIR"""
import csv
import io
import json
import subprocess
import sys
from pathlib import Path

git = sys.argv[1]
src = "examples/5_SCB_specimen_mixed_mode/reference/expe_beta_30.csv"
commit = "54a47941ec5e6ea5e19c7e130439deccddb3da41"
text = subprocess.run(["git", "--git-dir", git, "show", f"{commit}:{src}"], check=True, capture_output=True,
                      text=True).stdout
rows = list(csv.DictReader(io.StringIO(text)))
out = {
    "provenance": {
        "source": "Ayatollahi M.R., Aliha M.R.M., Hassani M.M. (2006), Mixed mode brittle fracture in PMMA - an "
                  "experimental study using SCB specimens, Materials Science and Engineering A 417, 348-356: "
                  "the fractured specimen with a 30 deg crack (its first point lies 0.27 mm from the tip of a "
                  "15 mm crack at 30 deg, the geometry of seed 004 sec. 6.6 in the scene's frame)",
        "digitised_by": "F. Loiseau, public repository github.com/floiseau/gcrack (Apache License 2.0), "
                        f"{src} at commit {commit}",
        "protocol": "the crack path from the specimen photograph, digitised point by point; x across the "
                    "specimen, y up from the middle of the flat edge, metres; the first point is the pre-crack "
                    "tip, the last the load point",
        "script": "data/experiments/make_scb_path_alpha30.py",
        "retrieved": "2026-12-06",
    },
    "alpha_deg": 30.0,
    "x_m": [float(r["xc_1"]) for r in rows],
    "y_m": [float(r["xc_2"]) for r in rows],
}
Path(__file__).with_name("scb_path_alpha30_ayatollahi2006.json").write_text(json.dumps(out, indent=1) + "\n")
