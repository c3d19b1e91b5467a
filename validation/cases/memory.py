"""bench-memory: bytes kept per directed bond by the pair models on a 2D plate.

For PMB, LPS, Ti-PD, NOSB (correspondence) and CPD, each at its default settings on one
square plate (horizon 3.015 spacings, 28 bonds per bulk particle), the case builds the
family, prepares the model, evaluates one force (so buffers made on first use are
there) and counts the bytes of every numpy buffer the family and the model keep
(:func:`upscale.engine.memory.bytes_per_bond`; the system's positions and volumes are
not charged), plus the run's per-bond state: the engine's bond state ``intact`` (bool, 1
byte per directed bond) and what a model keeps in ``state.extra`` (CPD: one bool per
triplet and quadruplet). Target (issue 53): the per-bond buffers at most 16 bytes per
bond plus that state (``bytes_per_bond_*``). The per-particle buffers (row pointers,
LPS's weighted volumes, the correspondence tensors of NOSB and of Ti-PD's surface
correction) are reported beside it, spread over the bonds (``all_kept_bytes_per_bond_*``):
at this horizon (28 bonds per particle) they are a large share for NOSB and Ti-PD, at
m = 6 or 12 about a quarter or a sixteenth of it.
"""
from __future__ import annotations


from validation.registry import case, table

E, NU, GC = 70e9, 1.0 / 3.0, 8.0
SPACING = 1e-3


def _models(horizon):
    from upscale.models.bond_based import PMB
    from upscale.models.correspondence import Correspondence
    from upscale.models.cpd import CPD
    from upscale.models.state_based import LPS
    from upscale.models.tipd import TiPD

    return {
        "pmb": (lambda: PMB(E=E, nu=NU, Gc=GC), "intact (bool per bond)"),
        "lps": (lambda: LPS(E=E, nu=NU, Gc=GC), "intact (bool per bond)"),
        "tipd": (lambda: TiPD(E=E, nu=NU), "intact (bool per bond)"),
        "nosb": (lambda: Correspondence(E=E, nu=NU), "intact (bool per bond)"),
        "cpd": (lambda: CPD(horizon=horizon, dim=2, E=E, nu=NU),
                "intact (bool per bond) + bool per triplet and quadruplet"),
    }


def measure(cells: int) -> list[dict]:
    """One row per model: bonds, and bytes per bond kept in per-bond buffers, in
    per-particle buffers, and in the run's bond state
    (:func:`upscale.engine.memory.bytes_per_bond`)."""
    from upscale.engine import State, build_family, square_lattice
    from upscale.engine.memory import bytes_per_bond

    s = square_lattice(cells, cells, SPACING, thickness=SPACING)
    horizon = 3.015 * SPACING
    rows = []
    for name, (make, state_name) in _models(horizon).items():
        fam = build_family(s, horizon)
        m = make()
        m.prepare(s, fam)
        st = State.reference(s.x0, fam.nb)
        m.init_state(st)
        m.force(st)
        b = bytes_per_bond(s, fam, [m], st)
        rows.append({"model": name, "bonds": fam.nb, "bond_B": b["bond"], "state_B": b["state"],
                     "bond+state_B": b["bond"] + b["state"], "target_B": 16.0 + b["state"],
                     "per_particle_B": b["particle"], "all_kept_B": b["total"], "state": state_name})
    return rows


def _args(p):
    p.add_argument("--cells", type=int, default=None,
                   help="particles per side of the plate (default 120: 403k bonds; quick 60)")


@case("bench-memory", "bytes kept per bond by PMB, LPS, Ti-PD, NOSB and CPD on a 2D plate "
      "(target: at most 16 plus the model's per-bond state)", add_arguments=_args)
def bench_memory(args):
    from upscale.engine.kernels import set_threads

    set_threads(1)
    cells = args.cells or (60 if args.quick else 120)
    rows = measure(cells)
    print(table(rows, floatfmt=".2f"))
    out = {"plate_particles": cells * cells, "bonds": rows[0]["bonds"]}
    ok = True
    for r in rows:
        m = r["model"]
        out[f"bytes_per_bond_{m}"] = round(r["bond+state_B"], 3)
        out[f"state_bytes_per_bond_{m}"] = round(r["state_B"], 3)
        out[f"all_kept_bytes_per_bond_{m}"] = round(r["all_kept_B"], 3)
        ok &= r["bond+state_B"] <= r["target_B"]
    out["pass"] = bool(ok)
    return out

