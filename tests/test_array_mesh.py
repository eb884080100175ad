"""P1 on the levels of structured rectangles held as arrays (domains.ArrayMesh): the same system as on the
NGSolve mesh of the level, the NGSolve mesh built only when something asks for it, and a fallback to it
for data that are not functions of the coordinates alone."""
from dataclasses import replace

import numpy as np
import pytest
from ngsolve import H1, CoefficientFunction, GridFunction, IfPos, Parameter, atan2, exp, sin, sqrt, specialcf, x, y

from ngcontact import CrissCrossSquare, StructuredSquare
from ngcontact.discretizations.base import coordinate_only
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.domains import DIRICHLET, ArrayMesh
from ngcontact.drivers import RunOptions, run_scene
from ngcontact.scenes import load_scene


def _level(domain, level, arrays):
    return list(domain.meshes(level + 1, arrays=arrays))[-1]


@pytest.mark.parametrize("scene, level", [("ex9_obstacle", 2), ("test1", 2)])
def test_array_level_gives_the_system_of_the_mesh(scene, level):
    problem = load_scene(scene).problem
    arr = _level(problem.domain, level, True)
    assert isinstance(arr, ArrayMesh)
    da = FEMDiscretization(problem, arr)
    dm = FEMDiscretization(problem, _level(problem.domain, level, False))
    sa, sm = da.system, dm.system
    assert (sa.K != sm.K).nnz == 0
    # data evaluated on MeshPoints of the coarsest mesh: the same values here (to rounding in general)
    for a, b in ((sa.F, sm.F), (sa.b, sm.b), (sa.D, sm.D), *zip(da.lift, dm.lift)):
        assert np.allclose(a, b, rtol=1e-14, atol=1e-14 * np.abs(b).max(initial=1.0))
    assert np.array_equal(da.interior, dm.interior)
    assert da.nelem == dm.mesh.ne and da.nvert == dm.mesh.nv


def test_the_mesh_is_built_on_first_use_and_matches_the_arrays():
    problem = load_scene("ex9_obstacle").problem  # f = 0: no load assembly
    arr = _level(problem.domain, 2, True)
    d = FEMDiscretization(problem, arr)
    assert d._mesh is None and d._fes is None  # nothing asked for them yet
    x0, y0 = d.initial_guess()
    assert d._mesh is None
    mesh = d.mesh
    assert mesh.ne == arr.ne and mesh.nv == arr.nv and mesh is arr.build()
    assert np.array_equal(mesh.ngmesh.Coordinates()[:, :2], arr.X)
    fes = d.fes
    free = np.array(list(fes.FreeDofs()), dtype=bool)
    assert np.array_equal(np.flatnonzero(free), d.interior)
    # after the mesh exists the nodes evaluate on it (not on the coarsest mesh: a GridFunction of this level
    # would be searched point by point there)
    assert d.nodes._points_of is None and d.nodes._mesh is mesh
    gf = GridFunction(H1(mesh, order=1))
    gf.Set(x + 2 * y)  # in the space: its nodal values are exact
    assert np.allclose(d.nodes.evaluate(gf), arr.X[:, 0] + 2 * arr.X[:, 1], atol=1e-13)


def test_dirichlet_vertices_of_the_arrays_are_those_of_the_space():
    arr = _level(CrissCrossSquare(n0=3), 2, True)
    fes = H1(arr.build(), order=1, dirichlet=DIRICHLET)
    assert np.array_equal(arr.dirichlet_vertices(), ~np.array(list(fes.FreeDofs()), dtype=bool))


def test_vertices_are_located_in_the_coarsest_mesh():
    dom = StructuredSquare(n0=3, xmin=-1, xmax=2, ymin=0, ymax=0.5)
    levels = list(dom.meshes(3, arrays=True))
    fine = levels[-1]
    mesh0, el, xi, eta = fine.vertex_location()
    assert mesh0.ne == levels[0].ne and len(el) == fine.nv
    assert xi.min() > -1e-14 and eta.min() > -1e-14 and (xi + eta).max() < 1 + 1e-14
    from ngcontact.discretizations.lagrange import meshpoints
    pts = meshpoints(mesh0, el, xi, eta)
    assert np.allclose(np.asarray(x(pts)).ravel(), fine.X[:, 0], atol=1e-15)
    assert np.allclose(np.asarray(y(pts)).ravel(), fine.X[:, 1], atol=1e-15)


@pytest.mark.parametrize("cf, pointwise", [
    (CoefficientFunction(2.5), True), (3 * x, True), (sin(x) * exp(-y) / 2, True), (atan2(y, x), True),
    (IfPos(x - 0.5, sqrt(x * x + y * y), -1.0), True), (Parameter(0.3) * x, True), (0 * x, True),
    (specialcf.normal(2)[0], False), (specialcf.mesh_size, False)])
def test_coordinate_only(cf, pointwise):
    assert coordinate_only(cf) is pointwise


def test_data_with_a_gridfunction_build_the_mesh_first():
    """A GridFunction (of another mesh) in the data: evaluated on the level's own mesh, as without arrays."""
    base = load_scene("ex9_obstacle").problem
    other = StructuredSquare(n0=4, xmin=-2, xmax=2, ymin=-2, ymax=2).mesh(0)
    gf = GridFunction(H1(other, order=1))
    gf.Set(0.1 * x)
    problem = replace(base, psi=base.psi + gf)
    assert not coordinate_only(problem.psi)
    arr = _level(problem.domain, 1, True)
    d = FEMDiscretization(problem, arr)
    assert d._mesh is not None  # built before any evaluation
    ref = FEMDiscretization(problem, _level(problem.domain, 1, False))
    assert np.array_equal(d.system.b, ref.system.b)


def test_nested_run_on_arrays_is_the_run_on_meshes(monkeypatch):
    scene = load_scene("ex9_obstacle")
    opts = RunOptions(levels=4, newton="multigrid")
    res = run_scene(scene, opts)
    assert isinstance(res.discretization._arrays, ArrayMesh)
    monkeypatch.setattr(FEMDiscretization, "array_meshes", False)
    ref = run_scene(scene, opts)
    assert ref.discretization._arrays is None
    for a, b in zip(res.rows, ref.rows):
        assert a["newton_its"] == b["newton_its"] and a["cg_its"] == b["cg_its"] and a["nelem"] == b["nelem"]
        assert a["err_max_nodal"] == pytest.approx(b["err_max_nodal"], rel=1e-12)
        assert a["err_energy"] == pytest.approx(b["err_energy"], rel=1e-12)
