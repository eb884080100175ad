"""Estimator at p >= 2 when the contact set reaches the Dirichlet boundary with lam > 0 there
(ngcontact/estimators/boundary.py; measured table: results/stability/BOUNDARY_CONTACT.md)."""
import numpy as np
import pytest
from ngsolve import CoefficientFunction, x

from ngcontact.drivers import RunOptions
from ngcontact.drivers.level import solve_level
from ngcontact.estimators import EstimatorOptions, estimate
from ngcontact.estimators.boundary import boundary_vertices, contact_band, residual_multiplier, vertex_values
from ngcontact.estimators.view import SolutionView
from ngcontact.scenes import load_scene


def _solutions(name, order, levels):
    scene = load_scene(name)
    opts = RunOptions.for_scene(scene, order=order, levels=levels)
    prev, out = None, []
    for mesh in scene.problem.domain.meshes(levels):
        o = solve_level(scene.problem, mesh, opts, previous=prev)
        prev = (o.disc, o.sol.x, o.sol.y)
        out.append(o)
    return out


@pytest.fixture(scope="module")
def full_contact_p2():
    return _solutions("full_contact", 2, 3)


def _i_eff(o, boundary=True):
    est = estimate(o.disc, o.sol.x, o.sol.y, EstimatorOptions(boundary_multiplier=boundary),
                   err_energy=o.errors["err_energy"])
    return est.i_eff


def test_full_contact_p2_effectivity_stays_bounded(full_contact_p2):
    """lam = 1 + x/2 + y/4 on the whole closed square: I_eff stays near 1 and stops growing (T0..T2)."""
    ieff = [_i_eff(o) for o in full_contact_p2]
    assert all(i >= 1.0 for i in ieff), ieff            # guaranteed
    assert ieff[-1] <= 1.3, ieff
    assert ieff[2] / ieff[1] <= 1.05, ieff


def test_full_contact_p2_without_boundary_multiplier_loses_half_an_order(full_contact_p2):
    """The moments-only multiplier on the boundary patches (the option off): eta ~ h^1.5 against the h^2 error,
    I_eff grows by about 2^(1/2) per level; still a bound."""
    ieff = [_i_eff(o, boundary=False) for o in full_contact_p2]
    assert all(i >= 1.0 for i in ieff), ieff
    assert ieff[2] / ieff[1] >= 1.2 and ieff[1] / ieff[0] >= 1.2, ieff


def test_residual_multiplier_and_band(full_contact_p2):
    """rho_h = lam + O(h) on P2 (the data are smooth), taken at the vertices inside every element; the band is
    every contact element here (full contact), and empty when no contact element touches the boundary."""
    o = full_contact_p2[-1]
    sv = SolutionView.of(o.disc, o.sol.x, o.sol.y)
    dv = sv.disc
    lam = vertex_values(dv, o.disc.problem.exact.lam)
    rho = vertex_values(dv, residual_multiplier(sv))
    assert np.abs(rho - lam).max() < 0.2
    assert np.abs(vertex_values(dv, CoefficientFunction(x)) - o.disc.mesh.ngmesh.Coordinates()[
        dv.element_vertices()][:, :, 0]).max() < 1e-14
    contact = np.ones(o.disc.mesh.ne, bool)
    assert contact_band(dv, contact).all()
    interior = ~boundary_vertices(dv)[dv.element_vertices()].any(axis=1)
    assert not contact_band(dv, interior).any()


def test_components_take_the_boundary_multiplier(full_contact_p2):
    """estimate_components (the Newton-path split) uses the same multiplier: eta_disc of the converged
    solution stays sharp on T2 (about 5.6 with the moments-only multiplier)."""
    from ngcontact.estimators import estimate_components

    o = full_contact_p2[-1]
    comp = estimate_components(o.disc, o.sol.x, o.sol.y, errors=True)
    assert 1.0 <= comp.i_eff <= 1.5, comp.i_eff
