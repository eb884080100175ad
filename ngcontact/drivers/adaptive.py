"""Adaptive mesh refinement: solve -> estimate -> mark -> refine (seed "Save computational time -- Adaptivity").

The loop builds no forms: a discretization turns (problem, mesh) into the
algebraic complementarity system, Newton solves it, :func:`ngcontact.estimators.estimate`
returns the element indicators eta_K, :mod:`ngcontact.drivers.marking` selects the
elements (Doerfler bulk criterion with parameter theta, or maximum marking),
and NGSolve refines them by newest-vertex bisection with conforming closure
(``mesh.SetRefinementFlags`` + ``mesh.Refine()``; new boundary points land on
the netgen geometry).

Refinement is done on a *copy* of the netgen mesh, so the previous mesh, its
discretization and its GridFunctions stay valid: the warm start of Newton on
the new mesh is the previous (u1h, u2h, lam_h) prolongated by
:meth:`FEMDiscretization.prolongate` -- u_ah interpolated at the new Lagrange
nodes (exact for nested spaces: bisection of straight triangles gives
V_h^old in V_h^new), lam_h interpolated as a function and re-mapped to its
algebraic representation (p = 1: nodal values of the lumped multiplier;
p >= 2: the dual-basis coefficients X3_l = (lam_h, psi_l)).

Stopping: eta <= target_eta, the next mesh would have more than max_ndof
DOFs, the cumulative wall time exceeds max_time, or max_levels levels.

Every level gives one history.csv row (same columns as uniform runs, plus
``marked``, ``time_mark_s``, ``time_prolong_s``); ``time_mesh_s`` of level j is the
copy + bisection producing T_j, ``time_mark_s`` the marking on T_{j-1}, and
``rate_energy`` / ``rate_eta`` are rates with respect to ndof^{-1/2} (the
"h" of a uniform mesh), so that the optimal value is p.
"""
from __future__ import annotations

import time
from dataclasses import asdict
from typing import Callable, Optional

import numpy as np
import ngsolve

from ..discretizations import DISCRETIZATIONS
from ..domains import mesh_size
from .marking import mark
from ..newton.loop import semismooth_newton
from ..rates import rates
from ..domains import DIRICHLET

__all__ = ["run_adaptive", "refine", "interior_nodes"]


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
    return int(sum(ngsolve.H1(mesh, order=order, dirichlet=DIRICHLET).FreeDofs()))


def _solve(disc, x0, y0, options, cb, warm: bool = False):
    """Newton on one level; the same drivers as :func:`ngcontact.drivers.run_scene`
    (``warm``: x0 is the prolongated previous level, the reference of the balanced stop)."""
    from .uniform import balance_reference, newton_options

    mode = getattr(options, "newton", "exact")
    if mode == "exact":
        ref = balance_reference(options, x0) if warm else None
        return semismooth_newton(disc.system, x0, y0, newton_options(options), callback=cb, reference=ref)
    from ..newton.inexact import InexactOptions, inexact_semismooth_newton

    iopts = InexactOptions(mode=mode.replace("exact-gmres", "exact"), cfun=options.cfun, tol=options.tol,
                           maxit=options.maxit, gamma_alg=options.gamma_alg, gamma_lin=options.gamma_lin,
                           nu=options.nu, ilu_drop_tol=options.ilu_drop_tol, ilu_fill=options.ilu_fill,
                           flux_order=options.flux_order)
    return inexact_semismooth_newton(disc.system, x0, y0, iopts, callback=cb, disc=disc)


def run_adaptive(scene, options, progress: Optional[Callable[[str], None]] = None, newton_callback=None):
    """Adaptive loop on ``scene`` (``options.adaptive``); returns a :class:`~ngcontact.drivers.RunResult`.

    Parameters
    ----------
    scene : Scene
    options : RunOptions
        uses order, disc, cfun, tol, maxit, solver, start ('nested': warm
        start from the prolongated previous solution; 'cold': the scene's
        initial guess on every level), marking, theta, max_ndof, target_eta,
        max_time, max_levels.
    progress : callable(str), optional
        one line per level.
    newton_callback : callable(level, IterationRecord), optional

    Returns
    -------
    RunResult
        rows (one per adaptive level), Newton iterations, the final
        discretization, solution and estimate; ``result.stop_reason`` says
        why the loop ended.
    """
    from ..estimators import EstimatorOptions, estimate
    from .uniform import RunResult, balance_columns

    say = progress or (lambda msg: None)
    problem = scene.problem
    Disc = DISCRETIZATIONS[options.disc]
    result = RunResult(scene=scene, options=options)
    result.stop_reason = "max_levels"
    t_cum, prev, marked, t_mark = 0.0, None, None, 0.0
    mesh = None
    for level in range(options.max_levels):
        t0 = time.perf_counter()
        if level == 0:
            mesh = problem.domain.mesh(0)
            t_mesh = time.perf_counter() - t0
        else:
            mesh, t_mesh = next_mesh, t_refine  # refined (and counted) at the end of the previous level
            t0 -= t_mesh + t_mark
        kw = {"condense": options.condense} if options.disc == "hho" else {}
        disc = Disc(problem, mesh, order=options.order, solver=options.solver, **kw)
        t1 = time.perf_counter()
        if prev is not None and options.start == "nested":
            x0, y0 = disc.prolongate(prev, result.x, result.y)
        else:
            x0, y0 = disc.initial_guess(scene.initial_guess)
        t_prolong = time.perf_counter() - t1

        def cb(rec, level=level):
            result.iterations.append({"level": level, **asdict(rec)})
            if newton_callback:
                newton_callback(level, rec)

        t2 = time.perf_counter()
        sol = _solve(disc, x0, y0, options, cb, warm=prev is not None and options.start == "nested")
        t3 = time.perf_counter()
        errs = disc.errors(sol.x, sol.y)
        comp = disc.complementarity(sol.x, sol.y)
        t4 = time.perf_counter()
        est = estimate(disc, sol.x, sol.y, EstimatorOptions(flux_order=options.flux_order),
                       err_energy=errs.get("err_energy"), errors=False)
        est_cols = est.summary()
        t5 = time.perf_counter()
        row = {
            "level": level,
            "nelem": mesh.ne,
            "h": mesh_size(mesh),
            "ndof": disc.ndof,
            "nodes": disc.n_interior,
            "marked": 0 if marked is None else len(marked),
            **errs,
            "newton_its": sol.iterations,
            "newton_converged": int(sol.converged),
            "res_final": sol.history[-1].res,
            **(balance_columns(sol) if options.newton_stop == "balanced" else {}),
            "active_nodes": sol.history[-1].n_active,
            "linear_size": max((getattr(r, "linear_size", 0) for r in sol.history), default=0),
            **comp,
            "time_mesh_s": t_mesh,
            "time_mark_s": t_mark,
            "time_assembly_s": disc.time_assembly,
            "time_prolong_s": t_prolong,
            "time_solve_s": t3 - t2,
            "time_linear_s": sol.time_linear,
            "time_post_s": t4 - t3,
            **est_cols,
            "time_estimate_s": t5 - t4,
        }
        result.rows.append(row)
        result.discretization, result.x, result.y, result.estimate, prev = disc, sol.x, sol.y, est, disc
        if not sol.converged:
            result.converged = False
            result.failures.append(f"level {level}: Newton did not converge: {sol.reason}")

        # ---- stop, or mark and refine (counted in the next level's time)
        stop = None
        if options.target_eta is not None and est.eta <= options.target_eta:
            stop = f"target_eta: eta {est.eta:.3e} <= {options.target_eta:g}"
        elif level == options.max_levels - 1:
            stop = f"max_levels: {options.max_levels} levels"
        elif options.max_time is not None and t_cum + (time.perf_counter() - t0) >= options.max_time:
            stop = f"max_time: {options.max_time:g} s"
        t_end = time.perf_counter()
        if stop is None:
            t6 = time.perf_counter()
            marked = mark(est.eta_K, options.theta, options.marking)
            t_mark = time.perf_counter() - t6
            t6 = time.perf_counter()
            next_mesh = refine(mesh, marked)
            n_next = (disc.nfields + 1) * interior_nodes(next_mesh, options.order)
            t_refine = time.perf_counter() - t6
            if options.max_ndof is not None and n_next > options.max_ndof:
                stop = f"max_ndof: the next mesh would have {n_next} > {options.max_ndof} DOFs"
                row["time_mark_s"] += t_mark + t_refine  # spent, so counted
                t_end = time.perf_counter()
        total = t_end - t0
        t_cum += total
        row["time_total_s"] = total
        row["time_cum_s"] = t_cum
        n_h = [q["ndof"] ** -0.5 for q in result.rows]
        for col, rate_col in (("err_energy", "rate_energy"), ("eta", "rate_eta")):
            if col in row:
                for q, r in zip(result.rows, rates(n_h, [q[col] for q in result.rows])):
                    q[rate_col] = r
        msg = (f"level {level}: ndof {disc.ndof:>8d}  marked {row['marked']:>6d}  Newton {sol.iterations:3d} its"
               f" ({sol.reason if sol.converged else 'NOT converged: ' + sol.reason})  eta {est.eta:.3e}")
        if "err_energy" in errs:
            msg += f"  err {errs['err_energy']:.3e}  I_eff {est.i_eff:.3f}"
        say(msg + f"  t_cum {t_cum:.2f} s")
        if stop is not None:
            result.stop_reason = stop
            say(f"adaptive loop stopped: {stop}")
            break
    return result
