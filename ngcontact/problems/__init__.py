"""Problem data: the declared problem interface, two membranes, obstacle; exact solutions; data checks."""
from .base import (BoundaryOrder, ContactProblem, ExactSolution, Problem, ProblemDataError, check_data_on_points,
                   data_fields)
from .membranes import TwoMembraneProblem
from .obstacle import ObstacleProblem
from .parabolic import ParabolicProblem, check_initial_on_points

__all__ = ["BoundaryOrder", "ContactProblem", "ExactSolution", "ObstacleProblem", "ParabolicProblem", "Problem", "ProblemDataError",
           "TwoMembraneProblem", "check_data_on_points", "check_initial_on_points", "data_fields"]
