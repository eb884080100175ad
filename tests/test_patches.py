"""The batched patch solver (ngcontact.estimators.patches) against NGSolve's PatchwiseSolve."""
import numpy as np
import pytest
from ngsolve import CoefficientFunction, Integrate, dx, sqrt

from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.estimators import EstimatorOptions, normal_jump, reconstruct_fluxes
from ngcontact.estimators.flux import patch_solver
from ngcontact.estimators.view import DiscretizationView
from ngcontact.newton.loop import NewtonOptions, semismooth_newton
from ngcontact.scenes import load_scene


def _solved(scene_name, p, level):
    scene = load_scene(scene_name)
    mesh = list(scene.problem.domain.meshes(level + 1))[-1]
    disc = FEMDiscretization(scene.problem, mesh, order=p)
    sol = semismooth_newton(disc.system, *disc.initial_guess(scene.initial_guess), NewtonOptions())
    assert sol.converged
    return disc, sol


@pytest.mark.parametrize("scene,p,level", [("disk", 1, 1), ("test1", 2, 1), ("test1", 3, 1), ("lshape", 2, 1),
                                           ("ex9_obstacle", 1, 1)])
def test_batched_equals_patchwise_solve(scene, p, level):
    """Same fluxes as PatchwiseSolve (interior and boundary patches, obstacle and membranes, RT_1..RT_3)."""
    disc, sol = _solved(scene, p, level)
    ref = reconstruct_fluxes(disc, sol.x, sol.y, EstimatorOptions(batched=False))
    new = reconstruct_fluxes(disc, sol.x, sol.y, EstimatorOptions(batched=True))
    mesh = disc.mesh
    for s_ref, s_new in zip(ref.sigma, new.sigma):
        diff = sqrt(Integrate((s_ref - s_new) ** 2 * dx, mesh))
        norm = sqrt(Integrate(s_ref ** 2 * dx, mesh))
        assert diff <= 1e-10 * norm, (diff, norm)
    assert max(normal_jump(new).values()) <= 1e-12



@pytest.mark.parametrize("scene,p,level", [("test1", 2, 1), ("disk", 1, 1), ("lshape", 3, 0)])
def test_opposite_edges_are_eliminated_per_element(scene, p, level, monkeypatch):
    """The facet dofs of the edge opposite to the patch vertex are eliminated per element (straight meshes with
    the element blocks from reference matrices, and the curved disk with the assembled ones): the patch systems
    hold the 2(q + 1) dofs per element of the edges at the vertex, and the fluxes are those of the patch systems
    with every facet dof of the patch (the elimination switched off) to round-off."""
    import ngcontact.estimators.opposite_edges as opposite_edges

    disc, sol = _solved(scene, p, level)
    q = p  # flux order p
    S = patch_solver(DiscretizationView.of(disc), q)
    assert S.nE == 2 * (q + 1) and S.elim.O.shape[2] == q + 1
    assert S.elim.fixed_O.any() and not S.elim.fixed_O.all()  # Dirichlet opposite edges: m = 0 there, nothing to solve
    with_elimination = reconstruct_fluxes(disc, sol.x, sol.y)
    monkeypatch.setattr(opposite_edges, "_opposite_vertices", lambda *a, **k: None)
    DiscretizationView.of(disc).cache.pop(("patch_solver", q))
    assert patch_solver(DiscretizationView.of(disc), q).nE == 3 * (q + 1)
    without = reconstruct_fluxes(disc, sol.x, sol.y)
    for a, b in zip(with_elimination.sigma, without.sigma):
        diff = sqrt(Integrate((a - b) ** 2 * dx, disc.mesh))
        assert diff <= 1e-12 * sqrt(Integrate(b ** 2 * dx, disc.mesh)), diff


def test_batched_solver_is_cached_and_exact_on_curved_meshes():
    """One solver per discretization and RT degree; on curved elements (disk_fitted P2) the eps -> 0 limit
    keeps the normal jumps at round-off (PatchwiseSolve with eps = 1e-10: ~1e-9)."""
    disc, sol = _solved("disk_fitted", 2, 1)
    assert patch_solver(DiscretizationView.of(disc), 2) is patch_solver(DiscretizationView.of(disc), 2)
    new = reconstruct_fluxes(disc, sol.x, sol.y)
    ref = reconstruct_fluxes(disc, sol.x, sol.y, EstimatorOptions(batched=False))
    assert max(normal_jump(new).values()) <= 1e-12
    assert max(normal_jump(ref).values()) > 1e-11  # the regularized solve is visibly less exact there
    for s_ref, s_new in zip(ref.sigma, new.sigma):
        diff = sqrt(Integrate((s_ref - s_new) ** 2 * dx, disc.mesh))
        assert diff <= 1e-6 * sqrt(Integrate(s_ref ** 2 * dx, disc.mesh))


def test_solve_several_right_hand_sides_at_once():
    """solve() with a list of right-hand sides equals one call per right-hand side."""
    from ngcontact.estimators.flux import PatchData, _patch_rhs, _times

    disc, sol = _solved("test1", 1, 0)
    S = patch_solver(DiscretizationView.of(disc), 1)
    gfs = disc.gridfunctions(sol.x, sol.y)
    lfs = [_patch_rhs(S.Y, PatchData(u=gfs[name], mu=1.0, hessian=False)) for name in ("u1", "u2")]
    both = S.solve([lambda hat, lf=lf: _times(hat, lf) for lf in lfs])
    for lf, c in zip(lfs, both):
        one = S.solve([lambda hat: _times(hat, lf)])[0]
        assert np.allclose(one, c, rtol=0, atol=1e-14 * max(np.abs(c).max(), 1.0))


def test_cached_operators_and_inverses_reproduce_the_first_call():
    """The flux operators and the patch inverses kept from the third call on give the fluxes of
    the first call (which solves without them) to round-off."""
    disc, sol = _solved("test1", 2, 1)
    first = reconstruct_fluxes(disc, sol.x, sol.y)
    S = patch_solver(DiscretizationView.of(disc), 2)
    assert not S._inv_cache
    for _ in range(2):
        again = reconstruct_fluxes(disc, sol.x, sol.y)
    assert S._inv_cache and S._ops
    for a, b in zip(first.sigma, again.sigma):
        diff = sqrt(Integrate((a - b) ** 2 * dx, disc.mesh))
        assert diff <= 1e-12 * sqrt(Integrate(a ** 2 * dx, disc.mesh))


@pytest.mark.parametrize("scene,p,level", [("test1", 3, 1), ("disk_fitted", 2, 1)])
def test_patch_constant_multiplier_beyond_the_vertex_device(scene, p, level):
    """multiplier="contact" for RT_3 / curved P2 (where the vertex device is not exact): the batched
    solver's patch-constant sources equilibrate lam^ exactly (checked on straight elements: on curved
    ones div sigma is not a mapped polynomial, see test_estimators), lam^ >= 0 (eta_nonc,2 = 0), and
    the estimate stays a guaranteed bound."""
    from ngcontact.estimators import equilibration_defect, estimate

    disc, sol = _solved(scene, p, level)
    contact = EstimatorOptions(multiplier="contact")
    flux = reconstruct_fluxes(disc, sol.x, sol.y, contact)
    if scene == "test1":
        defect = equilibration_defect(disc, flux)
        assert max(d["max_K"] for d in defect.values()) <= 1e-10, defect
    assert max(normal_jump(flux).values()) <= 1e-12
    est = estimate(disc, sol.x, sol.y, contact)
    assert est.eta_nonc2 == 0.0
    assert est.eta >= est.err_energy
    with pytest.raises(ValueError, match="batched"):
        from ngcontact.estimators.flux import PatchData, equilibrate_all
        equilibrate_all(disc.mesh, p, [PatchData(u=None, mu=1.0, vertex_values=np.zeros((disc.mesh.ne, 3)))])


def _same_fluxes(ref, other, mesh):
    for a, b in zip(ref.sigma, other.sigma):
        diff = sqrt(Integrate((a - b) ** 2 * dx, mesh))
        assert diff <= 1e-12 * sqrt(Integrate(a ** 2 * dx, mesh)), diff


@pytest.mark.parametrize("scene,p,level", [("test1", 1, 1), ("test1", 2, 1), ("lshape", 3, 0)])
def test_sparse_patch_operators_reproduce_the_loop(scene, p, level):
    """From the third call on (every patch inverse kept), scatter, inverses and gather are three sparse products
    (PatchSolver._patch_operators); the fluxes are those of the group loop of the first two calls to round-off
    (Dirichlet and interior patches, RT_1..RT_3)."""
    disc, sol = _solved(scene, p, level)
    S = patch_solver(DiscretizationView.of(disc), p)
    loop = [reconstruct_fluxes(disc, sol.x, sol.y) for _ in range(2)]
    assert S._patch_ops is None and not S._inv_cache
    # the element inverses come at once where element shapes are shared (cheap), else with the patch inverses
    assert (S.A_II_inv is None) == (S.blocks.shape is None)
    sparse = [reconstruct_fluxes(disc, sol.x, sol.y) for _ in range(2)]
    assert S._patch_ops is not None and S.A_II_inv is not None
    for ref in loop:
        for other in sparse:
            _same_fluxes(ref, other, disc.mesh)


@pytest.mark.parametrize("scene,p,level", [("test1", 1, 1), ("lshape", 3, 0)])
def test_expected_repeats_use_the_sparse_step_from_the_first_call(scene, p, level):
    """A discretization marked for repeated evaluations (the estimators inside a Newton loop) forms the patch
    inverses and the sparse patch step at the first call; the fluxes are those of an unmarked discretization's
    group loop to round-off."""
    from ngcontact.estimators import expect_repeated_evaluations

    from ngcontact.estimators.view import _cache_of

    disc, sol = _solved(scene, p, level)
    loop = reconstruct_fluxes(disc, sol.x, sol.y)
    assert patch_solver(DiscretizationView.of(disc), p)._patch_ops is None
    _cache_of(disc).clear()  # a fresh start: no patch solver, no kept inverses
    expect_repeated_evaluations(disc)
    first = reconstruct_fluxes(disc, sol.x, sol.y)
    S = patch_solver(DiscretizationView.of(disc), p)
    assert S._patch_ops is not None and S._calls == 1
    _same_fluxes(loop, first, disc.mesh)


@pytest.mark.parametrize("scene,p,level", [("lshape", 3, 0), ("disk", 2, 0)])
def test_patch_solver_constant_one_is_the_projection_of_one(scene, p, level):
    """The P_q coefficients of w = 1 on every element (the compatibility of the interior patches) from the moments
    (1, w_j)_K and the inverse element mass: those of NGSolve's Set(1), straight and curved (disk) elements."""
    from ngsolve import GridFunction

    disc, sol = _solved(scene, p, level)
    S = patch_solver(DiscretizationView.of(disc), p)
    ref = GridFunction(S.X.components[1])
    ref.Set(1.0)
    expect = ref.vec.FV().NumPy().reshape(S.one_Q.shape)
    assert np.abs(S.one_Q - expect).max() <= 1e-12
    areas = Integrate(CoefficientFunction(1.0) * dx, disc.mesh, element_wise=True).NumPy()
    assert np.allclose((S.one_Q * S.mass_Q).sum(axis=1), areas, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("scene,p,level", [("lshape", 3, 0), ("disk", 2, 0)])
def test_hat_moments_equal_the_three_hat_weighted_assemblies(scene, p, level):
    """(g psi_i, w_j)_K from one assembly of (g, v_m) on P_{q+1} and the reference products psi_i w_j = sum T v_m
    equal the three assemblies with the hats: a g with a kink and a fixed rule, on the straight L-shape (P3) and the
    curved disk (P2), elements of every ranking class."""
    from ngsolve import TRIG, IfPos, IntegrationRule, LinearForm, x, y

    from ngcontact.drivers.adaptive import refine

    problem = load_scene(scene).problem
    mesh = problem.domain.mesh(level)
    for _ in range(2):  # bisections: elements of all six ranking classes
        mesh = refine(mesh, np.arange(0, mesh.ne, 3))
    disc = FEMDiscretization(problem, mesh, order=p)
    S = patch_solver(DiscretizationView.of(disc), p)
    assert len(np.unique(S.ranking)) == 6
    rule = dx(intrules={TRIG: IntegrationRule(TRIG, 2 * p + 5)})
    g = IfPos(x - 0.1 * y - 0.05, 1.0 + x * y, -2.0 + y * y)
    got = S.hat_moments(lambda v: g * v * rule)
    w = S.X.components[1].TestFunction()
    for i, hat in enumerate(S.hats):
        ref = LinearForm(hat * g * w * rule).Assemble().vec.FV().NumPy().reshape(disc.mesh.ne, -1)
        assert np.abs(got[i] - ref).max() <= 1e-13 * np.abs(ref).max()


@pytest.mark.parametrize("q", [1, 2, 3, 4])
def test_facet_constant_one_is_the_dual_set_of_one(q):
    """The facet vector of the constant 1 (the null mode of the interior patches) from the facet dofs of the elements
    in their local order equals NGSolve's Set(1, dual=True), with and without Dirichlet facets, on a bisected mesh."""
    from ngsolve import GridFunction

    from ngcontact.drivers.adaptive import refine
    from ngcontact.estimators.mixed_blocks import AffineTriangles, _spaces, mixed_element_blocks
    from ngcontact.estimators.patches import facet_constant_one

    mesh = load_scene("lshape").problem.domain.mesh(0)
    mesh = refine(mesh, np.arange(0, mesh.ne, 2))
    V, Q, F, X = _spaces(mesh, q)
    fdofs = mixed_element_blocks(AffineTriangles.of(mesh), X, q).fdofs - V.ndof - Q.ndof
    ref = GridFunction(F)
    ref.Set(CoefficientFunction(1.0), dual=True)
    assert np.abs(facet_constant_one(F, fdofs) - ref.vec.FV().NumPy()).max() <= 1e-12
    assert np.array_equal(facet_constant_one(F), np.round(ref.vec.FV().NumPy(), 12))
