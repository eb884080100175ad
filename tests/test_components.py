"""Error components of an arbitrary iterate: eta_disc, eta_lin, eta_alg ([JSC20], seed "Corollary (Distinction
of the error components)"), along Newton iterations and for inexact linear solves."""
import warnings

import numpy as np
import pytest

from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.estimators import (Components, EstimatorOptions, FieldData, FluxReconstruction, equilibration_defect,
                                  estimate, estimate_components, newton_history, plot_components_history)
from ngcontact.drivers.level import newton_iterates
from ngcontact.estimators.flux import vertex_device_exact
from ngcontact.estimators.view import DiscretizationView
from ngcontact.scenes import load_scene


@pytest.mark.parametrize("scene,p,level", [("disk", 1, 0), ("disk", 2, 0), ("test1", 1, 1), ("test2", 2, 0)])
def test_components_at_convergence(solved_scene, scene, p, level):
    """Exact Newton, converged: eta_lin ~ 0, eta_alg = 0 and eta_disc = eta of estimate() with the same
    multiplier (the default estimate() is at most that)."""
    _, disc, sol = solved_scene(scene, level, p)
    assert sol.converged
    comp = estimate_components(disc, sol.x, sol.y, errors=True)
    # the components use one multiplier (patch constants, or the fit where the vertex device is not
    # exact); estimate() by default also tries the shaped one and may be smaller
    mult = None if p == 1 else ("contact" if vertex_device_exact(DiscretizationView.of(disc), p) else "fit")
    est = estimate(disc, sol.x, sol.y, EstimatorOptions(multiplier=mult))
    assert estimate(disc, sol.x, sol.y).eta <= est.eta * (1 + 1e-12)
    assert isinstance(comp, Components)
    assert comp.eta_alg == 0.0
    assert comp.eta_lin <= 1e-6 * comp.eta_disc, comp.eta_lin
    assert abs(comp.eta_disc - est.eta) <= 1e-10 * est.eta, (comp.eta_disc, est.eta)
    assert comp.eta >= comp.err_energy
    assert comp.eta_K.shape == (disc.mesh.ne,) and np.all(comp.eta_K >= 0)


def test_components_along_newton_iterations(tmp_path):
    """[JSC20] figures: every Newton-min iterate from X0 = [g, 0, 0] is bounded by eta = disc + lin + alg;
    X0 does not solve E X = F (eta_alg > 0), intermediate iterates violate the constraints
    (eta_lin > 0), the last one is converged (eta_lin ~ 0, eta_alg = 0)."""
    scene = load_scene("disk")
    disc = FEMDiscretization(scene.problem, scene.problem.domain.mesh(0), order=1)
    its = list(newton_iterates(disc, *disc.initial_guess(scene.initial_guess)))
    assert len(its) >= 4
    rows = newton_history(disc, its)
    for r in rows:
        assert r["eta_total"] >= r["err_energy"], r
        assert abs(r["eta_total"] - (r["eta_disc"] + r["eta_lin"] + r["eta_alg"])) <= 1e-14 * r["eta_total"]
    assert rows[0]["eta_alg"] > rows[0]["eta_disc"]
    assert max(r["eta_lin"] for r in rows[1:-1]) > rows[-1]["eta_disc"]
    assert rows[-1]["eta_lin"] <= 1e-6 * rows[-1]["eta_disc"] and rows[-1]["eta_alg"] == 0.0
    plot_components_history(rows, tmp_path / "hist.png")
    assert (tmp_path / "hist.png").stat().st_size > 1000


@pytest.mark.parametrize("scene,p", [("disk", 1), ("test2", 2)])
def test_components_inexact_solve(solved_scene, scene, p):
    """A perturbed solution with its algebraic residual: guaranteed bound, sigma_disc equilibrated with
    f - (-1)^a lam_h - r_ah, eta_alg proportional to the residual, any sigma_alg accepted.
    (p = 2 on straight elements: on curved ones the vertex device of :mod:`.moments` is exact
    only up to the curvature, equilibration ~1e-5 where r^ is nonzero at the boundary; the bound
    stays guaranteed since eta_R and eta_quad use the actual div sigma.)"""
    from ngsolve import HDiv, GridFunction

    _, disc, sol = solved_scene(scene, 0, p)
    assert sol.converged
    rng = np.random.default_rng(1)
    noise = rng.standard_normal(len(sol.x)) * np.abs(sol.x).max()
    etas = []
    for eps in (1e-4, 1e-6):
        xk = sol.x + eps * noise
        r = np.concatenate([-disc.system.residual(xk, sol.y), np.zeros(len(sol.y))])
        comp = estimate_components(disc, xk, sol.y, r_alg=r, errors=True)
        assert comp.eta >= comp.err_energy and comp.res_alg > 0
        etas.append(comp.eta_alg)
        for i, fd in enumerate(comp.sigma_disc):
            f = disc.problem.f1 if i == 0 else disc.problem.f2
            fl = FluxReconstruction(sigma=[fd], fields=[FieldData("u", 1.0, f, +1, None)], lam=comp.data[i],
                                    order=p, space=fd.space)
            assert equilibration_defect(disc, fl)["u"]["max_K"] <= 1e-10
    assert 50 <= etas[0] / etas[1] <= 200, etas
    zero = GridFunction(HDiv(disc.mesh, order=1, RT=True))
    comp0 = estimate_components(disc, xk, sol.y, r_alg=r, sigma_alg=[zero, zero], errors=True)
    assert comp0.eta_alg > 0 and comp0.eta >= comp0.err_energy
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        estimate_components(disc, xk, sol.y, r_alg=np.ones(len(r)))
    assert any("differs" in str(m.message) for m in w)


def test_components_use_the_flux_degree_of_the_options(solved_scene):
    """options.flux_order reaches sigma_disc (RT_{p+1}), and a degree other than p or p + 1 is refused
    before any work, naming the option."""
    _, disc, sol = solved_scene("disk", 0, 1)
    assert sol.converged
    comp = estimate_components(disc, sol.x, sol.y, options=EstimatorOptions(flux_order=2))
    assert all(s.space.globalorder == 2 for s in comp.sigma_disc)
    assert estimate_components(disc, sol.x, sol.y).sigma_disc[0].space.globalorder == 1
    with pytest.raises(ValueError, match="flux_order must be p = 1 or p \\+ 1 = 2.*got 3"):
        estimate_components(disc, sol.x, sol.y, options=EstimatorOptions(flux_order=3))
