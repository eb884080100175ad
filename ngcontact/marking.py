"""Marking strategies for adaptive refinement: pure functions of the element indicators.

Both take the local indicators eta_K (not squared) and return the indices of
the marked elements, sorted by decreasing eta_K (ties by index).

* :func:`doerfler` -- bulk criterion of Doerfler (SINUM 1996): a set M of
  *minimal cardinality* with  sum_{K in M} eta_K^2 >= theta sum_K eta_K^2.
* :func:`maximum` -- maximum strategy (Babuska-Vogelius):  eta_K >= theta max_K eta_K.

>>> doerfler([1.0, 3.0, 2.0, 0.5], 0.5).tolist()
[1]
>>> doerfler([1.0, 3.0, 2.0, 0.5], 0.9).tolist()
[1, 2]
>>> maximum([1.0, 3.0, 2.0, 0.5], 0.5).tolist()
[1, 2]
"""
from __future__ import annotations

import numpy as np

__all__ = ["doerfler", "maximum", "mark", "MARKINGS", "check_marking"]


def check_marking(strategy: str = "doerfler", theta: float = 0.5) -> None:
    """The one check of the marking parameters (run options and direct calls): ValueError naming the option."""
    if strategy not in MARKINGS:
        raise ValueError(f"option marking must be one of {sorted(MARKINGS)}, got {strategy!r}")
    if isinstance(theta, bool) or not isinstance(theta, (int, float, np.floating)) or not 0 < theta <= 1:
        raise ValueError(f"option theta must be a number in (0, 1], got {theta!r}")


def _check(eta_K, theta, name):
    eta = np.asarray(eta_K, dtype=float).ravel()
    if eta.size and (not np.all(np.isfinite(eta)) or eta.min() < 0):
        raise ValueError(f"{name}: eta_K must be finite and >= 0")
    check_marking(name, theta)
    return eta, float(theta)


def _by_decreasing(eta: np.ndarray) -> np.ndarray:
    return np.lexsort((np.arange(eta.size), -eta))  # stable: larger eta first, then smaller index


def doerfler(eta_K, theta: float = 0.5) -> np.ndarray:
    """Doerfler (bulk) marking: the fewest elements carrying a fraction theta of eta^2.

    Parameters
    ----------
    eta_K : array_like, shape (n,)
        local indicators eta_K >= 0.
    theta : float in (0, 1]
        bulk parameter (theta = 1 marks every element with eta_K > 0).

    Returns
    -------
    ndarray of int
        indices of the marked elements, sorted by decreasing eta_K; empty if
        all indicators vanish.  Taking the largest indicators first makes the
        set minimal: no set with fewer elements reaches theta sum eta_K^2.
    """
    eta, theta = _check(eta_K, theta, "doerfler")
    e2 = eta ** 2
    total = e2.sum()
    if total <= 0.0:
        return np.zeros(0, dtype=np.int64)
    order = _by_decreasing(eta)
    csum = np.cumsum(e2[order])
    # first k with csum[k] >= theta * total (relative round-off guard for theta = 1)
    k = int(np.searchsorted(csum, theta * total * (1 - 1e-14), side="left"))
    return order[: min(k + 1, eta.size)].astype(np.int64)


def maximum(eta_K, theta: float = 0.5) -> np.ndarray:
    """Maximum marking: every element with eta_K >= theta max eta_K (none if all vanish)."""
    eta, theta = _check(eta_K, theta, "max")
    if eta.size == 0 or eta.max() <= 0.0:
        return np.zeros(0, dtype=np.int64)
    order = _by_decreasing(eta)
    return order[eta[order] >= theta * eta.max()].astype(np.int64)


MARKINGS = {"doerfler": doerfler, "max": maximum}


def mark(eta_K, theta: float = 0.5, strategy: str = "doerfler") -> np.ndarray:
    """Dispatch by name: ``strategy`` in :data:`MARKINGS` ('doerfler' or 'max')."""
    check_marking(strategy, theta)
    return MARKINGS[strategy](eta_K, theta)
