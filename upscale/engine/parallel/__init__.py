"""One simulation over MPI ranks: a fixed decomposition of the reference configuration,
halo lists from the families and the exchange of halo rows.

``comm`` (the world communicator; mpi4py only under an MPI launcher), ``decomposition``
(recursive coordinate bisection weighted by bonds), ``halo`` (a rank's particles, rows
and exchange lists), ``partition`` (a simulation's body split: :func:`localize`).
:class:`~upscale.engine.simulation.Simulation` splits its body itself when the world has
several ranks, so a script or a scene runs unchanged under ``mpiexec -n N``.
"""
from upscale.engine.parallel.comm import launched_by_mpi, world
from upscale.engine.parallel.decomposition import balance, rcb
from upscale.engine.parallel.halo import Local, bond_states_agree, build_local
from upscale.engine.parallel.partition import Partition, halo_depth, localize, rank_path

__all__ = ["world", "launched_by_mpi", "rcb", "balance", "Local", "build_local",
           "bond_states_agree", "Partition", "localize", "halo_depth", "rank_path"]
