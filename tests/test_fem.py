"""Conforming FEM P1-P4 for the two-membrane and obstacle problems.

Expected rates (energy norm, w.r.t. h): test 1 of [CAMWA21] has a smooth
solution: p for p = 1, 2, 3; test 2 (lam discontinuous): ~1 for p = 1.
"""
import numpy as np
import pytest
from ngsolve import x, y

from ngcontact import CrissCrossSquare, ExactSolution, TwoMembraneProblem
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.rates import fitted_rate
from ngcontact.scenes import load_scene

# REFERENCE.md, "FEM DOFs (3 fields x interior Lagrange nodes)"
FEM_DOFS = {
    0: [75, 339, 795, 1443],
    1: [339, 1443, 3315, 5955],
    2: [1443, 5955, 13539, 24195],
}


@pytest.mark.parametrize("level", [0, 1, 2])
def test_dof_counts_match_camwa21(level):
    problem = load_scene("test1").problem
    mesh = problem.domain.mesh(level)
    counts = [FEMDiscretization(problem, mesh, order=p).ndof for p in (1, 2, 3, 4)]
    assert counts == FEM_DOFS[level]


@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_polynomial_solution_without_contact_is_exact(p, solve_one):
    """The space contains the exact solution and the constraint is inactive -> error ~ 0."""
    u1 = 2 + x * x + 0.5 * y  # degree 2 <= p (p = 1: linear part only)
    u2 = -1 - y * y + x
    if p == 1:
        u1, u2 = 2 + 0.3 * x + 0.5 * y, -1 + x - y
    f1 = -2.0 * 1.5 if p > 1 else 0.0
    f2 = 2.0 * 0.5 if p > 1 else 0.0
    prob = TwoMembraneProblem(CrissCrossSquare(), f1=f1, f2=f2, g1=u1, g2=u2, mu1=1.5, mu2=0.5,
                              exact=ExactSolution(u1, u2))
    disc, sol = solve_one(prob, level=0, order=p)
    assert sol.converged
    assert disc.errors(sol.x, sol.y)["err_energy"] < 1e-10
    assert np.all(sol.y == 0)


@pytest.mark.parametrize("p,levels", [(1, 4), (2, 4), (3, 4)])
def test_test1_energy_rate(p, levels, solve_levels):
    res = solve_levels("test1", p, levels)
    h = [r["h"] for r in res.rows]
    e = [r["err_energy"] for r in res.rows]
    assert fitted_rate(h, e, last=3) >= p - 0.15
    assert all(r["newton_converged"] for r in res.rows)


def test_test2_energy_rate_p1(solve_levels):
    res = solve_levels("test2", 1, 4)
    rate = fitted_rate([r["h"] for r in res.rows], [r["err_energy"] for r in res.rows], last=3)
    assert rate >= 1 - 0.15


def test_obstacle_ex9_rate_and_nodal_error(solve_levels):
    res = solve_levels("ex9_obstacle", 1, 4)
    h = [r["h"] for r in res.rows]
    assert fitted_rate(h, [r["err_energy"] for r in res.rows], last=3) >= 1 - 0.15
    emax = [r["err_max_nodal"] for r in res.rows]
    assert all(b < a for a, b in zip(emax, emax[1:]))


@pytest.mark.parametrize("p", [1, 2, 3])
@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_complementarity_at_convergence(p, cfun, solve_one):
    disc, sol = solve_one(load_scene("test1").problem, level=2, order=p, cfun=cfun)
    assert sol.converged, sol.reason
    # the stopping test ||Phi|| <= tol ||F|| bounds every |C_l| by tol ||F||, hence
    # the violations of gap >= 0, X3 >= 0 and of gap * X3 = 0 (Newton-min: exactly 0)
    bound = 1e-10 * np.linalg.norm(disc.system.F)
    c = disc.complementarity(sol.x, sol.y)
    assert c["gap_min"] >= -bound
    assert c["lam_min"] >= -bound
    assert c["product_max"] <= bound * max(np.abs(sol.y).max(), np.abs(disc.system.gap(sol.x)).max())
    if cfun == "min":
        assert c["gap_min"] >= -1e-14 and c["lam_min"] >= -1e-14 * np.abs(sol.y).max()
    assert np.linalg.norm(disc.system.residual(sol.x, sol.y)) <= 1e-10 * np.linalg.norm(disc.system.F)


@pytest.mark.parametrize("p", [1, 2])
def test_newton_min_and_fb_agree(p, solve_one):
    problem = load_scene("test2").problem
    d1, s1 = solve_one(problem, level=2, order=p, cfun="min")
    d2, s2 = solve_one(problem, level=2, order=p, cfun="fb")
    assert s1.converged and s2.converged
    assert np.abs(s1.x - s2.x).max() <= 1e-8 * np.abs(s1.x).max()
    assert np.abs(s1.y - s2.y).max() <= 1e-6 * np.abs(s1.y).max()


def test_nested_and_cold_start_reach_the_same_solution(solve_levels):
    nested = solve_levels("test2", 1, 3, start="nested")
    cold = solve_levels("test2", 1, 3, start="cold")
    np.testing.assert_allclose(nested.x, cold.x, atol=1e-9)
    assert [r["ndof"] for r in nested.rows] == [r["ndof"] for r in cold.rows]


def test_obstacle_solution_stays_above_obstacle(solve_one):
    disc, sol = solve_one(load_scene("ex9_obstacle").problem, level=1, order=1)
    assert sol.converged
    assert disc.system.gap(sol.x).min() >= -1e-12
    assert sol.y.min() >= -1e-12


@pytest.mark.parametrize("k", [0, 1])
def test_parent_table_is_checked_on_both_coordinates(k, monkeypatch):
    """The parent table of nested P1 levels is used only when the midpoints of every interior node's parents are
    its coordinates, bitwise: one node moved along coordinate k by a hundredth of h, and it is refused."""
    import ngcontact.discretizations.fem as fem

    problem = load_scene("ex9_obstacle").problem
    coarse_mesh, fine_mesh = list(problem.domain.meshes(3))[1:]
    coarse, fine = FEMDiscretization(problem, coarse_mesh), FEMDiscretization(problem, fine_mesh)
    assert fem._check_parent_pairs(coarse, fine) is not None
    moved = fine.nodes.coords.copy()
    moved[fine.interior[len(fine.interior) // 2], k] += 1e-2 * problem.domain.h(2)
    monkeypatch.setattr(fine.nodes, "coords", moved)
    assert fem._check_parent_pairs(coarse, fine) is None


@pytest.mark.parametrize("name", ["ex9_obstacle", "test1"])
def test_nested_p1_prolongation_equals_the_point_search(name, monkeypatch):
    """P1 on uniformly refined straight meshes: the parent table of the structured domains and the
    vertex / edge-midpoint lookup give the prolongation of the general point search."""
    import ngcontact.discretizations.fem as fem
    from ngcontact.newton.loop import semismooth_newton

    scene = load_scene(name)
    coarse_mesh, fine_mesh = list(scene.problem.domain.meshes(3))[1:]
    coarse, fine = FEMDiscretization(scene.problem, coarse_mesh), FEMDiscretization(scene.problem, fine_mesh)
    sol = semismooth_newton(coarse.system, *coarse.initial_guess(scene.initial_guess))
    pts = fine.nodes.coords[fine.interior]
    zeros = np.zeros((1, coarse.fes.ndof))
    assert fem._parent_p1_values(coarse, fine, zeros) is not None  # the parent table describes these meshes
    assert fem._nested_p1_values(coarse, pts, zeros) is not None  # every fine node is a vertex or a midpoint
    searches = []
    locate = fem._locate
    monkeypatch.setattr(fem, "_locate", lambda *a: searches.append(1) or locate(*a))
    x_parent, y_parent = fine.prolongate(coarse, sol.x, sol.y)
    monkeypatch.setattr(fem, "_parent_p1_values", lambda *a: None)
    x_nested, y_nested = fine.prolongate(coarse, sol.x, sol.y)
    assert not searches
    monkeypatch.setattr(fem, "_nested_p1_values", lambda *a: None)
    x_search, y_search = fine.prolongate(coarse, sol.x, sol.y)
    assert searches == [1]  # the reference values come from the point search
    for x_fast, y_fast in ((x_parent, y_parent), (x_nested, y_nested)):
        np.testing.assert_allclose(x_fast, x_search, atol=1e-13)
        np.testing.assert_allclose(y_fast, y_search, atol=1e-13 * max(1.0, np.abs(y_search).max()))
    # a point that is no coarse vertex or edge midpoint: fall back to the search
    assert fem._nested_p1_values(coarse, pts[:1] + 1e-3 * coarse.problem.domain.h(1), zeros) is None


def test_errors_need_no_multiplier_function(solve_one):
    """errors() reads the fields only: for p >= 2 it leaves the nodal mass matrix of lam_h unfactorized, and its
    energy error is the one of the fields' GridFunctions of gridfunctions()."""
    from ngsolve import Integrate, InnerProduct, grad

    problem = load_scene("test1").problem
    disc, sol = solve_one(problem, level=1, order=2)
    errs = disc.errors(sol.x, sol.y)
    assert disc._mass_solver is None
    gfs = disc.gridfunctions(sol.x, sol.y)  # lam_h included: a mass solve
    assert disc._mass_solver is not None
    e2 = 0.0
    for a, (name, mu) in enumerate(zip(problem.field_names, problem.mus)):
        d = problem.exact.gradient(a + 1) - grad(gfs[name])
        e2 += mu * Integrate(InnerProduct(d, d).Compile(), disc.mesh, order=2 * disc.order + disc.quad_bonus)
    assert errs["err_energy"] == pytest.approx(np.sqrt(e2), rel=1e-13)  # threaded sums: last bits


@pytest.mark.parametrize("p", [2, 3, 4])
def test_mass_solver_cg_then_cholesky(p, monkeypatch):
    """lam_h = M^{-1} [X3; 0]: the first solves by Jacobi-CG equal the sparse Cholesky solve to round-off, in the
    units of lam (rows by row), also for data scaled by 1e-8 and 1e8; the factorization comes at FACTOR_FROM, and a
    CG run that misses its target within MAXITER hands over to it at once."""
    from ngcontact.algebra.linalg import MassSolver, SPDSolver

    problem = load_scene("test1").problem
    disc = FEMDiscretization(problem, problem.domain.mesh(1), order=p)
    M = disc.mass_nodal()
    rng = np.random.default_rng(p)
    direct = SPDSolver(M)
    solver = MassSolver(M)
    for k, scale in enumerate((1.0, 1e-8, 1e8, 1.0)):
        b = scale * rng.standard_normal(M.shape[0])
        ref = direct.solve(b)
        got = solver.solve(b)
        assert solver.factorized == (k + 1 >= MassSolver.FACTOR_FROM)
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11 * np.abs(ref).max())
    assert not solver.factorized  # FACTOR_FROM = 5: four CG solves
    solver.solve(b)
    assert solver.factorized
    monkeypatch.setattr(MassSolver, "MAXITER", 2)
    short = MassSolver(M)
    np.testing.assert_allclose(short.solve(b), direct.solve(b), rtol=0, atol=1e-11 * np.abs(direct.solve(b)).max())
    assert short.factorized and short.calls == 1


def test_mass_solver_names_a_bad_matrix():
    import scipy.sparse as sp

    from ngcontact.algebra.linalg import MassSolver

    with pytest.raises(ValueError, match="non-positive diagonal"):
        MassSolver(sp.diags([1.0, 0.0, 2.0]))
