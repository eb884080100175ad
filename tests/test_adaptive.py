"""Adaptive refinement: marking (pure functions), the solve-estimate-mark-refine loop,
prolongation to bisected meshes, CLI options."""
import csv
import itertools
import json

import numpy as np
import pytest
from ngsolve import grad

from ngcontact.drivers.adaptive import interior_nodes, refine
from ngcontact.cli import main
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.marking import doerfler, mark, maximum
from ngcontact.newton import NewtonOptions, semismooth_newton
from ngcontact.drivers import RunOptions, run_scene
from ngcontact.scenes import load_scene


# ------------------------------------------------------------------ marking
@pytest.mark.parametrize("theta", [0.1, 0.3, 0.5, 0.8, 1.0])
def test_doerfler_minimal_set_covering_theta(theta):
    rng = np.random.default_rng(7)
    for trial in range(20):
        eta = rng.random(9) ** 3
        if trial % 4 == 0:
            eta[rng.integers(0, 9, 3)] = 0.0  # zeros and ties
        M = doerfler(eta, theta)
        total = (eta ** 2).sum()
        assert len(set(M.tolist())) == len(M)
        assert (eta[M] ** 2).sum() >= theta * total * (1 - 1e-12)  # bulk criterion
        # minimal cardinality: no subset with one element fewer reaches theta (brute force)
        k = len(M)
        if k > 1:
            best = max((eta[list(c)] ** 2).sum() for c in itertools.combinations(range(9), k - 1))
            assert best < theta * total


def test_doerfler_and_maximum_examples():
    eta = np.array([1.0, 3.0, 2.0, 0.5])
    assert doerfler(eta, 0.5).tolist() == [1]            # 9 >= 0.5 * 14.25
    assert doerfler(eta, 0.9).tolist() == [1, 2]          # 13 >= 12.825 > 9
    assert sorted(doerfler(eta, 1.0).tolist()) == [0, 1, 2, 3]
    assert maximum(eta, 0.5).tolist() == [1, 2]           # eta_K >= 1.5
    assert maximum(eta, 1.0).tolist() == [1]
    assert doerfler(np.zeros(5), 0.5).size == 0 and maximum(np.zeros(5), 0.5).size == 0
    assert mark(eta, 0.5, "max").tolist() == [1, 2]


@pytest.mark.parametrize("bad", [0.0, -0.1, 1.5, float("nan"), True])
def test_marking_rejects_bad_theta(bad):
    with pytest.raises(ValueError, match="theta"):
        doerfler([1.0, 2.0], bad)
    with pytest.raises(ValueError, match="theta"):
        maximum([1.0, 2.0], bad)


def test_marking_rejects_bad_indicators_and_strategy():
    with pytest.raises(ValueError, match="eta_K"):
        doerfler([1.0, -2.0], 0.5)
    with pytest.raises(ValueError, match="option marking"):
        mark([1.0], 0.5, "greedy")


# -------------------------------------------------------------- refinement
def _solve(problem, mesh, order):
    disc = FEMDiscretization(problem, mesh, order=order)
    x0, y0 = disc.initial_guess()
    sol = semismooth_newton(disc.system, x0, y0, NewtonOptions())
    assert sol.converged
    return disc, sol


def _centroids(mesh):
    P = np.array(mesh.ngmesh.Coordinates())[mesh.ngmesh.Elements2D().NumPy()["nodes"][:, :3] - 1]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return P.mean(axis=1), area, P


def test_refine_bisects_marked_elements_and_keeps_the_old_mesh():
    mesh = load_scene("point_load").problem.domain.mesh(0)
    ne = mesh.ne
    marked = np.array([3, 17, 40])
    new = refine(mesh, marked)
    assert mesh.ne == ne and new.ne > ne  # the old mesh is untouched
    c_new, a_new, _ = _centroids(new)
    _, a_old, P_old = _centroids(mesh)
    for k in marked:  # every child of a marked element has at most half its area
        a, b, c = P_old[k]
        T = np.column_stack([b - a, c - a])
        lam = np.linalg.solve(T, (c_new - a).T).T
        inside = (lam >= -1e-12).all(axis=1) & (lam.sum(axis=1) <= 1 + 1e-12)
        assert inside.any() and np.all(a_new[inside] <= a_old[k] / 2 + 1e-14)
    assert np.isclose(a_new.sum(), a_old.sum())
    assert interior_nodes(new, 2) == FEMDiscretization(load_scene("point_load").problem, new, order=2).n_interior


@pytest.mark.parametrize("order", [1, 2, 3])
def test_prolongation_to_bisected_mesh_reproduces_discrete_solution(order):
    """Nested spaces (bisection of straight triangles): u_h is reproduced exactly on the new mesh."""
    problem = load_scene("point_load").problem
    disc, sol = _solve(problem, problem.domain.mesh(0), order)
    rng = np.random.default_rng(order)
    new = refine(disc.mesh, rng.choice(disc.mesh.ne, size=disc.mesh.ne // 3, replace=False))
    disc2 = FEMDiscretization(problem, new, order=order)
    x0, y0 = disc2.prolongate(disc, sol.x, sol.y)
    old, newf = disc.gridfunctions(sol.x, sol.y), disc2.gridfunctions(x0, y0)
    pts = rng.random((400, 2))  # each function evaluated on its own mesh
    mp_old, mp_new = disc.mesh(pts[:, 0], pts[:, 1]), new(pts[:, 0], pts[:, 1])
    names = ["u1", "u2"] + (["lam"] if order == 1 else [])  # p = 1: lumped multiplier, nodal values
    for name in names:
        a, b = np.asarray(old[name](mp_old)).ravel(), np.asarray(newf[name](mp_new)).ravel()
        ga, gb = np.asarray(grad(old[name])(mp_old)), np.asarray(grad(newf[name])(mp_new))
        scale = max(np.abs(a).max(), 1e-3)
        assert np.abs(a - b).max() <= 1e-12 * scale * 10, name
        assert np.abs(ga - gb).max() <= 1e-10 * max(np.abs(ga).max(), 1e-3), name
    assert np.abs(old["u1"](mp_old)).max() > 1e-3  # a non-trivial solution


# ------------------------------------------------------------- the loop
def test_adaptive_loop_refines_where_eta_is_large_and_eta_decreases():
    scene = load_scene("lshape")
    res = run_scene(scene, RunOptions(order=1, adaptive=True, theta=0.5, max_levels=5))
    rows = res.rows
    assert len(rows) == 5 and res.converged and res.stop_reason.startswith("max_levels")
    eta = np.array([r["eta"] for r in rows])
    assert np.all(np.diff(eta) < 0)
    assert all(r["marked"] > 0 for r in rows[1:]) and rows[0]["marked"] == 0
    assert np.all(np.diff([r["ndof"] for r in rows]) > 0)
    assert np.all(np.diff([r["time_cum_s"] for r in rows]) > 0)
    # the re-entrant corner carries the largest indicators: the smallest elements touch it
    c, area, P = _centroids(res.discretization.mesh)
    dist = np.linalg.norm(P, axis=-1).min(axis=1)  # distance of each element to the corner
    c0, area0, P0 = _centroids(scene.problem.domain.mesh(0))
    corner0 = area0[np.linalg.norm(P0, axis=-1).min(axis=1) < 1e-12]
    assert area[dist < 1e-12].max() <= corner0.min() / 8  # corner elements bisected >= 3 times
    assert np.all(dist[np.argsort(area)[:10]] < 0.05)  # the smallest elements sit at the corner
    assert area.max() > 100 * area.min()  # and the refinement is local
    # the final estimate's largest indicators stay next to the corner or the contact zone
    assert np.linalg.norm(c[np.argmax(res.estimate.eta_K)]) < 0.2


def test_adaptive_loop_stops_on_budgets():
    scene = load_scene("point_load")
    res = run_scene(scene, RunOptions(order=1, adaptive=True, max_ndof=400))
    assert res.stop_reason.startswith("max_ndof") and all(r["ndof"] <= 400 for r in res.rows)
    assert len(res.rows) >= 3
    target = res.rows[1]["eta"] * 1.0001
    res2 = run_scene(scene, RunOptions(order=1, adaptive=True, target_eta=target))
    assert res2.stop_reason.startswith("target_eta") and len(res2.rows) == 2
    assert res2.rows[-1]["eta"] <= target < res2.rows[-2]["eta"]


# ------------------------------------------------------------- options/CLI
@pytest.mark.parametrize("kw, field", [(dict(theta=0.0), "theta"), (dict(theta=1.2), "theta"),
                                       (dict(marking="greedy"), "marking"), (dict(max_ndof=0), "max_ndof"),
                                       (dict(target_eta=-1.0), "target_eta"), (dict(max_time=0), "max_time"),
                                       (dict(max_levels=0), "max_levels"), (dict(disc="sipg"), "adaptive")])
def test_run_options_validate_adaptive_fields(kw, field):
    with pytest.raises(ValueError, match=f"option {field} "):
        RunOptions(adaptive=True, **kw)


@pytest.mark.parametrize("args, words", [(["--adaptive", "--theta", "1.5"], "theta"),
                                         (["--theta", "0.3"], "--theta need --adaptive"),
                                         (["--max-ndof", "0"], "option --max-ndof"),  # uniform runs: a budget too
                                         (["--adaptive", "--max-ndof", "-3"], "option --max-ndof"),
                                         (["--adaptive", "--disc", "hho"], "option --adaptive"),
                                         (["--adaptive", "--marking", "bulk"], "--marking")])
def test_cli_rejects_bad_adaptive_options(tmp_path, capsys, args, words):
    out = tmp_path / "never"
    assert main(["run", "point_load", *args, "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ngcontact: error:") and words in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_adaptive_run_writes_levels(tmp_path):
    out = tmp_path / "ad"
    assert main(["run", "point_load", "--adaptive", "--max-levels", "2", "--theta", "0.6", "--no-vtk",
                 "-q", "--out", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "history.csv")))
    assert [int(r["level"]) for r in rows] == [0, 1]
    for col in ("marked", "eta", "time_mesh_s", "time_assembly_s", "time_solve_s", "time_estimate_s",
                "time_mark_s", "time_cum_s"):
        assert col in rows[0], col
    s = json.loads((out / "summary.json").read_text())
    assert s["options"]["adaptive"] is True and s["options"]["theta"] == 0.6
    assert s["stop_reason"].startswith("max_levels")
    assert (out / "mesh.png").is_file()


# ------------------------------------------------------------- multiplier candidates
def _est(kept, etas):
    """A stand-in for an Estimate that chose between two candidates (eta: the kept one's bound)."""
    from types import SimpleNamespace

    return SimpleNamespace(multiplier=kept, eta=etas[kept], eta_candidates=dict(etas))


def test_candidate_schedule_skips_a_clear_loser_and_rechecks():
    """CandidateSchedule: after two levels where the same candidate won by more than the ratio, the next levels
    compute that one only, both again on every fourth level; a close second, a change of the winner or a
    candidate chosen by the user: both (or the user's) on every level."""
    from types import SimpleNamespace

    from ngcontact.drivers.adaptive import CandidateSchedule
    from ngcontact.estimators import EstimatorOptions

    opts = EstimatorOptions()
    s = CandidateSchedule(ratio=1.5, after=2, recheck=4)
    forced = []
    for _ in range(12):
        o = s.options(opts)
        forced.append(o.multiplier)
        s.record(_est("shape", {"fit": 3.0, "shape": 1.0}) if o.multiplier is None
                 else SimpleNamespace(multiplier="shape", eta=1.0, eta_candidates={}))
    assert forced == [None, None, "shape", "shape", "shape", None, "shape", "shape", "shape", None, "shape", "shape"]
    assert all(o is None or isinstance(o, str) for o in forced)
    for ests in ([_est("shape", {"fit": 1.4, "shape": 1.0})] * 3,
                 [_est("shape", {"fit": 3.0, "shape": 1.0}), _est("fit", {"fit": 1.0, "shape": 3.0})]):
        s = CandidateSchedule()
        for e in ests:
            s.record(e)
        assert s.options(opts) is opts
    s = CandidateSchedule()
    for _ in range(3):
        s.record(_est("shape", {"fit": 3.0, "shape": 1.0}))
    assert s.options(opts).multiplier == "shape"
    user = EstimatorOptions(multiplier="fit")
    assert s.options(user) is user


def test_adaptive_run_with_skipped_candidates_keeps_the_bounds(monkeypatch):
    """The adaptive L-shape P3 run (the "fit" bound loses by a wide margin from the eighth level on): the levels
    where the schedule computes one candidate report the same eta, level by level, as the run that computes
    both on every level (history columns multiplier / multiplier_candidates say which)."""
    import ngcontact.drivers.adaptive as adaptive

    scene = load_scene("lshape")
    opts = RunOptions(order=3, adaptive=True, theta=0.5, max_levels=11, decouple=True)
    res = run_scene(scene, opts)
    cands = [r["multiplier_candidates"] for r in res.rows]
    assert cands.count(1) >= 2 and cands[:2] == [2, 2] and all(r["multiplier"] == "shape" for r in res.rows)
    schedule = adaptive.CandidateSchedule
    monkeypatch.setattr(adaptive, "CandidateSchedule", lambda: schedule(ratio=float("inf")))
    full = run_scene(scene, opts)
    assert [r["multiplier_candidates"] for r in full.rows] == [2] * len(full.rows)
    assert [r["ndof"] for r in full.rows] == [r["ndof"] for r in res.rows]
    # equal up to the round-off of NGSolve's threaded integration (sums in a varying order; two runs of the same
    # estimate differ by ~1e-16 relative)
    assert [r["eta"] for r in full.rows] == pytest.approx([r["eta"] for r in res.rows], rel=1e-12, abs=0)
