"""Output directories that never delete a user's file: the manifest, the check before a run, replacement.

A directory written by ngcontact holds ``manifest.json``, the list of the files (and, for ``demo``,
the run subdirectories) it wrote.  An entry is *ours* when the manifest lists it, when it has one
of the fixed names of ngcontact outputs (:data:`OWN_NAMES`: a run killed between writing a file
and listing it, or a directory written before manifests existed), or when it is a temporary file
of an interrupted write (:data:`~.files.TMP_MARK`).  Any other entry is the user's: replacing the
directory is refused with one line naming it.  :meth:`OutputDir.start` removes our entries of the
previous contents only when the new contents are about to be written.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

from .files import TMP_MARK, atomic_write

__all__ = ["MANIFEST", "OWN_NAMES", "OutputDir", "check_output_dir"]

MANIFEST = "manifest.json"

#: fixed names of what ngcontact writes, per kind of directory (``run``: ``ngcontact run``; ``demo``: its two runs
#: and the overview figure)
OWN_NAMES = {
    "run": {"history.csv", "newton.csv", "summary.json", "convergence.png", "error_vs_time.png", "newton.png",
            "solution.png", "mesh.png", "eta_map.png", "solution.vtu", "solution.pvd"},
    "demo": {"p1", "p2", "convergence.png"},
}


def _manifest_files(directory: Path) -> set:
    try:
        return set(json.loads((directory / MANIFEST).read_text()).get("files", []))
    except (OSError, ValueError, AttributeError):
        return set()


def _is_series_file(name: str) -> bool:
    """solution_l<level>.vtu: the per-level files of a VTK series."""
    stem, dot, ext = name.partition(".")
    return ext == "vtu" and stem.startswith("solution_l") and stem[len("solution_l"):].replace("_n", "").isdigit()


def _ours(directory: Path, kind: str, listed: set) -> tuple:
    """(our entries, foreign entries) of an existing directory of this ``kind``."""
    ours, foreign = [], []
    for e in sorted(directory.iterdir()):
        name = e.name
        if name == MANIFEST or TMP_MARK in name or (kind == "run" and _is_series_file(name)):
            mine = not e.is_dir() or e.is_symlink()
        elif name in listed or name in OWN_NAMES[kind]:
            mine = not e.is_dir() or (kind == "demo" and not e.is_symlink() and not _ours(e, "run", _manifest_files(e))[1])
        else:
            mine = False
        (ours if mine else foreign).append(e)
    return ours, foreign


def _is_ours(directory: Path, kind: str) -> bool:
    """An ngcontact directory of this kind: it has a manifest, or (older runs) a summary.json / a demo's p1."""
    marker = {"run": "summary.json", "demo": "p1"}[kind]
    return (directory / MANIFEST).is_file() or (directory / marker).exists()


def _stale_siblings(out: Path) -> list:
    """Staging directories that killed runs of earlier versions left next to ``out``."""
    if not out.parent.is_dir():
        return []
    return sorted(p for pat in (f".tmp-{out.name}-*", f".old-{out.name}-*") for p in out.parent.glob(pat) if p.is_dir())


def check_output_dir(out_dir, field: str = "out", kind: str = "run") -> Path:
    """Check, before any work, that ngcontact may write a directory at ``out_dir``; returns it absolute.

    ``out_dir`` must be absent, empty, or a directory of this ``kind`` written by ngcontact that holds
    nothing else (module doc); its nearest existing ancestor must be a writable directory.  Errors
    (ValueError, one line) name ``field`` and the path.
    """
    if out_dir is None or str(out_dir).strip() == "":
        raise ValueError(f"{field} must be a directory path, got {str(out_dir)!r}")
    given = str(out_dir)
    out = Path(os.path.abspath(os.path.expanduser(given)))
    if out.parent == out:
        raise ValueError(f"{field} {given!r} is a file-system root, not an output directory")
    cwd = Path.cwd().resolve()
    if os.path.islink(out) and not out.exists():
        raise ValueError(f"{field} {given!r} is a broken symbolic link")
    if out.exists() and (out.resolve() == cwd or out.resolve() in cwd.parents):
        raise ValueError(f"{field} {given!r} is the working directory or contains it (an output directory is replaced "
                         f"as a whole): choose a subdirectory, e.g. {field} out/run")
    if out.exists():
        if not out.is_dir():
            raise ValueError(f"{field} {given!r} exists and is not a directory")
        entries = list(out.iterdir())
        if entries and not _is_ours(out, kind):
            raise ValueError(f"{field} {given!r} is a non-empty directory that ngcontact did not write (no {MANIFEST}); "
                             f"refusing to replace it: choose a new or empty directory")
        _, foreign = _ours(out, kind, _manifest_files(out))
        if foreign:
            raise ValueError(f"{field} {given!r} holds {foreign[0].name!r}"
                             f"{f' (and {len(foreign) - 1} more)' if len(foreign) > 1 else ''}, which ngcontact did not "
                             f"write; replacing the directory would delete it: move it away or choose another directory")
    anc = out.parent
    while not anc.exists():
        anc = anc.parent
    if not anc.is_dir():
        raise ValueError(f"{field} {given!r} cannot be created: {anc} is not a directory")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise ValueError(f"{field} {given!r} cannot be created: {anc} is not writable")
    probe_dir = out if out.is_dir() else anc
    try:  # access() says yes to root anywhere: try it
        os.rmdir(tempfile.mkdtemp(prefix=".ngcontact-probe-", dir=probe_dir))
    except OSError as exc:
        raise ValueError(f"{field} {given!r} cannot be written: {exc.strerror} ({probe_dir})") from None
    return out


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


class OutputDir:
    """A directory that ngcontact writes: checked at construction, replaced by :meth:`start`.

    Parameters
    ----------
    path : path
        must pass :func:`check_output_dir` for ``kind``.
    kind : 'run' or 'demo'
    field : str
        the name of the path in error messages (``--out``, ``out_dir``).
    """

    def __init__(self, path, kind: str = "run", field: str = "out_dir"):
        self.kind, self.field = kind, field
        self.path = check_output_dir(path, field, kind)
        self.files = None  # the manifest, once started
        self.notes = []  # what start() did about stale staging directories (one line each)

    @property
    def started(self) -> bool:
        return self.files is not None

    def start(self) -> "OutputDir":
        """Remove our entries of the previous contents, create the directory, write an empty manifest
        (idempotent).  Entries that appeared since the check and are not ours stay; so does the refusal."""
        if self.started:
            return self
        out = self.path
        if out.is_dir():
            ours, foreign = _ours(out, self.kind, _manifest_files(out))
            if foreign and not _is_ours(out, self.kind):
                raise ValueError(f"{self.field} {str(out)!r} changed during the run and now holds {foreign[0].name!r}: "
                                 f"not replaced")
            for e in ours:
                if e.is_dir() and not e.is_symlink():
                    shutil.rmtree(e)
                else:
                    e.unlink(missing_ok=True)
        elif os.path.lexists(out):
            raise ValueError(f"{self.field} {str(out)!r} appeared during the run and is not a directory")
        out.mkdir(parents=True, exist_ok=True)
        os.chmod(out, 0o777 & ~_umask())
        self.notes = self._clean_stale()
        self.files = []
        self._save()
        return self

    def _clean_stale(self) -> list:
        notes = []
        for d in _stale_siblings(self.path):
            if not _ours(d, "run", set())[1]:
                shutil.rmtree(d, ignore_errors=True)
                notes.append(f"removed {d.name}, a staging directory left by a killed run")
            else:
                notes.append(f"left {d} alone: it looks like the staging directory of a killed run but holds other "
                             f"files; remove it yourself")
        return notes

    def _save(self):
        from .. import __version__

        atomic_write(self.path / MANIFEST, json.dumps({"ngcontact": __version__, "kind": self.kind,
                                                       "files": self.files}, indent=1) + "\n")

    def register(self, name: str) -> Path:
        """List ``name`` in the manifest (before it is written: a kill in between leaves it listed); its path."""
        self.start()
        if name not in self.files:
            self.files.append(name)
            self._save()
        return self.path / name

    def write(self, name: str, data) -> Path:
        """Register and atomically write the file ``name`` (str or bytes)."""
        return atomic_write(self.register(name), data)

    def tmp_path(self, name: str) -> Path:
        """A temporary name for a file that a library writes itself (rename it to :meth:`register`'s path)."""
        return self.path / f".{name}{TMP_MARK}"
