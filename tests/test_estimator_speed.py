"""The fast paths of the estimate give the values of the plain ones (to round-off).

* :func:`ngcontact.estimators.flux.reconstruct_several` (the two multiplier candidates of RT_3 in one batched
  patch solve) against one :func:`~ngcontact.estimators.flux.reconstruct` per multiplier;
* the default estimate (candidates sharing their multiplier-independent terms) against the estimate with the
  chosen multiplier alone, component by component;
* :func:`ngcontact.estimators.boundary.residual_multiplier` on straight elements (a P_{p-2} GridFunction)
  against its defining expression with the Hessians of the fields;
* eta_F by the exact rule of :func:`ngcontact.estimators.terms.flux_rule_order` against the estimator quadrature;
* the multiplier's support (:attr:`ngcontact.estimators.flux.FluxReconstruction.lam_support`): lam^ vanishes outside
  it, and the estimate restricted to it equals the one over all elements; quadrature arrays on some elements are the
  rows of those on all; the element means of the flux residual from their parts against the plain rule.
"""
import numpy as np
import pytest
from ngsolve import L2, GridFunction, Integrate, Trace, dx

from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.estimators import EstimatorOptions, estimate
from ngcontact.estimators.boundary import residual_multiplier
from ngcontact.estimators.dirichlet import dirichlet_lifting
from ngcontact.estimators.flux import reconstruct, reconstruct_several
from ngcontact.estimators.terms import Integrals, corrected_fields, flux_residual, flux_rule_order
from ngcontact.estimators.view import SolutionView
from ngcontact.newton.loop import NewtonOptions, semismooth_newton
from ngcontact.scenes import load_scene


@pytest.fixture(scope="module")
def lshape_p3():
    sc = load_scene("lshape")
    disc = FEMDiscretization(sc.problem, sc.problem.domain.mesh(0), order=3)
    sol = semismooth_newton(disc.system, *disc.initial_guess(sc.initial_guess), NewtonOptions())
    return disc, sol


def test_reconstruct_several_equals_one_solve_per_multiplier(lshape_p3):
    disc, sol = lshape_p3
    sv = SolutionView.of(disc, sol.x, sol.y)
    joint = reconstruct_several(sv, 3, ("fit", "shape"))
    for m, fl in zip(("fit", "shape"), joint):
        alone = reconstruct(sv, 3, multiplier=m)
        assert len(fl.sigma) == len(alone.sigma) == 2
        for a, b in zip(fl.sigma, alone.sigma):
            va, vb = a.vec.FV().NumPy(), b.vec.FV().NumPy()
            assert np.abs(va - vb).max() <= 1e-12 * np.abs(vb).max()
        assert fl.lam_order == alone.lam_order and fl.lam_rule == alone.lam_rule
        dlam = Integrate((fl.lam - alone.lam) ** 2 * dx, disc.mesh)
        assert dlam <= 1e-24 * Integrate(alone.lam ** 2 * dx, disc.mesh)


def test_default_estimate_equals_the_estimate_with_the_chosen_multiplier(lshape_p3):
    disc, sol = lshape_p3
    est = estimate(disc, sol.x, sol.y)
    alone = estimate(disc, sol.x, sol.y, EstimatorOptions(multiplier=est.multiplier))
    a, b = est.summary(), alone.summary()
    for key in a:
        if key != "time_estimate_s":
            assert a[key] == pytest.approx(b[key], rel=1e-12, abs=1e-14 * b["eta"]), key
    for name in ("eta_F", "eta_R", "eta_C", "eta_K", "nonc1_K", "nonc2_K"):
        va, vb = np.asarray(getattr(est, name)), np.asarray(getattr(alone, name))
        assert np.abs(va - vb).max() <= 1e-12 * max(np.abs(vb).max(), 1e-300), name


@pytest.mark.parametrize("p", [2, 3])
def test_residual_multiplier_on_straight_elements_is_the_element_residual(lshape_p3, p):
    sc = load_scene("lshape")
    if p == 3:
        disc, sol = lshape_p3
    else:
        disc = FEMDiscretization(sc.problem, sc.problem.domain.mesh(0), order=p)
        sol = semismooth_newton(disc.system, *disc.initial_guess(sc.initial_guess), NewtonOptions())
    sv = SolutionView.of(disc, sol.x, sol.y)
    rho = residual_multiplier(sv)
    assert isinstance(rho, GridFunction)
    # rho_h = (sum_a s_a (-mu_a Lap u_ah - Pi f_a) / mu_a) / (sum_a 1 / mu_a), Pi onto P_{p-2}(K)
    Q = L2(disc.mesh, order=p - 2)
    num, den = 0.0, 0.0
    for fd in sv.fields:
        f = GridFunction(Q)
        f.Set(fd.f, bonus_intorder=disc.quad_bonus + 4)
        num = num + (fd.sign / fd.mu) * (-fd.mu * Trace(fd.u.Operator("hesse")) - f)
        den += 1.0 / fd.mu
    cf = num / den
    diff = Integrate((rho - cf) ** 2 * dx(bonus_intorder=4), disc.mesh, element_wise=True).NumPy()
    ref = Integrate(cf ** 2 * dx(bonus_intorder=4), disc.mesh, element_wise=True).NumPy()
    assert ref.sum() > 0.0
    assert np.sqrt(diff.max()) <= 1e-12 * np.sqrt(ref.max())


@pytest.mark.parametrize("scene,p", [("lshape", 3), ("disk", 1), ("test1", 2)])
def test_flux_term_by_the_exact_polynomial_rule(scene, p):
    """eta_F by the rule of :func:`~ngcontact.estimators.terms.flux_rule_order` (exact for |fl|^2 on straight
    elements) equals eta_F by the estimator quadrature ``dxq`` to round-off."""
    sc = load_scene(scene)
    disc = FEMDiscretization(sc.problem, sc.problem.domain.mesh(0), order=p)
    sol = semismooth_newton(disc.system, *disc.initial_guess(sc.initial_guess), NewtonOptions())
    sv = SolutionView.of(disc, sol.x, sol.y)
    dv, fields = sv.disc, sv.fields
    q = EstimatorOptions().flux_degree(p)
    fl = reconstruct(sv, q)
    ws = dirichlet_lifting(dv, fields, True)[0]
    ig = Integrals.of(dv, EstimatorOptions())
    grads = corrected_fields(dv, fields, ws)[1]
    data = [fd.sign * fl.lam for fd in fields]
    rule = flux_rule_order(dv, q, any(w is not None for w in ws))
    assert rule is not None and rule < 2 * (p + 2 + q) + ig.bonus
    exact = flux_residual(ig, fields, fl.sigma, grads, data, fl_rule=rule)[0]
    plain = flux_residual(ig, fields, fl.sigma, grads, data)[0]
    assert np.abs(exact - plain).max() <= 1e-12 * np.abs(plain).max()


def test_quadrature_arrays_on_some_elements_are_rows_of_the_full_ones(lshape_p3):
    from ngcontact.estimators.nonnegative import QuadratureArrays

    disc, sol = lshape_p3
    gfs = disc.gridfunctions(sol.x, sol.y)
    full = QuadratureArrays(disc.mesh, 12)
    rows = np.array([0, 5, disc.mesh.ne - 1, 3])
    some = QuadratureArrays(disc.mesh, 12, rows)
    assert np.array_equal(some.W, full.W[rows])
    assert np.array_equal(some.values(gfs["u1"]), full.values(gfs["u1"])[rows])
    assert np.array_equal(some.values(gfs["gap"], [1, 2]), full.values(gfs["gap"], rows[[1, 2]]))


@pytest.mark.parametrize("multiplier", ["shape", "contact"])
def test_multiplier_support_holds_and_the_restricted_estimate_equals_the_full_one(lshape_p3, multiplier):
    """lam^ of the batched patch-constant and shaped multipliers is zero on every element outside
    ``lam_support`` (at the points of a fine rule), the support is a proper part of the mesh, and the estimate that
    visits only its elements (concentrated multiplier, element means of the data) equals the one that visits all."""
    from ngcontact.estimators.nonnegative import QuadratureArrays

    disc, sol = lshape_p3
    sv = SolutionView.of(disc, sol.x, sol.y)
    fl = reconstruct(sv, 3, multiplier=multiplier)
    assert fl.lam_support is not None and 0 < fl.lam_support.sum() < 0.5 * disc.mesh.ne
    outside = np.flatnonzero(~fl.lam_support)
    assert np.abs(QuadratureArrays(disc.mesh, 16, outside).values(fl.lam)).max() == 0.0
    inside = np.flatnonzero(fl.lam_support)
    assert np.abs(QuadratureArrays(disc.mesh, 16, inside).values(fl.lam)).max() > 0.0
    restricted = estimate(disc, sol.x, sol.y, flux=fl)
    fl.lam_support = None
    everywhere = estimate(disc, sol.x, sol.y, flux=fl)
    a, b = restricted.summary(), everywhere.summary()
    for key in a:
        if key != "time_estimate_s":
            assert a[key] == pytest.approx(b[key], rel=1e-12, abs=1e-14 * b["eta"]), key
    assert np.abs(restricted.eta_C - everywhere.eta_C).max() <= 1e-14 * b["eta"] ** 2


def test_element_means_from_their_parts_equal_the_plain_rule(lshape_p3):
    """eta_quad with the element means summed from the load (kept per mesh), the data (on their support) and
    div sigma (exact rule of order q) equals eta_quad with the means of res = f + data - div sigma by the fine rule."""
    from ngsolve import div

    from ngcontact.estimators.terms import mean_term

    disc, sol = lshape_p3
    sv = SolutionView.of(disc, sol.x, sol.y)
    dv, fields = sv.disc, sv.fields
    fl = reconstruct(sv, 3, multiplier="shape")
    ws = dirichlet_lifting(dv, fields, True)[0]
    ig = Integrals.of(dv, EstimatorOptions())
    grads = corrected_fields(dv, fields, ws)[1]
    data = [fd.sign * fl.lam for fd in fields]
    eta_FR, eta_quad = flux_residual(ig, fields, fl.sigma, grads, data, data_support=fl.lam_support)[2:]
    plain = [ig.ew(fd.f + m - div(sig), dx(bonus_intorder=ig.bonus + 8)) / ig.area
             for fd, m, sig in zip(fields, data, fl.sigma)]
    want = mean_term(ig, plain, [fd.mu for fd in fields], eta_FR)
    assert want > 0.0 and eta_quad == pytest.approx(want, rel=1e-9)
    f = fields[0].f
    assert ig.data_integrals(f) is ig.data_integrals(f)  # kept for the same load object
