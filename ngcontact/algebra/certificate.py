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

__all__ = ["Certificate", "certificate", "pair_certificate", "ROUND_OFF"]

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


def pair_certificate(a: np.ndarray, b: np.ndarray, A: float, B: float, tol: float) -> Certificate:
    """The certificate of a >= 0, b >= 0, a . b = 0 with a measured relative to A and b relative to B."""
    tiny = np.finfo(float).tiny
    if not len(a):
        return Certificate(0.0, 0.0, 0.0, tol)
    A, B = max(A, tiny), max(B, tiny)
    pen = max(0.0, float(np.max(-a))) / A
    neg = max(0.0, float(np.max(-b))) / B
    slack = float(np.max(np.minimum(np.maximum(a, 0.0) / A, np.maximum(b, 0.0) / B)))
    vals = [v if np.isfinite(v) else float("inf") for v in (pen, neg, slack)]
    return Certificate(*vals, tol)


def certificate(system, x: np.ndarray, y: np.ndarray, tol: float) -> Certificate:
    """The certificate of (x, y) for the linear complementarity ``system`` (module doc)."""
    Dmax = float(np.max(system.D)) if len(system.D) else 1.0
    U = max(_inf(x), _inf(system.b))
    Y = max(_inf(y), ROUND_OFF * _inf(system.F) / Dmax)
    return pair_certificate(system.gap(x), y, U, Y, tol)
