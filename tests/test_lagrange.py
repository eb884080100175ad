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


@pytest.mark.parametrize("p", [1, 2, 3])
@pytest.mark.parametrize("domain", [CrissCrossSquare(), UnitDisk(maxh=0.4), "lshape-refined"],
                         ids=["square", "curved-disk", "lshape-refined"])
def test_element_tables_are_those_of_the_elements(p, domain):
    """The vectorized vertex table and the shared dof table agree with NGSolve's elements, element by element
    (also on a curved and on a locally refined mesh), and the dof table is kept on the space and rebuilt after an
    Update (the refined mesh)."""
    from ngsolve import VOL

    from ngcontact import LShape
    from ngcontact.discretizations.base import element_dofs
    from ngcontact.discretizations.lagrange import _element_tables

    if domain == "lshape-refined":
        mesh = LShape(maxh=0.5).mesh(0)
        for _ in range(2):
            for el in mesh.Elements(VOL):
                mesh.SetRefinementFlag(el, el.nr % 3 == 0)
            mesh.Refine()
    else:
        mesh = domain.mesh(1)
    fes = H1(mesh, order=p)
    dofs, verts = _element_tables(fes, mesh.ne, (p + 1) * (p + 2) // 2)
    for el in fes.Elements(VOL):
        assert list(dofs[el.nr]) == list(el.dofs)
        assert list(verts[el.nr]) == [v.nr for v in el.vertices]
    assert element_dofs(fes) is element_dofs(fes)
    with pytest.raises(ValueError):
        element_dofs(fes)[0, 0] = 0  # shared: read-only
    if domain != "lshape-refined":
        return
    mesh.Refine()
    fes.Update()
    fresh = element_dofs(fes)
    assert fresh.shape[0] == mesh.ne and all(list(fresh[el.nr]) == list(el.dofs) for el in fes.Elements(VOL))
