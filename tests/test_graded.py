"""Energy errors of solutions with point singularities: the graded rule (ngcontact/discretizations/graded.py)."""
import pytest
from ngsolve import Integrate, Mesh, x, y
from netgen.geom2d import unit_square

from ngcontact import ExactSolution
from ngcontact.discretizations import graded
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.newton import NewtonOptions, semismooth_newton
from ngcontact.scenes import load_scene

# int_{(0,1)^2} r^{-2/3}: polar coordinates, theta in (0, pi/4) twice, int_0^{1/cos} r^{1/3} dr = 3/4 cos^{-4/3}
R_23 = 2 * 0.75 * 0.9181133309375813  # int_0^{pi/4} cos(theta)^{-4/3} dtheta (scipy quad; = 1.37717 / 1.5, dblquad)


def test_graded_rule_integrates_a_corner_singularity():
    """r^{-2/3} (the density |grad u|^2 of the L-shape's corner function) over the unit square: the graded rule
    reaches 1e-7 relative (measured 9e-8, 1.5e-9, 5e-13 for orders 8, 12, 20: the elements next to the corner keep
    the plain rule) where Gauss rules of those orders on the same mesh are off by 7e-5...5e-4."""
    mesh = Mesh(unit_square.GenerateMesh(maxh=0.2))
    f = (x * x + y * y) ** (-1 / 3)
    for order in (8, 12, 20):
        assert abs(Integrate(f, mesh, order=order) / R_23 - 1) > 5e-5
        assert abs(graded.integrate_graded(f, mesh, order, [(0.0, 0.0)]) / R_23 - 1) <= 1e-7


def test_lshape_energy_error_with_the_graded_rule():
    """L-shape P3, mesh level 1: err_energy with the declared corner equals the value of a finer graded rule
    (depth 28, order + 8) to 1e-7; without the corner declared it is 7 % too small (the outside audit's
    I_eff 1.37 against 1.27)."""
    from dataclasses import replace

    scene = load_scene("lshape")
    problem = scene.problem
    assert problem.exact.singular_points == ((0.0, 0.0),)
    disc = FEMDiscretization(problem, problem.domain.mesh(1), order=3)
    sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
    err = disc.errors(sol.x, sol.y)["err_energy"]
    old = graded.DEPTH
    try:
        graded.DEPTH = 28
        disc.quad_bonus += 8
        fine = disc.errors(sol.x, sol.y)["err_energy"]
    finally:
        graded.DEPTH = old
        disc.quad_bonus -= 8
    assert abs(err / fine - 1) <= 1e-7
    plain = FEMDiscretization(replace(problem, exact=replace(problem.exact, singular_points=())),
                              problem.domain.mesh(1), order=3)
    assert plain.errors(sol.x, sol.y)["err_energy"] < 0.95 * err


@pytest.mark.parametrize("bad", [((0.0,),), (1.0, 2.0), "corner", ((0, "a"),)])
def test_singular_points_must_be_points(bad):
    with pytest.raises(ValueError, match="singular_points must be a sequence of points"):
        ExactSolution(u1=x, singular_points=bad)
