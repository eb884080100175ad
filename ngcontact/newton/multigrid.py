r"""Linear-solve strategy: PCG with multigrid on the reduced Newton system.

Step k solves the reduced SPD system A z = b of
:meth:`~ngcontact.algebra.system.ComplementaritySystem.linearize` by conjugate gradients,
preconditioned with one V-cycle, warm-started from X^{k-1}: the truncated geometric multigrid
:class:`~ngcontact.algebra.multigrid.Multigrid` on the nested hierarchy of the run's levels
(coarse spaces cut off on the unknowns the step fixes), or, on a mesh without one and with at
least ``amg_min_size`` reduced unknowns, algebraic multigrid
(:class:`~ngcontact.algebra.multigrid.AlgebraicMultigrid`); smaller systems are factorized.
The CG residual is the membrane part of the Newton residual at the new iterate
(:class:`~.linear.KrylovSolve` explains why), so the stopping tests are in the units of the
Newton loop's ||Phi|| / ||F||:

* ``exact``: ||b - A z|| <= ``accuracy`` tol ||F|| (tol: the Newton tolerance): a tenth of what the
  Newton test allows, and the Jacobi-scaled residual ||D^-1 (b - A z)||_inf <= ``accuracy`` tol
  ||x'||_inf (units of u: the soft membrane of very different tensions).  With ``early_exit`` (Newton-min
  rows) CG stops before that as soon as the active set of its iterate differs from the one the step
  solves for and the residual has dropped by ``early_reduction``: that step is not the last one, the
  next solves a different system (in the first ``early_steps`` Newton steps only: a solve that needs
  more is a hard case, e.g. tensions 1e12 apart, where inexact iterates made Newton-FB cycle).  The last step, which keeps the active set, is solved to the full
  target, so the converged solution is that of the direct solves; without ``early_exit`` every iterate
  is (up to the residual above);
* ``inexact``: ||b - A z|| <= max(eta_k ||b - A z^0||, ``accuracy`` tol ||F||) with the forcing term
  eta_k = c_k min(||Phi(X^{k-1})|| / ||F||, ``forcing_max``).  c_k starts at 1, is divided by ``FORCING_CUT``
  whenever a step made ||Phi|| grow and multiplied by ``FORCING_RECOVER`` (up to 1) whenever one decreased it.  A
  step solved to a tenth that changes many row classes can throw the iterate far off (two membranes 1e3 apart
  under a checkerboard load, 24k unknowns: ||Phi|| / ||F|| 0.77 -> 111 -> ... 3.7e4, 200 steps without
  convergence); a run that keeps going astray so turns into the exact mode's solves, while the single jump of a
  cold start costs two tighter solves, not the rest of the level.  When the diagonal of the Newton matrix spans
  more than :data:`~ngcontact.algebra.krylov.UNITS_SPREAD` (tensions far apart), the same relative test also holds
  for the Jacobi-scaled residual ||D^-1 r|| (``pcg(..., jacobi=True)``): the soft membrane in its own units.

Newton-min iterates are relaxed at the free boundary (``relax_sweeps`` > 0): after each of the first
``relax_steps`` steps whose iterate's active set differs from the one the step solved for by at least a tenth
of a layer of the free boundary (``RELAX_MIN_LAYERS``), ``relax_sweeps`` projected Jacobi sweeps on the rows
within as many layers of the free boundary move it where the next steps would, one layer per step
(:mod:`~ngcontact.algebra.relax`); the relaxed point replaces the iterate when it changes a row's class, as a
*provisional* point: the loop stops at it by the residual test ||Phi|| / ||F|| <= tol at the point itself and its
certificate only, never by the other tests of a rule (balanced, adaptive), and only when the point also passes the
test in units of u, ||diag(K)^-1 (K x - B^T D y - F)||_inf <= tol ||x||_inf (with tensions far apart the 2-norm
test sees the stiff membrane only).  The
converged solution then agrees with the direct solves' to the Newton tolerance rather than to the CG target (nested
test 1 at 2M unknowns: max nodal error 1.5200149e-7 against 1.5200150e-7, energy error equal to 11 digits), and the
finest level's Newton steps fall from 8 to 3 (5 when the loop did not stop at relaxed points: on the degenerate band
of test 1, where u1 - u2 and lambda both vanish, the step after a relaxed point that passes the test changes the
class of a few rows there and leaves a complementarity defect, which one more step removes).

The hierarchy is reused while the row classes of the steps do not change (the last Newton-min
step, which confirms the active set, then costs a few CG iterations); when at most
``update_fraction`` of the reduced unknowns changed class, only its finest level is rebuilt
(:meth:`~ngcontact.algebra.multigrid.Multigrid.updated`; the algebraic one is rebuilt), otherwise
the whole hierarchy (:class:`~ngcontact.algebra.multigrid.HierarchyCache`).  When PCG does not reach its
target in ``maxiter`` iterations the step is factorized (recorded in ``linear_path``).

Two membranes with K = blockdiag(S, alpha S) (``split``, exact mode): each coupled step is solved through the
s/w splitting of :mod:`.split` -- one Poisson solve for s per Newton run, an obstacle-type w-system of half the
size per step, no triple product Z^T K Z -- and accepted on the coupled step's own tests; a step that does not
pass them is solved on the coupled system as above (the record's ``split`` says which).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Tuple

import numpy as np

from ..algebra.krylov import cg, units_scale
from ..algebra.linalg import PCGResult, pcg
from ..algebra.multigrid import SMOOTHERS, AlgebraicMultigrid, HierarchyCache
from ..algebra.relax import FreeBoundaryRelaxation
from ..algebra.system import LINEAR_PATHS
from .base import IterationRecord, option_error
from .linear import Trial
from .split import MembraneSplit

__all__ = ["MultigridSolve", "MultigridIterationRecord", "MULTIGRID_MODES"]

MULTIGRID_MODES = ("exact", "inexact")
#: damping of the free-boundary relaxation's Jacobi sweeps (2/3: the smoothing factor of damped Jacobi for P1)
RELAX_OMEGA = 2.0 / 3.0
#: relax only a step that changed at least this many rows per row of the free boundary (a tenth of a layer: the
#: first step of the nested ex9 obstacle levels changes 8, 4, 4, 8, 24, 48 of 36, 68, 260, 508, 1012, 2028 free
#: boundary rows, the first finest-level step of test 1 at 2M unknowns 12,370 of 3,912, about three layers)
RELAX_MIN_LAYERS = 0.1


@dataclass
class MultigridIterationRecord(IterationRecord):
    """One Newton iteration with multigrid-preconditioned CG (``pcg_its``: CG iterations of the step)."""

    cg_cum: int = 0               # CG iterations cumulated over the steps of this solve
    mg_levels: int = 0            # levels of the V-cycle (0: factorized)
    amg: int = 0                  # 1: algebraic multigrid (no nested hierarchy)
    cg_early: int = 0             # 1: CG stopped early, its iterate's active set differs (the next step re-solves)
    mg_rebuilt: int = 0           # 0 hierarchy reused, 1 (re)built, 2 finest level updated (few rows changed)
    time_mg_setup: float = 0.0    # Galerkin products and coarsest factorization of this step
    relaxed: int = 0              # rows whose class the free-boundary relaxation changed (0: not relaxed)
    time_relax: float = 0.0       # free-boundary relaxation of this step's iterate
    split: int = 0                # 1: solved through the s/w splitting of two membranes (.split; linear_size:
                                  # the w-system's)


@dataclass(frozen=True)
class MultigridSolve:
    """PCG + truncated multigrid on the reduced Newton system (module docstring).  Fields validated once.

    ``matrices``: the unconstrained matrices of the levels below (Galerkin-consistent with the prolongations; the
    coarse matrices of the truncated hierarchy are read off them away from the contact set), or ();
    ``prolongations``: the nested P1 prolongations of the unconstrained unknowns, coarse to fine
    (a tuple; empty: algebraic multigrid from ``amg_min_size`` reduced unknowns, below that the step
    is factorized); ``tol``: the Newton tolerance the ``accuracy`` factor refers to.
    """

    mode: str = "exact"
    tol: float = 1e-10
    accuracy: float = 0.1
    forcing_max: float = 0.1
    smoother: str = "gauss-seidel"
    degree: int = 1
    ratio: float = 8.0
    amg_min_size: int = 20000
    maxiter: int = 100
    update_fraction: float = 0.05
    split: bool = True            # two membranes with K = blockdiag(S, alpha S): steps through s/w (.split)
    early_exit: bool = True       # exact mode, Newton-min rows: stop CG when the iterate's active set changes
    early_reduction: float = 1e-3
    early_every: int = 2
    early_steps: int = 4          # ... in the first steps only (later ones: hard cases, solved exactly)
    relax_sweeps: int = 20        # free-boundary relaxation of the iterates of Newton-min steps (0: none)
    relax_steps: int = 4          # ... of the first steps that change the active set
    prolongations: Tuple = ()
    matrices: Tuple = ()          # K_0..K_{L-1} of the levels below, Galerkin-consistent (drivers.level)
    record_type = MultigridIterationRecord

    def __post_init__(self):
        if self.mode not in MULTIGRID_MODES:
            raise option_error("multigrid mode", self.mode, f"one of {MULTIGRID_MODES}")
        for name in ("tol", "accuracy", "forcing_max", "update_fraction", "early_reduction"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0 < v < 1):
                raise option_error(name, v, "a number in (0, 1)")
        if self.smoother not in SMOOTHERS:
            raise option_error("smoother", self.smoother, f"one of {SMOOTHERS}")
        for name in ("early_exit", "split"):
            if not isinstance(getattr(self, name), bool):
                raise option_error(name, getattr(self, name), "True or False")
        for name, lo in (("degree", 1), ("maxiter", 1), ("amg_min_size", 1), ("early_every", 1), ("early_steps", 1),
                         ("relax_sweeps", 0), ("relax_steps", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int) and v >= lo):
                raise option_error(name, v, "a positive integer" if lo else "an integer >= 0")
        v = self.ratio
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and v > 1):
            raise option_error("ratio", v, "a number > 1")

    def start(self, system, estimates: list):
        return _MultigridSession(self, system)


#: inexact mode: the forcing term is divided by FORCING_CUT after each step that made ||Phi|| grow and multiplied
#: by FORCING_RECOVER (up to the plain term) after each one that decreased it (module doc)
FORCING_CUT = 100.0
FORCING_RECOVER = 10.0


class _MultigridSession:
    def __init__(self, opt: MultigridSolve, system):
        self.opt, self.system = opt, system
        matrices = tuple(opt.matrices) + (system.K,) if opt.matrices else ()
        self.hierarchy = HierarchyCache(opt.prolongations, opt, system.solver, matrices=matrices)
        self.cg_cum = 0
        self._relaxation = None
        self._res_before, self._forcing_scale = None, 1.0  # inexact mode: c_k of the forcing term (module doc)
        self.split = MembraneSplit.build(system, opt) if opt.split else None

    can_refresh = False

    def step(self, k, x, y, c, Ca, Cb, res_prev) -> Trial:
        opt, system = self.opt, self.system
        t0 = time.perf_counter()
        lin = system.linearize(x, y, c, Ca, Cb)
        floor = opt.accuracy * opt.tol * system.scale()  # a tenth of the Newton test's ||Phi||
        fields = dict(linear_size=lin.size, mg_levels=0, mg_rebuilt=0, time_mg_setup=0.0, pcg_its=0)
        early = opt.early_exit and k <= opt.early_steps and not lin.mixed.any()
        spent = 0  # CG iterations of a split attempt that handed the step back
        if self.split is not None:
            out = self.split.step(k, x, lin, floor, self._early_exit if early else None)
            self.cg_cum += self.split.its
            if out is not None:
                xn, yn, split_fields, r = out
                fields.update(split_fields, linear_path=LINEAR_PATHS.index("multigrid"))
                return self._trial(k, xn, yn, lin, fields, t0, residual=r)
            spent = self.split.its
        z = None
        if opt.prolongations or lin.size >= opt.amg_min_size:
            mg, how = self.hierarchy.get(lin)
            fields.update(mg_levels=len(mg.levels), mg_rebuilt=how, time_mg_setup=mg.time_setup if how else 0.0,
                          amg=int(isinstance(mg, AlgebraicMultigrid)))
            z0 = lin.restrict(x)
            target = floor
            if opt.mode == "inexact":
                if self._res_before is not None and res_prev > self._res_before:  # the last step made Phi grow
                    self._forcing_scale /= FORCING_CUT
                elif self._res_before is not None:  # it decreased Phi: back towards the plain forcing term
                    self._forcing_scale = min(1.0, self._forcing_scale * FORCING_RECOVER)
                self._res_before = res_prev
                r0 = float(np.linalg.norm(lin.b - lin.A @ z0))
                target = max(floor, self._forcing_scale * min(res_prev, opt.forcing_max) * r0)
            bnorm = float(np.linalg.norm(lin.b)) or 1.0
            stopped_early = False
            if opt.mode == "exact" and early:
                res, stopped_early = self._early_exit(lin.A, lin.b, z0, mg, target,
                                                      lambda z: np.less_equal(*system.pair(*lin.recover(z))), lin.eq)
            else:
                # inexact: for rows of very different size the forcing test also in the units of u (krylov.UNITS_SPREAD)
                res = pcg(lin.A, lin.b, mg, z0, rtol=target / bnorm, maxiter=opt.maxiter,
                          jacobi=opt.mode == "inexact" and units_scale(lin.A) is not None)
            its = res.iterations
            fields["cg_early"] = int(stopped_early)
            if opt.mode == "exact" and not stopped_early:
                res, its = self._units_check(lin, mg, res, its, target, bnorm)
            fields["pcg_its"] = its + spent
            self.cg_cum += its
            if res.converged:
                z = res.x
                fields["linear_path"] = LINEAR_PATHS.index("multigrid")
            else:
                fields["linear_path"] = LINEAR_PATHS.index("pcg-failed")
        if z is None:
            z = system.direct_solve(lin.A, lin.b)
        xn, yn = lin.recover(z)
        return self._trial(k, xn, yn, lin, fields, t0)

    def _trial(self, k, xn, yn, lin, fields, t0, residual=None) -> Trial:
        """The step's iterate, relaxed at the free boundary where that applies (``residual``: that of (xn, yn),
        handed on unless the point is relaxed)."""
        opt = self.opt
        fields["cg_cum"] = self.cg_cum
        t_lin = time.perf_counter() - t0
        relaxed = False
        if opt.relax_sweeps and k <= opt.relax_steps and not lin.mixed.any():
            xn, yn, relaxed = self._relax(xn, yn, lin, fields)
        if not relaxed:
            return Trial(xn, yn, t_lin, fields, residual=residual)
        # the relaxed point may end the loop only if it also passes the test in units of u (the exact mode's second
        # test, :meth:`_units_check`): ||Phi|| / ||F|| is dominated by the stiffest rows, and with tensions 1e4 and
        # more apart a relaxed point passed it with the soft membrane off by 1e-4 of its size
        system = self.system
        r = system.residual(xn, yn)
        u_scale = float(np.max(np.abs(xn), initial=0.0))
        units = float(np.max(np.abs(r / system.diagonal()), initial=0.0))
        return Trial(xn, yn, t_lin, fields, provisional=True, residual=r, may_stop=units <= opt.tol * u_scale)

    def _relax(self, x, y, lin, fields):
        """The free-boundary relaxation (:mod:`~ngcontact.algebra.relax`) of a Newton-min iterate whose active set
        differs from the one its step solved for (a step that keeps the active set is left as it is): (x, y,
        whether the point returned is the relaxed one)."""
        system = self.system
        moved = int(np.count_nonzero(np.less_equal(*system.pair(x, y)) != lin.eq))
        if not moved:
            return x, y, False
        t0 = time.perf_counter()
        if self._relaxation is None:
            self._relaxation = FreeBoundaryRelaxation(system)
        sweeps = self.opt.relax_sweeps
        xr, yr, changed = self._relaxation.relax(x, y, sweeps=sweeps, omega=RELAX_OMEGA, layers=sweeps, moved=moved,
                                                 min_layers=RELAX_MIN_LAYERS)
        fields.update(relaxed=changed, time_relax=time.perf_counter() - t0)
        # the relaxed point only where it moves the free boundary: otherwise the next step is the same, and the
        # Newton iterate (an exact solve of its linearization when CG ran to the target) stays the iterate
        return (xr, yr, True) if changed else (x, y, False)

    def _early_exit(self, A, b, z0, mg, target: float, active, eq):
        """CG on A z = b from z0 that stops as soon as its iterate's active set differs from ``eq``, the one this
        step solves for, once the residual has dropped by ``early_reduction``: the next Newton-min step solves a
        different system anyway (a Newton step that keeps the active set is solved to the full target).
        ``active(z)``: the active set {weight g <= y} of the Newton iterate of z.  Returns a
        :class:`~ngcontact.algebra.linalg.PCGResult` and whether CG stopped early (else the usual tests apply to
        its iterate)."""
        opt = self.opt
        bnorm = float(np.linalg.norm(b)) or 1.0
        stop = {}

        def monitor(st):
            # no check before the residual dropped, nor at an iterate that meets the target (CG stops there anyway)
            if st.i == 0:
                stop["r0"] = st.res * bnorm  # the initial true residual ||b - A z0||
                return False
            if st.res * bnorm > opt.early_reduction * stop["r0"] or st.res * bnorm <= target:
                return False
            if np.array_equal(active(st.x), eq):
                return False
            stop["i"] = st.i
            return True

        kr = cg(A, b, z0, _Callable(mg), rtol=target / bnorm, maxiter=opt.maxiter, nu=opt.early_every,
                monitor=monitor)
        if "i" not in stop:
            return PCGResult(kr.x, kr.iterations, kr.converged, kr.res), False
        return PCGResult(kr.x, kr.iterations, True, kr.res), True

    def _units_check(self, lin, mg, res, its: int, target: float, bnorm: float):
        """The exact mode's second test, in units of u: the Jacobi-scaled residual ||D^-1 (b - A z)||_inf <=
        ``accuracy`` tol ||x'||_inf.  The 2-norm test is dominated by the stiffest rows; with tensions that
        differ by many orders (mu1 / mu2 = 1e12) the soft membrane's unknowns may still be off by more than
        the exit certificate allows.  CG continues with 1e-3 times the target, at most three times."""
        opt = self.opt
        dA = lin.diagonal()
        for _ in range(3):
            if not res.converged:
                break
            u_scale = max(float(np.max(np.abs(res.x), initial=0.0)), float(np.max(np.abs(lin.x_aff), initial=0.0)))
            if float(np.max(np.abs((lin.b - lin.A @ res.x) / dA), initial=0.0)) <= opt.accuracy * opt.tol * u_scale:
                break
            target *= 1e-3
            res = pcg(lin.A, lin.b, mg, res.x, rtol=target / bnorm, maxiter=opt.maxiter, jacobi=True)
            its += res.iterations
        return res, its

    def after_step(self, k, x, y, step) -> dict:
        return {}


class _Callable:
    """``solve(r)`` interface of :func:`~ngcontact.algebra.krylov.cg` for a callable preconditioner."""

    def __init__(self, M):
        self.solve = M
