"""The seed-spread comparison case (validation.cases.seeds): arithmetic and input checks."""
import argparse
import json

import numpy as np
import pytest

from validation.cases.references import REF_DIR
from validation.registry import discover


def _run(tmp_path, coarse: dict, pristine: bool):
    f = tmp_path / "coarse.json"
    f.write_text(json.dumps({"result": coarse}))
    args = argparse.Namespace(coarse=[f], pristine=pristine, quick=False, outdir=tmp_path)
    return discover()["seeds-extensometer"].run(args)


def _coarse(pristine, strengths):
    runs = [{"seed": 1000 + i, "strength_GPa": s, "strain_at_peak": 0.2,
             "youngs_modulus_TPa": 1.0, "strain_at_peak_ext": 0.2,
             "youngs_modulus_ext_TPa": 1.0} for i, s in enumerate(strengths)]
    return {"coarsening": 2.0, "pristine": pristine, "tubes": {"10,10": {"runs": runs, "stats": {
        k: {"mean": float(np.mean([r[k] for r in runs])), "sd": 0.0}
        for k in runs[0] if k != "seed"}}}}


@pytest.mark.parametrize("pristine,name", [(False, "seed_spread.json"),
                                           (True, "seed_spread_pristine.json")])
def test_seed_means_are_compared_with_the_matching_lammps_spread(tmp_path, pristine, name):
    out = _run(tmp_path, _coarse(pristine, [100.0, 110.0]), pristine)
    ref = json.loads((REF_DIR / name).read_text())["tubes"]["10,10"]["runs"]
    lam = np.mean([r["strength_GPa"] for r in ref])
    (row,) = out["rows"]
    assert row["strength_err_%"] == pytest.approx(100.0 * (105.0 - lam) / lam, rel=1e-12)
    assert row["seeds_lammps"] == len(ref) and out["lammps_file"].endswith(name)


def test_a_pristine_run_is_not_compared_with_the_vacancy_spread(tmp_path):
    with pytest.raises(SystemExit, match="pristine run; valid: vacancy runs"):
        _run(tmp_path, _coarse(True, [100.0]), pristine=False)
