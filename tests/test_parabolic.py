"""The parabolic two-membrane problem: data checks, backward Euler steps, scenes, the manufactured solution,
factorization reuse across steps, the space-time bound."""
import json
import math

import numpy as np
import pytest
from ngsolve import Parameter, sin

from ngcontact import CrissCrossSquare, TwoMembraneProblem
from ngcontact.problems import ParabolicProblem, ProblemDataError
from ngcontact.scenes import load_scene
from ngcontact.timestepping.driver import ParabolicOptions, run_parabolic
from ngcontact.timestepping.euler import BackwardEuler
from ngcontact.timestepping.run import run_parabolic_scene, write_parabolic_run


def _stat(**kw):
    return TwoMembraneProblem(domain=CrissCrossSquare(n0=2), f1=-1.0, f2=1.0, **kw)


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize("kw, words", [
    (dict(t_final=-1.0), ["t_final", "-1.0"]),
    (dict(t_final=0.0), ["t_final", "0.0"]),
    (dict(u0=(1.0,)), ["u0", "(1.0,)"]),
    (dict(u0=(0.0, "a")), ["u0[1]", "str"]),
    (dict(time=0.3), ["time", "float"]),
])
def test_parabolic_problem_errors_name_field_and_value(kw, words):
    with pytest.raises(ProblemDataError) as e:
        ParabolicProblem(_stat(), **kw)
    for w in words:
        assert w in str(e.value)


def test_initial_order_checked_on_the_nodes():
    P = ParabolicProblem(_stat(), u0=(0.0, 0.1), t_final=1.0)
    with pytest.raises(ProblemDataError, match=r"u1\^0 < u2\^0.*-1.000e-01"):
        BackwardEuler(P, P.domain.mesh(0))


def test_time_dependent_dirichlet_data_rejected():
    t = Parameter(0.0)
    P = ParabolicProblem(_stat(g1=1.0 + t), u0=(1.0, 0.0), t_final=1.0, time=t)
    with pytest.raises(ProblemDataError, match="g1 depends on the time parameter"):
        BackwardEuler(P, P.domain.mesh(0))


@pytest.mark.parametrize("kw, words", [(dict(dt=-1), ["dt", "-1"]), (dict(newton="x"), ["newton", "'x'"]),
                                       (dict(t_final=0), ["t_final", "0"])])
def test_options_errors(kw, words):
    with pytest.raises(ValueError) as e:
        ParabolicOptions(**kw)
    for w in words:
        assert w in str(e.value)


# ------------------------------------------------------------------ the manufactured solution
def test_manufactured_solution_solves_the_pde_and_complementarity():
    """Finite differences (independent of the symbolic Diff that built f) of the exact solution."""
    sc = load_scene("parabolic_manufactured")
    P = sc.problem
    ex, st, mesh = P.exact, P.stationary, P.domain.mesh(2)
    rng = np.random.default_rng(1)
    pts = rng.uniform(0.05, 0.95, size=(40, 2))
    h, k = 1e-4, 1e-5

    def val(cf, px, py, t):
        P.time.Set(t)
        return cf(mesh(px, py))

    worst = 0.0
    for t in (0.1, 0.3):
        for px, py in pts:
            lam = val(ex.lam, px, py, t)
            gap = val(ex.u1, px, py, t) - val(ex.u2, px, py, t)
            assert gap >= -1e-14 and lam >= 0 and abs(gap * lam) < 1e-14
            for u, f, s in ((ex.u1, st.f1, 1), (ex.u2, st.f2, -1)):
                dt_u = (val(u, px, py, t + k) - val(u, px, py, t - k)) / (2 * k)
                lap = (val(u, px + h, py, t) + val(u, px - h, py, t) + val(u, px, py + h, t) + val(u, px, py - h, t)
                       - 4 * val(u, px, py, t)) / h ** 2
                worst = max(worst, abs(dt_u - lap - s * lam - val(f, px, py, t)))
    assert worst < 1e-4  # FD truncation O(h^2 u'''') + rounding O(eps/h^2)
    assert (np.array([val(ex.lam, px, py, 0.3) for px, py in pts]) > 0).any()  # a contact zone exists


# ------------------------------------------------------------------ steps, reuse, bound
def test_factorizations_reused_across_steps():
    sc = load_scene("parabolic_disk")
    r = run_parabolic(sc.problem, sc.problem.domain.mesh(0), ParabolicOptions(dt=0.02))
    fact = sum(row["factorizations"] for row in r.rows)
    newton = sum(row["newton_its"] for row in r.rows)
    assert len(r.rows) == 15 and r.converged
    assert fact <= 3 < newton  # one factorization of E, PCG for the later active sets
    assert r.summary["factorizations_total"] == fact


def test_disk_contact_onset_and_stationary_limit():
    sc = load_scene("parabolic_disk")
    r, _, _ = run_parabolic_scene(sc, dict(sc.test_options))
    s = r.summary
    assert 0.1 < s["onset_disk"] < 0.2
    assert all(row["gap_min"] >= -1e-12 for row in r.rows)
    # u_h(t) approaches the stationary discrete solution: at T = 0.3 the remaining transient is below the
    # stationary discretization error, and the distance to the exact stationary solution at most their sum
    assert s["dist_stationary_discrete_T"] < s["err_stationary_discrete"]
    assert s["dist_stationary_T"] <= s["err_stationary_discrete"] + s["dist_stationary_discrete_T"] + 1e-12
    assert s["dist_stationary_T"] > s["err_stationary_discrete"]  # t = 0.3 is not yet the steady state


def test_space_time_bound_on_manufactured_solution(tmp_path):
    sc = load_scene("parabolic_manufactured")
    r, opts, mesh_opts = run_parabolic_scene(sc, dict(dt=0.05, t_final=0.1, level=0, estimate=True))
    s = r.summary
    assert s["bound_proven"], s["bound_not_proven_because"]
    assert s["eta_st"] >= s["err_spacetime"] > 0
    assert s["i_eff"] == pytest.approx(s["eta_st"] / s["err_spacetime"])
    path = write_parabolic_run(tmp_path / "run", sc, r, opts, mesh_opts, plots=False)
    summ = json.loads((path / "summary.json").read_text())
    assert summ["steps"] == 2 and math.isclose(summ["eta_st"], s["eta_st"])
    assert (path / "steps.csv").read_text().count("\n") == 3


@pytest.mark.parametrize("newton, cfun", [("inexact", "min"), pytest.param("adaptive", "fb", marks=pytest.mark.slow)])
def test_rings_short_run_krylov(newton, cfun):
    sc = load_scene("parabolic_rings")
    r, _, _ = run_parabolic_scene(sc, dict(sc.test_options, t_final=0.03, newton=newton, cfun=cfun))
    assert r.converged and len(r.rows) == 3
    assert r.summary["gmres_total"] > 0
    # one preconditioner per distinct reduced matrix: step 1's last matrix serves step 2's first iteration
    assert r.summary["preconditioners_reused"] > 0
    assert r.summary["preconditioners_built"] + r.summary["preconditioners_reused"] == r.summary["newton_total"]
    assert r.rows[-1]["active_disk"] > 0 and r.rows[-1]["active_ring"] == 0


def test_rings_short_run_cg_algebraic_multigrid():
    """--krylov cg: CG + algebraic multigrid in the Krylov modes, the same solution as the direct steps."""
    sc = load_scene("parabolic_rings")
    d, _, _ = run_parabolic_scene(sc, dict(sc.test_options, t_final=0.03))
    r, _, _ = run_parabolic_scene(sc, dict(sc.test_options, t_final=0.03, newton="gmres", krylov="cg"))
    g, _, _ = run_parabolic_scene(sc, dict(sc.test_options, t_final=0.03, newton="gmres"))
    assert r.converged and r.summary["gmres_total"] > 0
    assert r.summary["gmres_total"] != g.summary["gmres_total"]  # another Krylov method did the steps
    K = d.stepper.K
    diff = r.x - d.x
    assert float(np.sqrt(diff @ (K @ diff))) <= 1e-9 * float(np.sqrt(d.x @ (K @ d.x)))
    with pytest.raises(ValueError, match="option krylov"):
        ParabolicOptions(krylov="cg")


@pytest.mark.slow
def test_adaptive_dt_takes_fewer_steps():
    sc = load_scene("parabolic_disk")
    opts = ParabolicOptions(dt=0.01, t_final=0.3, adaptive_dt=True)
    r = run_parabolic(sc.problem, sc.problem.domain.mesh(0), opts)
    assert r.converged and abs(r.summary["t_final"] - 0.3) < 1e-12
    assert len(r.rows) < 30


# ------------------------------------------------------------------ command line
def test_cli_time_dependent_run(tmp_path, capsys):
    from ngcontact.cli import main

    out = tmp_path / "run"
    assert main(["run", "parabolic_disk", "--test", "--t-final", "0.1", "-q", "--vtk-every", "2",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "5 steps to t = 0.1" in text
    for name in ("steps.csv", "summary.json", "contact_spacetime.csv", "solution.pvd", "contact_area.png",
                 "contact_spacetime.png", "estimators_t.png", "iterations_t.png"):
        assert (out / name).is_file(), name
    assert (out / "solution.pvd").read_text().count("<DataSet") == 3  # steps 2, 4 and the last


@pytest.mark.parametrize("args, msg", [
    (["run", "parabolic_disk", "--dt", "-1"], "option --dt must be > 0, got -1.0"),
    (["run", "parabolic_disk", "--levels", "2"], "--levels do not apply to the time-dependent scene"),
    (["run", "disk", "--dt", "0.1"], "--dt need a time-dependent scene"),
])
def test_cli_time_dependent_usage_errors(args, msg, capsys, tmp_path):
    from ngcontact.cli import main

    assert main([*args, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert msg in err and len(err.strip().splitlines()) == 1


def test_manufactured_refinement_in_h_and_dt_keeps_effectivity():
    """The study's refinement (ngcontact.studies.parabolic.MMS_H: dt0 / 2^(p l) on level l), P1, two levels:
    the space-time error halves and the estimate stays a bound within 1.5 of it."""
    from ngcontact.studies.parabolic import MMS_H, _run
    from ngcontact.timestepping.run import scene_mesh

    sc = load_scene("parabolic_manufactured")
    dt0, _ = MMS_H[1]
    s = [_run(sc, scene_mesh(sc, {"level": lev}), order=1, dt=dt0 / 2 ** lev, t_final=0.04, estimate=True)[1]
         for lev in (0, 1)]
    assert all(r["bound_proven"] and 1.0 <= r["i_eff"] <= 1.5 for r in s), [r["i_eff"] for r in s]
    assert 1.8 < s[0]["err_spacetime"] / s[1]["err_spacetime"] < 2.2


def test_preconditioner_cache_reuses_only_identical_matrices():
    import scipy.sparse as sp

    from ngcontact.algebra.krylov import PreconditionerCache

    A = sp.diags([2.0, 3.0, 4.0]).tocsr()
    cache, built = PreconditionerCache(size=2), []
    M1, r1 = cache.get(A, lambda: built.append(1) or "M1")
    M2, r2 = cache.get(A.copy(), lambda: built.append(2) or "M2")
    assert (M1, r1, M2, r2) == ("M1", False, "M1", True)
    B = A.copy()
    B.data[1] = 3.0 + 1e-15  # one value changed in the last bits
    assert cache.get(B, lambda: "MB") == ("MB", False)
    assert cache.get(A, lambda: "M3", extra=[0, 2]) == ("M3", False)  # other kept unknowns
    assert cache.get(A, lambda: "M4") == ("M4", False)  # size 2: the first entry was dropped
    assert (cache.hits, cache.misses) == (1, 4)


def test_disk_onset_matches_the_radial_problem():
    """Test 6.1: the FEM contact onset (level 1, dt = 1e-3) against the onset of the radial heat equation
    of w = u1 - u2 solved by finite differences (ngcontact.studies.parabolic.disk_onset_radial)."""
    from ngcontact.studies.parabolic import disk_onset_radial

    t_star, r_star = disk_onset_radial(n=1000, dt=1e-4)
    assert 0.17 < t_star < 0.175 and 0.5 < r_star < 0.65
    sc = load_scene("parabolic_disk")
    r, _, _ = run_parabolic_scene(sc, dict(dt=1e-3, t_final=0.18, level=1))
    assert abs(r.summary["onset_disk"] - t_star) <= 2e-3  # one step of 1e-3 plus the spatial error


def test_cli_adaptive_dt_flags(tmp_path, capsys):
    from ngcontact.cli import main

    assert main(["run", "parabolic_disk", "--test", "--dt-rule", "balance", "--out", str(tmp_path / "a")]) == 2
    assert "need --adaptive-dt" in capsys.readouterr().err
    assert main(["run", "parabolic_disk", "--test", "--adaptive-dt", "--dt-safety", "-1",
                 "--out", str(tmp_path / "b")]) == 2
    assert "safety" in capsys.readouterr().err and not (tmp_path / "b").exists()
    out = tmp_path / "c"
    assert main(["run", "parabolic_disk", "--test", "--t-final", "0.1", "--adaptive-dt", "--dt-rule", "balance",
                 "--dt-safety", "0.5", "-q", "--out", str(out)]) == 0
    opts = json.loads((out / "summary.json").read_text())["options"]
    assert (opts["dt_rule"], opts["safety"], opts["adaptive_dt"]) == ("balance", 0.5, True)


def test_equidistributing_steps_beat_fixed_steps():
    """Test 6.2 on a coarse mesh to T = 0.1: the default adaptive rule (dt_rule 'equidistribute') needs fewer
    steps than fixed steps for the same final estimate (fixed-step count interpolated as in the study)."""
    from ngcontact.studies.parabolic import _fixed_steps_at
    from ngcontact.timestepping.run import scene_mesh

    sc = load_scene("parabolic_rings")
    mesh = scene_mesh(sc, {"maxh": 0.15})
    fixed = {dt: run_parabolic(sc.problem, mesh, ParabolicOptions(dt=dt, t_final=0.1, estimate=True)).summary
             for dt in (4e-3, 2e-3)}
    ad = run_parabolic(sc.problem, mesh, ParabolicOptions(dt=2e-3, t_final=0.1, adaptive_dt=True, safety=0.2)).summary
    n_fixed = _fixed_steps_at(fixed, ad["eta_st"])
    assert n_fixed is not None and ad["steps"] < 0.85 * n_fixed, (ad["steps"], n_fixed)


def test_spacetime_picture_uses_the_step_times():
    """Nonuniform steps: the contact picture's columns sit at the real times (t_{n-1}, t_n]."""
    from types import SimpleNamespace

    import matplotlib.pyplot as plt

    from ngcontact.timestepping.plots import write_parabolic_plots

    ts = [0.001, 0.002, 0.01, 0.1]
    rows = [dict(t=t, contact_area=0.0, newton_its=1, gmres_its=0) for t in ts]
    frac = [np.array([0.0, 0.0]), np.array([0.0, 0.0]), np.array([1.0, 0.0]), np.array([1.0, 1.0])]
    res = SimpleNamespace(rows=rows, spacetime=list(zip(ts, frac)), bins=np.array([0.0, 0.5, 1.0]))
    figs = write_parabolic_plots(res, "t")
    mesh = figs["contact_spacetime.png"].axes[0].collections[0]
    x = np.unique(mesh.get_coordinates()[..., 0])
    assert np.allclose(x, [0.0] + ts)
    # the first column in contact covers (0.002, 0.01]
    assert np.allclose(np.asarray(mesh.get_array()).reshape(2, 4)[0], [0, 0, 1, 1])
    for f in figs.values():
        plt.close(f)


# ------------------------------------------------------------------ units of the stopping tests
def _shifted(problem, c):
    """The same problem with c added to both membranes (Dirichlet and initial data; loads unchanged)."""
    from dataclasses import replace

    st = replace(problem.stationary, g1=problem.stationary.g1 + c, g2=problem.stationary.g2 + c)
    return replace(problem, stationary=st, u0=(problem.u0[0] + c, problem.u0[1] + c))


def test_constant_added_to_both_membranes_shifts_the_solution():
    """u + c solves the problem with data + c: the steps must give the shifted iterates.  With the Newton test
    relative to F^n (which carries M X^{n-1} / dt) and the certificate's penetration relative to ||u||_inf, the
    shifted run stopped with gaps of -8.7e-5 (1e-4 of the solution's range)."""
    from dataclasses import replace

    sc = load_scene("parabolic_manufactured")
    c = 1e6
    runs = [run_parabolic_scene(replace(sc, problem=p), dict(dt=0.05, t_final=0.3, level=1), snapshot_every=1)[0]
            for p in (sc.problem, _shifted(sc.problem, c))]
    a, b = runs
    ni = a.stepper.disc.n_interior
    assert b.converged and len(a.snapshots) == len(b.snapshots) == 6
    for sa, sb in zip(a.snapshots, b.snapshots):
        assert np.abs((sb[2] - c) - sa[2]).max() <= 1e-8  # round-off of 1e6 is 1e-10
        assert (sb[2][:ni] - sb[2][ni:]).min() >= -1e-9
        # X3 = (K X - F) / D: round-off 1e-16 c ||K|| / D ~ 4e-8 here (old: 3e-5, the wrong active set)
        assert np.abs(sb[3] - sa[3]).max() <= 1e-5 * np.abs(sa[3]).max()


def test_tiny_time_step_keeps_the_multiplier():
    """dt = 1e-12: the step's Newton test is relative to what drives the step (F(t) - K X^{n-1}), not to F^n ~ 1/dt,
    so the contact force is computed (with F^n as the divisor the start passed the test: 0 iterations, X3 = 0)."""
    sc = load_scene("parabolic_manufactured")
    ys = []
    for dt in (1e-8, 1e-12):
        r, _, _ = run_parabolic_scene(sc, dict(dt=dt, t_final=2 * dt, level=1))
        assert r.converged and all(q["newton_its"] >= 1 for q in r.rows[:1])
        ys.append(r.y.sum())
    assert ys[0] > 0.1 and ys[1] == pytest.approx(ys[0], rel=1e-5)


def test_contact_area_in_the_units_of_the_gap():
    """The same contact set (and area) for the data scaled by 1e-8 (the threshold was 1e-10 max(1, |X|))."""
    from dataclasses import replace

    sc = load_scene("parabolic_manufactured")
    P = sc.problem
    areas = []
    for f in (1.0, 1e-8):
        st = replace(P.stationary, f1=f * P.stationary.f1, f2=f * P.stationary.f2)
        r, _, _ = run_parabolic_scene(replace(sc, problem=replace(P, stationary=st, u0=(f * P.u0[0], f * P.u0[1]))),
                                      dict(dt=0.05, t_final=0.1, level=1))
        areas.append([q["contact_area"] for q in r.rows])
    assert areas[0][0] > 0.1 and np.allclose(areas[1], areas[0], rtol=1e-6)


def test_summary_states_the_steps_taken():
    """--t-final below dt: one step of t_final; the summary keeps the requested dt and states the steps taken."""
    sc = load_scene("parabolic_manufactured")
    r, _, _ = run_parabolic_scene(sc, dict(dt=0.05, t_final=0.01, level=0))
    s = r.summary
    assert s["steps"] == 1 and s["dt"] == 0.05
    assert s["dt_min_used"] == s["dt_max_used"] == pytest.approx(0.01)


def test_step_cap_is_a_named_stop():
    sc = load_scene("parabolic_manufactured")
    r, _, _ = run_parabolic_scene(sc, dict(dt=0.05, t_final=0.3, level=0, max_steps=2))
    assert not r.converged and len(r.rows) == 2
    assert any(f.startswith("max_steps: 2 steps") and "t = 0.1 < T = 0.3" in f for f in r.failures)


def test_dirichlet_data_periodic_in_time_rejected():
    """g(0) = g(T) but g depends on t (the check compared t = 0 and t = T only)."""
    t = Parameter(0.0)
    P = ParabolicProblem(_stat(g1=1.0 + 0.1 * sin(2 * math.pi * t)), u0=(1.0, 0.0), t_final=1.0, time=t)
    with pytest.raises(ProblemDataError, match="g1 depends on the time parameter"):
        BackwardEuler(P, P.domain.mesh(0))


def test_data_with_a_parameter_need_the_time_argument():
    t = Parameter(0.0)
    with pytest.raises(ProblemDataError, match=r"stationary.f1 depends on an ngsolve Parameter but .*time is None"):
        ParabolicProblem(TwoMembraneProblem(domain=CrissCrossSquare(n0=2), f1=-1.0 - t, f2=1.0), u0=(1.0, 0.0),
                         t_final=1.0)


def test_hypotheses_allow_round_off_multipliers():
    """X3 = -1e-14 max X3 (a Fischer-Burmeister iterate where the multiplier is 0) keeps the bound proven; a
    negative multiplier of 1e-6 max X3 does not."""
    from types import SimpleNamespace

    from ngcontact.timestepping.estimate import hypotheses

    sc = load_scene("parabolic_manufactured")
    disc = BackwardEuler(sc.problem, sc.problem.domain.mesh(0)).disc
    ni = disc.n_interior
    x = np.concatenate([np.ones(ni), np.zeros(ni)])
    comp = SimpleNamespace(terms={"eta_bc": 0.0, "eps_w": 0.0})
    y = np.zeros(ni)
    y[0] = 2.0
    y[1] = -2e-14
    assert hypotheses(disc, x, y, comp) == (True, "")
    y[1] = -2e-6
    assert not hypotheses(disc, x, y, comp)[0]


def test_study_cache_records_the_revision_of_each_experiment(tmp_path):
    """A computed experiment of the parabolic study is entered in runs/PROVENANCE.json with the revision it ran with;
    a cached one is read back, not recomputed, and keeps its entry; the report's provenance section names the
    revision of every experiment and says when one was cached without it (a stale cache is then visible)."""
    from ngcontact.studies.parabolic import _cached, provenance_lines, read_provenance

    calls = []

    def compute():
        calls.append(1)
        return {"value": len(calls)}

    first = _cached(tmp_path, "exp-a", compute, lambda *_: None, "abc1234")
    again = _cached(tmp_path, "exp-a", compute, lambda *_: None, "def5678")
    assert first == again == {"value": 1} and len(calls) == 1
    assert read_provenance(tmp_path)["exp-a"]["revision"] == "abc1234"
    (tmp_path / "runs" / "exp-b.json").write_text("[1, 2]\n")  # cached by an older study: no entry
    text = "\n".join(provenance_lines(tmp_path, ["exp-a", "exp-b"]))
    assert "| exp-a | abc1234 |" in text and "| exp-b | not recorded" in text and "several code revisions" in text
    assert "Every experiment was computed with revision abc1234." in provenance_lines(tmp_path, ["exp-a"])
    assert "No experiment has a recorded revision" in "\n".join(provenance_lines(tmp_path, ["exp-b"]))
