"""Run directories: the output schema (key columns level, n, t), the plots hook, data kept when figures fail."""
import csv
import json
from dataclasses import dataclass
from types import SimpleNamespace

import pytest

from ngcontact.cli import main
from ngcontact.results import KEY_COLUMNS, markdown_table, read_history, write_run


@dataclass
class _Options:
    order: int = 1
    disc: str = "fem"
    cfun: str = "min"
    start: str = "nested"


def _result(rows, iterations):
    """What write_run reads of a RunResult, without a discretization (no VTK, no solution plots)."""
    scene = SimpleNamespace(name="timed", path=None, description="rows with time steps",
                            problem=SimpleNamespace(domain=SimpleNamespace(name="square")))
    return SimpleNamespace(scene=scene, options=_Options(), rows=rows, iterations=iterations, discretization=None,
                           x=None, y=None, estimate=None, converged=True, failures=[])


def _header(path):
    return next(csv.reader(open(path)))


def test_time_step_rows_are_written_and_read_back_with_the_keys_first(tmp_path):
    rows = [{"nelem": 8, "ndof": 27, "t": 0.5 * n, "err_energy": 0.1 / (n + 1), "level": 0, "n": n,
             "newton_its": 3, "time_solve_s": 0.01, "time_linear_s": 0.005, "time_total_s": 0.02}
            for n in (1, 2, 3)]
    iterations = [{"k": k, "res": 10.0 ** -k, "step": 1.0, "t": r["t"], "n": r["n"], "level": 0}
                  for r in rows for k in range(2)]
    out = write_run(_result(rows, iterations), tmp_path / "run", vtk=False)
    assert _header(out / "history.csv")[:4] == ["level", "n", "t", "nelem"]
    assert _header(out / "newton.csv") == ["level", "n", "t", "k", "res", "step"]
    back = read_history(out / "history.csv")
    assert list(back[0])[:3] == list(KEY_COLUMNS)
    assert [(r["level"], r["n"], r["t"]) for r in back] == [(0, 1, 0.5), (0, 2, 1.0), (0, 3, 1.5)]
    assert all(isinstance(r["n"], int) and isinstance(r["t"], float) for r in back)
    assert back[1]["err_energy"] == pytest.approx(0.1 / 3, rel=1e-9)
    its = read_history(out / "newton.csv")
    assert [(r["n"], r["k"]) for r in its] == [(1, 0), (1, 1), (2, 0), (2, 1), (3, 0), (3, 1)]
    table = markdown_table([out])
    assert "| level | n | t | ndof |" in table and "| T0 | 2 | 1 | 27 |" in table


def test_stationary_run_files_have_no_time_columns(tmp_path):
    out = tmp_path / "st"
    assert main(["run", "test1", "--levels", "2", "--out", str(out), "-q", "--no-vtk", "--no-plots"]) == 0
    assert _header(out / "history.csv") == [
        "level", "nelem", "h", "ndof", "nodes", "err_energy", "rate_energy", "err_max_nodal", "newton_its",
        "newton_converged", "res_final", "certified", "cert_penetration", "cert_negativity", "cert_slackness",
        "cert_equilibrium", "cert_tol", "newton_remedies", "active_nodes", "linear_size", "gap_min", "lam_min", "product_max",
        "time_mesh_s", "time_assembly_s", "time_prolong_s", "time_solve_s", "time_linear_s", "time_post_s",
        "time_total_s", "time_cum_s"]
    assert _header(out / "newton.csv") == [
        "level", "k", "res", "res_lin", "res_c", "n_active", "n_changed", "step", "time_linear", "time_step",
        "linear_size", "linear_path", "pcg_its", "eps_lin", "eps_disc", "remedy"]
    assert "| level | ndof | err_energy | rate |" in markdown_table([out])


def test_plots_hook_draws_into_the_run_directory_after_the_data(tmp_path):
    seen = []

    def plots(directory, result):
        summary = json.loads((directory / "summary.json").read_text())
        seen.append((directory, sorted(p.name for p in directory.iterdir()), summary["complete"]))
        (directory / "figure.png").write_bytes(b"png")
        return ["figure.png"]

    out = write_run(_result([{"level": 0, "ndof": 3}], []), tmp_path / "run", vtk=False, plots=plots)
    (directory, present, complete), = seen
    assert directory == out
    assert present == ["history.csv", "manifest.json", "newton.csv", "summary.json"]  # data first, then the figures
    assert complete is False  # until the figures are there
    assert (out / "figure.png").read_bytes() == b"png"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scene"] == "timed" and summary["complete"] is True and summary["reason"] is None
    assert json.loads((out / "manifest.json").read_text())["files"] == ["history.csv", "newton.csv", "summary.json",
                                                                        "figure.png"]


def test_failing_plots_hook_keeps_the_data_and_says_incomplete(tmp_path):
    out = write_run(_result([{"level": 0, "ndof": 3}], []), tmp_path / "run", vtk=False)

    def broken(directory, result):
        raise RuntimeError("no display")

    with pytest.raises(RuntimeError, match="no display"):
        write_run(_result([{"level": 0, "ndof": 99}], []), out, vtk=False, plots=broken)
    assert read_history(out / "history.csv")[0]["ndof"] == 99  # the computed data are kept
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and "RuntimeError: no display" in summary["reason"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary file left
    with pytest.raises(TypeError, match="plots must be None or a callable"):
        write_run(_result([{"level": 0, "ndof": 3}], []), tmp_path / "other", plots=True)
    assert not (tmp_path / "other").exists()


def test_read_history_keeps_names_and_numbers(tmp_path):
    """history.csv round trip: ints, floats, NaN (empty cell) and names (the multiplier candidate) as written."""
    from ngcontact.results import HISTORY_COLUMNS, read_history
    from ngcontact.results.files import csv_text

    rows = [{"level": 0, "ndof": 12, "multiplier": "shape", "multiplier_candidates": 2, "eta": 0.25},
            {"level": 1, "ndof": 30, "multiplier": "fit", "multiplier_candidates": 1, "eta": float("nan")}]
    (tmp_path / "history.csv").write_text(csv_text(rows, HISTORY_COLUMNS))
    back = read_history(tmp_path / "history.csv")
    assert [r["multiplier"] for r in back] == ["shape", "fit"]
    assert [r["multiplier_candidates"] for r in back] == [2, 1] and back[0]["eta"] == 0.25
    assert back[1]["eta"] != back[1]["eta"] and list(back[0]) == ["level", "ndof", "multiplier", "multiplier_candidates", "eta"]


def test_adaptive_speed_break_even():
    """The break-even cost per estimate: (wall(inexact) - (wall(adaptive) - estimating)) / estimates, per tag and
    degree; a CG pair whose adaptive run is slower even without its estimates gets a negative break-even."""
    from ngcontact.studies.adaptive_speed import break_even_lines

    def row(tag, mode, wall, est=0.0, n=0, order=1):
        return dict(tag=tag, order=order, mode=mode, fitted=True, nelem=100, wall_s=wall, time_estimate_s=est,
                    n_estimates=n)

    rows = [row("a", "inexact", 4.0), row("a", "adaptive", 10.0, est=6.0, n=20), row("b", "inexact", 4.0),
            row("a", "inexact-cg", 1.0), row("a", "adaptive-cg", 5.0, est=3.0, n=10), row("a", "direct", 2.0)]
    lines = break_even_lines(rows)
    body = [ln for ln in lines if ln.startswith("| a ")]
    assert body == ["| a | 1 | 100 fitted | adaptive | 20 | 0.300 | 0.000 | - |",
                    "| a | 1 | 100 fitted | adaptive-cg | 10 | 0.300 | -0.100 | - |"]
    rows[1]["wall_s"] = 9.0  # 3 s outside the estimates: break-even (4 - 3) / 20 = 0.05 s, cost 0.3 s: 6x
    assert "| a | 1 | 100 fitted | adaptive | 20 | 0.300 | 0.050 | 6.0 |" in break_even_lines(rows)
    assert break_even_lines([row("a", "inexact", 4.0)]) == []
