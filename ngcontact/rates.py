"""Convergence rates: the one place where rates and fitted slopes are computed (tables, plots, tests)."""
from __future__ import annotations

import numpy as np

__all__ = ["rates", "fitted_rate"]


def rates(h, err) -> np.ndarray:
    """Rates between consecutive levels, log(e_{j-1}/e_j) / log(h_{j-1}/h_j); nan first.

    >>> rates([0.5, 0.25, 0.125], [1.0, 0.25, 0.0625]).round(6).tolist()
    [nan, 2.0, 2.0]
    """
    h, err = np.asarray(h, float), np.asarray(err, float)
    out = np.full(len(err), np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        out[1:] = np.log(err[:-1] / err[1:]) / np.log(h[:-1] / h[1:])
    return out


def fitted_rate(x, values, last: int = 3) -> float:
    """Least-squares slope of log(values) against log(x) over the last ``last`` points.

    With x = h it is the convergence rate in h (energy error of P_p: p); with x = ndof it is the
    slope against the number of unknowns (energy error of P_p in 2D: -p/2).

    >>> round(fitted_rate([1, 0.5, 0.25, 0.125], [3, 0.8, 0.2, 0.05], last=3), 6)
    2.0
    >>> round(fitted_rate([10, 100, 1000], [1.0, 0.1, 0.01]), 6)
    -1.0
    """
    x, v = np.asarray(x, float)[-last:], np.asarray(values, float)[-last:]
    return float(np.polyfit(np.log(x), np.log(v), 1)[0])
