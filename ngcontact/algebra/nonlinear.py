r"""The nonlinear complementarity system: what the Newton loop needs from a problem like two-phase flow.

    R(X) = 0,    a(X) >= 0,  b(X) >= 0,  a(X) . b(X) = 0,

with R the conservation equations and (a, b) a complementary pair of *functions* of the unknowns
(two-phase flow [CG20]: a = 1 - S, b = H (P + P_c(S)) - beta_l chi).  With a C-function
phi the system reads Phi(X) = [R(X); C(a(X), b(X))] = 0, and a semismooth Newton step solves

    J dX = -Phi(X),    J = [dR/dX; Ca da/dX + Cb db/dX],

(Ca, Cb) the C-function's diagonal generalized Jacobian at (a(X), b(X)).  The matrix is
nonsymmetric; no reduction to an SPD system as for the linear systems of :mod:`.system`.

The Newton loop (:func:`ngcontact.newton.loop.semismooth_newton`) calls a system through
``residual(x, y)``, ``pair(x, y)`` and ``scale()``; the linear strategies of
:mod:`ngcontact.newton.nonlinear` call ``stack``, ``jacobian`` and ``exact_rows``.  ``y`` is the part of the
unknowns kept apart by the loop (multipliers of the linear systems); the systems here have none
and take an empty array.
"""
from __future__ import annotations

import numpy as np

from .certificate import pair_certificate

__all__ = ["NonlinearComplementaritySystem"]


class NonlinearComplementaritySystem:
    """Protocol (base class documenting it; every method is overridden by a concrete system).

    Attributes
    ----------
    n : int
        number of unknowns X (= number of rows of Phi).
    y0 : ndarray
        the empty multiplier vector handed to the loop.
    """

    n: int = 0
    y0 = np.zeros(0)

    def residual(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """R(X): the conservation rows, in the units of the stopping test (scaled by the system)."""
        raise NotImplementedError

    def pair(self, x: np.ndarray, y: np.ndarray):
        """(a(X), b(X)): the complementary pair, one entry per constraint."""
        raise NotImplementedError

    def stack(self, r: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Phi = [R; C] in the row order of :meth:`jacobian`."""
        raise NotImplementedError

    def jacobian(self, x: np.ndarray, y: np.ndarray, Ca: np.ndarray, Cb: np.ndarray):
        """The sparse Newton matrix J = [dR/dX; Ca da/dX + Cb db/dX] at X (rows as :meth:`stack`)."""
        raise NotImplementedError

    def exact_rows(self, x: np.ndarray, dx: np.ndarray, c: np.ndarray, Ca: np.ndarray, Cb: np.ndarray) -> np.ndarray:
        """The step dx with the rows of the linearization that are trivial to satisfy made exact (an iterative
        solver leaves an algebraic residual in every row; e.g. Newton-min's rows 1 - S = 0).  Default: dx."""
        return dx

    def scale(self) -> float:
        """Divisor of ||Phi|| in the loop's relative residual (the linear systems use ||F||)."""
        return 1.0

    def chain(self, da: np.ndarray, db: np.ndarray):
        """(Ca, Cb) as :meth:`jacobian` takes them: the derivatives with respect to the pair themselves."""
        return da, db

    def data_scale(self) -> float:
        """1: the system's rows are already in the units of its stopping test (:meth:`residual`)."""
        return 1.0

    def rescaled(self, s: float):
        """The system for the data / s; only s = 1 (:meth:`data_scale`)."""
        if s != 1.0:
            raise ValueError(f"a nonlinear complementarity system is not rescaled, got s = {s!r}")
        return self

    def certificate(self, x: np.ndarray, y: np.ndarray, tol: float):
        """The exit certificate of the pair (a, b) = :meth:`pair` (:func:`~.certificate.pair_certificate`):
        a relative to max(||a||_inf, 1) (a dimensionless pair entry, e.g. 1 - S), b relative to ||b||_inf."""
        a, b = self.pair(x, y)
        return pair_certificate(a, b, max(float(np.max(np.abs(a), initial=0.0)), 1.0),
                                float(np.max(np.abs(b), initial=0.0)), tol)
