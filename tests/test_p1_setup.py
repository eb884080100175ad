"""The vectorized P1 set-up (ngcontact.discretizations.p1, algebra.sparse) against NGSolve's assembly and
the general path of FEMDiscretization: same matrices to rounding, same nodes, free dofs and data."""
import numpy as np
import pytest
import scipy.sparse as sp
from ngsolve import H1, BilinearForm, LinearForm, dx, grad

import ngcontact.discretizations.fem as fem
import ngcontact.discretizations.p1_levels as p1_levels
from ngcontact import CrissCrossSquare, StructuredSquare
from ngcontact.algebra.sparse import abs_row_sums, row_entries, submatrix
from ngcontact.discretizations.base import scipy_csr
from ngcontact.discretizations.lagrange import LagrangeNodes
from ngcontact.discretizations.p1 import dirichlet_vertices, p1_matrices, p1_tables, symmetric_from_upper
from ngcontact.domains import DIRICHLET, LShape, UnitDisk
from ngcontact.scenes import load_scene


def _meshes():
    disk = UnitDisk(maxh=0.3, interface_radius=0.5).mesh(0)
    lshape = LShape(maxh=0.5).mesh(0)
    lshape.SetRefinementFlags([i % 3 == 0 for i in range(lshape.ne)])
    lshape.Refine()  # bisection: hanging-free, unstructured numbering
    return {"structured": StructuredSquare(n0=6, xmin=-2, xmax=2).mesh(1),
            "criss-cross": CrissCrossSquare(n0=3).mesh(1), "disk-interface": disk, "lshape-bisected": lshape}


MESHES = _meshes()


@pytest.mark.parametrize("name", sorted(MESHES))
def test_p1_matrices_are_ngsolves(name):
    mesh = MESHES[name]
    fes = H1(mesh, order=1, dirichlet=DIRICHLET)
    tables = p1_tables(mesh, fes)
    assert tables is not None
    u, v = fes.TnT()
    S = scipy_csr(BilinearForm(grad(u) * grad(v) * dx).Assemble())
    K, w = p1_matrices(*tables)
    assert abs(K - S).max() <= 1e-13 * abs(S).max()
    # the pattern: NGSolve's (every vertex pair of a triangle) without the couplings of right angles, which
    # NGSolve stores as 0 or as a rounding residue
    Snz = S.copy()
    Snz.data[np.abs(Snz.data) <= 1e-14 * abs(S).max()] = 0.0
    Snz.eliminate_zeros()
    assert K.shape == S.shape and K.nnz == Snz.nnz and np.all(K.data != 0)
    assert (K != 0).multiply(Snz != 0).nnz == K.nnz  # the same entries
    ones = LinearForm(v * dx).Assemble().vec.FV().NumPy()
    assert np.abs(w - ones).max() <= 1e-14 * ones.max()
    bnd = dirichlet_vertices(mesh, DIRICHLET, fes)
    assert np.array_equal(~bnd, np.array(list(fes.FreeDofs()), dtype=bool))


def test_dirichlet_vertices_refuses_a_count_mismatch():
    mesh = MESHES["disk-interface"]
    fes = H1(mesh, order=1, dirichlet=DIRICHLET)
    assert dirichlet_vertices(mesh, DIRICHLET, fes) is not None
    assert dirichlet_vertices(mesh, ".*", fes) is None  # the interface nodes are free in fes


def test_p1_tables_refuse_other_spaces():
    mesh = MESHES["structured"]
    assert p1_tables(mesh, H1(mesh, order=2)) is None


@pytest.mark.parametrize("name", sorted(MESHES))
def test_p1_nodes_are_those_of_the_general_build(name):
    mesh = MESHES[name]
    fes = H1(mesh, order=1, dirichlet=DIRICHLET)
    a, b = LagrangeNodes.build(fes), LagrangeNodes.from_p1_tables(fes, *p1_tables(mesh, fes))
    # the netgen vertices, bitwise; build's mapped reference points round differently (by 1e-17) on some meshes
    assert np.array_equal(b.coords, np.asarray(mesh.ngmesh.Coordinates())[:, :2])
    assert np.abs(a.coords - b.coords).max() <= 1e-15 * np.abs(a.coords).max()
    assert np.array_equal(a.elem_nodes, b.elem_nodes) and np.array_equal(a.elem_dofs, b.elem_dofs)
    assert all(np.array_equal(p, q) for p, q in zip(a.rep, b.rep))
    assert (a.V != b.V).nnz == 0 and np.array_equal(a.level, b.level)
    cf = load_scene("ex9_obstacle").problem.psi
    assert np.array_equal(a.evaluate(cf), b.evaluate(cf))
    where = np.arange(0, fes.ndof, 3)
    assert np.array_equal(a.evaluate(cf, where), b.evaluate(cf, where))
    assert np.array_equal(a.evaluate(cf)[where], b.evaluate(cf, where))


def _general(monkeypatch, problem, mesh, **kw):
    with monkeypatch.context() as m:
        m.setattr(fem, "p1_tables", lambda *a: None)
        return fem.FEMDiscretization(problem, mesh, **kw)


@pytest.mark.parametrize("scene, mesh", [("ex9_obstacle", None), ("test1", None), ("disk", "disk-interface")])
def test_fem_p1_fast_setup_matches_the_general_path(monkeypatch, scene, mesh):
    problem = load_scene(scene).problem
    m = problem.domain.mesh(1) if mesh is None else MESHES[mesh]
    fast, ref = fem.FEMDiscretization(problem, m, order=1), _general(monkeypatch, problem, m, order=1)
    assert isinstance(fast.nodes, LagrangeNodes) and fast.nodes._points is None  # the fast path ran
    assert ref.nodes._points is not None  # the general one
    assert np.array_equal(fast.interior, ref.interior) and np.array_equal(fast.boundary, ref.boundary)
    s, r = fast.system, ref.system
    assert abs(s.K - r.K).max() <= 1e-13 * abs(r.K).max()
    scale = max(np.abs(r.F).max(), 1e-300)
    assert np.abs(s.F - r.F).max() <= 1e-13 * scale
    assert np.abs(s.D - r.D).max() <= 1e-14 * r.D.max()
    assert np.array_equal(s.b, r.b) and np.array_equal(s.up, r.up) and np.array_equal(s.lo, r.lo)
    assert all(np.array_equal(p, q) for p, q in zip(fast.lift, ref.lift))


def test_fem_p2_system_is_the_two_step_extraction():
    """Order 2 (general path): K and F are, bitwise, those of the Lagrange-basis matrix indexed in two steps."""
    problem = load_scene("ex9_obstacle").problem
    disc = fem.FEMDiscretization(problem, problem.domain.mesh(0), order=2)
    u, v = disc.fes.TnT()
    S = disc.nodes.transform(scipy_csr(BilinearForm(grad(u) * grad(v) * dx).Assemble()))
    i, b = disc.interior, disc.boundary
    K = S[i][:, i]
    assert all(np.array_equal(getattr(disc.system.K, a), getattr(K, a)) for a in ("indptr", "indices", "data"))
    F = -(S[i][:, b] @ disc.lift[0][b])  # f = 0
    assert np.array_equal(disc.system.F, F)


@pytest.mark.parametrize("rows, cols", [("mask", "mask"), ("index", "index"), ("index", "all")])
def test_submatrix_is_the_two_step_index(rows, cols):
    rng = np.random.default_rng(1)
    A = sp.random(60, 50, density=0.2, random_state=2, format="csr")
    A.data[::7] = 0.0  # explicit zeros stay
    rmask, cmask = rng.random(60) < 0.6, rng.random(50) < 0.5
    r = rmask if rows == "mask" else np.flatnonzero(rmask)
    c = {"mask": cmask, "index": np.flatnonzero(cmask), "all": np.arange(50)}[cols]
    want = A[np.flatnonzero(rmask)][:, np.flatnonzero(cmask) if cols != "all" else np.arange(50)]
    got = submatrix(A, r, c)
    assert got.shape == want.shape
    for name in ("indptr", "indices", "data"):
        assert np.array_equal(getattr(got, name), getattr(want, name)), name


def test_abs_row_sums_are_those_of_abs_a():
    """The absolute row sums (infinity norm of pcg's floor, Gershgorin bound of the Chebyshev smoother) equal
    abs(A).sum(axis=1), on rows of mixed signs and on empty rows (the first, inner ones and the last)."""
    A = sp.random(40, 30, density=0.15, random_state=3, format="lil")
    A[[0, 7, 8, 39], :] = 0.0
    A = A.tocsr()
    A.data -= 0.5
    assert np.count_nonzero(np.diff(A.indptr) == 0) >= 4 and (A.data < 0).any()
    want = np.asarray(abs(A).sum(axis=1)).ravel()
    assert np.array_equal(abs_row_sums(A), want)
    assert np.array_equal(abs_row_sums(A.tocsc()), want)


def test_symmetric_from_upper_is_the_sparse_sum():
    """S = U + U^T + diag written row by row equals scipy's sums entry for entry (canonical; rows without an
    upper or a lower part, zero diagonal entries not stored, an empty row)."""
    U = sp.triu(sp.random(30, 30, density=0.2, random_state=6, format="csr"), 1, format="csr")
    U = sp.csr_matrix(U.toarray())
    diag = np.random.default_rng(7).random(30) + 1.0
    diag[[0, 11, 29]] = 0.0
    U = U.tolil()
    U[11, :] = 0.0
    U[:, 11] = 0.0
    U = U.tocsr()
    U.eliminate_zeros()
    want = U + U.T.tocsr() + sp.diags(diag, format="csr")
    want.sort_indices()
    got = symmetric_from_upper(U, diag)
    assert got.has_canonical_format and np.diff(got.indptr)[11] == 0 and np.diff(U.indptr)[0] > 0
    for name in ("indptr", "indices", "data"):
        assert np.array_equal(getattr(got, name), getattr(want, name)), name


def test_row_entries_are_those_of_the_row_index():
    """row_entries(indptr, rows) reads the entries of the rows in their order, repeated and empty rows included."""
    A = sp.random(30, 20, density=0.15, random_state=8, format="lil")
    A[4, :] = 0.0
    A = A.tocsr()
    rows = np.array([7, 4, 0, 29, 7, 13])
    assert np.array_equal(A.indices[row_entries(A.indptr, rows)], A[rows].indices)
    assert np.array_equal(A.data[row_entries(A.indptr, rows)], A[rows].data)
    assert len(row_entries(A.indptr, np.array([], dtype=int))) == 0


def test_submatrix_refuses_bad_selections():
    A = sp.identity(5, format="csr")
    with pytest.raises(ValueError, match="increasing"):
        submatrix(A, [2, 1], [0])
    with pytest.raises(ValueError, match="mask has length 4"):
        submatrix(A, np.ones(4, dtype=bool), [0])


@pytest.mark.parametrize("name", sorted(MESHES))
def test_p1_matrices_chunks_agree(name):
    """Chunks of triangles summed as CSR matrices: the same matrix as one chunk, canonical, symmetric."""
    X, T = p1_tables(MESHES[name])
    one, w1 = p1_matrices(X, T)
    many, w7 = p1_matrices(X, T, chunk=7)
    assert one.has_canonical_format and many.has_canonical_format
    assert np.array_equal(one.indptr, many.indptr) and np.array_equal(one.indices, many.indices)
    assert np.abs(one.data - many.data).max() <= 1e-15 * np.abs(one.data).max()
    assert np.abs(w1 - w7).max() <= 1e-15 * w1.max()
    assert abs(one - one.T).max() == 0.0


@pytest.mark.parametrize("scene, order", [("ex9_obstacle", 1), ("test1", 1), ("lshape", 3), ("disk_fitted", 2)])
def test_nodal_data_in_one_pass_are_the_single_evaluations(scene, order):
    """The data evaluated in one pass (a vector CoefficientFunction) are, bitwise, those of one evaluation each
    (P1 arrays, and the Lagrange nodes of NGSolve meshes of higher degree, curved included)."""
    problem = load_scene(scene).problem
    disc = fem.FEMDiscretization(problem, problem.domain.mesh(1), order=order)
    got = fem._nodal_data(problem, disc.nodes, disc.boundary)
    assert list(got) == list(problem.data())
    for name, cf in problem.data().items():
        if name in problem.dirichlet_names:
            want = np.zeros(disc.nodes.ndof)
            want[disc.boundary] = disc.nodes.evaluate(cf, disc.boundary)
        else:
            want = disc.nodes.evaluate(cf)
        assert np.array_equal(got[name], want), name
    # the lifts of the discretization are the Dirichlet data at the boundary nodes, zero inside
    for lift, g in zip(disc.lift, problem.dirichlet):
        want = np.zeros(disc.nodes.ndof)
        want[disc.boundary] = disc.nodes.evaluate(g, disc.boundary)
        assert np.array_equal(lift, want)


def test_parent_pairs_are_kept_for_their_coarse_level_only():
    problem = load_scene("ex9_obstacle").problem
    d0, d1, d2 = (fem.FEMDiscretization(problem, m, order=1) for m in problem.domain.meshes(3))
    pairs = fem._parent_pairs(d1, d2)
    assert pairs is not None and fem._parent_pairs(d1, d2) is pairs
    assert fem._parent_pairs(d0, d2) is None  # not the parent level: checked afresh, refused
    assert fem._parent_pairs(d0, d1) is not None


def test_load_compiled_is_the_same_vector_and_zero_data_stay_folded():
    """assemble_load with compiled data: bitwise the load of the plain integrand; a zero datum is recognized on
    the plain integrand (NGSolve folds 0 * v), so the compiled one is never built or assembled."""
    from ngsolve import CoefficientFunction, x, y

    from ngcontact.discretizations.base import assemble_load

    mesh = load_scene("test1").problem.domain.mesh(1)
    fes = H1(mesh, order=2)
    v = fes.TestFunction()
    f = (x - 0.3) ** 3 * y + 1
    plain = assemble_load(fes, lambda: f * v * dx(bonus_intorder=4))
    fast = assemble_load(fes, lambda: f * v * dx(bonus_intorder=4), lambda: f.Compile() * v * dx(bonus_intorder=4))
    assert np.array_equal(plain, fast) and np.abs(plain).max() > 0
    zero = CoefficientFunction(0.0)

    def never():
        raise AssertionError("the compiled integrand of zero data was built")

    assert not assemble_load(fes, lambda: zero * v * dx, never).any()


def _polynomial_membranes(domain):
    from ngsolve import x, y

    from ngcontact import TwoMembraneProblem

    # degree <= 6: the P1 load integrands (degree <= 7) are integrated exactly by the order-8 rule of every level
    return TwoMembraneProblem(domain=domain, f1=1 + x * y * (1 - x) ** 3, f2=-(x ** 2) * y ** 4, g1=0.1, g2=0.0,
                              mu1=1.0, mu2=2.0)


@pytest.mark.parametrize("domain", [CrissCrossSquare(n0=3), StructuredSquare(n0=4)])
def test_nested_loads_are_the_assembled_loads_of_every_level(domain):
    """The finest level's vectors are (bitwise) those its discretization assembles; a coarser level's, the
    restriction P^T F, are its own assembled loads where both quadratures are exact (polynomial loads)."""
    problem = _polynomial_membranes(domain)
    meshes = list(domain.meshes(3, arrays=True))
    loads = p1_levels.nested_loads(problem, meshes)
    assert len(loads) == 3
    for j, m in enumerate(domain.meshes(3, arrays=True)):
        disc = fem.FEMDiscretization(problem, m, order=1)
        for k, f in enumerate(problem.loads):
            want = disc.load_vector(f)
            if j == 2:
                assert np.array_equal(loads[j][k], want)
            else:
                assert np.abs(loads[j][k] - want).max() <= 1e-14 * np.abs(want).max(), (j, k)


@pytest.mark.parametrize("scene,domain", [("test1", CrissCrossSquare(n0=3)),
                                          ("ex9_obstacle", StructuredSquare(n0=4, xmin=-2, xmax=2, ymin=-2, ymax=2))])
def test_nested_data_are_the_evaluated_data_of_every_level(scene, domain):
    """The data injected from the finest level are those each level's set-up evaluates (the same points)."""
    from dataclasses import replace

    problem = replace(load_scene(scene).problem, domain=domain)
    data = p1_levels.nested_data(problem, list(domain.meshes(3, arrays=True)))
    assert len(data) == 3
    for j, m in enumerate(domain.meshes(3, arrays=True)):
        disc = fem.FEMDiscretization(problem, m, order=1)
        want = fem._nodal_data(problem, disc.nodes, disc.boundary)
        assert list(data[j]) == list(want)
        for name, v in want.items():
            assert np.abs(data[j][name] - v).max() <= 1e-15 * max(np.abs(v).max(), 1.0), (j, name)
        # and the discretization built from them is the one that evaluates them
        given = fem.FEMDiscretization(problem, m, order=1, data=data[j])
        assert np.abs(given.system.F - disc.system.F).max() <= 1e-14 * np.abs(disc.system.F).max()
        assert np.abs(given.system.b - disc.system.b).max() <= 1e-15 * max(np.abs(disc.system.b).max(), 1.0)


def test_nested_inputs_apply_to_p1_on_array_hierarchies_only():
    problem = _polynomial_membranes(CrissCrossSquare(n0=2))
    meshes = list(problem.domain.meshes(2, arrays=True))
    assert p1_levels.nested_loads(problem, meshes, order=2) is None
    assert p1_levels.nested_loads(problem, meshes, constraints="bernstein") is None
    for kw in (dict(order=2), dict(constraints="bernstein")):
        assert p1_levels.nested_data(problem, meshes, **kw) is None
        assert p1_levels.nested_inputs(problem, meshes, **kw) is None
    ngmeshes = list(problem.domain.meshes(2))
    assert p1_levels.nested_inputs(problem, ngmeshes) is None
    ex9 = load_scene("ex9_obstacle").problem  # f = 0: no loads, the data only
    levels = list(ex9.domain.meshes(2, arrays=True))
    assert p1_levels.nested_loads(ex9, levels) is None
    assert all(list(kw) == ["data"] for kw in p1_levels.nested_inputs(ex9, levels))
    # data that are not functions of the coordinates only: no injection (the level builds its NGSolve mesh)
    from dataclasses import replace

    from ngsolve import specialcf

    odd = replace(problem, g1=0.1 + 0 * specialcf.mesh_size)
    assert p1_levels.nested_data(odd, meshes) is None
    assert list(p1_levels.nested_inputs(odd, meshes)[0]) == ["loads"]


def test_loads_of_the_wrong_shape_are_refused():
    problem = _polynomial_membranes(CrissCrossSquare(n0=2))
    mesh = next(problem.domain.meshes(1, arrays=True))
    with pytest.raises(ValueError, match=r"loads: expected 2 vectors of length 13, got shapes \[\(13,\), \(12,\)\]"):
        fem.FEMDiscretization(problem, mesh, order=1, loads=[np.zeros(13), np.zeros(12)])
    good = p1_levels.nested_data(problem, [mesh])[0]
    with pytest.raises(ValueError, match=r"data: expected the values of \['f1', 'f2', 'g1', 'g2'\] at 13 vertices, "
                                         r"got .*'g2': \(12,\)"):
        fem.FEMDiscretization(problem, mesh, order=1, data={**good, "g2": np.zeros(12)})
    with pytest.raises(ValueError, match="data: nodal data are taken by P1 on an ArrayMesh"):
        fem.FEMDiscretization(problem, problem.domain.mesh(0), order=1, data=good)


def test_uniform_runs_use_the_restricted_loads(monkeypatch):
    """A nested P1 run on array levels discretizes every level with the restriction of the finest load and the
    data injected from it (its systems' right-hand sides are those of FEMDiscretization(..., **nested_inputs))."""
    from ngcontact.drivers import RunOptions, run_scene

    scene = load_scene("test1")
    got, evaluations = [], []
    p1_data = p1_levels._nodal_data
    for module in (fem, p1_levels):  # where the levels and the finest level evaluate
        monkeypatch.setattr(module, "_nodal_data", lambda *a: evaluations.append(1) or p1_data(*a))
    run_scene(scene, RunOptions.for_scene(scene, levels=3),
              on_level=lambda res: got.append(res.discretization.system.F.copy()))
    assert len(evaluations) == 1  # the data are evaluated on the finest level only
    monkeypatch.undo()
    problem = scene.problem
    inputs = p1_levels.nested_inputs(problem, list(problem.domain.meshes(3, arrays=True)))
    assert all(sorted(kw) == ["data", "loads"] for kw in inputs)
    for j, m in enumerate(problem.domain.meshes(3, arrays=True)):
        want = fem.FEMDiscretization(problem, m, order=1, **inputs[j]).system.F
        assert np.array_equal(got[j], want), j
    assert not np.array_equal(got[0], fem.FEMDiscretization(problem, next(problem.domain.meshes(1, arrays=True)),
                                                            order=1).system.F)


def test_other_domains_are_generated_level_by_level(monkeypatch):
    """Only array levels are generated before level 0: a curved domain's NGSolve meshes come one at a time."""
    from ngcontact.drivers import RunOptions, run_scene

    scene = load_scene("disk")
    domain_type = type(scene.problem.domain)
    meshes = domain_type.meshes
    yielded = []

    def counting(self, levels, arrays=False):
        for m in meshes(self, levels, arrays=arrays):
            yielded.append(m)
            yield m

    monkeypatch.setattr(domain_type, "meshes", counting)
    seen = []
    res = run_scene(scene, RunOptions.for_scene(scene, levels=2), on_level=lambda r: seen.append(len(yielded)))
    assert seen == [1, 2] and len(res.rows) == 2
    assert res.rows[0]["time_mesh_s"] > 0


def test_bit_mask_is_the_bitarray():
    """base.bit_mask: the bits of a BitArray, as iterating it gives them (free dofs of H1 spaces with Dirichlet
    parts, all free, none free, empty)."""
    from ngsolve import H1, BitArray

    from ngcontact.discretizations.base import bit_array, bit_mask

    mesh = load_scene("lshape").problem.domain.mesh(0)
    for bits in (H1(mesh, order=3, dirichlet=".*").FreeDofs(), H1(mesh, order=2, dirichlet="").FreeDofs(),
                 H1(mesh, order=1, dirichlet=".*").FreeDofs(), BitArray([False, True, True, False, True]),
                 BitArray([False] * 7), BitArray(0)):
        want = np.array(list(bits), dtype=bool)
        got = bit_mask(bits)
        assert got.dtype == bool and np.array_equal(got, want)
        assert np.array_equal(np.array(list(bit_array(want)), dtype=bool), want)  # and back
