"""Estimation time vs Newton time at ~1e5 dofs (issue 4 acceptance: estimate <= 2 x Newton).

    .venv/bin/python benchmarks/bench_estimate.py [scene:p:level ...]     (default disk:1:4 test1:1:5)

Per case, in one run: Newton-min cold start (scene initial guess), nested start (solve level - 1,
prolongate), then ``estimate`` (Dirichlet correction on / "fast" / off) and
``estimate_components``; prints a table with the ratios estimate / Newton.  No assertions.
"""
import sys
import time

from ngcontact.discretizations.fem import FEMDiscretization
from ngcontact.estimators import estimate, estimate_components
from ngcontact.newton import NewtonOptions, semismooth_newton
from ngcontact.scenes import load_scene


def run(scene_name, p, level):
    scene = load_scene(scene_name)
    prob = scene.problem
    meshes = list(prob.domain.meshes(level + 1))
    coarse = FEMDiscretization(prob, meshes[level - 1], order=p)
    sc = semismooth_newton(coarse.system, *coarse.initial_guess(scene.initial_guess), NewtonOptions())
    disc = FEMDiscretization(prob, meshes[level], order=p)
    t0 = time.perf_counter()
    cold = semismooth_newton(disc.system, *disc.initial_guess(scene.initial_guess), NewtonOptions())
    t_cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    nested = semismooth_newton(disc.system, *disc.prolongate(coarse, sc.x, sc.y), NewtonOptions())
    t_nested = time.perf_counter() - t0
    out = []
    for label, fn in [("estimate", lambda: estimate(disc, cold.x, cold.y, errors=False)),
                      ("estimate fast", lambda: estimate(disc, cold.x, cold.y, errors=False,
                                                         dirichlet_correction="fast")),
                      ("estimate no-bc", lambda: estimate(disc, cold.x, cold.y, errors=False,
                                                          dirichlet_correction=False)),
                      ("components", lambda: estimate_components(disc, cold.x, cold.y))]:
        t0 = time.perf_counter()
        fn()
        t = time.perf_counter() - t0
        out.append((label, t))
    print(f"\n{scene_name} P{p} level {level}: ndof {disc.ndof}, Newton cold {t_cold:.2f} s ({cold.iterations} its), "
          f"nested {t_nested:.2f} s ({nested.iterations} its)")
    print(f"{'':16s} {'time [s]':>9s} {'/cold':>7s} {'/nested':>8s}")
    for label, t in out:
        print(f"{label:16s} {t:9.2f} {t / t_cold:7.2f} {t / t_nested:8.2f}")
    sys.stdout.flush()


if __name__ == "__main__":
    cases = sys.argv[1:] or ["disk:1:4", "test1:1:5"]
    for c in cases:
        s, p, lev = c.split(":")
        run(s, int(p), int(lev))
