"""HHO (cells P_p, faces P_{p-1}) with and without static condensation.

Expected: the DOF table of [CAMWA21] (REFERENCE.md), exactness on P_p
without contact, energy rate p on test 1 (smooth solution), identical
iterates with and without condensation, complementarity at convergence.
"""
import numpy as np
import pytest
from ngsolve import Integrate, InnerProduct, grad, x, y

from ngcontact import CrissCrossSquare, ExactSolution, TwoMembraneProblem
from ngcontact.algebra.cfunctions import get_cfunction
from ngcontact.discretizations.hho import HHODiscretization
from ngcontact.newton.loop import NewtonOptions, semismooth_newton
from ngcontact.rates import fitted_rate
from ngcontact.scenes import load_scene

# REFERENCE.md, "HHO DOFs": (no SC, SC) for P1..P4
HHO_DOFS = {
    0: [(752, 176), (1504, 352), (2448, 528), (3584, 704)],
    1: [(3040, 736), (6080, 1472), (9888, 2208), (14464, 2944)],
    2: [(12224, 3008), (24448, 6016), (39744, 9024), (58112, 12032)],
    3: [(49024, 12160), (98048, 24320), (159360, 36480), (232960, 48640)],
    4: [(196352, 48896), (392704, 97792), (638208, 146688), (932864, 195584)],
}


def solve_nested(problem, order, levels, **kw):
    """Nested iteration T0..T(levels-1); returns [(disc, NewtonResult)]."""
    out, prev = [], None
    for level in range(levels):
        disc = HHODiscretization(problem, problem.domain.mesh(level), order=order, **kw)
        x0, y0 = disc.initial_guess() if prev is None else disc.prolongate(prev[0], prev[1].x, prev[1].y)
        sol = semismooth_newton(disc.system, x0, y0, NewtonOptions())
        out.append((disc, sol))
        prev = (disc, sol)
    return out


def polynomial_problem(p):
    """u1, u2 in P_p (p <= 2 used), no contact (u1 - u2 >= 2 on the unit square)."""
    if p == 1:
        u1, u2, f1, f2 = 3 + 0.3 * x + 0.5 * y, -1 + x - y, 0.0, 0.0
    else:
        u1, u2, f1, f2 = 3 + x * x + 0.5 * y, -1 - y * y + x, -2.0 * 1.5, 2.0 * 0.5
    return TwoMembraneProblem(CrissCrossSquare(), f1=f1, f2=f2, g1=u1, g2=u2, mu1=1.5, mu2=0.5,
                              exact=ExactSolution(u1, u2))


@pytest.mark.parametrize("level", [0, 1, 2])
def test_dof_counts_match_camwa21(level):
    problem = load_scene("test1").problem
    mesh = problem.domain.mesh(level)
    counts = [(d.ndof, d.ndof_sc) for d in (HHODiscretization(problem, mesh, order=p) for p in (1, 2, 3, 4))]
    assert counts == HHO_DOFS[level]


@pytest.mark.slow
@pytest.mark.parametrize("level", [3, 4])
def test_dof_counts_match_camwa21_fine(level):
    problem = load_scene("test1").problem
    mesh = problem.domain.mesh(level)
    counts = [(d.ndof, d.ndof_sc) for d in (HHODiscretization(problem, mesh, order=p) for p in (1, 2, 3, 4))]
    assert counts == HHO_DOFS[level]


@pytest.mark.parametrize("condense", [True, False])
@pytest.mark.parametrize("p,deg", [(1, 1), (2, 2), (3, 2)])
def test_polynomial_solution_without_contact_is_exact(p, deg, condense):
    """The potential reconstruction is exact on P_p: the cell unknowns reproduce u_a."""
    problem = polynomial_problem(deg)
    disc = HHODiscretization(problem, problem.domain.mesh(0), order=p, condense=condense)
    sol = semismooth_newton(disc.system, *disc.initial_guess(), NewtonOptions())
    assert sol.converged
    err = disc.errors(sol.x, sol.y)
    assert err["err_energy"] < 1e-10 and err["err_max_nodal"] < 1e-10
    assert np.all(sol.y == 0)


def test_seed_full_gradient_reconstruction_is_not_exact_on_Pp():
    """G_K tested with all of P_p(K; R^2) (seed slide) loses exactness on P_p (module doc)."""
    problem = polynomial_problem(2)
    disc = HHODiscretization(problem, problem.domain.mesh(0), order=2, reconstruction="full")
    sol = semismooth_newton(disc.system, *disc.initial_guess(), NewtonOptions())
    assert disc.errors(sol.x, sol.y)["err_energy"] > 1e-3


def test_element_matrices_symmetric_and_kernel_constants():
    problem = load_scene("test1").problem
    for p in (1, 2, 3, 4):
        A = HHODiscretization(problem, problem.domain.mesh(0), order=p).A_loc
        assert np.abs(A - A.transpose(0, 2, 1)).max() < 1e-12 * np.abs(A).max()
        nc = (p + 1) * (p + 2) // 2
        ones = np.zeros(A.shape[1])  # the constant 1: nodal values 1, face coefficients (1, 0, ..)
        ones[:nc] = 1.0
        ones[nc::p] = 1.0
        assert np.abs(A @ ones).max() < 1e-12 * np.abs(A).max()
        eig = np.linalg.eigvalsh(A)
        assert np.all(eig[:, 1] > 1e-8)  # only the constants in the kernel


@pytest.mark.parametrize("p", [1, 2, 3])
def test_test1_energy_rate(p):
    """[CAMWA21] test 1: energy error of the cell unknowns O(h^p) (T0..T3, fit over T1..T3)."""
    problem = load_scene("test1").problem
    runs = solve_nested(problem, p, 4)
    assert all(sol.converged for _, sol in runs)
    h = [problem.domain.h(level) for level in range(4)]
    err = [d.errors(s.x, s.y)["err_energy"] for d, s in runs]
    assert fitted_rate(h, err, last=3) >= p - 0.15


@pytest.mark.parametrize("scene,p", [("test1", 2), ("test2", 3)])
def test_condensed_and_full_solves_agree(scene, p):
    problem = load_scene(scene).problem
    mesh = problem.domain.mesh(1)
    sols = []
    for condense in (True, False):
        disc = HHODiscretization(problem, mesh, order=p, condense=condense)
        sols.append(semismooth_newton(disc.system, *disc.initial_guess(), NewtonOptions(cfun="min")))
    a, b = sols
    assert a.converged and b.converged and a.iterations == b.iterations
    assert np.abs(a.x - b.x).max() <= 1e-10 * np.abs(b.x).max()
    assert np.abs(a.y - b.y).max() <= 1e-10 * np.abs(b.y).max()


def _steps_from_one_state(problem, dc, df, cfun, seed):
    """One linearized step of the condensed system ``dc`` and of the generic one ``df`` from the same random state
    near the exact solution (C-function ``cfun``)."""
    rng = np.random.default_rng(seed)
    x = dc.initial_guess([problem.exact.u1, problem.exact.u2])[0] + 1e-4 * rng.standard_normal(dc.system.n)
    y = np.maximum(0.0, 1e-4 * rng.standard_normal(dc.system.m))
    cf = get_cfunction(cfun)
    g = dc.system.gap(x)
    C, (Ca, Cb) = cf.value(g, y), cf.jacobian(g, y)
    return dc.system.newton_step(x, y, C, Ca, Cb), df.system.newton_step(x, y, C, Ca, Cb)


@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_condensed_newton_step_equals_generic_step(cfun):
    """One linearized step from the same state (FB: mixed rows included) in both systems."""
    problem = load_scene("test1").problem
    mesh = problem.domain.mesh(1)
    dc = HHODiscretization(problem, mesh, order=2, condense=True)
    df = HHODiscretization(problem, mesh, order=2, condense=False)
    (xc, yc, info), (xf, yf, _) = _steps_from_one_state(problem, dc, df, cfun, seed=1)
    assert info.reduced_size == dc.ndof_sc
    assert np.abs(xc - xf).max() <= 1e-10 * np.abs(xf).max()
    assert np.abs(yc - yf).max() <= 1e-10 * np.abs(yf).max()


@pytest.mark.parametrize("p", [1, 2, 3])
def test_complementarity_at_convergence(p):
    problem = load_scene("test1").problem
    disc = HHODiscretization(problem, problem.domain.mesh(1), order=p)
    sol = semismooth_newton(disc.system, *disc.initial_guess(), NewtonOptions())
    assert sol.converged, sol.reason
    bound = 1e-10 * np.linalg.norm(disc.system.F)
    c = disc.complementarity(sol.x, sol.y)
    assert c["gap_min"] >= -bound and c["lam_min"] >= -bound
    assert c["product_max"] <= bound * max(np.abs(sol.y).max(), np.abs(disc.system.gap(sol.x)).max())
    assert np.linalg.norm(disc.system.residual(sol.x, sol.y)) <= 1e-10 * np.linalg.norm(disc.system.F)
    # contact points: the nodes with gap <= X3; Newton-min leaves gap = 0 exactly there
    # (where they lie is not checked: u1 - u2 = 2 (r^2 - R^2)^6 is below the discretization
    # error in a wide band around r = R, and coarse P1 cells also touch near the corners)
    pts = disc.contact_points(sol.x, sol.y)
    active = disc.system.gap(sol.x) <= sol.y
    assert pts.shape == (active.sum(), 2) and active.sum() > 0
    assert np.all(disc.system.gap(sol.x)[active] == 0.0)


def test_gridfunctions_match_cell_unknowns():
    """The L2 GridFunction gives the same energy error as the cell-wise quadrature."""
    problem = load_scene("test1").problem
    disc = HHODiscretization(problem, problem.domain.mesh(1), order=2)
    sol = semismooth_newton(disc.system, *disc.initial_guess(), NewtonOptions())
    gfs = disc.gridfunctions(sol.x, sol.y)
    e2 = 0.0
    for a, name in enumerate(("u1", "u2")):
        d = problem.exact.gradient(a + 1) - grad(gfs[name])
        e2 += Integrate(InnerProduct(d, d), disc.mesh, order=12)
    assert np.sqrt(e2) == pytest.approx(disc.errors(sol.x, sol.y)["err_energy"], rel=1e-8)
    # lam_h = sum_l X3_l Theta_l has the moments X3 against the nodal basis
    np.testing.assert_allclose(disc.basis.nodal_to_dual(disc.basis.interpolate(gfs["lam"])).ravel(), sol.y,
                               atol=1e-12 * np.abs(sol.y).max())


def test_prolongation_reproduces_the_coarse_cell_polynomials():
    problem = load_scene("test1").problem
    (coarse, sol), = solve_nested(problem, 2, 1)
    fine = HHODiscretization(problem, problem.domain.mesh(1), order=2)
    x0, y0 = fine.prolongate(coarse, sol.x, sol.y)
    e_c = coarse.errors(sol.x, sol.y)["err_energy"]
    assert fine.errors(x0, y0)["err_energy"] == pytest.approx(e_c, rel=1e-6)


@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_condensed_step_with_the_stiffer_second_membrane_equals_generic_step(cfun):
    """mu2 > mu1: the coupled cells are condensed in the cell values of field 2 (the stiffer) and d = x1 - x2; one
    linearized step (FB: mixed rows) equals the generic step."""
    from ngcontact.problems.manufactured import disk_contact

    problem = disk_contact(1.0, 10.0, A=1000.0)
    mesh = problem.domain.mesh(1)
    dc = HHODiscretization(problem, mesh, order=2, condense=True)
    df = HHODiscretization(problem, mesh, order=2, condense=False)
    assert dc.system.primary == 2
    (xc, yc, _), (xf, yf, _) = _steps_from_one_state(problem, dc, df, cfun, seed=2)
    assert np.abs(xc - xf).max() <= 1e-10 * np.abs(xf).max()
    assert np.abs(yc - yf).max() <= 1e-10 * np.abs(yf).max()


@pytest.mark.parametrize("mu2", [1e9, 1e12, 1e-12])
def test_condensed_hho_resolves_membranes_with_tensions_far_apart(mu2):
    """Tensions 1e9...1e12 apart: the condensed HHO Newton converges to round-off and is certified, and each field's
    equations hold in that field's own units (the softer one included); it agrees with the uncondensed solve.  With
    the softer field's values as the cell variable the condensed step stalled at ||Phi|| / ||F|| ~ 1e-5 (no
    progress: not converged) for mu2 / mu1 = 1e9 and 1e12."""
    from ngcontact.problems.manufactured import disk_contact

    problem = disk_contact(1.0, mu2, A=1000.0)
    mesh = problem.domain.mesh(1)
    sols = {}
    for condense in (True, False):
        disc = HHODiscretization(problem, mesh, order=1, condense=condense)
        sols[condense] = (disc, semismooth_newton(disc.system, *disc.initial_guess(), NewtonOptions()))
    disc, sol = sols[True]
    assert sol.converged and sol.certificate.valid and sol.history[-1].res <= 1e-14
    sy = disc.system
    r, Kx, n = sy.residual(sol.x, sol.y), sy.K @ sol.x, sy.n // 2
    for rows in (slice(0, n), slice(n, None)):  # each field in its own units
        assert np.abs(r[rows]).max() <= 1e-13 * (np.abs(sy.F[rows]).max() + np.abs(Kx[rows]).max())
    other = sols[False][1]
    for rows in (slice(0, n), slice(n, None)):
        assert np.abs(sol.x[rows] - other.x[rows]).max() <= 1e-12 * np.ptp(other.x[rows])
