"""Command line: ``python -m ngcontact {run,list,plot,table,demo}``.

Examples::

    python -m ngcontact run test1 --order 2 --levels 5
    python -m ngcontact run lshape --order 3 --adaptive --max-ndof 50000
    python -m ngcontact run path/to/my_scene.py --cfun fb --out out/my
    python -m ngcontact list
    python -m ngcontact plot out/a out/b --out compare.png
    python -m ngcontact table out/a out/b --out tables.md

Bad input (unknown scene, scene with an error, bad option or data) prints
one line ``ngcontact: error: ...`` and exits with code 2; no partial
outputs are left (also on Ctrl-C, exit 130, and SIGTERM, exit 143).  ``--out`` must be a
new or empty directory or a previous run directory (with summary.json), which is replaced;
it is checked before any computation.  If Newton does not converge on some level, the outputs
are written with ``"converged": false`` in summary.json and the exit code is 3.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import traceback
from pathlib import Path

__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit code 2
        raise _UsageError(message)


class _UsageError(Exception):
    pass


def _build_parser():
    p = _Parser(prog="python -m ngcontact", description=__doc__.split("\n\n")[0])
    p.add_argument("--debug", action="store_true", help="show tracebacks (anywhere on the line)")
    sub = p.add_subparsers(dest="cmd", parser_class=_Parser)

    r = sub.add_parser("run", help="solve a scene on uniformly refined meshes (--levels) or adaptively (--adaptive)")
    r.add_argument("scene", help="scene name in cases/ (see `list`) or path to a scene .py file")
    r.add_argument("--order", type=int, help="polynomial degree p (fem: 1..4; default: the scene's DEFAULTS, else 1)")
    r.add_argument("--levels", type=int,
                   help="uniform runs: number of mesh levels T0..T_{L-1} (default: the scene's DEFAULTS, else 4); "
                        "with --adaptive use --max-levels")
    r.add_argument("--disc", choices=["fem", "hho", "sipg", "nipg", "iipg"],
                   help="discretization: fem (conforming P_p), hho (hybrid high-order), sipg/nipg/iipg (dG)")
    r.add_argument("--cfun", choices=["min", "fb"], help="C-function: min (Newton-min) or fb (Fischer-Burmeister)")
    r.add_argument("--start", choices=["nested", "cold"],
                   help="initial guess per level: nested (prolongate previous level, default) or cold")
    r.add_argument("--tol", type=float, help="Newton tolerance on ||Phi||/||F|| (default 1e-10)")
    r.add_argument("--maxit", type=int, help="maximum Newton iterations per level (default 200)")
    r.add_argument("--solver", choices=["sparsecholesky", "scipy"],
                   help="direct solver: sparsecholesky (NGSolve; UMFPACK for the non-symmetric NIPG/IIPG, default) "
                        "or scipy (SuperLU)")
    r.add_argument("--no-condense", action="store_true",
                   help="hho: solve the full system instead of the statically condensed face system")
    r.add_argument("--estimate", action="store_true",
                   help="a posteriori estimators per level (fem): eta, components, I_eff, eta_K maps")
    r.add_argument("--flux-order", dest="flux_order", metavar="{p,p+1}",
                   help="with --estimate, --adaptive or --newton adaptive: RT degree of the equilibrated flux, p "
                        "(default) or p+1 (also as a number); p+1 is often a tighter bound on coarse and adaptive "
                        "meshes, at about 1.3-2x the estimation time (README, 'A posteriori estimators')")
    r.add_argument("--decouple", action="store_true",
                   help="two membranes with mu1, mu2 constant (fem): Newton on w = u1 - u2 only, one Poisson solve for "
                        "mu1 u1 + mu2 u2 (same discrete solution; coupled Newton when the structure does not allow it)")
    r.add_argument("--newton", choices=["direct", "gmres", "inexact", "adaptive"],
                   help="Newton linear solves: direct (sparse factorization, default), gmres (GMRES+ILU to "
                        "||R||/||B|| <= 2e-12, the 'exact' mode of [JSC20]), inexact (GMRES with a forcing term), "
                        "adaptive (GMRES stopped by the estimators, [JSC20]); the GMRES modes: fem only")
    r.add_argument("--gamma-alg", type=float, dest="gamma_alg",
                   help="adaptive: stop GMRES when eta_alg <= GAMMA_ALG max(eta_disc, eta_lin), in (0, 1) (default 0.3)")
    r.add_argument("--gamma-lin", type=float, dest="gamma_lin",
                   help="adaptive: stop Newton when eta_lin <= GAMMA_LIN eta_disc, in (0, 1) (default 0.3)")
    r.add_argument("--newton-stop", choices=["residual", "balanced"], dest="newton_stop",
                   help="exact Newton: stop on ||Phi||/||F|| <= tol (residual, default) or also when the linearization "
                        "defect is below GAMMA_BALANCE x the coarse-to-fine change (balanced, nested levels)")
    r.add_argument("--gamma-balance", type=float, dest="gamma_balance",
                   help="with --newton-stop balanced: the ratio (default 1e-3)")
    r.add_argument("--nu", type=int, help="adaptive: GMRES iterations between estimator evaluations (default 10)")
    r.add_argument("--ilu-drop", type=float, dest="ilu_drop_tol",
                   help="GMRES modes: ILU drop tolerance (scipy spilu drop_tol, default 1e-5)")
    r.add_argument("--ilu-fill", type=float, dest="ilu_fill",
                   help="GMRES modes: ILU fill bound nnz(L+U) <= ILU_FILL nnz(A) (spilu fill_factor, default 8)")
    r.add_argument("--adaptive", action="store_true",
                   help="adaptive refinement (fem): solve -> estimate -> mark -> bisect, warm-started Newton")
    r.add_argument("--marking", choices=["doerfler", "max"], help="with --adaptive: marking strategy (default doerfler)")
    r.add_argument("--theta", type=float, help="with --adaptive: marking parameter in (0, 1] (default 0.5)")
    r.add_argument("--max-ndof", type=int, dest="max_ndof", help="with --adaptive: DOF budget (no level above it)")
    r.add_argument("--target-eta", type=float, dest="target_eta", help="with --adaptive: stop when eta <= E")
    r.add_argument("--max-time", type=float, dest="max_time", help="with --adaptive: wall-time budget [s]")
    r.add_argument("--max-levels", type=int, dest="max_levels", help="with --adaptive: at most L levels (default 30)")
    # without any of --max-ndof / --target-eta / --max-time an adaptive CLI run gets DEFAULT_MAX_NDOF (said in its header)
    r.add_argument("--out", help="output directory: new, empty or a previous run directory, which is replaced "
                                 "(default results/runs/SCENE-DISC-pP[-adaptive])")
    r.add_argument("--no-vtk", action="store_true", help="skip the .vtu output")
    r.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    r.add_argument("--test", action="store_true",
                   help="short run with the scene's TEST_OPTIONS (options given explicitly override them)")
    r.add_argument("-v", "--verbose", action="store_true", help="log every Newton iteration")
    r.add_argument("-q", "--quiet", action="store_true", help="no per-level progress: only the final table, the stop reason and the output paths")

    sub.add_parser("list", help="list the bundled scenes")

    pl = sub.add_parser("plot", help="overlay energy error vs ndof and vs time of several runs")
    pl.add_argument("dirs", nargs="+", help="run directories (with history.csv)")
    pl.add_argument("--out", required=True, help="PNG file to write")
    pl.add_argument("--title", default="")

    tb = sub.add_parser("table", help="markdown tables (error, rate, Newton its, times) of run directories")
    tb.add_argument("dirs", nargs="+", help="run directories (with history.csv)")
    tb.add_argument("--out", help="markdown file to write (default: print)")

    d = sub.add_parser("demo", help="the default scene: test1, P1 and P2, 4 uniform levels")
    d.add_argument("--out", default="results/demo", help="output directory (default results/demo)")
    d.add_argument("--levels", type=int, default=4, help="uniform mesh levels per degree (default 4)")
    return p


def format_table(rows, title="") -> str:
    cols = [("level", "{:>5d}"), ("ndof", "{:>8d}"), ("ndof_sc", "{:>8d}"), ("h", "{:>9.3e}"),
            ("err_energy", "{:>11.3e}"), ("rate_energy", "{:>6.2f}"), ("eta", "{:>10.3e}"), ("i_eff", "{:>6.3f}"),
            ("err_max_nodal", "{:>10.2e}"), ("newton_its", "{:>6d}"),
            ("active_nodes", "{:>7d}"), ("time_solve_s", "{:>9.2f}"), ("time_total_s", "{:>9.2f}")]
    heads = {"level": "level", "ndof": "ndof", "ndof_sc": "ndof_sc", "eta": "eta", "i_eff": "I_eff", "h": "h", "err_energy": "err_energy", "rate_energy": "rate",
             "err_max_nodal": "err_max", "newton_its": "newton", "active_nodes": "active",
             "time_solve_s": "solve[s]", "time_total_s": "total[s]"}
    cols = [(c, f) for c, f in cols if rows and c in rows[0]]
    width = [len(f.format(0 if "d" in f else 0.0)) for _, f in cols]
    lines = [title] if title else []
    lines.append(" ".join(heads[c].rjust(w) for (c, _), w in zip(cols, width)))
    for r in rows:
        cells = []
        for (c, f), w in zip(cols, width):
            v = r.get(c)
            if v is None or (isinstance(v, float) and v != v):
                cells.append("-".rjust(w))
            else:
                cells.append(f.format(v))
        lines.append(" ".join(cells))
    return "\n".join(lines)


def _check_solver_options(args, newton: str) -> None:
    """Options of the GMRES Newton modes given with a mode that does not use them: a usage error
    (silently ignoring them would let a user believe they changed the run)."""
    gmres = {"ilu_drop_tol": "--ilu-drop", "ilu_fill": "--ilu-fill"}
    adaptive = {"gamma_alg": "--gamma-alg", "gamma_lin": "--gamma-lin", "nu": "--nu"}
    used = [flag for name, flag in gmres.items() if getattr(args, name, None) is not None]
    if used and newton == "direct":
        raise _UsageError(f"option(s) {', '.join(used)} need --newton gmres, inexact or adaptive "
                          f"(the direct mode uses no iterative solver)")
    used = [flag for name, flag in adaptive.items() if getattr(args, name, None) is not None]
    if used and newton != "adaptive":
        raise _UsageError(f"option(s) {', '.join(used)} need --newton adaptive (got --newton {newton})")


#: CLI flag of a RunOptions field whose name differs from --field-name
_FLAGS = {"ilu_drop_tol": "--ilu-drop", "condense": "--no-condense", "estimate": "--estimate",
          "adaptive": "--adaptive"}

#: DOF budget of an adaptive CLI run that gives no stopping criterion (its header says so)
DEFAULT_MAX_NDOF = 100_000


def _flag(name: str) -> str:
    return _FLAGS.get(name, "--" + name.replace("_", "-"))


def _cli_message(exc: Exception) -> str:
    """A RunOptions error in the words of the command line (``option max_ndof`` -> ``option --max-ndof``)."""
    import re

    msg = re.sub(r"\boption (\w+)", lambda m: "option " + _flag(m.group(1)), str(exc))
    return msg.replace("(or None)", "(or omitted)").replace(", or None", "")


def _parse_flux_order(value, order: int):
    """--flux-order: 'p', 'p+1' or a number."""
    if value is None:
        return None
    v = str(value).replace(" ", "").lower()
    if v == "p":
        return order
    if v == "p+1":
        return order + 1
    try:
        return int(v)
    except ValueError:
        raise _UsageError(f"option --flux-order must be p, p+1 or an integer, got {value!r}") from None


def _check_run_flags(args, options, scene) -> None:
    """Flags that the chosen run would silently ignore: usage errors."""
    _check_solver_options(args, options.newton)
    if args.verbose and args.quiet:
        raise _UsageError("options -v/--verbose and -q/--quiet exclude each other")
    if args.adaptive and args.levels is not None:
        raise _UsageError("option --levels sets the number of uniform levels; with --adaptive use --max-levels "
                          "(or a budget: --max-ndof, --target-eta, --max-time)")
    if args.no_condense and options.disc != "hho":
        raise _UsageError(f"option --no-condense needs --disc hho (got --disc {options.disc})")
    if args.decouple and scene.problem.nfields != 2:
        raise _UsageError(f"option --decouple needs a two-membrane scene ({scene.name} is a "
                          f"{type(scene.problem).__name__})")
    if args.gamma_balance is not None and options.newton_stop != "balanced":
        raise _UsageError("option --gamma-balance needs --newton-stop balanced")


def _cmd_run(args, argv) -> int:
    from dataclasses import replace

    from .plotting import write_run_plots
    from .results import check_output_dir, write_run
    from .drivers import RunOptions, run_scene
    from .scenes import load_scene

    scene = load_scene(args.scene)
    given = dict(order=args.order, levels=args.levels, disc=args.disc, cfun=args.cfun, start=args.start,
                 tol=args.tol, maxit=args.maxit, solver=args.solver,
                 condense=False if args.no_condense else None, estimate=True if args.estimate else None,
                 newton=args.newton, gamma_alg=args.gamma_alg, gamma_lin=args.gamma_lin, nu=args.nu,
                 decouple=True if args.decouple else None, newton_stop=args.newton_stop,
                 gamma_balance=args.gamma_balance, ilu_drop_tol=args.ilu_drop_tol, ilu_fill=args.ilu_fill)
    adaptive_opts = dict(marking=args.marking, theta=args.theta, max_ndof=args.max_ndof, target_eta=args.target_eta,
                         max_time=args.max_time, max_levels=args.max_levels)
    if not args.adaptive and any(v is not None for v in adaptive_opts.values()):
        used = [k for k, v in adaptive_opts.items() if v is not None]
        raise _UsageError(f"option(s) {', '.join('--' + k.replace('_', '-') for k in used)} need --adaptive")
    given.update(adaptive=True if args.adaptive else None, **adaptive_opts)
    if args.test:
        if not scene.test_options:
            raise _UsageError(f"option --test needs TEST_OPTIONS in the scene file ({scene.name} has none)")
        given = {**scene.test_options, **{k: v for k, v in given.items() if v is not None}}
    try:
        options = RunOptions.for_scene(scene, **given)
        _check_run_flags(args, options, scene)
        if args.flux_order is not None:
            if not (options.estimate or options.adaptive or options.newton == "adaptive"):
                raise _UsageError("option --flux-order needs --estimate, --adaptive or --newton adaptive "
                                  "(nothing is estimated)")
            options = replace(options, flux_order=_parse_flux_order(args.flux_order, options.order))
        budget = ""
        if options.adaptive and options.max_ndof is None and options.target_eta is None and options.max_time is None:
            options = replace(options, max_ndof=DEFAULT_MAX_NDOF)
            budget = f", default budget --max-ndof {DEFAULT_MAX_NDOF}"
    except ValueError as exc:
        raise _UsageError(_cli_message(exc)) from None
    given_out = args.out
    if given_out is None:
        given_out = f"results/runs/{scene.name}-{options.disc}-p{options.order}" + ("-adaptive" if options.adaptive else "")
    check_output_dir(given_out, "--out")  # before solving: a bad path fails in a second
    out = Path(given_out)
    say = (lambda m: None) if args.quiet else (lambda m: print(m, flush=True))
    desc = scene.description.rstrip(".")
    say(f"ngcontact: scene {scene.name} ({desc}) | {options.disc} P{options.order}, "
        + (f"adaptive ({options.marking}, theta={options.theta:g}{budget}), " if options.adaptive
           else f"{options.levels} levels, ")
        + f"Newton-{options.cfun}, {options.start} start")
    newton_cb = None
    if args.verbose:
        def newton_cb(level, rec):
            print(f"  [level {level}] k={rec.k:3d} res={rec.res:.3e} active={rec.n_active} "
                  f"changed={rec.n_changed} step={rec.step:.3g} linear={rec.time_linear:.3f}s", flush=True)
    t0 = time.perf_counter()
    result = run_scene(scene, options, progress=say, newton_callback=newton_cb)
    write_run(result, out, vtk=not args.no_vtk, plots=None if args.no_plots else write_run_plots,
              argv=["python -m ngcontact", *argv])
    print(format_table(result.rows, f"\n{scene.name}: {options.disc} P{options.order} ({time.perf_counter() - t0:.1f} s)"))
    if result.stop_reason and args.quiet:  # otherwise the loop's progress line said it
        print(f"adaptive loop stopped: {result.stop_reason}")
    print(f"outputs: {out}/ (history.csv, newton.csv, summary.json"
          + ("" if args.no_plots else ", *.png") + ("" if args.no_vtk else ", solution.vtu") + ")")
    if not result.converged:
        for f in result.failures:
            print(f"ngcontact: warning: {f}", file=sys.stderr)
        if any("round-off floor" in f for f in result.failures):
            print("ngcontact: hint: the Newton tolerance is --tol", file=sys.stderr)
        return 3
    return 0


def _cmd_demo(args, argv) -> int:
    from .plotting import plot_compare, write_run_plots
    from .results import check_output_dir, write_run
    from .drivers import RunOptions, run_scene
    from .scenes import load_scene

    scene = load_scene("test1")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {args.out!r} exists and is not a directory")
    for p in (1, 2):
        check_output_dir(out / f"p{p}", "--out")
    try:
        opts_p = {p: RunOptions.for_scene(scene, order=p, levels=args.levels) for p in (1, 2)}
    except ValueError as exc:
        raise _UsageError(_cli_message(exc)) from None
    dirs = []
    status = 0
    for p in (1, 2):
        opts = opts_p[p]
        print(f"== demo: {scene.name} ({scene.description.rstrip('.')}), FEM P{p}, {args.levels} uniform levels",
              flush=True)
        res = run_scene(scene, opts, progress=lambda m: print(m, flush=True))
        d = write_run(res, out / f"p{p}", plots=write_run_plots, argv=["python -m ngcontact", *argv])
        dirs.append(d)
        print(format_table(res.rows, f"\ntest1 FEM P{p}"))
        print()
        status = status or (0 if res.converged else 3)
    png = plot_compare(dirs, out / "convergence.png", title="test1 [CAMWA21]: FEM P1, P2")
    print(f"outputs: {out}/p1, {out}/p2 (history.csv, newton.csv, summary.json, PNGs, solution.vtu); overview {png}")
    return status


def _apply_thread_setting() -> None:
    """``NGCONTACT_THREADS=N``: N NGSolve threads (default: NGSolve's, all cores).  The study targets of the
    Makefile set 1, so that ``make -j2`` runs two single-threaded runs instead of oversubscribing the cores
    with NGSolve's spinning task threads."""
    value = os.environ.get("NGCONTACT_THREADS")
    if value is None or value == "":
        return
    if not value.isdigit() or int(value) < 1:
        raise _UsageError(f"environment variable NGCONTACT_THREADS must be a positive integer, got {value!r}")
    from ngsolve import SetNumThreads

    SetNumThreads(int(value))


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that partial outputs are removed on the way out."""


def _on_sigterm(signum, frame):
    raise _Terminated()


def main(argv=None) -> int:
    import signal

    argv = list(sys.argv[1:] if argv is None else argv)
    parser = _build_parser()
    try:
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread (embedded use): leave signals alone
        previous = None
    try:
        return _main(argv, parser)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _main(argv, parser) -> int:
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    try:
        args = parser.parse_args(argv)
        if args.cmd is None:
            parser.print_help()
            return 2
        if args.cmd == "list":
            from .scenes import list_scenes, load_scene

            for name in list_scenes():
                try:
                    print(f"{name:14s} {load_scene(name).description}")
                except Exception as exc:  # a broken scene should not hide the others
                    print(f"{name:14s} (cannot load: {exc})")
            return 0
        if args.cmd == "plot":
            from .plotting import plot_compare

            for d in args.dirs:
                if not (Path(d) / "history.csv").is_file():
                    raise ValueError(f"{d} is not a run directory (no history.csv)")
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            print(plot_compare(args.dirs, args.out, args.title))
            return 0
        if args.cmd == "table":
            from .results import markdown_table

            for d in args.dirs:
                if not (Path(d) / "history.csv").is_file():
                    raise ValueError(f"{d} is not a run directory (no history.csv)")
            text = markdown_table(args.dirs)
            if args.out:
                Path(args.out).parent.mkdir(parents=True, exist_ok=True)
                Path(args.out).write_text(text + "\n")
                print(args.out)
            else:
                print(text)
            return 0
        _apply_thread_setting()
        if args.cmd == "demo":
            return _cmd_demo(args, argv)
        return _cmd_run(args, argv)
    except _UsageError as exc:
        print(f"ngcontact: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("ngcontact: interrupted", file=sys.stderr)
        return 130
    except _Terminated:
        print("ngcontact: terminated", file=sys.stderr)
        return 143
    except (ValueError, FileNotFoundError, ArithmeticError) as exc:
        if debug:
            traceback.print_exc()
        print(f"ngcontact: error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:
        if debug:
            traceback.print_exc()
        print(f"ngcontact: error: {type(exc).__name__}: {exc} (rerun with --debug for the traceback)",
              file=sys.stderr)
        return 2
