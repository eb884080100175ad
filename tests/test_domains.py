"""Tests of ngcontact.domains: mesh counts of [CAMWA21], nesting, boundary names."""
import numpy as np
import pytest
from ngsolve import H1, Integrate
from netgen.occ import Circle, OCCGeometry

from ngcontact.domains import (CrissCrossSquare, GeometryDomain, LShape, MeshFileDomain,
                               StructuredSquare, UnitDisk, mesh_size)


def arrays(mesh):
    """Vertex coordinates, triangles and boundary segments (0-based) of an NGSolve mesh.

    Copies: ``Coordinates()`` is a view that dies with the mesh.
    """
    ngm = mesh.ngmesh
    T = ngm.Elements2D().NumPy()["nodes"][:, :3] - 1
    S = ngm.Elements1D().NumPy()["nodes"][:, :2] - 1
    return np.array(ngm.Coordinates()), T, S


def free_count(mesh, order):
    return sum(H1(mesh, order=order, dirichlet=".*").FreeDofs())


def areas(X, T):
    a, b = X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]
    return 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def small_domains(tmp_path):
    disk_file = tmp_path / "disk.vol"
    UnitDisk(maxh=0.4).mesh(0).ngmesh.Save(str(disk_file))
    return [CrissCrossSquare(2), StructuredSquare(4, -1.0, 1.0, 0.0, 0.5), UnitDisk(maxh=0.4),
            LShape(maxh=0.5), MeshFileDomain(disk_file, curved=True),
            GeometryDomain(OCCGeometry(Circle((0, 0), 1).Face(), dim=2), maxh=0.5)]


@pytest.mark.parametrize("level, ntri, nv, nint", [(0, 64, 41, 25), (1, 256, 145, 113),
                                                   (2, 1024, 545, 481)])
def test_criss_cross_counts(level, ntri, nv, nint):
    mesh = CrissCrossSquare().mesh(level)
    assert (mesh.ne, mesh.nv, free_count(mesh, 1)) == (ntri, nv, nint)
    assert np.allclose(areas(*arrays(mesh)[:2]), 1.0 / ntri)  # all congruent, oriented
    assert CrissCrossSquare().h(level) == mesh_size(mesh) == 0.25 / 2 ** level


def test_criss_cross_fem_dofs():
    """FEM DOF table of [CAMWA21] (3 fields x interior Lagrange nodes)."""
    d = CrissCrossSquare()
    t0 = d.mesh(0)
    assert t0.nedge == 104
    assert [3 * free_count(t0, p) for p in (1, 2, 3, 4)] == [75, 339, 795, 1443]
    assert 3 * free_count(d.mesh(1), 2) == 1443


def test_criss_cross_red_refinement_is_nested():
    X0, T0, _ = arrays(CrissCrossSquare().mesh(0))
    X1, T1, _ = arrays(CrissCrossSquare().mesh(1))
    assert np.array_equal(X1[:len(X0)], X0)  # coarse vertices keep their numbers
    # children 4k..4k+3 lie in parent k (red refinement, not criss-cross 8x8)
    centroids = X1[T1].mean(axis=1).reshape(-1, 4, 2)
    lam = np.linalg.solve(np.stack([X0[T0[:, 1]] - X0[T0[:, 0]], X0[T0[:, 2]] - X0[T0[:, 0]]], -1),
                          centroids.transpose(1, 0, 2)[..., None] - X0[T0[:, 0]][..., None])[..., 0]
    assert lam.min() > 0 and lam.sum(axis=-1).max() < 1


def test_structured_square():
    d = StructuredSquare(n0=16)
    m0, m1 = d.mesh(0), d.mesh(1)
    assert (m0.ne, m0.nv, m1.ne) == (512, 289, 2048)
    X, T, _ = arrays(m0)
    assert np.allclose(areas(X, T), 0.5 / 256)
    # every diagonal runs from (x_i, y_j) to (x_{i+1}, y_{j+1})
    E = X[T] - X[np.roll(T, 1, axis=1)]
    diag = E[np.all(np.abs(E) > 1e-12, axis=-1)]
    assert len(diag) == 512 and np.allclose(diag[:, 0], diag[:, 1])
    assert d.h(1) == 1 / 32


def test_disk_refinement_projects_onto_circle():
    d = UnitDisk(maxh=0.3, radius=2.0, center=(1.0, -1.0))
    m0, m1 = d.mesh(0), d.mesh(1)
    assert m1.ne == 4 * m0.ne and d.curved
    X, _, S = arrays(m1)
    r = np.linalg.norm(X[np.unique(S)] - [1.0, -1.0], axis=1)
    assert np.abs(r - 2.0).max() < 1e-12


def test_meshes_are_independent_and_match_mesh():
    d = UnitDisk(maxh=0.5)
    ms = list(d.meshes(3))
    assert [m.ne for m in ms] == [d.mesh(k).ne for k in range(3)]
    assert np.array_equal(ms[2].ngmesh.Coordinates(), d.mesh(2).ngmesh.Coordinates())
    ms[0].Refine()
    assert ms[1].ne == 4 * d.mesh(0).ne
    cc = list(CrissCrossSquare(2).meshes(3))
    assert [m.ne for m in cc] == [16, 64, 256]
    assert np.array_equal(arrays(cc[2])[0], arrays(CrissCrossSquare(2).mesh(2))[0])


def test_all_domains_whole_boundary_named_and_dirichlet(tmp_path):
    for d in small_domains(tmp_path):
        for mesh in d.meshes(2):
            X, T, S = arrays(mesh)
            assert areas(X, T).min() > 0, d.name
            E = np.sort(T[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
            e, cnt = np.unique(E, axis=0, return_counts=True)
            assert np.array_equal(e[cnt == 1], np.unique(np.sort(S, axis=1), axis=0)), d.name
            assert all(mesh.GetBoundaries()), d.name
            free = np.array(H1(mesh, order=1, dirichlet=".*").FreeDofs())
            assert not free[np.unique(S)].any() and free.sum() == mesh.nv - len(np.unique(S))
            assert mesh_size(mesh) > 0 and isinstance(d.name, str)


def test_lshape_and_mesh_file(tmp_path):
    m = LShape().mesh(1)
    assert abs(Integrate(1, m) - 3.0) < 1e-12 and not LShape().curved
    assert 0.1 < LShape().h(0) < 0.5  # netgen's maxh is not a strict bound
    disk = UnitDisk(maxh=0.4)
    path = tmp_path / "disk.vol"
    disk.mesh(0).ngmesh.Save(str(path))
    LShape(maxh=0.5).mesh(0)  # netgen's Mesh.Load would attach this (last meshed) geometry
    X, T, S = arrays(MeshFileDomain(path).mesh(1))
    assert len(T) == disk.mesh(1).ne and areas(X, T).min() > 0
    assert np.linalg.norm(X[np.unique(S)], axis=1).max() < 1 + 1e-12  # midpoints: inside
    X, _, S = arrays(MeshFileDomain(path, curved=True, geometry=disk.geometry).mesh(1))
    assert np.abs(np.linalg.norm(X[np.unique(S)], axis=1) - 1).max() < 1e-12
    with pytest.raises(FileNotFoundError, match="nope.vol"):
        MeshFileDomain(tmp_path / "nope.vol")
    (tmp_path / "bad.vol").write_text("garbage\n")
    with pytest.raises(ValueError, match="bad.vol"):
        MeshFileDomain(tmp_path / "bad.vol").mesh()


@pytest.mark.parametrize("make, field", [
    (lambda: CrissCrossSquare(0), "n0"), (lambda: CrissCrossSquare(2.5), "n0"),
    (lambda: CrissCrossSquare(xmax=-1.0), "xmax"), (lambda: StructuredSquare(ymin="a"), "ymin"),
    (lambda: StructuredSquare(True), "n0"), (lambda: UnitDisk(maxh=0), "maxh"),
    (lambda: UnitDisk(radius=-1), "radius"), (lambda: UnitDisk(center=(0,)), "center"),
    (lambda: LShape(maxh=float("nan")), "maxh"), (lambda: GeometryDomain(None, 0.1), "geometry"),
    (lambda: MeshFileDomain(3), "path"), (lambda: MeshFileDomain(__file__, geometry=1), "geometry"), (lambda: CrissCrossSquare().mesh(-1), "level"),
    (lambda: list(CrissCrossSquare().meshes(1.5)), "levels"),
])
def test_bad_arguments(make, field):
    with pytest.raises(ValueError, match=field):
        make()


def test_disk_with_interface_fits_the_circle_and_keeps_it_out_of_the_dirichlet_boundary():
    from ngcontact.domains import DIRICHLET

    rho = 2 ** -0.5
    d = UnitDisk(maxh=0.3, interface_radius=rho)
    m = d.mesh(1)
    assert set(m.GetBoundaries()) == {"boundary", "interface"}
    X, _, S = arrays(m)
    r = np.linalg.norm(X[np.unique(S)], axis=1)  # every segment vertex on one of the two circles
    assert np.all(np.minimum(np.abs(r - 1.0), np.abs(r - rho)) < 1e-12)
    V = H1(m, order=1, dirichlet=DIRICHLET)
    on_outer = int(np.sum(np.abs(np.linalg.norm(X, axis=1) - 1.0) < 1e-12))
    assert sum(V.FreeDofs()) == m.nv - on_outer
    for bad in (0.0, 1.0, -0.5, float("nan")):
        with pytest.raises(ValueError, match="interface_radius"):
            UnitDisk(maxh=0.3, interface_radius=bad)


def test_interface_meshes_are_rejected_by_hho_and_dg():
    from ngcontact.discretizations import DISCRETIZATIONS
    from ngcontact.scenes import load_scene

    prob = load_scene("disk_fitted").problem
    for disc in ("hho", "sipg"):
        with pytest.raises(ValueError, match="fem only"):
            DISCRETIZATIONS[disc](prob, prob.domain.mesh(0), order=1)


def test_uniform_run_measures_h_on_its_own_meshes(monkeypatch):
    """A uniform run on a netgen geometry meshes it once: the h column is measured on the level meshes the run
    has (Domain.h(level, mesh=...)), not by generating the levels again; the values are the levels' mesh sizes."""
    from dataclasses import replace

    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.scenes import load_scene

    base = load_scene("disk")
    domain = UnitDisk(maxh=0.4)
    scene = replace(base, problem=replace(base.problem, domain=domain), defaults={})
    calls = []
    coarse = UnitDisk._coarse
    monkeypatch.setattr(UnitDisk, "_coarse", lambda self: calls.append(1) or coarse(self))
    res = run_scene(scene, RunOptions(levels=3))
    assert len(calls) == 1
    monkeypatch.setattr(UnitDisk, "_coarse", coarse)
    assert [row["h"] for row in res.rows] == [mesh_size(m) for m in UnitDisk(maxh=0.4).meshes(3)]


def _vol_lines(tmp_path):
    path = tmp_path / "square.vol"
    StructuredSquare(2).mesh(0).ngmesh.Save(str(path))
    return path, path.read_text().splitlines()


def test_mesh_file_cut_off_or_with_bad_point_numbers_is_refused(tmp_path):
    """netgen's Mesh.Load reads such files past their end (the process crashed without a message)."""
    path, lines = _vol_lines(tmp_path)
    i = lines.index("surfaceelements")
    bad = tmp_path / "cut.vol"
    bad.write_text("\n".join(lines[:i + 4]) + "\n")
    with pytest.raises(ValueError, match="section 'surfaceelements' .* cut off"):
        MeshFileDomain(bad).mesh(0)
    fields = lines[i + 2].split()
    fields[5] = "9999"
    bad.write_text("\n".join(lines[:i + 2] + [" ".join(fields)] + lines[i + 3:]) + "\n")
    with pytest.raises(ValueError, match=r"refers to points \[9999, 2, 5\] \(the file has 9 points\)"):
        MeshFileDomain(bad).mesh(0)
    assert MeshFileDomain(path).mesh(0).ne == 8  # the untouched file loads


def test_degenerate_triangle_is_refused(tmp_path):
    path, lines = _vol_lines(tmp_path)
    i = lines.index("surfaceelements")
    fields = lines[i + 2].split()
    fields[7] = fields[6]  # a repeated vertex: zero area
    bad = tmp_path / "flat.vol"
    bad.write_text("\n".join(lines[:i + 2] + [" ".join(fields)] + lines[i + 3:]) + "\n")
    with pytest.raises(ValueError, match="1 degenerate triangle"):
        MeshFileDomain(bad).mesh(0)
