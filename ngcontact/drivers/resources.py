"""What a run may use of the machine: NGSolve threads, and a DOF budget from the memory.

* Threads: ``run_scene(..., threads=N)``, else the environment variable ``NGCONTACT_THREADS``, else
  NGSolve's default (all cores).
* Size: before a uniform level is built, its DOF count is estimated from the finished levels
  (:func:`next_level_ndof`); a run with ``max_ndof`` stops there with a named reason instead of
  building a level that exceeds it.  :func:`memory_budget` turns the memory this process may still
  use (available memory, ``ulimit -v``, cgroup limit: the smallest) into such a DOF count.
"""
from __future__ import annotations

import os
import resource
from contextlib import contextmanager
from pathlib import Path

__all__ = ["env_threads", "threads_used", "configured_threads", "next_level_ndof", "memory_available", "memory_budget", "BYTES_PER_DOF"]

#: bytes of memory budgeted per DOF: a solve, and a solve with the estimators (flux reconstruction, patch
#: problems); above the peak memory per DOF of the bundled scenes, checked by tests/test_outputs.py
BYTES_PER_DOF = {"solve": 4000, "estimate": 10000}

#: share of the free memory that the budget hands out (the rest: the interpreter, fragmentation, plots)
MEMORY_SHARE = 0.8


def env_threads():
    """``NGCONTACT_THREADS`` as a positive int, or None when unset; ValueError naming it otherwise."""
    value = os.environ.get("NGCONTACT_THREADS", "")
    if value == "":
        return None
    if not value.isdigit() or int(value) < 1:
        raise ValueError(f"environment variable NGCONTACT_THREADS must be a positive integer, got {value!r}")
    return int(value)


@contextmanager
def threads_used(threads=None):
    """Run the body with ``threads`` NGSolve threads (None: ``NGCONTACT_THREADS``, else unchanged); the
    previous setting is restored afterwards."""
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise ValueError(f"threads must be a positive integer (or None), got {threads!r}")
    n = threads if threads is not None else env_threads()
    if n is None:
        yield
        return
    from ngsolve import SetNumThreads

    previous = configured_threads()
    SetNumThreads(n)
    try:
        yield
    finally:
        SetNumThreads(previous)


def configured_threads() -> int:
    """The number of threads NGSolve's TaskManager runs with (``GetNumThreads`` tells it only inside one;
    NGSolve releases without it: the number of cores, their default)."""
    import ngsolve

    if not hasattr(ngsolve, "GetNumThreads"):
        return os.cpu_count() or 1
    with ngsolve.TaskManager():
        return ngsolve.GetNumThreads()


def next_level_ndof(rows) -> int:
    """Estimated DOFs of the next uniform level (one red refinement: 4x the triangles) from the finished
    ``rows``: the last ratio of two levels (at least 4), else 4x the last level.

    >>> next_level_ndof([{"ndof": 75}, {"ndof": 339}])
    1532
    >>> next_level_ndof([{"ndof": 75}])
    300
    """
    last = rows[-1]["ndof"]
    ratio = max(last / rows[-2]["ndof"], 4.0) if len(rows) > 1 and rows[-2]["ndof"] else 4.0
    return int(round(last * ratio))


def _proc_bytes(path: str, key: str):
    """The ``key:  N kB`` entry of a /proc file in bytes, or None."""
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _meminfo_available():
    avail = _proc_bytes("/proc/meminfo", "MemAvailable")
    if avail is not None:
        return avail
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _cgroup_free():
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit == "max":
            return None
        return int(limit) - int(Path("/sys/fs/cgroup/memory.current").read_text())
    except (OSError, ValueError):
        return None


def memory_available():
    """(bytes, what limits them) that this process may still allocate: the smallest of the available
    memory, the address-space limit (``ulimit -v``) minus the current virtual size, and the cgroup's
    limit minus its usage; (None, reason) when none is known."""
    found = []
    avail = _meminfo_available()
    if avail is not None:
        found.append((avail, "available memory"))
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        found.append((soft - (_proc_bytes("/proc/self/status", "VmSize") or 0), "ulimit -v"))
    cg = _cgroup_free()
    if cg is not None:
        found.append((cg, "cgroup memory limit"))
    if not found:
        return None, "no memory information"
    return min(found)


def memory_budget(options):
    """(max_ndof, explanation) for a run with ``options``: :data:`MEMORY_SHARE` of :func:`memory_available`
    divided by :data:`BYTES_PER_DOF`; (None, reason) when the memory is unknown."""
    free, source = memory_available()
    if free is None:
        return None, source
    estimated = options.estimate or options.adaptive or options.newton == "adaptive"
    per_dof = BYTES_PER_DOF["estimate" if estimated else "solve"]
    ndof = max(int(MEMORY_SHARE * max(free, 0) / per_dof), 1)
    return ndof, f"from {free / 2 ** 30:.1f} GB of {source} at {per_dof} bytes per DOF"
