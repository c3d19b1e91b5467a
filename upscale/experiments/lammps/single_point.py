"""Single-point LAMMPS evaluations: energy, per-atom energies, forces and virial of any ASE
Atoms under given ``pair_style``/``pair_coeff`` lines (one ``run 0``), and the same figures
from an ASE calculator, to compare the project's potentials with LAMMPS's term by term.

    ref = evaluate(atoms, tersoff_pair_lines(lammps_potential_path("BNC.tersoff"), ["C"]))
    ours = evaluate_calculator(atoms, Tersoff.from_lammps("BNC.tersoff", elements=["C"]))
    errors(ours, ref)   # energy_rel_err, force_max_abs_err_eV_per_A, virial_rel_err, ...
"""
from __future__ import annotations

import numpy as np

__all__ = ["evaluate", "evaluate_calculator", "errors", "to_lammps_frame",
           "tersoff_pair_lines", "bundle_pair_lines"]

NKTV2P_METAL = 1.6021765e6  # LAMMPS force->nktv2p in metal units (eV/A^3 -> bar)


def to_lammps_frame(atoms, margin: float = 10.0):
    """Rotation and box that put ``atoms`` into a LAMMPS triclinic box.

    Non-periodic directions get vectors orthogonal to the periodic ones, long enough to hold
    every atom with ``margin`` Angstrom to spare (LAMMPS boundary ``f``).

    Returns
    -------
    Q : (3, 3) rotation, LAMMPS coordinates are ``x @ Q``
    box : dict with xhi, yhi, zhi, xy, xz, yz (lows are 0)
    x_lmp : (N, 3) positions in the box
    """
    from potentials.neighbours import complete_cell

    pbc = atoms.pbc
    x = atoms.positions.copy()
    full = complete_cell(atoms.cell.array, pbc)
    # wrap along periodic directions
    s = x @ np.linalg.inv(full)
    s[:, pbc] -= np.floor(s[:, pbc])
    # non-periodic directions: unit vectors scaled to the atoms' extent + 2 margins
    for d in range(3):
        if not pbc[d]:
            lo, hi = s[:, d].min(), s[:, d].max()
            length = hi - lo + 2 * margin
            s[:, d] = (s[:, d] - lo + margin) / length
            full[d] = full[d] * length
    x = s @ full
    # rotate so that a is along x and b in the xy plane: full = L @ Q.T, L lower triangular
    q, u = np.linalg.qr(full.T)
    sign = np.sign(np.diag(u))
    sign[sign == 0] = 1
    q = q * sign
    L = full @ q
    if np.linalg.det(q) < 0:
        raise ValueError("the cell is left-handed; LAMMPS needs a right-handed cell")
    box = {k: float(v) for k, v in dict(xhi=L[0, 0], yhi=L[1, 1], zhi=L[2, 2], xy=L[1, 0],
                                        xz=L[2, 0], yz=L[2, 1]).items()}
    return q, box, x @ q


def evaluate(atoms, pair_lines: list[str], types=None, masses=None) -> dict:
    """Energy, per-atom energies, forces and virial of ``atoms`` from LAMMPS (one run 0).

    Parameters
    ----------
    atoms : ase.Atoms
    pair_lines : list of str, e.g. ``["pair_style tersoff", "pair_coeff * * BNC.tersoff C"]``
    types : (N,) int, LAMMPS atom types (1-based); default: 1 for all
    masses : masses per type (irrelevant for a static evaluation; default 12.011)

    Returns
    -------
    dict with energy (eV), energies (N,), forces (N, 3) eV/A, virial (3, 3) eV in the
    frame of ``atoms`` (LAMMPS sign: W = sum r (x) f).
    """
    from potentials.lammps_runtime import new_lammps

    n = len(atoms)
    types = np.ones(n, int) if types is None else np.asarray(types, int)
    ntypes = int(types.max())
    q, box, x = to_lammps_frame(atoms)
    bnd = " ".join("p" if p else "f" for p in atoms.pbc)
    lmp = new_lammps()
    try:
        cmds = ["units metal", "atom_style atomic", "atom_modify map array sort 0 0.0",
                f"boundary {bnd}",
                f"region box prism 0 {box['xhi']!r} 0 {box['yhi']!r} 0 {box['zhi']!r} "
                f"{box['xy']!r} {box['xz']!r} {box['yz']!r} units box",
                f"create_box {ntypes} box"]
        for c in cmds:
            lmp.command(c)
        created = lmp.create_atoms(n, list(range(1, n + 1)), types.tolist(),
                                   x.ravel().tolist())
        if created != n:
            raise RuntimeError(f"LAMMPS created {created} of {n} atoms")
        for t in range(1, ntypes + 1):
            m = 12.011 if masses is None else masses[t - 1]
            lmp.command(f"mass {t} {m}")
        for c in pair_lines:
            lmp.command(c)
        for c in ["neighbor 1.0 bin", "compute pea all pe/atom",
                  "compute vir all pressure NULL virial", "thermo_style custom step pe",
                  "run 0"]:
            lmp.command(c)
        energy = lmp.get_thermo("pe")
        f = np.array(lmp.gather_atoms("f", 1, 3)).reshape(n, 3)
        ids = np.array(lmp.numpy.extract_atom("id")[:n]).astype(int)
        pea_local = np.array(lmp.numpy.extract_compute("pea", 1, 1)[:n])
        pea = np.empty(n)
        pea[ids - 1] = pea_local
        pv = np.array(lmp.numpy.extract_compute("vir", 0, 1)[:6])
        vol = box["xhi"] * box["yhi"] * box["zhi"]
        w = pv * vol / NKTV2P_METAL
        W = np.array([[w[0], w[3], w[4]], [w[3], w[1], w[5]], [w[4], w[5], w[2]]])
    finally:
        lmp.close()
    return {"energy": float(energy), "energies": pea, "forces": f @ q.T,
            "virial": q @ W @ q.T}


def tersoff_pair_lines(path, elements) -> list[str]:
    """``pair_style tersoff`` with the file ``path`` mapped onto ``elements`` (one per type)."""
    return ["pair_style tersoff", f"pair_coeff * * {path} {' '.join(elements)}"]


def bundle_pair_lines(ntubes: int, tersoff_file, lj_only: bool = False) -> list[str]:
    """The references' bundle pair (upscale.experiments.lammps.potential): Tersoff within a tube
    (atom type = tube), lj/cut between tubes; ``lj_only``: the LJ part alone."""
    from upscale.experiments.lammps.potential import LJ_CUTOFF, LJ_EPSILON_EV, LJ_SIGMA  # noqa: PLC0415

    if lj_only:
        out = [f"pair_style lj/cut {LJ_CUTOFF}", f"pair_coeff * * 0.0 {LJ_SIGMA}"]
        out += [f"pair_coeff {i} {j} {LJ_EPSILON_EV} {LJ_SIGMA}"
                for i in range(1, ntubes + 1) for j in range(i + 1, ntubes + 1)]
        return out
    elems = " ".join(["C"] * ntubes)
    out = [f"pair_style hybrid tersoff lj/cut {LJ_CUTOFF}",
           f"pair_coeff * * tersoff {tersoff_file} {elems}"]
    out += [f"pair_coeff {i} {j} lj/cut {LJ_EPSILON_EV} {LJ_SIGMA}"
            for i in range(1, ntubes + 1) for j in range(i + 1, ntubes + 1)]
    return out


def errors(ours: dict, ref: dict) -> dict:
    """Error measures between two evaluations (energy, forces, virial)."""
    e_rel = abs(ours["energy"] - ref["energy"]) / abs(ref["energy"])
    f_err = float(np.max(np.abs(ours["forces"] - ref["forces"])))
    w_scale = max(np.max(np.abs(ref["virial"])), 1e-300)
    w_rel = float(np.max(np.abs(ours["virial"] - ref["virial"])) / w_scale)
    ea_err = float(np.max(np.abs(ours["energies"] - ref["energies"])))
    return {"energy_rel_err": e_rel, "force_max_abs_err_eV_per_A": f_err,
            "virial_rel_err": w_rel, "energies_max_abs_err_eV": ea_err}


def evaluate_calculator(atoms, calc) -> dict:
    """The figures of :func:`evaluate` from an ASE calculator (on a copy of ``atoms``)."""
    a = atoms.copy()
    a.calc = calc
    return {"energy": a.get_potential_energy(), "energies": a.get_potential_energies(),
            "forces": a.get_forces(), "virial": calc.get_virial(a)}
