"""Problem data: two membranes, obstacle; exact solutions; data checks."""
from .base import (ExactSolution, ObstacleProblem, ProblemDataError, TwoMembraneProblem, check_data_on_points,
                   data_fields)

__all__ = ["ExactSolution", "ObstacleProblem", "ProblemDataError", "TwoMembraneProblem", "check_data_on_points",
           "data_fields"]
