"""Output every N steps: extxyz (ase.io), VTK (meshio) and a JSON summary.

* ``traj.extxyz``: one frame per output step, written through :func:`ase.io.write`, with
  per-particle arrays ``displacement`` (3), ``velocity`` (3, m/s), ``damage`` and
  ``volume``, for every field of the generalised degrees of freedom
  (:mod:`upscale.engine.fields`, e.g. rotations ``rot``) its values ``<name>`` and rates
  ``<name>_rate`` (the field's unit, per second), and ``time``/``step`` in the frame info:
  ASE and OVITO read it. ASE writes
  real columns with a fixed ``%16.8f``, which would round SI lengths of a millimetre-sized
  body to 1e-8 m; positions, displacements and volumes are therefore written in a length
  unit ``length_unit_m`` (a power of ten putting the spacing in [1000, 10000): 1e-8 of a
  unit is then 1e-11 of a spacing; recorded in every frame's info), e.g. 1e-7 m for a
  0.1 mm spacing.
* ``vtk/frame_NNNNNN.vtu``: points with the same point data, through meshio (ParaView).
* On several MPI ranks (:mod:`upscale.engine.parallel`): ``traj.extxyz`` holds the whole
  body, gathered on rank 0 (on request: leave ``"extxyz"`` out of ``formats`` for large
  runs); VTK is parallel, each rank writing its owned particles to
  ``vtk/frame_NNNNNN_<rank>.vtu`` and rank 0 the ``vtk/frame_NNNNNN.pvtu`` that lists
  them (ParaView opens the ``.pvtu``); the JSON summary is rank 0's, of global sums.
* ``summary.json``: the run's description and one row per output step (time, kinetic
  energy of translations and fields, the fields' part of it, strain energy if asked,
  broken bonds, max damage), rewritten atomically.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from upscale.io import write_json

__all__ = ["Output", "FORMATS"]

FORMATS = ("extxyz", "vtk", "json")


class Output:
    """Write the state every ``every`` steps to ``outdir``.

    Parameters
    ----------
    outdir : path
    every : int
        Output interval in steps.
    formats : iterable of {"extxyz", "vtk", "json"}
    energy : bool
        Evaluate the strain energy at output steps (costs one energy pass per output).
    """

    def __init__(self, outdir, every: int = 100, formats=FORMATS, energy: bool = False,
                 symbol: str = "X", length_unit: float | None = None):
        if int(every) < 1:
            raise ValueError(f"output interval must be >= 1 step, got {every!r}")
        bad = [f for f in formats if f not in FORMATS]
        if bad:
            raise ValueError(f"unknown output format {bad[0]!r}; valid: {', '.join(FORMATS)}")
        self.outdir = Path(outdir)
        self.every = int(every)
        self.formats = tuple(formats)
        self.energy = bool(energy)
        self.symbol = symbol
        self.length_unit = length_unit
        self.rows: list[dict] = []
        self.meta: dict = {}
        self._started = False

    def start(self, sim) -> None:
        """Prepare the directory (a resumed run appends to its trajectory)."""
        self.outdir.mkdir(parents=True, exist_ok=True)
        if "vtk" in self.formats:
            (self.outdir / "vtk").mkdir(exist_ok=True)
        traj = self.outdir / "traj.extxyz"
        if "extxyz" in self.formats and sim.state.step == 0 and traj.exists() and _root(sim):
            traj.unlink()  # a fresh run starts a fresh trajectory
        self.meta = sim.describe()
        if self.length_unit is None:
            self.length_unit = float(10.0 ** (np.floor(np.log10(sim.system.spacing)) - 3))
        self.meta["extxyz_length_unit_m"] = self.length_unit
        self._started = True

    def write(self, sim) -> dict:
        if not self._started:
            self.start(sim)
        st = sim.state
        part = getattr(sim, "part", None)
        mu = sim.damage()
        top = float(mu.max()) if mu.size else 0.0
        if part is not None:  # every call below is collective on several ranks
            top = float(part.comm.allreduce_max(float(mu[part.owned].max())))
        row = {"step": int(st.step), "time_s": float(st.t),
               "kinetic_energy_J": float(sim.kinetic_energy()),
               "field_kinetic_energy_J": _field_ke(sim),
               "broken_bonds": sim.broken_bonds() if part is not None
               else int(st.intact.size - np.count_nonzero(st.intact)),
               "max_damage": top}
        if self.energy:
            row["strain_energy_J"] = float(sim.energy())
        u = st.u
        if "extxyz" in self.formats:
            if part is None:
                self._extxyz(st.y, u, st.v, mu, sim.system.volume, st)
            else:
                a = [part.gather(x) for x in (st.y, u, st.v, mu, sim.system.volume)]
                if part.rank == 0:
                    self._extxyz(*a, st)
        if "vtk" in self.formats:
            if part is None:
                self._vtk(sim, u, mu)
            else:
                self._pvtu(sim, u, mu, part)
        self.rows.append(row)
        if "json" in self.formats and _root(sim):
            write_json(self.outdir / "summary.json", {"run": self.meta, "frames": self.rows})
        return row

    def _extxyz(self, y, u, v, mu, volume, st):
        import ase
        import ase.io

        k = 1.0 / self.length_unit
        atoms = ase.Atoms(symbols=[self.symbol] * y.shape[0], positions=y * k, pbc=False)
        atoms.new_array("displacement", u * k)
        atoms.new_array("velocity", v.copy())
        atoms.new_array("damage", mu)
        atoms.new_array("volume", volume * k ** 3)
        for name, val, rate in _fields(st):
            atoms.new_array(name, val)
            atoms.new_array(name + "_rate", rate)
        atoms.info["length_unit_m"] = self.length_unit
        atoms.info["time"] = float(st.t)
        atoms.info["step"] = int(st.step)
        ase.io.write(self.outdir / "traj.extxyz", atoms, format="extxyz", append=True)

    def _vtk(self, sim, u, mu):
        import meshio

        st = sim.state
        n = st.y.shape[0]
        pdata = {"displacement": u, "velocity": st.v, "damage": mu, "volume": sim.system.volume}
        for name, val, rate in _fields(st):
            pdata[name], pdata[name + "_rate"] = val, rate
        mesh = meshio.Mesh(st.y, [("vertex", np.arange(n).reshape(-1, 1))], point_data=pdata)
        mesh.write(self.outdir / "vtk" / f"frame_{st.step:06d}.vtu")


    def _pvtu(self, sim, u, mu, part):
        """This rank's owned particles as a ``.vtu`` piece; rank 0 writes the ``.pvtu``
        that lists every rank's piece (the arrays declared as in the pieces)."""
        import meshio

        st, own = sim.state, part.owned
        pdata = {"displacement": u[own], "velocity": st.v[own], "damage": mu[own],
                 "volume": sim.system.volume[own]}
        n = int(own.sum())
        stem = f"frame_{st.step:06d}"
        mesh = meshio.Mesh(st.y[own], [("vertex", np.arange(n).reshape(-1, 1))], point_data=pdata)
        mesh.write(self.outdir / "vtk" / f"{stem}_{part.rank}.vtu")
        if part.rank == 0:
            arrays = "".join(f'      <PDataArray type="Float64" Name="{k}" NumberOfComponents='
                             f'"{1 if v.ndim == 1 else v.shape[1]}"/>\n' for k, v in pdata.items())
            pieces = "".join(f'    <Piece Source="{stem}_{r}.vtu"/>\n' for r in range(part.size))
            text = ('<?xml version="1.0"?>\n<VTKFile type="PUnstructuredGrid" version="0.1" '
                    'byte_order="LittleEndian">\n  <PUnstructuredGrid GhostLevel="0">\n'
                    f'    <PPointData>\n{arrays}    </PPointData>\n    <PPoints>\n'
                    '      <PDataArray type="Float64" NumberOfComponents="3"/>\n    </PPoints>\n'
                    f'{pieces}  </PUnstructuredGrid>\n</VTKFile>\n')
            (self.outdir / "vtk" / f"{stem}.pvtu").write_text(text)


def _root(sim) -> bool:
    part = getattr(sim, "part", None)
    return part is None or part.rank == 0


def _fields(st):
    """(name, values (N, k), rates (N, k)) of the state's fields, copies."""
    fv = getattr(st, "field_v", {}) or {}
    return [(k, np.array(v, dtype=float), np.array(fv.get(k, np.zeros_like(v)), dtype=float))
            for k, v in (getattr(st, "fields", {}) or {}).items()]


def _field_ke(sim) -> float:
    from upscale.engine.fields import field_kinetic_energy

    return float(field_kinetic_energy(sim))
