"""Analysis of tension runs: stress with the wall-thickness convention (:mod:`.stress`),
damage index, crack position and angle on the unrolled tube surface (:mod:`.damage`, reads
LAMMPS dumps with MDAnalysis), and matplotlib plots (:mod:`.plots`)."""
from upscale.analysis.damage import (bond_network, crack_line, damage_index, dump_damage,
                                     read_dump, unroll)
from upscale.analysis.stress import (WALL_THICKNESS, curve_metrics, stress_from_force,
                                     stress_from_pressure, wall_area)

__all__ = ["WALL_THICKNESS", "wall_area", "stress_from_pressure", "stress_from_force",
           "curve_metrics", "bond_network", "damage_index", "unroll", "crack_line",
           "read_dump", "dump_damage"]
