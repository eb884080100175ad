"""Newton steps solved by PCG with an earlier step's factorization (FactorReuse)."""
import numpy as np
import pytest
import scipy.sparse as sp

from ngcontact.algebra.reuse import FactorReuse
from ngcontact.algebra.system import LINEAR_PATHS, ComplementaritySystem
from ngcontact.algebra.linalg import SPDSolver, pcg
from ngcontact.newton.loop import NewtonOptions, semismooth_newton


def _laplace2d(n):
    h = 1.0 / (n + 1)
    T = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    I = sp.identity(n)
    t = np.arange(1, n + 1) * h
    X, Y = np.meshgrid(t, t, indexing="ij")
    return (sp.kron(T, I) + sp.kron(I, T)).tocsr(), X.ravel(), Y.ravel(), h


def _obstacle(n=24):
    """-Δu = -8 above the obstacle psi = 0.2 - |x - c|^2 (contact in a disk around the centre)."""
    K, X, Y, h = _laplace2d(n)
    F = -8.0 * h * h * np.ones(K.shape[0])
    psi = 0.2 - ((X - 0.5) ** 2 + (Y - 0.5) ** 2)
    N = K.shape[0]
    return ComplementaritySystem(K, F, np.arange(N), -np.ones(N, dtype=np.int64), psi, np.full(N, h * h))


def _membranes(n=20):
    """Two membranes, the first pushed down in the middle, with different tensions and a gap b(x)."""
    K, X, Y, h = _laplace2d(n)
    N = K.shape[0]
    f1 = np.where((X - 0.5) ** 2 + (Y - 0.5) ** 2 < 0.1, -30.0, 5.0)
    F = np.concatenate([f1 * h * h, 2.0 * h * h * np.ones(N)])
    return ComplementaritySystem(sp.block_diag([K, 3 * K], format="csr"), F, np.arange(N), N + np.arange(N),
                                 0.01 * X, np.full(N, h * h))


def _iterates(system, x0, y0, reuse, cfun="min"):
    """x^k, y^k for k = 1.. (each from a run stopped after k iterations) and the final history."""
    full = semismooth_newton(system, x0, y0, NewtonOptions(cfun=cfun, reuse_factorization=reuse))
    assert full.converged
    out = []
    for k in range(1, full.iterations + 1):
        r = semismooth_newton(system, x0, y0, NewtonOptions(cfun=cfun, maxit=k, reuse_factorization=reuse))
        out.append((r.x, r.y))
    return out, full


def _start(system, scale):
    """A start near the solution (as in nested iteration): few active-set changes per step."""
    ref = semismooth_newton(system, np.zeros(system.n), np.zeros(system.m), NewtonOptions(reuse_factorization=False))
    rng = np.random.default_rng(1)
    return ref.x + scale * rng.standard_normal(system.n) * np.abs(ref.x).max(), ref.y.copy()


@pytest.mark.parametrize("make", [_obstacle, _membranes])
def test_reuse_gives_the_iterates_of_fresh_factorizations_and_is_taken(make):
    s = make()
    x0, y0 = _start(s, 0.02)
    fresh, rf = _iterates(s, x0, y0, reuse=False)
    reused, rr = _iterates(s, x0, y0, reuse=True)
    assert rf.iterations == rr.iterations >= 3
    scale = np.abs(fresh[-1][0]).max()
    for (xa, ya), (xb, yb) in zip(fresh, reused):
        np.testing.assert_allclose(xb, xa, atol=1e-10 * scale, rtol=0)
        np.testing.assert_allclose(yb, ya, atol=1e-10 * np.abs(fresh[-1][1]).max(), rtol=0)
    paths = [LINEAR_PATHS[h.linear_path] for h in rr.history[1:]]
    assert paths[0] == "factor" and "pcg" in paths
    assert all(h.linear_path == 0 and h.pcg_its == 0 for h in rf.history[1:])
    assert rr.history[-1].res <= 1e-13  # still a direct-solver-accurate final step
    assert all(h.pcg_its <= 60 for h in rr.history)


def test_reuse_with_fischer_burmeister_rows_changes_weights_and_stays_exact():
    s = _obstacle(16)
    x0, y0 = _start(s, 0.01)
    a = semismooth_newton(s, x0, y0, NewtonOptions(cfun="fb", reuse_factorization=False))
    b = semismooth_newton(s, x0, y0, NewtonOptions(cfun="fb", reuse_factorization=True))
    assert a.converged and b.converged and a.iterations == b.iterations
    np.testing.assert_allclose(b.x, a.x, atol=1e-10 * np.abs(a.x).max(), rtol=0)


def test_too_many_changes_or_a_failed_pcg_refactorize():
    s = _obstacle(16)
    x0, y0 = _start(s, 0.02)
    g = s.gap(x0)
    C = np.minimum(g, y0)
    Ca, Cb = (g <= y0).astype(float), (g > y0).astype(float)
    lin = s.linearize(x0, y0, C, Ca, Cb)
    reuse = FactorReuse(s, max_changed=0)
    assert reuse.changed_rows(lin) is None  # nothing factorized yet
    z1, path, _ = reuse.solve(lin)
    assert path == "factor"
    z2, path, its = reuse.solve(lin)  # same system: exact preconditioner
    assert path == "pcg" and its <= 1
    np.testing.assert_allclose(z2, z1, rtol=1e-12, atol=1e-14)
    # flip one active row: more changes than allowed -> fresh factorization
    Ca2, Cb2 = Ca.copy(), Cb.copy()
    l = np.flatnonzero(Ca)[0]
    Ca2[l], Cb2[l] = 0.0, 1.0
    lin2 = s.linearize(x0, y0, C, Ca2, Cb2)
    assert reuse.changed_rows(lin2) == 1
    _, path, _ = reuse.solve(lin2)
    assert path == "factor"
    # a PCG capped at 0 iterations falls back, and the answer is the direct one
    reuse = FactorReuse(s, maxiter=1, time_fraction=None)
    reuse.solve(lin)
    z, path, its = reuse.solve(lin2)
    assert path == "pcg-failed" and its == 1
    np.testing.assert_allclose(z, SPDSolver(lin2.A).solve(lin2.b), rtol=1e-10)


def test_pcg_converges_on_the_true_residual():
    K, *_ = _laplace2d(12)
    b = np.random.default_rng(0).standard_normal(K.shape[0])
    d = K.diagonal()
    r = pcg(K, b, lambda v: v / d, rtol=1e-12, maxiter=500)
    assert r.converged and np.linalg.norm(b - K @ r.x) <= 1e-12 * np.linalg.norm(b)
    exact = SPDSolver(K)
    r = pcg(K, b, exact.solve, rtol=1e-12)
    assert r.converged and r.iterations <= 1
    r = pcg(K, b, lambda v: v / d, rtol=1e-12, maxiter=3)
    assert not r.converged and r.iterations == 3


def test_fixed_pattern_cholesky_solves_the_reduced_matrices():
    """FixedPatternCholesky: K + diag(d) on the kept unknowns, refactorized in K's pattern, solves like a
    fresh factorization of the reduced matrix; a second refactorization (other kept set) too."""
    from ngcontact.algebra.linalg import FixedPatternCholesky

    K, *_ = _laplace2d(15)
    n = K.shape[0]
    rng = np.random.default_rng(3)
    fp = FixedPatternCholesky(K)
    for trial in range(2):
        keep = rng.random(n) > 0.3
        d = np.where(rng.random(n) > 0.8, rng.random(n), 0.0)
        A = (K + sp.diags(d)).tocsr()[keep][:, keep]
        b = rng.standard_normal(keep.sum())
        fp.factor(keep, d)
        full = np.zeros(n)
        full[keep] = b
        z = fp.solve(full)
        assert np.abs(z[~keep]).max() == 0.0
        assert np.linalg.norm(A @ z[keep] - b) <= 1e-12 * np.linalg.norm(b)
    assert fp.factorizations == 2


@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_fixed_pattern_reuse_gives_the_iterates_of_fresh_factorizations(cfun):
    """Obstacle-type systems refactorize in K's pattern (FactorReuse.fixed_pattern): same iterates as
    fresh reduced factorizations (FB: mixed rows add to the diagonal).  The FB multiplier of a mixed
    row, y' = c0 - w g(x'), amplifies rounding in x' by w = Ca/Cb (huge near degenerate nodes), so for
    FB the multipliers are compared at convergence only."""
    s = _obstacle()
    x0, y0 = _start(s, 0.02)
    assert FactorReuse(s).fixed_pattern and not FactorReuse(_membranes()).fixed_pattern
    fresh, ref = _iterates(s, x0, y0, reuse=False, cfun=cfun)
    reused, full = _iterates(s, x0, y0, reuse=True, cfun=cfun)
    assert len(fresh) == len(reused)
    for (xa, ya), (xb, yb) in zip(fresh, reused):
        assert np.abs(xa - xb).max() <= 1e-10 * np.abs(xa).max()
        if cfun == "min":
            assert np.abs(ya - yb).max() <= 1e-10 * max(np.abs(ya).max(), 1e-300)
    assert np.abs(ref.y - full.y).max() <= 1e-8 * np.abs(ref.y).max()


@pytest.mark.parametrize("make", [_obstacle, _membranes])
def test_reuse_across_systems_that_share_K(make):
    """A factorization is reused for the steps of another system with the same K and constraint rows
    (another load F, e.g. the next time step), never for a system with another K or other rows."""
    s = make()
    x0, y0 = _start(s, 0.02)
    g = s.gap(x0)
    C = np.minimum(g, y0)
    Ca, Cb = (g <= y0).astype(float), (g > y0).astype(float)
    reuse = FactorReuse(s)
    _, path, _ = reuse.solve(s.linearize(x0, y0, C, Ca, Cb))
    assert path == "factor"
    same_K = ComplementaritySystem(s.K, 2.0 * s.F + 1.0, s.up, s.lo, s.b, s.D)
    lin = same_K.linearize(x0, y0, C, Ca, Cb)
    assert reuse.changed_rows(lin) == 0
    z, path, its = reuse.solve(lin)
    assert path == "pcg" and its <= 1
    np.testing.assert_allclose(z, SPDSolver(lin.A).solve(lin.b), rtol=1e-10, atol=1e-14 * np.abs(z).max())
    for other in (ComplementaritySystem(s.K.copy(), s.F, s.up, s.lo, s.b, s.D),  # equal values, another K
                  ComplementaritySystem(s.K, s.F, s.up, s.lo, s.b, 2.0 * s.D)):  # other rows
        assert reuse.changed_rows(other.linearize(x0, y0, C, Ca, Cb)) is None


def test_systems_declare_whether_the_newton_loop_may_reuse_factorizations():
    from ngcontact.discretizations.condensed import CondensedHHOSystem
    from ngcontact.discretizations.dg import DGComplementaritySystem

    assert ComplementaritySystem.factor_reuse
    assert not DGComplementaritySystem.factor_reuse and not CondensedHHOSystem.factor_reuse
    s = _obstacle(16)
    x0, y0 = _start(s, 0.02)
    assert any(h.linear_path == 1 for h in semismooth_newton(s, x0, y0, NewtonOptions()).history[1:])
    s.factor_reuse = False  # the loop reads the declaration
    assert all(h.linear_path == 0 for h in semismooth_newton(s, x0, y0, NewtonOptions()).history[1:])


def _flipped(s, x0, y0, nflip):
    """The linearization at (x0, y0) and one with ``nflip`` active rows made inactive."""
    g = s.gap(x0)
    C = np.minimum(g, y0)
    Ca, Cb = (g <= y0).astype(float), (g > y0).astype(float)
    Ca2, Cb2 = Ca.copy(), Cb.copy()
    rows = np.flatnonzero(Ca)[:nflip]
    Ca2[rows], Cb2[rows] = 0.0, 1.0
    return s.linearize(x0, y0, C, Ca, Cb), s.linearize(x0, y0, C, Ca2, Cb2)


def test_pcg_gets_twice_the_changed_rows_plus_a_slack_and_stops_after_a_failure(monkeypatch):
    s = _obstacle(16)
    x0, y0 = _start(s, 0.02)
    lin, lin2 = _flipped(s, x0, y0, 3)
    # unrestricted: PCG needs a few iterations for the three changed rows
    free = FactorReuse(s, time_fraction=None)
    free.solve(lin)
    _, path, its = free.solve(lin2)
    assert path == "pcg" and its >= 2
    # budget 2 * 3 + slack: with the slack chosen so that the budget is one iteration short, PCG gives up,
    # the step is factorized, and no later step tries PCG again (even an unchanged system)
    monkeypatch.setattr(FactorReuse, "ITER_SLACK", its - 1 - 2 * 3)
    reuse = FactorReuse(s, time_fraction=None)
    reuse.solve(lin)
    z, path, its2 = reuse.solve(lin2)
    assert path == "pcg-failed" and its2 == its - 1 and reuse.failed == 1
    np.testing.assert_allclose(z, SPDSolver(lin2.A).solve(lin2.b), rtol=1e-10, atol=1e-14 * np.abs(z).max())
    _, path, _ = reuse.solve(lin2)
    assert path == "factor"
    # a new Newton run (e.g. the next time step sharing the factorization) tries again
    reuse.new_run()
    monkeypatch.setattr(FactorReuse, "ITER_SLACK", 10)
    _, path, its3 = reuse.solve(lin2)
    assert path == "pcg" and its3 <= 1  # lin2 itself is the kept factorization now
    # with the budget just met, the same attempt converges and later attempts go on
    monkeypatch.setattr(FactorReuse, "ITER_SLACK", its - 2 * 3)
    reuse = FactorReuse(s, time_fraction=None)
    reuse.solve(lin)
    assert reuse.solve(lin2)[1] == "pcg" and reuse.solve(lin2)[1] == "pcg" and reuse.failed == 0


def test_pcg_is_not_tried_when_its_iterations_cannot_beat_a_factorization(monkeypatch):
    """Above TIME_CAP_FROM, the kept factorization's solve time prices a PCG iteration: if 2 #changed + 1 of
    them cost more than the next factorization, the step is factorized without an attempt."""
    s = _obstacle(16)
    x0, y0 = _start(s, 0.02)
    lin, lin2 = _flipped(s, x0, y0, 3)
    monkeypatch.setattr(FactorReuse, "TIME_CAP_FROM", 0.0)

    def kept(solve_share):
        """A FactorReuse with lin factorized, its solve priced at solve_share x the next factorization / 7."""
        r = FactorReuse(s)
        r.solve(lin)
        t_next = r._t_factor * (r.NUMERIC_FRACTION if r._symbolic_in_t_factor else 1.0)
        r._t_solve = solve_share * t_next / (2 * 3 + 1)
        return r

    reuse = kept(1.01)
    assert reuse._attempt(3) is None and reuse._attempt(0) is not None
    z, path, its = reuse.solve(lin2)
    assert path == "factor" and its == 0 and reuse.failed == 0
    np.testing.assert_allclose(z, SPDSolver(lin2.A).solve(lin2.b), rtol=1e-10, atol=1e-14 * np.abs(z).max())
    reuse = kept(0.99)
    assert reuse._attempt(3) is not None


def test_pcg_with_no_iterations_allowed_returns_the_start_unconverged():
    s = _obstacle(8)
    A, b = s.K, s.F
    res = pcg(A, b, lambda r: r / A.diagonal(), maxiter=0)
    assert not res.converged and res.iterations == 0 and np.array_equal(res.x, np.zeros_like(b))
