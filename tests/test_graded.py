"""Energy errors of solutions with point singularities: the graded rule (ngcontact/discretizations/graded.py)."""
import numpy as np
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


def _error_and_finer(disc, sol):
    """err_energy of ``disc`` at ``sol``, and the same with a finer graded rule (depth 28, order + 8)."""
    err = disc.errors(sol.x, sol.y)["err_energy"]
    old = graded.DEPTH
    try:
        graded.DEPTH = 28
        disc.quad_bonus += 8
        fine = disc.errors(sol.x, sol.y)["err_energy"]
    finally:
        graded.DEPTH = old
        disc.quad_bonus -= 8
    return err, fine


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
    err, fine = _error_and_finer(disc, sol)
    assert abs(err / fine - 1) <= 1e-7
    plain = FEMDiscretization(replace(problem, exact=replace(problem.exact, singular_points=())),
                              problem.domain.mesh(1), order=3)
    assert plain.errors(sol.x, sol.y)["err_energy"] < 0.95 * err


@pytest.mark.parametrize("bad", [((0.0,),), (1.0, 2.0), "corner", ((0, "a"),), 3, (p for p in [(0.0,)])])
def test_singular_points_must_be_points(bad):
    with pytest.raises(ValueError, match="singular_points must be a sequence of points"):
        ExactSolution(u1=x, singular_points=bad)
    assert ExactSolution(u1=x, singular_points=(p for p in [(0, 1)])).singular_points == ((0.0, 1.0),)


def test_graded_rule_finds_the_element_containing_the_point_and_curved_elements():
    """Outside review, stop 49: a point at an element's centroid (0.505 diameters from its nearest vertex) was
    graded towards by no element (error 1e-2 at order 20, as the plain rule); two points on one element were graded
    towards the last one only (4e-5); curved elements took the straight triangle's area (-2e-4 on the disk).  Now:
    the centroid case agrees with a finer graded rule to 1e-8, two points to 1e-7, and on a curved disk the
    graded rule integrates 1 as NGSolve does."""
    from ngsolve import CF, sqrt
    from ngcontact.domains import UnitDisk

    mesh = Mesh(unit_square.GenerateMesh(maxh=0.2))
    coords, els = graded._triangles(mesh)
    c = coords[els[7]].mean(axis=0)
    f = ((x - c[0]) ** 2 + (y - c[1]) ** 2) ** (-1 / 3)
    value = graded.integrate_graded(f, mesh, 12, [tuple(c)])
    old = graded.DEPTH
    try:
        graded.DEPTH = 28
        fine = graded.integrate_graded(f, mesh, 20, [tuple(c)])
    finally:
        graded.DEPTH = old
    assert abs(value / fine - 1) <= 1e-8 < 1e-4 <= abs(Integrate(f, mesh, order=12) / fine - 1)
    a, b = coords[els[7]][0], coords[els[7]][1]  # two vertices of one element
    fa = ((x - a[0]) ** 2 + (y - a[1]) ** 2) ** (-1 / 3)
    fb = ((x - b[0]) ** 2 + (y - b[1]) ** 2) ** (-1 / 3)
    both = graded.integrate_graded(fa + fb, mesh, 12, [tuple(a), tuple(b)])
    apart = graded.integrate_graded(fa, mesh, 12, [tuple(a)]) + graded.integrate_graded(fb, mesh, 12, [tuple(b)])
    assert abs(both / apart - 1) <= 1e-7
    disk = UnitDisk(maxh=0.3).mesh(0)
    disk.Curve(3)
    pts = np.array(disk.ngmesh.Coordinates())[:, :2]
    p = pts[np.argmax(np.linalg.norm(pts, axis=1))]  # on the curved boundary
    one = CF(1.0) + 0 * sqrt(x * x)
    assert abs(graded.integrate_graded(one, disk, 8, [tuple(p)]) / Integrate(one, disk, order=8) - 1) <= 1e-12


def test_hho_energy_error_with_the_graded_rule():
    """HHO P3 on the L-shape, mesh level 1: the error of the cell unknowns with the declared corner equals a finer
    graded rule (depth 28, order + 8) to 1e-7; the fixed rule (corner not declared) is 4 % too small."""
    from dataclasses import replace

    from ngcontact.discretizations.hho import HHODiscretization

    problem = load_scene("lshape").problem
    mesh = problem.domain.mesh(1)
    disc = HHODiscretization(problem, mesh, order=3)
    sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
    err, fine = _error_and_finer(disc, sol)
    assert abs(err / fine - 1) <= 1e-7
    plain = HHODiscretization(replace(problem, exact=replace(problem.exact, singular_points=())), mesh, order=3)
    assert plain.errors(sol.x, sol.y)["err_energy"] < 0.97 * err
