"""What keeps the peak memory of nested runs down: the coarser level is freed once it is prolongated, the
multigrid Newton steps do not hold two copies of the reduced matrix, structured domains do not keep the
arrays of a level while it is in use."""
import gc
import subprocess
import sys
import weakref

import numpy as np
import pytest

from ngcontact.algebra.cfunctions import get_cfunction
from ngcontact.algebra.sparse import submatrix
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.drivers import RunOptions
from ngcontact.drivers.level import multigrid_hierarchy, solve_level
from ngcontact.newton.multigrid import MultigridSolve
from ngcontact.scenes import load_scene


def _levels(n):
    problem = load_scene("ex9_obstacle").problem
    return problem, list(problem.domain.meshes(n))


def test_a_handed_over_coarser_level_is_freed_after_its_prolongation():
    problem, meshes = _levels(3)
    opts = RunOptions(levels=3, newton="multigrid")
    out = solve_level(problem, meshes[1], opts)
    ref = weakref.ref(out.disc)
    handoff = [(out.disc, out.sol.x, out.sol.y)]
    kept = solve_level(problem, meshes[2], opts, previous=list(handoff))  # a copy of the list: still referenced
    assert ref() is not None and kept.sol.converged
    del kept
    out = None
    seen = []

    def callback(rec):  # during the Newton iterations of the fine level
        gc.collect()
        seen.append(ref() is None)

    fine = solve_level(problem, meshes[2], opts, previous=handoff, callback=callback)
    assert handoff == [] and seen and all(seen)  # emptied, and the coarse level gone before Newton
    assert fine.sol.converged and fine.sol.iterations <= 3


def _session_steps():
    """A multigrid session on ex9 level 3 and the linearizations at two iterates with the same row classes
    (the Newton-min active set of the first) and at a third with a few rows changed."""
    problem, meshes = _levels(4)
    disc = None
    for mesh in meshes:
        fine = FEMDiscretization(problem, mesh, order=1)
        fine.mg_prolongations = multigrid_hierarchy(fine, disc) if disc is not None else ()
        disc = fine
    s = disc.system
    x = s.b.copy()  # on the obstacle everywhere ...
    x[: len(x) // 2] += 1.0  # ... but half the nodes lifted off
    y = np.zeros(s.m)
    cf = get_cfunction("min")

    def lin_at(x, y):
        Ca, Cb = s.chain(*cf.jacobian(*s.pair(x, y)))
        return s.linearize(x, y, cf.value(*s.pair(x, y)), Ca, Cb)

    session = MultigridSolve(prolongations=tuple(disc.mg_prolongations)).start(s, [])
    x2 = x.copy()
    x2[len(x) // 2: len(x) // 2 + 20] += 1.0  # 20 more rows lifted off
    return session, lin_at(x, y), lin_at(x.copy(), y.copy()), lin_at(x2, y)


def test_multigrid_session_shares_the_reduced_matrix_of_unchanged_rows():
    session, lin1, lin2, lin3 = _session_steps()
    mg, how = session.hierarchy.get(lin1)
    assert how == 1
    A1 = mg.levels[0].A
    mg2, how = session.hierarchy.get(lin2)
    assert how == 0 and mg2 is mg and lin2._A is A1  # not formed again
    want = submatrix(lin2._Kaug, lin2.keep, lin2.keep)
    assert (lin2.A != want).nnz == 0
    mg3, how = session.hierarchy.get(lin3)
    assert how == 2 and mg.levels[0].A is None  # the old finest matrix was released before the update
    assert mg3.levels[0].A is lin3.A and (lin3.A != submatrix(lin3._Kaug, lin3.keep, lin3.keep)).nnz == 0


def test_structured_meshes_do_not_keep_their_arrays():
    from ngcontact import CrissCrossSquare, StructuredSquare

    gen = StructuredSquare(n0=4)._levels(0, 3)
    for _ in range(3):
        box = next(gen)
        assert gen.gi_frame.f_locals["arrays"] is None  # the box (emptied by the consumer) holds them only
        box.clear()
    gen = CrissCrossSquare(n0=2)._levels(0, 2)
    next(gen)
    assert gen.gi_frame.f_locals["arrays"] is not None  # red refinement needs the arrays of the level before


def _forms(mesh):
    """ndof and the entries of a mass and a stiffness-like form of the spaces the package uses."""
    from ngsolve import H1, L2, BilinearForm, FacetFESpace, HDiv, div, dx, grad, specialcf

    out = []
    for fes in [H1(mesh, order=p, dirichlet=".*") for p in (1, 2, 3, 4)] + [L2(mesh, order=2)]:
        u, v = fes.TnT()
        a = BilinearForm(grad(u) * grad(v) * dx + u * v * dx).Assemble()
        out.append((fes.ndof, sum(fes.FreeDofs()), np.array(a.mat.AsVector())))
    X = HDiv(mesh, order=2, RT=True, discontinuous=True) * L2(mesh, order=2) * FacetFESpace(mesh, order=2)
    (s, r, lam), (t, q, mu) = X.TnT()
    n = specialcf.normal(2)
    a = BilinearForm(X)
    a += (s * t + div(s) * q + div(t) * r) * dx + (s * n * mu + t * n * lam) * dx(element_boundary=True)
    a += lam * mu * dx(element_boundary=True)
    out.append((X.ndof, sum(X.FreeDofs()), np.array(a.Assemble().mat.AsVector())))
    return out


def test_box_meshes_without_a_face_table_give_the_same_spaces_forms_and_refinements():
    import ngsolve
    from ngcontact import CrissCrossSquare
    from ngcontact.domains import _to_ngmesh

    arrays = CrissCrossSquare(n0=2)._arrays(1)
    plain, with_faces = _to_ngmesh(*arrays), _to_ngmesh(*arrays)
    with_faces.EnableTable("faces", True)
    m0, m1 = ngsolve.Mesh(plain), ngsolve.Mesh(with_faces)
    assert m0.nface == 0 and m1.nface == m1.ne  # the table is really off
    for mesh in (m0, m1):
        mesh.SetRefinementFlags([k % 3 == 0 for k in range(mesh.ne)])
        mesh.Refine()
    assert (m0.nv, m0.ne, m0.nedge) == (m1.nv, m1.ne, m1.nedge)
    assert np.array_equal(np.asarray(m0.ngmesh.Coordinates()), np.asarray(m1.ngmesh.Coordinates()))
    for (n0, f0, a0), (n1, f1, a1) in zip(_forms(m0), _forms(m1)):
        assert (n0, f0) == (n1, f1) and np.array_equal(a0, a1)



@pytest.mark.parametrize("scene, options", [("ex9_obstacle", "levels=3"),
                                            ("lshape", "order=2, adaptive=True, max_ndof=2000")])
def test_a_finished_run_is_freed_without_a_garbage_collection(scene, options):
    """Nested ex9 (structured levels located on the coarsest mesh) and adaptive L-shape P2 (the prolongation locates
    the new nodes in the old mesh) both search meshes with matplotlib's trifinder, imported on first use: the runs
    leave nothing of their levels to the cyclic garbage collector -- every level but the last is freed when the
    next one is solved, and dropping the result frees the last.  A fresh interpreter, so that the first import
    happens during the run."""
    code = (
        "import gc, weakref\n"
        "gc.disable()\n"
        "import ngcontact.drivers.level as L, ngcontact.drivers.adaptive as A, ngcontact.drivers.uniform as U\n"
        "from ngcontact.drivers import RunOptions, run_scene\n"
        "from ngcontact.scenes import load_scene\n"
        "refs, solve = [], L.solve_level\n"
        "def tracked(*a, **k):\n"
        "    out = solve(*a, **k)\n"
        "    refs.append(weakref.ref(out.disc))\n"
        "    return out\n"
        "A.solve_level = U.solve_level = tracked\n"
        f"res = run_scene(load_scene({scene!r}), RunOptions({options}))\n"
        "assert len(refs) >= 3 and res.rows[-1]['newton_converged']\n"
        "print('ALIVE', sum(r() is not None for r in refs))\n"
        "res = None\n"
        "print('ALIVE', sum(r() is not None for r in refs))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert [l for l in out.stdout.splitlines() if l.startswith("ALIVE")] == ["ALIVE 1", "ALIVE 0"]


def test_a_finished_cli_run_is_freed_without_a_garbage_collection(tmp_path):
    """The CLI imports the plotting module (matplotlib) when a run starts: nothing of the run is left to the cyclic
    garbage collector once the command has returned (studies call the CLI several times in one process).  A fresh
    interpreter, so that the first import happens in the command."""
    code = (
        "import gc, weakref, sys\n"
        "gc.disable()\n"
        "import ngcontact.drivers.level as L, ngcontact.drivers.adaptive as A\n"
        "from ngcontact.cli import main\n"
        "refs, solve = [], L.solve_level\n"
        "def tracked(*a, **k):\n"
        "    out = solve(*a, **k)\n"
        "    refs.append(weakref.ref(out.disc))\n"
        "    return out\n"
        "A.solve_level = tracked\n"
        "rc = main(['run', 'lshape', '--order', '2', '--adaptive', '--max-ndof', '2000', '--out', sys.argv[1], '-q',\n"
        "           '--no-plots', '--no-vtk'])\n"
        "assert rc == 0 and len(refs) >= 3\n"
        "print('ALIVE', sum(r() is not None for r in refs))\n")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "run")], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert [l for l in out.stdout.splitlines() if l.startswith("ALIVE")] == ["ALIVE 0"]
