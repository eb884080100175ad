"""Drivers: run a scene over uniform levels or the adaptive loop, one level step each.

:func:`run_scene` dispatches on ``options.adaptive``; both drivers call
:func:`.level.solve_level` (discretize -> Newton -> errors -> estimate) once per mesh and the
caller's ``on_level(result)`` after each finished level (e.g. :meth:`ngcontact.results.RunWriter.level`,
which writes it to disk).  Threads and the DOF budget: :mod:`.resources`.
"""
from ..options import RunOptions
from .adaptive import run_adaptive
from .level import RunResult
from .resources import memory_budget, threads_used
from .uniform import run_uniform

__all__ = ["RunOptions", "RunResult", "run_scene", "run_uniform", "run_adaptive", "memory_budget"]


def run_scene(scene, options: RunOptions, progress=None, newton_callback=None, on_level=None,
              threads=None) -> RunResult:
    """Solve ``scene`` with ``options``: uniform levels, or solve -> estimate -> mark -> refine.

    ``on_level(result)``: called after every finished level.  ``threads``: NGSolve threads for this
    run (default: the environment variable NGCONTACT_THREADS, else NGSolve's setting).
    """
    run = run_adaptive if options.adaptive else run_uniform
    with threads_used(threads):
        return run(scene, options, progress=progress, newton_callback=newton_callback, on_level=on_level)
