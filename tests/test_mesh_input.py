"""A mesh of the user's as the domain: ngsolve.Mesh / netgen meshes accepted, quadrilaterals and 3D refused."""
import re

import ngsolve
import pytest
from netgen.csg import unit_cube
from netgen.geom2d import unit_square

from ngcontact import MeshDomain, MeshFileDomain, ProblemDataError, TwoMembraneProblem, as_domain
from ngcontact.drivers import RunOptions, run_scene
from ngcontact.scenes import Scene


def test_an_ngsolve_mesh_is_a_domain_with_refined_levels():
    mesh = ngsolve.Mesh(unit_square.GenerateMesh(maxh=0.25))
    domain = as_domain(mesh)
    assert isinstance(domain, MeshDomain) and as_domain(domain) is domain
    assert as_domain(mesh.ngmesh).name == domain.name == f"given mesh ({mesh.ne} triangles)"
    t0, t1 = domain.meshes(2)
    assert (t0.ne, t1.ne) == (mesh.ne, 4 * mesh.ne)
    assert mesh.ne == len(mesh.ngmesh.Elements2D())  # the caller's mesh is not refined
    problem = TwoMembraneProblem(domain=domain, f1=-8.0, f2=8.0, g1=0.0, g2=0.0)
    res = run_scene(Scene(name="mine", path=None, problem=problem), RunOptions(order=2, levels=2))
    assert res.converged and res.rows[-1]["active_nodes"] > 0


def test_a_problem_takes_an_ngsolve_mesh_as_its_domain():
    mesh = ngsolve.Mesh(unit_square.GenerateMesh(maxh=0.25))
    problem = TwoMembraneProblem(domain=mesh, f1=-8.0, f2=8.0, g1=0.0, g2=0.0)
    assert isinstance(problem.domain, MeshDomain)
    res = run_scene(Scene(name="mine", path=None, problem=problem), RunOptions(order=1, levels=2))
    assert res.converged and res.rows[0]["nelem"] == mesh.ne and res.rows[1]["nelem"] == 4 * mesh.ne
    with pytest.raises(ProblemDataError, match="domain must be .* or an ngsolve.Mesh, got str"):
        TwoMembraneProblem(domain="square.vol", f1=-8.0, f2=8.0, g1=0.0, g2=0.0)


@pytest.mark.parametrize("make, words", [
    (lambda: unit_square.GenerateMesh(maxh=0.4, quad_dominated=True), "quadrilateral element(s)"),
    (lambda: unit_cube.GenerateMesh(maxh=0.5), "is a 3D mesh"),
])
def test_unsupported_meshes_are_refused_with_a_message(make, words, tmp_path):
    mesh = make()
    with pytest.raises(ValueError, match=re.escape(words)):
        MeshDomain(ngsolve.Mesh(mesh))
    path = tmp_path / "m.vol"
    mesh.Save(str(path))
    with pytest.raises(ValueError, match=f"MeshFileDomain.path .*{re.escape(words)}"):
        MeshFileDomain(str(path)).mesh(0)


def test_other_objects_are_not_domains():
    with pytest.raises(TypeError, match="ngcontact Domain .* or an ngsolve.Mesh, got str"):
        as_domain("square.vol")
