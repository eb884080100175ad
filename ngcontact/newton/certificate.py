"""The exit certificate of a contact solve: is X = (x, y) a solution of the complementarity conditions?

The Newton loop's residual test measures ||Phi(X)|| / ||F||, one number that mixes a residual in the
units of F with a complementarity defect; the certificate checks the three conditions of
g(x) >= 0, y >= 0, g . y = 0 one by one, each in its own units:

* ``penetration`` = max(-g)^+ / U, U = max(||x||_inf, ||b||_inf) (units of u);
* ``negativity``  = max(-y)^+ / Y, Y = max(||y||_inf, ROUND_OFF ||F||_inf / max D) (units of y:
  K x - B^T D y = F makes F / D a multiplier; the second term keeps round-off multipliers of a
  solve without contact from counting as negative);
* ``slackness``   = max_i min(g_i^+ / U, y_i^+ / Y) (a row with both an open gap and a positive
  multiplier).

All three are invariant under scaling of the data (u, F, y by s) and of the tensions (F, y by s,
u fixed).  The certificate holds when each is at most ``tol``; ``tol = inf`` records the values
without requiring them (the adaptive stop of [JSC20], whose iterates the estimators certify).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["Certificate", "certificate", "ROUND_OFF"]

#: multipliers below ROUND_OFF ||F||_inf / max D are round-off (a solve without contact leaves y ~ 1e-19 there)
ROUND_OFF = 1e-8


@dataclass(frozen=True)
class Certificate:
    penetration: float
    negativity: float
    slackness: float
    tol: float

    @property
    def valid(self) -> bool:
        return max(self.penetration, self.negativity, self.slackness) <= self.tol

    def failure(self) -> str:
        """What fails, in words ('' if valid)."""
        bad = [f"{name} {v:.1e}" for name, v in (("penetration", self.penetration),
                                                  ("negative multiplier", self.negativity),
                                                  ("slackness", self.slackness)) if not v <= self.tol]
        return "" if not bad else "certificate not met (relative " + ", ".join(bad) + f" > {self.tol:.0e})"

    def as_dict(self) -> dict:
        d = asdict(self)
        d["valid"] = self.valid
        return d


def _inf(v) -> float:
    return float(np.max(np.abs(v))) if len(v) else 0.0


def certificate(system, x: np.ndarray, y: np.ndarray, tol: float) -> Certificate:
    """The certificate of (x, y) for ``system`` (module doc)."""
    tiny = np.finfo(float).tiny
    g = system.gap(x)
    U = max(_inf(x), _inf(system.b), tiny)
    Dmax = float(np.max(system.D)) if len(system.D) else 1.0
    Y = max(_inf(y), ROUND_OFF * _inf(system.F) / Dmax, tiny)
    if not len(g):
        return Certificate(0.0, 0.0, 0.0, tol)
    pen = max(0.0, float(np.max(-g))) / U
    neg = max(0.0, float(np.max(-y))) / Y
    slack = float(np.max(np.minimum(np.maximum(g, 0.0) / U, np.maximum(y, 0.0) / Y)))
    vals = [pen, neg, slack]
    vals = [v if np.isfinite(v) else float("inf") for v in vals]
    return Certificate(*vals, tol)
