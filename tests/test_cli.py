"""The command line: outputs, one-line errors with exit code 2, user scenes."""
import csv
import json
import textwrap

import pytest

from ngcontact.cli import main
from ngcontact.results import HISTORY_COLUMNS

USER_SCENE = textwrap.dedent('''
    """My scene: mu1 != mu2, contact zone off-centre."""
    from ngsolve import x, y, exp
    from ngcontact import CrissCrossSquare, TwoMembraneProblem

    bump = exp(-40 * ((x - 0.3) ** 2 + (y - 0.65) ** 2))
    problem = TwoMembraneProblem(
        domain=CrissCrossSquare(n0=4),
        f1=-30 * bump, f2=10.0, g1=0.05, g2=-0.05, mu1=2.0, mu2=0.5,
    )
    DEFAULTS = dict(order=2, levels=3)
''')


def test_run_writes_documented_outputs(tmp_path, capsys):
    out = tmp_path / "t2"
    assert main(["run", "test2", "--levels", "2", "--out", str(out), "-q"]) == 0
    for f in ["history.csv", "newton.csv", "summary.json", "convergence.png", "error_vs_time.png",
              "newton.png", "solution.png", "solution.vtu"]:
        assert (out / f).is_file(), f
    header = next(csv.reader(open(out / "history.csv")))
    assert set(header) <= set(HISTORY_COLUMNS)
    for col in ["level", "ndof", "h", "err_energy", "rate_energy", "newton_its", "time_solve_s", "time_total_s"]:
        assert col in header
    s = json.loads((out / "summary.json").read_text())
    assert s["scene"] == "test2" and s["converged"] is True
    assert s["options"]["order"] == 1 and "ngsolve" in s["versions"] and s["git_revision"]
    assert "level" in capsys.readouterr().out


def test_user_scene_without_exact_solution(tmp_path):
    scene = tmp_path / "my_scene.py"
    scene.write_text(USER_SCENE)
    out = tmp_path / "mine"
    assert main(["run", str(scene), "--out", str(out), "-q", "--no-vtk"]) == 0
    rows = list(csv.DictReader(open(out / "history.csv")))
    assert len(rows) == 3 and "err_energy" not in rows[0]  # nothing asked, nothing computed
    assert int(rows[-1]["active_nodes"]) > 0  # the membranes touch
    assert not (out / "convergence.png").exists()
    assert json.loads((out / "summary.json").read_text())["options"]["order"] == 2


@pytest.mark.parametrize("args,msg", [
    (["run", "no_such_scene"], "unknown scene 'no_such_scene'"),
    (["run", "missing/file.py"], "scene file not found"),
    (["run", "test1", "--order", "7"], "option --order must be one of"),
    (["run", "test1", "--levels", "0"], "option --levels must be"),
    (["run", "test1", "--cfun", "max"], "invalid choice"),
    (["run", "test1", "--tol", "abc"], "invalid float value"),
    (["run", "test1", "--newton-stop", "balanced", "--gamma-balance", "5"], "option --gamma-balance must be"),
    (["run", "test1", "--ilu-drop", "1e-6"], "--ilu-drop need --newton gmres, inexact or adaptive"),
    (["run", "test1", "--newton", "inexact", "--nu", "5"], "--nu need --newton adaptive"),
    (["run", "test1", "--newton", "multigrid", "--krylov", "cg"], "--krylov need --newton gmres, inexact or adaptive"),
    (["run", "test1", "--disc", "hho", "--newton", "multigrid"], "option --newton must be 'direct' for disc 'hho'"),
    (["run", "test1", "--newton", "inexact", "--ilu-fill", "0.5"], "option --ilu-fill must be a number >= 1"),
    (["run", "test1", "--flux-order", "2"], "--flux-order needs --estimate, --adaptive or --newton adaptive"),
    (["run", "test1", "--estimate", "--order", "2", "--flux-order", "4"], "option --flux-order must be p = 2 or p + 1 = 3 (or omitted), got 4"),
    (["run", "test1", "--decouple", "--newton", "inexact"], "option --decouple needs the direct Newton solves: option --newton 'direct' (got 'inexact')"),
    (["run", "test1", "--estimate", "--flux-order", "q"], "option --flux-order must be p, p+1 or an integer, got 'q'"),
    (["run", "test1", "--adaptive", "--levels", "3"], "option --levels sets the number of uniform levels"),
    (["run", "test1", "--adaptive", "--max-ndof", "-5"], "option --max-ndof must be a positive integer (or omitted)"),
    (["run", "test1", "-v", "-q"], "-v/--verbose and -q/--quiet exclude each other"),
    (["run", "test1", "--no-condense"], "--no-condense needs --disc hho"),
    (["run", "test1", "--disc", "hho", "--decouple"], "--decouple needs disc 'fem' (got disc 'hho')"),
    (["run", "ex9_obstacle", "--decouple"], "--decouple needs a two-membrane scene"),
    (["run", "test1", "--gamma-balance", "0.1"], "--gamma-balance needs --newton-stop balanced"),
    (["run", "test1", "--newton", "adaptive", "--gamma-alg", "5"], "option --gamma-alg must be a number in (0, 1)"),
    (["frobnicate"], "invalid choice"),
])
def test_bad_input_gives_one_line_and_exit_code_2(args, msg, capsys, tmp_path):
    assert main(args + ["--out", str(tmp_path / "o")] if args[0] == "run" else args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("ngcontact: error:") and msg in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_scene_with_an_error_leaves_no_outputs(tmp_path, capsys):
    bad = tmp_path / "bad.py"
    bad.write_text("from ngcontact import *\nproblem = TwoMembraneProblem(CrissCrossSquare(), f1=0, f2=0, mu1=-2)\n")
    out = tmp_path / "o"
    assert main(["run", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "bad.py (line 2)" in err and "mu1" in err and "-2" in err
    assert not out.exists()
    typo = tmp_path / "typo.py"
    typo.write_text("problem = = 1\n")
    assert main(["run", str(typo), "--out", str(out)]) == 2
    assert "SyntaxError" in capsys.readouterr().err


def test_data_error_on_the_mesh_is_one_line(tmp_path, capsys):
    bad = tmp_path / "incompatible.py"
    bad.write_text("from ngcontact import *\nproblem = TwoMembraneProblem(CrissCrossSquare(), f1=0, f2=0, g1=0, g2=1)\n")
    assert main(["run", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "g1 < g2 on the boundary" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_failed_run_keeps_previous_outputs_intact(tmp_path, capsys):
    out = tmp_path / "keep"
    assert main(["run", "test2", "--levels", "1", "--out", str(out), "-q", "--no-vtk", "--no-plots"]) == 0
    before = (out / "history.csv").read_text()
    bad = tmp_path / "bad.py"
    bad.write_text("from ngcontact import *\nproblem = TwoMembraneProblem(CrissCrossSquare(), f1=0, f2=0, g1=0, g2=1)\n")
    assert main(["run", str(bad), "--out", str(out)]) == 2
    assert (out / "history.csv").read_text() == before
    assert not list(tmp_path.glob(".tmp-*"))


def test_newton_failure_is_reported_with_exit_code_3(tmp_path, capsys):
    out = tmp_path / "nc"
    assert main(["run", "test1", "--levels", "2", "--maxit", "1", "--start", "cold", "--out", str(out),
                 "-q", "--no-vtk", "--no-plots"]) == 3
    assert "Newton did not converge" in capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["converged"] is False and s["failures"]


def test_list_shows_bundled_scenes(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in ["test1", "test2", "disk", "ex9_obstacle"]:
        assert name in out


def test_decouple_flag_gives_the_coupled_errors(tmp_path):
    """--decouple (Newton on w = u1 - u2) reaches the same discrete solution as the coupled Newton."""
    from ngcontact.results import read_history

    for flag, name in (([], "coupled"), (["--decouple"], "decoupled")):
        assert main(["run", "test1", "--levels", "2", "--order", "2", "--no-vtk", "--no-plots", "-q",
                     "--out", str(tmp_path / name)] + flag) == 0
    a, b = (read_history(tmp_path / n / "history.csv") for n in ("coupled", "decoupled"))
    for ra, rb in zip(a, b):
        assert abs(ra["err_energy"] - rb["err_energy"]) <= 1e-10 * ra["err_energy"]
    s = json.loads((tmp_path / "decoupled" / "summary.json").read_text())
    assert s["options"]["decouple"] is True


def test_bad_thread_setting_names_the_variable(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("NGCONTACT_THREADS", "two")
    assert main(["run", "test1", "--levels", "1", "--out", str(tmp_path / "o")]) == 2
    assert "NGCONTACT_THREADS" in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_flux_order_option_reaches_the_estimator(tmp_path):
    """--flux-order p+1: the estimator uses RT_{p+1} (recorded), the bound stays guaranteed."""
    out = tmp_path / "q"
    assert main(["run", "test1", "--order", "2", "--levels", "2", "--estimate", "--flux-order", "3",
                 "--out", str(out), "-q", "--no-vtk", "--no-plots"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["options"]["flux_order"] == 3
    rows = list(csv.DictReader(open(out / "history.csv")))
    assert all(float(r["i_eff"]) >= 1.0 for r in rows)
    ref = tmp_path / "p"
    assert main(["run", "test1", "--order", "2", "--levels", "2", "--estimate",
                 "--out", str(ref), "-q", "--no-vtk", "--no-plots"]) == 0
    base = list(csv.DictReader(open(ref / "history.csv")))
    assert [r["err_energy"] for r in rows] == [r["err_energy"] for r in base]  # same solutions
    assert all(abs(float(a["eta"]) / float(b["eta"]) - 1) > 1e-6 for a, b in zip(rows, base))  # another flux


def test_out_never_replaces_a_foreign_directory(tmp_path, capsys):
    """--out naming a non-empty directory that is not a run directory is refused before any work, its
    files untouched; a previous run directory is replaced."""
    mine = tmp_path / "thesis"
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    assert main(["run", "test1", "--levels", "1", "--out", str(mine), "-q", "--no-vtk", "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "ngcontact did not write" in err and len(err.strip().splitlines()) == 1
    assert (mine / "thesis.tex").read_text() == "precious"
    run = tmp_path / "run"
    for _ in range(2):  # the second run replaces the first one's directory
        assert main(["run", "test1", "--levels", "1", "--out", str(run), "-q", "--no-vtk", "--no-plots"]) == 0
    assert (run / "summary.json").is_file() and not list(tmp_path.glob(".tmp-*"))
    (run / "notes.txt").write_text("mine")  # a run directory holding a user's file is not replaced either
    assert main(["run", "test1", "--levels", "1", "--out", str(run), "-q", "--no-vtk", "--no-plots"]) == 2
    assert "holds 'notes.txt'" in capsys.readouterr().err and (run / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("make_out,msg", [
    (lambda t: "", "--out must be a directory path, got ''"),
    (lambda t: str(t / "afile" / "sub"), "is not a directory"),
    (lambda t: str(t / "afile"), "exists and is not a directory"),
])
def test_bad_out_is_found_before_solving(make_out, msg, tmp_path, capsys):
    import time

    (tmp_path / "afile").write_text("x")
    t0 = time.perf_counter()
    assert main(["run", "test1", "--levels", "6", "--out", make_out(tmp_path)]) == 2
    assert time.perf_counter() - t0 < 20  # level 6 of test 1 is not solved first
    err = capsys.readouterr().err.strip()
    assert err.startswith("ngcontact: error: --out") and msg in err and len(err.splitlines()) == 1


def test_run_directory_follows_the_umask_and_summary_numbers_are_numbers(tmp_path):
    import os
    import stat

    old = os.umask(0o022)
    try:
        out = tmp_path / "perm"
        assert main(["run", "test1", "--levels", "1", "--out", str(out), "-q", "--no-vtk", "--no-plots"]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == 0o755
    final = json.loads((out / "summary.json").read_text())["final"]
    assert isinstance(final["h"], float) and isinstance(final["ndof"], int) and isinstance(final["err_energy"], float)


def test_flux_order_accepts_p_and_p_plus_1(tmp_path):
    out = tmp_path / "fo"
    assert main(["run", "test1", "--levels", "1", "--estimate", "--flux-order", "p+1", "--out", str(out),
                 "-q", "--no-vtk", "--no-plots"]) == 0
    assert json.loads((out / "summary.json").read_text())["options"]["flux_order"] == 2


def test_adaptive_run_without_a_budget_gets_the_default_one(tmp_path, capsys):
    from ngcontact.cli import DEFAULT_MAX_NDOF

    out = tmp_path / "ad"
    assert main(["run", "test1", "--adaptive", "--max-levels", "2", "--out", str(out), "--no-vtk",
                 "--no-plots"]) == 0
    assert f"default budget --max-ndof {DEFAULT_MAX_NDOF}" in capsys.readouterr().out
    assert json.loads((out / "summary.json").read_text())["options"]["max_ndof"] == DEFAULT_MAX_NDOF


@pytest.mark.parametrize("name,text,msg", [
    ("data.csv", "a,b\n", "must be a Python file (.py)"),
    ("long_guess.py", "from ngcontact import *\nproblem = TwoMembraneProblem(CrissCrossSquare(), f1=0, f2=0)\n"
                       "INITIAL_GUESS = (1.0, 0.0, 2.0)\n", "INITIAL_GUESS must be a tuple of at most 2 entries"),
    ("text_guess.py", "from ngcontact import *\nproblem = TwoMembraneProblem(CrissCrossSquare(), f1=0, f2=0)\n"
                      "INITIAL_GUESS = ('a', 0.0)\n", "INITIAL_GUESS[0] must be a number"),
])
def test_scene_file_problems_are_one_line(name, text, msg, tmp_path, capsys):
    f = tmp_path / name
    f.write_text(text)
    assert main(["run", str(f), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert main(["run", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert "is a directory, not a scene .py file" in capsys.readouterr().err


def test_sigterm_keeps_the_finished_levels(tmp_path):
    """SIGTERM during a run: exit code 143; the levels finished before it are on disk, summary.json says
    "complete": false and why; no temporary file is left."""
    import signal
    import subprocess
    import sys

    from ngcontact.results import read_history

    out = tmp_path / "term"
    proc = subprocess.Popen([sys.executable, "-m", "ngcontact", "run", "test1", "--order", "2", "--levels", "7",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().startswith("ngcontact: scene test1")  # the header: the run has started
    for line in proc.stdout:
        if line.startswith("level 2:"):  # levels 0..2 are finished
            break
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "terminated (SIGTERM)" in err and "complete" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and summary["reason"].startswith("terminated (SIGTERM) during level")
    levels = [r["level"] for r in read_history(out / "history.csv")]
    assert levels[:3] == [0, 1, 2] and levels == list(range(len(levels))) and len(levels) < 7
    assert {r["level"] for r in read_history(out / "newton.csv")} == set(levels)
    assert not [p for p in out.iterdir() if p.name.startswith(".")] and not list(tmp_path.glob(".tmp-*"))


def test_out_cannot_be_the_working_directory(tmp_path, monkeypatch, capsys):
    """Replacing the working directory (or a directory containing it) would pull it from under the shell."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    for out in (".", str(tmp_path)):
        assert main(["run", "test1", "--levels", "1", "--out", out]) == 2
        assert "is the working directory or contains it" in capsys.readouterr().err
    assert work.is_dir() and not list(work.iterdir())


def test_line_search_stall_is_remedied_and_logged(tmp_path, capsys, monkeypatch):
    """HHO without condensation, Fischer-Burmeister, test 1 T1, with the factorization-reuse PCG stopping short
    (rtol 1e-8: a fault injected here; until stop 48 PCG's loose round-off floor did this by itself): the Armijo
    line search fails near ||Phi||/||F|| ~ 1e-10, the loop continues with Newton-min steps; a step that then returns
    its start gets a fresh factorization (newton.safeguards); the run converges and says so on stderr and in
    summary.json."""
    import ngcontact.algebra.reuse as reuse

    real = reuse.pcg
    monkeypatch.setattr(reuse, "pcg", lambda A, b, M, x0=None, *, rtol=1e-12, **kw:
                        real(A, b, M, x0, rtol=max(rtol, 1e-8), **kw))
    args = ["run", "test1", "--disc", "hho", "--cfun", "fb", "--no-condense", "--levels", "2", "-q", "--no-vtk",
            "--no-plots"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "Newton safeguard, level 1: iteration" in err and "line search failed: switch to Newton-min" in err
    assert "no progress: fresh factorization" in err
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["safeguards"] and summary["final"]["certified"] == 1 and summary["final"]["newton_remedies"] >= 1


def test_test_flag_needs_test_options(tmp_path, capsys):
    scene = tmp_path / "my_scene.py"
    scene.write_text(USER_SCENE)
    assert main(["run", str(scene), "--test", "--out", str(tmp_path / "o")]) == 2
    assert "--test needs TEST_OPTIONS" in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_table_and_plot_commands_read_run_directories(tmp_path, capsys):
    """`table` prints the markdown tables of run directories (their numbers as in history.csv), `plot`
    writes the overlay PNG; a directory without history.csv is refused with one line."""
    from ngcontact.results import read_history

    dirs = [str(tmp_path / f"p{p}") for p in (1, 2)]
    for p, d in zip((1, 2), dirs):
        assert main(["run", "test1", "--order", str(p), "--levels", "2", "--estimate", "--out", d, "-q",
                     "--no-vtk", "--no-plots"]) == 0
    capsys.readouterr()
    assert main(["table", *dirs]) == 0
    text = capsys.readouterr().out
    assert "### test1: FEM P1" in text and "### test1: FEM P2" in text
    for d in dirs:
        final = read_history(f"{d}/history.csv")[-1]
        assert f"| T1 | {final['ndof']} | {final['err_energy']:.3e} |" in text
        assert f"| {final['i_eff']:.3f} |" in text  # the estimator table
    png = tmp_path / "cmp" / "overlay.png"
    assert main(["plot", *dirs, "--out", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert main(["table", str(tmp_path)]) == 2
    assert "is not a run directory" in capsys.readouterr().err


def test_error_in_scene_defaults_names_the_scene(tmp_path, monkeypatch, capsys):
    """An invalid value in a scene's DEFAULTS is reported with where it came from (not as if typed on the
    command line); the same option given on the command line overrides it."""
    from ngcontact.cli import main

    (tmp_path / "s_def.py").write_text("from ngcontact import CrissCrossSquare, TwoMembraneProblem\n"
                                       "problem = TwoMembraneProblem(domain=CrissCrossSquare(n0=4), f1=1.0, f2=0.0)\n"
                                       "DEFAULTS = dict(order=7)\n")
    monkeypatch.setenv("NGCONTACT_CASES", str(tmp_path))
    assert main(["run", "s_def", "--out", str(tmp_path / "a")]) == 2
    assert "got 7 (from the DEFAULTS of scene s_def)" in capsys.readouterr().err
    assert main(["run", "s_def", "--order", "1", "--levels", "1", "-q", "--no-vtk", "--out", str(tmp_path / "b")]) == 0


SINGULAR_BC_SCENE = textwrap.dedent('''
    """Obstacle far below; g = r^(1/2) cos(theta/2) around (0.4, 0): singular inside the bottom edge."""
    from ngsolve import atan2, cos, x, y
    from ngcontact import CrissCrossSquare, ObstacleProblem

    r2, th = (x - 0.4) ** 2 + y ** 2, atan2(y, x - 0.4)
    problem = ObstacleProblem(domain=CrissCrossSquare(n0=4), psi=-10.0 + 0 * x, f=0.0, g=r2 ** 0.25 * cos(th / 2))
    DEFAULTS = dict(order=2, levels=2)
''')


def test_unproven_bound_is_a_warning_and_a_caveat(tmp_path, capsys):
    """Dirichlet data singular inside a boundary edge: the run succeeds, the CLI warns that eta is not a proven
    bound on each level (naming the trace defect), history.csv has bound_proven = 0, summary.json the caveats."""
    scene = tmp_path / "singular_bc.py"
    scene.write_text(SINGULAR_BC_SCENE)
    out = tmp_path / "sing"
    assert main(["run", str(scene), "--estimate", "--out", str(out), "-q", "--no-vtk", "--no-plots"]) == 0
    err = capsys.readouterr().err
    assert err.count("ngcontact: warning: level") == 2 and "trace defect indicator" in err
    rows = list(csv.DictReader(open(out / "history.csv")))
    assert [r["bound_proven"] for r in rows] == ["0", "0"]
    assert float(rows[-1]["eta_trace"]) > 0.1 * float(rows[-1]["eta"])
    caveats = json.loads((out / "summary.json").read_text())["caveats"]
    assert len(caveats) == 2 and caveats[0].startswith("level 0: error bound eta not proven")
