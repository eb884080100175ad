"""Writing a run directory level by level (:class:`RunWriter`) or at once (:func:`write_run`)."""
from __future__ import annotations

import json
import os
import platform
import subprocess
from dataclasses import asdict
from pathlib import Path

from .directory import OutputDir
from .files import HISTORY_COLUMNS, csv_text, json_value
from .vtk import pvd_text, write_solution_vtu

__all__ = ["RunWriter", "write_run", "versions", "git_revision"]

#: the package directory (ngcontact/) and the directory that holds it
_PACKAGE = Path(__file__).resolve().parent.parent


def git_revision():
    """``git describe``-like revision (short hash, ``+dirty``) of the repository the package runs from, or None
    when it does not run from its own checkout (an installed copy, also one inside another repository)."""
    root = _PACKAGE.parent
    try:
        if 'name = "ngcontact"' not in (root / "pyproject.toml").read_text():
            return None
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=root, capture_output=True, text=True,
                             timeout=5)
        if top.returncode or Path(top.stdout.strip()).resolve() != root:
            return None
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                             timeout=5)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=5)
        if rev.returncode:
            return None
        return rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def versions() -> dict:
    import matplotlib
    import numpy
    import scipy
    import ngsolve

    from .. import __version__

    return {"ngcontact": __version__, "ngsolve": ngsolve.__version__, "numpy": numpy.__version__,
            "scipy": scipy.__version__, "matplotlib": matplotlib.__version__,
            "python": platform.python_version()}


def _display_path(path) -> str:
    """``path`` relative to the working directory when it lies below it (no absolute paths of the
    machine that ran it in committed summaries), else as given."""
    if path is None:
        return None
    p = Path(path)
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


class RunWriter:
    """Writes a :class:`~ngcontact.drivers.RunResult` into a run directory while the run goes.

    Use :meth:`level` as the drivers' ``on_level`` hook, then :meth:`finish` with the returned
    result, or :meth:`abort` with the reason when the run ends by an exception (package doc).

    Parameters
    ----------
    out_dir : path
        must pass :func:`~.directory.check_output_dir` (checked here, before any work).
    vtk : bool
        write solution.vtu of the final level (needs ``result.discretization``).
    plots : callable or None
        ``plots(directory, result)`` draws the figures into the run directory once the data files of
        the completed run are there and returns the names written, e.g.
        :func:`ngcontact.plotting.write_run_plots`; None or False: no figures.
    argv : list of str or None
        the command line, recorded in summary.json.
    vtk_series : bool
        also write ``solution_l<level>.vtu`` after every level and ``solution.pvd`` listing them.
    field : str
        the name of ``out_dir`` in error messages.
    """

    def __init__(self, out_dir, *, vtk: bool = True, plots=None, argv=None, vtk_series: bool = False,
                 field: str = "out_dir"):
        if plots and not callable(plots):
            raise TypeError(f"plots must be None or a callable (directory, result), got {plots!r}; "
                            "figures are drawn by e.g. ngcontact.plotting.write_run_plots")
        self.dir = OutputDir(out_dir, "run", field)
        self.vtk, self.plots, self.argv, self.vtk_series = vtk, plots, argv, vtk_series
        self.result = None
        self.done = (0, 0)  # rows and Newton iterations of the finished levels
        self.series = []  # (level, file) of the VTK series

    @property
    def path(self) -> Path:
        return self.dir.path

    @property
    def started(self) -> bool:
        return self.dir.started

    def level(self, result) -> None:
        """The ``on_level`` hook: all finished levels of ``result`` to disk, summary.json "running or killed".

        The first call replaces the previous contents of the directory."""
        self.result = result
        self.done = (len(result.rows), len(result.iterations))
        self._data(_Partial(result, *self.done), complete=False,
                   reason=f"running or killed: {self.done[0]} level(s) finished; process {os.getpid()} was computing "
                          f"the next one when this summary was written")
        if self.vtk_series and result.discretization is not None:
            level = result.rows[-1]["level"]
            name = f"solution_l{level}.vtu"
            write_solution_vtu(self.dir.register(name), self.dir.tmp_path(name), result.discretization, result.x,
                               result.y, result.estimate)
            self.series.append((level, name))
            self.dir.write("solution.pvd", pvd_text(self.series))

    def abort(self, reason: str):
        """The run ended by an exception: keep the finished levels, summary.json ``"complete": false`` with
        ``reason``.  Returns the directory, or None when no level had finished (nothing was written and a
        previous run there is untouched)."""
        if not self.started or self.result is None:
            return None
        self._data(_Partial(self.result, *self.done), complete=False, reason=reason)
        return self.path

    def finish(self, result) -> Path:
        """The run returned: data files, figures, VTK, then summary.json with ``complete`` (false with the stop
        reason when ``result.complete`` is false, e.g. a uniform run stopped at its DOF budget)."""
        self.result = result
        self.done = (len(result.rows), len(result.iterations))
        vtk = self.vtk and result.discretization is not None
        # summary.json while figures and VTK are written: only when there is one already or something follows
        self._data(result, complete=False, reason="writing figures and VTK files",
                   summary=self.started or bool(self.plots) or vtk)
        try:
            if self.plots:
                for name in self.plots(self.path, result) or []:
                    self.dir.register(name)
            if vtk:
                write_solution_vtu(self.dir.register("solution.vtu"), self.dir.tmp_path("solution.vtu"),
                                   result.discretization, result.x, result.y, result.estimate)
        except Exception as exc:
            self._data(result, complete=False, reason=f"figures or VTK failed: {type(exc).__name__}: {exc}",
                       tables=False)
            raise
        complete = getattr(result, "complete", True)
        self._data(result, complete=complete, reason=None if complete else result.stop_reason, tables=False)
        return self.path

    def _data(self, result, complete: bool, reason, summary: bool = True, tables: bool = True) -> None:
        if tables:
            self.dir.write("history.csv", csv_text(result.rows, HISTORY_COLUMNS))
            self.dir.write("newton.csv", csv_text(result.iterations))
        if summary:
            self.dir.write("summary.json", json.dumps(self._summary(result, complete, reason), indent=2) + "\n")

    def _summary(self, result, complete: bool, reason) -> dict:
        scene = result.scene
        return {
            "scene": scene.name,
            "scene_file": _display_path(scene.path),
            "problem": type(scene.problem).__name__,
            "domain": scene.problem.domain.name,
            "description": scene.description,
            "options": asdict(result.options),
            "converged": result.converged,
            "failures": result.failures,
            "safeguards": list(getattr(result, "notes", [])),
            "caveats": list(getattr(result, "caveats", [])),
            **({"stop_reason": result.stop_reason} if getattr(result, "stop_reason", None) else {}),
            "complete": bool(complete),
            "reason": reason,
            "final": {k: json_value(v) for k, v in result.rows[-1].items()} if result.rows else {},
            "versions": versions(),
            "git_revision": git_revision(),
            "command": " ".join(self.argv) if self.argv else None,
        }


class _Partial:
    """The finished levels of a result whose next level was cut short (rows, iterations and failures so far)."""

    def __init__(self, result, rows: int, iterations: int):
        self.scene, self.options = result.scene, result.options
        self.rows, self.iterations = result.rows[:rows], result.iterations[:iterations]
        done = {r["level"] for r in self.rows}
        self.failures = [f for f in result.failures if _failure_level(f) in done]
        self.notes = [f for f in getattr(result, "notes", []) if _failure_level(f) in done]
        self.converged = not self.failures
        self.stop_reason = None  # the run has not ended (or ended by an exception: the summary's reason)


def _failure_level(message: str):
    """The level of a failure message ``level L: ...``."""
    head = message.split(":", 1)[0].split()
    return int(head[1]) if len(head) == 2 and head[0] == "level" and head[1].isdigit() else None


def write_run(result, out_dir, vtk: bool = True, plots=None, argv=None) -> Path:
    """Write all outputs of a finished :class:`~ngcontact.drivers.RunResult` into ``out_dir``.

    Parameters as for :class:`RunWriter`; ``out_dir`` must be absent, empty or a directory that
    ngcontact wrote and that holds nothing else (it is replaced).  summary.json says ``"complete": true``
    once everything is written; if ``plots`` or the VTK output fail, the exception propagates and the
    data files stay, with ``"complete": false`` and the error as the reason.
    """
    return RunWriter(out_dir, vtk=vtk, plots=plots, argv=argv).finish(result)
