"""Stiff and extreme cases (issue 20): scale-invariant stopping, exit certificate, Newton safeguards, data range.

The fast subset of the stability suite (ngcontact/studies/stability.py, ``make stability``) runs once per
module; the other tests check the pieces on small systems."""
import math

import numpy as np
import pytest
import scipy.sparse as sp

from ngcontact.algebra.system import ComplementaritySystem
from ngcontact.drivers import RunOptions, run_scene
from ngcontact.newton import NewtonOptions, semismooth_newton
from ngcontact.algebra.certificate import certificate
from ngcontact.newton.linear import DirectSolve
from ngcontact.newton.loop import round_off_hint
from ngcontact.problems import ProblemDataError
from ngcontact.problems.manufactured import disk_contact, scale_problem
from ngcontact.scenes import Scene
from ngcontact.studies import stability


@pytest.fixture(scope="module")
def quick():
    outcomes, verdicts = stability.run_all(stability.quick_cases(), progress=lambda s: None)
    return {o.case.name: (o, v) for o, v in zip(outcomes, verdicts)}


def test_quick_stability_subset_passes_the_rule(quick):
    failed = {name: verdict for name, (out, (ok, verdict)) in quick.items() if not ok}
    assert not failed
    assert {"test1-p1-fb-tension1e+09", "offcentre-p2-fb", "offcentre-p1-balanced",
            "test1-p1-min-data1e-150"} <= set(quick)


def test_tension_scale_1e9_gives_the_unscaled_solution_with_fb(quick):
    """Tensions, loads and lam times 1e9, u unchanged: the max nodal error is the unscaled one (a mixed-unit
    residual test stopped such runs after 1 iteration with a 7x larger error)."""
    out, (ok, verdict) = quick["test1-p1-fb-tension1e+09"]
    base, _ = quick["test1-p1-fb"]
    assert out.status == "converged" and ok and verdict.startswith("= test1-p1-fb")
    for r, b in zip(out.rows, base.rows):
        assert abs(r["err_max_nodal"] - b["err_max_nodal"]) <= 1e-8 * b["err_max_nodal"]
        assert r["certified"] == 1 and r["cert_penetration"] <= 1e-7


def test_tension_scale_keeps_newton_min_iterates():
    """A power-of-2 tension scale: the same Newton counts and active sets, level by level (the gap enters the
    C-function weighted by the harmonic mean of the tensions)."""
    runs = []
    for t in (1.0, 2.0 ** 30):
        scene = Scene("t", None, scale_problem(disk_contact(), tension=t))
        res = run_scene(scene, RunOptions.for_scene(scene, order=1, levels=3, start="cold"), threads=1)
        runs.append(res)
    a, b = runs
    assert [r["newton_its"] for r in a.rows] == [r["newton_its"] for r in b.rows]
    assert [r["active_nodes"] for r in a.rows] == [r["active_nodes"] for r in b.rows]
    assert [i["n_active"] for i in a.iterations] == [i["n_active"] for i in b.iterations]


def test_fb_at_p2_does_not_stall(quick):
    """Two membranes mu = (1, 3), off-centre contact disk, P2, Newton-FB: the Armijo line search fails on the
    finer levels; the loop continues with Newton-min steps, converges with a certificate and logs it."""
    out, (ok, _) = quick["offcentre-p2-fb"]
    assert out.status == "converged" and ok
    assert all(r["certified"] == 1 for r in out.rows)
    assert sum(r["newton_remedies"] for r in out.rows) >= 1


def test_balanced_stop_returns_a_feasible_multiplier(quick):
    """The balanced stop accepted iterates with lam_min = -0.0056 (lam_max = 0.0081) on level 2 of this case:
    it now also needs the certificate at gamma_balance."""
    out, (ok, _) = quick["offcentre-p1-balanced"]
    assert out.status == "converged" and ok
    for r in out.rows:
        assert r["certified"] == 1 and r["cert_negativity"] <= 1e-3 and r["lam_min"] >= -1e-6


def test_data_outside_the_range_are_refused_with_the_field_named(quick):
    out, (ok, verdict) = quick["test1-p1-min-data1e-150"]
    assert out.status == "refused" and ok and "f1" in out.reason and "outside" in out.reason
    scene = Scene("t", None, scale_problem(disk_contact(), data=1e-160))
    with pytest.raises(ProblemDataError, match=r"f1: max \|f1\| / min\(mu\) = .*e-16[0-9] .* outside"):
        run_scene(scene, RunOptions.for_scene(scene, order=1, levels=1), threads=1)
    scene = Scene("t", None, scale_problem(disk_contact(), tension=1e-120))
    with pytest.raises(ProblemDataError, match="mu1 = 1.000e-120 is outside"):
        run_scene(scene, RunOptions.for_scene(scene, order=1, levels=1), threads=1)


def test_data_scale_1e_50_gives_the_same_iterates(quick):
    out, (ok, verdict) = quick["test1-p1-min-data1e-50"]
    base, _ = quick["test1-p1-min"]
    assert ok and verdict.startswith("= test1-p1-min")
    assert [r["newton_its"] for r in out.rows] == [r["newton_its"] for r in base.rows]


# ---------------------------------------------------------------- small systems
def _obstacle_system(n=30, s=1.0, t=1.0):
    """1D -u'' = f - lam on n interior nodes, u >= psi: K = t tridiag(-1, 2, -1), one-sided rows."""
    K = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr") * t
    xs = np.arange(1, n + 1) / (n + 1)
    F = -0.5 * np.ones(n) / (n + 1) * s * t
    psi = (-0.02 - 0.1 * (xs - 0.5) ** 2) * s
    return ComplementaritySystem(K, F, np.arange(n), -np.ones(n, dtype=np.int64), psi, np.ones(n),
                                 stiffness_scale=t)


def test_certificate_measures_each_condition_in_its_own_units():
    sysm = _obstacle_system()
    x = sysm.b + 0.1
    y = np.zeros(sysm.m)
    c = certificate(sysm, x, y, 1e-7)
    assert c.penetration == c.negativity == c.slackness == 0  # feasible and complementary (not a solution)
    x[3] = sysm.b[3] - 0.01  # penetration 0.01 relative to max |x| ~ 0.1
    c = certificate(sysm, x, y, 1e-7)
    assert not c.valid and 0.05 < c.penetration < 0.2 and c.negativity == 0 and "penetration" in c.failure()
    x[3] = sysm.b[3] + 0.1
    y[5], y[6] = 1.0, -0.5  # a positive multiplier where the gap is open, and a negative one
    c = certificate(sysm, x, y, 1e-7)
    # measured by what it does to u: D y / K_66 = 0.25 against osc(x) (U), as that is more than y / Y = 0.5
    U = np.ptp(x)
    assert c.negativity == pytest.approx(0.25 / U) and 0.25 / U > 0.5 and c.slackness > 0.5
    x_big = x.copy()
    x_big[20] += 100.0  # U ~ 100: the multiplier pushes u by 0.25 / 100, and its unit is Y = max |y| = 1 again
    assert certificate(sysm, x_big, y, 1e-7).negativity == pytest.approx(0.5)
    for s, t in ((1e-80, 1.0), (1e80, 1e-20), (3.0, 7e9)):
        scaled = _obstacle_system(s=s, t=t)
        c2 = certificate(scaled, x * s, y * s * t, 1e-7)
        assert c2.penetration == pytest.approx(c.penetration, rel=1e-12)
        assert c2.negativity == pytest.approx(c.negativity, rel=1e-12)
        assert c2.slackness == pytest.approx(c.slackness, rel=1e-12)


def test_certificate_equilibrium_is_the_residual_in_units_of_u():
    """At the Newton solution of the 1D obstacle system the residual of the rows without contact is round-off in
    units of u; moving one such unknown by delta gives equilibrium = K_jj delta / (K_jj U) = delta / U (U = osc x),
    which fails the certificate, and the same at data x 1e-80 and tensions x 7e9."""
    for s, t in ((1.0, 1.0), (1e-80, 1.0), (3.0, 7e9)):
        sysm = _obstacle_system(s=s, t=t)
        res = semismooth_newton(sysm, np.zeros(30), np.zeros(30), NewtonOptions())
        assert res.converged and res.certificate.valid and res.certificate.equilibrium <= 1e-14
        free = np.flatnonzero(res.y == 0)
        j = free[len(free) // 2]
        x = res.x.copy()
        x[j] += 1e-3 * np.ptp(res.x)
        c = certificate(sysm, x, res.y, 1e-7)
        assert c.equilibrium == pytest.approx(1e-3 * np.ptp(res.x) / np.ptp(x), rel=1e-9)
        assert not c.valid and "residual in the units of its field" in c.failure()


@pytest.mark.parametrize("s,t", [(2.0 ** -500, 1.0), (2.0 ** 480, 1.0), (1.0, 2.0 ** 90), (2.0 ** -400, 2.0 ** 200)])
def test_newton_iterates_do_not_depend_on_the_data_scale(s, t):
    """Newton-min and FB on the 1D obstacle system with data times s (tensions times t): the same iterations
    and the solution times s (to round-off: threaded factorizations are not bitwise reproducible); no squared
    residual under- or overflows."""
    for cfun in ("min", "fb"):
        ref = semismooth_newton(_obstacle_system(), np.zeros(30), np.zeros(30), NewtonOptions(cfun=cfun))
        res = semismooth_newton(_obstacle_system(s=s, t=t), np.zeros(30), np.zeros(30), NewtonOptions(cfun=cfun))
        assert ref.converged and res.converged and res.iterations == ref.iterations
        assert np.allclose(res.x / s, ref.x, rtol=1e-12, atol=0) and np.allclose(res.y / (s * t), ref.y, rtol=1e-12,
                                                                                  atol=1e-14 * np.abs(ref.y).max())
        # FB's path amplifies the round-off of threaded factorizations (1e-16 at the start, ~1e-11 at the end)
        assert np.allclose([h.res for h in res.history], [h.res for h in ref.history], rtol=1e-8, atol=0)


class _BrokenSolve:
    """A linear strategy whose steps jump between two fixed iterates (a wrong linear solver) until it is told
    to factorize afresh (``fresh``) or, with ``refresh=False``, for its first ``broken`` steps."""

    record_type = DirectSolve.record_type

    def __init__(self, refresh=True, broken=10 ** 9):
        self.refresh, self.broken = refresh, broken

    def start(self, system, estimates):
        outer = self
        exact = DirectSolve(reuse=False).start(system, estimates)

        class Session:
            fixed = False
            calls = 0
            can_refresh = outer.refresh

            def fresh(self):
                self.fixed = True

            def step(self, k, x, y, c, Ca, Cb, res_prev):
                self.calls += 1
                trial = exact.step(k, x, y, c, Ca, Cb, res_prev)
                if self.fixed or self.calls > outer.broken:
                    return trial
                n = len(x)
                up = (self.calls % 2 == 1)
                trial.x = system.b + (0.05 if up else -0.05) * (np.arange(n) % 3 == 0)
                trial.y = np.where(np.arange(n) % 3 == 0, 0.0 if up else 1.0, 0.0)
                return trial

            def after_step(self, k, x, y, step):
                return {}

        return Session()


def test_cycling_is_detected_and_a_fresh_factorization_ends_it():
    res = semismooth_newton(_obstacle_system(), np.zeros(30), np.zeros(30), NewtonOptions(maxit=50),
                            linear=_BrokenSolve())
    assert res.converged and res.certificate.valid
    assert [h.remedy for h in res.history].count(1) == 1
    assert "fresh factorization" in res.remedies[0] and "active set of iteration" in res.remedies[0]


def test_cycling_without_refactorization_switches_to_fb():
    res = semismooth_newton(_obstacle_system(), np.zeros(30), np.zeros(30), NewtonOptions(maxit=50),
                            linear=_BrokenSolve(refresh=False, broken=4))
    assert res.converged and res.certificate.valid
    assert [h.remedy for h in res.history].count(3) == 1 and "switch to Newton-FB" in res.remedies[0]


def test_cycling_that_no_remedy_ends_is_a_named_failure():
    res = semismooth_newton(_obstacle_system(), np.zeros(30), np.zeros(30), NewtonOptions(maxit=50),
                            linear=_BrokenSolve(refresh=False))
    assert not res.converged
    assert "(after the remedies: iteration" in res.reason


def test_round_off_hint_only_near_the_tolerance():
    assert round_off_hint(5e-8, 1e-10) == ""
    assert "within 100x of tol = 1e-10" in round_off_hint(1.07e-10, 1e-10)
    assert round_off_hint(1e-11, 1e-10) == ""  # the residual test holds: a looser tolerance would not help


def test_manufactured_disk_family_solves_its_pde():
    """disk_contact data: f1 = -mu1 Lap u1 - lam, f2 = -mu2 Lap u2 + lam (finite differences, off the contact
    circle), u1 - u2 >= 0, lam >= 0, (u1 - u2) lam = 0 at sample points."""
    from ngsolve import Mesh
    from netgen.geom2d import unit_square

    mesh = Mesh(unit_square.GenerateMesh(maxh=0.2))
    p = disk_contact(mu1=0.3, mu2=5.0, centre=(0.42, 0.56), R=0.3, N=3, M=2, A=2.0, b=0.1, lam_r3=False)
    ex = p.exact
    rng = np.random.default_rng(1)
    h = 1e-3
    checked = 0
    for px, py in rng.uniform(0.05, 0.95, size=(60, 2)):
        r = math.hypot(px - 0.42, py - 0.56)
        if abs(r - 0.3) < 5 * h:
            continue
        ev = lambda cf, a, b: cf(mesh(a, b))  # noqa: E731
        for u, f, mu, sgn in ((ex.u1, p.f1, p.mu1, -1), (ex.u2, p.f2, p.mu2, 1)):
            lap = (ev(u, px + h, py) + ev(u, px - h, py) + ev(u, px, py + h) + ev(u, px, py - h)
                   - 4 * ev(u, px, py)) / h ** 2
            assert abs(ev(f, px, py) - (-mu * lap + sgn * ev(ex.lam, px, py))) <= 1e-4 * (1 + abs(ev(f, px, py)))
        gap, lam = ev(ex.u1, px, py) - ev(ex.u2, px, py), ev(ex.lam, px, py)
        assert gap >= 0 and lam >= 0 and gap * lam == 0
        checked += 1
    assert checked > 40


def test_certificate_keeps_a_mixed_unit_residual_test_from_stopping_early(quick, monkeypatch):
    """Tensions times 1e9 and no tension scale declared (constraint weight 1): ||Phi|| / ||F|| is dominated by
    the PDE residual and falls below tol after one FB step on the finer levels, with open or penetrated gaps;
    the exit certificate makes the loop go on to the solution of the unscaled problem."""
    from ngcontact.problems.base import ContactProblem

    monkeypatch.setattr(ContactProblem, "stiffness_scale", property(lambda self: 1.0))
    base, _ = quick["test1-p1-fb"]
    scene = Scene("t", None, scale_problem(disk_contact(), tension=1e9))
    res = run_scene(scene, RunOptions.for_scene(scene, order=1, levels=4, cfun="fb"), threads=1)
    assert res.converged
    for r, b in zip(res.rows, base.rows):
        assert r["certified"] == 1
        assert abs(r["err_max_nodal"] - b["err_max_nodal"]) <= 1e-6 * b["err_max_nodal"]


def test_constant_added_to_both_membranes_changes_nothing():
    """test 1 with g1, g2 + 1e6 (u + 1e6 solves it): the same Newton steps and errors on every level.  With the
    certificate's penetration relative to ||u||_inf (1e6) level 1 stopped after one step on a wrong active set
    (energy error 3.9656e-3 instead of 3.9584e-3)."""
    from dataclasses import replace

    from ngcontact.scenes import load_scene

    sc = load_scene("test1")
    P = sc.problem
    runs = [run_scene(replace(sc, problem=p), RunOptions(levels=3))
            for p in (P, replace(P, g1=P.g1 + 1e6, g2=P.g2 + 1e6))]
    a, b = runs
    assert [q["newton_its"] for q in b.rows] == [q["newton_its"] for q in a.rows]
    for qa, qb in zip(a.rows, b.rows):
        assert qb["err_energy"] == pytest.approx(qa["err_energy"], rel=1e-6)
        assert qb["gap_min"] >= -1e-9


def test_membranes_equal_everywhere_without_multiplier_converge():
    """f1 / mu1 = f2 / mu2 and g1 = g2: u1 = u2 everywhere and lam = 0; the multipliers of the solve are round-off
    (-1e-13 F / D at 6k unknowns), which the certificate's negativity measures in the units F / D of the balance
    equations (relative to 1e-8 F / D every level from 1 on ran 200 steps and ended 'not converged')."""
    from ngcontact import CrissCrossSquare, TwoMembraneProblem

    problem = TwoMembraneProblem(domain=CrissCrossSquare(n0=4), f1=3.0, f2=0.2, g1=0.0, g2=0.0, mu1=3.0, mu2=0.2)
    res = run_scene(Scene(name="equal", path=None, problem=problem), RunOptions(levels=4))
    assert res.converged
    assert all(q["newton_its"] <= 2 and q["certified"] for q in res.rows)


def _membrane_levels(mu1, mu2, levels, **opts):
    """(x, y, system) of every level of the disk family with loads of size 1000 (the stiff membrane's scale)."""
    out = []
    run_scene(Scene(name="ratio", path=None, problem=disk_contact(mu1=mu1, mu2=mu2, A=1000.0)),
              RunOptions(order=1, levels=levels, **opts),
              on_level=lambda r: out.append((np.array(r.x), np.array(r.y), r.discretization.system)))
    return out


def _soft_units(x, y, system):
    """Per membrane, the residual of its rows without contact, diag(K)^-1 r, relative to the membrane's own size."""
    m, r, d = system.m, system.residual(x, y), system.diagonal()
    free = ~(y > 0)
    return [float(np.abs(r[s][free] / d[s][free]).max() / np.ptp(x[s])) for s in (slice(0, m), slice(m, 2 * m))]


@pytest.mark.parametrize("mu2", [1e-9, 1e12])
def test_membranes_tensions_far_apart_are_each_resolved(mu2):
    """mu1 = 1 and mu2 = 1e-9 (u2 soft) or 1e12 (u1 soft), loads of the stiff membrane's size: the coupled Newton
    and the splitting (--decouple) give the same solution, each membrane's residual at round-off of its own
    size.  Before: the coupled u2 (1e-9) was off by 1.6e-4 of its size at level 2 -- a multiplier of -3e-13 Y
    passed the certificate, pushing the soft membrane by that much, and the factorization-reuse PCG stopped on
    a residual norm that the stiff rows dominate; the split u1 (1e12) was off by 0.8, its w-loop stopping at once
    on a tolerance loosened by ||F|| / ||F_w|| ~ 1e12."""
    coupled, split = _membrane_levels(1.0, mu2, 3), _membrane_levels(1.0, mu2, 3, decouple=True)
    for (xc, yc, sc), (xs, ys, _) in zip(coupled, split):
        m = sc.m
        for s in (slice(0, m), slice(m, 2 * m)):
            assert np.abs(xc[s] - xs[s]).max() <= 1e-12 * np.abs(xs[s]).max()
        assert max(_soft_units(xc, yc, sc) + _soft_units(xs, ys, sc)) <= 1e-13
        assert certificate(sc, xc, yc, 1e-7).valid


def test_pcg_jacobi_resolves_rows_of_every_size():
    """Rows 1e12 apart (two decoupled 2D Laplacians), preconditioned by an exact solve of the matrix perturbed on 60
    rows (an earlier factorization): with ``jacobi`` the small rows' residual reaches the target in their own units,
    while the plain norm stops with it far above; and CG is not restarted on every iteration while only the plain
    test holds (outside review, stop 49: 337 iterations where 34 do)."""
    from ngcontact.algebra.linalg import pcg
    import scipy.sparse.linalg as spla

    n = 40
    T = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    L = (sp.kron(T, sp.identity(n)) + sp.kron(sp.identity(n), T)).tocsr()
    N = n * n
    A = sp.block_diag([L, 1e-12 * L], format="csr")
    xs = np.concatenate([np.sin(np.linspace(0, 3, N)), 0.3 * np.cos(np.linspace(0, 5, N))])
    b = A @ xs
    rows = np.random.default_rng(1).choice(2 * N, 60, replace=False)
    pert = np.zeros(2 * N)
    pert[rows] = 5 * A.diagonal()[rows]
    solve = spla.factorized((A + sp.diags(pert)).tocsc())
    small = slice(N, 2 * N)
    rel, its = {}, {}
    for jacobi in (False, True):
        res = pcg(A, b, solve, rtol=1e-12, maxiter=500, jacobi=jacobi)
        assert res.converged
        r = b - A @ res.x
        rel[jacobi] = float(np.abs(r[small] / A.diagonal()[small]).max() / np.ptp(res.x[small]))
        its[jacobi] = res.iterations
    assert rel[True] <= 1e-11 < 1e-8 < rel[False]  # the rtol target, in each row's own units
    assert its[True] <= 60


@pytest.mark.parametrize("mode, krylov", [("inexact", "gmres"), ("gmres", "gmres"), ("inexact", "cg"),
                                          ("multigrid-inexact", None)])
@pytest.mark.parametrize("mu2", [1e9, 1e12])
def test_inexact_modes_resolve_membranes_with_tensions_far_apart(mode, krylov, mu2):
    """mu2 / mu1 = 1e9 / 1e12, loads of the stiff membrane's size: every level of the inexact modes converges, is
    certified, and equals the direct solution in each field's own units (measured: 5e-16 ... 6e-14, and 1e-11 for
    multigrid-inexact).  The Krylov residuals are measured in the units of u (GMRES on the Jacobi-scaled system, CG
    and the multigrid CG with Jacobi-weighted tests).  Before: the plain 2-norm let the stiff rows decide, and the
    soft membrane stayed unresolved (Newton-min cycled, stopped with no progress, or missed the certificate)."""
    problem = disk_contact(mu1=1.0, mu2=mu2, A=1000.0)
    scene = Scene(name="ratio", path=None, problem=problem)
    direct = run_scene(scene, RunOptions(order=1, levels=3))
    kw = {} if krylov is None else {"krylov": krylov}
    result = run_scene(scene, RunOptions(order=1, levels=3, newton=mode, **kw))
    assert result.converged, result.failures
    assert all(r["certified"] == 1 and r["cert_equilibrium"] <= r["cert_tol"] for r in result.rows)
    ni = len(direct.x) // 2
    for field in (slice(0, ni), slice(ni, None)):
        ref = direct.x[field]
        assert np.abs(result.x[field] - ref).max() <= 1e-9 * np.abs(ref).max()


@pytest.mark.parametrize("case", ["pressed", "constant"])
def test_equilibrium_counts_only_beyond_round_off(case):
    """Solutions correct to round-off pass the equilibrium measure (outside review, stop 49): two membranes pressed
    together by loads 1e12 times their elastic forces (f1 = -(P + 1), f2 = P, g = x: u1 = u2 = x) leave eps |F| in
    every contact row, and a constant field (u1 = 0.02, no load) has the 1e-6 floor of its size as its unit; both
    failed the certificate (1.3e-6 > 1e-7, 1.7e-10 > 1e-10) before the residual was counted beyond its round-off."""
    from ngcontact import CrissCrossSquare, TwoMembraneProblem
    from ngsolve import x as X

    if case == "pressed":
        problem = TwoMembraneProblem(domain=CrissCrossSquare(n0=4), f1=-(1e12 + 1.0), f2=1e12, g1=X, g2=X)
        opts = dict(levels=3)
    else:
        problem = TwoMembraneProblem(domain=CrissCrossSquare(n0=4), f1=0.0, f2=0.0, g1=0.02, g2=0.0)
        opts = dict(levels=2, tol=1e-13)
    result = run_scene(Scene(name=case, path=None, problem=problem), RunOptions(order=1, **opts))
    assert result.converged and all(r["certified"] == 1 for r in result.rows)


@pytest.mark.parametrize("disc", ["sipg", "nipg", "hho"])
@pytest.mark.parametrize("mu2", [1e9, 1e12])
def test_broken_discretizations_resolve_membranes_with_tensions_far_apart(disc, mu2):
    """dG and HHO (condensed, and uncondensed: the generic step), mu1 = 1 soft against mu2 = 1e9 / 1e12: every level
    converges and is certified.  Before: the multiplier of an active row came from the slave's (u2's) equation,
    (K x - F) of the stiff field's size cancelling to the soft field's size (1e-4 off at 1e12): SIPG / NIPG ran
    into the iteration cap on level 2 ('the certificate not met'); the condensed HHO step stalled on every level."""
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.problems.manufactured import disk_contact
    from ngcontact.scenes import Scene

    scene = Scene(name="far-apart", path=None, problem=disk_contact(1.0, mu2, A=1000.0))
    runs = [dict(disc=disc, order=1, levels=3)] + ([dict(disc=disc, order=1, levels=2, condense=False)]
                                                   if disc == "hho" else [])
    for kw in runs:
        res = run_scene(scene, RunOptions(**kw))
        assert res.converged, kw
        assert all(r["newton_converged"] == 1 and r["certified"] == 1 for r in res.rows), kw
