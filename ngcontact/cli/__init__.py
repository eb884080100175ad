"""Command line: ``ngcontact {run,list,plot,table,demo}`` (also ``python -m ngcontact``).

Exit codes, examples and environment variables: :data:`.parser.EPILOG` (``ngcontact --help``).
Errors print one line ``ngcontact: error: ...``; ``--debug`` adds the traceback.  A run writes its
run directory level by level (:class:`ngcontact.results.RunWriter`): when it ends by an error,
Ctrl-C or SIGTERM, the finished levels stay with ``"complete": false`` and the reason in
summary.json; when it fails before its first level is finished, nothing is written and a previous
run in ``--out`` is untouched.  A closed output pipe (``ngcontact list | head -1``) ends the
program quietly with exit code 141.
"""
from __future__ import annotations

import os
import signal
import sys
import traceback

import numpy as np

from .parser import UsageError, build_parser
from .report import cmd_list, cmd_plot, cmd_table, format_table
from .run import DEFAULT_MAX_NDOF, RunStopped, Session, cmd_demo, cmd_run

__all__ = ["main", "format_table", "DEFAULT_MAX_NDOF"]


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that the run directory is closed on the way out."""


def _on_sigterm(signum, frame):
    raise _Terminated()


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread (embedded use): leave signals alone
        previous = None
    try:
        return _main(argv)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _main(argv) -> int:
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    parser = build_parser()
    try:
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:  # --help, --version
            return exc.code or 0
        if args.cmd is None:
            parser.print_help()
            return 2
        if args.cmd in ("list", "plot", "table"):
            return {"list": cmd_list, "plot": cmd_plot, "table": cmd_table}[args.cmd](args)
        from ..drivers.resources import env_threads

        env_threads()  # NGCONTACT_THREADS checked before any work (run_scene applies it)
        return (cmd_demo if args.cmd == "demo" else cmd_run)(args, argv)
    except BaseException as exc:  # noqa: B036 -- every way out closes the run directory and names the reason
        return _fail(exc, debug)
    finally:
        Session.writer = None


#: (exception type, exit code, what happened); the first match counts
_OUTCOMES = (
    (UsageError, 2, None),
    (RunStopped, 4, None),
    (BrokenPipeError, 141, "the output pipe was closed"),
    (KeyboardInterrupt, 130, "interrupted (Ctrl-C)"),
    (_Terminated, 143, "terminated (SIGTERM)"),
    (MemoryError, 4, "out of memory (MemoryError)"),
    (np.linalg.LinAlgError, 4, None),  # a ValueError, but a failure of the numerics, not of the input
    ((ValueError, FileNotFoundError), 2, None),
    (Exception, 4, None),
)


def _fail(exc: BaseException, debug: bool) -> int:
    match = next(((c, w) for t, c, w in _OUTCOMES if isinstance(exc, t)), None)
    if match is None:  # SystemExit, GeneratorExit: not ours to translate
        raise exc
    code, what = match
    if what is None:
        what = str(exc) if code == 2 or isinstance(exc, RunStopped) else _internal(exc)
    kept = None
    writer = Session.writer
    if writer is not None and writer.started:
        what = f"{what} during level {writer.done[0]}"
        try:
            kept = writer.abort(what)
        except Exception:  # the directory cannot be written either: say what happened first
            kept = None
    if code == 141:  # quiet; later writes to stdout (at exit) go nowhere
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        return code
    if debug and not isinstance(exc, UsageError):
        traceback.print_exception(type(exc), exc, exc.__traceback__)
    tail = ""
    if kept is not None:
        n = writer.done[0]
        tail = f"; the finished level(s) 0-{n - 1} are in {kept}/ (summary.json: \"complete\": false)"
    if code == 4 and not isinstance(exc, RunStopped) and not debug:
        tail += " (rerun with --debug for the traceback)"
    prefix = "ngcontact: error: " if code in (2, 4) else "ngcontact: "
    print(f"{prefix}{what}{tail}", file=sys.stderr)
    return code


def _internal(exc: BaseException) -> str:
    """An unexpected exception in one line: NGSolve's errors and our bugs alike, named."""
    name = type(exc).__name__
    text = " ".join(str(exc).split()) or "(no message)"
    if name == "NgException":
        return f"NGSolve error (NgException): {text}"
    return f"internal error: {name}: {text}"
