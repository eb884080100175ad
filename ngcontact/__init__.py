"""ngcontact: contact problems (variational inequalities) on NGSolve.

Problem data (:mod:`ngcontact.problems`), domains and meshes
(:mod:`ngcontact.domains`), discretizations (:mod:`ngcontact.discretizations`),
C-functions and semismooth Newton (:mod:`ngcontact.algebra.cfunctions`,
:mod:`ngcontact.newton`), runs and outputs (:mod:`ngcontact.drivers`,
:mod:`ngcontact.results`, :mod:`ngcontact.plotting`, :mod:`ngcontact.cli`).
Threads: ``ngcontact.drivers.run_scene(..., threads=N)`` or the environment variable NGCONTACT_THREADS.
"""
__version__ = "0.1.0"

from .domains import (CrissCrossSquare, Domain, GeometryDomain, LShape, MeshDomain, MeshFileDomain,  # noqa: E402
                      StructuredSquare, UnitDisk, as_domain, mesh_size)
from .problems import ExactSolution, ObstacleProblem, ProblemDataError, TwoMembraneProblem  # noqa: E402

__all__ = [
    "CrissCrossSquare", "Domain", "GeometryDomain", "LShape", "MeshDomain", "MeshFileDomain", "StructuredSquare",
    "UnitDisk", "as_domain", "mesh_size", "ExactSolution", "ObstacleProblem", "ProblemDataError", "TwoMembraneProblem",
]
