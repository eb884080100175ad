"""Drivers: run a scene over uniform levels or the adaptive loop, one level step each.

:func:`run_scene` dispatches on ``options.adaptive``; both drivers call
:func:`.level.solve_level` (discretize -> Newton -> errors -> estimate) once per mesh.
"""
from ..options import RunOptions
from .adaptive import run_adaptive
from .level import RunResult
from .uniform import run_uniform

__all__ = ["RunOptions", "RunResult", "run_scene", "run_uniform", "run_adaptive"]


def run_scene(scene, options: RunOptions, progress=None, newton_callback=None) -> RunResult:
    """Solve ``scene`` with ``options``: uniform levels, or solve -> estimate -> mark -> refine."""
    run = run_adaptive if options.adaptive else run_uniform
    return run(scene, options, progress=progress, newton_callback=newton_callback)
