"""Run directories that survive: level-by-level writes, the manifest, safe replacement, VTK cell data,
figures that leave the caller's matplotlib alone, the git revision of installed copies."""
import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from ngcontact.results import MANIFEST, RunWriter, check_output_dir, read_history, write_run
from ngcontact.results.directory import OutputDir

from tests.test_results import _result

ROOT = Path(__file__).resolve().parent.parent


def _clean_env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT)
    env["NGCONTACT_THREADS"] = "1"
    return env


# ------------------------------------------------------------------ level by level
def test_writer_keeps_the_finished_levels_when_the_run_is_cut_short(tmp_path):
    res = _result([], [])
    w = RunWriter(tmp_path / "run", vtk=False)
    for level in range(2):
        res.iterations += [{"level": level, "k": k, "res": 10.0 ** -k} for k in range(3)]
        res.rows.append({"level": level, "ndof": 10 * 4 ** level})
        w.level(res)
        running = json.loads((w.path / "summary.json").read_text())
        assert running["complete"] is False and running["reason"].startswith("running or killed")
        assert [r["level"] for r in read_history(w.path / "history.csv")] == list(range(level + 1))
    res.iterations.append({"level": 2, "k": 0, "res": 1.0})  # level 2 started, then Ctrl-C
    assert w.abort("interrupted (Ctrl-C) during level 2") == w.path
    summary = json.loads((w.path / "summary.json").read_text())
    assert summary["complete"] is False and summary["reason"] == "interrupted (Ctrl-C) during level 2"
    assert summary["final"]["level"] == 1
    assert {r["level"] for r in read_history(w.path / "newton.csv")} == {0, 1}  # finished levels only
    assert set(json.loads((w.path / MANIFEST).read_text())["files"]) == {"history.csv", "newton.csv", "summary.json"}


def test_a_run_that_fails_before_its_first_level_leaves_the_previous_run(tmp_path):
    out = write_run(_result([{"level": 0, "ndof": 3}], []), tmp_path / "run", vtk=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    w = RunWriter(out, vtk=False)
    assert w.abort("bad data on the coarsest mesh") is None
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


# ------------------------------------------------------------------ replacement
def test_replacing_a_run_removes_only_its_files_and_refuses_a_users_file(tmp_path):
    out = write_run(_result([{"level": 0, "ndof": 3}], []), tmp_path / "run", vtk=False)
    (out / "my_analysis.csv").write_text("mine")  # looks like an output, was not written by the run
    with pytest.raises(ValueError, match="holds 'my_analysis.csv'.*did not write"):
        write_run(_result([{"level": 0, "ndof": 5}], []), out, vtk=False)
    assert (out / "my_analysis.csv").read_text() == "mine" and read_history(out / "history.csv")[0]["ndof"] == 3
    (out / "my_analysis.csv").unlink()
    (out / ".history.csv.ngcontact-tmp").write_text("half")  # a write interrupted by a kill
    write_run(_result([{"level": 0, "ndof": 5}], []), out, vtk=False)
    assert sorted(p.name for p in out.iterdir()) == ["history.csv", MANIFEST, "newton.csv", "summary.json"]


def test_run_directories_of_earlier_versions_are_replaced_by_their_fixed_names(tmp_path):
    old = tmp_path / "old"
    old.mkdir()
    for name in ("history.csv", "newton.csv", "summary.json", "convergence.png", "solution.vtu"):
        (old / name).write_text("x")
    write_run(_result([{"level": 0, "ndof": 3}], []), old, vtk=False)
    assert not (old / "convergence.png").exists() and (old / MANIFEST).is_file()
    (old / "results.json").write_text("x")
    os.remove(old / MANIFEST)
    with pytest.raises(ValueError, match="'results.json'"):
        check_output_dir(old)


def test_stale_staging_directories_are_removed_or_reported(tmp_path):
    ours = tmp_path / ".tmp-run-abc123"
    ours.mkdir()
    (ours / "history.csv").write_text("x")
    theirs = tmp_path / ".old-run-4242"
    theirs.mkdir()
    (theirs / "thesis.tex").write_text("precious")
    d = OutputDir(tmp_path / "run").start()
    assert not ours.exists() and (theirs / "thesis.tex").read_text() == "precious"
    assert any("removed .tmp-run-abc123" in n for n in d.notes)
    assert any(".old-run-4242" in n and "remove it yourself" in n for n in d.notes)


def test_demo_directory_follows_the_same_rule(tmp_path):
    demo = tmp_path / "demo"
    d = OutputDir(demo, "demo")
    for name in ("p1", "p2"):
        write_run(_result([{"level": 0, "ndof": 3}], []), d.register(name), vtk=False)
    d.write("convergence.png", b"png")
    check_output_dir(demo, kind="demo")  # a demo directory may be replaced
    (demo / "p1" / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="holds 'p1'"):
        check_output_dir(demo, kind="demo")
    (demo / "p1" / "notes.txt").unlink()
    (demo / "convergence.png").write_bytes(b"x")
    (demo / "paper.pdf").write_text("mine")
    with pytest.raises(ValueError, match="holds 'paper.pdf'"):
        check_output_dir(demo, kind="demo")


# ------------------------------------------------------------------ VTK
def test_eta_k_is_vtk_cell_data_and_the_series_lists_every_level(tmp_path):
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.results.vtk import read_vtu_arrays
    from ngcontact.scenes import load_scene

    scene = load_scene("test1")
    w = RunWriter(tmp_path / "run", vtk=True, vtk_series=True)
    res = run_scene(scene, RunOptions(order=2, levels=2, estimate=True), on_level=w.level)
    out = w.finish(res)
    arrays = read_vtu_arrays(out / "solution.vtu")
    types = arrays[("Cells", "types")]
    eta_k = np.asarray(res.estimate.eta_K)
    per_element = len(types) // len(eta_k)
    assert per_element * len(eta_k) == len(types) and per_element > 1  # P2: subdivided elements
    assert np.array_equal(arrays[("CellData", "eta_K")], np.repeat(eta_k, per_element))
    assert ("PointData", "eta_K") not in arrays and ("PointData", "gap") in arrays
    pvd = (out / "solution.pvd").read_text()
    assert 'timestep="0" file="solution_l0.vtu"' in pvd and 'timestep="1" file="solution_l1.vtu"' in pvd
    assert ("CellData", "eta_K") in read_vtu_arrays(out / "solution_l0.vtu")


# ------------------------------------------------------------------ library hygiene
def test_plotting_leaves_the_callers_matplotlib_alone(tmp_path):
    """Importing ngcontact.plotting and drawing a run's figures keeps the caller's backend and never imports
    pyplot (a notebook's inline backend stays)."""
    code = f"""
import matplotlib, sys
matplotlib.use("pdf")
from ngcontact.plotting import plot_run
from tests.test_results import _result
from ngcontact.results import write_run
out = write_run(_result([{{"level": l, "ndof": 10 * 4 ** l, "err_energy": 2.0 ** -l, "time_cum_s": 1.0 + l}}
                         for l in range(3)], [{{"level": 0, "k": 0, "res": 1.0}}]), {str(tmp_path / "run")!r}, vtk=False)
print(plot_run(out, 1), matplotlib.get_backend(), "matplotlib.pyplot" in sys.modules)
"""
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=_clean_env(), capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split()[-2:] == ["pdf", "False"], proc.stdout
    assert (tmp_path / "run" / "newton.png").read_bytes()[:4] == b"\x89PNG"


def test_git_revision_only_from_the_packages_own_repository(tmp_path):
    import shutil

    from ngcontact.results import git_revision

    assert git_revision()  # this checkout
    other = tmp_path / "another_repo"
    shutil.copytree(ROOT / "ngcontact", other / "vendored" / "ngcontact",
                    ignore=shutil.ignore_patterns("__pycache__"))
    subprocess.run(["git", "init", "-q", str(other)], check=True)
    (other / "pyproject.toml").write_text('[project]\nname = "something-else"\n')
    subprocess.run(["git", "-C", str(other), "add", "."], check=True)
    subprocess.run(["git", "-C", str(other), "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "x"],
                   check=True)
    env = _clean_env()
    env["PYTHONPATH"] = str(other / "vendored")
    proc = subprocess.run([sys.executable, "-c", "from ngcontact.results import git_revision; import ngcontact; "
                                                 "print(ngcontact.__file__, git_revision())"],
                          cwd=other, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    where, rev = proc.stdout.split()
    assert where.startswith(str(other)) and rev == "None"


def test_threads_from_the_api_and_the_environment(monkeypatch):
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.drivers.resources import configured_threads
    from ngcontact.scenes import load_scene

    scene = load_scene("test1")
    before = configured_threads()
    seen = []
    run_scene(scene, RunOptions(levels=1), on_level=lambda r: seen.append(configured_threads()), threads=3)
    monkeypatch.setenv("NGCONTACT_THREADS", "2")
    run_scene(scene, RunOptions(levels=1), on_level=lambda r: seen.append(configured_threads()))
    assert seen == [3, 2] and configured_threads() == before
    monkeypatch.setenv("NGCONTACT_THREADS", "many")
    with pytest.raises(ValueError, match="NGCONTACT_THREADS must be a positive integer, got 'many'"):
        run_scene(scene, RunOptions(levels=1))


def test_uniform_run_stops_at_its_dof_budget_before_building_the_level():
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.drivers.resources import next_level_ndof
    from ngcontact.scenes import load_scene

    res = run_scene(load_scene("test1"), RunOptions(levels=6, max_ndof=2000))
    assert [r["ndof"] for r in res.rows] == [75, 339, 1443]
    assert next_level_ndof(res.rows) > 2000 >= 1443
    assert res.complete is False and res.stop_reason.startswith("max_ndof: level 3 would have about")


# ------------------------------------------------------------------ figures
def test_solution_figure_has_titles_axes_colour_bars_and_the_contact_boundary():
    from ngcontact.discretizations.fem import FEMDiscretization
    from ngcontact.newton import NewtonOptions, semismooth_newton
    from ngcontact.plotting import solution_figure
    from ngcontact.scenes import load_scene

    scene = load_scene("test1")
    disc = FEMDiscretization(scene.problem, scene.problem.domain.mesh(1), order=1)
    sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
    fig = solution_figure(disc, sol.x, sol.y, title="test1 FEM P1")
    fields, bars = fig.axes[:2], fig.axes[2:]
    assert len(bars) == 2 and all(b.get_ylabel() for b in bars)  # one labelled colour bar per field
    assert [a.get_xlabel() for a in fields] == ["x", "x"] and all(a.get_title() for a in fields)
    assert "gap" in fields[0].get_title() and "lambda" in fields[1].get_title()
    assert fields[0].get_legend().get_texts()[0].get_text() == "boundary of the contact set"
    assert not [ln for ln in fields[0].lines if ln.get_marker() not in (None, "None", "")]  # no markers over the field
    assert fig._suptitle.get_text().startswith("test1 FEM P1")


def test_solution_figure_of_a_large_mesh_is_drawn_on_a_grid(monkeypatch):
    """Above MAX_PLOT_TRIANGLES the fields are sampled on a regular grid (matplotlib renders 1e6 triangles
    in minutes): same contact boundary as the triangle plot, values of the discrete fields at the grid points."""
    import ngcontact.plotting as plotting
    from matplotlib.collections import QuadMesh
    from ngcontact.discretizations.fem import FEMDiscretization
    from ngcontact.newton import NewtonOptions, semismooth_newton
    from ngcontact.scenes import load_scene

    scene = load_scene("test1")
    disc = FEMDiscretization(scene.problem, scene.problem.domain.mesh(2), order=1)
    sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
    monkeypatch.setattr(plotting, "MAX_PLOT_TRIANGLES", 100)
    monkeypatch.setattr(plotting, "GRID_POINTS", 41)
    fig = plotting.solution_figure(disc, sol.x, sol.y, title="large")
    fields = fig.axes[:2]
    meshes = [c for c in fields[0].collections if isinstance(c, QuadMesh)]
    assert meshes and "grid" in fig._suptitle.get_text()
    assert fields[0].get_legend().get_texts()[0].get_text() == "boundary of the contact set"
    gap = np.asarray(meshes[0].get_array()).reshape(41, 41)
    gfs = disc.gridfunctions(sol.x, sol.y)
    mesh = disc.mesh
    assert gap[20, 20] == pytest.approx(gfs["gap"](mesh(0.5, 0.5)), abs=1e-12)  # the centre of the unit square
    contact = disc.contact_points(sol.x, sol.y)
    coords = np.array(mesh.ngmesh.Coordinates())[:, :2]
    ind = plotting._contact_vertices(coords, contact)
    assert ind.sum() == len(contact) and set(np.unique(ind)) <= {0.0, 1.0}


def test_newton_plot_colours_are_distinct_for_many_levels(tmp_path):
    from ngcontact.plotting import level_colors, plot_run

    colours = level_colors(25)
    assert len(set(colours)) == 25
    its = [{"level": lv, "k": k, "res": 10.0 ** -k} for lv in range(25) for k in range(3)]
    out = write_run(_result([{"level": 0, "ndof": 3}], its), tmp_path / "run", vtk=False)
    assert "newton.png" in plot_run(out, 1)


def test_plot_draws_eta_without_an_exact_solution_and_refuses_without_either(tmp_path, capsys):
    from ngcontact.cli import main
    from tests.test_cli import USER_SCENE

    scene = tmp_path / "my_scene.py"
    scene.write_text(USER_SCENE)
    est, plain = tmp_path / "est", tmp_path / "plain"
    for out, extra in ((est, ["--estimate"]), (plain, [])):
        assert main(["run", str(scene), "--levels", "2", "--out", str(out), "-q", "--no-vtk", "--no-plots",
                     *extra]) == 0
    capsys.readouterr()
    png = tmp_path / "cmp.png"
    assert main(["plot", str(est), "--out", str(png)]) == 0
    assert "has no exact solution: its curve is the estimator eta" in capsys.readouterr().err
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert main(["plot", str(plain), "--out", str(tmp_path / "none.png")]) == 2
    err = capsys.readouterr().err
    assert "no energy error" in err and "--estimate" in err and not (tmp_path / "none.png").exists()


def test_legends_name_the_scene_and_the_method():
    from ngcontact.plotting import run_label

    assert run_label({"scene": "disk", "options": {"disc": "fem", "order": 2, "adaptive": True}}) == "disk FEM P2 adaptive"
    assert run_label(SimpleNamespace(**{}).__dict__) == "? ? P?"


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc")
@pytest.mark.parametrize("args, kind", [(["--order", "4", "--levels", "3"], "solve"),
                                        (["--order", "2", "--levels", "4", "--estimate"], "estimate")])
def test_peak_memory_per_dof_is_below_the_budgets_bytes_per_dof(args, kind, tmp_path):
    """The DOF budget's BYTES_PER_DOF bound the peak memory per DOF (above the interpreter's) of a run."""
    from ngcontact.drivers.resources import BYTES_PER_DOF

    out = tmp_path / "m"
    # VmHWM: the peak of this process image (ru_maxrss would carry the forking pytest process's peak over exec)
    code = ("import sys; import ngcontact.cli, ngcontact.drivers, ngcontact.plotting, ngcontact.estimators; "
            "hwm = lambda: [ln.split()[1] for ln in open('/proc/self/status') if ln.startswith('VmHWM')][0]; "
            "base = hwm(); assert ngcontact.cli.main(sys.argv[1:]) == 0; print(base, hwm())")
    proc = subprocess.run([sys.executable, "-c", code, "run", "test1", *args, "--no-vtk", "--no-plots", "-q",
                           "--max-ndof", "10000000", "--out", str(out)],
                          env=_clean_env(), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    base, peak = map(int, proc.stdout.split()[-2:])
    ndof = read_history(out / "history.csv")[-1]["ndof"]
    per_dof = (peak - base) * 1024 / ndof  # VmHWM in kB
    assert 0 < per_dof < BYTES_PER_DOF[kind], per_dof
