"""Run the pre-cracked plate for a number of steps and save the whole body's displacements
and bond states (rank 0 writes them): ``python tests/parallel_plate_run.py MODEL N STEPS
OUT.npz [WORKDIR CHECKPOINT_EVERY]``, alone or under ``mpiexec -n K``. With a workdir it
checkpoints there and resumes from it (the restart tests kill it and start it again)."""
import sys

import numpy as np

from upscale.engine.checkpoint import Checkpoint
from upscale.experiments.scenes.plate import PlateScene


def main(argv):
    model, n, steps, out = argv[0], int(argv[1]), int(argv[2]), argv[3]
    sim = PlateScene(n, model=model).sim
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
