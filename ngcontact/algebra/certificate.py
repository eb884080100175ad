"""The exit certificate of a contact solve: is X = (x, y) a solution of the complementarity conditions?

The Newton loop's residual test measures ||Phi(X)|| / ||F||, one number that mixes a residual in the
units of F with a complementarity defect; the certificate checks the three conditions of
g(x) >= 0, y >= 0, g . y = 0 one by one, each in its own units:

* ``penetration`` = max(-g)^+ / U (units of u), U = max(osc x, osc b, SHIFT_FLOOR max(||x||_inf, ||b||_inf)),
  osc v = max v - min v: a constant added to u and to the obstacle (or to both membranes) changes neither the gap
  nor U; the floor keeps round-off gaps of a constant u (osc x = 0) from counting;
* ``negativity``  = max(-y)^+ / Y, Y = max(||y||_inf, ||F||_inf / max D) (units of y: K x - B^T D y = F makes
  F / D a multiplier, and the multipliers y = (K x - F) / D of a solve are resolved to round-off of that size,
  which grows with the condition number of K: where the multiplier vanishes (no contact, or u1 = u2 with
  lam = 0 everywhere) y ~ -1e-13 F / D on a P1 mesh of 8k triangles);
* ``slackness``   = max_i min(g_i^+ / U, y_i^+ / Y) (a row with both an open gap and a positive
  multiplier).

All three are invariant under scaling of the data (u, F, y by s), of the tensions (F, y by s,
u fixed) and under shifts of u and b by a constant.  The certificate holds when each is at most ``tol``;
``tol = inf`` records the values without requiring them (the adaptive stop of [JSC20], whose iterates the
estimators certify).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["Certificate", "certificate", "pair_certificate", "gap_unit", "SHIFT_FLOOR"]

#: the smallest unit of the gap relative to the size of u: gaps of 1e-16 ||x||_inf (round-off) pass the default
#: tolerance 1e-7 even where u is constant
SHIFT_FLOOR = 1e-6


@dataclass(frozen=True)
class Certificate:
    penetration: float
    negativity: float
    slackness: float
    tol: float
    #: what the three measure, in the words of :meth:`failure` (a nonlinear pair names its own functions)
    names: tuple = ("penetration", "negative multiplier", "slackness")

    @property
    def valid(self) -> bool:
        return max(self.penetration, self.negativity, self.slackness) <= self.tol

    def failure(self) -> str:
        """What fails, in words ('' if valid)."""
        bad = [f"{name} {v:.1e}" for name, v in zip(self.names, (self.penetration, self.negativity, self.slackness))
               if not v <= self.tol]
        return "" if not bad else "certificate not met (relative " + ", ".join(bad) + f" > {self.tol:.0e})"

    def as_dict(self) -> dict:
        d = asdict(self)
        d.pop("names")
        d["valid"] = self.valid
        return d


def _inf(v) -> float:
    return float(np.max(np.abs(v))) if len(v) else 0.0


def _osc(v) -> float:
    return float(np.max(v) - np.min(v)) if len(v) else 0.0


def pair_certificate(a: np.ndarray, b: np.ndarray, A: float, B: float, tol: float,
                     names: tuple = Certificate.names) -> Certificate:
    """The certificate of a >= 0, b >= 0, a . b = 0 with a measured relative to A and b relative to B (``names``:
    the words of its failure message for negative a, negative b, both positive)."""
    tiny = np.finfo(float).tiny
    if not len(a):
        return Certificate(0.0, 0.0, 0.0, tol, names)
    A, B = max(A, tiny), max(B, tiny)
    pen = max(0.0, float(np.max(-a))) / A
    neg = max(0.0, float(np.max(-b))) / B
    slack = float(np.max(np.minimum(np.maximum(a, 0.0) / A, np.maximum(b, 0.0) / B)))
    vals = [v if np.isfinite(v) else float("inf") for v in (pen, neg, slack)]
    return Certificate(*vals, tol, names)


def certificate(system, x: np.ndarray, y: np.ndarray, tol: float) -> Certificate:
    """The certificate of (x, y) for the linear complementarity ``system`` (module doc)."""
    Dmax = float(np.max(system.D)) if len(system.D) else 1.0
    Y = max(_inf(y), _inf(system.F) / Dmax)
    return pair_certificate(system.gap(x), y, gap_unit(system, x), Y, tol)


def gap_unit(system, x: np.ndarray) -> float:
    """U of the module doc: the unit of the gaps of ``x`` (shift-invariant)."""
    size = max(_inf(x), _inf(system.b))
    return max(_osc(x), _osc(system.b), SHIFT_FLOOR * size)
