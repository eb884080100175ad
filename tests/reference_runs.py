"""Stored reference histories: a few short runs whose per-level numbers are regression-checked.

``tests/test_reference.py`` reruns every entry of :data:`RUNS` and compares the
columns :data:`COLUMNS` with ``tests/data/reference_histories.json`` (written
by ``make reference-histories``, i.e. ``python -m tests.reference_runs``).
Regenerate the file only when a change of the numbers is intended, and say so
in the commit message.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

DATA = Path(__file__).resolve().parent / "data" / "reference_histories.json"

#: name -> (scene, RunOptions fields)
RUNS = {
    "test1-fem-p2": ("test1", dict(order=2, levels=4)),
    "test1-fem-p1-fb-cold": ("test1", dict(order=1, levels=3, cfun="fb", start="cold")),
    "test1-hho-p3": ("test1", dict(disc="hho", order=3, levels=3)),
    "test1-hho-p1-nosc-fb": ("test1", dict(disc="hho", order=1, levels=3, condense=False, cfun="fb")),
    "test1-sipg-p2": ("test1", dict(disc="sipg", order=2, levels=3)),
    "test1-nipg-p1-fb": ("test1", dict(disc="nipg", order=1, levels=3, cfun="fb")),
    "test1-fem-p1-decouple-balanced": ("test1", dict(order=1, levels=4, decouple=True, newton_stop="balanced")),
    "ex9-p1-balanced": ("ex9_obstacle", dict(order=1, levels=4, newton_stop="balanced")),
    "disk-fem-p1-estimate": ("disk", dict(order=1, levels=3, estimate=True)),
    "disk-fem-p2-estimate-cold": ("disk", dict(order=2, levels=2, estimate=True, start="cold")),
    "disk-fem-p1-inexact": ("disk", dict(order=1, levels=2, newton="inexact")),
    "disk-fem-p1-gmres": ("disk", dict(order=1, levels=2, newton="gmres")),
    "disk-fem-p1-adaptive-newton": ("disk", dict(order=1, levels=2, newton="adaptive")),
    "disk-fem-p2-adaptive-newton-fb": ("disk", dict(order=2, levels=1, newton="adaptive", cfun="fb")),
    "lshape-adaptive-p1": ("lshape", dict(order=1, adaptive=True, max_levels=8)),
    "test1-adaptive-p2-max": ("test1", dict(order=2, adaptive=True, max_levels=5, marking="max")),
}

#: compared columns (those present in a run's rows)
COLUMNS = ("ndof", "err_energy", "err_max_nodal", "i_eff", "newton_its", "gmres_its", "marked")
#: (active-set sizes are not compared: nodes with gap = X3 = 0 up to round-off, e.g. disk P2, flip between
#: runs of the same code)
#: and every column whose name starts with this (the estimator and its parts)
PREFIX = "eta"

#: relative tolerance of the comparison for floating-point columns (integers must match exactly).
#: Reordered floating-point sums may move values by round-off; a changed Newton path moves them by far more.
RTOL = 1e-7


def compute(name: str) -> list:
    """Rows of the run ``name``, restricted to :data:`COLUMNS`."""
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.scenes import load_scene

    scene_name, opts = RUNS[name]
    scene = load_scene(scene_name)
    result = run_scene(scene, RunOptions.for_scene(scene, **opts))
    return [{c: v for c, v in row.items() if c in COLUMNS or c.startswith(PREFIX)} for row in result.rows]


def main(argv=None) -> int:
    names = (argv if argv is not None else sys.argv[1:]) or list(RUNS)
    data = json.loads(DATA.read_text()) if DATA.exists() else {}
    for name in names:
        print(f"running {name}", flush=True)
        data[name] = compute(name)
    DATA.parent.mkdir(parents=True, exist_ok=True)
    DATA.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
