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
    (["run", "test1", "--order", "7"], "option order must be one of"),
    (["run", "test1", "--levels", "0"], "option levels must be"),
    (["run", "test1", "--cfun", "max"], "invalid choice"),
    (["run", "test1", "--tol", "abc"], "invalid float value"),
    (["run", "test1", "--newton-stop", "balanced", "--gamma-balance", "5"], "option gamma_balance must be"),
    (["run", "test1", "--ilu-drop", "1e-6"], "--ilu-drop need --newton exact-gmres, inexact or adaptive"),
    (["run", "test1", "--newton", "inexact", "--nu", "5"], "--nu need --newton adaptive"),
    (["run", "test1", "--newton", "inexact", "--ilu-fill", "0.5"], "option ilu_fill must be a number >= 1"),
    (["run", "test1", "--flux-order", "2"], "--flux-order needs --estimate, --adaptive or --newton adaptive"),
    (["run", "test1", "--estimate", "--order", "2", "--flux-order", "4"], "option flux_order must be None, 2 or 3"),
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
