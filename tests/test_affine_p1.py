"""The closed-form P1 terms of :mod:`ngcontact.estimators.affine_p1` against the quadrature path of
:mod:`ngcontact.estimators.components` (``EstimatorOptions(closed_form=False)``), and the one-solve RT_0
norm of :class:`ngcontact.estimators.terms.P0Dual` against its quadrature of the field."""
import numpy as np
import pytest

from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.drivers.level import newton_iterates
from ngcontact.estimators import EstimatorOptions, algebraic_flux, estimate_components
from ngcontact.estimators.affine_p1 import applies
from ngcontact.estimators.terms import P0Dual
from ngcontact.estimators.view import DiscretizationView
from ngcontact.scenes import load_scene

#: terms in units of the energy squared (works, contact products); the others are in units of the energy
SQUARED = ("eta_C", "P_lin", "nonc3_disc", "nonc3_lin", "theta_disc", "theta_lin")


@pytest.fixture(scope="module")
def disk_p1():
    scene = load_scene("disk")
    disc = FEMDiscretization(scene.problem, scene.problem.domain.mesh(0), order=1)
    its = newton_iterates(disc, *disc.initial_guess(scene.initial_guess))
    return disc, its


def _same(a, b):
    """Every component and term of a and b equal to round-off: |difference| <= 1e-11 of the value, or of eta
    (eta^2 for the squared terms) where the value itself is a small difference (Theta, P_lin)."""
    eta = b.eta
    for name in ("eta_disc", "eta_lin", "eta_alg", "eta"):
        assert abs(getattr(a, name) - getattr(b, name)) <= 1e-11 * getattr(b, name) + 1e-300, name
    for name, v in b.terms.items():
        if name.startswith("time"):
            continue
        scale = eta ** 2 if name in SQUARED else eta
        assert abs(a.terms[name] - v) <= 1e-11 * max(abs(v), scale), (name, a.terms[name], v)
    assert np.allclose(a.eta_K, b.eta_K, rtol=1e-10, atol=1e-12 * eta)
    assert np.allclose(a.eta_K_lin, b.eta_K_lin, rtol=1e-10, atol=1e-12 * eta)


def test_closed_form_terms_equal_the_quadrature(disk_p1):
    """Newton-min iterates of the [JSC20] disk from X0 = [g, 0, 0] (X0 violates E X = F, the next ones the
    constraints: negative nodal gaps and multipliers, so every term is active somewhere), each exact, with
    the global RT_0 algebraic flux, and with a look-ahead algebraic flux (RT_0, :mod:`.algebraic`)."""
    disc, its = disk_p1
    fast, slow = EstimatorOptions(), EstimatorOptions(closed_form=False)
    dv = DiscretizationView.of(disc)
    assert applies(dv, fast, True) and not applies(dv, slow, True)
    seen = set()
    for k, (x, y) in enumerate(its[:-1]):
        xn = its[k + 1][0]
        r = np.concatenate([-disc.system.residual(x, y), np.zeros(len(y))])
        sig = algebraic_flux(disc, xn - x, fast)
        for kw in ({}, {"r_alg": r}, {"r_alg": r, "sigma_alg": sig}):
            a = estimate_components(disc, x, y, options=fast, **kw)
            b = estimate_components(disc, x, y, options=slow, **kw)
            _same(a, b)
            seen.update(n for n, v in b.terms.items() if v != 0.0)
    # the iterates exercise the multiplier defect, the gap correction, the algebraic terms and the contact work
    assert {"nonc2_lin", "nonc1_lin", "alg_flux", "alg_res", "theta_lin", "eta_C", "eta_quad"} <= seen, seen
    assert ("affine_p1", EstimatorOptions().quad_bonus or disc.quad_bonus + 4) in dv.cache


def test_p0dual_one_solve_norm_equals_quadrature(disk_p1):
    """||zeta||^2 = phi^T A phi + sum rbar_K^2 J_K / 4 on affine elements equals the quadrature of
    -grad phi + rbar/2 (x - x_K) to round-off."""
    mesh = disk_p1[0].mesh
    rb = np.random.default_rng(3).standard_normal(mesh.ne)
    a, b = P0Dual(mesh).norm(rb), P0Dual(mesh, affine=False).norm(rb)
    assert abs(a - b) <= 1e-12 * b and b > 0
