"""The command line's options and help texts."""
from __future__ import annotations

import argparse

from ..results import __version__

__all__ = ["build_parser", "UsageError", "EPILOG"]


class UsageError(Exception):
    """Bad usage: one line ``ngcontact: error: ...`` and exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit code 2
        raise UsageError(message)


DESCRIPTION = "Contact problems (two membranes, obstacle) with finite elements on NGSolve."

EPILOG = """\
examples:
  ngcontact list
  ngcontact run test1 --order 2 --levels 5
  ngcontact run lshape --order 3 --adaptive --max-ndof 50000
  ngcontact run my_scene.py --cfun fb --out out/mine
  ngcontact plot out/a out/b --out compare.png
  ngcontact table out/a out/b --out tables.md

exit codes:
  0    success
  2    bad usage or bad input (unknown scene, bad option, bad data)
  3    Newton did not converge on some level (the outputs say where)
  4    resources exhausted or internal error: out of memory, the DOF budget reached before the
       requested levels, an NGSolve error, a bug (--debug shows the traceback)
  130  interrupted (Ctrl-C); 143 terminated (SIGTERM); 141 the output pipe was closed
  A run that ends early keeps its finished levels; its summary.json says "complete": false and why.

environment variables:
  NGCONTACT_THREADS  number of NGSolve threads (default: all cores)
  NGCONTACT_CASES    directory of scene files used instead of the bundled scenes
  OPENBLAS_NUM_THREADS  OpenBLAS threads (default here: 1; the package's BLAS work is vector operations)
"""


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="ngcontact", description=DESCRIPTION, epilog=EPILOG,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"ngcontact {__version__}")
    p.add_argument("--debug", action="store_true", help="show the traceback of an error (also anywhere later on the line)")
    sub = p.add_subparsers(dest="cmd", parser_class=_Parser, metavar="{run,list,plot,table,demo}")

    r = sub.add_parser("run", help="solve a scene on uniformly refined meshes or adaptively",
                       description="Solve a scene on uniformly refined meshes (--levels) or adaptively (--adaptive) "
                                   "and write a run directory.", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("scene", help="a bundled scene (see ngcontact list) or the path of a scene .py file")
    r.add_argument("--order", type=int, help="polynomial degree p (fem: 1 to 4; default: the scene's DEFAULTS, else 1)")
    r.add_argument("--levels", type=int,
                   help="uniform runs: number of mesh levels T0 to T(L-1) (default: the scene's DEFAULTS, else 4); "
                        "with --adaptive use --max-levels")
    r.add_argument("--disc", choices=["fem", "hho", "sipg", "nipg", "iipg"],
                   help="discretization: fem (conforming P_p), hho (hybrid high-order), sipg/nipg/iipg (dG)")
    r.add_argument("--constraints", choices=["nodal", "equispaced", "bernstein"],
                   help="contact constraints: nodal (default; at a node set on which no Lagrange basis function "
                        "has a negative integral: differs from the lattice at p = 4), equispaced (the lattice of "
                        "[CAMWA21]; its p = 4 edge midpoints have weight -1/45 and P4 converges at rate 1) or "
                        "bernstein (fem: nonnegative Bernstein coefficients of u1 - u2, the multiplier dual to the "
                        "Bernstein basis)")
    r.add_argument("--cfun", choices=["min", "fb"], help="C-function: min (Newton-min) or fb (Fischer-Burmeister)")
    r.add_argument("--start", choices=["nested", "cold"],
                   help="initial guess per level: nested (the previous level's solution, default) or cold")
    r.add_argument("--tol", type=float, help="Newton tolerance on ||Phi||/||F|| (default 1e-10)")
    r.add_argument("--maxit", type=int, help="maximum Newton iterations per level (default 200)")
    r.add_argument("--solver", choices=["sparsecholesky", "scipy"],
                   help="direct solver: sparsecholesky (NGSolve; UMFPACK for the non-symmetric NIPG/IIPG, default) "
                        "or scipy (SuperLU)")
    r.add_argument("--no-condense", action="store_true",
                   help="hho: solve the full system instead of the statically condensed face system")
    r.add_argument("--estimate", action="store_true",
                   help="a posteriori estimators per level (fem): eta, its parts, I_eff, eta_K maps")
    r.add_argument("--flux-order", dest="flux_order", metavar="{p,p+1}",
                   help="with --estimate, --adaptive or --newton adaptive: degree of the equilibrated flux, p "
                        "(default) or p+1 (also as a number); p+1 is often a tighter bound on coarse and adaptive "
                        "meshes, at about 1.3 to 2 times the estimation time")
    r.add_argument("--decouple", action="store_true",
                   help="two membranes with constant mu1, mu2 (fem): Newton on w = u1 - u2 only, one Poisson solve "
                        "for mu1 u1 + mu2 u2 (the same discrete solution)")
    r.add_argument("--newton", choices=["direct", "gmres", "inexact", "adaptive", "multigrid", "multigrid-inexact"],
                   help="Newton linear solves: direct (sparse factorization, default), gmres (GMRES with ILU to "
                        "||R||/||B|| <= 2e-12), inexact (GMRES with a forcing term), adaptive (GMRES stopped by the "
                        "estimators); the GMRES modes: fem only; multigrid (CG + multigrid to a tenth of the Newton "
                        "tolerance: truncated geometric multigrid on nested P1 levels of the box domains, else "
                        "algebraic multigrid; small levels are factorized), multigrid-inexact (the same with a "
                        "forcing term): fem; two-phase scenes: direct, gmres, inexact, adaptive")
    r.add_argument("--krylov", choices=["gmres", "cg"],
                   help="with --newton gmres|inexact|adaptive: the Krylov method, gmres (restarted GMRES + ILU, "
                        "[JSC20], default) or cg (CG + multigrid: geometric on nested P1 levels, else algebraic)")
    r.add_argument("--gamma-alg", type=float, dest="gamma_alg",
                   help="adaptive: stop GMRES when eta_alg <= GAMMA_ALG max(eta_disc, eta_lin), in (0, 1) (default 0.3)")
    r.add_argument("--gamma-lin", type=float, dest="gamma_lin",
                   help="adaptive: stop Newton when eta_lin <= GAMMA_LIN eta_disc, in (0, 1) (default 0.3)")
    r.add_argument("--newton-stop", choices=["residual", "balanced"], dest="newton_stop",
                   help="direct Newton: stop on ||Phi||/||F|| <= tol (residual, default) or also when the "
                        "linearization defect is below GAMMA_BALANCE times the coarse-to-fine change (balanced)")
    r.add_argument("--gamma-balance", type=float, dest="gamma_balance",
                   help="with --newton-stop balanced: the ratio (default 1e-3)")
    r.add_argument("--nu", type=int, help="adaptive: GMRES iterations between estimator evaluations (default 10)")
    r.add_argument("--ilu-drop", type=float, dest="ilu_drop_tol",
                   help="GMRES modes: ILU drop tolerance (default 1e-5)")
    r.add_argument("--ilu-fill", type=float, dest="ilu_fill",
                   help="GMRES modes: ILU fill bound, nnz(L+U) <= ILU_FILL nnz(A) (default 8)")
    r.add_argument("--adaptive", action="store_true",
                   help="adaptive refinement (fem): solve, estimate, mark, bisect; Newton warm-started")
    r.add_argument("--marking", choices=["doerfler", "max"], help="with --adaptive: marking strategy (default doerfler)")
    r.add_argument("--theta", type=float, help="with --adaptive: marking parameter in (0, 1] (default 0.5)")
    r.add_argument("--max-ndof", type=int, dest="max_ndof",
                   help="DOF budget: no level above it (default: from the memory this process may use; adaptive "
                        "runs without --target-eta and --max-time: 100000)")
    r.add_argument("--target-eta", type=float, dest="target_eta", help="with --adaptive: stop when eta <= E")
    r.add_argument("--max-time", type=float, dest="max_time", help="with --adaptive: wall-time budget in seconds")
    r.add_argument("--max-levels", type=int, dest="max_levels", help="with --adaptive: at most L levels (default 30)")
    r.add_argument("--out", help="output directory: new, empty, or one that ngcontact wrote and that holds nothing "
                                 "else, which is replaced (default results/runs/SCENE-DISC-pP[-adaptive])")
    r.add_argument("--no-vtk", action="store_true", help="no solution.vtu")
    r.add_argument("--vtk-series", action="store_true",
                   help="also solution_l<level>.vtu after every level and solution.pvd listing them (ParaView)")
    r.add_argument("--no-plots", action="store_true", help="no PNG figures")
    r.add_argument("--test", action="store_true",
                   help="short run with the scene's TEST_OPTIONS (options given explicitly override them)")
    r.add_argument("--cells", type=int, help="two-phase scenes: number of cells (default 1000)")
    r.add_argument("--dt-years", type=float, dest="dt_years", help="two-phase scenes: time step in years (default 5000)")
    r.add_argument("--t-final-years", type=float, dest="t_final_years",
                   help="two-phase scenes: final time in years (default 1e6)")
    r.add_argument("--dt", type=float, help="time-dependent scenes: time step (default: the scene's, 1e-3)")
    r.add_argument("--t-final", type=float, dest="t_final", help="time-dependent scenes: final time T")
    r.add_argument("--adaptive-dt", action="store_true", dest="adaptive_dt",
                   help="time-dependent scenes: time steps balancing the temporal and spatial estimators")
    r.add_argument("--dt-rule", choices=("equidistribute", "balance"), dest="dt_rule",
                   help="with --adaptive-dt: equal contributions of the steps to the estimate (default) or "
                        "eta_tm = safety x eta_sp per step")
    r.add_argument("--dt-safety", type=float, dest="safety",
                   help="with --adaptive-dt: the rule's safety factor (default 0.2 equidistribute, 0.8 balance)")
    r.add_argument("--level", type=int, help="time-dependent scenes: uniform refinements of the scene's mesh")
    r.add_argument("--maxh", type=float, help="time-dependent scenes: mesh size of the scene's (netgen) domain")
    r.add_argument("--vtk-every", type=int, dest="vtk_every", metavar="K",
                   help="time-dependent scenes: solution_n*.vtu every K-th step and solution.pvd")
    r.add_argument("-v", "--verbose", action="store_true", help="print every Newton iteration")
    r.add_argument("-q", "--quiet", action="store_true",
                   help="no per-level progress: only the final table, the stop reason and the output paths")

    sub.add_parser("list", help="list the bundled scenes", description="List the bundled scenes.")

    pl = sub.add_parser("plot", help="overlay the error (or estimator) of several runs",
                        description="Energy error against DOFs and against run time of several run directories "
                                    "(the estimator eta for runs without an exact solution).")
    pl.add_argument("dirs", nargs="+", help="run directories (with history.csv)")
    pl.add_argument("--out", required=True, help="PNG file to write")
    pl.add_argument("--title", default="")

    tb = sub.add_parser("table", help="markdown tables of run directories",
                        description="Markdown tables (error, rate, Newton iterations, times) of run directories.")
    tb.add_argument("dirs", nargs="+", help="run directories (with history.csv)")
    tb.add_argument("--out", help="markdown file to write (default: print)")

    d = sub.add_parser("demo", help="test1, P1 and P2 on 4 uniform levels, with an overview figure",
                       description="The default scene test1 with FEM P1 and P2 on uniform levels.")
    d.add_argument("--out", default="results/runs/demo",
                   help="output directory, replaced like a run directory (default results/runs/demo)")
    d.add_argument("--levels", type=int, default=4, help="uniform mesh levels per degree (default 4)")
    return p
