"""Weights (psi_l, 1)_K / |K| of the cardinal functions of the constraint node sets, p = 1..6.

The rule (issue 23, :mod:`ngcontact.discretizations.nodesets`): no constraint node may have a
negative weight.  The equispaced lattice breaks it at p = 4 and p = 6; the positive sets do not.
"""
from itertools import permutations

import numpy as np
import pytest

from ngcontact.discretizations.nodesets import (cardinal_weights, constraint_node_set, edge_points, lattice,
                                                lebesgue_constant, reference_nodes)

DEGREES = range(1, 7)


def _collapsed_gauss(n):
    """A Duffy (collapsed) Gauss rule on the reference triangle, exact for degree <= 2 n - 2."""
    x, w = np.polynomial.legendre.leggauss(n)
    x, w = (x + 1) / 2, w / 2
    u, v = np.meshgrid(x, x, indexing="ij")
    wu, wv = np.meshgrid(w, w, indexing="ij")
    pts = np.stack([u.ravel(), (v * (1 - u)).ravel()], axis=1)
    return pts, (wu * wv * (1 - u)).ravel()


def _weights_by_quadrature(bary):
    """The same integrals, by quadrature of the cardinal functions (Vandermonde in the Legendre-free
    power basis, an independent path from :func:`cardinal_weights`)."""
    p = int(round((np.sqrt(8 * len(bary) + 1) - 3) / 2))
    ex = [(a, b) for a in range(p + 1) for b in range(p + 1 - a)]
    mono = lambda q: np.stack([q[:, 0] ** a * q[:, 1] ** b for a, b in ex], axis=1)
    pts, w = _collapsed_gauss(p + 2)
    psi = mono(pts) @ np.linalg.inv(mono(np.asarray(bary)[:, :2]))
    return 2.0 * w @ psi  # units of |K| = 1/2


def _by_entity(p, w):
    """Weights grouped by the entity of their lattice point: vertex, edge, interior."""
    nz = (lattice(p) > 0).sum(axis=1)
    return w[nz == 1], w[nz == 2], w[nz == 3]


@pytest.mark.parametrize("kind", ["equispaced", "positive"])
@pytest.mark.parametrize("p", DEGREES)
def test_weights_exact_and_sum_to_one(p, kind):
    b = reference_nodes(p, kind)
    w = cardinal_weights(b)
    assert abs(w.sum() - 1.0) < 1e-12
    assert np.allclose(w, _weights_by_quadrature(b), rtol=0, atol=1e-12)


def test_equispaced_weights_have_the_sign_problems():
    w = {p: cardinal_weights(reference_nodes(p, "equispaced")) for p in DEGREES}
    v, e, c = _by_entity(4, w[4])
    assert np.allclose(v, 0, atol=1e-13)
    assert np.allclose(np.sort(e), [-1 / 45] * 3 + [4 / 45] * 6, rtol=0, atol=1e-13)  # midpoints, quarter points
    assert np.allclose(c, 8 / 45, rtol=0, atol=1e-13)
    v, e, _ = _by_entity(2, w[2])
    assert np.allclose(v, 0, atol=1e-13) and np.allclose(e, 1 / 3, rtol=0, atol=1e-13)
    v, e, c = _by_entity(3, w[3])
    assert np.allclose(v, 1 / 30, atol=1e-13) and np.allclose(e, 3 / 40, atol=1e-13) \
        and np.allclose(c, 9 / 20, atol=1e-13)
    assert w[5].min() > 0.01
    assert w[6].min() < -0.06  # P6 negative again


@pytest.mark.parametrize("p", DEGREES)
def test_positive_sets_have_no_negative_weight(p):
    w = cardinal_weights(reference_nodes(p, "positive"))
    if p == 2:  # forced node set (vertices and edge midpoints): vertex weight 0, edge 1/3
        v, e, _ = _by_entity(2, w)
        assert np.abs(v).max() < 1e-13 and np.allclose(e, 1 / 3, atol=1e-13)
    else:
        assert w.min() > 3e-3


def test_positive_p4_numbers():
    """Edge nodes at (1 -+ sqrt(3/7))/2 and 1/2, interior orbit (0.6, 0.2, 0.2) ."""
    s = edge_points(4, "positive")
    assert np.allclose(s, [0, (1 - np.sqrt(3 / 7)) / 2, 0.5, (1 + np.sqrt(3 / 7)) / 2, 1], atol=1e-15)
    v, e, c = _by_entity(4, cardinal_weights(reference_nodes(4, "positive")))
    # 0.0122, 0.0181 / 0.0533, 0.2315 as rationals
    assert np.allclose(v, 11 / 900, rtol=0, atol=1e-13)
    assert np.allclose(np.sort(e), [49 / 2700] * 6 + [4 / 75] * 3, rtol=0, atol=1e-13)
    assert np.allclose(c, 25 / 108, rtol=0, atol=1e-13)


@pytest.mark.parametrize("p", DEGREES)
def test_sets_are_symmetric_and_conforming(p):
    """Invariant under the vertex permutations; edge nodes at the same parameters on every edge,
    symmetric about the midpoint; equal to the lattice where the lattice has no negative weight."""
    b = reference_nodes(p, "positive")
    key = lambda pts: sorted(map(tuple, np.round(pts, 12)))
    for perm in permutations(range(3)):
        assert key(b[:, perm]) == key(b)
    s = edge_points(p, "positive")
    assert np.allclose(s + s[::-1], 1, atol=1e-15) and np.all(np.diff(s) > 0)
    if p not in (4, 6):
        assert np.array_equal(b, lattice(p) / p)


def test_lebesgue_constants():
    leb = {(p, k): lebesgue_constant(reference_nodes(p, k)) for p in (3, 4, 6) for k in ("equispaced", "positive")}
    assert abs(leb[3, "equispaced"] - leb[3, "positive"]) < 1e-12
    assert abs(leb[4, "equispaced"] - 3.47) < 0.01 and abs(leb[4, "positive"] - 2.94) < 0.01
    assert abs(leb[6, "equispaced"] - 8.75) < 0.01 and abs(leb[6, "positive"] - 5.10) < 0.01


def test_constraints_option_names():
    assert constraint_node_set("nodal") == "positive" and constraint_node_set("equispaced") == "equispaced"
    with pytest.raises(ValueError, match="option constraints must be one of .*got 'lobatto'"):
        constraint_node_set("lobatto")
    with pytest.raises(ValueError, match="node set"):
        reference_nodes(4, "nodal")
