"""Before/after table of dcbr-seeds results (old-result flags removed): per tube the seed
means before and after, and each against LAMMPS's seed mean (data/reference/seed_spread.json,
or the one stored seed data/reference/dyn_N-M_vac4.json for a tube not in the spread).

    python validation/results/noflags_compare.py OLD.json NEW.json [OLD.json NEW.json ...]
"""
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
REF = ROOT / "data" / "reference"
KEYS = (("strength_GPa", "strength"), ("youngs_modulus_TPa", "E_grip"),
        ("strain_at_peak", "eps_peak"))


def _load(p):
    d = json.loads(Path(p).read_text())
    return d.get("result", d)


def _lammps(tube):
    spread = _load(REF / "seed_spread.json")["tubes"]
    if tube in spread:
        return {k: spread[tube]["stats"][k]["mean"] for k, _ in KEYS}, len(spread[tube]["runs"])
    one = _load(REF / f"dyn_{tube.replace(',', '-')}_vac4.json")
    return {k: one[k] for k, _ in KEYS}, 1


def main(argv):
    if len(argv) % 2:
        raise SystemExit("give pairs OLD.json NEW.json")
    print("| tube | K | seeds | LAMMPS seeds | " + " | ".join(
        f"{s} old -> new (vs LAMMPS old / new %)" for _, s in KEYS) + " |")
    print("|---" * (4 + len(KEYS)) + "|")
    for a, b in zip(argv[::2], argv[1::2]):
        old, new = _load(a), _load(b)
        for tube, v in new["tubes"].items():
            ref, nref = _lammps(tube)
            cells = []
            for k, _ in KEYS:
                o = old["tubes"][tube]["stats"][k]["mean"]
                n = v["stats"][k]["mean"]
                r = ref[k]
                cells.append(f"{o:.5g} -> {n:.5g} ({100 * (o - r) / r:+.2f} / "
                             f"{100 * (n - r) / r:+.2f})")
            print(f"| ({tube}) | {new['coarsening']:g} | {len(v['runs'])} | {nref} | "
                  + " | ".join(cells) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
