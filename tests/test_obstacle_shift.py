"""The bound for the interpolated obstacle (ngcontact/estimators/obstacle.py): obstacles outside the FE space.

Full contact, u = psi, lam = LAM > 0 everywhere, f = -mu Lap psi - lam, g = psi on the boundary: the exact solution
is psi itself (u - psi = 0, -mu Lap u - f = lam >= 0), and the discrete solution is the interpolant psi_h (every node
active), so |||u - u_h||| = |||psi - psi_h|||.
"""
import math

import numpy as np
import pytest
from ngsolve import BND, Integrate, cos, sin, x, y

from ngcontact import CrissCrossSquare, ExactSolution, ObstacleProblem
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.estimators import EstimatorOptions, estimate
from ngcontact.estimators.obstacle import shifted_obstacle
from ngcontact.estimators.view import SolutionView
from ngcontact.newton import NewtonOptions, semismooth_newton
from ngcontact.problems.manufactured import scale_problem
from ngcontact.scenes import load_scene

LAM = 10.0


def _full_contact(psi, lap_psi, g=None):
    return ObstacleProblem(domain=CrissCrossSquare(n0=4), psi=psi, f=-lap_psi - LAM, g=psi if g is None else g,
                           mu=1.0, exact=ExactSolution(u1=psi, lam=LAM + 0 * x), name="full_contact_obstacle")


def _sine():  # psi = 0 on the boundary: psi_h = psi on every Dirichlet edge
    S = sin(math.pi * x) * sin(math.pi * y)
    return _full_contact(S / (2 * math.pi ** 2), -S)


def _cosine():  # psi not a polynomial on the boundary edges, contact up to the boundary
    C = 0.1 * cos(x) * cos(y)
    return _full_contact(C, -2 * C)


def _solve(problem, level, p, constraints="nodal"):
    disc = FEMDiscretization(problem, problem.domain.mesh(level), order=p, constraints=constraints)
    sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions(tol=1e-12))
    assert sol.converged
    return disc, sol


def _effectivities(problem, p, levels, constraints="nodal"):
    out = []
    for level in levels:
        disc, sol = _solve(problem, level, p, constraints)
        err = disc.errors(sol.x, sol.y)["err_energy"]
        e = estimate(disc, sol.x, sol.y, EstimatorOptions(), err_energy=err)
        plain = estimate(disc, sol.x, sol.y, EstimatorOptions(shift_obstacle=False), errors=False).eta
        out.append((e.eta / err, plain / err, e.eta_obstacle / err, e))
    return out


@pytest.mark.parametrize("constraints", ["nodal", "bernstein"])
def test_p3_full_contact_interpolated_obstacle_stays_efficient(constraints):
    """P3: the bound with psi itself grows like h^-1 (its contact term is O(h^2)); the bound for psi_h plus
    |||psi - psi_h||| (= the error here) stays at I_eff ~ 2 and above 1 (guaranteed)."""
    rows = _effectivities(_sine(), 3, [0, 1, 2], constraints)
    for (ieff, plain, obst, e), nxt in zip(rows, rows[1:] + [None]):
        assert 1.0 <= ieff <= 2.3
        assert obst == pytest.approx(1.0, rel=1e-6)  # u_h = psi_h: |||psi - psi_h||| is the error
        assert e.eta_plain_obstacle / e.eta == pytest.approx(plain / ieff, rel=1e-9)
        if nxt is not None:
            assert nxt[1] > 1.8 * plain  # the plain bound: I_eff 25.6, 50.1, 99.4
    assert rows[-1][1] > 40 * rows[-1][0]


def test_p2_full_contact_effectivity_bounded():
    """P2 (not every node active with the dual basis): I_eff 4.1-4.6 with the interpolated obstacle, against
    6.9 -> 13.7 with psi itself."""
    rows = _effectivities(_sine(), 2, [0, 1, 2])
    assert all(1.0 <= r[0] <= 5.0 for r in rows)
    assert rows[2][1] > 1.9 * rows[0][1]
    assert rows[2][0] < 1.15 * rows[0][0]


@pytest.mark.parametrize("scale", [1e-8, 1e8])
def test_interpolated_obstacle_bound_is_scale_invariant(scale):
    ref = _effectivities(_sine(), 3, [1])[0]
    got = _effectivities(scale_problem(_sine(), data=scale), 3, [1])[0]
    assert got[0] == pytest.approx(ref[0], rel=1e-8)
    assert got[2] == pytest.approx(ref[2], rel=1e-8)


def test_contact_up_to_a_nonpolynomial_trace():
    """psi not a polynomial on the boundary edges, contact up to them: psi~ takes the trace Pi psi (P5 lifting of the
    trace error), so its boundary mismatch is the trace defect of psi, orders below the interpolation error, and is
    counted in eta_trace (the bound stays proven); P3 I_eff 2.08, 2.07, 2.06 against 131, 336, 719 for psi itself."""
    problem = _cosine()
    rows = _effectivities(problem, 3, [0, 1, 2])
    for (ieff, plain, obst, e), nxt in zip(rows, rows[1:] + [None]):
        assert 1.0 <= ieff <= 2.2
        assert e.bound_proven and e.eta_trace > 0.0
        if nxt is not None:
            assert nxt[1] > 2.0 * plain
    disc, sol = _solve(problem, 1, 3)
    sh = shifted_obstacle(SolutionView.of(disc, sol.x, sol.y))
    psi_h = SolutionView.of(disc, sol.x, sol.y).disc.function(disc.nodes.evaluate(problem.psi))
    mesh = disc.mesh
    mismatch = Integrate((problem.psi - sh.psi) ** 2, mesh, BND, order=14)
    interpolation = Integrate((problem.psi - psi_h) ** 2, mesh, BND, order=14)
    assert mismatch < 1e-4 * interpolation


def test_polynomial_obstacle_is_not_shifted():
    """psi in P_p: psi_h = psi, nothing to shift (the estimate is the plain one)."""
    problem = _full_contact(0.5 * x * (1 - x) * y, -1.0 * y)  # degree 3
    disc, sol = _solve(problem, 1, 3)
    assert shifted_obstacle(SolutionView.of(disc, sol.x, sol.y)) is None
    e = estimate(disc, sol.x, sol.y, EstimatorOptions(), errors=False)
    assert e.eta_obstacle == 0.0 and math.isnan(e.eta_plain_obstacle)


def test_ex9_keeps_the_plain_bound():
    """ex9 (hemisphere, moderate multiplier): the plain bound is the smaller one; the estimate is unchanged."""
    problem = load_scene("ex9_obstacle").problem
    disc, sol = _solve(problem, 1, 3)
    e = estimate(disc, sol.x, sol.y, EstimatorOptions(), errors=False)
    plain = estimate(disc, sol.x, sol.y, EstimatorOptions(shift_obstacle=False), errors=False)
    assert e.eta_obstacle == 0.0
    assert e.eta == plain.eta == e.eta_plain_obstacle


def test_curved_disk_full_contact_to_the_boundary():
    """Curved P3 elements, psi not a polynomial on the (curved) Dirichlet boundary, contact up to it: the boundary
    lifting takes the boundary layer's gap away too; what remains is the flux term of the curved boundary layer
    (I_eff 24.4 against 182 at level 1); the bound stays guaranteed."""
    from ngcontact.domains import UnitDisk

    C = 0.1 * cos(x) * cos(y)
    problem = ObstacleProblem(domain=UnitDisk(maxh=0.3), psi=C, f=2 * C - LAM, g=C, mu=1.0,
                              exact=ExactSolution(u1=C, lam=LAM + 0 * x), name="disk_obstacle")
    ieff, plain, obst, e = _effectivities(problem, 3, [1])[0]
    assert 1.0 <= ieff < 0.2 * plain
    assert 0.0 < obst < 1.0


def test_obstacle_trace_defect_enters_eta_trace():
    """Polynomial Dirichlet data (g = 0, no trace defect of its own) above a non-polynomial obstacle, contact in the
    middle: when the interpolated-obstacle bound wins, the trace defect indicator of psi is the estimate's eta_trace
    (the shift's premise, delta = 0 on the boundary, holds up to it)."""
    psi = 0.1 * cos(3 * x - 1.5) * cos(3 * y - 1.5) - 0.12
    problem = ObstacleProblem(domain=CrissCrossSquare(n0=4), psi=psi, f=-30.0, g=0.0, mu=1.0, name="interior_contact")
    disc, sol = _solve(problem, 2, 3)
    sv = SolutionView.of(disc, sol.x, sol.y)
    e = estimate(disc, sol.x, sol.y, EstimatorOptions(), errors=False)
    plain = estimate(disc, sol.x, sol.y, EstimatorOptions(shift_obstacle=False), errors=False)
    assert plain.eta_trace == 0.0 and e.eta_obstacle > 0.0
    assert e.eta_trace == pytest.approx(shifted_obstacle(sv).eta_trace, rel=1e-12) and e.eta_trace > 0.0
    assert e.bound_proven


def test_newton_loop_estimators_use_the_interpolated_obstacle():
    """estimate_components (the estimators inside the Newton loop) with shift_obstacle: the same choice as estimate()
    (P3: I_eff 2.05 against 50.1 for psi itself, |||psi - psi~||| in eta_disc); without it (the parabolic estimators)
    the plain bound.  The adaptive Newton mode passes it: its eta_disc of the last step is the shifted one."""
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.estimators import estimate_components
    from ngcontact.scenes import Scene

    problem = _sine()
    disc, sol = _solve(problem, 1, 3)
    err = disc.errors(sol.x, sol.y)["err_energy"]
    e = estimate(disc, sol.x, sol.y, EstimatorOptions(), errors=False)
    shifted = estimate_components(disc, sol.x, sol.y, options=EstimatorOptions(), shift_obstacle=True)
    plain = estimate_components(disc, sol.x, sol.y, options=EstimatorOptions())
    assert shifted.terms["eta_obstacle"] == pytest.approx(err, rel=1e-6) and plain.terms["eta_obstacle"] == 0.0
    assert shifted.eta == pytest.approx(e.eta, rel=1e-2) and e.eta < 0.1 * plain.eta
    run = run_scene(Scene(name="np", path=None, problem=problem), RunOptions(order=3, levels=1, newton="adaptive"))
    assert run.converged
    row = run.rows[-1]
    assert row["eta_disc_final"] <= 2.3 * row["err_energy"]


@pytest.mark.parametrize("edge", [0.5, 0.53])
def test_jumping_obstacle_keeps_the_plain_bound(edge):
    """A step obstacle (not in H^1) at the contact set, along mesh lines (0.5) or across elements (0.53): the shift
    argument needs psi in H^1 there, and |psi - psi_h| beyond what psi's own gradient allows reveals the jump, so no
    shifted obstacle is formed (before the check: one with |||psi - psi~||| computed from the piecewise gradient,
    which does not see the jump)."""
    from ngsolve import IfPos

    problem = ObstacleProblem(domain=CrissCrossSquare(n0=4), psi=IfPos(x - edge, -1.0, 0.05 - 0.2 * (y - 0.5) ** 2),
                              f=-40.0, g=0.1, mu=1.0, name="step")
    disc, sol = _solve(problem, 1, 3)
    assert shifted_obstacle(SolutionView.of(disc, sol.x, sol.y)) is None
    e = estimate(disc, sol.x, sol.y, EstimatorOptions(), errors=False)
    assert e.eta_obstacle == 0.0 and math.isnan(e.eta_plain_obstacle)
