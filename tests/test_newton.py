"""Semismooth Newton on a small algebraic system with a known solution."""
import numpy as np
import pytest
import scipy.sparse as sp

from ngcontact.algebra.cfunctions import get_cfunction
from ngcontact.algebra.system import ComplementaritySystem
from ngcontact.newton import NewtonOptions, StopOptions, semismooth_newton
from ngcontact.newton.stopping import linearization_defect


def _system(n=60, solver="sparsecholesky"):
    """1D two-membrane analogue: membrane 1 pushed down in the middle, up near the ends."""
    h = 1.0 / (n + 1)
    t = np.arange(1, n + 1) * h
    L = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]) / h
    K = sp.block_diag([L, 2 * L], format="csr")
    f1 = np.where(np.abs(t - 0.5) < 0.2, -8.0, 6.0)
    F = np.concatenate([f1 * h, np.ones(n) * h])
    return ComplementaritySystem(K, F, np.arange(n), n + np.arange(n), np.zeros(n), np.full(n, h), solver=solver)


@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_converges_to_a_complementary_solution(cfun):
    s = _system()
    res = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun=cfun))
    assert res.converged and res.reason == "converged"
    g = s.gap(res.x)
    assert g.min() >= -1e-12 and res.y.min() >= -1e-12
    assert np.abs(g * res.y).max() <= 1e-12
    assert 0 < (res.y > 1e-8).sum() < s.m // 2  # partial contact really happens
    assert np.linalg.norm(s.residual(res.x, res.y)) <= 1e-10 * np.linalg.norm(s.F)


def test_min_and_fb_give_the_same_solution_and_min_terminates_finitely():
    s = _system()
    a = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun="min"))
    b = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun="fb"))
    np.testing.assert_allclose(a.x, b.x, atol=1e-10)
    # Newton-min (primal-dual active set) stops with an exact solution: the last step does not change the
    # active set and its residual is at the round-off of a direct solve.  Checked with fresh factorizations:
    # with factorization reuse the last step is a PCG solve, which stops at that floor by design (measured
    # 1.02e-13 with threaded factorizations, below 1e-13 without), see test_reuse.py.
    d = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun="min", reuse_factorization=False))
    assert d.iterations == a.iterations and d.history[-1].n_changed == 0
    assert d.history[-1].res < 1e-13


def test_non_convergence_is_named_not_silent():
    s = _system()
    res = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun="min", maxit=1))
    assert not res.converged
    assert "maximum number of iterations (1)" in res.reason
    assert res.iterations == 1


def test_history_logs_residuals_active_sets_and_times():
    s = _system()
    seen = []
    res = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(), callback=seen.append)
    assert len(seen) == res.iterations + 1 == len(res.history)
    assert all(r.time_linear >= 0 for r in res.history)
    assert res.history[-1].res <= NewtonOptions().tol
    assert [r.k for r in res.history] == list(range(res.iterations + 1))


@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_every_record_describes_its_iterate(cfun):
    """Record k (residual, active set, changes) agrees with the iterate X^k, obtained as the result of a
    run stopped after k iterations.  (scipy's factorization: the runs are the same to the bit; with NGSolve's threaded
    one the Fischer-Burmeister iterates of two runs were seen to part by 4e-9 relative.)"""
    s = _system(solver="scipy")
    full = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun=cfun))
    cf = get_cfunction(cfun)
    active_prev = np.zeros(s.m, dtype=bool)  # X^0 = 0: g = y = 0, every row active
    active_prev[:] = True
    for k in range(1, full.iterations + 1):
        it = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun=cfun, maxit=k))
        rec = full.history[k]
        phi = np.concatenate([s.residual(it.x, it.y), cf.value(s.gap(it.x), it.y)])
        # the record's ||Phi||/||F|| is the one recomputed here from the same iterate, up to round-off
        assert rec.res == pytest.approx(np.linalg.norm(phi) / np.linalg.norm(s.F), rel=1e-9, abs=1e-12)
        active = s.gap(it.x) <= it.y
        assert rec.n_active == int(active.sum())
        assert rec.n_changed == int((active != active_prev).sum())
        active_prev = active


def test_fb_line_search_decreases_the_merit_function():
    s = _system()
    res = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun="fb"))
    r = [h.res for h in res.history]
    assert all(b < a for a, b in zip(r, r[1:]))


@pytest.mark.parametrize("bad", [dict(cfun="max"), dict(tol=-1.0), dict(maxit=0), dict(armijo=0.7),
                                 dict(line_search="yes")])
def test_bad_newton_options_are_rejected_by_name(bad):
    (name, _), = bad.items()
    with pytest.raises(ValueError, match=f"option {name} "):
        NewtonOptions(**bad)


@pytest.mark.parametrize("bad", [dict(newton_stop="energy"), dict(gamma_balance=0.0), dict(gamma_balance=1.5),
                                 dict(gamma_lin=1.0)])
def test_bad_stop_options_are_rejected_by_name(bad):
    (name, _), = bad.items()
    with pytest.raises(ValueError, match=f"option {name} "):
        StopOptions(**bad)


@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_linearization_defect_vanishes_at_the_solution_and_tracks_the_remaining_error(cfun):
    s = _system()
    ref = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun=cfun))
    assert linearization_defect(s, ref.x, ref.y) <= 1e-12 * np.sqrt(ref.x @ (s.K @ ref.x))

    def energy(v):
        return np.sqrt(v @ (s.K @ v))

    seen = 0
    for k in range(1, ref.iterations):  # iterates before convergence: defect ~ |||x_k - x*|||
        it = semismooth_newton(s, np.zeros(s.n), np.zeros(s.m), NewtonOptions(cfun=cfun, maxit=k))
        true, est = energy(it.x - ref.x), linearization_defect(s, it.x, it.y)
        if true > 1e-12:  # never far below the true error (that would stop too early); above it only
            seen += 1     # where a damped FB step leaves a linear residual (diagonal scaling: 5-10x)
            assert 0.1 * true <= est, (k, true, est)
            if it.history[-1].step == 1.0:
                assert est <= 10 * true, (k, true, est)
    assert seen >= 1


def test_balanced_stop_saves_newton_steps_without_moving_the_error():
    """test 1 (degenerate band u1 - u2 < 1e-12 around r = R), nested levels: the residual stop needs
    3-4 steps per level to settle ~1e-9 gaps; the balanced stop takes 1-2 and the energy error agrees to
    1e-6 relative (gamma = 1e-3: the linearization error is 1e-3 of the discretization proxy)."""
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.scenes import load_scene

    scene = load_scene("test1")
    runs = {stop: run_scene(scene, RunOptions(levels=5, newton_stop=stop)) for stop in ("residual", "balanced")}
    its = {stop: [r["newton_its"] for r in run.rows] for stop, run in runs.items()}
    assert its["balanced"][0] == its["residual"][0]  # level 0: cold start, no reference, residual stop
    assert all(b <= a for a, b in zip(its["residual"], its["balanced"]))
    assert sum(its["balanced"][1:]) < sum(its["residual"][1:])
    bal = runs["balanced"].rows
    assert any(r["newton_balanced"] for r in bal) and all(r["newton_converged"] for r in bal)
    for a, b in zip(runs["residual"].rows, bal):
        assert abs(a["err_energy"] - b["err_energy"]) <= 1e-6 * a["err_energy"]
        if b["newton_balanced"]:
            assert b["eps_lin_final"] <= 1e-3 * b["eps_disc_final"]


def test_balanced_stop_option_errors_name_the_field():
    from ngcontact.drivers import RunOptions

    with pytest.raises(ValueError, match="newton_stop"):
        RunOptions(newton_stop="energy")
    with pytest.raises(ValueError, match="newton_stop"):
        RunOptions(newton_stop="balanced", newton="adaptive")
    with pytest.raises(ValueError, match="gamma_balance"):
        RunOptions(gamma_balance=2.0)


def _ex9_nested(level: int):
    """ex9 on levels ``level`` - 1 and ``level`` of its nested meshes: (coarse discretization, its converged Newton
    result, fine discretization)."""
    from ngcontact.discretizations.fem import FEMDiscretization
    from ngcontact.scenes import load_scene

    scene = load_scene("ex9_obstacle")
    meshes = list(scene.problem.domain.meshes(level + 1))
    coarse = FEMDiscretization(scene.problem, meshes[level - 1], order=1)
    sc = semismooth_newton(coarse.system, *coarse.initial_guess(scene.initial_guess), NewtonOptions())
    return coarse, sc, FEMDiscretization(scene.problem, meshes[level], order=1)


def test_obstacle_warm_start_sweeps_keep_the_solution_and_help_the_first_step(monkeypatch):
    """Nested start of the ex9 obstacle problem (level 4 from level 3): the projected Jacobi sweeps of
    ComplementaritySystem.warm_start leave the converged solution unchanged (finite termination) and
    misclassify no more rows in the first Newton step than the plain projected start (measured 4 vs 8)."""
    from ngcontact.algebra.system import ComplementaritySystem

    coarse, sc, fine = _ex9_nested(4)
    default = ComplementaritySystem.WARM_SWEEPS
    assert default > 0
    out = {}
    for sweeps in (0, default):
        monkeypatch.setattr(ComplementaritySystem, "WARM_SWEEPS", sweeps)
        x0, y0 = fine.prolongate(coarse, sc.x, sc.y)
        recs = []
        res = semismooth_newton(fine.system, x0, y0, NewtonOptions(), callback=recs.append)
        assert res.converged
        out[sweeps] = (res, recs[1].n_changed)
    (a, ca), (b, cb) = out[0], out[default]
    np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-12 * np.abs(a.x).max())
    assert cb <= ca and b.iterations <= a.iterations


def test_band_solve_covering_everything_is_the_discrete_solution():
    """FreeBoundaryRelaxation.solve_band with a band wider than the mesh solves the whole ex9 obstacle problem
    (level 3) from the interpolated start: the converged Newton solution, and Newton from it stops at once."""
    from ngcontact.algebra.relax import FreeBoundaryRelaxation

    coarse, sc, fine = _ex9_nested(3)
    x0, y0 = fine.prolongate(coarse, sc.x, sc.y)
    ref = semismooth_newton(fine.system, x0, y0, NewtonOptions())
    R = FreeBoundaryRelaxation(fine.system)
    lifted = x0 + 0.5 * np.median(y0[y0 > 0]) / fine.system.constraint_weight  # part of the contact set let go
    for start in ((x0, y0), (lifted, y0)):
        active = fine.system.constraint_weight * fine.system.gap(start[0]) <= start[1]
        x, y, changed = R.solve_band(*start, layers=10 ** 6)
        np.testing.assert_allclose(x, ref.x, rtol=0, atol=1e-10 * np.abs(ref.x).max())
        np.testing.assert_allclose(y, ref.y, rtol=0, atol=1e-8 * np.abs(ref.y).max())
        assert semismooth_newton(fine.system, x, y, NewtonOptions()).iterations == 0
        assert changed == np.count_nonzero(active != (ref.y > 0))
    assert changed > 0  # the lifted start: rows let go are taken back


def test_unsettled_band_solve_hands_on_the_next_active_set():
    """solve_band(settle=False) stops after max_steps solves and encodes the iteration's next active set in y:
    one step from its result is the iteration's second step (ex9 level 3, band = the whole mesh), chained
    steps reach the discrete solution, and Newton from the one-step result ends at that solution."""
    from ngcontact.algebra.relax import FreeBoundaryRelaxation

    coarse, sc, fine = _ex9_nested(3)
    s = fine.system
    x0, y0 = fine.prolongate(coarse, sc.x, sc.y)
    x0 = x0 + 0.5 * np.median(y0[y0 > 0]) / s.constraint_weight  # part of the contact set let go
    ref = semismooth_newton(s, x0, y0, NewtonOptions())
    R, L = FreeBoundaryRelaxation(s), 10 ** 6
    assert R.solve_band(x0, y0, L, max_steps=1) is None  # settle=True: one solve does not settle here
    one = R.solve_band(x0, y0, L, max_steps=1, settle=False)
    two = R.solve_band(x0, y0, L, max_steps=2, settle=False)
    assert one[2] > 0
    again = R.solve_band(one[0], one[1], L, max_steps=1, settle=False)
    np.testing.assert_allclose(again[0], two[0], rtol=0, atol=1e-12 * np.abs(ref.x).max())
    np.testing.assert_allclose(again[1], two[1], rtol=0, atol=1e-9 * np.abs(ref.y).max())
    x, y = one[0], one[1]
    for _ in range(20):
        x, y, changed = R.solve_band(x, y, L, max_steps=1, settle=False)
        if not changed:
            break
    np.testing.assert_allclose(x, ref.x, rtol=0, atol=1e-10 * np.abs(ref.x).max())
    res = semismooth_newton(s, one[0], one[1], NewtonOptions())
    assert res.converged and res.iterations < ref.iterations
    np.testing.assert_allclose(res.x, ref.x, rtol=0, atol=1e-10 * np.abs(ref.x).max())


def test_nested_obstacle_start_band_solve_saves_the_second_newton_step(monkeypatch):
    """The band solve of the nested start (ComplementaritySystem.WARM_BAND layers): ex9 on 6 nested levels takes
    one Newton step on the finest level (261k unknowns, a band of 16 % of them; Newton-min and FB), two without it; with the band
    solved on every level (no size rule) one step per level; the same converged solutions."""
    from ngcontact.algebra.system import ComplementaritySystem
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.scenes import load_scene

    sc = load_scene("ex9_obstacle")
    band = run_scene(sc, RunOptions(levels=6))
    # Fischer-Burmeister: the band iteration settles before Newton starts (an unsettled start handed on, as for
    # Newton-min above WARM_BAND_ALL rows, took FB 4 steps on the finest level)
    fb = run_scene(sc, RunOptions(levels=6, cfun="fb"))
    assert fb.rows[-1]["newton_its"] == 1
    assert fb.rows[-1]["err_energy"] == pytest.approx(band.rows[-1]["err_energy"], rel=1e-10)
    monkeypatch.setattr(ComplementaritySystem, "WARM_BAND_ALL", 10 ** 9)
    everywhere = run_scene(sc, RunOptions(levels=6))
    monkeypatch.setattr(ComplementaritySystem, "WARM_BAND", 0)
    plain = run_scene(sc, RunOptions(levels=6))
    assert band.rows[-1]["newton_its"] == 1 and plain.rows[-1]["newton_its"] == 2
    assert all(r["newton_its"] <= 1 for r in everywhere.rows[1:])
    for a, b, c in zip(plain.rows, band.rows, everywhere.rows):
        for r in (b, c):
            assert r["certified"] == 1 and r["active_nodes"] == a["active_nodes"]
            assert r["err_energy"] == pytest.approx(a["err_energy"], rel=1e-10)


@pytest.mark.parametrize("tension", [1e-6, 2.0 ** -20 * 3.0, 1e8])
def test_obstacle_warm_start_is_invariant_under_a_tension_scale(tension):
    """The nested start's active set, and so every Newton iterate, must not depend on the units of the
    tension: with mu times t (u fixed, loads and multipliers times t) the nested ex9 run takes the
    Newton steps of the unscaled one, level by level (the start compares w g with the multiplier read off
    the residual, both in units of y; comparing g itself took 3/4/3/4 steps at t = 1e-6 instead of 3/2/1/2)."""
    from dataclasses import replace

    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.problems.manufactured import scale_problem
    from ngcontact.scenes import load_scene

    scene = load_scene("ex9_obstacle")
    runs = {}
    for t in (1.0, tension):
        sc = replace(scene, problem=scale_problem(scene.problem, data=1.0, tension=t))
        res = run_scene(sc, RunOptions(levels=4), progress=lambda m: None)
        runs[t] = res
    base, scaled = runs[1.0], runs[tension]
    assert [r["newton_its"] for r in scaled.rows] == [r["newton_its"] for r in base.rows]
    assert [r["active_nodes"] for r in scaled.rows] == [r["active_nodes"] for r in base.rows]
    np.testing.assert_allclose(scaled.x, base.x, rtol=0, atol=1e-10 * np.abs(base.x).max())


@pytest.mark.parametrize("layout, ordered", [("obstacle", 1), ("membranes", 2), ("permuted", 0), ("partial", 0)])
def test_gap_from_slices_is_b_x_minus_b(layout, ordered):
    """g(x) = B x - b read off slices of x for rows in the unknowns' order (an obstacle on 0..m-1, membranes
    0..m-1 over m..2m-1): bitwise the product B x - b, which the other layouts use; diag(K) extracted once."""
    rng = np.random.default_rng(8)
    m = 7
    n = m if layout == "obstacle" else 2 * m
    K = sp.diags(rng.random(n) + 1.0, format="csr")
    up = {"permuted": rng.permutation(m) + m}.get(layout, np.arange(m))
    lo = {"obstacle": -np.ones(m, dtype=int), "partial": np.where(np.arange(m) < 3, m + np.arange(m), -1),
          "permuted": np.arange(m)}.get(layout, m + np.arange(m))
    s = ComplementaritySystem(K, rng.random(n), up, lo, rng.standard_normal(m), np.ones(m))
    assert s._ordered == ordered
    x = rng.standard_normal(n)
    assert np.array_equal(s.gap(x), s._B @ x - s.b)
    assert np.array_equal(s.diagonal(), K.diagonal()) and s.diagonal() is s.diagonal()


@pytest.mark.parametrize("scene_name", ["ex9_obstacle", "test1"])
def test_reduced_right_hand_side_and_diagonal_by_indexing(scene_name):
    """The reduced step's right-hand side Z^T (rhs - K x_aff) and diag(A), read off by indexing where Z selects the
    kept unknowns (obstacle rows), equal the products; the membranes' merged slaves keep the products."""
    from ngcontact.discretizations.fem import FEMDiscretization
    from ngcontact.scenes import load_scene

    problem = load_scene(scene_name).problem
    disc = FEMDiscretization(problem, list(problem.domain.meshes(3))[2], order=1)
    s = disc.system  # a varying diagonal (the structured ex9 mesh has a constant one)
    s = ComplementaritySystem(s.K + sp.diags(np.random.default_rng(9).random(s.n)), s.F, s.up, s.lo, s.b, s.D)
    one = semismooth_newton(s, *disc.initial_guess(None), NewtonOptions(maxit=1))
    x, y = one.x, one.y
    cf = get_cfunction("min")
    C = cf.value(*s.pair(x, y))
    lin = s.linearize(x, y, C, *s.chain(*cf.jacobian(*s.pair(x, y))))
    assert lin.eq.any() and (~lin.eq).any()
    assert lin.slave_is_lo.any() == (scene_name == "test1")
    np.testing.assert_array_equal(lin.b, lin.Z.T @ (lin.rhs - s.K @ lin.x_aff))
    np.testing.assert_array_equal(lin.diagonal(), lin.A.diagonal())


@pytest.mark.parametrize("factor", [1.0, 1e-8, 1e8])
def test_a_load_free_obstacle_problem_converges(factor):
    """f = 0, g = 0 and obstacle cones whose tips touch at nodes (outside audit, stop 48): ||F|| = 0, and the
    relative residual ||Phi|| / ||F|| was ~1e291 at the solution -- every level 'not converged'.  The divisor is
    then the force that holds the unknowns at the obstacle, ||K B^T b||: converged and certified at every scale."""
    from ngsolve import IfPos, x, y

    from ngcontact import ObstacleProblem, StructuredSquare
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.scenes import Scene

    def cone(cx, cy, h):
        return h - 4 * (IfPos(x - cx, x - cx, cx - x) + IfPos(y - cy, y - cy, cy - y))

    psi = factor * IfPos(cone(0.25, 0.25, 0.1) - cone(0.75, 0.5, 0.08), cone(0.25, 0.25, 0.1), cone(0.75, 0.5, 0.08))
    problem = ObstacleProblem(domain=StructuredSquare(n0=8), psi=psi, f=0.0, g=0.0, name="cones")
    run = run_scene(Scene(name="cones", path=None, problem=problem), RunOptions(levels=2))
    assert run.converged and all(r["certified"] == 1 and r["newton_its"] <= 2 for r in run.rows)
    assert np.abs(run.x).max() == pytest.approx(0.1 * factor, rel=1e-12)  # the higher tip, held there
