"""Backward Euler in time, conforming P_p in space: one complementarity system per time step ([CMAME20]).

Step n (t_n = t_{n-1} + dt) solves

    E X^n = F^n,  X1 - X2 >= 0,  X3 >= 0,  (X1 - X2) . X3 = 0,
    E = K + blockdiag(M, M) / dt,     F^n = F(t_n) + blockdiag(M, M) X^{n-1} / dt,

(the Newton loop solves it for the increment X^n - X^{n-1}: :meth:`BackwardEuler.increment_system`)

K, F, D of the stationary :class:`~ngcontact.discretizations.fem.FEMDiscretization` (lumped
multiplier product for p = 1, dual basis for p >= 2) and M the Lagrange-basis mass matrix on the
interior nodes.  M is the consistent mass matrix for every p: with it the hat moments of
(u_h^n - u_h^{n-1}) / dt are those of the discrete equation, which the equilibrated fluxes of the
estimators need (with a lumped time derivative the patch problems of :mod:`ngcontact.estimators`
would be incompatible by O(h^2) d_t u).  The Dirichlet data are constant in t (checked), so the
boundary values contribute to F only through K.

The constant parts (K, M, the Dirichlet part of F, and F itself when the loads do not depend on
t) are assembled once; E is built once per distinct dt and shared (the same object) by all step
systems with that dt, so :class:`~ngcontact.algebra.reuse.FactorReuse` reuses factorizations
across time steps (:class:`SharedDirectSolve`).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..algebra.reuse import FactorReuse
from ..algebra.system import ComplementaritySystem
from ..discretizations.fem import FEMDiscretization, _block_diag_csr
from ..newton.base import IterationRecord
from ..newton.linear import _DirectSession
from ..problems.parabolic import DIRICHLET_CHECK_TIMES, ParabolicProblem, check_initial_on_points

__all__ = ["BackwardEuler", "SharedDirectSolve"]


class SharedDirectSolve:
    """The direct linear-solve strategy of the Newton loop with ONE :class:`FactorReuse` for the whole
    time integration: a step system with the same E (dt unchanged) starts from the last factorization.

    The driver counts the fresh factorizations: records with ``linear_path`` 0 or 2."""

    record_type = IterationRecord

    def __init__(self):
        self.reuse = None

    def start(self, system, estimates):
        if self.reuse is None:
            self.reuse = FactorReuse(system)
        return _DirectSession(system, self.reuse)


class BackwardEuler:
    """Step systems of the backward Euler / P_p discretization of a :class:`ParabolicProblem`.

    Parameters
    ----------
    problem : ParabolicProblem
    mesh : ngsolve.Mesh
    order : int, 1..3 (4 works too)
    solver : str
        sparse SPD solver ('sparsecholesky' or 'scipy').

    Attributes
    ----------
    disc : FEMDiscretization
        the stationary discretization at t = 0 (spaces, nodes, K, D, lifting, errors, fields).
    x0 : ndarray
        interior nodal values of the initial data (u1^0, u2^0).
    """

    def __init__(self, problem: ParabolicProblem, mesh, order: int = 1, solver: str = "sparsecholesky"):
        if not isinstance(problem, ParabolicProblem):
            raise TypeError(f"problem must be a ParabolicProblem, got {type(problem).__name__}")
        self.problem = problem
        problem.set_time(0.0)
        self.disc = disc = FEMDiscretization(problem.stationary, mesh, order=order, solver=solver)
        nodes, ni = disc.nodes, disc.n_interior
        u0 = [nodes.evaluate(cf) for cf in problem.u0]
        bnd = disc.boundary
        g0 = [nodes.evaluate(g)[bnd] for g in problem.stationary.dirichlet]
        later = []
        if problem.time is not None:
            for frac in DIRICHLET_CHECK_TIMES:
                problem.set_time(frac * problem.t_final)
                later.append((frac * problem.t_final, [nodes.evaluate(g)[bnd] for g in problem.stationary.dirichlet]))
        problem.set_time(0.0)
        check_initial_on_points(problem, u0, g0, later, nodes.coords)
        self.x0 = np.concatenate([v[disc.interior] for v in u0])
        self.y0 = np.zeros(ni)
        M = disc.mass_nodal()
        self.M = M[disc.interior][:, disc.interior].tocsr()
        self.Mblk = _block_diag_csr([self.M] * disc.nfields)
        self.K = disc.system.K
        self.time_dependent = problem.time is not None
        # F = loads + Dirichlet part; the Dirichlet part is constant in t
        self._F_bc = disc.system.F - self._loads()
        self._F_const = None if self.time_dependent else disc.system.F
        self._E = {}

    def _loads(self) -> np.ndarray:
        """(f_a(t), phi_l) at the interior nodes for the current value of the time parameter."""
        disc = self.disc
        return np.concatenate([(disc.nodes.T.T @ disc.load_vector(f))[disc.interior] for f in disc.problem.loads])

    def load(self, t: float) -> np.ndarray:
        """F(t) of the stationary system (loads + Dirichlet part)."""
        if self._F_const is not None:
            return self._F_const
        self.problem.set_time(t)
        return self._loads() + self._F_bc

    def matrix(self, dt: float) -> sp.csr_matrix:
        """E = K + blockdiag(M)/dt, built once per dt (the same object for every step with this dt)."""
        key = float(dt)
        if key not in self._E:
            self._E[key] = (self.K + self.Mblk / key).tocsr()
        return self._E[key]

    def system(self, x_prev: np.ndarray, t: float, dt: float) -> ComplementaritySystem:
        """The complementarity system of the step t - dt -> t from X^{n-1} = ``x_prev``."""
        if not dt > 0:
            raise ValueError(f"option dt must be > 0, got {dt!r}")
        s = self.disc.system
        F = self.load(t) + self.Mblk @ x_prev / dt
        return ComplementaritySystem(self.matrix(dt), F, s.up, s.lo, s.b, s.D, solver=s.solver)

    def increment_system(self, system: ComplementaritySystem, x_prev: np.ndarray, t: float) -> ComplementaritySystem:
        """The step ``system`` (from :meth:`system`) in the increment d = X - X^{n-1}, which the Newton loop solves:

            E d = F(t_n) - K X^{n-1},   g(d) = B d - (b - B X^{n-1})   (the gaps of X^{n-1} + d),

        the same residuals and gaps, without the cancellation of blockdiag(M) X^{n-1} / dt in E X - F^n: the
        right-hand side is what drives the step (zero at a stationary state), so the Newton loop's relative
        residual test is in its units whatever dt and whatever constant u carries.  F^n itself would be a divisor
        of size 1/dt (the load-driven part of the residual is dt ||F^n||), and the cancellation leaves round-off
        of 1e-16 ||M X^{n-1} / dt|| in the residual of X."""
        F = self.load(t) - self.K @ x_prev
        b = -system.gap(x_prev)
        return ComplementaritySystem(system.K, F, system.up, system.lo, b, system.D, solver=system.solver)
