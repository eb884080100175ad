"""The discretization comparison report, the time-to-accuracy rule of the study tables, and the
--disc / --no-condense run options."""
import csv
import math

import pytest

from ngcontact.cli import main
from ngcontact.studies.compare import write_report
from ngcontact.studies.tables import time_to_reach


def test_time_to_reach_interpolates_log_log_between_the_bracketing_levels():
    times, errors = [1.0, 10.0, 100.0, 400.0], [1e-1, 1e-2, 1e-4, 1e-5]
    assert time_to_reach(times, errors, 1e-3) == pytest.approx(31.6227766)  # halfway in log-log, levels 1-2
    assert time_to_reach(times, errors, 1e-2) == pytest.approx(10.0)  # reached on a level: its time
    assert time_to_reach(times, errors, 1.0) == 1.0  # the first level is already below
    assert math.isnan(time_to_reach(times, errors, 1e-6))  # never reached: no extrapolation
    assert time_to_reach([0.0, 5.0], [1e-1, 1e-3], 1e-2) == 5.0  # no logarithm of t = 0: the level's time


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("cmp")
    spec = {"test1-fem-p1-nested": ["--disc", "fem"], "test1-hho-p1-nested": ["--disc", "hho"],
            "test1-hho-p1-nested-nosc": ["--disc", "hho", "--no-condense"],
            "test1-sipg-p1-nested": ["--disc", "sipg"], "test1-fem-p1-cold": ["--disc", "fem", "--start", "cold"],
            "test1-hho-p1-cold": ["--disc", "hho", "--start", "cold"]}
    for name, extra in spec.items():
        assert main(["run", "test1", "--order", "1", "--levels", "3", "--no-vtk", "--no-plots", "-q",
                     "--out", str(base / name), *extra]) == 0
    return base, sorted(base.iterdir())


def test_report_is_computed_from_the_runs(runs, tmp_path):
    base, dirs = runs
    md = write_report(tmp_path / "rep", dirs).read_text()
    rows = list(csv.DictReader(open(tmp_path / "rep" / "all.csv")))
    assert len(rows) == 6 * 3
    assert {r["method"] for r in rows} == {"FEM", "HHO", "HHO noSC", "SIPG"}
    # condensed and full HHO solve the same discrete problem: same errors, smaller system with SC
    sc = [r for r in rows if r["method"] == "HHO" and r["start"] == "nested"]
    full = [r for r in rows if r["method"] == "HHO noSC"]
    for a, b in zip(sc, full):
        assert float(a["err_energy"]) == pytest.approx(float(b["err_energy"]), rel=1e-8)
        assert int(a["linear_size"]) == int(a["ndof_sc"]) < int(b["linear_size"])
    # the finest-level FEM error in the table is the one in all.csv
    fem = [r for r in rows if r["method"] == "FEM" and r["start"] == "nested"][-1]
    assert f"{float(fem['err_energy']):.3e}" in md
    assert "Ratio FEM / HHO" in md and (tmp_path / "rep" / "test1.png").is_file()
    assert (tmp_path / "rep" / "newton_cold.png").is_file()


def test_no_condense_and_estimate_options_validated(tmp_path, capsys):
    assert main(["run", "test1", "--disc", "hho", "--estimate", "--levels", "1", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "estimate" in err and "hho" in err and not (tmp_path / "x").exists()
    assert main(["run", "test1", "--disc", "nope"]) == 2
    assert "--disc" in capsys.readouterr().err
