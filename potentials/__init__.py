"""Molecular side of upscale: carbon potentials (Tersoff, Brenner/REBO-I, Lennard-Jones)
as numba kernels and ASE calculators. Depends on nothing in :mod:`upscale`."""
