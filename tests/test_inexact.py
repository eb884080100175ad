"""Inexact and adaptive inexact semismooth Newton ([JSC20]): GMRES + ILU, stopping rules, agreement of modes."""
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp

from ngcontact.algebra.cfunctions import get_cfunction
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.algebra.krylov import ILU, gmres
from ngcontact.drivers.level import LevelEstimator
from ngcontact.newton import AdaptiveStop, KrylovSolve, NewtonOptions, semismooth_newton
from ngcontact.newton.linear import algebraic_residual, rhs_norm
from ngcontact.newton.stopping import stop_linear, stop_newton
from ngcontact.scenes import load_scene


def _krylov(disk, mode, estimator=None, callback=None, gamma_lin=0.3, **kw):
    """GMRES Newton on the disk level 0 (the stopping rule of the mode: adaptive or residual)."""
    stop = AdaptiveStop(gamma_lin) if mode == "adaptive" else None
    if mode == "adaptive" and estimator is None:
        estimator = LevelEstimator(disk.disc, None)
    linear = KrylovSolve(mode=mode, estimator=estimator, **kw)
    return semismooth_newton(disk.disc.system, disk.x0, disk.y0, NewtonOptions(), callback, linear=linear, stop=stop)


def _laplace2d(n):
    T = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    return (sp.kron(T, sp.eye(n)) + sp.kron(sp.eye(n), T)).tocsr()


@pytest.fixture(scope="module")
def disk():
    scene = load_scene("disk")
    disc = FEMDiscretization(scene.problem, scene.problem.domain.mesh(0), order=1)
    x0, y0 = disc.initial_guess(scene.initial_guess)
    ref = semismooth_newton(disc.system, x0, y0, NewtonOptions())
    assert ref.converged
    return SimpleNamespace(disc=disc, x0=x0, y0=y0, ref=ref, err=disc.errors(ref.x, ref.y)["err_energy"])


# ----------------------------------------------------------------------------- GMRES
def test_gmres_exposes_the_true_residual_every_nu_iterations():
    A = _laplace2d(20) + sp.diags(np.linspace(0, 1, 400)) @ sp.eye(400, k=1)  # nonsymmetric
    b = np.random.default_rng(1).standard_normal(400)
    seen = []
    res = gmres(A, b, M=ILU(A), rtol=1e-12, restart=15, nu=7, monitor=lambda s: seen.append(s) and False)
    assert res.converged and res.reason == "tolerance"
    assert [s.i for s in seen] == list(range(0, res.iterations + 1, 7))[: len(seen)]
    assert len(seen) == res.iterations // 7 + 1  # every nu iterations, across restarts (15 is not a multiple of 7)
    for s in seen:  # the monitor sees the iterate and its computed residual b - A x
        assert np.allclose(s.r, b - A @ s.x, rtol=0, atol=1e-12 * np.linalg.norm(b))
        assert s.res == pytest.approx(np.linalg.norm(b - A @ s.x) / np.linalg.norm(b), rel=1e-10)
    assert np.linalg.norm(b - A @ res.x) <= 1.01e-12 * np.linalg.norm(b)
    assert np.allclose(res.x, sp.linalg.spsolve(A.tocsc(), b), atol=1e-9)
    # the residual history is non-increasing (GMRES minimizes it over a growing space within a cycle)
    h = np.array(res.res_history)
    assert np.all(np.diff(h) <= 1e-12)


def test_gmres_monitor_stops_and_warm_start_counts():
    A = _laplace2d(15)
    b = np.ones(A.shape[0])
    res = gmres(A, b, M=ILU(A), rtol=0.0, nu=5, monitor=lambda s: s.i >= 10)
    assert res.reason == "monitor" and res.iterations == 10 and not res.converged
    x = sp.linalg.spsolve(A.tocsc(), b)
    assert gmres(A, b, x0=x, rtol=1e-10).iterations == 0  # warm start at the solution: nothing to do


# --------------------------------------------------------- linearization residual
@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_reduced_residual_is_the_3field_algebraic_residual(disk, cfun):
    """R = B - A X for the recovered 3-field iterate: zero constraint rows, norm = reduced residual."""
    s, cf = disk.disc.system, get_cfunction(cfun)
    rng = np.random.default_rng(0)
    x = disk.ref.x + 1e-3 * rng.standard_normal(s.n)
    y = np.abs(disk.ref.y + 1e-3 * rng.standard_normal(s.m))
    c = cf.value(s.gap(x), y)
    Ca, Cb = cf.jacobian(s.gap(x), y)
    lin = s.linearize(x, y, c, Ca, Cb)
    z = lin.restrict(x) + 1e-4 * rng.standard_normal(lin.size)  # any inexact reduced iterate
    xi, yi = lin.recover(z)
    R = algebraic_residual(s, xi, yi, x, y, c, Ca, Cb)
    scale = rhs_norm(s, x, y, c, Ca, Cb)
    assert np.abs(R[s.n:]).max() <= 1e-12 * scale  # linearized complementarity rows hold exactly
    assert np.linalg.norm(R) == pytest.approx(np.linalg.norm(lin.b - lin.A @ z), rel=1e-9)
    # and the exact reduced solution is the direct Newton step
    x1, y1, _ = s.newton_step(x, y, c, Ca, Cb)
    xe, ye = lin.recover(sp.linalg.spsolve(lin.A.tocsc(), lin.b))
    assert np.allclose(x1, xe, atol=1e-11) and np.allclose(y1, ye, atol=1e-9)


# ------------------------------------------------------------- stopping predicates
def test_stopping_predicates():
    assert stop_linear(eta_alg=0.3, eta_disc=1.0, eta_lin=0.2, gamma_alg=0.3)
    assert not stop_linear(eta_alg=0.31, eta_disc=1.0, eta_lin=0.2, gamma_alg=0.3)
    assert stop_linear(eta_alg=0.6, eta_disc=0.1, eta_lin=2.0, gamma_alg=0.3)  # max(eta_disc, eta_lin)
    assert not stop_linear(eta_alg=0.6, eta_disc=0.1, eta_lin=2.0, gamma_alg=0.03)
    assert stop_newton(eta_lin=0.03, eta_disc=0.1, gamma_lin=0.3)
    assert not stop_newton(eta_lin=0.031, eta_disc=0.1, gamma_lin=0.3)
    assert not stop_newton(eta_lin=1e-3, eta_disc=0.1, gamma_lin=1e-3)


def test_options_are_validated_by_name():
    for kw, name in [(dict(mode="fast"), "newton"), (dict(gamma_alg=0.0), "gamma_alg"), (dict(nu=0), "nu"),
                     (dict(tol_alg=2.0), "tol_alg"), (dict(restart=0), "restart"),
                     (dict(ilu_drop_tol=-1e-6), "ilu_drop_tol"), (dict(ilu_fill=0.5), "ilu_fill")]:
        with pytest.raises(ValueError, match=f"option {name} "):
            KrylovSolve(**kw)


def test_estimating_modes_refuse_to_run_without_an_estimator(disk):
    with pytest.raises(ValueError, match="needs an estimator"):
        semismooth_newton(disk.disc.system, disk.x0, disk.y0, linear=KrylovSolve(mode="adaptive"))


def test_adaptive_rules_trigger_as_specified_with_synthetic_estimators(disk):
    """Injected estimators: eta_alg = ||R^{k,i}|| / ||F||, eta_lin = 0.03 / k^2, eta_disc = 0.01.

    GMRES must stop at the first evaluation satisfying eta_alg <= g_alg max(eta_disc, eta_lin),
    Newton at the first k with eta_lin <= g_lin eta_disc.
    """
    s = disk.disc.system
    calls = []

    def components(x, y, r_alg, dx):
        assert dx is not None and len(dx) == s.n  # the look-ahead increment that defines sigma_alg
        eta_alg = float(np.linalg.norm(r_alg)) / float(np.linalg.norm(s.F))
        k = 1 + sum(1 for c in calls if c == "accepted")
        comp = SimpleNamespace(eta_disc=1e-2, eta_lin=0.03 / k ** 2, eta_alg=eta_alg, eta=float("nan"), terms={})
        calls.append(comp)
        return comp

    # a weaker ILU than the default so that GMRES on this small case runs long enough for several
    # estimator evaluations per step (with ILU(1e-5, fill 8) it reaches its tolerance before the rule)
    opts = dict(gamma_alg=0.3, nu=5, ilu_drop_tol=1e-4, ilu_fill=2.0)
    recs = []

    def cb(rec):
        recs.append(rec)
        if rec.k > 0:
            calls.append("accepted")
    res = _krylov(disk, "adaptive", SimpleNamespace(components=components), cb, gamma_lin=0.3, **opts)
    assert res.converged and res.reason == "adaptive stopping criterion"
    # eta_lin = 0.03/k^2 <= 0.3 * 1e-2  <=>  k >= 3.16: Newton stops at k = 4 exactly
    assert res.iterations == 4
    for k in range(1, res.iterations + 1):
        ev = [e for e in res.estimates if e.k == k]
        assert ev and all(e.i % opts["nu"] == 0 and e.i >= opts["nu"] for e in ev)
        flags = [stop_linear(e.eta_alg, e.eta_disc, e.eta_lin, opts["gamma_alg"]) for e in ev]
        assert flags[-1] and not any(flags[:-1])  # stopped at the first evaluation that satisfies the rule
        assert [e.stop_linear for e in ev] == flags
        rec = res.history[k]
        assert rec.gmres_accepted == ev[-1].i and rec.gmres_its == ev[-1].i + opts["nu"]  # look-ahead counted
        assert rec.eta_alg == ev[-1].eta_alg
        assert stop_newton(rec.eta_lin, rec.eta_disc, 0.3) == (k == res.iterations)


# --------------------------------------------------------------- the three modes
def test_three_modes_converge_to_the_same_discrete_solution(disk):
    s, ref = disk.disc.system, disk.ref
    scale = np.linalg.norm(ref.x)
    out = {}
    for mode in ("gmres", "inexact", "adaptive"):
        res = _krylov(disk, mode)
        assert res.converged, (mode, res.reason)
        out[mode] = res
        assert res.gmres_total == sum(r.gmres_its for r in res.history) > 0
        assert res.history[-1].gmres_cum == res.gmres_total
    for mode in ("gmres", "inexact"):  # ||Phi||/||F|| <= 1e-10 with GMRES: the direct solution
        res = out[mode]
        assert res.history[-1].res <= 1e-10
        assert np.linalg.norm(res.x - ref.x) <= 1e-8 * scale
        assert np.array_equal(s.gap(res.x) <= res.y, s.gap(ref.x) <= ref.y)  # same contact set
    for r in out["gmres"].history[1:]:
        assert r.res_alg <= 2e-12  # ||R^{k,i}|| / ||B^{k-1}||
    # adaptive: stopped by the estimators, error components balanced, energy error as exact's
    ad = out["adaptive"]
    last = ad.history[-1]
    assert ad.reason == "adaptive stopping criterion"
    assert last.eta_lin <= 0.3 * last.eta_disc and last.eta_alg <= 0.3 * max(last.eta_disc, last.eta_lin)
    err = disk.disc.errors(ad.x, ad.y)["err_energy"]
    assert abs(err - disk.err) <= 0.05 * disk.err
    assert ad.iterations <= ref.iterations and ad.gmres_total < out["gmres"].gmres_total


def test_algebraic_flux_estimates_the_algebraic_error(disk):
    """eta_alg = ||mu^{-1/2} sigma_alg|| vs the energy norm of the nu-step correction and of the true error."""
    from ngcontact.estimators.algebraic import algebraic_correction_norm, algebraic_flux, eta_alg_of

    s, cf = disk.disc.system, get_cfunction("min")
    x, y = disk.x0, disk.y0
    c = cf.value(s.gap(x), y)
    Ca, Cb = cf.jacobian(s.gap(x), y)
    lin = s.linearize(x, y, c, Ca, Cb)
    xe, _ = lin.recover(sp.linalg.spsolve(lin.A.tocsc(), lin.b))
    checks = []
    gmres(lin.A, lin.b, lin.restrict(x), ILU(lin.A), rtol=0.0, maxiter=40, nu=10,
          monitor=lambda st: checks.append(lin.recover(st.x)[0]) and False)
    ratios = []
    for xi, xj in zip(checks[:-1], checks[1:]):
        d, e = xj - xi, xe - xi
        if algebraic_correction_norm(disk.disc, d) < 1e-9 * algebraic_correction_norm(disk.disc, xe):
            continue  # round-off level
        eta = eta_alg_of(disk.disc, algebraic_flux(disk.disc, d))
        # equilibrated flux of the correction: equivalent to |||d||| (measured 0.48-0.96 on this mesh) ...
        assert 0.4 <= eta / algebraic_correction_norm(disk.disc, d) <= 1.05
        ratios.append(eta / algebraic_correction_norm(disk.disc, e))
    # ... and |||d||| -> |||e|||: a real estimate of the algebraic error |||u_h^k - u_h^{k,i}|||
    assert len(ratios) >= 2 and all(0.4 <= r <= 1.05 for r in ratios), ratios


def test_ilu_options_reach_the_preconditioner(disk):
    """A larger ILU fill is used (recorded fill ratio) and pays in GMRES iterations; same discrete solution."""
    ref = disk.ref
    runs = {}
    for ilu in ((1e-4, 2.0), (1e-6, 15.0)):
        res = _krylov(disk, "gmres", ilu_drop_tol=ilu[0], ilu_fill=ilu[1])
        assert res.converged
        assert np.linalg.norm(res.x - ref.x) <= 1e-8 * np.linalg.norm(ref.x)
        fills = [r.ilu_fill_ratio for r in res.history[1:]]
        assert all(1.0 <= f <= ilu[1] * 1.0001 for f in fills), fills
        runs[ilu] = (res.gmres_total, float(np.mean(fills)))
    (its_weak, fill_weak), (its_strong, fill_strong) = runs[(1e-4, 2.0)], runs[(1e-6, 15.0)]
    assert fill_strong > fill_weak and its_strong < its_weak


def test_inexact_cycling_remedy_solves_the_later_steps_to_the_gmres_tolerance(disk):
    """The inexact mode's cycling remedy (:mod:`ngcontact.newton.safeguards`): after ``fresh()`` a step is solved to
    the gmres mode's tolerance instead of its forcing term (the same state: more GMRES iterations, a residual at
    tol_alg); the gmres and adaptive modes have no such remedy; the log names it."""
    from ngcontact.newton.safeguards import Safeguards

    system = disk.disc.system
    cf = get_cfunction("min")
    x, y = disk.x0, disk.y0
    g = system.gap(x)
    C, (Ca, Cb) = cf.value(g, y), cf.jacobian(g, y)
    opt = KrylovSolve(mode="inexact")
    session = opt.start(system, [])
    assert session.can_refresh
    loose = session.step(1, x, y, C, Ca, Cb, 0.5).fields
    guard = Safeguards(session)
    assert guard.next_remedy("cycling") == 1 and not session.can_refresh
    guard.note(3, 1, "active set of iteration 1 again")
    assert guard.log == ["iteration 3: active set of iteration 1 again: solve the steps to the gmres tolerance"]
    tight = session.step(1, x, y, C, Ca, Cb, 0.5).fields
    assert loose["res_alg"] > 1e4 * opt.tol_alg and tight["res_alg"] <= 10 * opt.tol_alg  # measured: 2e-5, 2e-15
    assert tight["gmres_its"] > loose["gmres_its"]
    for mode in ("gmres", "adaptive"):
        assert not KrylovSolve(mode=mode, estimator=object()).start(system, []).can_refresh


@pytest.mark.slow
def test_rings_fb_inexact_step_15_converges():
    """[CMAME20] rings, P1 on 19k triangles, Newton-FB with inexact GMRES (the full parabolic study's table): step 15
    cycled and stopped at ||Phi||/||F|| = 3.9 (not converged) with the steps left at their forcing terms; with the
    remedy it converges (11 Newton steps)."""
    from ngcontact.studies.parabolic import SIZES
    from ngcontact.timestepping.driver import ParabolicOptions, run_parabolic
    from ngcontact.timestepping.run import scene_mesh

    rings = load_scene("parabolic_rings")
    mesh = scene_mesh(rings, {"maxh": SIZES["full"]["table_maxh"]})
    res = run_parabolic(rings.problem, mesh, ParabolicOptions(dt=1e-3, t_final=0.016, cfun="fb", newton="inexact"))
    assert res.converged, res.failures
