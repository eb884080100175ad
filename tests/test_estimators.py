"""A posteriori estimates by equilibrated fluxes ([JSC20], seed "Theorem (A posteriori error estimate)").

Structural checks (equilibration, normal continuity), the guaranteed bound
I_eff >= 1 on every level, effectivity on the finer levels, eta = 0 when the
discrete space contains the exact solution, and the estimator converging at
the error's rate; the multipliers, the Dirichlet lifting and the options of the
estimate.  Known failures are xfail with the measured values.  The error
components of an iterate (eta_disc, eta_lin, eta_alg): tests/test_components.py.
"""
import numpy as np
import pytest
from ngsolve import Integrate, dx, x, y

from ngcontact import CrissCrossSquare, ExactSolution, TwoMembraneProblem
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.estimators import EstimatorOptions, complementarity_report, equilibration_defect, estimate, normal_jump
from ngcontact.estimators.flux import reconstruct
from ngcontact.estimators.view import DiscretizationView, SolutionView
from ngcontact.newton.loop import NewtonOptions, semismooth_newton
from ngcontact.rates import fitted_rate
from ngcontact.scenes import load_scene

# (scene, p) -> number of levels run (whole file < 60 s).  P1 on the squares needs T3 for the
# coarse-mesh terms to fade (test 1 / test 2: I_eff(T2) = 1.255 / 1.262, I_eff(T3) = 1.166 / 1.123,
# results/estimators/TABLES.md).
LEVELS = {("test1", 1): 4, ("test1", 2): 3, ("test2", 1): 4, ("test2", 2): 3, ("disk", 1): 3, ("disk", 2): 3,
          ("disk_fitted", 1): 3, ("disk_fitted", 2): 3, ("test2_fitted", 1): 4, ("test2_fitted", 2): 4}
_CACHE = {}


def study(scene_name, p):
    """Solve (cold start) and estimate on every level; cached per module run."""
    key = (scene_name, p)
    if key not in _CACHE:
        scene = load_scene(scene_name)
        prob = scene.problem
        rows = []
        for level, mesh in enumerate(prob.domain.meshes(LEVELS[key])):
            disc = FEMDiscretization(prob, mesh, order=p)
            x0, y0 = disc.initial_guess(scene.initial_guess)
            sol = semismooth_newton(disc.system, x0, y0, NewtonOptions())
            assert sol.converged
            est = estimate(disc, sol.x, sol.y)
            rows.append(dict(level=level, h=prob.domain.h(level), est=est,
                             eq=equilibration_defect(disc, est.flux), jump=normal_jump(est.flux)))
        _CACHE[key] = rows
    return _CACHE[key]


CASES = sorted(LEVELS)

#: the equilibration check below is exact on straight elements; disk_fitted and test2_fitted at p = 2
#: have curved interior elements (the interface is curved with the mesh), where div sigma is not a mapped
#: polynomial: the moment defect is 2e-5 .. 3e-7 there (geometry, checked by the guaranteed bound instead)
STRAIGHT_INTERIOR = [c for c in CASES if c not in (("disk_fitted", 2), ("test2_fitted", 2))]


@pytest.mark.parametrize("scene,p", STRAIGHT_INTERIOR)
def test_equilibration(scene, p):
    """max_K ||Pi_q(f_a + s_a lam^_h - div sigma_ah)||_K / ||Pi_q(f_a + s_a lam^_h)|| <= 1e-10 on every level
    (moment sense: on the curved disk elements div sigma is not a mapped polynomial)."""
    for row in study(scene, p):
        assert max(v["max_K"] for v in row["eq"].values()) <= 1e-10, row["level"]


@pytest.mark.parametrize("scene,p", CASES)
def test_normal_continuity(scene, p):
    """The sum of the patch fluxes is in H(div): relative normal jumps at round-off, also on curved meshes
    (the batched patch solver solves the eps -> 0 limit exactly; PatchwiseSolve with eps = 1e-10 left
    jumps of 2e-10 .. 7e-10 there)."""
    for row in study(scene, p):
        assert max(row["jump"].values()) <= 1e-12, row["level"]


@pytest.mark.parametrize("scene,p", CASES)
def test_guaranteed_bound(scene, p):
    """eta >= |||u - u_h||| on every level (I_eff >= 1)."""
    for row in study(scene, p):
        assert row["est"].i_eff >= 1.0, (row["level"], row["est"].i_eff)



@pytest.mark.parametrize("scene,p", [
    ("test1", 1), ("test1", 2), ("test2", 1), ("disk", 1),
    pytest.param("test2", 2, marks=pytest.mark.xfail(
        strict=True, reason="f and lam jump across r = R, which cuts elements: the data oscillation "
        "h/pi ||f - Pi_2 f||_K on the cut elements (eta_R 0.9-1.2 x the error), eta_nonc,1 (0.5 x) and the "
        "element-mean term (0.35 x on T4) are O(h^1.5) like the P2 error; measured I_eff 1.905, 1.909, 2.322 "
        "(T0-T2), 2.368, 2.939 (T3, T4); "
        "fitted mesh: test2_fitted")),
    pytest.param("disk", 2, marks=pytest.mark.xfail(
        strict=True, reason="f jumps across r = 1/sqrt 2, which cuts elements: eta_R (oscillation of f) alone is "
        "~1.4 x error; measured I_eff 3.326, 3.176, 3.044 (levels 0-2); fitted mesh: disk_fitted")),
    ("disk_fitted", 1), ("disk_fitted", 2), ("test2_fitted", 1), ("test2_fitted", 2),
])
def test_effectivity_on_finest_level(scene, p):
    """I_eff <= 1.3 on the finest level run (disk P1: published 1.034-1.038 [JSC20])."""
    est = study(scene, p)[-1]["est"]
    assert est.i_eff <= 1.3, est.i_eff


def test_disk_p1_effectivity_close_to_published():
    """Disk P1, exact Newton: 1 <= I_eff <= 1.10 ([JSC20]: 1.034-1.038 on 2k-35k elements).

    Checked from level 1 (1088 triangles) on; level 0 (272 triangles, coarser
    than the published meshes) gives 1.114.  Measured: 1.076, 1.066 (levels
    1, 2), 1.055, 1.043 (levels 3, 4); without eta_quad (the FE load
    quadrature of the discontinuous f) level 3 gives 1.038.
    """
    for row in study("disk", 1)[1:]:
        assert 1.0 <= row["est"].i_eff <= 1.10, (row["level"], row["est"].i_eff)


@pytest.mark.parametrize("scene,p", CASES)
def test_estimator_rate_matches_error_rate(scene, p):
    """eta converges at the error's rate (fitted over the last two levels run).  test2 P2 (f jumps inside
    the elements cut by r = R) was pre-asymptotic with the patch-constant multiplier (eta rate 1.41 vs
    error 1.76 on T1-T2); the smaller of the patch-constant and shaped bounds (.estimators, "Multiplier")
    follows the error's rate there too."""
    rows = study(scene, p)
    h = [r["h"] for r in rows]
    rate_eta = fitted_rate(h, [r["est"].eta for r in rows], last=2)
    rate_err = fitted_rate(h, [r["est"].err_energy for r in rows], last=2)
    assert abs(rate_eta - rate_err) <= 0.3, (rate_eta, rate_err)


def test_disk_fitted_p2_effectivity():
    """Disk P2 on meshes fitted to the free boundary (issue 4 acceptance: P2 <= 1.2): 1 <= I_eff <= 1.2 on
    every level.

    Measured: 1.193, 1.081, 1.047 (levels 0-2, results/estimators/TABLES.md) with the contact-weighted fit of
    lam^ (curved elements) and the direct bound (eta_nonc,1 paid once); earlier 1.421, 1.185, 1.107 with the
    patch constants and the seed's route; the continuous P1 lam^ gave 2.69, 3.31, 4.42, 6.07.
    """
    rows = study("disk_fitted", 2)
    for row in rows:
        assert 1.0 <= row["est"].i_eff <= 1.2, (row["level"], row["est"].i_eff)


def test_disk_fitted_p3_effectivity():
    """Disk P3 on fitted meshes: the contact-weighted lam^ with tiny weights off the contact elements keeps the
    contact term at round-off.  Measured 1.005, 1.004 (levels 0-1); with the former weights (1e-3, 1e-6)
    2.16, 6.12 (and 18.5 on level 2)."""
    scene = load_scene("disk_fitted")
    for level, mesh in enumerate(scene.problem.domain.meshes(2)):
        disc = FEMDiscretization(scene.problem, mesh, order=3)
        sol = semismooth_newton(disc.system, *disc.initial_guess(scene.initial_guess), NewtonOptions())
        assert sol.converged
        est = estimate(disc, sol.x, sol.y)
        assert 1.0 <= est.i_eff <= 1.05, (level, est.i_eff)


@pytest.mark.parametrize("scene,p", [("disk", 2), ("test2_fitted", 1), ("test2_fitted", 2), ("test1", 2)])
def test_direct_bound_inequality_holds_for_the_exact_error(scene, p):
    """The quadratic inequality behind eta_direct, E^2 <= A E + B with E = |||u - u~_h||| (exact data here,
    u~_h = u_h), checked with the true error on level 0, where eta_nonc,1 > 0; and eta_direct <= the seed's
    route eta_seed + eta_nonc,1 there."""
    est = study(scene, p)[0]["est"]
    assert est.eta_nonc1 > 0.0
    E = est.err_energy
    A = est.eta_FR + est.eta_quad + est.eta_nonc1 + est.eta_nonc2
    B = est.theta_contact + 0.5 * float(est.eta_C.sum())
    if est.eta_bc == 0.0:
        assert E * E <= A * E + max(B, 0.0)
    assert est.eta_direct <= est.eta_seed + est.eta_nonc1
    assert est.eta >= E


def test_disk_fitted_p1_effectivity_on_every_level():
    """Disk P1 on meshes fitted to the free boundary: 1 <= I_eff <= 1.10 on every level, [JSC20]: 1.034-1.038.

    Measured 1.053, 1.041, 1.036 (levels 0-2; 360-6435 dofs), 1.034 (level 3, 26211 dofs).
    """
    for row in study("disk_fitted", 1):
        assert 1.0 <= row["est"].i_eff <= 1.10, (row["level"], row["est"].i_eff)


@pytest.mark.parametrize("p", [1, 2])
def test_eta_vanishes_for_polynomial_solution_without_contact(p):
    """Membranes far apart, u_alpha in P_p, f constant: sigma = -mu grad u_h exactly, eta = 0."""
    if p == 1:
        u1, u2, f1, f2 = 2 + 0.3 * x + 0.5 * y, -1 + x - y, 0.0, 0.0
    else:
        u1, u2, f1, f2 = 2 + x * x + 0.5 * y, -1 - y * y + x, -2.0 * 1.5, 2.0 * 0.5
    prob = TwoMembraneProblem(CrissCrossSquare(), f1=f1, f2=f2, g1=u1, g2=u2, mu1=1.5, mu2=0.5,
                              exact=ExactSolution(u1, u2))
    disc = FEMDiscretization(prob, prob.domain.mesh(1), order=p)
    sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
    est = estimate(disc, sol.x, sol.y)
    assert est.eta < 1e-10
    assert est.eta_bc == 0.0 and est.eta_nonc1 == 0.0
    cells = est.cell_data()
    assert set(cells) == {"eta_K", "eta_C", "eta_F_u1", "eta_F_u2", "eta_R_u1", "eta_R_u2"}


def test_flux_order_and_signs(solved_scene):
    """RT_0 is also equilibrated (in the means) but less effective than the default RT_1 for p = 1."""
    scene, disc, sol = solved_scene("disk", 1, 1)
    flux0 = reconstruct(SolutionView.of(disc, sol.x, sol.y), 0)
    assert max(v["max_K"] for v in equilibration_defect(disc, flux0).values()) <= 1e-10
    assert [fd.sign for fd in flux0.fields] == [1, -1]
    e0 = estimate(disc, sol.x, sol.y, flux=flux0)
    e1 = estimate(disc, sol.x, sol.y)
    assert 1.0 <= e1.i_eff < e0.i_eff


def test_complementarity_report_at_convergence(solved_scene):
    scene, disc, sol = solved_scene("disk", 0, 1)
    rep = complementarity_report(disc, sol.x, sol.y)
    assert rep["gap_min_nodal"] >= -1e-12 and rep["y_min"] >= -1e-12
    assert rep["product_max_nodal"] <= 1e-12
    assert rep["lam_neg_L2"] <= 1e-12  # p = 1: nodal signs give pointwise signs
    assert rep["contact_product"] >= 0.0


def test_nonconformity_estimator_sees_a_kg_violation(solved_scene):
    """A Newton iterate with u1h < u2h somewhere has eta_nonc1 > 0 and stays a bound."""
    scene, disc, sol = solved_scene("disk", 1, 1, maxit=1)
    assert disc.system.gap(sol.x).min() < 0
    est = estimate(disc, sol.x, sol.y)
    assert est.eta_nonc1 > 0
    assert est.i_eff >= 1.0


def test_gap_terms_are_integrated_on_the_negative_support_only(solved_scene):
    """eta_nonc,1, Theta and |||s~_h - (s_h + w_h)||| integrate IfPos(-gap, ., 0) terms over the elements where
    the gap is negative at a point of the rule only: the same numbers as over the whole mesh (a P2 Newton
    iterate with u1h < u2h on part of the mesh); the values of n = max(-gap, 0) at the points of the
    concentration rule are those of the gap's."""
    from ngsolve import IfPos

    from ngcontact.estimators.terms import (Integrals, admissible_correction, contact_work, corrected_fields,
                                            nonconformity, split)

    scene, disc, sol = solved_scene("disk", 1, 2, maxit=1)
    sv = SolutionView.of(disc, sol.x, sol.y)
    dv, fields = sv.disc, sv.fields
    ig = Integrals.of(dv, EstimatorOptions())
    vals, grads, gap, ggap = corrected_fields(dv, fields, [None] * len(fields))
    nc = nonconformity(sv, ig, gap, ggap, exact_bc=False)
    assert nc.pointwise and 0 < nc.support.sum() < dv.mesh.ne
    whole = split(dv.mus)[1] * np.maximum(ig.ew(IfPos(-gap, ggap * ggap, 0.0)), 0.0)
    assert np.abs(nc.loc - whole).max() <= 1e-14 * whole.max()
    theta = contact_work(ig, fields, grads, nc.n, nc.grad_n, nc.support)
    theta_whole = contact_work(ig, fields, grads, nc.n, nc.grad_n)
    assert theta != 0.0 and abs(theta - theta_whole) <= 1e-13 * abs(theta_whole)
    d, corr, support = admissible_correction(ig, dv.mus, gap, ggap, exact_polynomial_gap=False)
    assert np.array_equal(support, nc.support) and abs(d - nc.eta) <= 1e-13 * nc.eta
    qa = ig.quadrature(10)
    assert np.array_equal(nc.values(qa, qa.values(gap)), qa.values(nc.n))


@pytest.mark.parametrize("maxit", [4, 30])
def test_gap_values_only_where_the_multiplier_is_not_zero(solved_scene, monkeypatch, maxit):
    """The concentrated contact terms evaluate the gap only on the elements where lam^ is not 0 at a point of the
    rule (bound.gap_elements): the estimate is the same as with the gap evaluated everywhere, to rounding (P2, the
    4th Newton iterate, where lam^ and the gap overlap, and the converged solution)."""
    import ngcontact.estimators.bound as bound

    scene, disc, sol = solved_scene("disk", 1, 2, maxit=maxit)
    est = estimate(disc, sol.x, sol.y)
    assert 0 < bound.gap_elements(np.ones((3, 2))).sum()
    monkeypatch.setattr(bound, "gap_elements", lambda lam_values: np.ones(len(lam_values), dtype=bool))
    DiscretizationView.of(disc).cache.clear()
    every = estimate(disc, sol.x, sol.y)
    # the same numbers up to the rounding of NGSolve's vectorized evaluation, which depends on the batch of points
    for name in ("eta", "eta_FR", "eta_nonc2", "eta_nonc3", "eta_direct"):
        assert abs(getattr(est, name) - getattr(every, name)) <= 1e-13 * est.eta, name
    assert np.abs(est.eta_C - every.eta_C).max() <= 1e-13 * np.abs(every.eta_C).sum()


@pytest.mark.slow
def test_estimation_time_vs_newton_at_1e5_dofs():
    """Benchmark (issue 4): estimation <= 2 x Newton solve time, disk P1 level 4 (103491 dofs).

    Measured (results/bench/ESTIMATE.md, one run): estimate 4.63 s (first call), Newton-min cold
    start 5.40 s (20 its): ratio 0.86; nested start 1.58 s (4 its): ratio 2.93.
    """
    import time

    scene = load_scene("disk")
    prob = scene.problem
    disc = FEMDiscretization(prob, prob.domain.mesh(4), order=1)
    assert disc.ndof == 103491
    t0 = time.perf_counter()
    sol = semismooth_newton(disc.system, *disc.initial_guess(scene.initial_guess), NewtonOptions())
    t_newton = time.perf_counter() - t0
    est = estimate(disc, sol.x, sol.y)
    assert 1.0 <= est.i_eff <= 1.10
    assert est.time_total <= 2.0 * t_newton, (est.time_total, t_newton)


def test_contact_multiplier_moments_and_support(solve_one):
    """ContactMultiplier (p >= 2): (lam^, psi_a) equals the hat moment of the discrete multiplier at every
    interior vertex (patch compatibility, to round-off), and on the mesh fitted to the contact boundary
    (level 1) lam^ ~ lam = 2g inside r < 1/sqrt 2 (within 10 %) and ~0 outside (within 1 % of 2g), where
    the continuous P1 fit with the same moments is off by >= 30 % next to the jump."""
    from ngsolve import H1, VOL, CoefficientFunction, Integrate, IntegrationRule, LinearForm, dx as ngdx

    from ngcontact.domains import DIRICHLET
    from ngcontact.estimators.moments import data_rules
    from ngcontact.estimators.multipliers import ContactMultiplier, multiplier_p1

    scene = load_scene("disk_fitted")
    disc, sol = solve_one(scene.problem, 1, 2, init=scene.initial_guess)
    sv = SolutionView.of(disc, sol.x, sol.y)
    gfs = sv.gfs
    lam = ContactMultiplier(sv.disc, sol.y)(disc.D * sol.y)
    V = H1(disc.mesh, order=1, dirichlet=DIRICHLET)
    v = V.TestFunction()
    rule = data_rules(sv.disc)["mass"]
    got = LinearForm(lam * v * ngdx(intrules=rule)).Assemble().vec.FV().NumPy()
    want = LinearForm(gfs["lam"] * v * ngdx(intrules=rule)).Assemble().vec.FV().NumPy()
    free = np.array(list(V.FreeDofs()), dtype=bool)
    assert np.abs(got - want)[free].max() <= 1e-12 * np.abs(want).max()
    # values at the element vertices, split by the element centroid radius
    mesh = disc.mesh
    ir = IntegrationRule(points=[(0, 0), (1, 0), (0, 1), (1 / 3, 1 / 3)], weights=[0.0] * 4)
    r = np.sqrt(np.asarray((CoefficientFunction((x * x + y * y)))(mesh.MapToAllElements(ir, VOL)))).reshape(mesh.ne, 4)[:, 3]
    rho, g = 1 / np.sqrt(2), 0.05
    for name, cf in (("contact", lam), ("p1", multiplier_p1(sv))):
        vals = np.asarray(cf(mesh.MapToAllElements(ir, VOL))).reshape(mesh.ne, 4)[:, :3]
        err_in = np.abs(vals[r < rho] - 2 * g).max()
        err_out = np.abs(vals[r > rho]).max()
        if name == "contact":
            assert err_in <= 0.1 * 2 * g and err_out <= 0.01 * 2 * g, (err_in, err_out)  # measured 7.6 %, 0.1 %
        else:  # the smeared fit, for contrast: O(1) relative error next to r = rho
            assert max(err_in, err_out) >= 0.3 * 2 * g, (err_in, err_out)
    assert Integrate(lam * lam * ngdx, mesh) > 0


def test_patch_contact_multiplier(solve_one):
    """PatchContactMultiplier (p >= 2, q <= 2): patch compatibility sum_K g_a|_K (psi_a, 1)_K = m_a at every
    vertex, lam^ >= 0, zero on the elements outside the contact set of the fitted disk, ~2g inside."""
    from ngsolve import VOL, CoefficientFunction, IntegrationRule

    from ngcontact.estimators.moments import vertex_moments
    from ngcontact.estimators.multipliers import PatchContactMultiplier

    scene = load_scene("disk_fitted")
    disc, sol = solve_one(scene.problem, 1, 2, init=scene.initial_guess)
    dv = DiscretizationView.of(disc)
    pm = PatchContactMultiplier(dv, sol.y)
    lam = pm(disc.D * sol.y)
    vals = lam.vec.FV().NumPy().reshape(disc.mesh.ne, 3)  # vertex values per element
    Psi, vol, _ = vertex_moments(dv)
    m = Psi.T @ (disc.D * sol.y)
    ev = dv.element_vertices()
    moments = np.bincount(ev.ravel(), weights=(vals * dv.cache["vol_ka"]).ravel(), minlength=disc.mesh.nv)
    assert np.abs(moments - m).max() <= 1e-12 * np.abs(m).max()
    assert vals.min() >= 0.0
    mesh = disc.mesh
    ir = IntegrationRule(points=[(1 / 3, 1 / 3)], weights=[0.0])
    r = np.sqrt(np.asarray(CoefficientFunction(x * x + y * y)(mesh.MapToAllElements(ir, VOL))).ravel())
    rho, g = 1 / np.sqrt(2), 0.05
    assert vals[r > rho].max() == 0.0
    assert np.abs(vals[r < rho] - 2 * g).max() <= 0.05 * 2 * g  # measured 3.0 % (level 1)
    assert pm.n_contact_elements == int((r < rho).sum())


def test_dirichlet_correction_enters_the_marking_indicators():
    """Non-polynomial Dirichlet data (test 1): the element parts bc_K of the data correction sum to
    eta_bc^2 + eps_w^2 and are part of eta_K (the adaptive loop refines where they are large); exact
    data (disk): no bc_K."""
    est = study("test1", 1)[1]["est"]
    assert est.bc_K is not None and est.eta_bc > 0
    assert abs(est.bc_K.sum() - (est.eta_bc ** 2 + est.eps_w ** 2)) <= 1e-10 * (est.eta_bc ** 2 + est.eps_w ** 2)
    base = ((est.eta_F + est.eta_R) ** 2).sum(axis=0) + np.maximum(est.eta_C, 0.0)
    nonc1_K = est.nonc1_K if est.nonc1_K is not None else 0.0
    assert np.allclose(est.eta_K ** 2, base + est.bc_K + nonc1_K)
    assert study("disk", 1)[0]["est"].bc_K is None


def test_test2_fitted_p2_effectivity_decreases_to_published_range():
    """Test 2, P2, on meshes fitted to r = R (the jump of f and lam): the error converges at rate 2 (on the
    criss-cross meshes: 1.93, 1.76, 1.83, 1.67 on T1-T4) and I_eff decreases level by level to <= 1.2
    (unfitted: 1.905 -> 2.939 on T0-T4, growing).

    Measured (cold start, results/estimators/TABLES.md): I_eff 1.441, 1.247, 1.130, 1.073 (levels 0-3;
    before the contact-weighted lam^ on curved elements and the direct bound: 2.208, 1.586, 1.325, 1.199);
    the coarse levels are dominated by the Dirichlet-data terms eta_bc, eps_w and eta_nonc,1.
    """
    rows = study("test2_fitted", 2)
    effs = [r["est"].i_eff for r in rows]
    assert all(b < a for a, b in zip(effs, effs[1:])), effs
    assert effs[-1] <= 1.2, effs
    h = [r["h"] for r in rows]
    assert fitted_rate(h, [r["est"].err_energy for r in rows], last=2) >= 1.9


@pytest.mark.slow
def test_curved_patch_regularization_keeps_test2_fitted_p2_sharp_on_level_4():
    """Regression (flux.patch_regularization): with eps = 1e-12 on curved meshes one interface patch of
    test2_fitted P2 level 4 (88131 dofs) amplified the quadrature incompatibility of its data and alone made
    I_eff 4.85; eps = 1e-10 gave 1.122 (1e-8, 1e-6 the same to 4 digits; PatchwiseSolve, before the direct
    bound); the default estimate now gives 1.044 (results/estimators/TABLES.md, T4)."""
    scene = load_scene("test2_fitted")
    mesh = list(scene.problem.domain.meshes(5))[-1]
    disc = FEMDiscretization(scene.problem, mesh, order=2)
    sol = semismooth_newton(disc.system, *disc.initial_guess(scene.initial_guess), NewtonOptions())
    assert sol.converged
    est = estimate(disc, sol.x, sol.y)
    assert 1.0 <= est.i_eff <= 1.2, est.i_eff


def test_dirichlet_lifting_in_a_boundary_strip():
    """w_h lives in the strip of STRIP_LAYERS element layers along the Dirichlet boundary and vanishes beyond;
    with enough layers to cover the mesh it is the global discrete harmonic lifting.  A thin strip (one
    layer) gives a larger but still guaranteed estimate (test 1, P1, level 3: the lifting of the one-signed P1
    trace error decays slowly; 8 layers: 1.118 vs 1.109 global on level 5)."""
    from ngcontact.estimators import dirichlet as E

    scene = load_scene("test1")
    mesh = list(scene.problem.domain.meshes(4))[-1]
    disc = FEMDiscretization(scene.problem, mesh, order=1)
    sol = semismooth_newton(disc.system, *disc.initial_guess(scene.initial_guess), NewtonOptions())
    sv = SolutionView.of(disc, sol.x, sol.y)
    thin = E.dirichlet_correction(sv.disc, sv.fields, 3, 3, layers=1)
    full = E.dirichlet_correction(sv.disc, sv.fields, 3, 3, layers=10 ** 6)
    strip, _ = E.boundary_strip(sv.disc, 1)
    w_off = Integrate(thin[0][0] ** 2 * dx, mesh, element_wise=True).NumPy()[~strip]
    assert strip.any() and (~strip).any() and np.abs(w_off).max() == 0.0
    assert thin[1] >= full[1] > 0.0  # |||w_h||| of the global discrete harmonic lifting is the smallest
    old = E.STRIP_LAYERS
    try:
        E.STRIP_LAYERS = 1
        est = estimate(disc, sol.x, sol.y)
    finally:
        E.STRIP_LAYERS = old
    assert est.eta >= est.err_energy


def test_dirichlet_strip_is_two_layers_for_p_at_least_2(monkeypatch):
    """p >= 2: the Dirichlet lifting lives on a strip of STRIP_LAYERS_HIGH = 2 layers (its trace error oscillates
    along the edges and the lifting decays within it; results/estimators/STRIP_LAYERS.md): w_h vanishes beyond
    two layers and reaches into the second, and the estimate stays guaranteed and within 1 % of the one with the
    P1 strip of 8 layers (test 1, P2, level 2)."""
    from ngcontact.estimators import dirichlet as E

    assert E.strip_layers(1) == E.STRIP_LAYERS == 8 and E.strip_layers(2) == E.strip_layers(4) == 2
    scene = load_scene("test1")
    mesh = list(scene.problem.domain.meshes(3))[-1]
    disc = FEMDiscretization(scene.problem, mesh, order=2)
    sol = semismooth_newton(disc.system, *disc.initial_guess(scene.initial_guess), NewtonOptions())
    sv = SolutionView.of(disc, sol.x, sol.y)
    ws = E.dirichlet_lifting(sv.disc, sv.fields, True)[0]
    two, _ = E.boundary_strip(sv.disc, 2)
    one, _ = E.boundary_strip(sv.disc, 1)
    w2 = Integrate(ws[0] ** 2 * dx, mesh, element_wise=True).NumPy()
    assert (~two).any() and np.abs(w2[~two]).max() == 0.0 and np.abs(w2[two & ~one]).max() > 0.0
    est = estimate(disc, sol.x, sol.y)
    monkeypatch.setattr(E, "STRIP_LAYERS_HIGH", 8)
    wide = estimate(disc, sol.x, sol.y)
    assert est.eta >= est.err_energy and abs(est.eta / wide.eta - 1.0) <= 0.01


def test_dirichlet_strip_follows_the_part_of_the_boundary_with_a_trace_to_lift(monkeypatch):
    """The strip of the lifting grows from the boundary elements where the trace Pi g - u_h is above round-off of g:
    L-shape P3 with the re-entrant corner refined 12 times -- g vanishes on the corner's edges except for the P3
    interpolation error of phi (O(h^4), below 1e-13 |g| on the smallest edges) -- gives a smaller strip than the
    whole Dirichlet boundary's, w_h vanishes off it, and eta_bc, eps_w agree with the whole strip's to 1e-6."""
    from ngcontact.estimators import dirichlet as E
    from ngcontact.discretizations.base import bit_mask
    from ngcontact.domains import DIRICHLET
    from ngsolve import H1

    scene = load_scene("lshape")
    mesh = scene.problem.domain.mesh(0)
    for _ in range(12):
        for el in mesh.Elements():
            mesh.SetRefinementFlag(el, any(np.hypot(*mesh[v].point) < 1e-12 for v in el.vertices))
        mesh.Refine()
    disc = FEMDiscretization(scene.problem, mesh, order=3)
    sol = semismooth_newton(disc.system, *disc.initial_guess(scene.initial_guess), NewtonOptions())
    sv = SolutionView.of(disc, sol.x, sol.y)
    strips = []
    plain = E.boundary_strip
    monkeypatch.setattr(E, "boundary_strip", lambda dv, layers, seed=None: strips.append(plain(dv, layers, seed))
                        or strips[-1])
    ws, bc, eps, _ = E.dirichlet_correction(sv.disc, sv.fields, 5, 5)
    seeded, whole = strips[-1][0], plain(sv.disc, 2)[0]
    assert seeded.sum() < whole.sum() and not (seeded & ~whole).any()
    for w in ws:
        w_off = Integrate(w ** 2 * dx, mesh, element_wise=True).NumPy()[~seeded]
        assert np.abs(w_off).max() == 0.0
    dirichlet = ~bit_mask(H1(mesh, order=1, dirichlet=DIRICHLET).FreeDofs())[:mesh.nv]
    monkeypatch.setattr(E, "trace_vertices", lambda V, dofs, nv: dirichlet)
    _, bc_whole, eps_whole, _ = E.dirichlet_correction(sv.disc, sv.fields, 5, 5)
    assert strips[-1][0].sum() == whole.sum()
    assert abs(bc / bc_whole - 1) <= 1e-6 and abs(eps / eps_whole - 1) <= 1e-6 and bc > 0 and eps > 0


def test_dirichlet_correction_scales_with_the_data():
    """The lifting's 'nothing to lift' threshold is in the units of g: test 1 (P1) with data x 1e-50 gets eta_bc and
    eps_w x 1e-50 and the baseline's I_eff (with a threshold fixed at 1e-13 the lifting was dropped there)."""
    from ngcontact.estimators import dirichlet as E
    from ngcontact.problems.manufactured import scale_problem

    scene = load_scene("test1")
    out = []
    for scale in (1.0, 1e-50):
        problem = scale_problem(scene.problem, data=scale)
        disc = FEMDiscretization(problem, problem.domain.mesh(1), order=1)
        sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
        sv = SolutionView.of(disc, sol.x, sol.y)
        _, bc, eps, _ = E.dirichlet_correction(sv.disc, sv.fields, 3, 3)
        out.append((bc / scale, eps / scale, estimate(disc, sol.x, sol.y).i_eff))
    (bc1, eps1, i1), (bc2, eps2, i2) = out
    assert bc1 > 0 and eps1 > 0
    assert abs(bc2 / bc1 - 1) <= 1e-8 and abs(eps2 / eps1 - 1) <= 1e-8 and abs(i2 / i1 - 1) <= 1e-8


def test_contact_fit_reweighting_removes_negative_lobes(solved_scene):
    """L-shape P3 (continuous free boundary): the reweighted contact fit of lam^ has no negative part left
    (eta_nonc,2 at round-off) and a smaller estimate than the plain fit (measured I_eff 1.464 -> 1.387)."""
    from ngcontact.estimators import multipliers as FL

    scene, disc, sol = solved_scene("lshape", 0, 3)
    fit = EstimatorOptions(multiplier="fit")
    est = estimate(disc, sol.x, sol.y, fit)
    old = FL.ContactMultiplier.ROUNDS
    try:
        FL.ContactMultiplier.ROUNDS = 0
        plain = estimate(disc, sol.x, sol.y, fit)
    finally:
        FL.ContactMultiplier.ROUNDS = old
    assert plain.eta_nonc2 > 1e-3 * plain.eta
    assert est.eta_nonc2 <= 1e-10 * est.eta
    assert est.err_energy <= est.eta < plain.eta


def test_contact_fit_matrices_are_kept_for_the_same_weights(solved_scene):
    """The contact-weighted fit keeps its weighted mass matrices and factorizations per discretization: the same
    iterate again (the same contact set and reweighting rounds, as between the evaluations inside a Newton step)
    factorizes nothing and gives the same estimate; another contact set adds new ones."""
    from ngcontact.estimators.view import DiscretizationView

    scene, disc, sol = solved_scene("lshape", 0, 3)
    fit = EstimatorOptions(multiplier="fit")
    first = estimate(disc, sol.x, sol.y, fit)
    kept = DiscretizationView.of(disc).cache["contact_fit_matrices"]
    before = [id(e[2]) for e in kept]
    again = estimate(disc, sol.x, sol.y, fit)
    assert [id(e[2]) for e in kept] == before
    assert again.eta == pytest.approx(first.eta, rel=1e-12)
    y = np.where(np.arange(len(sol.y)) % 2 == 0, sol.y, 0.0)  # half of the contact vertices
    estimate(disc, sol.x, y, fit)
    assert [id(e[2]) for e in kept] != before


@pytest.mark.parametrize("scene,p,level,expect", [("lshape", 3, 0, None), ("disk_fitted", 3, 0, "fit")])
def test_default_multiplier_is_the_smaller_of_fit_and_shape(scene, p, level, expect):
    """RT_3: the default estimate is the smaller of the two guaranteed bounds (contact-weighted fit,
    shaped patch sources); on the fitted disk (lam jumps at the free boundary) the fit wins by far,
    and the shaped multiplier is nonnegative (eta_nonc,2 = 0)."""
    sc = load_scene(scene)
    disc = FEMDiscretization(sc.problem, list(sc.problem.domain.meshes(level + 1))[level], order=p)
    sol = semismooth_newton(disc.system, *disc.initial_guess(sc.initial_guess), NewtonOptions())
    est = estimate(disc, sol.x, sol.y)
    fit = estimate(disc, sol.x, sol.y, EstimatorOptions(multiplier="fit"))
    shape = estimate(disc, sol.x, sol.y, EstimatorOptions(multiplier="shape"))
    assert est.eta == pytest.approx(min(fit.eta, shape.eta), rel=1e-10)  # first call: solves, later: kept inverses
    assert est.multiplier == ("fit" if fit.eta <= shape.eta else "shape")
    assert shape.eta_nonc2 == 0.0
    assert min(fit.eta, shape.eta) >= est.err_energy
    if expect:
        assert est.multiplier == expect and shape.eta > 2 * fit.eta


def test_marking_indicators_carry_the_nonconformity():
    """eta_K (the marking indicators) holds the element parts of eta_nonc,1^2 as well as those of the flux,
    residual, contact, Dirichlet and multiplier terms: on the disk P2 (eta_nonc,1 > 0 on every level)."""
    for row in study("disk", 2):
        est = row["est"]
        assert est.eta_nonc1 > 0.0
        assert est.nonc1_K is not None and np.all(est.nonc1_K >= 0.0)
        assert abs(est.nonc1_K.sum() - est.eta_nonc1 ** 2) <= 1e-10 * est.eta_nonc1 ** 2
        base = ((est.eta_F + est.eta_R) ** 2).sum() + np.maximum(est.eta_C, 0.0).sum()
        assert (est.eta_K ** 2).sum() >= base + 0.999 * est.eta_nonc1 ** 2


def test_estimator_options_are_validated_once():
    """Bad option values are refused when the options are made, naming the field and the value; the RT
    degrees are resolved from p in one method each."""
    for kw, what in [(dict(flux_order=-1), "flux_order.*-1"), (dict(flux_order=True), "flux_order.*True"),
                     (dict(alg_flux_order=1.5), "alg_flux_order.*1.5"), (dict(multiplier="lumped"), "multiplier.*lumped"),
                     (dict(dirichlet_correction="slow"), "dirichlet_correction.*slow"),
                     (dict(friedrichs=0.0), "friedrichs.*0.0"), (dict(batched=1), "batched.*1"),
                     (dict(concentrate="yes"), "concentrate.*yes"), (dict(res_tol=-1.0), "res_tol.*-1.0")]:
        with pytest.raises(ValueError, match="option " + what):
            EstimatorOptions(**kw)
    assert [EstimatorOptions().flux_degree(p) for p in (1, 2, 3)] == [1, 2, 3]
    assert EstimatorOptions(flux_order=3).flux_degree(2) == 3
    with pytest.raises(ValueError, match="flux_order must be p = 2 or p \\+ 1 = 3.*got 4"):
        EstimatorOptions(flux_order=4).flux_degree(2)
    assert [EstimatorOptions().alg_flux_degree(p) for p in (1, 2, 3)] == [0, 1, 2]
    assert EstimatorOptions(alg_flux_order=2).alg_flux_degree(1) == 2


def test_energy_error_from_the_caller(solved_scene):
    """estimate(..., err_energy=e) reports e and i_eff = eta / e; with e the energy error, the summary equals
    that of the estimate computing the error itself (columns, order and values; times aside).  The flux degree
    of the options reaches the fluxes."""
    scene, disc, sol = solved_scene("disk", 0, 1)
    own = estimate(disc, sol.x, sol.y)
    err = disc.errors(sol.x, sol.y)["err_energy"]
    given = estimate(disc, sol.x, sol.y, err_energy=err, errors=False)
    a, b = own.summary(), given.summary()
    assert list(a) == list(b) and list(a)[-2:] == ["time_estimate_s", "i_eff"]
    # equal up to the round-off of NGSolve's threaded integration (sums in a varying order)
    assert {k: v for k, v in b.items() if k != "time_estimate_s"} == pytest.approx(
        {k: v for k, v in a.items() if k != "time_estimate_s"}, rel=1e-12, abs=1e-15 * a["eta"])
    assert estimate(disc, sol.x, sol.y, err_energy=2 * err, errors=False).i_eff == pytest.approx(own.i_eff / 2)
    assert "i_eff" not in estimate(disc, sol.x, sol.y, errors=False).summary()
    assert estimate(disc, sol.x, sol.y, EstimatorOptions(flux_order=2)).flux.order == 2


def test_negative_part_of_a_nonnegative_p1_function_is_zero_without_quadrature():
    """negative_part_squares: a P1 GridFunction with nonnegative coefficients gives zeros (no quadrature), as the
    quadrature of (lam^-)^2 does; one negative vertex value, or a P2 function (negative also with nonnegative
    coefficients), goes through the quadrature."""
    from ngsolve import H1, GridFunction, IfPos

    from ngcontact.estimators.options import EstimatorOptions as Opts
    from ngcontact.estimators.terms import Integrals, negative_part_squares

    scene = load_scene("test1")
    mesh = list(scene.problem.domain.meshes(2))[-1]
    disc = FEMDiscretization(scene.problem, mesh, order=1)
    ig = Integrals.of(DiscretizationView.of(disc), Opts())
    for order in (1, 2):
        lam = GridFunction(H1(mesh, order=order))
        lam.Set(1 + x * y)
        vals = negative_part_squares(ig, lam)
        ref = ig.ew(IfPos(-lam, lam * lam, 0.0))
        assert np.array_equal(vals, ref)
        assert order > 1 or not vals.any()
        lam.vec.FV().NumPy()[0] = -1.0
        vals = negative_part_squares(ig, lam)
        assert vals.max() > 0.0 and np.array_equal(vals, ig.ew(IfPos(-lam, lam * lam, 0.0)))
    # P2 with nonnegative coefficients can be negative (NGSolve's edge functions): no shortcut there
    lam.vec.FV().NumPy()[:] = 0.0
    lam.vec.FV().NumPy()[mesh.nv] = 1.0
    assert negative_part_squares(ig, lam).max() > 0.0


def test_concentrated_multiplier_against_explicit_candidates():
    """concentrated_multiplier (candidate sums from products with the shape matrix) returns lam~ >= 0 with the
    element means of lam^, the defect (h/pi)^2 ||lam^ - lam~||_K^2 summed directly, and the choice of the
    search over explicitly formed candidates c = m_K phi / mean_K(phi): the same objective value."""
    import math
    from types import SimpleNamespace

    from ngsolve import TRIG, IntegrationRule

    from ngcontact.estimators.nonnegative import concentrated_multiplier

    ir = IntegrationRule(TRIG, 8)
    ref = np.array([ip.point[:2] for ip in ir])
    bary = np.stack([ref[:, 0], ref[:, 1], 1 - ref[:, 0] - ref[:, 1]])
    rng = np.random.default_rng(7)
    n = 400
    det = rng.uniform(1e-4, 1e-2, n)
    W = np.array([ip.weight for ip in ir])[None] * det[:, None]
    lam = np.maximum(rng.standard_normal((n, len(ref))) + 0.7, 0.0)
    lam[:50] = 0.0
    # gaps small near a random vertex of each element: concentrating there pays
    gap = 0.1 * rng.random(n)[:, None] * (bary[rng.integers(0, 3, n)] + 0.05 * rng.random((n, len(ref))))
    h, C_mu, scale = np.sqrt(det), 1.3, 2e-3
    qa = SimpleNamespace(W=W, bary=bary)
    lam_t, loc2 = concentrated_multiplier(qa, lam, gap, h, C_mu, scale)
    area = W.sum(axis=1)
    assert lam_t.min() >= 0.0
    assert np.abs((W * lam_t).sum(axis=1) - (W * lam).sum(axis=1)).max() <= 1e-12 * np.abs(W * lam).sum(axis=1).max()
    hk = (h / math.pi) ** 2
    assert np.array_equal(loc2, hk * (W * (lam - lam_t) ** 2).sum(axis=1))
    moved = np.abs(lam_t - lam).max(axis=1) > 0
    assert 50 < moved.sum() < n - 50  # the search moves some elements and keeps others

    def objective(lt):
        return (scale + C_mu * math.sqrt((hk * (W * (lam - lt) ** 2).sum(axis=1)).sum())) ** 2 + 2.0 * (W * lt * gap).sum()

    # explicit search: candidates formed one by one, the same price sweep
    m = (W * lam).sum(axis=1) / area
    cands = [lam] + [m[:, None] * phi[None] / ((W * phi[None]).sum(axis=1) / area)[:, None]
                     for k in (1, 2, 4) for phi in [bary[i] ** k for i in range(3)] + [(1 - bary[i]) ** k for i in range(3)]]
    C = np.array([(W * c * gap).sum(axis=1) for c in cands])
    X = np.array([hk * (W * (lam - c) ** 2).sum(axis=1) for c in cands])
    cols = np.arange(n)
    best = lam
    for t in np.logspace(-3, 6, 46) * C_mu / scale * np.abs(C).max() / X.max():
        idx = np.argmin(2.0 * C + t * X, axis=0)
        trial = np.array([cands[j][i] for i, j in zip(cols, idx)])
        if objective(trial) < objective(best):
            best = trial
    assert objective(best) < objective(lam)
    assert objective(lam_t) == pytest.approx(objective(best), rel=1e-12)


def test_strip_study_table_reports_estimation_over_solve():
    """The adaptive row of make strip-study carries the ratio estimation / Newton solve of the last levels."""
    from ngcontact.studies.strip_layers import _table

    adaptive = {2: {"levels": 24, "t_1e-5": 20.3, "t_1e-5_run": 18.1, "t_estimate": 13.3, "t_solve": 4.8,
                    "i_eff_last": [1.18, 1.15, 1.14], "est_over_solve": [2.5, 2.25, 2.0, 1.5]}}
    text = _table({}, adaptive)
    assert "| estimation / solve, last 4 levels |" in text
    assert "| 2 | 24 | 20.3 | 18.1 | 13.3 | 4.8 | 1.180 1.150 1.140 | 2.50 2.25 2.00 1.50 |" in text


def test_strip_study_run_times_leave_out_the_exact_error_evaluations():
    """The time to 1e-5 'without the exact errors' subtracts every level's time_post_s up to that level."""
    from ngcontact.studies.strip_layers import run_times

    rows = [{"time_cum_s": 1.0, "time_post_s": 0.25}, {"time_cum_s": 3.0, "time_post_s": 0.5},
            {"time_cum_s": 7.0, "time_post_s": 1.0}]
    assert run_times(rows) == [0.75, 2.25, 5.25]


def _singular_boundary_data(x0: float):
    """Obstacle problem far below u = r^{1/2} cos(theta/2) around (x0, 0) (harmonic, f = 0, no contact); g = u is
    singular inside the bottom edge when x0 is not a mesh vertex."""
    from ngsolve import CoefficientFunction, atan2, cos, sin
    from ngcontact import ObstacleProblem

    r2, th = (x - x0) ** 2 + y ** 2, atan2(y, x - x0)
    u = r2 ** 0.25 * cos(th / 2)
    grad_u = CoefficientFunction((0.5 * r2 ** -0.25 * cos(th / 2), 0.5 * r2 ** -0.25 * sin(th / 2)))
    return ObstacleProblem(domain=CrissCrossSquare(n0=4), psi=-10.0 + 0 * x, f=0.0, g=u,
                           exact=ExactSolution(u1=u, grad_u1=grad_u), name="singular_bc")


def test_trace_defect_flags_dirichlet_data_singular_inside_an_edge():
    """g singular inside a boundary edge (x0 = 0.4, not a vertex): the part g - Pi g that w_h leaves out is not
    small, and the estimate says its bound is not proven (eta_trace > 0.1 eta; the outside audit's P3 run had
    I_eff 0.79 there).  With the singular point at a vertex (x0 = 0.5) the trace is still (x - 0.5)_+^{1/2} on the
    edges next to it: not proven either (the audit's runs there had I_eff >= 1.04, which the proof does not
    cover).  Test 1's smooth data from level 1 on are proven; polynomial data have eta_trace = 0."""
    out = {}
    for x0 in (0.4, 0.5):
        problem = _singular_boundary_data(x0)
        disc = FEMDiscretization(problem, problem.domain.mesh(1), order=2)
        sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
        out[x0] = estimate(disc, sol.x, sol.y)
    assert out[0.4].eta_trace > 0.1 * out[0.4].eta and not out[0.4].bound_proven
    assert "not resolved on the boundary" in out[0.4].why_not_proven
    assert out[0.4].summary()["bound_proven"] == 0
    assert out[0.5].eta_trace > 0.1 * out[0.5].eta and not out[0.5].bound_proven
    scene = load_scene("test1")
    disc = FEMDiscretization(scene.problem, scene.problem.domain.mesh(1), order=1)
    sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
    est = estimate(disc, sol.x, sol.y)
    assert 0 < est.eta_trace <= 0.05 * est.eta and est.bound_proven and est.why_not_proven == ""
    # without the correction the trace of u_h itself (degree p) is what the proof takes as exact
    off = estimate(disc, sol.x, sol.y, EstimatorOptions(dirichlet_correction=False))
    assert off.eta_trace > 0.1 * off.eta and not off.bound_proven
    scene = load_scene("disk")  # polynomial Dirichlet data
    disc = FEMDiscretization(scene.problem, scene.problem.domain.mesh(0), order=1)
    sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
    assert estimate(disc, sol.x, sol.y).eta_trace == 0.0


def test_trace_defect_scales_with_the_data():
    """eta_trace is in the units of eta: the singular data x 1e-8 and x 1e8 give eta_trace / eta of the baseline."""
    from ngcontact.problems.manufactured import scale_problem

    ratios = []
    for scale in (1.0, 1e-8, 1e8):
        problem = scale_problem(_singular_boundary_data(0.4), data=scale)
        disc = FEMDiscretization(problem, problem.domain.mesh(0), order=1)
        sol = semismooth_newton(disc.system, *disc.initial_guess(None), NewtonOptions())
        est = estimate(disc, sol.x, sol.y)
        ratios.append(est.eta_trace / est.eta)
    assert ratios[0] > 0.1
    assert max(abs(r / ratios[0] - 1) for r in ratios) <= 1e-8


def test_adaptive_target_reached_by_an_unproven_bound_says_so():
    """An adaptive run whose target eta is met by an estimate that is not a proven bound (Dirichlet data singular
    inside an edge) names that in its stop reason, not only in the level's caveat (outside review, stop 49)."""
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.scenes import Scene

    problem = _singular_boundary_data(0.4)
    result = run_scene(Scene(name="singular_bc", path=None, problem=problem),
                       RunOptions(order=1, adaptive=True, target_eta=10.0, max_levels=3))
    assert result.stop_reason.startswith("target_eta") and "not a proven bound" in result.stop_reason
    assert result.caveats and result.caveats[0].startswith("level 0: error bound eta not proven")
