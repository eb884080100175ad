"""Problem data validation: errors name the field and the value."""
import pytest
from ngsolve import IfPos, x, y

from ngcontact import CrissCrossSquare, ExactSolution, ObstacleProblem, ProblemDataError, TwoMembraneProblem
from ngcontact.discretizations.fem import FEMDiscretization

SQ = CrissCrossSquare()


@pytest.mark.parametrize("field,value", [("mu1", 0.0), ("mu2", -1.0), ("mu1", float("nan")), ("mu2", "abc")])
def test_nonpositive_tension_is_rejected(field, value):
    with pytest.raises(ProblemDataError, match=f"TwoMembraneProblem.{field}"):
        TwoMembraneProblem(SQ, f1=0.0, f2=0.0, **{field: value})


def test_nonfinite_constant_is_rejected():
    with pytest.raises(ProblemDataError, match="f1 must be finite"):
        TwoMembraneProblem(SQ, f1=float("inf"), f2=0.0)


def test_wrong_types_are_rejected():
    with pytest.raises(ProblemDataError, match="TwoMembraneProblem.f2"):
        TwoMembraneProblem(SQ, f1=0.0, f2="x**2")
    with pytest.raises(ProblemDataError, match="domain"):
        TwoMembraneProblem("unit square", f1=0.0, f2=0.0)
    with pytest.raises(ProblemDataError, match="exact.u2"):
        TwoMembraneProblem(SQ, f1=0.0, f2=0.0, exact=ExactSolution(u1=x))


def test_nonfinite_load_detected_on_the_mesh():
    prob = TwoMembraneProblem(SQ, f1=1.0 / x, f2=0.0)  # inf on the side x = 0
    with pytest.raises(ProblemDataError, match=r"f1 is not finite at \(0, "):
        FEMDiscretization(prob, SQ.mesh(0), order=1)


def test_incompatible_boundary_data_g1_below_g2():
    prob = TwoMembraneProblem(SQ, f1=0.0, f2=0.0, g1=IfPos(x - 0.9, -1.0, 0.0), g2=0.0)
    with pytest.raises(ProblemDataError, match="g1 < g2 on the boundary"):
        FEMDiscretization(prob, SQ.mesh(0), order=2)


def test_obstacle_above_dirichlet_data():
    prob = ObstacleProblem(SQ, psi=y - 0.5, g=0.0)
    with pytest.raises(ProblemDataError, match="obstacle psi above the Dirichlet data"):
        FEMDiscretization(prob, SQ.mesh(0), order=1)


def test_bad_order_is_rejected():
    prob = TwoMembraneProblem(SQ, f1=0.0, f2=0.0)
    with pytest.raises(ValueError, match="order must be 1, 2, 3 or 4"):
        FEMDiscretization(prob, SQ.mesh(0), order=5)
