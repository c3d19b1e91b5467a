"""An ASE calculator of the coarse tube model.

:class:`DCBRCalculator` wraps :class:`upscale.models.dcbr.model.DCBRModel` (with
``shifts="relaxed"``): the ``Atoms`` are the model's rows, its non-slave coarse particles
(mass: max(w_c, N_c / 2) carbon masses) then the free atoms of its atomistic regions (one
carbon mass each), as :func:`dcbr_atoms` builds them. At every new configuration the
sublattice shifts delta (massless internal degrees of freedom) are relaxed at fixed rows,
warm started from the last ones, so the energy is the relaxed coarse energy

    E*(y) = min_delta E(y, delta)

and the forces its exact negative gradient, -dE*/dy = -dE/dy at the relaxed shifts (the
envelope theorem: dE/d delta = 0 there). A tube periodic along z takes its period from the
cell's third vector (``cell[2, 2]``, Å); ``calc.axial_force`` is dE*/dL (eV/Å) at fixed
rows (with a ghost-force load, at the load prepared for this period: the load's own
dependence on L is not differentiated, :mod:`upscale.models.dcbr.ghost`). No stress is
offered (a tube in vacuum has no volume). Units: eV, Å.

    model = DCBRModel(vacancy(swcnt(10, 10, 60.0)), 2.0)
    atoms = dcbr_atoms(model)
    atoms.calc = DCBRCalculator(model)
    atoms.get_potential_energy(), atoms.get_forces()
"""
from __future__ import annotations

import numpy as np
from ase import Atoms
from ase.calculators.calculator import Calculator, all_changes

__all__ = ["DCBRCalculator", "dcbr_atoms"]


def dcbr_atoms(model) -> Atoms:
    """The rows of ``model`` (a :class:`~upscale.models.dcbr.model.DCBRModel`) at its
    reference as ASE Atoms: positions ``model.x0`` (Å), masses in amu, the cell and
    periodicity of the atoms the model was built from (a periodic tube's period
    ``model.Lz`` on the cell's third vector); ``info["rows"]``: the particle rows then
    the free atoms' count."""
    a = Atoms("C" * model.n, positions=model.x0, cell=model.atoms.cell.copy(),
              pbc=model.atoms.pbc.copy())
    if model.Lz is not None:
        cell = np.array(a.cell)
        cell[2] = [0.0, 0.0, model.Lz]
        a.set_cell(cell, scale_atoms=False)
    a.set_masses(model.masses() * model.unit)
    nf = 0 if model.coupling is None else model.coupling.nf
    a.info["rows"] = {"particles": model.n - nf, "atoms": nf}
    return a


class DCBRCalculator(Calculator):
    """ASE calculator of a coarse tube (module docstring).

    Parameters
    ----------
    model : upscale.models.dcbr.model.DCBRModel
        Built with ``shifts="relaxed"`` (the default); it is called with the Atoms'
        positions as its rows (the calculator keeps its own state: shifts, links).
    """

    implemented_properties = ["energy", "free_energy", "forces"]
    default_parameters: dict = {}

    def __init__(self, model, **kwargs):
        if getattr(model, "shifts", None) != "relaxed":
            raise ValueError(f"DCBRCalculator of a model with shifts="
                             f"{getattr(model, 'shifts', None)!r}; valid: a DCBRModel with "
                             "shifts='relaxed' (massless shifts relaxed at every call)")
        super().__init__(**kwargs)
        from upscale.engine.state import State  # noqa: PLC0415

        self.model = model
        self.state = State.reference(np.array(model.x0, dtype=float), 0)
        model.init_state(self.state)
        self.axial_force = None

    def calculate(self, atoms=None, properties=("energy",), system_changes=all_changes):
        super().calculate(atoms, properties, system_changes)
        m = self.model
        if len(self.atoms) != m.n:
            raise ValueError(f"the Atoms have {len(self.atoms)} rows; valid: the model's "
                             f"{m.n} (its non-slave particles, then its free atoms: "
                             "dcbr_atoms(model))")
        if m.Lz is not None:
            L = float(self.atoms.cell[2, 2])
            if L != m.Lz:
                m.set_cell(L)
        st = self.state
        st.y = np.array(self.atoms.get_positions(), dtype=float)
        E = m.energy(st)  # (the shifts relaxed in st.extra, warm started)
        f = np.zeros_like(st.y)
        m.add_force(st, f)
        self.axial_force = m.cell_force(st) if m.Lz is not None else None
        self.results["energy"] = float(E)
        self.results["free_energy"] = float(E)
        self.results["forces"] = f
