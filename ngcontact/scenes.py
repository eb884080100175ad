"""Scenes: small importable Python files of problem data (``cases/*.py``, installed as ``ngcontact.cases``).

A scene file defines

* ``problem`` (required): a :class:`~ngcontact.problems.TwoMembraneProblem` or
  :class:`~ngcontact.problems.ObstacleProblem`, or the parameters of a two-phase flow
  (:class:`~ngcontact.twophase.TwoPhaseParams`: ``ngcontact run`` hands it to its own time loop);
* ``DEFAULTS`` (optional): run options used when the command line does not
  give them, e.g. ``dict(order=2, levels=4)``;
* ``INITIAL_GUESS`` (optional): a tuple of CoefficientFunctions (one per
  field) for the cold start of Newton (default: zero inside);
* ``TEST_OPTIONS`` (optional): a short run for the test suite;
* its docstring: the description shown by ``ngcontact list``.
"""
from __future__ import annotations

import importlib.util
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from .problems import ObstacleProblem, ParabolicProblem, TwoMembraneProblem
from .twophase.params import TwoPhaseParams

__all__ = ["Scene", "SceneError", "load_scene", "cases_dir", "list_scenes"]


class SceneError(ValueError):
    """A scene cannot be found or loaded; the message says which and why."""


@dataclass
class Scene:
    name: str
    path: Path
    problem: object
    description: str = ""
    defaults: dict = field(default_factory=dict)
    initial_guess: Optional[tuple] = None
    test_options: dict = field(default_factory=dict)
    module: object = None  # the scene's module (time-dependent scenes: REGIONS, SPACE_AXIS)


def cases_dir() -> Path:
    """Directory of the bundled scenes.

    ``$NGCONTACT_CASES`` if set; else ``cases/`` of the source tree when the package runs from its
    own checkout (``pyproject.toml`` and ``cases/`` next to ``ngcontact/``); else the installed
    package data ``ngcontact.cases`` (the same files, shipped in the wheel).
    """
    env = os.environ.get("NGCONTACT_CASES")
    if env:
        return Path(env)
    root = Path(__file__).resolve().parent.parent
    if (root / "pyproject.toml").is_file() and (root / "cases").is_dir():
        return root / "cases"
    from importlib.resources import files

    try:
        return Path(str(files("ngcontact.cases")))
    except ModuleNotFoundError:
        raise SceneError("the bundled scenes are missing: neither a source checkout's cases/ nor the installed "
                         "package ngcontact.cases was found (set NGCONTACT_CASES to a directory of scenes)") from None


def list_scenes() -> list:
    """Names of the bundled scenes (the ``*.py`` files of :func:`cases_dir`, without ``_*.py``)."""
    return sorted(p.stem for p in cases_dir().glob("*.py") if not p.stem.startswith("_"))


def load_scene(spec: str) -> Scene:
    """Load a scene by name (``cases/NAME.py``) or by path to a Python file."""
    path = Path(spec)
    if path.suffix == ".py" or os.sep in spec:
        if path.is_dir():
            raise SceneError(f"scene {spec!r} is a directory, not a scene .py file")
        if not path.is_file():
            raise SceneError(f"scene file not found: {spec}")
        if path.suffix != ".py":
            raise SceneError(f"scene file {spec!r} must be a Python file (.py), got suffix {path.suffix!r}")
    else:
        path = cases_dir() / f"{spec}.py"
        if not path.is_file():
            known = ", ".join(list_scenes()) or "none"
            raise SceneError(f"unknown scene {spec!r} (known: {known}; or give a path to a .py file)")
    modname = f"ngcontact_scene_{path.stem}"
    try:
        spec_ = importlib.util.spec_from_file_location(modname, path)
        module = importlib.util.module_from_spec(spec_)
        sys.modules[modname] = module
        spec_.loader.exec_module(module)
    except SceneError:
        raise
    except Exception as exc:  # the scene's own error, reported in one line
        where = ""
        tb = exc.__traceback__
        while tb is not None:
            if Path(tb.tb_frame.f_code.co_filename).resolve() == path.resolve():
                where = f" (line {tb.tb_lineno})"
            tb = tb.tb_next
        if isinstance(exc, SyntaxError) and exc.lineno:
            where = f" (line {exc.lineno})"
        raise SceneError(f"scene {path.name}{where}: {type(exc).__name__}: {exc}") from exc
    problem = getattr(module, "problem", None)
    if not isinstance(problem, (TwoMembraneProblem, ObstacleProblem, ParabolicProblem, TwoPhaseParams)):
        raise SceneError(
            f"scene {path.name} must define `problem` as a TwoMembraneProblem, ObstacleProblem, ParabolicProblem "
            f"or TwoPhaseParams"
            f" (got {type(problem).__name__})"
        )
    guess = getattr(module, "INITIAL_GUESS", None)
    if not isinstance(problem, TwoPhaseParams):
        _check_initial_guess(path.name, guess, 2 if isinstance(problem, TwoMembraneProblem) else 1)
    doc = (module.__doc__ or "").strip()
    return Scene(
        name=path.stem,
        path=path.resolve(),
        problem=problem,
        description=doc.splitlines()[0] if doc else "",
        defaults=dict(getattr(module, "DEFAULTS", {})),
        initial_guess=guess,
        test_options=dict(getattr(module, "TEST_OPTIONS", {})),
        module=module,
    )


def _check_initial_guess(scene_file: str, guess, nfields: int) -> None:
    """INITIAL_GUESS: None, or at most one entry per field (number, CoefficientFunction or None; missing
    trailing fields start at zero)."""
    if guess is None:
        return
    import numbers

    from ngsolve import CoefficientFunction

    try:
        entries = list(guess)
    except TypeError:
        entries = None
    if entries is None or isinstance(guess, (str, bytes)) or not 1 <= len(entries) <= nfields:
        raise SceneError(f"scene {scene_file}: INITIAL_GUESS must be a tuple of at most {nfields} entries (one per "
                         f"field: {'u1, u2' if nfields == 2 else 'u'}), got {guess!r}")
    for i, v in enumerate(entries):
        if v is None or isinstance(v, CoefficientFunction) or (isinstance(v, numbers.Real) and not isinstance(v, bool)):
            continue
        raise SceneError(f"scene {scene_file}: INITIAL_GUESS[{i}] must be a number, a CoefficientFunction or None, "
                         f"got {v!r}")
