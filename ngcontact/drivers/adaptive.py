"""Adaptive mesh refinement: solve -> estimate -> mark -> refine (seed "Save computational time -- Adaptivity").

The loop builds no forms: each level is one :func:`~.level.solve_level` (discretize, Newton,
errors, the estimate with its element indicators eta_K), :mod:`ngcontact.marking` selects the
elements (Doerfler bulk criterion with parameter theta, or maximum marking), and NGSolve refines
them by newest-vertex bisection with conforming closure (``mesh.SetRefinementFlags`` +
``mesh.Refine()``; new boundary points land on the netgen geometry).

Refinement is done on a *copy* of the netgen mesh, so the previous mesh, its discretization and
its GridFunctions stay valid: the warm start on the new mesh is the previous (u1h, u2h, lam_h)
prolongated by the discretization (exact for nested spaces: bisection of straight triangles
gives V_h^old in V_h^new).

Stopping: eta <= target_eta, the next mesh would have more than max_ndof DOFs, the cumulative
wall time exceeds max_time, or max_levels levels.

Multiplier candidates.  For p >= 2 the estimate computes two guaranteed bounds, one per multiplier candidate,
and keeps the smaller (:mod:`ngcontact.estimators.bound`, "Multiplier").  Along an adaptive run the ratio of
the two changes slowly from level to level; :class:`CandidateSchedule` stops computing the candidate that gave a
bound more than ``ratio`` times the kept one on the last ``after`` levels where both were computed, and computes
both again on every ``recheck``-th level.  The estimate of a level that computes one candidate is that
candidate's guaranteed bound (the same number the pair would have kept unless the order of the two changed
since the last check).  The columns ``multiplier`` (the kept candidate) and ``multiplier_candidates`` (how many
were computed) say which it was.

Every level gives one history.csv row (the columns of uniform runs, plus ``marked``, the multiplier columns
and ``time_mark_s``); ``time_mesh_s`` of level j is the copy + bisection producing T_j,
``time_mark_s`` the marking on T_{j-1}, and ``rate_energy`` / ``rate_eta`` are rates with
respect to ndof^{-1/2} (the "h" of a uniform mesh), so that the optimal value is p.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable, List, Optional, Tuple

import numpy as np
import ngsolve

from ..domains import DIRICHLET, mesh_size
from ..marking import mark
from .level import RunResult, iteration_callback, level_row, record_level, solve_level, status, update_rates

__all__ = ["run_adaptive", "refine", "interior_nodes", "CandidateSchedule"]


@dataclass
class CandidateSchedule:
    """Which multiplier candidates the estimate of the next adaptive level computes (module docstring).

    ``ratio``: a candidate whose bound exceeded the kept one by more than this factor on the last ``after`` levels
    where both were computed (the same one kept on each) is skipped; ``recheck``: both are computed at least on
    every recheck-th level."""

    ratio: float = 1.5
    after: int = 2
    recheck: int = 4
    checks: List[Tuple[str, float]] = field(default_factory=list)  # (kept, other bound / kept bound)
    skipped: int = 0  # levels since the last one that computed both

    def options(self, opts):
        """The estimator options of the next level: ``opts``, or ``opts`` with the kept candidate forced."""
        if opts.multiplier is not None or len(self.checks) < self.after or self.skipped >= self.recheck - 1:
            return opts
        last = self.checks[-self.after:]
        if len({kept for kept, _ in last}) == 1 and all(r > self.ratio for _, r in last):
            return replace(opts, multiplier=last[-1][0])
        return opts

    def record(self, est) -> None:
        """Account for the estimate of a level (both candidates computed or one)."""
        if len(est.eta_candidates) == 2:
            other = max(est.eta_candidates.values())
            self.checks.append((est.multiplier, other / est.eta if est.eta > 0 else 1.0))
            self.skipped = 0
        else:
            self.skipped += 1


def refine(mesh, marked) -> ngsolve.Mesh:
    """A new mesh: ``mesh`` with the elements ``marked`` (indices) bisected, plus conforming closure.

    ``mesh`` itself is not changed (the netgen mesh is copied first).
    """
    new = ngsolve.Mesh(mesh.ngmesh.Copy())
    flags = np.zeros(new.ne, dtype=bool)
    flags[np.asarray(marked, dtype=np.int64)] = True
    new.SetRefinementFlags(flags.tolist())
    new.Refine()
    return new


def interior_nodes(mesh, order: int) -> int:
    """Interior Lagrange nodes of P_order on ``mesh`` (= free H1 dofs; cheap, no assembly)."""
    return ngsolve.H1(mesh, order=order, dirichlet=DIRICHLET).FreeDofs().NumSet()


def run_adaptive(scene, options, progress: Optional[Callable[[str], None]] = None, newton_callback=None,
                 on_level: Optional[Callable[[RunResult], None]] = None):
    """Adaptive loop on ``scene``; returns a :class:`~.level.RunResult`.

    Parameters
    ----------
    scene : Scene
    options : RunOptions
        the level step's options (order, disc, cfun, tol, maxit, solver, start: 'nested' warm-starts
        from the prolongated previous solution, 'cold' takes the scene's initial guess on every
        level) and ``options.adaptive_options`` (marking, theta, max_ndof, target_eta, max_time,
        max_levels).
    progress : callable(str), optional
        one line per level.
    newton_callback : callable(level, IterationRecord), optional
    on_level : callable(RunResult), optional
        called after every finished level (its row complete, its solution in the result).

    Returns
    -------
    RunResult
        rows (one per adaptive level), Newton iterations, the final discretization, solution and
        estimate; ``result.stop_reason`` says why the loop ended.
    """
    say = progress or (lambda msg: None)
    ad = options.adaptive_options
    problem = scene.problem
    result = RunResult(scene=scene, options=options, stop_reason="max_levels")
    t_cum, previous, marked, t_mark = 0.0, None, None, 0.0
    t0 = time.perf_counter()
    mesh = problem.domain.mesh(0)
    t_mesh = time.perf_counter() - t0
    schedule = CandidateSchedule()
    for level in range(ad.max_levels):
        if level > 0:  # the refinement and marking of the previous level count for this one
            t0 = time.perf_counter() - t_mesh - t_mark
        est_opts = schedule.options(options.estimator_options)
        out = solve_level(problem, mesh, options, previous=previous, initial_guess=scene.initial_guess,
                          with_estimate=True, callback=iteration_callback(result, level, newton_callback),
                          estimator_options=est_opts)
        est = out.estimate
        if est_opts.multiplier is not None and est_opts is not options.estimator_options:
            est.multiplier = est_opts.multiplier  # the schedule's single candidate
        schedule.record(est)
        head = {"marked": 0 if marked is None else len(marked)}
        if est.multiplier:  # p >= 2 with two candidates: which was kept, how many were computed
            head.update(multiplier=est.multiplier, multiplier_candidates=len(est.eta_candidates) or 1)
        row = level_row(level, out, options, h=mesh_size(mesh), head=head,
                        times={"time_mesh_s": t_mesh, "time_mark_s": t_mark})
        result.rows.append(row)
        record_level(result, level, out)

        # ---- stop, or mark and refine (counted in the next level's time)
        stop = None
        if ad.target_eta is not None and est.eta <= ad.target_eta:
            stop = f"target_eta: eta {est.eta:.3e} <= {ad.target_eta:g}"
            if not est.bound_proven:  # reached, but by an eta that is not a proven bound (Estimate.bound_proven)
                stop += " (not a proven bound: " + est.why_not_proven + ")"
        elif level == ad.max_levels - 1:
            stop = f"max_levels: {ad.max_levels} levels"
        elif ad.max_time is not None and t_cum + (time.perf_counter() - t0) >= ad.max_time:
            stop = f"max_time: {ad.max_time:g} s"
        t_end = time.perf_counter()
        if stop is None:
            t6 = time.perf_counter()
            marked = mark(est.eta_K, ad.theta, ad.marking)
            t_mark = time.perf_counter() - t6
            t6 = time.perf_counter()
            next_mesh = refine(mesh, marked)
            n_next = (out.disc.nfields + 1) * interior_nodes(next_mesh, options.order)
            t_mesh = time.perf_counter() - t6
            if ad.max_ndof is not None and n_next > ad.max_ndof:
                stop = f"max_ndof: the next mesh would have {n_next} > {ad.max_ndof} DOFs"
                row["time_mark_s"] += t_mark + t_mesh  # spent, so counted
                t_end = time.perf_counter()
            mesh = next_mesh
        total = t_end - t0
        t_cum += total
        row["time_total_s"] = total
        row["time_cum_s"] = t_cum
        update_rates(result.rows, lambda q: q["ndof"] ** -0.5)
        msg = (f"level {level}: ndof {out.disc.ndof:>8d}  marked {row['marked']:>6d}  Newton {out.sol.iterations:3d} its"
               f" ({status(out.sol)})  eta {est.eta:.3e}")
        if "err_energy" in out.errors:
            msg += f"  err {out.errors['err_energy']:.3e}  I_eff {est.i_eff:.3f}"
        msg += "" if est.bound_proven else "  (bound not proven)"
        if on_level is not None:  # on disk before the progress line says it is done
            on_level(result)
        say(msg + f"  t_cum {t_cum:.2f} s")
        previous = (out.disc, out.sol.x, out.sol.y)
        if stop is not None:
            result.stop_reason = stop
            say(f"adaptive loop stopped: {stop}")
            break
    return result
