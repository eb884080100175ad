"""Interior penalty dG (SIPG / NIPG / IIPG) for the two-membrane problem.

Expected (test 1 of [CAMWA21], smooth solution): broken energy error O(h^p)
for SIPG (and NIPG, IIPG: optimal in energy, suboptimal only in L2 for
NIPG with even p); exactness on P_p without contact (IP methods are
consistent); symmetric SPD matrix for SIPG with the default penalty,
non-symmetric for NIPG/IIPG (solved by LU).
"""
import numpy as np
import pytest
from ngsolve import x, y

from ngcontact import CrissCrossSquare, ExactSolution, TwoMembraneProblem
from ngcontact.algebra.cfunctions import get_cfunction
from ngcontact.algebra.system import ComplementaritySystem
from ngcontact.discretizations.dg import DGComplementaritySystem, DGDiscretization
from ngcontact.newton.loop import NewtonOptions, semismooth_newton
from ngcontact.rates import fitted_rate
from ngcontact.scenes import load_scene


def solve_nested(problem, order, levels, variant):
    out, prev = [], None
    for level in range(levels):
        disc = DGDiscretization(problem, problem.domain.mesh(level), order=order, variant=variant)
        x0, y0 = disc.initial_guess() if prev is None else disc.prolongate(prev[0], prev[1].x, prev[1].y)
        sol = semismooth_newton(disc.system, x0, y0, NewtonOptions())
        out.append((disc, sol))
        prev = (disc, sol)
    return out


def energy_rate(variant, p, levels):
    problem = load_scene("test1").problem
    runs = solve_nested(problem, p, levels, variant)
    assert all(sol.converged for _, sol in runs)
    h = [problem.domain.h(level) for level in range(levels)]
    errs = [d.errors(s.x, s.y) for d, s in runs]
    return fitted_rate(h, [e["err_energy"] for e in errs], last=3), errs


@pytest.mark.parametrize("p", [1, 2, pytest.param(3, marks=pytest.mark.slow), pytest.param(4, marks=pytest.mark.slow)])
def test_matrix_symmetry_and_coercivity_with_default_penalty(p):
    problem = load_scene("test1").problem
    mesh = problem.domain.mesh(0)
    for variant in ("sipg", "nipg", "iipg"):
        A = DGDiscretization(problem, mesh, order=p, variant=variant).A.toarray()
        asym = np.abs(A - A.T).max() / np.abs(A).max()
        assert (asym < 1e-12) if variant == "sipg" else (asym > 1e-3)
        assert np.linalg.eigvalsh(0.5 * (A + A.T)).min() > 1e-3  # coercive (weak Dirichlet: no kernel)


def test_sipg_with_too_small_penalty_is_indefinite():
    """The penalty is not cosmetic: c = 1 (p = 2) loses coercivity (module doc)."""
    problem = load_scene("test1").problem
    A = DGDiscretization(problem, problem.domain.mesh(0), order=2, variant="sipg", penalty=1.0).A.toarray()
    assert np.linalg.eigvalsh(A).min() < 0


@pytest.mark.parametrize("variant", ["sipg", "nipg", "iipg"])
@pytest.mark.parametrize("p", [1, 2, 3])
def test_polynomial_solution_without_contact_is_exact(variant, p):
    u1, u2 = 3 + x * x + 0.5 * y, -1 - y * y + x
    f1, f2 = -2.0 * 1.5, 2.0 * 0.5
    if p == 1:
        u1, u2, f1, f2 = 3 + 0.3 * x + 0.5 * y, -1 + x - y, 0.0, 0.0
    problem = TwoMembraneProblem(CrissCrossSquare(), f1=f1, f2=f2, g1=u1, g2=u2, mu1=1.5, mu2=0.5,
                                 exact=ExactSolution(u1, u2))
    disc = DGDiscretization(problem, problem.domain.mesh(0), order=p, variant=variant)
    sol = semismooth_newton(disc.system, *disc.initial_guess(), NewtonOptions())
    assert sol.converged
    err = disc.errors(sol.x, sol.y)
    assert err["err_energy"] < 1e-9 and err["err_jump"] < 1e-9
    assert np.all(sol.y == 0)


def test_dof_counts():
    problem = load_scene("test1").problem
    disc = DGDiscretization(problem, problem.domain.mesh(0), order=2)
    # 64 cells x 6 nodes for u1 and u2; lam on the nodes off the boundary (16 boundary edges x 3 nodes)
    # and 12 non-corner boundary vertices seen by 2 cells without a boundary edge each
    assert disc.ndof == 2 * 64 * 6 + (64 * 6 - 16 * 3 - 24)
    assert disc.n_interior == disc.system.m == 64 * 6 - 16 * 3 - 24


@pytest.mark.parametrize("p", [1, 2, 3])
def test_sipg_test1_energy_rate(p):
    rate, errs = energy_rate("sipg", p, 4)
    assert rate >= p - 0.15
    assert errs[-1]["err_jump"] < errs[0]["err_jump"]


@pytest.mark.parametrize("p", [1, 2])
def test_nipg_test1_energy_rate(p):
    rate, _ = energy_rate("nipg", p, 4)
    assert rate >= p - 0.5


@pytest.mark.slow
@pytest.mark.parametrize("variant,p", [("nipg", 3), ("iipg", 1), ("iipg", 2), ("iipg", 3)])
def test_nonsymmetric_test1_energy_rate(variant, p):
    rate, _ = energy_rate(variant, p, 4)
    assert rate >= p - 0.5


@pytest.mark.parametrize("factorization", ["umfpack", "sparsecholesky", "splu"])
@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_dg_newton_step_equals_generic_step_on_symmetric_system(cfun, factorization):
    """The step written for NIPG/IIPG reproduces the base class step on the SIPG system."""
    problem = load_scene("test1").problem
    disc = DGDiscretization(problem, problem.domain.mesh(1), order=2, variant="sipg")
    s = disc.system
    base = ComplementaritySystem(s.K, s.F, s.up, s.lo, s.b, s.D)
    lu = DGComplementaritySystem(s.K, s.F, s.up, s.lo, s.b, s.D)
    lu.factorization = factorization
    rng = np.random.default_rng(0)
    xs = disc.initial_guess([problem.exact.u1, problem.exact.u2])[0] + 1e-4 * rng.standard_normal(s.n)
    ys = np.maximum(0.0, 1e-4 * rng.standard_normal(s.m))
    cf = get_cfunction(cfun)
    g = s.gap(xs)
    C, (Ca, Cb) = cf.value(g, ys), cf.jacobian(g, ys)
    x1, y1, _ = base.newton_step(xs, ys, C, Ca, Cb)
    x2, y2, _ = lu.newton_step(xs, ys, C, Ca, Cb)
    assert np.abs(x1 - x2).max() <= 1e-10 * np.abs(x1).max()
    assert np.abs(y1 - y2).max() <= 1e-10 * np.abs(y1).max()


@pytest.mark.parametrize("variant", ["sipg", "nipg", "iipg"])
def test_complementarity_at_convergence(variant):
    problem = load_scene("test1").problem
    disc = DGDiscretization(problem, problem.domain.mesh(1), order=2, variant=variant)
    assert disc.system.factorization == ("sparsecholesky" if variant == "sipg" else "umfpack")
    sol = semismooth_newton(disc.system, *disc.initial_guess(), NewtonOptions())
    assert sol.converged, sol.reason
    bound = 1e-10 * np.linalg.norm(disc.system.F)
    c = disc.complementarity(sol.x, sol.y)
    assert c["gap_min"] >= -bound and c["lam_min"] >= -bound
    assert c["product_max"] <= bound * max(np.abs(sol.y).max(), np.abs(disc.system.gap(sol.x)).max())
    assert np.linalg.norm(disc.system.residual(sol.x, sol.y)) <= 1e-10 * np.linalg.norm(disc.system.F)
    active = disc.system.gap(sol.x) <= sol.y
    assert disc.contact_points(sol.x, sol.y).shape == (active.sum(), 2)


def test_prolongation_reproduces_the_coarse_cell_polynomials():
    problem = load_scene("test1").problem
    (coarse, sol), = solve_nested(problem, 2, 1, "sipg")
    fine = DGDiscretization(problem, problem.domain.mesh(1), order=2)
    x0, y0 = fine.prolongate(coarse, sol.x, sol.y)
    e_c, e_f = coarse.errors(sol.x, sol.y), fine.errors(x0, y0)
    assert e_f["err_energy"] == pytest.approx(e_c["err_energy"], rel=1e-5)  # quadrature of the exact solution
    # the jumps of the coarse function: the same on coarse edges, zero on the new ones, but
    # measured with |F|^-1 on halved edges: sum |F|^-1 ||[u]||^2 doubles
    assert e_f["err_jump"] == pytest.approx(np.sqrt(2) * e_c["err_jump"], rel=1e-4)  # boundary: g quadrature
