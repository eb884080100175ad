"""Convergence rates: the one helper used by tables, plots and tests."""
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


def fitted_rate(h, err, last: int = 3) -> float:
    """Least-squares slope of log(err) against log(h) over the last levels.

    >>> round(fitted_rate([1, 0.5, 0.25, 0.125], [3, 0.8, 0.2, 0.05], last=3), 6)
    2.0
    """
    h, err = np.asarray(h, float)[-last:], np.asarray(err, float)[-last:]
    return float(np.polyfit(np.log(h), np.log(err), 1)[0])
