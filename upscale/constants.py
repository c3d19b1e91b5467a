"""Physical constants and unit conversions, defined once for the whole project.

SI values are CODATA 2018 (exact where the SI defines them). The GPa-per-eV/Å^3 factor
keeps the CODATA 2014 elementary charge with which every stored tube result was computed
(it differs from the 2018 value by 1.6e-9 relative, far below any reported digit).
"""
from __future__ import annotations

__all__ = ["K_B_SI", "K_B_EV", "EV_J", "AMU_KG", "CARBON_MASS_AMU", "EV_PER_A3_IN_GPA",
           "WALL_THICKNESS_A", "ASE_TIME_FS", "ACC_EV_A_AMU_IN_A_FS2"]

#: Boltzmann constant, J/K (exact)
K_B_SI = 1.380649e-23
#: Boltzmann constant, eV/K
K_B_EV = 8.617333262e-5
#: electronvolt in J (exact)
EV_J = 1.602176634e-19
#: atomic mass unit (dalton) in kg
AMU_KG = 1.66053906660e-27
#: carbon, standard atomic weight (amu), the mass of one atom in every carbon model
CARBON_MASS_AMU = 12.011
#: 1 eV/Å^3 in GPa (CODATA 2014 e, see the module docstring)
EV_PER_A3_IN_GPA = 160.21766208
#: wall thickness of a single-wall carbon tube for its stress (graphite interlayer spacing), Å
WALL_THICKNESS_A = 3.4
#: the time unit of eV, Å, amu (ASE's, Å sqrt(amu/eV)) in fs
ASE_TIME_FS = 10.1805055
#: acceleration of 1 eV/Å on 1 amu, in Å/fs^2
ACC_EV_A_AMU_IN_A_FS2 = EV_J / (1e-10 * AMU_KG) * 1e-20
