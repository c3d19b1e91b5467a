"""FE reference for the plate with a hole of seed 003 sec. 5.2 (scikit-fem, quadratic
triangles on a gmsh mesh graded towards the hole).

Plate ``[-L/2, L/2] x [-W/2, W/2]`` (L = 150 mm, W = 50 mm, thickness 1 mm), central hole
of radius 10 mm, plane stress, linear elasticity with a general anisotropic Voigt stiffness
(11, 22, 12). Clamped grips: ``u = 0`` on x = -L/2, ``u = (U, 0)`` on x = +L/2; the other
edges and the hole are free. The particle model uses the same grips as layers of width
delta beyond the two ends holding the same displacements.

Results: displacements probed at given points, the grip reaction (N, thickness included),
the gross-section stress concentration ``Kt = sigma_xx(0, R) / (F / (W t))`` with
sigma_xx at the hole's top from the tangential strain of the boundary trace and the
free-surface condition (:meth:`FEPlate.Kt_trace`; the L2-projected nodal stress is kept as
``Kt_l2_projection``), and its mesh convergence.

Meshes: size h within 1 mm of the hole (the orthotropic peak falls half-way to the far
stress within about 0.65 mm of the hole, so the layer holding it is uniformly fine),
growing linearly to 2 mm at 6 mm from it; the levels halve h.

Run ``python -m validation.fem_plate`` to regenerate ``data/reference/tipd_hole_fem.json``
(provenance inside: library versions, meshes, command).
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["plate_mesh", "FEPlate", "solve_plate", "ISO", "ORTHO", "kirsch_kt", "lekhnitskii_kt",
           "REFERENCE", "generate", "threshold_field"]

L_PLATE, W_PLATE, R_HOLE, THICK = 0.15, 0.05, 0.01, 1e-3
U_GRIP = 4e-4            # 1e-4 mm/s x 4000 s (seed 003 sec. 5.2)
REFERENCE = Path(__file__).resolve().parents[1] / "data" / "reference" / "tipd_hole_fem.json"


def _iso():
    E, nu = 210e9, 0.25
    a = E / (1 - nu * nu)
    return np.array([[a, a * nu, 0], [a * nu, a, 0], [0, 0, E / (2 * (1 + nu))]])


def _ortho():
    E1, E2, G12, nu12 = 144.8e9, 11.7e9, 9.66e9, 0.21
    nu21 = nu12 * E2 / E1
    d = 1 - nu12 * nu21
    return np.array([[E1 / d, nu12 * E2 / d, 0], [nu12 * E2 / d, E2 / d, 0], [0, 0, G12]])


ISO = _iso()
ORTHO = _ortho()


def kirsch_kt() -> float:
    """Kirsch: sigma_max / sigma_inf = 3 for a small hole in a large isotropic plate."""
    return 3.0


def lekhnitskii_kt(E1=144.8e9, E2=11.7e9, G12=9.66e9, nu12=0.21) -> float:
    """Lekhnitskii: Kt = 1 + sqrt(2 (sqrt(E1/E2) - nu12) + E1/G12) for a circular hole in
    a large orthotropic plate loaded along axis 1."""
    return float(1 + np.sqrt(2 * (np.sqrt(E1 / E2) - nu12) + E1 / G12))


def threshold_field(kind, items, size_min, size_max, dist_min, dist_max, sampling=None) -> int:
    """A gmsh size field: ``size_min`` within ``dist_min`` of the points or curves ``items``
    (``kind``: "PointsList" or "CurvesList"), growing linearly to ``size_max`` at ``dist_max``."""
    import gmsh

    f = gmsh.model.mesh.field
    d = f.add("Distance")
    f.setNumbers(d, kind, items)
    if sampling:
        f.setNumber(d, "Sampling", sampling)
    th = f.add("Threshold")
    for key, v in (("InField", d), ("SizeMin", size_min), ("SizeMax", size_max), ("DistMin", dist_min),
                   ("DistMax", dist_max)):
        f.setNumber(th, key, v)
    return th


def plate_mesh(h_hole: float, h_far: float, *, L=L_PLATE, W=W_PLATE, R=R_HOLE,
               dist_min: float | None = None, dist_max: float | None = None):
    """gmsh triangulation of the plate with a hole: size h_hole within ``dist_min`` (default
    0.2 R) of the hole, growing linearly to h_far at ``dist_max`` (default 3 R). Returns
    (points (2, n), triangles (3, m)) for skfem."""
    import gmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("plate")
        occ = gmsh.model.occ
        rect = occ.addRectangle(-L / 2, -W / 2, 0, L, W)
        # the hole as four arcs, so that its top (0, R) and bottom are mesh vertices
        c = occ.addPoint(0, 0, 0)
        pts = [occ.addPoint(R * np.cos(a), R * np.sin(a), 0) for a in np.arange(4) * np.pi / 2]
        hole = [occ.addCircleArc(pts[k], c, pts[(k + 1) % 4]) for k in range(4)]
        disk = occ.addPlaneSurface([occ.addCurveLoop(hole)])
        occ.cut([(2, rect)], [(2, disk)], removeTool=True)
        occ.synchronize()
        hole = [cv[1] for cv in gmsh.model.getEntities(1)
                if max(abs(v) for v in gmsh.model.getBoundingBox(1, cv[1])) <= 1.0001 * R]
        th = threshold_field("CurvesList", hole, h_hole, h_far, 0.2 * R if dist_min is None else dist_min,
                             3 * R if dist_max is None else dist_max, sampling=400)
        gmsh.model.mesh.field.setAsBackgroundMesh(th)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)
        gmsh.model.mesh.generate(2)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        etypes, _, enodes = gmsh.model.mesh.getElements(2)
        tri = np.asarray(enodes[list(etypes).index(2)], dtype=np.int64).reshape(-1, 3)
    finally:
        gmsh.finalize()
    xyz = coords.reshape(-1, 3)[:, :2]
    used = np.unique(tri)                        # drop nodes no triangle uses (arc centre)
    pos = {int(tg): k for k, tg in enumerate(tags)}
    new = {int(tg): k for k, tg in enumerate(used)}
    p = xyz[[pos[int(tg)] for tg in used]].T.copy()
    t = np.vectorize(new.get)(tri).T
    return p, t


class FEPlate:
    """A solved plate: ``probe(points (k, 2)) -> u (k, 2)``, ``reaction_N``, ``Kt``.

    The solution lives on the isoparametric mesh; displacements are probed with the same
    dofs on its straight-sided twin (the two differ only in the elements on the hole), and
    stresses are the L2 projection of ``sigma_xx`` onto scalar quadratics on the curved mesh,
    read at its nodes (``sigma_xx_nodes``)."""

    def __init__(self, basis, probe_basis, u, reaction, C, h_hole, W=W_PLATE):
        from skfem import Basis, BilinearForm, ElementTriP2, LinearForm, solve
        self.basis, self.probe_basis, self.u = basis, probe_basis, u
        self.reaction_N, self.C, self.h_hole = reaction, C, h_hole
        self.sigma_gross = reaction / (W * THICK)
        bs = Basis(basis.mesh, ElementTriP2(), intorder=4)
        Cm = C

        @BilinearForm
        def mass(a, v, w):
            return a * v

        @LinearForm
        def rhs(v, w):
            g = w["uu"].grad
            exx, eyy, gxy = g[0, 0], g[1, 1], g[0, 1] + g[1, 0]
            return (Cm[0, 0] * exx + Cm[0, 1] * eyy + Cm[0, 2] * gxy) * v

        uu = Basis(basis.mesh, basis.elem, intorder=4).interpolate(u)
        self.sxx = solve(mass.assemble(bs), rhs.assemble(bs, uu=uu))
        self.sbasis = bs
        self.Kt_l2_projection = self.sigma_xx_node(0.0, R_HOLE) / self.sigma_gross
        self.Kt = self.Kt_trace()

    def Kt_trace(self, points: int = 5) -> float:
        """Kt from the tangential strain of the displacement trace on the hole at its top:
        at a traction-free point with normal y, ``sigma_yy = sigma_xy = 0`` make
        ``sigma_xx = (1 / S_11) eps_xx`` (S = C^-1, the compliance; E1 for the orthotropic
        plate), and ``eps_xx = eps_tt = (du_theta/dtheta + u_r) / R`` there. The derivative
        is that of the polynomial of degree ``points - 1`` through the ``points`` boundary
        nodes centred on the top (5: the two quadratic edges that meet there). It uses the
        free-surface condition exactly, where the projected and the element gradients
        satisfy it only weakly (their error at the boundary node is first order in h on
        these meshes for the orthotropic plate)."""
        b = self.basis
        ix, iy = b.split_indices()
        loc = b.doflocs[:, ix]
        on = np.flatnonzero(np.abs(np.hypot(loc[0], loc[1]) - R_HOLE) < 1e-9 * R_HOLE)
        th = np.arctan2(loc[1, on], loc[0, on])
        near = np.argsort(np.abs(th - np.pi / 2))[:points]
        near = near[np.argsort(th[near])]
        t = th[near]
        ux, uy = self.u[ix][on[near]], self.u[iy][on[near]]
        ut = -ux * np.sin(t) + uy * np.cos(t)
        ur = ux * np.cos(t) + uy * np.sin(t)
        c = np.polyfit(t - np.pi / 2, ut, points - 1)
        k = int(np.argmin(np.abs(t - np.pi / 2)))
        eps = (c[-2] + ur[k]) / R_HOLE
        S11 = np.linalg.inv(self.C)[0, 0]
        return float(eps / S11 / self.sigma_gross)

    def probe(self, points) -> np.ndarray:
        """Displacement (k, 2) (m) at points (k, 2)."""
        pts = np.asarray(points, dtype=np.float64).T
        out = np.zeros((pts.shape[1], 2))
        for c in range(2):
            sub = self.probe_basis.split_bases()[c]
            out[:, c] = sub.probes(pts) @ self.u[self.probe_basis.split_indices()[c]]
        return out

    def sigma_xx_node(self, x, y) -> float:
        """Projected sigma_xx (Pa) at the node nearest (x, y)."""
        loc = self.sbasis.doflocs
        k = int(np.argmin((loc[0] - x) ** 2 + (loc[1] - y) ** 2))
        return float(self.sxx[k])

    def sigma_xx(self, points) -> np.ndarray:
        """Projected sigma_xx (Pa) at points, probed on the straight-sided twin."""
        from skfem import Basis, ElementTriP2

        pb = Basis(self.probe_basis.mesh, ElementTriP2())
        return pb.probes(np.asarray(points, dtype=np.float64).T) @ self.sxx


def solve_plate(C, h_hole: float = 5e-4, h_far: float | None = None, U: float = U_GRIP, *,
                L: float = L_PLATE, W: float = W_PLATE, dist_min: float | None = None,
                dist_max: float | None = None) -> FEPlate:
    """Solve the clamped plate with stiffness ``C`` (Voigt, Pa) on a mesh of size
    ``h_hole`` at the hole (``h_far`` default 8 h_hole, at most 5 mm; ``dist_min``,
    ``dist_max`` as :func:`plate_mesh`); ``L``, ``W`` the plate's length and width (m; the
    hole stays R = 10 mm)."""
    from dataclasses import replace

    from skfem import Basis, BilinearForm, ElementTriP2, ElementVector, MeshTri, MeshTri2, condense, solve
    from skfem.helpers import sym_grad

    h_far = h_far or min(8 * h_hole, 5e-3)
    p, t = plate_mesh(h_hole, h_far, L=L, W=W, dist_min=dist_min, dist_max=dist_max)
    m1 = MeshTri(p, t)
    # quadratic (isoparametric) geometry: mid-side nodes of the hole's facets on the circle
    mesh = MeshTri2.from_mesh(m1)
    bf = mesh.boundary_facets()
    mid = mesh.p[:, mesh.facets[:, bf]].mean(axis=1)
    hole_f = bf[np.hypot(mid[0], mid[1]) < 1.01 * R_HOLE]
    D = mesh.dofs.get_facet_dofs(hole_f).flatten()
    doflocs = mesh.doflocs.copy()
    doflocs[:, D] *= R_HOLE / np.linalg.norm(doflocs[:, D], axis=0)
    mesh = replace(mesh, doflocs=doflocs)
    basis = Basis(mesh, ElementVector(ElementTriP2()))
    Cm = np.asarray(C, dtype=np.float64)

    @BilinearForm
    def a(u, v, w):
        eu, ev = sym_grad(u), sym_grad(v)
        su = [eu[0, 0], eu[1, 1], 2 * eu[0, 1]]
        sv = [ev[0, 0], ev[1, 1], 2 * ev[0, 1]]
        out = 0.0
        for i in range(3):
            for j in range(3):
                if Cm[i, j] != 0.0:
                    out = out + Cm[i, j] * su[j] * sv[i]
        return out * THICK

    K = a.assemble(basis)
    tol = 1e-9
    left = basis.get_dofs(lambda x: x[0] < -L / 2 + tol)
    right = basis.get_dofs(lambda x: x[0] > L / 2 - tol)
    u = np.zeros(basis.N)
    rdofs_x = right.all("u^1")
    u[rdofs_x] = U
    D = np.concatenate([left.all(), right.all()])
    u = solve(*condense(K, np.zeros(basis.N), x=u, D=D))
    reaction = float((K @ u)[rdofs_x].sum())
    probe_basis = Basis(m1, ElementVector(ElementTriP2()))
    far = np.hypot(*probe_basis.doflocs) > 1.5 * R_HOLE
    if not np.allclose(probe_basis.doflocs[:, far], basis.doflocs[:, far]):
        raise RuntimeError("dof layouts of the curved mesh and its straight twin differ")
    return FEPlate(basis, probe_basis, u, reaction, Cm, h_hole, W)


def sample_points(dx: float) -> dict:
    """Points where the particle model of spacing dx has particles next to y = 0 and next
    to the free edges: cell centres ``x = -L/2 + (i + 1/2) dx`` at ``y = +-dx/2`` (outside
    the hole) and ``y = +-(W/2 - dx/2)``."""
    nx, ny = int(round(L_PLATE / dx)), int(round(W_PLATE / dx))
    x = -L_PLATE / 2 + (np.arange(nx) + 0.5) * dx
    rows = (0.0,) if ny % 2 else (dx / 2, -dx / 2)       # an odd count has a row on y = 0
    mid = np.concatenate([np.stack([x, np.full(nx, y)], 1) for y in rows])
    mid = mid[np.hypot(mid[:, 0], mid[:, 1]) > R_HOLE]
    edge = np.concatenate([np.stack([x, np.full(nx, s * (W_PLATE / 2 - dx / 2))], 1) for s in (1, -1)])
    return {"mid": mid, "edge": edge}


MESH = {"h_far": 2e-3, "dist_min": 1e-3, "dist_max": 6e-3}


def generate(path: Path = REFERENCE, h_levels=(2.5e-4, 1.25e-4, 6.25e-5, 3.125e-5),
             spacings=(2e-3, 1e-3, 5e-4, 2.5e-4)):
    """Solve both materials on four graded meshes (``MESH``, h halving) and store the
    finest, with the differences to the coarser meshes as the convergence record."""
    import gmsh
    import skfem

    out = {"provenance": {
        "generator": "python -m validation.fem_plate", "library": f"scikit-fem {skfem.__version__}",
        "mesher": f"gmsh {gmsh.__version__}", "element": "ElementVector(ElementTriP2) on MeshTri2 (quadratic, isoparametric: hole edges on the circle)",
        "geometry_m": {"L": L_PLATE, "W": W_PLATE, "R": R_HOLE, "thickness": THICK},
        "grips": "u = 0 on x = -L/2, u = (U, 0) on x = +L/2 (clamped), others free; plane stress",
        "U_m": U_GRIP, "mesh_sizes_at_hole_m": list(h_levels),
        "mesh_grading": "gmsh Threshold on the distance to the hole: h_hole within 1 mm, linear to 2 mm at 6 mm",
        "Kt": "trace recovery (FEPlate.Kt_trace, 5 boundary nodes); Kt_l2_projection: projected nodal sigma_xx",
        "large_plate": "1.2 m x 0.6 m, same hole and grips, h_hole 62.5 um within 1 mm, linear to 20 mm at "
                       "100 mm: for Kirsch / Lekhnitskii",
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())},
        "materials": {}}
    for name, C in (("iso", ISO), ("ortho", ORTHO)):
        sols = []
        for h in h_levels:
            t0 = time.perf_counter()
            sols.append(solve_plate(C, h, **MESH))
            print(f"{name}: h_hole = {h:g} m, dofs {sols[-1].basis.N}, Kt {sols[-1].Kt:.5f} "
                  f"(projected {sols[-1].Kt_l2_projection:.5f}), "
                  f"reaction {sols[-1].reaction_N:.6g} N ({time.perf_counter() - t0:.1f} s)", flush=True)
        fine = sols[-1]
        k = [s.Kt for s in sols]
        # the unstructured levels are not nested: Kt wanders by a few 1e-4 relative instead of
        # decreasing geometrically, so the spread of the finest three is its uncertainty
        rec = {"C_voigt_Pa": C.tolist(), "Kt": k, "Kt_l2_projection": [s.Kt_l2_projection for s in sols],
               "Kt_spread_finest3": float(np.ptp(k[-3:])),
               "reaction_N": [s.reaction_N for s in sols],
               "dofs": [int(s.basis.N) for s in sols], "samples": {}}
        conv = {}
        for dx in spacings:
            pts = sample_points(dx)
            entry = {}
            for key, P in pts.items():
                uf = fine.probe(P)
                uc = sols[-2].probe(P)
                entry[key] = {"xy_m": P.round(12).tolist(), "u_m": uf.tolist()}
                comp = 0 if key == "mid" else 1
                conv[f"{key}_dx{dx:g}"] = float(np.linalg.norm(uf[:, comp] - uc[:, comp]) /
                                                np.linalg.norm(uf[:, comp]))
            rec["samples"][f"{dx:g}"] = entry
        rec["rel_change_last_refinement"] = conv
        ys = R_HOLE + np.concatenate([np.linspace(0, 2e-3, 41)[:-1], np.linspace(2e-3, W_PLATE / 2 - R_HOLE - 2e-4, 60)])
        ys[0] = R_HOLE + 1e-7
        rec["sigma_xx_over_gross_on_x0"] = {
            "y_m": ys.tolist(),
            "value": (fine.sigma_xx(np.stack([np.zeros_like(ys), ys], 1)) / fine.sigma_gross).tolist()}
        big = solve_plate(C, 6.25e-5, 0.02, U=U_GRIP * 8, L=1.2, W=0.6, dist_min=1e-3, dist_max=0.1)
        rec["Kt_large_plate_1200x600mm"] = big.Kt
        rec["Kt_large_plate_1200x600mm_l2_projection"] = big.Kt_l2_projection
        print(f"{name}: large plate (1.2 m x 0.6 m, d/W = 1/30) Kt {big.Kt:.5f}", flush=True)
        out["materials"][name] = rec
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out))
    print(f"wrote {path}")
    return out


if __name__ == "__main__":  # pragma: no cover
    generate()
    sys.exit(0)
