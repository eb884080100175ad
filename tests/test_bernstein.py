"""Bernstein basis and ``--constraints bernstein`` (FEM)."""
import numpy as np
import pytest
import scipy.sparse as sp
from ngsolve import H1, GridFunction, LinearForm, dx, x, y

from ngcontact import CrissCrossSquare
from ngcontact.discretizations import FEMDiscretization
from ngcontact.discretizations.bernstein import BernsteinBasis, bernstein_values
from ngcontact.discretizations.nodesets import lattice
from ngcontact.drivers import RunOptions, run_scene
from ngcontact.scenes import load_scene


@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_reference_bernstein_polynomials(p):
    rng = np.random.default_rng(p)
    bary = rng.dirichlet(np.ones(3), size=50)
    B = bernstein_values(p, bary)
    assert B.min() >= 0 and np.allclose(B.sum(axis=1), 1, atol=1e-14)
    # equal integrals |K| / dim P_p: a Duffy rule exact for degree p
    g, w = np.polynomial.legendre.leggauss(p + 2)
    g, w = (g + 1) / 2, w / 2
    u, v = np.meshgrid(g, g, indexing="ij")
    xi, eta = u.ravel(), (v * (1 - u)).ravel()
    wq = (np.outer(w, w) * (1 - u)).ravel()
    ints = 2 * wq @ bernstein_values(p, np.stack([xi, eta, 1 - xi - eta], axis=1))
    assert np.allclose(ints, 1 / len(lattice(p)), atol=1e-14)


@pytest.mark.parametrize("p", [2, 3, 4])
def test_global_basis(p):
    mesh = CrissCrossSquare().mesh(1)
    fes = H1(mesh, order=p)
    B = BernsteinBasis.build(fes)
    n = fes.ndof
    assert abs(B.V @ B.T - sp.identity(n)).max() < 1e-11
    assert abs(B.M @ B.Minv - sp.identity(n)).max() < 1e-11
    gf = GridFunction(fes)
    # partition of unity, and coefficients >= 0 give a function >= 0 everywhere (not only at nodes)
    gf.vec.FV().NumPy()[:] = B.T @ np.ones(n)
    pts = np.random.default_rng(0).uniform(0, 1, size=(400, 2))
    vals = np.array([gf(mesh(a, b)) for a, b in pts])
    assert np.allclose(vals, 1, atol=1e-12)
    c = np.random.default_rng(1).uniform(0, 1, n) ** 8  # many coefficients near 0
    gf.vec.FV().NumPy()[:] = B.T @ c
    assert min(gf(mesh(a, b)) for a, b in pts) >= 0
    # interpolation is exact on P_p: from_values of the values of a degree-p polynomial
    poly = (x - 0.3) ** p + x * y ** (p - 1)
    gf.vec.FV().NumPy()[:] = B.T @ B.from_values(B.evaluate(poly))
    exact = np.array([(a - 0.3) ** p + a * b ** (p - 1) for a, b in pts])
    assert np.allclose([gf(mesh(a, b)) for a, b in pts], exact, atol=1e-12)
    # every basis function has a positive integral
    ones = LinearForm(fes.TestFunction() * dx).Assemble().vec.FV().NumPy()
    assert (B.T.T @ ones).min() > 0


def test_fem_bernstein_p1_is_the_nodal_method():
    problem = load_scene("test1").problem
    mesh = CrissCrossSquare().mesh(1)
    a, b = (FEMDiscretization(problem, mesh, order=1, constraints=c).system for c in ("nodal", "bernstein"))
    assert abs(a.K - b.K).max() == 0 and np.array_equal(a.F, b.F)


def _min_gap(res, n=20000):
    disc = res.discretization
    gap = disc.gridfunctions(res.x, res.y)["gap"]
    pts = np.random.default_rng(2).uniform(0, 1, size=(n, 2))
    return float(np.min(gap(disc.mesh(pts[:, 0], pts[:, 1]))))


def test_fem_bernstein_p2_gap_nonnegative_everywhere_and_estimate_guaranteed():
    """test 1, P2 T0..T2: rate 2, the discrete gap >= 0 at every sampled point (its Bernstein coefficients
    are >= 0; the nodal method's gap dips below 0 between the nodes), the estimator a bound of the error."""
    scene = load_scene("test1")
    res = run_scene(scene, RunOptions.for_scene(scene, order=2, levels=3, constraints="bernstein", estimate=True))
    err = [r["err_energy"] for r in res.rows]
    assert np.log2(err[1] / err[2]) > 1.9
    assert all(r["i_eff"] >= 1.0 for r in res.rows)
    assert _min_gap(res) >= -1e-12
    nodal = run_scene(scene, RunOptions.for_scene(scene, order=2, levels=3))
    assert _min_gap(nodal) < -1e-8
