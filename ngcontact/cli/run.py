"""``ngcontact run`` and ``ngcontact demo``: options -> run -> run directory, written level by level."""
from __future__ import annotations

import re
import sys
import time
from dataclasses import replace

from .parser import UsageError
from .report import format_table

__all__ = ["cmd_run", "cmd_demo", "DEFAULT_MAX_NDOF", "RunStopped"]

#: DOF budget of an adaptive CLI run that gives no stopping criterion (its header says so)
DEFAULT_MAX_NDOF = 100_000

#: CLI flag of a RunOptions field whose name differs from --field-name
_FLAGS = {"ilu_drop_tol": "--ilu-drop", "condense": "--no-condense", "estimate": "--estimate",
          "adaptive": "--adaptive"}


class RunStopped(Exception):
    """A run that ended before its requested levels (the DOF budget): exit code 4, the outputs written."""


def _flag(name: str) -> str:
    return _FLAGS.get(name, "--" + name.replace("_", "-"))


def _cli_message(exc: Exception) -> str:
    """A RunOptions error in the words of the command line (``option max_ndof`` -> ``option --max-ndof``)."""
    msg = re.sub(r"\boption (\w+)", lambda m: "option " + _flag(m.group(1)), str(exc))
    return msg.replace("(or None)", "(or omitted)").replace(", or None", "")


def _parse_flux_order(value, order: int):
    """--flux-order: 'p', 'p+1' or a number."""
    v = str(value).replace(" ", "").lower()
    if v == "p":
        return order
    if v == "p+1":
        return order + 1
    try:
        return int(v)
    except ValueError:
        raise UsageError(f"option --flux-order must be p, p+1 or an integer, got {value!r}") from None


def _check_solver_options(args, newton: str) -> None:
    """Options of the GMRES Newton modes given with a mode that does not use them: a usage error
    (silently ignoring them would let a user believe they changed the run)."""
    gmres = {"ilu_drop_tol": "--ilu-drop", "ilu_fill": "--ilu-fill", "krylov": "--krylov"}
    adaptive = {"gamma_alg": "--gamma-alg", "gamma_lin": "--gamma-lin", "nu": "--nu"}
    used = [flag for name, flag in gmres.items() if getattr(args, name, None) is not None]
    if used and newton not in ("gmres", "inexact", "adaptive"):
        raise UsageError(f"option(s) {', '.join(used)} need --newton gmres, inexact or adaptive "
                         f"(the {newton} mode uses no GMRES)")
    used = [flag for name, flag in adaptive.items() if getattr(args, name, None) is not None]
    if used and newton != "adaptive":
        raise UsageError(f"option(s) {', '.join(used)} need --newton adaptive (got --newton {newton})")


def _check_run_flags(args, options, scene) -> None:
    """Flags that the chosen run would silently ignore: usage errors."""
    _check_solver_options(args, options.newton)
    if args.verbose and args.quiet:
        raise UsageError("options -v/--verbose and -q/--quiet exclude each other")
    if args.adaptive and args.levels is not None:
        raise UsageError("option --levels sets the number of uniform levels; with --adaptive use --max-levels "
                         "(or a budget: --max-ndof, --target-eta, --max-time)")
    if args.no_condense and options.disc != "hho":
        raise UsageError(f"option --no-condense needs --disc hho (got --disc {options.disc})")
    if args.decouple and scene.problem.nfields != 2:
        kind = type(scene.problem).__name__
        raise UsageError(f"option --decouple needs a two-membrane scene ({scene.name} is "
                         f"{'an' if kind[0] in 'AEIOU' else 'a'} {kind})")
    if args.gamma_balance is not None and options.newton_stop != "balanced":
        raise UsageError("option --gamma-balance needs --newton-stop balanced")
    if args.vtk_series and args.no_vtk:
        raise UsageError("options --vtk-series and --no-vtk exclude each other")


def with_budget(options, given_max_ndof):
    """(options with max_ndof, header text): the DOF budget of a CLI run (``--max-ndof`` help)."""
    from ..drivers import memory_budget

    if given_max_ndof is not None:
        return options, ""
    budget, why = memory_budget(options)
    if options.adaptive and options.target_eta is None and options.max_time is None:
        if budget is None or budget >= DEFAULT_MAX_NDOF:
            return replace(options, max_ndof=DEFAULT_MAX_NDOF), f", default budget --max-ndof {DEFAULT_MAX_NDOF}"
    if budget is None:
        return options, ""
    return replace(options, max_ndof=budget), f", DOF budget {budget} ({why}; --max-ndof)"


def _run_options(scene, args):
    """The RunOptions of ``ngcontact run`` and the budget text of its header."""
    from ..drivers import RunOptions

    given = dict(order=args.order, levels=args.levels, disc=args.disc, cfun=args.cfun, start=args.start,
                 tol=args.tol, maxit=args.maxit, solver=args.solver,
                 condense=False if args.no_condense else None, estimate=True if args.estimate else None,
                 newton=args.newton, gamma_alg=args.gamma_alg, gamma_lin=args.gamma_lin, nu=args.nu,
                 decouple=True if args.decouple else None, newton_stop=args.newton_stop,
                 gamma_balance=args.gamma_balance, ilu_drop_tol=args.ilu_drop_tol, ilu_fill=args.ilu_fill,
                 max_ndof=args.max_ndof, constraints=args.constraints, krylov=args.krylov)
    adaptive_opts = dict(marking=args.marking, theta=args.theta, target_eta=args.target_eta,
                         max_time=args.max_time, max_levels=args.max_levels)
    if not args.adaptive and any(v is not None for v in adaptive_opts.values()):
        used = [k for k, v in adaptive_opts.items() if v is not None]
        raise UsageError(f"option(s) {', '.join('--' + k.replace('_', '-') for k in used)} need --adaptive")
    given.update(adaptive=True if args.adaptive else None, **adaptive_opts)
    if args.test:
        if not scene.test_options:
            raise UsageError(f"option --test needs TEST_OPTIONS in the scene file ({scene.name} has none)")
        given = {**scene.test_options, **{k: v for k, v in given.items() if v is not None}}
    try:
        options = RunOptions.for_scene(scene, **given)
        _check_run_flags(args, options, scene)
        if args.flux_order is not None:
            if not (options.estimate or options.adaptive or options.newton == "adaptive"):
                raise UsageError("option --flux-order needs --estimate, --adaptive or --newton adaptive "
                                 "(nothing is estimated)")
            options = replace(options, flux_order=_parse_flux_order(args.flux_order, options.order))
        return with_budget(options, args.max_ndof)
    except ValueError as exc:
        raise UsageError(_cli_message(exc)) from None


class Session:
    """The writer of the run in progress (``Session.writer``), so that the error handler can close its directory."""

    writer = None


def cmd_run(args, argv) -> int:
    from ..domains.base import import_collected
    from ..drivers import run_scene

    import_collected("ngcontact.plotting")  # matplotlib's first import: no garbage holding this frame's locals
    from ..plotting import write_run_plots
    from ..results import RunWriter
    from ..scenes import load_scene
    from ..twophase.params import TwoPhaseParams
    from .twophase import check_membrane_flags, cmd_run_twophase

    scene = load_scene(args.scene)
    from ..problems import ParabolicProblem

    if isinstance(scene.problem, TwoPhaseParams):  # water-hydrogen flow: its own time loop and outputs
        return cmd_run_twophase(scene, args, argv)
    if isinstance(scene.problem, ParabolicProblem):
        from .parabolic import cmd_run_parabolic

        return cmd_run_parabolic(scene, args, argv)
    check_membrane_flags(args)
    time_flags = [f for f, v in (("--dt", args.dt), ("--t-final", args.t_final), ("--adaptive-dt", args.adaptive_dt),
                                 ("--dt-rule", args.dt_rule), ("--dt-safety", args.safety),
                                 ("--level", args.level), ("--maxh", args.maxh), ("--vtk-every", args.vtk_every)) if v]
    if time_flags:
        raise UsageError(f"option(s) {', '.join(time_flags)} need a time-dependent scene ({scene.name} is stationary)")
    options, budget = _run_options(scene, args)
    out = args.out if args.out is not None else (f"results/runs/{scene.name}-{options.disc}-p{options.order}"
                                                 + ("-adaptive" if options.adaptive else ""))
    writer = RunWriter(out, vtk=not args.no_vtk, vtk_series=args.vtk_series,  # checks --out before solving
                       plots=None if args.no_plots else write_run_plots, argv=["ngcontact", *argv], field="--out")
    Session.writer = writer
    say = (lambda m: None) if args.quiet else (lambda m: print(m, flush=True))
    say(f"ngcontact: scene {scene.name} ({scene.description.rstrip('.')}) | {options.disc} P{options.order}, "
        + (f"adaptive ({options.marking}, theta={options.theta:g}{budget}), " if options.adaptive
           else f"{options.levels} levels{budget}, ")
        + f"Newton-{options.cfun}, {options.start} start")
    newton_cb = None
    if args.verbose:
        def newton_cb(level, rec):
            print(f"  [level {level}] k={rec.k:3d} res={rec.res:.3e} active={rec.n_active} "
                  f"changed={rec.n_changed} step={rec.step:.3g} linear={rec.time_linear:.3f}s", flush=True)
    t0 = time.perf_counter()
    result = run_scene(scene, options, progress=say, newton_callback=newton_cb, on_level=writer.level)
    path = writer.finish(result)
    Session.writer = None
    for note in writer.dir.notes:
        print(f"ngcontact: note: {note}", file=sys.stderr)
    for note in result.notes:
        print(f"ngcontact: note: Newton safeguard, {note}", file=sys.stderr)
    for caveat in result.caveats:
        print(f"ngcontact: warning: {caveat}", file=sys.stderr)
    print(format_table(result.rows, f"\n{scene.name}: {options.disc} P{options.order} ({time.perf_counter() - t0:.1f} s)"))
    if result.stop_reason and args.quiet and result.complete:  # otherwise the loop's progress line said it
        print(f"adaptive loop stopped: {result.stop_reason}")
    print(f"outputs: {path}/ (history.csv, newton.csv, summary.json"
          + ("" if args.no_plots else ", *.png") + ("" if args.no_vtk else ", solution.vtu") + ")")
    if not result.complete:
        raise RunStopped(f"stopped before the requested {options.levels} levels: {result.stop_reason}; the finished "
                         f"levels are in {path}/ (a larger --max-ndof raises the budget)")
    if not result.converged:
        for f in result.failures:
            print(f"ngcontact: warning: {f}", file=sys.stderr)
        if any("round-off floor" in f for f in result.failures):
            print("ngcontact: hint: the Newton tolerance is --tol", file=sys.stderr)
        return 3
    return 0


def cmd_demo(args, argv) -> int:
    from ..domains.base import import_collected
    from ..drivers import RunOptions, run_scene

    import_collected("ngcontact.plotting")  # as in cmd_run
    from ..plotting import plot_compare, write_run_plots
    from ..results import OutputDir, RunWriter
    from ..scenes import load_scene

    scene = load_scene("test1")
    demo = OutputDir(args.out, "demo", "--out")
    try:
        opts_p = {p: RunOptions.for_scene(scene, order=p, levels=args.levels) for p in (1, 2)}
    except ValueError as exc:
        raise UsageError(_cli_message(exc)) from None
    dirs, status = [], 0
    for p in (1, 2):
        opts, budget = with_budget(opts_p[p], None)
        print(f"== demo: {scene.name} ({scene.description.rstrip('.')}), FEM P{p}, {args.levels} uniform levels{budget}",
              flush=True)
        writer = RunWriter(demo.path / f"p{p}", plots=write_run_plots, argv=["ngcontact", *argv], field="--out")
        Session.writer = writer

        def on_level(result, writer=writer, name=f"p{p}"):
            demo.register(name)  # the first call replaces the previous demo
            writer.level(result)
        res = run_scene(scene, opts, progress=lambda m: print(m, flush=True), on_level=on_level)
        dirs.append(writer.finish(res))
        Session.writer = None
        print(format_table(res.rows, f"\ntest1 FEM P{p}"))
        print()
        if not res.complete:
            raise RunStopped(f"FEM P{p} stopped before the requested {args.levels} levels: {res.stop_reason}")
        status = status or (0 if res.converged else 3)
    png = plot_compare(dirs, demo.register("convergence.png"), title="test1 [CAMWA21]: FEM P1, P2")
    print(f"outputs: {demo.path}/p1, {demo.path}/p2 (history.csv, newton.csv, summary.json, PNGs, solution.vtu); "
          f"overview {png}")
    return status
