"""FE reference for the semi-circular bend (SCB) specimen: geometry factors, T-stress,
compliance (scikit-fem, plane stress, gmsh mesh refined at the crack tip).

Geometry (seed 004 sec. 6.6, Fig. 6.5): a half disc of radius R on the flat edge y = 0,
centre at the origin; an edge crack of length a from the middle of the flat edge at angle
alpha to the symmetry line (tip at a (sin alpha, cos alpha)); supports at x = +-S on the
flat edge, the load at (0, R). Loads and supports act on boundary segments of width w
(the particle model's 3 dx patches): the load segment moves rigidly by (0, -d), the
supports hold u_y = 0 (rollers, default) or u = 0 (``supports="pinned"``, the literal
u_x(+-S, 0) = 0 of eq. 6.40).

The crack is a slit of mouth width ``mouth`` (a wedge of negligible angle, so that the
two faces are distinct boundary curves). Quadratic triangles (P2); K_I, K_II from the
crack-face displacement jump (displacement correlation, plane stress kappa = (3 - nu)/
(1 + nu)), Delta u_{y'} = (kappa + 1) K_I sqrt(r / 2 pi) / mu and Delta u_{x'} =
(kappa + 1) K_II sqrt(r / 2 pi) / mu, evaluated over 0.01 a < r < 0.1 a and extrapolated
to r = 0 by a fit K(r) = K + c r (tip frame: x' along the crack from mouth to tip,
y' = (cos alpha, -sin alpha), the side away from the load line for alpha > 0, so that
K_II > 0 for 0 < alpha < 90 deg; this frame is mirrored, and kink angles are measured in
it, positive toward +y', i.e. away from the load line); the T-stress from sigma_{x'x'} - sigma_{y'y'} ahead of
the tip (singular terms cancel there for both modes), fitted as T + c1 sqrt(r) + c2 r over
0.01 a < r < 0.15 a. Geometry factors (eqs. 6.30-6.31)

    Y_{I,II} = K_{I,II} 2 R t / (P sqrt(pi a)),   T* = T 2 R t / P.

``python -m validation.fem_scb`` writes ``data/reference/scb_fem.json``.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from validation.fem_plate import threshold_field

__all__ = ["scb_mesh", "solve_scb", "ALPHAS_DEG", "PMMA", "GEOMETRY"]

ALPHAS_DEG = (0.0, 10.0, 20.0, 30.0, 40.0, 43.0, 47.0, 50.0)
PMMA = {"E_Pa": 3.75e9, "nu": 0.35}
GEOMETRY = {"R_m": 0.05, "a_over_R": 0.3, "S_over_R": 0.43, "t_m": 0.005}


def scb_mesh(alpha_deg, *, R=0.05, a_over_R=0.3, S_over_R=0.43, w=1.5e-3, h_far=2.5e-3,
             h_tip=2e-5, h_patch=None, mouth=2e-5):
    """gmsh triangulation of the SCB (linear triangles): points (2, n), triangles (3, m)."""
    import gmsh

    a, S = a_over_R * R, S_over_R * R
    al = np.radians(alpha_deg)
    tip = (a * np.sin(al), a * np.cos(al))
    hp = w / 6 if h_patch is None else h_patch
    hm = 0.5 * mouth
    gmsh.initialize(["-v", "0"]) if not gmsh.isInitialized() else None
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("scb")
    g = gmsh.model.geo
    pts_xy = [(hm, 0), (S - w / 2, 0), (S + w / 2, 0), (R, 0)]
    yt = np.sqrt(R * R - (w / 2) ** 2)
    pts_xy += [(w / 2, yt), (-w / 2, yt), (-R, 0), (-S - w / 2, 0), (-S + w / 2, 0), (-hm, 0), tip]
    sizes = [h_tip * 4, hp, hp, h_far, hp, hp, h_far, hp, hp, h_tip * 4, h_tip]
    P = [g.addPoint(x, y, 0, s) for (x, y), s in zip(pts_xy, sizes)]
    c0 = g.addPoint(0, 0, 0, h_far)
    L = [g.addLine(P[0], P[1]), g.addLine(P[1], P[2]), g.addLine(P[2], P[3]),
         g.addCircleArc(P[3], c0, P[4]), g.addCircleArc(P[4], c0, P[5]),
         g.addCircleArc(P[5], c0, P[6]), g.addLine(P[6], P[7]), g.addLine(P[7], P[8]),
         g.addLine(P[8], P[9]), g.addLine(P[9], P[10]), g.addLine(P[10], P[0])]
    loop = g.addCurveLoop(L)
    g.addPlaneSurface([loop])
    g.synchronize()
    f = gmsh.model.mesh.field
    th = threshold_field("PointsList", [P[10]], h_tip, h_far, 10 * h_tip, 0.5 * a)
    th2 = threshold_field("CurvesList", [L[9], L[10]], 0.02 * a, h_far, 0.02 * a, 0.3 * a, sampling=400)
    th3 = threshold_field("PointsList", [P[1], P[2], P[4], P[5], P[7], P[8]], hp, h_far, w, 10 * w)
    mn = f.add("Min")
    f.setNumbers(mn, "FieldsList", [th, th2, th3])
    f.setAsBackgroundMesh(mn)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 1)
    gmsh.option.setNumber("Mesh.Algorithm", 6)
    gmsh.model.mesh.generate(2)
    tags, xyz, _ = gmsh.model.mesh.getNodes()
    _, _, enodes = gmsh.model.mesh.getElements(2)
    gmsh.model.remove()
    idx = np.zeros(int(tags.max()) + 1, dtype=np.int64)
    idx[tags.astype(np.int64)] = np.arange(len(tags))
    p = xyz.reshape(-1, 3)[:, :2].T.copy()
    t = idx[enodes[0].astype(np.int64)].reshape(-1, 3).T.copy()
    used = np.unique(t)                          # drop geometry-only nodes (the arc centre)
    remap = np.full(p.shape[1], -1, np.int64)
    remap[used] = np.arange(used.size)
    p, t = p[:, used], remap[t]
    return p, t, np.array(tip)


def solve_scb(alpha_deg, *, E=3.75e9, nu=0.35, R=0.05, a_over_R=0.3, S_over_R=0.43, t=0.005,
              w=1.5e-3, supports="rollers", h_tip=2e-5, h_far=2.5e-3, mouth=2e-5, patch="segment",
              block=None):
    """Plane-stress P2 solve of the SCB under a unit load-segment displacement.

    ``patch="segment"`` (default): load and supports act on boundary segments of width
    ``w``. ``patch="block"``: they act on the regions the particle model's patches occupy
    (every dof inside them is constrained: the load block |x| <= hb, x^2 + y^2 >= (R - db)^2
    moves rigidly, the support blocks |x -+ S| <= hb, y <= db hold u_y, or u when pinned),
    with ``block = (hb, db)`` in m (default (2 w / 3, w): the cells of 3 x 3 particles of
    spacing w / 3).

    Returns a dict: ``Y_I, Y_II, T_star`` (dimensionless), ``K_I_Pa_sqrt_m, K_II_Pa_sqrt_m,
    T_Pa`` per newton of load (load P = 1 N), ``compliance_m_per_N`` (load-segment
    displacement over P), ``n_nodes``, ``n_dofs``, ``wall_s``.
    """
    from skfem import Basis, ElementTriP2, ElementVector, MeshTri, asm, condense, solve
    from skfem.models.elasticity import linear_elasticity, plane_stress

    if supports not in ("rollers", "pinned"):
        raise ValueError(f"supports={supports!r}; valid: 'rollers', 'pinned'")
    t0 = time.perf_counter()
    a, S = a_over_R * R, S_over_R * R
    p, tri, tip = scb_mesh(alpha_deg, R=R, a_over_R=a_over_R, S_over_R=S_over_R, w=w,
                           h_tip=h_tip, h_far=h_far, mouth=mouth)
    m = MeshTri(p, tri)
    e = ElementVector(ElementTriP2())
    ib = Basis(m, e, intorder=4)
    lam, mu = plane_stress(E, nu)
    K = asm(linear_elasticity(lam, mu), ib)
    tol = 1e-9
    yt = np.sqrt(R * R - (w / 2) ** 2)
    top = m.facets_satisfying(lambda x: (np.abs(x[0]) < w / 2 + tol) & (x[1] > yt - 1e-6), boundaries_only=True)
    sup = m.facets_satisfying(lambda x: (np.abs(np.abs(x[0]) - S) < w / 2 + tol) & (np.abs(x[1]) < tol),
                              boundaries_only=True)
    dt = ib.get_dofs(top)
    ds = ib.get_dofs(sup)
    top_x, top_y = dt.all("u^1"), dt.all("u^2")
    sup_y = ds.all("u^2")
    sup_x = ds.all("u^1")
    if patch == "block":
        hb, db = block if block is not None else (2 * w / 3, w)
        X = ib.doflocs
        comp = np.zeros(X.shape[1], int)
        comp[ib.nodal_dofs[1]] = 1
        comp[ib.facet_dofs[1]] = 1 if ib.facet_dofs.size else 0
        in_load = (np.abs(X[0]) <= hb + tol) & (X[0] ** 2 + X[1] ** 2 >= (R - db) ** 2 - tol)
        in_sup = (np.abs(np.abs(X[0]) - S) <= hb + tol) & (X[1] <= db + tol)
        top_x = np.union1d(top_x, np.flatnonzero(in_load & (comp == 0)))
        top_y = np.union1d(top_y, np.flatnonzero(in_load & (comp == 1)))
        sup_y = np.union1d(sup_y, np.flatnonzero(in_sup & (comp == 1)))
        sup_x = np.union1d(sup_x, np.flatnonzero(in_sup & (comp == 0)))
    elif patch != "segment":
        raise ValueError(f"patch={patch!r}; valid: 'segment', 'block'")
    fixed = [top_x, top_y, sup_y] + ([sup_x] if supports == "pinned" else [])
    D = np.unique(np.concatenate(fixed))
    d = 1e-5
    u = np.zeros(K.shape[0])
    u[top_y] = -d
    u = solve(*condense(K, np.zeros(K.shape[0]), x=u, D=D))
    r = K @ u
    P = -r[top_y].sum() * t                      # N (per-unit-thickness reaction x t)
    # crack-face displacement jump
    al = np.radians(alpha_deg)
    ex = np.array([np.sin(al), np.cos(al)])      # crack direction x'
    ey = np.array([np.cos(al), -np.sin(al)])     # normal y' (toward +x: K_II > 0 for alpha > 0)
    nodes = m.p
    rel = nodes - tip[:, None]
    along = ex @ rel
    across = ey @ rel
    on_face = (along < 0) & (np.abs(across) < 1e-3 * a + mouth) & (-along < a)
    # faces: the wedge's two sides are at +-(mouth/2)(|along|/a) across
    ux = u[ib.nodal_dofs[0]]
    uy = u[ib.nodal_dofs[1]]
    up = across > 0
    rr = np.geomspace(0.005 * a, 0.2 * a, 60)
    jump = []
    for sgn in (True, False):
        sel = on_face & (up == sgn)
        bnd = np.zeros(nodes.shape[1], bool)
        bnd[m.boundary_nodes()] = True
        sel &= bnd
        rs = -along[sel]
        o = np.argsort(rs)
        rs = rs[o]
        ux_s, uy_s = ux[sel][o], uy[sel][o]
        jump.append(np.vstack([np.interp(rr, rs, ux_s), np.interp(rr, rs, uy_s)]))
    du = jump[0] - jump[1]                       # upper minus lower face
    du_x, du_y = ex @ du, ey @ du
    kappa = (3 - nu) / (1 + nu)
    fac = mu / (kappa + 1) * np.sqrt(2 * np.pi / rr)
    KI_r, KII_r = fac * du_y, fac * du_x        # per unit thickness load -> scale to P
    win = (rr > 0.01 * a) & (rr < 0.1 * a)
    KI = np.polyfit(rr[win], KI_r[win], 1)[1]
    KII = np.polyfit(rr[win], KII_r[win], 1)[1]
    # T-stress ahead of the tip
    sb = ib.with_element(ElementTriP2())
    grad = ib.interpolate(u).grad
    eps = 0.5 * (grad + np.swapaxes(grad, 0, 1))
    tr = eps[0, 0] + eps[1, 1]
    sig = {k: 2 * mu * eps[i, j] + (lam * tr if i == j else 0.0)
           for k, (i, j) in {"xx": (0, 0), "yy": (1, 1), "xy": (0, 1)}.items()}
    proj = {k: sb.project(v) for k, v in sig.items()}
    ra = np.linspace(0.005 * a, 0.2 * a, 80)
    pts = tip[:, None] + ex[:, None] * ra[None, :]
    Pm = sb.probes(pts)
    sxx, syy, sxy = (Pm @ proj[k] for k in ("xx", "yy", "xy"))
    s_xx = ex[0] ** 2 * sxx + ex[1] ** 2 * syy + 2 * ex[0] * ex[1] * sxy
    s_yy = ey[0] ** 2 * sxx + ey[1] ** 2 * syy + 2 * ey[0] * ey[1] * sxy
    Tr = s_xx - s_yy
    win = (ra > 0.01 * a) & (ra < 0.15 * a)
    A = np.column_stack([np.ones(win.sum()), np.sqrt(ra[win]), ra[win]])
    T = np.linalg.lstsq(A, Tr[win], rcond=None)[0][0]
    Pu = P / t                                    # load per unit thickness for the 2D fields
    KI, KII, T = KI / Pu / t, KII / Pu / t, T / Pu / t   # per newton of total load
    Y = lambda k: k * 2 * R * t / np.sqrt(np.pi * a)
    return {"alpha_deg": float(alpha_deg), "Y_I": float(Y(KI)), "Y_II": float(Y(KII)),
            "T_star": float(T * 2 * R * t), "K_I_Pa_sqrt_m_per_N": float(KI),
            "K_II_Pa_sqrt_m_per_N": float(KII), "T_Pa_per_N": float(T),
            "compliance_m_per_N": float(d / P), "supports": supports, "w_m": w,
            "n_nodes": int(m.p.shape[1]), "n_dofs": int(K.shape[0]), "h_tip_m": h_tip,
            "wall_s": time.perf_counter() - t0}


#: the particle spacings of the geometry factors' convergence (m): the FE with each one's
#: patches (``patch="block"``, the particle model's boundary conditions)
BLOCK_DX = (1e-3, 5e-4, 2.5e-4, 1.25e-4)


def block_references(out, dxs=BLOCK_DX) -> dict:
    """Y_I, Y_II, T* and the compliance of the eight angles with the particle model's
    patches at each spacing ``dxs`` (load and support blocks of 3 x 3 particles: width 3 dx,
    held box (1.5 dx, 2.5 dx)), rollers; written to ``out`` with provenance."""
    import datetime

    rows = [solve_scb(al, w=3 * dx, patch="block", block=(1.5 * dx, 2.5 * dx)) | {"dx_m": dx}
            for dx in dxs for al in ALPHAS_DEG]
    doc = {"provenance": {"made_by": "python -m validation.fem_scb --block (validation/fem_scb.py)",
                          "date": datetime.date.today().isoformat(),
                          "method": "scikit-fem P2 plane stress, gmsh tip-refined mesh (h_tip 2e-5 m); "
                                    "the particle model's load and support blocks at each dx",
                          "geometry": GEOMETRY, "material": PMMA},
           "rows": rows}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(doc, indent=1))
    return doc


def main(argv=None):
    import argparse
    import datetime

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None)
    ap.add_argument("--block", action="store_true",
                    help="the references with the particle model's patches at each spacing of "
                         "BLOCK_DX (data/reference/scb_fem_block.json)")
    args = ap.parse_args(argv)
    if args.block:
        block_references(args.out or "data/reference/scb_fem_block.json")
        return
    args.out = args.out or "data/reference/scb_fem.json"
    rows = {}
    for sup in ("rollers", "pinned"):
        rows[sup] = [solve_scb(al, supports=sup) for al in ALPHAS_DEG]
    conv = [solve_scb(al, h_tip=h) for al in (0.0, 50.0) for h in (8e-5, 4e-5, 2e-5, 1e-5)]
    doc = {"provenance": {"made_by": "python -m validation.fem_scb (validation/fem_scb.py)",
                          "date": datetime.date.today().isoformat(),
                          "method": "scikit-fem P2 plane stress, gmsh tip-refined mesh; K from "
                                    "crack-face displacement jump, T from sigma_x'x' - sigma_y'y' ahead of the tip",
                          "geometry": GEOMETRY, "material": PMMA,
                          "load_and_support_width_m": 1.5e-3},
           "rollers": rows["rollers"], "pinned": rows["pinned"], "tip_convergence": conv}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
