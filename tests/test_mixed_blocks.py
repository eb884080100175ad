"""Element blocks of the mixed patch form from reference matrices (ngcontact.estimators.mixed_blocks) against
NGSolve's assembly of the form (ngcontact.estimators.patches._assembled_blocks)."""
import numpy as np
import pytest
from netgen.geom2d import SplineGeometry, unit_square
from ngsolve import H1, GridFunction, Mesh

from ngcontact.estimators.flux import _mixed_patch_problem
from ngcontact.estimators.flux import _flux_operator, PatchData
from ngcontact.estimators.mixed_blocks import AffineTriangles, flux_operators, mixed_element_blocks
from ngcontact.estimators.patches import PatchSolver, _assembled_blocks


def _sorted_facets(A_VF, fdofs):
    order = np.argsort(fdofs, axis=1)
    return np.take_along_axis(A_VF, order[:, None, :], axis=2), np.take_along_axis(fdofs, order, axis=1)


def _meshes():
    """An unstructured mesh, the same after two adaptive bisection steps, and one with a re-entrant corner."""
    ng = unit_square.GenerateMesh(maxh=0.25)
    yield Mesh(ng)
    mesh = Mesh(unit_square.GenerateMesh(maxh=0.3))
    for _ in range(2):
        for el in mesh.Elements():
            mesh.SetRefinementFlag(el, el.nr % 3 == 0)
        mesh.Refine()
    yield mesh
    geo = SplineGeometry()
    pts = [geo.AppendPoint(*p) for p in [(0, 0), (1, 0), (1, 1), (-1, 1), (-1, -1), (0, -1)]]
    for a, b in zip(pts, pts[1:] + pts[:1]):
        geo.Append(["line", a, b], bc="dirichlet")
    yield Mesh(geo.GenerateMesh(maxh=0.4))


@pytest.mark.parametrize("q", [1, 2, 3, 4])
def test_reference_blocks_equal_assembled(q):
    for mesh in _meshes():
        _, X, bf, _ = _mixed_patch_problem(mesh, q, 0.0)
        V, Q, _ = X.components
        ne = mesh.ne
        nV, nQ = V.ndof // ne, Q.ndof // ne
        ref = mixed_element_blocks(AffineTriangles.of(mesh), X, q)
        assert ref is not None
        A_II, A_VF, fd = _assembled_blocks(X, bf, ne, nV, nQ)
        scale = np.abs(A_II).max()
        assert np.abs(ref.per_element(ref.A_II) - A_II).max() <= 1e-13 * scale
        B, f = _sorted_facets(ref.per_element(ref.A_VF), ref.fdofs)
        assert np.array_equal(f, fd)
        assert np.abs(B - A_VF).max() <= 1e-13 * np.abs(A_VF).max()


def test_similar_triangles_share_one_block():
    """Uniform bisection of a structured mesh: few shapes (ranking class x similarity), every element's block is
    its own to round-off; an unstructured mesh keeps one block per element."""
    geo = SplineGeometry()
    pts = [geo.AppendPoint(*p) for p in [(0, 0), (1, 0.1), (1.2, 1), (0.3, 0.9)]]
    for a, b in zip(pts, pts[1:] + pts[:1]):
        geo.Append(["line", a, b], bc="dirichlet")
    mesh = Mesh(geo.GenerateMesh(maxh=0.2))
    assert mixed_element_blocks(AffineTriangles.of(mesh), _mixed_patch_problem(mesh, 1, 0.0)[1], 1).shape is None
    from ngcontact import CrissCrossSquare

    mesh = CrissCrossSquare(n0=4).mesh(3)
    _, X, bf, _ = _mixed_patch_problem(mesh, 2, 0.0)
    V, Q, _ = X.components
    ref = mixed_element_blocks(AffineTriangles.of(mesh), X, 2)
    assert ref.shape is not None and ref.nshapes <= 6 * 8 < mesh.ne / 10, (ref.nshapes, mesh.ne)
    A_II, A_VF, fd = _assembled_blocks(X, bf, mesh.ne, V.ndof // mesh.ne, Q.ndof // mesh.ne)
    assert np.abs(ref.per_element(ref.A_II) - A_II).max() <= 1e-13 * np.abs(A_II).max()


def test_curved_mesh_falls_back_to_assembly():
    geo = SplineGeometry()
    geo.AddCircle((0, 0), 1, bc="dirichlet")
    mesh = Mesh(geo.GenerateMesh(maxh=0.5))
    mesh.Curve(2)
    assert AffineTriangles.of(mesh) is None
    _, X, _, _ = _mixed_patch_problem(mesh, 2, 0.0)
    assert mixed_element_blocks(None, X, 2) is None


@pytest.mark.parametrize("q,p", [(1, 1), (2, 1), (2, 2), (3, 2), (3, 3), (4, 4)])
def test_reference_flux_operators_equal_assembled(q, p):
    """The hat-weighted flux operators (RT_q x P_q rows, P_p columns; q = p + 1: the flux_order option) from
    reference matrices against NGSolve's assembly of the operator's form (Hessian and element-boundary terms)."""
    for mesh in _meshes():
        _, X, bf, _ = _mixed_patch_problem(mesh, q, 0.0)
        ev = mesh.ngmesh.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
        tri = AffineTriangles.of(mesh)
        solver = PatchSolver(mesh, X, bf, ev, blocks=mixed_element_blocks(tri, X, q), affine=tri)
        u = GridFunction(H1(mesh, order=p, dirichlet="dirichlet|.*"))
        key, space, form_of_hat, _, _, reference = _flux_operator(solver, PatchData(u=u, mu=1.0, hessian=p > 1))
        assembled = PatchSolver.operators(solver, key, space, form_of_hat)      # no reference: NGSolve's assembly
        ref = reference(solver)
        assert ref is not None and ref is not assembled
        assert assembled.shape == ref.shape == (3 * mesh.ne * solver.nI, space.ndof)
        mat = ref.tocsr()
        assert abs(assembled - mat).max() <= 1e-12 * abs(assembled).max(), \
            abs(assembled - mat).max() / abs(assembled).max()
        U = np.random.default_rng(3).standard_normal((space.ndof, 3))  # element by element = the matrix
        for v in (U[:, 0], U):
            assert np.abs(ref @ v - mat @ v).max() <= 1e-13 * np.abs(mat @ v).max()
    assert flux_operators(None, solver.Y, q, space, True) is None


def test_shape_blocks_apply_like_per_element_products():
    """ElementBlocks.apply (shapes stacked by their numbers of elements) equals the product with the matrices
    gathered per element, for shapes with 1, 2 and 5 elements and for one block per element."""
    from ngcontact.estimators.mixed_blocks import ElementBlocks

    rng = np.random.default_rng(3)
    shape = rng.permutation(np.repeat(np.arange(6), [1, 2, 5, 2, 1, 5]))
    M, X = rng.standard_normal((6, 4, 3)), rng.standard_normal((len(shape), 3, 2))
    blocks = ElementBlocks(A_II=np.zeros((6, 1, 1)), A_VF=None, fdofs=None, shape=shape)
    assert np.abs(blocks.apply(M, X) - np.matmul(blocks.per_element(M), X)).max() <= 1e-15
    M1 = rng.standard_normal((len(shape), 4, 3))
    single = ElementBlocks(A_II=np.zeros((len(shape), 1, 1)), A_VF=None, fdofs=None)
    assert np.array_equal(single.apply(M1, X), np.matmul(M1, X))


@pytest.mark.parametrize("q,p", [(1, 2), (3, 3), (4, 4)])
def test_product_dofs_from_the_edges_of_the_fe_space(q, p, monkeypatch):
    """The dofs of X = broken RT x P_q x facet P_q built from the FE space's edge numbers equal NGSolve's, element by
    element, without a pass over X's elements; P1 spaces have no edge numbers, and a wrong edge table is caught by
    the sample check (the table is then read element by element)."""
    import ngcontact.estimators.mixed_blocks as MB
    from ngcontact.discretizations.base import element_dofs, element_edges

    assert element_edges(H1(Mesh(unit_square.GenerateMesh(maxh=0.3)), order=1)) is None
    for mesh in _meshes():
        _, X, _, _ = _mixed_patch_problem(mesh, q, 0.0)
        nI = X.components[0].ndof // mesh.ne + X.components[1].ndof // mesh.ne
        truth = np.array([list(el.dofs) for el in X.Elements()])
        edges = element_edges(H1(mesh, order=p))
        with monkeypatch.context() as m:
            m.setattr(MB, "element_dofs", lambda space: pytest.fail("read element by element"))
            np.testing.assert_array_equal(MB._product_dofs(X, mesh.ne, nI, edges), truth)
        wrong = edges.copy()
        wrong[-1] = wrong[-1, [1, 2, 0]]
        np.testing.assert_array_equal(MB._product_dofs(X, mesh.ne, nI, wrong), element_dofs(X))
