"""Drivers: solve a scene over uniform levels or an adaptive loop."""
from .uniform import ESTIMATED, RunOptions, RunResult, run_scene

__all__ = ["RunOptions", "RunResult", "run_scene", "ESTIMATED"]
