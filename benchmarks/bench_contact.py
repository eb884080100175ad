"""Benchmarks: nested Newton cost vs one unconstrained linear solve.

    python -m benchmarks.bench_contact [--quick] [--out results/bench]

Cases (each in its own subprocess so that peak memory is per case):
  ex9      PETSc SNES ex9 obstacle problem, P1, N = 16 * 2^j up to 1024 (65k/261k/1.05M unknowns);
           max nodal errors must match PETSc (9.340e-5 / 1.918e-5 / 6.59e-6).
  test1    [CAMWA21] test 1 on criss-cross meshes with n0 = 11, 7 levels: ~0.99M nodes per membrane,
           coupled reduced Newton, and 'test1-decoupled' (s/w change of variables).
  *-mg     the same nested runs with CG + truncated geometric multigrid in every Newton step
           (--newton multigrid; ngcontact.newton.multigrid) instead of sparse Cholesky factorizations.
  *-balanced  the same nested runs (ex9, ex9-mg, test1-decoupled) with the balanced Newton stop
           (--newton-stop balanced, gamma 1e-3: a level also stops when the linearization defect is
           below 1e-3 x the coarse-to-fine change; ngcontact.newton module doc); errors must not move.
Columns (one row per finest level N of a nested run from the coarsest mesh):
  t_total_s    whole nested run up to that level (meshes, assembly, prolongation, Newton, errors)
  t_solve_s    contact solve: t_total minus the finest level's mesh + assembly and minus all
               error evaluations (what an unconstrained solve on the same matrix needs too is excluded)
  t_run_s      whole nested run up to that level without the exact-error evaluations.  The levels of these
               structured squares are arrays (domains.ArrayMesh): P1 builds its system from them, and a
               level's NGSolve mesh and H1 space are built by the first thing that needs them -- here the exact
               errors (Integrate), so they are part of the error evaluation, not of t_run (ex9: f = 0; test1's
               loads are assembled by NGSolve, which builds them during its set-up)
  t_linear_s   one unconstrained solve K x = F of the finest level, sparse Cholesky (factor + solve)
  ratio        t_solve_s / t_linear_s
  t_linear_fast_s, ratio_fast  one unconstrained solve with the fastest solver of the package: CG +
               multigrid on the nested hierarchy from x = 0 to ||F - K x|| <= 1e-11 ||F|| (what the
               multigrid Newton mode asks of its steps), hierarchy set-up included
  ratio_fast_runs  (finest level of the repeated cases) t_solve_s / t_linear_fast_s of each repetition, the
               run against the baseline timed right after it: the spread of the ratio on the shared machine
  t_newton_s, ratio_newton_fast  prolongations and Newton solves of all levels (t_solve_s without the
               coarser levels' meshes and assemblies, which the multigrid hierarchy of the unconstrained
               solve needs as well), and its ratio to t_linear_fast_s
  t_finest_newton_s, ratio_finest_fast  the finest level's Newton solve alone (no prolongation) and its ratio
               to t_linear_fast_s: what the contact constraint costs on top of one linear solve at that level
  cg_its       (-mg) CG iterations per level, coarse to fine (level 0 is factorized)
  t_linear_split_s, ratio_split  (two membranes, K = blockdiag(S, alpha S)) the unconstrained problem's
               fastest direct solve: one factorization of S, two solves -- the stricter baseline
  (ex9 cases and test1-mg: the whole nested run and the linear solves are each timed three times in the same process
   (the first run includes imports and first-touch memory); the finest level's CG + multigrid solve right after each
   run, so that both sides of the ratio see the same phases of the shared machine (it varies by 10-30 % within
   minutes); every column takes the minimum)
  newton_its   Newton iterations per level, coarse to fine
  peak_rss_mb  resource.getrusage peak resident memory of the case's process (the baseline solves of the finest
               level run on its algebraic system; its mesh and space are released before them)
  peak_rss_run_mb  the same right after the first nested run, before any baseline solve
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

PETSC_S = {256: 0.45, 512: 1.0, 1024: 7.1}  # REFERENCE.md, vinewtonrsls + GAMG, this machine class
PETSC_ERR = {256: 9.340e-5, 512: 1.918e-5, 1024: 6.59e-6}


def _level_disc(scene, L: int):
    """The P1 discretization of level L with its multigrid hierarchy (the chain of levels 0..L)."""
    from ngcontact.discretizations.fem import FEMDiscretization
    from ngcontact.drivers.level import multigrid_hierarchy

    disc = None
    for mesh in scene.problem.domain.meshes(L + 1):
        fine = FEMDiscretization(scene.problem, mesh, order=1)
        fine.mg_prolongations = multigrid_hierarchy(fine, disc) if disc is not None else ()
        disc = fine
    return disc


def fastest_linear(disc, tol: float):
    """One unconstrained solve K x = F with CG + multigrid on the discretization's hierarchy, to the accuracy
    the multigrid Newton mode asks of its steps (||F - K x|| <= 0.1 tol ||F||), from x = 0: (seconds, x)."""
    import numpy as np

    from ngcontact.algebra.linalg import pcg
    from ngcontact.algebra.multigrid import Multigrid

    s = disc.system
    t0 = time.perf_counter()
    mg = Multigrid(s.K, disc.mg_prolongations)
    res = pcg(s.K, s.F, mg, rtol=0.1 * tol, maxiter=200)
    t = time.perf_counter() - t0
    assert res.converged and np.all(np.isfinite(res.x))
    return t, res.x


def run_case(case: str, quick: bool) -> list:
    import numpy as np
    from ngsolve import SetNumThreads

    from ngcontact import CrissCrossSquare
    from ngcontact.drivers import RunOptions, run_scene
    from ngcontact.scenes import load_scene
    from ngcontact.studies.strip_layers import run_times

    SetNumThreads(2)
    stop = "balanced" if "-balanced" in case else "residual"
    newton = "multigrid" if "-mg" in case else "direct"
    if case.startswith("ex9"):
        scene = load_scene("ex9_obstacle")
        levels, report = (6, (4, 5)) if quick else (7, (4, 5, 6))
        opts = RunOptions(levels=levels, newton_stop=stop, newton=newton)
    else:
        scene = load_scene("test1")
        scene = replace(scene, problem=replace(scene.problem, domain=CrissCrossSquare(n0=11)))
        levels = 5 if quick else 7
        report = (levels - 1,)
        opts = RunOptions(levels=levels, decouple="decoupled" in case, newton_stop=stop, newton=newton)
    # best of `repeat` (ex9 and test1 multigrid: 3), the finest level's fastest linear solve timed right after each run
    # (interleaved, so that both sides of the ratio see the same phases of the shared machine)
    repeat = 3 if case.startswith("ex9") or newton == "multigrid" else 1
    runs, fast_finest = [], []  # rows of every repetition; only the last result's algebra is kept alive
    finest = None
    for _ in range(repeat):
        res = finest = None
        res = run_scene(scene, opts, progress=lambda m: print(f"[{case}] {m}", flush=True))
        runs.append(res.rows)
        if len(runs) == 1:  # before any baseline solve
            peak_run = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        # the baselines of the finest level need its algebra only: its mesh and space are let go first
        fin_disc = res.discretization
        finest = SimpleNamespace(system=fin_disc.system, n_interior=fin_disc.n_interior,
                                 mg_prolongations=tuple(getattr(fin_disc, "mg_prolongations", ())))
        res = fin_disc = None
        if finest.mg_prolongations:
            fast_finest.append(fastest_linear(finest, opts.tol))
    rows = []

    def solve_time(rows_upto):
        fin = rows_upto[-1]
        return fin["time_cum_s"] - fin["time_mesh_s"] - fin["time_assembly_s"] - sum(q["time_post_s"] for q in rows_upto)

    def newton_time(rows_upto):  # prolongations and Newton solves of all levels (no mesh, assembly, errors)
        return sum(q["time_prolong_s"] + q["time_solve_s"] for q in rows_upto)

    def run_time(rows_upto):  # the whole nested run without the error evaluations
        return run_times(rows_upto)[-1]

    for L in report:
        r = runs[-1][: L + 1]
        fin = r[-1]
        t_total = min(run[L]["time_cum_s"] for run in runs)
        t_run = min(run_time(run[: L + 1]) for run in runs)
        t_solve = min(solve_time(run[: L + 1]) for run in runs)
        t_newton = min(newton_time(run[: L + 1]) for run in runs)
        t_fin_newton = min(run[L]["time_solve_s"] for run in runs)
        # one unconstrained solve on this level's matrix (rebuild the level: the run keeps only the last)
        disc = finest if L == levels - 1 else _level_disc(scene, L)
        if not getattr(disc, "mg_prolongations", ()):
            disc = _level_disc(scene, L)
        t_lins = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            xs = disc.system.unconstrained_solve()
            t_lins.append(time.perf_counter() - t0)
            assert np.all(np.isfinite(xs))
        t_lin = min(t_lins)
        fast = fast_finest if disc is finest and fast_finest else \
            [fastest_linear(disc, opts.tol) for _ in range(repeat)]
        t_fast = min(t for t, _ in fast)
        # the ratio of each repetition (run i against the baseline timed right after it): the spread of the ratio
        # on the shared machine, next to the ratio of the two minima
        per_run = [solve_time(run[: L + 1]) / t for run, (t, _) in zip(runs, fast_finest)] \
            if disc is finest and len(fast_finest) == len(runs) > 1 else None
        assert np.abs(fast[0][1] - xs).max() <= 1e-6 * np.abs(xs).max()
        # two membranes with K = blockdiag(S, alpha S): the unconstrained problem is two Poisson problems
        # with one matrix -- one factorization of S and two solves is its fastest direct solve
        t_split = None
        split = disc.system.membrane_split()
        if split is not None:
            from ngcontact.algebra.linalg import SPDSolver

            S, alpha = split
            m = disc.system.m
            t0 = time.perf_counter()
            solver = SPDSolver(S, disc.system.solver)
            xs1, xs2 = solver.solve(disc.system.F[:m]), solver.solve(disc.system.F[m:] / alpha)
            t_split = time.perf_counter() - t0
            assert np.allclose(np.concatenate([xs1, xs2]), xs, rtol=1e-8, atol=1e-12 * np.abs(xs).max())
            del solver
        ex9 = case.startswith("ex9")
        N = 16 * 2 ** L if ex9 else 11 * 2 ** L
        row = {"case": case, "N": N, "nodes": disc.n_interior, "unknowns": disc.system.n,
               "err_max_nodal": fin.get("err_max_nodal"), "err_energy": fin.get("err_energy"),
               "rate_energy": fin.get("rate_energy"),
               "err_petsc": PETSC_ERR.get(N) if ex9 else None,
               "newton_its": "/".join(str(q["newton_its"]) for q in r),
               "cg_its": "/".join(str(q["cg_its"]) for q in r) if newton == "multigrid" else None,
               "repeats": repeat,
               "converged": all(q["newton_converged"] for q in r),
               "t_total_s": t_total, "t_run_s": t_run, "t_solve_s": t_solve, "t_linear_s": t_lin,
               "ratio": t_solve / t_lin, "t_linear_fast_s": t_fast, "ratio_fast": t_solve / t_fast,
               "ratio_fast_runs": None if per_run is None else "/".join(f"{q:.2f}" for q in per_run),
               "t_newton_s": t_newton, "ratio_newton_fast": t_newton / t_fast,
               "t_linear_split_s": t_split, "ratio_split": None if t_split is None else t_solve / t_split,
               "t_finest_newton_s": t_fin_newton, "ratio_finest_fast": t_fin_newton / t_fast,
               "t_finest_assembly_s": fin["time_assembly_s"],
               "petsc_s": PETSC_S.get(N) if ex9 else None,
               "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "peak_rss_run_mb": peak_run}
        rows.append(row)
    return rows


def _fmt(v):
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.3e}" if abs(v) < 1e-2 else f"{v:.2f}"
    return str(v)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="results/bench")
    ap.add_argument("--quick", action="store_true", help="smaller sizes (smoke test)")
    ap.add_argument("--case", help=argparse.SUPPRESS)  # worker mode
    ap.add_argument("--cases", help="comma-separated subset (default: all; rows of other cases are not kept)")
    a = ap.parse_args(argv)
    if a.case:
        print("ROWS " + json.dumps(run_case(a.case, a.quick)), flush=True)
        return
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    ap_cases = ("ex9", "ex9-mg", "ex9-balanced", "ex9-mg-balanced", "test1", "test1-mg", "test1-decoupled",
                "test1-decoupled-balanced")
    for case in (a.cases.split(",") if a.cases else ap_cases):
        cmd = [sys.executable, "-m", "benchmarks.bench_contact", "--case", case] + (["--quick"] if a.quick else [])
        env = {**os.environ, "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1")}
        p = subprocess.run(cmd, capture_output=True, text=True, env=env)
        sys.stdout.write(p.stdout.replace("ROWS ", "# rows: ") if p.returncode else
                         "".join(l + "\n" for l in p.stdout.splitlines() if not l.startswith("ROWS ")))
        if p.returncode:
            sys.stderr.write(p.stderr)
            raise SystemExit(f"bench case {case} failed")
        case_rows = json.loads(next(l for l in p.stdout.splitlines() if l.startswith("ROWS "))[5:])
        with open(out / f"{case}.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(case_rows[0]))
            w.writeheader()
            w.writerows(case_rows)
        rows += case_rows
    cols = ["case", "N", "unknowns", "err_max_nodal", "err_petsc", "err_energy", "newton_its", "cg_its", "t_solve_s",
            "t_linear_s", "ratio", "t_linear_fast_s", "ratio_fast", "ratio_fast_runs", "t_newton_s",
            "ratio_newton_fast", "t_finest_newton_s", "ratio_finest_fast", "t_linear_split_s", "ratio_split", "t_run_s",
            "t_total_s", "petsc_s", "peak_rss_mb", "peak_rss_run_mb"]
    lines = ["# Benchmarks: contact solve vs one linear solve", "",
             "Generated by `make bench` (`python -m benchmarks.bench_contact`); definitions in "
             "`benchmarks/bench_contact.py`. P1, nested Newton-min, 2 NGSolve threads, 1 OpenBLAS thread; "
             "cases without -mg: sparse Cholesky per Newton step, -mg: CG + truncated multigrid "
             "(`--newton multigrid`). PETSc reference (REFERENCE.md, issue 24): vinewtonrsls + CG/GAMG, "
             "6.5-7.0 s at N = 1024 on this machine class. Times: best of 3 runs (ex9 cases, test1-mg), 1 (the "
             "other test1 cases); the finest level's CG + multigrid baseline timed right after each run.", "",
             "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(_fmt(r[c]) for c in cols) + " |" for r in rows]
    if a.cases:  # a subset: printed, BENCH.md keeps the last full run
        lines.insert(2, f"(subset {a.cases}; not written to BENCH.md)")
    else:
        (out / "BENCH.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
