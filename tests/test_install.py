"""The package as a user installs it: build the wheel, install it into a fresh venv, run it elsewhere.

The wheel is built from a copy of the files a clone has (so nothing is written into the repository,
e.g. no ``build/``), without build isolation when this interpreter's setuptools can build wheels
(the ``test`` extra asks for setuptools >= 70.1), else with it (pip then fetches setuptools).
The venv gets only the wheel (``--no-deps``); a ``.pth`` file lets it see the site-packages
where ngsolve, numpy, scipy and matplotlib are installed, so nothing large is downloaded.
Every command runs from a directory outside the repository, without PYTHONPATH.
"""
import importlib.util
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SOURCE = ("pyproject.toml", "setup.py", "README.md", "ngcontact", "cases")


def _setuptools_builds_wheels() -> bool:
    try:
        import setuptools
    except ImportError:
        return False
    major, minor = (int(x) for x in setuptools.__version__.split(".")[:2])
    return (major, minor) >= (70, 1) or importlib.util.find_spec("wheel") is not None


def _run(cmd, cwd, env, timeout=300):
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{' '.join(map(str, cmd))} -> {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(venv python, ngcontact script, clean environment, working directory outside the repository)."""
    import ngsolve

    tmp = tmp_path_factory.mktemp("install")
    src = tmp / "src"
    for name in SOURCE:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            src.mkdir(exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    build = ["--no-build-isolation", "--no-index"] if _setuptools_builds_wheels() else []
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", *build, "-w", tmp / "dist", src], tmp,
         dict(os.environ))  # the build sees what this interpreter sees
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NGCONTACT_CASES")}
    env["NGCONTACT_THREADS"] = "1"
    wheel, = (tmp / "dist").glob("ngcontact-*.whl")
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], tmp, env)
    site, = venv.glob("lib/python*/site-packages")
    deps = Path(ngsolve.__file__).resolve().parent.parent  # ngsolve, numpy, scipy, matplotlib (and pip)
    (site / "_ngcontact_test_deps.pth").write_text(f"{deps}\n")
    py = venv / "bin" / "python"
    _run([py, "-m", "pip", "install", "-q", "--no-deps", "--no-index", wheel], tmp, env)
    work = tmp / "elsewhere"
    work.mkdir()
    return py, venv / "bin" / "ngcontact", env, work, wheel


def test_the_wheel_holds_every_module_and_scene(installed):
    *_, wheel = installed
    names = set(zipfile.ZipFile(wheel).namelist())
    want = {str(p.relative_to(ROOT)) for p in (ROOT / "ngcontact").rglob("*.py")}
    want |= {f"ngcontact/cases/{p.name}" for p in (ROOT / "cases").glob("*.py")}
    assert want <= names, sorted(want - names)


def test_installed_package_runs_from_another_directory(installed):
    py, script, env, work, _ = installed
    where = _run([py, "-c", "import ngcontact, ngcontact.estimators, ngcontact.studies.sweep, ngcontact.scenes as s; "
                            "print(ngcontact.__file__); print(s.cases_dir())"], work, env).split()
    venv = script.parent.parent
    assert all(Path(w).resolve().is_relative_to(venv.resolve()) for w in where), where  # not the repository's files
    from ngcontact import __version__

    assert _run([script, "--version"], work, env).strip() == f"ngcontact {__version__}"
    listed = _run([script, "list"], work, env)
    assert {line.split()[0] for line in listed.splitlines()} == {p.stem for p in (ROOT / "cases").glob("[!_]*.py")}
    _run([script, "run", "test1", "--levels", "2", "--estimate", "--out", "est", "-q"], work, env)
    _run([script, "run", "lshape", "--adaptive", "--max-levels", "2", "--out", "ada", "-q", "--no-vtk"], work, env)
    for d in ("est", "ada"):
        assert (work / d / "summary.json").is_file() and (work / d / "history.csv").is_file()
    assert '"complete": true' in (work / "ada" / "summary.json").read_text()
    summary = (work / "est" / "summary.json").read_text()
    assert '"git_revision": null' in summary  # an installed copy has no revision of its own
