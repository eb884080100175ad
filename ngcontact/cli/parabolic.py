"""``ngcontact run`` of a time-dependent scene (a ParabolicProblem): backward Euler steps, a run directory."""
from __future__ import annotations

import re
import time

from .parser import UsageError

__all__ = ["cmd_run_parabolic"]

#: flags of stationary runs that a time-dependent run does not use
_STATIONARY_ONLY = ("levels", "disc", "start", "solver", "no_condense", "flux_order", "decouple", "newton_stop",
                    "gamma_balance", "ilu_drop_tol", "ilu_fill", "adaptive", "marking", "theta", "max_ndof",
                    "target_eta", "max_time", "max_levels", "vtk_series", "no_vtk")


def _flag(name: str) -> str:
    return "--" + {"ilu_drop_tol": "ilu-drop"}.get(name, name.replace("_", "-"))


def cmd_run_parabolic(scene, args, argv) -> int:
    from ..timestepping.run import run_parabolic_scene, write_parabolic_run

    unused = [_flag(n) for n in _STATIONARY_ONLY if getattr(args, n, None) not in (None, False)]
    if unused:
        raise UsageError(f"option(s) {', '.join(unused)} do not apply to the time-dependent scene {scene.name}")
    if (args.dt_rule is not None or args.safety is not None) and not args.adaptive_dt:
        raise UsageError("option(s) --dt-rule/--dt-safety need --adaptive-dt")
    given = dict(order=args.order, dt=args.dt, t_final=args.t_final, newton=args.newton, cfun=args.cfun, tol=args.tol,
                 maxit=args.maxit, estimate=True if args.estimate else None, gamma_alg=args.gamma_alg,
                 gamma_lin=args.gamma_lin, nu=args.nu, adaptive_dt=True if args.adaptive_dt else None,
                 level=args.level, maxh=args.maxh, krylov=args.krylov, dt_rule=args.dt_rule, safety=args.safety)
    if args.test:
        if not scene.test_options:
            raise UsageError(f"option --test needs TEST_OPTIONS in the scene file ({scene.name} has none)")
        given = {**scene.test_options, **{k: v for k, v in given.items() if v is not None}}
    if args.vtk_every is not None and args.vtk_every < 1:
        raise UsageError(f"option --vtk-every must be a positive integer, got {args.vtk_every}")
    say = (lambda m: None) if args.quiet else (lambda m: print(m, flush=True))
    from ..timestepping.run import parabolic_options

    try:
        options, mesh_opts = parabolic_options(scene, given)
    except ValueError as exc:
        raise UsageError(re.sub(r"\boption (\w+)", lambda m: "option " + _flag(m.group(1)), str(exc))) from None
    out = args.out if args.out is not None else f"results/runs/{scene.name}-p{options.order}-{options.newton}"
    from ..results.directory import check_output_dir

    check_output_dir(out, "--out", "run")  # before the run: a bad --out fails at once
    say(f"ngcontact: scene {scene.name} ({scene.description.rstrip('.')}) | P{options.order}, dt={options.dt:g}"
        f"{' (adaptive)' if options.adaptive_dt else ''}, Newton-{options.cfun} {options.newton}")
    t0 = time.perf_counter()
    res, options, mesh_opts = run_parabolic_scene(scene, {k: v for k, v in given.items() if v is not None},
                                                  progress=say if args.verbose or not args.quiet else None,
                                                  snapshot_every=args.vtk_every or 0)
    path = write_parabolic_run(out, scene, res, options, mesh_opts, argv=["ngcontact", *argv],
                               plots=not args.no_plots, vtk_every=args.vtk_every or 0)
    s = res.summary
    print(f"{scene.name}: {s['steps']} steps to t = {s['t_final']:.4g} on {s['nelem']} triangles "
          f"({time.perf_counter() - t0:.1f} s): Newton {s['newton_total']}, GMRES {s['gmres_total']}, "
          f"factorizations {s['factorizations_total']}"
          + "".join(f", {k} {v:.4g}" for k, v in s.items() if k.startswith("onset_"))
          + (f", eta_st {s['eta_st']:.4e}" if "eta_st" in s else "")
          + (f", error {s['err_spacetime']:.4e}" if "err_spacetime" in s else ""))
    print(f"outputs: {path}/ (steps.csv, contact_spacetime.csv, summary.json"
          + ("" if args.no_plots else ", *.png") + (", solution.pvd" if args.vtk_every else "") + ")")
    if not res.converged:
        for f in res.failures:
            print(f"ngcontact: warning: {f}")
        return 3
    return 0
