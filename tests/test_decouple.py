"""The s = u1 + alpha u2, w = u1 - u2 decoupling gives the coupled discrete solution."""
import numpy as np
import pytest
from ngsolve import x, y

from ngcontact import CrissCrossSquare, TwoMembraneProblem
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.newton import NewtonOptions, decoupled_newton, semismooth_newton


def _disc(mu2, order=1, level=2):
    problem = TwoMembraneProblem(domain=CrissCrossSquare(n0=4), f1=-30 * (x - 0.3) * (y - 0.6) - 8.0, f2=6.0,
                                 g1=0.05, g2=-0.05, mu1=2.0, mu2=mu2)
    mesh = list(problem.domain.meshes(level + 1))[-1]
    return FEMDiscretization(problem, mesh, order=order)


@pytest.mark.parametrize("mu2,order", [(2.0, 1), (0.5, 1), (0.5, 2)])
def test_decoupled_newton_gives_the_coupled_solution(mu2, order):
    d = _disc(mu2, order)
    s = d.system
    split = s.membrane_split()
    assert split is not None and split[1] == pytest.approx(mu2 / 2.0)
    x0, y0 = d.initial_guess()
    a = semismooth_newton(s, x0, y0, NewtonOptions())
    b = decoupled_newton(s, x0, y0, NewtonOptions())
    assert a.converged and b.converged
    assert 0 < (a.y > 1e-8).sum() < s.m  # partial contact
    np.testing.assert_allclose(b.x, a.x, atol=1e-11 * np.abs(a.x).max())
    np.testing.assert_allclose(b.y, a.y, atol=1e-9 * np.abs(a.y).max())
    assert s.gap(b.x).min() >= -1e-12 and b.y.min() >= -1e-12


@pytest.mark.parametrize("mu2,order", [(2.0, 1), (0.5, 1), (3.0, 2)])
def test_declared_tensions_give_the_split_that_the_comparison_finds(mu2, order):
    """The FEM declares K = blockdiag(mu1 S, mu2 S) (``tensions``): the split read off that way is the one found by
    comparing K's blocks."""
    import copy

    s = _disc(mu2, order).system
    assert s.tensions == (2.0, mu2)
    S, alpha = s.membrane_split()
    checked = copy.copy(s)
    checked.tensions = None
    S2, alpha2 = checked.membrane_split()
    assert alpha == mu2 / 2.0 and alpha2 == pytest.approx(alpha, rel=1e-15)
    assert (S != S2).nnz == 0 and S.shape == S2.shape


def test_no_split_for_the_obstacle_problem_or_coupled_blocks():
    d = _disc(1.0)
    s = d.system
    from ngcontact.algebra.system import ComplementaritySystem

    m = s.m
    K = s.K.tolil()
    K[0, m] = K[m, 0] = -1e-3  # couple the fields: no longer block diagonal
    coupled = ComplementaritySystem(K.tocsr(), s.F, s.up, s.lo, s.b, s.D)
    assert coupled.membrane_split() is None
    obstacle = ComplementaritySystem(s.K[:m, :m], s.F[:m], np.arange(m), -np.ones(m, dtype=np.int64),
                                     np.zeros(m), s.D)
    assert obstacle.membrane_split() is None
    # fallback: decoupled_newton then is the coupled Newton
    x0, y0 = np.zeros(coupled.n), np.zeros(m)
    r = decoupled_newton(coupled, x0, y0)
    assert r.converged and np.allclose(r.x, semismooth_newton(coupled, x0, y0).x)


def test_adaptive_run_with_decoupled_newton_follows_the_coupled_one():
    """--adaptive --decouple: every level solved by the w-Newton gives the coupled level's solution, so the estimator
    marks the same elements and the run refines to the same meshes with the same errors (L-shape P2)."""
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.scenes import load_scene

    sc = load_scene("lshape")
    runs = [run_scene(sc, RunOptions(order=2, adaptive=True, max_ndof=6000, decouple=d)) for d in (False, True)]
    coupled, dec = (r.rows for r in runs)
    assert len(coupled) == len(dec) >= 4
    # the w-Newton's systems have at most one unknown per node, the coupled ones more
    size = [{it["level"]: it["linear_size"] for it in r.iterations if it["k"] > 0} for r in runs]
    assert all(size[1][lv] < size[0][lv] for lv in size[1])
    for a, b in zip(coupled, dec):
        assert a["nelem"] == b["nelem"] and a["active_nodes"] == b["active_nodes"]
        assert b["newton_converged"] == 1 and b["certified"] == 1
        assert b["err_energy"] == pytest.approx(a["err_energy"], rel=1e-9)
        assert b["eta"] == pytest.approx(a["eta"], rel=1e-8)
