"""Run the pre-cracked plate for a number of steps and save the whole body's displacements
and bond states (rank 0 writes them): ``python tests/parallel_plate_run.py MODEL N STEPS
OUT.npz [WORKDIR CHECKPOINT_EVERY]``, alone or under ``mpiexec -n K``. With a workdir it
checkpoints there and resumes from it (the restart tests kill it and start it again).
``MODEL`` as ``lean:pmb``: the plate of :func:`lean_plate` (each rank builds its rows)."""
import sys

import numpy as np

from upscale.engine.checkpoint import Checkpoint
from upscale.experiments.scenes.plate import PlateScene


def lean_plate(n, model, thermostat=None):
    """The :class:`PlateScene` plate's simulation with its family as a
    :class:`~upscale.engine.families.FamilyRecipe` (the pre-crack as bonds broken at the
    start): on several ranks each rank builds its own rows only."""
    from upscale import models
    from upscale.engine import Simulation, bonds_crossing_segment, square_lattice
    from upscale.engine.conditions import Velocity, region
    from upscale.engine.families import FamilyRecipe
    from upscale.engine.integrators import VelocityVerlet
    from upscale.experiments.scenes import plate as P

    h = P.L_PLATE / n
    system = square_lattice(n, n, h, thickness=h, density=P.RHO, plane="stress", centered=True)
    cut = bonds_crossing_segment(system.x0, (-P.CRACK / 2, 0.0), (P.CRACK / 2, 0.0))
    cls = models.get(model)
    mdl = cls(E=P.E_PLATE, s0=P.S0) if model == "pmb" else cls(E=P.E_PLATE, nu=1 / 3, s0=P.S0)
    L = P.L_PLATE
    top = region(system, "top rows", box=((None, L / 2 - 3 * h, None), (None, None, None)))
    bottom = region(system, "bottom rows", box=((None, None, None), (None, -L / 2 + 3 * h, None)))
    conds = [Velocity(top, (0.0, P.V_EDGE, 0.0), components=(1,)),
             Velocity(bottom, (0.0, -P.V_EDGE, 0.0), components=(1,))]
    return Simulation(system, FamilyRecipe(system, 3.015 * h, broken=cut), mdl, conds,
                      integrator=VelocityVerlet(thermostat=thermostat))


def main(argv):
    model, n, steps, out = argv[0], int(argv[1]), int(argv[2]), argv[3]
    lean = model.startswith("lean:")
    sim = lean_plate(n, model[5:]) if lean else PlateScene(n, model=model).sim
    ck = None
    if len(argv) > 4:
        ck = Checkpoint(f"{argv[4]}/checkpoint.npz", every=int(argv[5]))
        if sim.resume(ck.path):
            sim.prepare()
            ck.last_step = sim.state.step
    info = sim.run(max(0, steps - sim.state.step), checkpoint=ck)
    u = sim.gather(sim.state.u)
    intact = sim.state.intact if sim.part is None else sim.part.gather_bonds(sim.state.intact)
    agree = True
    if sim.part is not None:
        from upscale.engine.parallel import bond_states_agree

        agree = bond_states_agree(sim.part.comm, sim.part.local, sim.state.intact)
    ke, energy = sim.kinetic_energy(), sim.energy()
    if sim.part is None or sim.part.rank == 0:
        np.savez(out, u=u, intact=intact, ke=ke, energy=energy, broken=info["broken_bonds"],
                 agree=agree, ranks=1 if sim.part is None else sim.part.size)


if __name__ == "__main__":
    main(sys.argv[1:])
