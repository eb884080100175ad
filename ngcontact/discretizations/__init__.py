"""Discretizations: turn problem data + mesh into a complementarity system.

Each class takes ``(problem, mesh, order=..., solver=...)`` and exposes
``system`` (:class:`~ngcontact.complementarity.ComplementaritySystem`),
``ndof``, ``initial_guess``, ``prolongate``, ``gridfunctions``, ``errors``,
``complementarity`` and ``time_assembly``.
"""
from .fem import FEMDiscretization


DISCRETIZATIONS = {"fem": FEMDiscretization}

__all__ = ["DISCRETIZATIONS", "FEMDiscretization"]
