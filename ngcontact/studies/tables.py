"""Helpers shared by the study reports: time to reach an error, table cells.

Fitted slopes come from :func:`ngcontact.rates.fitted_rate`.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["time_to_reach", "fmt", "md_row", "report_main"]


def time_to_reach(times, errors, target: float) -> float:
    """Time at which ``errors`` first reaches ``target`` (levels in order, ``times`` cumulated).

    Rule: let j be the first level with e_j <= target.  For j >= 1, log(t) is interpolated linearly
    in log(e) between levels j-1 and j; t_j itself when j = 0 or when a time or error of the two
    levels is not positive (no logarithm).  nan when no level reaches the target (no extrapolation).

    >>> round(time_to_reach([1.0, 100.0], [1e-2, 1e-4], 1e-3), 6)
    10.0
    >>> time_to_reach([1.0, 100.0], [1e-2, 1e-4], 1e-2), time_to_reach([2.0, 5.0], [1e-3, 1e-4], 1e-2)
    (1.0, 2.0)
    >>> math.isnan(time_to_reach([1.0, 10.0], [1e-2, 1e-3], 1e-4))
    True
    """
    t, e = np.asarray(times, float), np.asarray(errors, float)
    reached = np.flatnonzero(e <= target)
    if reached.size == 0:
        return float("nan")
    j = int(reached[0])
    if j == 0 or not (t[j - 1] > 0 and t[j] > 0 and e[j - 1] > 0 and e[j] > 0):
        return float(t[j])
    s = (math.log(target) - math.log(e[j - 1])) / (math.log(e[j]) - math.log(e[j - 1]))
    return math.exp(math.log(t[j - 1]) + s * (math.log(t[j]) - math.log(t[j - 1])))


def fmt(v, spec: str = ".3e", missing: str = "-") -> str:
    """A table cell: ``format(v, spec)``, or ``missing`` for None and non-finite numbers.

    >>> fmt(0.0123456), fmt(float("nan")), fmt(None, missing="--"), fmt(3, ".0f")
    ('1.235e-02', '-', '--', '3')
    """
    if v is None or (isinstance(v, (float, np.floating)) and not math.isfinite(v)):
        return missing
    return format(v, spec)


def md_row(cells) -> str:
    """One markdown table row.

    >>> md_row(["a", 1])
    '| a | 1 |'
    """
    return "| " + " | ".join(map(str, cells)) + " |"


def report_main(name: str, usage: str, write, argv=None) -> int:
    """The command line of a study report: ``python -m ngcontact.studies.NAME OUT RUN_DIR...`` calls
    ``write(OUT, RUN_DIRS)`` and prints the text it returns; exit code 2 with one line on bad usage or a
    ValueError / OSError."""
    import sys

    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) < 2:
        print(f"usage: python -m ngcontact.studies.{name} {usage}", file=sys.stderr)
        return 2
    try:
        print(write(argv[0], argv[1:]))
    except (ValueError, OSError) as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 2
    return 0
