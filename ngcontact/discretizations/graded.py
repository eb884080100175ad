"""Integrals of error densities with point singularities: a rule graded towards the singular points.

The energy error of an exact solution with a point singularity (the L-shape's r^{2/3} sin(2 theta/3): the
density |grad(u - u_h)|^2 ~ r^{-2/3}) is too small with a Gauss rule of fixed order on the elements at the
point: on uniform L-shape meshes, P3, by about 7 % (outside audit, stop 48).  :func:`integrate_graded` keeps
NGSolve's rule of the given order on every element and replaces the integral of each element within
:data:`NEAR` diameters of a declared point (:attr:`~ngcontact.problems.ExactSolution.singular_points`) by a
composite rule: the element's reference triangle is split into four (midpoints) :data:`DEPTH` times, each time
only the children at the point (closer to it than their diameter, or containing it), and the same Gauss rule
is used on every leaf.  The innermost leaves are 2^-DEPTH of the element's size: r^{-2/3} leaves out
(2^-DEPTH)^{4/3} ~ 1e-8 of the element's integral.  Straight (affine) elements: the Jacobian is the
element's area.
"""
from __future__ import annotations

import functools

import numpy as np
from ngsolve import TRIG, VOL, ElementId, IntegrationRule, Integrate

__all__ = ["integrate_graded", "DEPTH", "NEAR"]

#: subdivision levels towards a singular point
DEPTH = 20
#: elements whose nearest vertex is within NEAR diameters of a singular point get the graded rule (the last
#: adaptive L-shape P3 level of 18: NEAR 0.5, 1 and 1.5 agree to 1e-9 relative, none 0.9 % below)
NEAR = 0.5


def _triangles(mesh):
    """(coords (nv, 2), element vertex numbers (ne, 3)) of a 2D mesh (NGSolve's VOL element order)."""
    ng = mesh.ngmesh
    coords = np.array(ng.Coordinates())[:, :2]
    els = ng.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    return coords, els


@functools.lru_cache(maxsize=64)
def _rule(pt: tuple, depth: int, order: int):
    """(IntegrationRule, weights) of the reference triangle (vertices (1, 0), (0, 1), (0, 0), NGSolve's TRIG) split
    towards the reference point ``pt`` (module doc); cached: a singular point at a vertex has three positions."""
    ref = np.array(pt)
    todo = [np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])]
    leaves = []
    for level in range(depth + 1):
        nxt = []
        for T in todo:
            diam = max(np.linalg.norm(T[0] - T[1]), np.linalg.norm(T[1] - T[2]), np.linalg.norm(T[2] - T[0]))
            near = min(np.linalg.norm(T - ref, axis=1)) < diam or _inside(T, ref)
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


def _element_integral(mesh, cf, k: int, corners: np.ndarray, pt: np.ndarray, order: int) -> float:
    """The graded integral of ``cf`` over element ``k`` with vertex coordinates ``corners`` (3, 2)."""
    # reference coordinates of pt: x = xi v0 + eta v1 + (1 - xi - eta) v2 (rounded: the key of the cached rule)
    J = np.column_stack([corners[0] - corners[2], corners[1] - corners[2]])
    ref = np.round(np.linalg.solve(J, pt - corners[2]), 12) + 0.0
    ir, weights = _rule((float(ref[0]), float(ref[1])), DEPTH, order)
    values = np.asarray(cf(mesh.GetTrafo(ElementId(VOL, int(k)))(ir))).ravel()
    return float(abs(np.linalg.det(J)) * np.dot(weights, values))


def integrate_graded(cf, mesh, order: int, points=()) -> float:
    """Integral of the scalar ``cf`` over ``mesh``: NGSolve's rule of ``order``, graded towards ``points`` on the
    elements at them (module doc); without points, ``Integrate(cf, mesh, order=order)``."""
    if not points:
        return Integrate(cf, mesh, order=order)
    values = Integrate(cf, mesh, order=order, element_wise=True).NumPy().copy()
    coords, els = _triangles(mesh)
    tri = coords[els]  # (ne, 3, 2)
    diam = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    for p in points:
        pt = np.asarray(p, dtype=float)
        dist = np.min(np.linalg.norm(tri - pt, axis=2), axis=1)
        for k in np.flatnonzero(dist < NEAR * diam):
            values[k] = _element_integral(mesh, cf, k, tri[k], pt, order)
    return float(values.sum())
