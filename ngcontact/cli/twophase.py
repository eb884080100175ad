"""``ngcontact run`` of a two-phase scene (``problem = TwoPhaseParams(...)``): options -> time loop -> run directory.

The run is computed first and written only when it finished: a run that gives up (repeated Newton
failure after the dt cuts) or is interrupted leaves no directory behind.
"""
from __future__ import annotations

import re
import sys
import tempfile
import time
from pathlib import Path

from .parser import UsageError

__all__ = ["cmd_run_twophase", "check_membrane_flags", "TWOPHASE_FLAGS"]

#: the two-phase flags (args attribute -> flag)
TWOPHASE_FLAGS = {"cells": "--cells", "dt_years": "--dt-years", "t_final_years": "--t-final-years"}
#: membrane flags a two-phase run would ignore
_MEMBRANE_ONLY = {"order": "--order", "levels": "--levels", "disc": "--disc", "start": "--start", "solver": "--solver",
                  "no_condense": "--no-condense", "estimate": "--estimate", "flux_order": "--flux-order",
                  "decouple": "--decouple", "newton_stop": "--newton-stop", "gamma_balance": "--gamma-balance",
                  "nu": "--nu", "ilu_drop_tol": "--ilu-drop", "ilu_fill": "--ilu-fill", "adaptive": "--adaptive",
                  "marking": "--marking", "theta": "--theta", "max_ndof": "--max-ndof", "target_eta": "--target-eta",
                  "max_time": "--max-time", "max_levels": "--max-levels", "vtk_series": "--vtk-series",
                  "dt_rule": "--dt-rule", "safety": "--dt-safety"}


def _given(args, names) -> list:
    return [flag for name, flag in names.items() if getattr(args, name, None) not in (None, False)]


def check_membrane_flags(args) -> None:
    """The two-phase flags given for a membrane scene: a usage error."""
    used = _given(args, TWOPHASE_FLAGS)
    if used:
        raise UsageError(f"option(s) {', '.join(used)} need a two-phase scene (e.g. h2_storage)")


def _options(scene, args) -> dict:
    used = _given(args, _MEMBRANE_ONLY)
    if used:
        raise UsageError(f"option(s) {', '.join(used)} do not apply to the two-phase scene {scene.name}")
    newton = args.newton or "direct"
    if newton != "adaptive" and (args.gamma_alg is not None or args.gamma_lin is not None):
        raise UsageError(f"option(s) --gamma-alg/--gamma-lin need --newton adaptive (got --newton {newton})")
    opts = dict(cells=1000, dt_years=5000.0, t_final_years=1e6)
    opts.update(scene.defaults)
    if args.test:
        if not scene.test_options:
            raise UsageError(f"option --test needs TEST_OPTIONS in the scene file ({scene.name} has none)")
        opts.update(scene.test_options)
    given = dict(cells=args.cells, dt_years=args.dt_years, t_final_years=args.t_final_years, tol=args.tol,
                 maxit=args.maxit, gamma_alg=args.gamma_alg, gamma_lin=args.gamma_lin)
    opts.update({k: v for k, v in given.items() if v is not None})
    opts.update(newton=newton, cfun=args.cfun or "min")
    return opts


def _flag_words(exc: Exception) -> str:
    """An option error in the words of the command line (``option dt_years`` -> ``option --dt-years``)."""
    return re.sub(r"\boption (\w+)", lambda m: "option --" + m.group(1).replace("_", "-"), str(exc))


def cmd_run_twophase(scene, args, argv) -> int:
    from ..results import OutputDir
    from ..twophase import run_h2
    from ..twophase.run import check_options
    from ..twophase.outputs import DEFAULT_PROFILE_YEARS, benchmark_quantities, run_files, write_plots

    opts = _options(scene, args)
    try:
        check_options(**opts)
    except ValueError as exc:
        raise UsageError(_flag_words(exc)) from None
    out = args.out if args.out is not None else f"results/runs/{scene.name}-{opts['newton']}-{opts['cfun']}"
    directory = OutputDir(out, "run", "--out")  # checked before solving
    say = (lambda m: None) if args.quiet else (lambda m: print(m, flush=True))
    say(f"ngcontact: scene {scene.name} ({scene.description.rstrip('.')}) | {opts['cells']} cells, dt = "
        f"{opts['dt_years']:g} years to {opts['t_final_years']:g} years | Newton-{opts['cfun']}, {opts['newton']} solves")
    profile = [t for t in DEFAULT_PROFILE_YEARS if t <= opts["t_final_years"]] + [opts["t_final_years"]]
    t0 = time.perf_counter()
    try:
        run = run_h2(scene.problem, progress=say if (args.verbose or not args.quiet) else None,
                     profile_years=profile, **opts)
    except ValueError as exc:
        raise UsageError(_flag_words(exc)) from None
    if not run.completed:
        for line in run.log[-3:]:
            print(f"ngcontact: {line}", file=sys.stderr)
        print(f"ngcontact: the run stopped at t = {run.rows[-1].t_years if run.rows else 0:g} years; nothing written",
              file=sys.stderr)
        return 3
    missing = [tp for tp in profile if float(tp) not in run.profiles]
    if missing:  # the profiles are the states at step ends
        print(f"ngcontact: note: no profile at t = {', '.join(f'{tp:g}' for tp in missing)} years: no step ends there "
              f"with dt = {opts['dt_years']:g} years", file=sys.stderr)
    files = run_files(run, dict(opts, argv=["ngcontact", *argv]), case=scene.name)
    with tempfile.TemporaryDirectory() as td:  # plots drawn before anything is written
        pngs = {} if args.no_plots else {n: (Path(td) / n).read_bytes()
                                         for n in write_plots(files, lambda n: Path(td) / n)}
    for name, data in {**files, **pngs}.items():
        directory.write(name, data)
    q = benchmark_quantities(run)
    print(f"\n{scene.name}: {len(run.rows)} steps, Newton {q['newton_total']}, GMRES {q['gmres_total']}, "
          f"dt cuts {q['dt_cuts']} ({time.perf_counter() - t0:.1f} s)")
    print(f"  at x = 0: gas appears {q['gas_appears_years']} y; P peak {q['P_peak_Pa'] / 1e6:.4f} MPa at "
          f"{q['P_peak_years']:g} y; Pg peak {q['Pg_peak_Pa'] / 1e6:.4f} MPa at {q['Pg_peak_years']:g} y; "
          f"gas gone {q['gas_gone_years']} y")
    print(f"  max mass-balance defects per step: water {q['max_water_defect_rel']:.1e}, H2 "
          f"{q['max_h2_defect_rel']:.1e} (relative to the mass in the domain); "
          f"water {q['max_water_defect_flux']:.1e}, H2 "
          f"{q['max_h2_defect_flux']:.1e} (relative to the mass through the boundary in the step)")
    listed = ", ".join(n for n in files if n.endswith((".csv", ".json"))) + ("" if args.no_plots else ", *.png")
    print(f"outputs: {directory.path}/ ({listed})")
    return 0
