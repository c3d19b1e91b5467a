"""The LAMMPS runners' public names in one place (their implementations are split by
protocol): tension of tubes and bundles, and the other quasi-static loads.

* :mod:`upscale.experiments.lammps.setup`: the LAMMPS instance, the minimisers
  (:class:`MinSettings`), the zero-stress relaxation every run starts from
  (:func:`relax_zero_stress`), the common part of the records;
* :mod:`upscale.experiments.lammps.quasistatic`: quasi-static tension and compression of
  a periodic tube or bundle through its cell (:func:`quasi_static_tension`,
  :func:`quasi_static_compression`);
* :mod:`upscale.experiments.lammps.torsion`: quasi-static torsion of an open tube between
  rigid grips (:func:`quasi_static_torsion`);
* :mod:`upscale.experiments.lammps.dynamic`: dynamic tension of an open tube or bundle
  pulled by its grips (:func:`dynamic_tension`), its set-up alone
  (:func:`open_tube_setup`) and the static stiffness of its grips
  (:func:`static_grip_stiffness`).

Units ``metal`` (Å, eV, ps, bar); stresses in GPa with the wall-thickness convention of
:mod:`upscale.analysis.stress`. :func:`upscale.experiments.lammps.run` runs any of them from
a protocol object (:mod:`upscale.experiments.protocols`).
"""
from __future__ import annotations

from upscale.experiments.lammps.dynamic import (dynamic_tension, open_tube_setup,
                                                static_grip_stiffness)
from upscale.experiments.lammps.quasistatic import (quasi_static_compression,
                                                    quasi_static_tension)
from upscale.experiments.lammps.setup import (CARBON_MASS, MIN_NORMS, SETUP_MIN_STYLES,
                                              MinSettings, default_dump_dir,
                                              extensometer_commands, per_tube_grip_commands,
                                              relax_zero_stress)
from upscale.experiments.lammps.torsion import quasi_static_torsion

__all__ = ["relax_zero_stress", "quasi_static_tension", "quasi_static_compression",
           "quasi_static_torsion", "dynamic_tension", "default_dump_dir",
           "static_grip_stiffness", "CARBON_MASS", "MinSettings", "SETUP_MIN_STYLES",
           "MIN_NORMS", "open_tube_setup", "extensometer_commands", "per_tube_grip_commands"]
