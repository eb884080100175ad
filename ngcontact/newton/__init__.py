"""Semismooth Newton for the complementarity systems of :mod:`ngcontact.algebra`.

One loop (:mod:`.loop`); the linear solves (:mod:`.linear`: direct, or GMRES + ILU in the modes
``gmres`` / ``inexact`` / ``adaptive`` of [JSC20]; :mod:`.multigrid`: CG + truncated multigrid) and the stopping rule (:mod:`.stopping`: residual,
balanced, adaptive) are objects handed to it; :mod:`.decoupled` splits two membranes with
proportional stiffness into a w = u1 - u2 Newton and one linear solve.  This layer imports only
:mod:`ngcontact.algebra`: estimators reach it as objects from the drivers.
"""
from .base import IterationRecord, NewtonOptions, NewtonResult
from .decoupled import decoupled_newton
from .linear import KRYLOV_MODES, DirectSolve, EstimatorRecord, KrylovIterationRecord, KrylovSolve
from .loop import semismooth_newton
from .multigrid import MULTIGRID_MODES, MultigridIterationRecord, MultigridSolve
from .stopping import AdaptiveStop, BalancedStop, Reference, ResidualStop, StopOptions

__all__ = ["NewtonOptions", "IterationRecord", "NewtonResult", "semismooth_newton", "decoupled_newton",
           "DirectSolve", "KrylovSolve", "KrylovIterationRecord", "EstimatorRecord", "KRYLOV_MODES",
           "MultigridSolve", "MultigridIterationRecord", "MULTIGRID_MODES", "StopOptions", "ResidualStop", "BalancedStop", "AdaptiveStop", "Reference"]
