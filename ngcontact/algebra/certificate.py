"""The exit certificate of a contact solve: is X = (x, y) a solution of the complementarity conditions?

The Newton loop's residual test measures ||Phi(X)|| / ||F||, one number that mixes a residual in the
units of F with a complementarity defect; the certificate checks the three conditions of
g(x) >= 0, y >= 0, g . y = 0 one by one and the equilibrium K x - B^T D y = F field by field, each in its own
units:

* ``penetration`` = max(-g)^+ / U (units of u), U = max(osc x, osc b, SHIFT_FLOOR max(||x||_inf, ||b||_inf)),
  osc v = max v - min v: a constant added to u and to the obstacle (or to both membranes) changes neither the gap
  nor U; the floor keeps round-off gaps of a constant u (osc x = 0) from counting;
* ``negativity``  = max(-y)^+ / Y, Y = max(||y||_inf, ||F||_inf / max D) (units of y: K x - B^T D y = F makes
  F / D a multiplier, and the multipliers y = (K x - F) / D of a solve are resolved to round-off of that size,
  which grows with the condition number of K: where the multiplier vanishes (no contact, or u1 = u2 with
  lam = 0 everywhere) y ~ -1e-13 F / D on a P1 mesh of 8k triangles);
* ``slackness``   = max_i min(g_i^+ / U, y_i^+ / Y_i) (a row with both an open gap and a positive
  multiplier).

The multiplier's unit is row by row Y_i = min(Y, 1 / P_i), P_i = D_i max(1 / (K_jj U_up), 1 / (K_kk U_lo))
over the row's unknowns j (up) and k (lo): y_i D_i / K_jj is about the displacement that the multiplier
of row i gives its unknown j, and U_up, U_lo are the units of the up and lo unknowns on their own
(max(osc, SHIFT_FLOOR max(||x||_inf, ||b||_inf)) of x[up], x[lo]).  A multiplier is so measured also by what
it does to the softer field: with tensions 1e9 apart a multiplier of -3e-13 Y pushed the soft membrane by
1.6e-4 of its size (outside audit, stop 48) and passed; where the fields are alike (h^2 f / (mu U) < 1),
Y_i = Y.  ``negativity`` uses Y_i as well.

* ``equilibrium`` = the residual r = K x - B^T D y - F of the constrained unknowns in the units of their own
  field, max_j |r_j| / (K_jj U_up) over the up unknowns of rows without contact (y_i <= 0), likewise for
  lo with U_lo, and on rows in contact (y_i > 0) with a lo unknown the sum r_up + r_lo, where y cancels, over
  (K_jj + K_kk) min(U_up, U_lo) (one-sided rows in contact: y takes up the residual, nothing to measure); above
  ``tol``, only the part of each residual beyond the round-off of its evaluation counts (:func:`equilibrium`).  The
  loop's residual test measures ||Phi|| / ||F|| in one norm, which the stiffer field's rows dominate: with
  tensions 1e12 apart the inexact modes stopped with the softer field's rows at 1e-3 of its size.

All four are invariant under scaling of the data (u, F, y by s), of the tensions (F, y by s,
u fixed) and under shifts of u and b by a constant.  The certificate holds when each is at most ``tol``;
``tol = inf`` records the values without requiring them (the adaptive stop of [JSC20], whose iterates the
estimators certify).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from .sparse import abs_matrix

__all__ = ["Certificate", "certificate", "pair_certificate", "gap_unit", "multiplier_units", "equilibrium",
           "SHIFT_FLOOR"]

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
    equilibrium: float = 0.0

    @property
    def valid(self) -> bool:
        return max(self.penetration, self.negativity, self.slackness, self.equilibrium) <= self.tol

    def failure(self) -> str:
        """What fails, in words ('' if valid)."""
        named = zip(self.names + ("residual in the units of its field",),
                    (self.penetration, self.negativity, self.slackness, self.equilibrium))
        bad = [f"{name} {v:.1e}" for name, v in named if not v <= self.tol]
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
    """The certificate of a >= 0, b >= 0, a . b = 0 with a measured relative to A and b relative to B (a number or
    one per row; ``names``: the words of its failure message for negative a, negative b, both positive)."""
    tiny = np.finfo(float).tiny
    if not len(a):
        return Certificate(0.0, 0.0, 0.0, tol, names)
    A, B = max(A, tiny), np.maximum(B, tiny)
    pen = max(0.0, float(np.max(-a))) / A
    neg = max(0.0, float(np.max(-b / B)))
    slack = float(np.max(np.minimum(np.maximum(a, 0.0) / A, np.maximum(b, 0.0) / B)))
    vals = [v if np.isfinite(v) else float("inf") for v in (pen, neg, slack)]
    return Certificate(*vals, tol, names)


def certificate(system, x: np.ndarray, y: np.ndarray, tol: float) -> Certificate:
    """The certificate of (x, y) for the linear complementarity ``system`` (module doc)."""
    Dmax = float(np.max(system.D)) if len(system.D) else 1.0
    Y = max(_inf(y), _inf(system.F) / Dmax)
    cert = pair_certificate(system.gap(x), y, gap_unit(system, x), multiplier_units(system, x, Y), tol)
    eq = equilibrium(system, x, y, tol)
    return replace(cert, equilibrium=eq if np.isfinite(eq) else float("inf"))


def _field_unit(system, x: np.ndarray, cols: np.ndarray) -> float:
    """U_up or U_lo of the module doc."""
    floor = SHIFT_FLOOR * max(_inf(x), _inf(system.b))
    return max(_osc(x[cols]), floor, np.finfo(float).tiny)


#: the residual of a row counts beyond ROUND_OFF eps (|K| |x| + |B^T D y| + |F|) of that row, its evaluation's round-off
ROUND_OFF = 64.0


def _measure(system, x, y, r, allowance) -> float:
    tiny = np.finfo(float).tiny
    d = np.maximum(system.diagonal(), tiny)
    a = np.maximum(np.abs(r) - allowance, 0.0) if allowance is not None else np.abs(r)
    free, two = ~(y > 0), system.lo >= 0
    up, lo = system.up, system.lo[two]
    U_up = _field_unit(system, x, up)
    out = float(np.max(a[up[free]] / d[up[free]], initial=0.0)) / U_up
    if len(lo):
        U_lo = _field_unit(system, x, lo)
        f2 = free[two]
        out = max(out, float(np.max(a[lo[f2]] / d[lo[f2]], initial=0.0)) / U_lo)
        ju, jl = system.up[two][~f2], lo[~f2]
        both = r[ju] + r[jl]
        if allowance is not None:
            both = np.maximum(np.abs(both) - allowance[ju] - allowance[jl], 0.0)
        out = max(out, float(np.max(np.abs(both) / (d[ju] + d[jl]), initial=0.0)) / min(U_up, U_lo))
    return out


def equilibrium(system, x: np.ndarray, y: np.ndarray, tol: float = 0.0) -> float:
    """``equilibrium`` of the module doc.  Where it exceeds ``tol``, each row's residual counts only beyond
    :data:`ROUND_OFF` eps times the size of its terms: loads 1e12 times the elastic
    forces, balanced in contact, leave a residual of eps |F| that no x removes, and so does a field of constant
    value (its range, the unit, is a 1e-6 floor of its size)."""
    if not len(system.up):
        return 0.0
    r = system.residual(x, y)
    out = _measure(system, x, y, r, None)
    if out <= tol:
        return out
    size = abs_matrix(system.K) @ np.abs(x) + np.abs(system._B.T @ (system.D * y)) + np.abs(system.F)
    return _measure(system, x, y, r, ROUND_OFF * np.finfo(float).eps * size)


def multiplier_units(system, x: np.ndarray, Y: float) -> np.ndarray:
    """Y_i of the module doc: the unit of each row's multiplier, at most ``Y``."""
    tiny = np.finfo(float).tiny
    d = system.diagonal()
    push = np.zeros(len(system.up))
    for rows, cols in ((slice(None), system.up), (system.lo >= 0, system.lo[system.lo >= 0])):
        if len(cols):
            U = _field_unit(system, x, cols)
            push[rows] = np.maximum(push[rows], system.D[rows] / (np.maximum(d[cols], tiny) * U))
    units = np.full(len(push), Y)
    big = push * Y > 1.0
    units[big] = 1.0 / push[big]
    return units


def gap_unit(system, x: np.ndarray) -> float:
    """U of the module doc: the unit of the gaps of ``x`` (shift-invariant)."""
    size = max(_inf(x), _inf(system.b))
    return max(_osc(x), _osc(system.b), SHIFT_FLOOR * size)
