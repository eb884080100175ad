"""Two-phase water-hydrogen flow with gas appearance and disappearance (MoMaS / Couplex-gas 1D; [CG20], [BGJ14]).

What is solved: :mod:`.params` (validated data), :mod:`.laws` (van Genuchten-Mualem, regularized at
S = 1); how: :mod:`.mesh1d` (cell-centred geometry) and :mod:`.fv` (two-point FV, upwind, backward
Euler -> one nonlinear complementarity system per step, :mod:`ngcontact.algebra.nonlinear`);
running: :mod:`.run` (time loop through the one Newton loop, dt cuts on failure),
:mod:`.estimators` ([CG20] a posteriori components and adaptive stopping), :mod:`.outputs`
(CSV, JSON, plots).  numpy/scipy only.
"""
from .params import YEAR, TwoPhaseParams
from .run import TwoPhaseRun, run_h2

__all__ = ["TwoPhaseParams", "YEAR", "run_h2", "TwoPhaseRun"]
