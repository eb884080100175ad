"""Integrals of error densities with point singularities: a rule graded towards the singular points.

The energy error of an exact solution with a point singularity (the L-shape's r^{2/3} sin(2 theta/3): the
density |grad(u - u_h)|^2 ~ r^{-2/3}) is too small with a Gauss rule of fixed order on the elements at the
point: on uniform L-shape meshes, P3, by about 7 % (outside audit, stop 48).  :func:`integrate_graded` keeps
NGSolve's rule of the given order on every element and replaces the integral of each element closer than
:data:`NEAR` of its diameters to a declared point (:attr:`~ngcontact.problems.ExactSolution.singular_points`;
distance 0 for an element that contains it) by a composite rule: the element's reference triangle is split into
four (midpoints) :data:`DEPTH` times, each time only the children at one of the element's points (closer to it
than their diameter, or containing it), and the same Gauss rule is used on every leaf.  The innermost leaves are
2^-DEPTH of the element's size: r^{-2/3} leaves out (2^-DEPTH)^{4/3} ~ 1e-8 of the element's integral.  The
Jacobian determinant is evaluated at every point (curved elements included).
"""
from __future__ import annotations

import functools

import numpy as np
from ngsolve import TRIG, VOL, Det, ElementId, IfPos, IntegrationRule, Integrate, specialcf

__all__ = ["integrate_graded", "DEPTH", "NEAR"]

_DETJ = Det(specialcf.JacobianMatrix(2))

#: subdivision levels towards a singular point
DEPTH = 20
#: elements closer than NEAR diameters to a singular point get the graded rule (the last adaptive L-shape P3 level of
#: 18, nearest-vertex distance: NEAR 0.5, 1 and 1.5 agree to 1e-9 relative, none 0.9 % below)
NEAR = 0.5


def _triangles(mesh):
    """(coords (nv, 2), element vertex numbers (ne, 3)) of a 2D mesh (NGSolve's VOL element order)."""
    ng = mesh.ngmesh
    coords = np.array(ng.Coordinates())[:, :2]
    els = ng.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    return coords, els


@functools.lru_cache(maxsize=64)
def _rule(points: tuple, depth: int, order: int):
    """(IntegrationRule, weights) of the reference triangle (vertices (1, 0), (0, 1), (0, 0), NGSolve's TRIG) split
    towards the reference points ``points`` (module doc); cached: a singular point at a vertex has three positions."""
    refs = [np.array(p) for p in points]
    todo = [np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])]
    leaves = []
    for level in range(depth + 1):
        nxt = []
        for T in todo:
            diam = max(np.linalg.norm(T[0] - T[1]), np.linalg.norm(T[1] - T[2]), np.linalg.norm(T[2] - T[0]))
            near = any(min(np.linalg.norm(T - ref, axis=1)) < diam or _inside(T, ref) for ref in refs)
            if level == depth or not near:
                leaves.append(T)
                continue
            m01, m12, m20 = (T[0] + T[1]) / 2, (T[1] + T[2]) / 2, (T[2] + T[0]) / 2
            nxt += [np.array([T[0], m01, m20]), np.array([m01, T[1], m12]), np.array([m20, m12, T[2]]),
                    np.array([m01, m12, m20])]
        todo = nxt
    leaves = np.array(leaves)
    base = IntegrationRule(TRIG, order)
    q = np.array([p[:2] for p in base.points])
    w = np.array(base.weights)  # sum 1/2, the reference triangle's area
    A, B, C = leaves[:, 0], leaves[:, 1], leaves[:, 2]
    pts = A[:, None, :] + (B - A)[:, None, :] * q[None, :, 0, None] + (C - A)[:, None, :] * q[None, :, 1, None]
    area = 0.5 * np.abs((B - A)[:, 0] * (C - A)[:, 1] - (B - A)[:, 1] * (C - A)[:, 0])
    weights = ((2.0 * area)[:, None] * w[None, :]).ravel()  # the leaf rules, in reference measure
    return IntegrationRule(points=pts.reshape(-1, 2).tolist(), weights=weights.tolist()), weights


def _inside(T, p) -> bool:
    d = [(p[0] - T[j][0]) * (T[i][1] - T[j][1]) - (T[i][0] - T[j][0]) * (p[1] - T[j][1])
         for i, j in ((0, 1), (1, 2), (2, 0))]
    return not (min(d) < 0 < max(d))


def _element_integral(mesh, cf, k: int, corners: np.ndarray, points: list, order: int) -> float:
    """The graded integral of ``cf`` over element ``k`` (vertex coordinates ``corners`` (3, 2)) towards ``points``."""
    # reference coordinates: x = xi v0 + eta v1 + (1 - xi - eta) v2 (of the straight triangle; rounded: the key of
    # the cached rule)
    J = np.column_stack([corners[0] - corners[2], corners[1] - corners[2]])
    refs = tuple(tuple(float(v) for v in np.round(np.linalg.solve(J, p - corners[2]), 12) + 0.0) for p in points)
    ir, weights = _rule(refs, DEPTH, order)
    mapped = mesh.GetTrafo(ElementId(VOL, int(k)))(ir)
    values = np.asarray((cf * IfPos(_DETJ, _DETJ, -_DETJ))(mapped)).ravel()
    return float(np.dot(weights, values))


def _distances(tri: np.ndarray, pt: np.ndarray) -> np.ndarray:
    """Distance from ``pt`` to each triangle of ``tri`` (ne, 3, 2); 0 inside."""
    out = np.full(len(tri), np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        a, e = tri[:, i], tri[:, j] - tri[:, i]
        t = np.clip(np.einsum("ij,ij->i", pt - a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0.0, 1.0)
        out = np.minimum(out, np.linalg.norm(a + t[:, None] * e - pt, axis=1))
    cross = [(tri[:, j, 0] - tri[:, i, 0]) * (pt[1] - tri[:, i, 1])
             - (tri[:, j, 1] - tri[:, i, 1]) * (pt[0] - tri[:, i, 0]) for i, j in ((0, 1), (1, 2), (2, 0))]
    inside = (np.minimum.reduce(cross) >= 0) | (np.maximum.reduce(cross) <= 0)
    out[inside] = 0.0
    return out


def integrate_graded(cf, mesh, order: int, points=()) -> float:
    """Integral of the scalar ``cf`` over ``mesh``: NGSolve's rule of ``order``, graded towards ``points`` on the
    elements at them (module doc); without points, ``Integrate(cf, mesh, order=order)``."""
    if not points:
        return Integrate(cf, mesh, order=order)
    values = Integrate(cf, mesh, order=order, element_wise=True).NumPy().copy()
    coords, els = _triangles(mesh)
    tri = coords[els]  # (ne, 3, 2)
    diam = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    near = {}  # element -> the points it is graded towards
    for p in points:
        pt = np.asarray(p, dtype=float)
        for k in np.flatnonzero(_distances(tri, pt) < NEAR * diam):
            near.setdefault(int(k), []).append(pt)
    for k, pts in near.items():
        values[k] = _element_integral(mesh, cf, k, tri[k], pts, order)
    return float(values.sum())
