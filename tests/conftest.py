import pytest

from ngcontact.newton import NewtonOptions, semismooth_newton
from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.scenes import load_scene


@pytest.fixture
def solve_levels():
    """Run a bundled scene through the runner; returns the RunResult."""
    from ngcontact.drivers import RunOptions, run_scene

    def _run(scene_name, order, levels, cfun="min", start="nested"):
        scene = load_scene(scene_name)
        opts = RunOptions.for_scene(scene, order=order, levels=levels, cfun=cfun, start=start)
        return run_scene(scene, opts)
    return _run


@pytest.fixture
def solved_scene():
    """Solve a bundled scene on mesh level ``level`` with FEM P_order from its initial guess:
    returns (scene, disc, NewtonResult)."""
    def _solve(name, level=0, order=1, **newton):
        scene = load_scene(name)
        disc = FEMDiscretization(scene.problem, scene.problem.domain.mesh(level), order=order)
        sol = semismooth_newton(disc.system, *disc.initial_guess(scene.initial_guess), NewtonOptions(**newton))
        return scene, disc, sol
    return _solve


@pytest.fixture
def solve_one():
    def _solve(problem, level=0, order=1, cfun="min", init=None, **kw):
        disc = FEMDiscretization(problem, problem.domain.mesh(level), order=order)
        x0, y0 = disc.initial_guess(init)
        sol = semismooth_newton(disc.system, x0, y0, NewtonOptions(cfun=cfun, **kw))
        return disc, sol
    return _solve
