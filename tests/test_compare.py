"""The discretization comparison report (issue 3 study) and the new run options."""
import csv
import math

import pytest

from ngcontact.cli import main
from ngcontact.studies.compare import time_to_error, write_report


def test_time_to_error_interpolates_log_log():
    rows = [{"err_energy": 1e-2, "time_cum_s": 1.0}, {"err_energy": 1e-4, "time_cum_s": 100.0}]
    assert time_to_error(rows, 1e-3) == pytest.approx(10.0)  # halfway in log-log
    assert time_to_error(rows, 1e-2) == pytest.approx(1.0)
    assert math.isnan(time_to_error(rows, 1e-5))


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
