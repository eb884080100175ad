"""Uniform levels: solve a scene on levels 0..L-1 of its domain (nested or cold start).

Builds no forms (the discretization does) and draws nothing (plotting reads the written files).
Before a level is built its DOF count is estimated; with ``options.max_ndof`` the run stops before
a level that would exceed it (``result.complete`` False, ``result.stop_reason`` says why).

P1 on the array levels of a structured rectangle (without ``max_ndof``): the loads of all levels are the finest
level's load vectors and their restrictions, the data at the vertices the finest level's values injected
(``FEMDiscretization.nested_inputs``), so only the finest level builds an NGSolve mesh, assembles loads and
evaluates data.  The levels' arrays are then generated before level 0 (each level's time still in its
``time_mesh_s``), and that work on the finest level counts in the finest level's ``time_assembly_s``.
"""
from __future__ import annotations

import itertools
import time
from typing import Callable, Optional

import numpy as np

from ..discretizations import DISCRETIZATIONS
from ..domains import ArrayMesh
from .level import RunResult, iteration_callback, level_row, record_level, solve_level, status, update_rates
from .resources import next_level_ndof

__all__ = ["run_uniform"]


def run_uniform(scene, options, progress: Optional[Callable[[str], None]] = None,
                newton_callback=None, on_level: Optional[Callable[[RunResult], None]] = None) -> RunResult:
    """Solve ``scene`` on levels 0..options.levels-1 of its domain; one history row per level.

    ``on_level(result)`` is called after every finished level (its row appended, its solution in ``result``).
    """
    say = progress or (lambda msg: None)
    problem = scene.problem
    result = RunResult(scene=scene, options=options)
    previous, t_cum = None, 0.0
    # P1 FEM on structured rectangles: levels as arrays, NGSolve meshes only where something asks (domains.ArrayMesh)
    Disc = DISCRETIZATIONS[options.disc]
    meshes = _timed(problem.domain.meshes(options.levels, arrays=Disc.array_meshes))
    meshes, inputs, t_inputs = _nested_inputs(Disc, problem, options, meshes, say)
    for level in range(options.levels):
        if level > 0 and options.max_ndof is not None:
            ndof = next_level_ndof(result.rows)
            if ndof > options.max_ndof:
                result.complete = False
                result.stop_reason = f"max_ndof: level {level} would have about {ndof:.3g} DOFs > {options.max_ndof}"
                say(f"stopped before level {level}: {result.stop_reason}")
                break
        t0 = time.perf_counter()
        if isinstance(meshes, list):  # generated before level 0, released here
            (mesh, t_mesh, before), meshes[level] = meshes[level], None
        else:
            mesh, t_mesh, before = next(meshes)
        t_before = t_mesh if before else 0.0  # its generation is not in this level's clock
        level_inputs = None
        if inputs is not None:
            level_inputs, inputs[level] = inputs[level], None
        # hand the coarser level over (no reference left here): freed once it is prolongated (solve_level)
        handoff, previous, out = ([previous] if previous is not None else None), None, None
        result.discretization = result.x = result.y = None
        out = solve_level(problem, mesh, options, previous=handoff, initial_guess=scene.initial_guess,
                          with_estimate=options.estimate, callback=iteration_callback(result, level, newton_callback),
                          inputs=level_inputs)
        h = problem.domain.h(level, mesh=mesh)  # measured on this level's mesh (not generated again)
        mesh = level_inputs = None
        if level == options.levels - 1 and t_inputs:
            out.disc.time_assembly += t_inputs  # the finest level's loads and data, before level 0
        total = time.perf_counter() - t0 + t_before + (t_inputs if level == options.levels - 1 else 0.0)
        t_cum += total
        row = level_row(level, out, options, h=h, times={"time_mesh_s": t_mesh})
        row.update(time_total_s=total, time_cum_s=t_cum)
        result.rows.append(row)
        update_rates(result.rows, lambda q: q["h"])
        record_level(result, level, out)
        msg = f"level {level}: ndof {out.disc.ndof:>8d}  Newton {out.sol.iterations:3d} its ({status(out.sol)})  " \
              f"solve {out.time_solve:7.2f} s"
        if "err_energy" in row:
            rate = row["rate_energy"]
            msg += f"  err {row['err_energy']:.3e}" + (f"  rate {rate:.2f}" if np.isfinite(rate) else "")
        if out.estimate is not None:
            msg += f"  eta {out.estimate.eta:.3e}" + (f"  I_eff {row['i_eff']:.3f}" if "i_eff" in row else "")
            msg += "" if out.estimate.bound_proven else "  (bound not proven)"
        if on_level is not None:  # on disk before the progress line says it is done
            on_level(result)
        say(msg)
        previous = (out.disc, out.sol.x, out.sol.y)
    return result


def _timed(meshes):
    """(mesh, seconds to generate it, False) for each level of the iterator ``meshes`` (the last item: generated
    before the level's clock starts)."""
    while True:
        t0 = time.perf_counter()
        mesh = next(meshes, None)
        if mesh is None:
            return
        yield mesh, time.perf_counter() - t0, False


def _nested_inputs(Disc, problem, options, meshes, say):
    """(meshes, inputs, seconds): for a discretization with ``nested_inputs``, array levels and a run without
    ``max_ndof``, every level of :func:`_timed` ``meshes`` generated now (a list), the keyword arguments per level
    (None where nothing is handed on) and the time spent on them; else the levels as they come, None, 0."""
    nested = getattr(Disc, "nested_inputs", None)
    if options.max_ndof is not None or nested is None or options.order != 1:
        return meshes, None, 0.0
    first = next(meshes, None)
    if first is None or not isinstance(first[0], ArrayMesh):  # other domains: level by level
        return itertools.chain([(first[0], first[1], True)] if first is not None else [], meshes), None, 0.0
    levels = [(m, t, True) for m, t, _ in (first, *meshes)]
    say(f"loads and data of levels 0..{len(levels) - 1}: from level {len(levels) - 1}")
    t0 = time.perf_counter()
    inputs = nested(problem, [m for m, _, _ in levels], order=options.order, constraints=options.constraints)
    return levels, inputs, (time.perf_counter() - t0 if inputs is not None else 0.0)
