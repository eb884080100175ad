"""Change of basis hierarchical H1 <-> Lagrange nodal values (p = 1..4)."""
import numpy as np
import pytest
import scipy.sparse as sp
from ngsolve import H1, BilinearForm, GridFunction, dx, grad

from ngcontact import CrissCrossSquare, UnitDisk
from ngcontact.discretizations.lagrange import LagrangeNodes


@pytest.mark.parametrize("p", [1, 2, 3, 4])
@pytest.mark.parametrize("domain", [CrissCrossSquare(), UnitDisk(maxh=0.4)], ids=["square", "curved-disk"])
def test_evaluation_matrix_is_exact_and_inverted(p, domain):
    mesh = domain.mesh(1)
    if domain.curved:
        mesh.Curve(p)
    fes = H1(mesh, order=p, dirichlet=".*")
    nodes = LagrangeNodes.build(fes)
    rng = np.random.default_rng(p)
    c = rng.normal(size=fes.ndof)
    gf = GridFunction(fes)
    gf.vec.FV().NumPy()[:] = c
    values = np.array([gf(mesh(px, py)) for px, py in nodes.coords])
    np.testing.assert_allclose(nodes.V @ c, values, atol=1e-12)
    assert abs(nodes.V @ nodes.T - sp.identity(fes.ndof)).max() < 1e-12
    # CoefficientFunction values at the nodes through the mapped lattice points
    np.testing.assert_allclose(nodes.evaluate(gf), values, atol=1e-12)


@pytest.mark.parametrize("p", [2, 3, 4])
def test_nodal_stiffness_is_the_lagrange_stiffness(p):
    mesh = CrissCrossSquare().mesh(0)
    fes = H1(mesh, order=p)
    nodes = LagrangeNodes.build(fes)
    u, v = fes.TnT()
    a = BilinearForm(grad(u) * grad(v) * dx).Assemble()
    data, ind, ptr = a.mat.CSR()
    S = nodes.transform(sp.csr_matrix((np.array(data), np.array(ind), np.array(ptr))))
    # the Lagrange basis is a partition of unity: constants are in the kernel
    assert np.abs(S @ np.ones(fes.ndof)).max() < 1e-10
    assert abs(S - S.T).max() < 1e-12
    # boundary/interior classification: free dofs <-> nodes off the boundary
    free = np.array(list(H1(mesh, order=p, dirichlet=".*").FreeDofs()))
    xy = nodes.coords
    on_bnd = (np.minimum.reduce([xy[:, 0], 1 - xy[:, 0], xy[:, 1], 1 - xy[:, 1]]) < 1e-12)
    assert np.array_equal(~free, on_bnd)
