"""The command line as a tool: --version, help, exit codes 0/2/3/4, --debug, a closed pipe, SIGKILL and a
memory limit (subprocesses where signals, pipes or limits are involved)."""
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ngcontact.cli import main
from ngcontact.results import read_history

ROOT = Path(__file__).resolve().parent.parent


def _env():
    return {**os.environ, "PYTHONPATH": str(ROOT), "NGCONTACT_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def _cli(*args):
    return [sys.executable, "-m", "ngcontact", *map(str, args)]


def test_version_and_plain_help(capsys):
    from ngcontact import __version__

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"ngcontact {__version__}"
    for argv in (["--help"], ["run", "--help"]):
        assert main(argv) == 0
        text = capsys.readouterr().out
        assert text.startswith("usage: ngcontact") and "`" not in text and "python -m" not in text
        for words in ("NGCONTACT_THREADS", "NGCONTACT_CASES", "exit codes", "resources exhausted", "--debug"):
            assert words in text, words


def test_closed_output_pipe_is_quiet():
    proc = subprocess.Popen(_cli("list"), stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env(), cwd=ROOT)
    assert proc.stdout.readline()  # like `ngcontact list | head -1`
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141 and err == ""


def _failing_level(monkeypatch, exc, at=2):
    """solve_level raises ``exc`` on level ``at``."""
    from ngcontact.drivers import uniform

    real = uniform.solve_level
    calls = []

    def solve_level(*args, **kw):
        calls.append(1)
        if len(calls) > at:
            raise exc
        return real(*args, **kw)
    monkeypatch.setattr(uniform, "solve_level", solve_level)


@pytest.mark.parametrize("exc, words", [
    (MemoryError(), "out of memory (MemoryError) during level 2"),
    (RuntimeError("boom\nsecond line"), "internal error: RuntimeError: boom second line during level 2"),
    (type("NgException", (Exception,), {})("no field of name x"), "NGSolve error (NgException): no field of name x"),
    # a ValueError subclass, but a failure of the numerics, not bad input (exit 2 before stop 48)
    (np.linalg.LinAlgError("2-th leading minor not positive definite"),
     "internal error: LinAlgError: 2-th leading minor not positive definite during level 2"),
])
def test_resources_and_internal_errors_exit_4_and_keep_the_finished_levels(exc, words, monkeypatch, tmp_path, capsys):
    _failing_level(monkeypatch, exc)
    out = tmp_path / "o"
    assert main(["run", "test1", "--levels", "4", "--out", str(out), "-q", "--no-vtk", "--no-plots"]) == 4
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err and "0-1 are in" in err and "--debug" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and words in summary["reason"]
    assert [r["level"] for r in read_history(out / "history.csv")] == [0, 1]


def test_debug_shows_the_traceback(monkeypatch, tmp_path, capsys):
    _failing_level(monkeypatch, RuntimeError("boom"), at=0)
    assert main(["run", "test1", "--levels", "2", "--out", str(tmp_path / "o"), "--debug"]) == 4
    err = capsys.readouterr().err
    assert "Traceback" in err and "RuntimeError: boom" in err
    assert not (tmp_path / "o").exists()  # failed before its first level: nothing written


def test_dof_budget_stops_a_uniform_run_with_exit_4(tmp_path, capsys):
    out = tmp_path / "b"
    assert main(["run", "test1", "--levels", "6", "--max-ndof", "2000", "--out", str(out), "-q", "--no-vtk"]) == 4
    err = capsys.readouterr().err
    assert "stopped before the requested 6 levels: max_ndof: level 3 would have about" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["reason"].startswith("max_ndof: level 3")
    assert len(read_history(out / "history.csv")) == 3 and (out / "convergence.png").is_file()


def test_sigkill_during_level_5_keeps_levels_0_to_4_and_a_second_run_keeps_a_users_file(tmp_path):
    out = tmp_path / "killed"
    proc = subprocess.Popen(_cli("run", "test1", "--levels", "6", "--out", out, "--no-vtk"), stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, env=_env(), cwd=tmp_path)
    for line in proc.stdout:
        if line.startswith("level 4:"):  # on disk before this line is printed; level 5 has started
            break
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["reason"].startswith("running or killed: 5 level(s) finished")
    assert [r["level"] for r in read_history(out / "history.csv")] == [0, 1, 2, 3, 4]
    assert main(["plot", str(out), "--out", str(tmp_path / "partial.png")]) == 0  # partial results can be plotted
    (out / "my_analysis.csv").write_text("mine")
    second = subprocess.run(_cli("run", "test1", "--levels", "1", "--out", out), capture_output=True, text=True,
                            env=_env(), cwd=tmp_path, timeout=120)
    assert second.returncode == 2 and "my_analysis.csv" in second.stderr
    assert (out / "my_analysis.csv").read_text() == "mine" and len(read_history(out / "history.csv")) == 5
    (out / "my_analysis.csv").unlink()
    assert main(["run", "test1", "--levels", "1", "--out", str(out), "-q", "--no-vtk", "--no-plots"]) == 0
    assert json.loads((out / "summary.json").read_text())["complete"] is True


def _vm_size_after_import() -> int:
    code = ("import ngcontact.cli, ngcontact.drivers, ngcontact.plotting; "
            "print([l for l in open('/proc/self/status') if l.startswith('VmSize')][0].split()[1])")
    return int(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(),
                              check=True).stdout) * 1024


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
def test_a_memory_limit_becomes_a_dof_budget(tmp_path):
    """Under ``ulimit -v`` (baseline + 400 MB here) the default budget stops test1 P1 before level 5 with a named
    reason: levels 0-4 on disk, "complete": false, exit code 4."""
    import resource

    limit = _vm_size_after_import() + 400 * 2 ** 20
    out = tmp_path / "limited"
    proc = subprocess.run(_cli("run", "test1", "--levels", "6", "--out", out, "--no-vtk", "--no-plots"),
                          capture_output=True, text=True, env=_env(), cwd=tmp_path, timeout=300,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (limit, limit)))
    assert proc.returncode == 4, proc.stderr
    assert "of ulimit -v" in proc.stdout and "stopped before level 5" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["reason"].startswith("max_ndof: level 5")
    assert [r["level"] for r in read_history(out / "history.csv")] == [0, 1, 2, 3, 4]


def test_demo_writes_its_runs_and_refuses_a_foreign_file(tmp_path, capsys):
    out = tmp_path / "demo"
    for _ in range(2):  # the second replaces the first
        assert main(["demo", "--levels", "1", "--out", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {"p1", "p2", "convergence.png", "manifest.json"}
    (out / "notes.md").write_text("mine")
    assert main(["demo", "--levels", "1", "--out", str(out)]) == 2
    assert "notes.md" in capsys.readouterr().err and (out / "notes.md").read_text() == "mine"
