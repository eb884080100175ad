"""Regression check of the stored reference histories (``tests/reference_runs.py``).

Errors, estimators, I_eff, Newton / GMRES counts and active-set sizes of a few short runs (every
discretization, Newton mode and driver) must reproduce the stored values: integers exactly, floats
to ``RTOL`` relative to the larger of the value and the level's eta or energy error (parts of the estimate
that are round-off, ~1e-18, are compared in the units of the estimate).
"""
import json
import math

import pytest

from tests.reference_runs import DATA, RTOL, RUNS, compute

STORED = json.loads(DATA.read_text())


@pytest.mark.parametrize("name", sorted(RUNS))
def test_reference_history(name):
    want = STORED[name]
    got = compute(name)
    assert len(got) == len(want), f"{name}: {len(got)} levels, stored {len(want)}"
    for level, (g, w) in enumerate(zip(got, want)):
        scale = max(abs(w.get("eta", 0.0)), abs(w.get("err_energy", 0.0)))
        assert sorted(g) == sorted(w), f"{name} level {level}: columns differ"
        for col, ref in w.items():
            val = g[col]
            if isinstance(ref, int):
                assert val == ref, f"{name} level {level}: {col} = {val}, stored {ref}"
            elif math.isnan(ref):
                assert math.isnan(val), f"{name} level {level}: {col} = {val}, stored nan"
            else:
                assert abs(val - ref) <= RTOL * max(abs(ref), scale), \
                    f"{name} level {level}: {col} = {val!r}, stored {ref!r}"
