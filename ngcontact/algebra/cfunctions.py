"""Complementarity functions (C-functions) and their generalized Jacobians.

A C-function phi satisfies phi(a, b) = 0  <=>  a >= 0, b >= 0, a b = 0
(seed slide "C-functions"; Facchinei & Pang 2003).  Applied componentwise to
a = X1 - X2 (the gap) and b = X3 (the multiplier), the discrete complementarity
problem becomes the nonsmooth system  E X = F,  C(X) = 0.

Each C-function gives its value and an element (da, db) of the generalized
(Clarke / B-) Jacobian, diagonal in (a, b).
"""
from __future__ import annotations

import numpy as np

__all__ = ["CFunction", "MinFunction", "FischerBurmeister", "get_cfunction", "CFUNCTIONS"]


class CFunction:
    """Base class: ``value(a, b)`` and ``jacobian(a, b) -> (da, db)``."""

    name = "abstract"

    def value(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def jacobian(self, a: np.ndarray, b: np.ndarray):
        raise NotImplementedError

    def __repr__(self):
        return f"{type(self).__name__}()"


class MinFunction(CFunction):
    """phi(a, b) = min(a, b).

    Jacobian: (1, 0) where a <= b (the gap is selected: contact, "active"),
    (0, 1) where a > b.  Newton-min with this choice is the primal-dual
    active set method (Hintermüller, Ito, Kunisch 2002).

    >>> MinFunction().value(np.array([1., -2.]), np.array([0.5, 3.])).tolist()
    [0.5, -2.0]
    """

    name = "min"

    def value(self, a, b):
        return np.minimum(a, b)

    def jacobian(self, a, b):
        sel = a <= b
        return sel.astype(float), (~sel).astype(float)


class FischerBurmeister(CFunction):
    """phi(a, b) = sqrt(a^2 + b^2) - a - b (Fischer 1992).

    Jacobian: (a/r - 1, b/r - 1), r = sqrt(a^2 + b^2); at a = b = 0 the
    element (1/sqrt 2 - 1, 1/sqrt 2 - 1) of the generalized Jacobian.
    Both entries lie in [-2, 0] and are not both zero, so the reduced Newton
    matrix stays symmetric positive definite (see :mod:`ngcontact.newton`).

    >>> float(FischerBurmeister().value(np.array([0.]), np.array([2.]))[0])
    0.0
    """

    name = "fb"

    def value(self, a, b):
        return np.hypot(a, b) - a - b

    def jacobian(self, a, b):
        r = np.hypot(a, b)
        zero = r == 0.0
        rs = np.where(zero, 1.0, r)
        s = 1.0 / np.sqrt(2.0)
        da = np.where(zero, s, a / rs) - 1.0
        db = np.where(zero, s, b / rs) - 1.0
        return da, db


CFUNCTIONS = {"min": MinFunction, "fb": FischerBurmeister}


def get_cfunction(name) -> CFunction:
    """C-function by name ('min' or 'fb'), or pass an instance through."""
    if isinstance(name, CFunction):
        return name
    try:
        return CFUNCTIONS[name]()
    except KeyError:
        raise ValueError(f"cfun must be one of {sorted(CFUNCTIONS)}, got {name!r}") from None
