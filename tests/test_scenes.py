"""Every bundled scene is importable, runs in its short mode and converges."""
import numpy as np
import pytest

from ngcontact.drivers import RunOptions, run_scene
from ngcontact.problems import ParabolicProblem
from ngcontact.scenes import list_scenes, load_scene
from ngcontact.twophase import TwoPhaseParams, run_h2


@pytest.mark.parametrize("name", list_scenes())
def test_scene_runs_in_test_mode(name):
    scene = load_scene(name)
    if isinstance(scene.problem, TwoPhaseParams):  # a time loop of its own (tests/test_twophase.py)
        run = run_h2(scene.problem, **scene.test_options)
        assert run.completed and not run.log and run.rows[-1].gas_end_m > 0
        return
    if isinstance(scene.problem, ParabolicProblem):
        pytest.skip("time-dependent scene: run by tests/test_parabolic.py")
    opts = RunOptions.for_scene(scene, **scene.test_options)
    res = run_scene(scene, opts)
    assert res.converged, res.failures
    assert len(res.rows) == opts.levels
    for r in res.rows:
        assert r["gap_min"] >= -1e-10
    assert res.rows[-1]["active_nodes"] > 0  # every scene has a contact zone
    if scene.problem.exact is not None:
        e = [r["err_energy"] for r in res.rows]
        assert all(b < a for a, b in zip(e, e[1:]))
        assert np.isfinite(e).all()
