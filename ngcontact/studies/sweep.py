"""Sweep definition and report: uniform vs adaptive refinement, error and estimator against ndof and run time.

``make sweep`` runs every entry of :data:`SWEEP` as an independent make target
(``python -m ngcontact.studies.sweep run NAME`` -> ``results/sweep/runs/NAME``, a normal
run directory written by the CLI), so ``make -j2 sweep`` runs two at a time;
``make report`` (``python -m ngcontact.studies.sweep report``) only reads their
``history.csv`` / ``summary.json`` and writes ``results/REPORT.md`` and the
PNGs under ``results/report/``.

Run names are ``SCENE-MODE-pP``, MODE = ``uniform`` (T_0..T_{L-1}) or
``adaptive`` (Doerfler theta = 0.5, estimator-driven bisection, warm-started
Newton); both with ``--decouple`` (:data:`SWEEP_FLAGS`).

Timing conventions (stated in the report):

* adaptive runs: ``time_cum_s`` -- every phase of every level, estimation,
  marking and refinement included (the estimator is needed to adapt);
* uniform runs: ``time_cum_s`` minus the cumulated ``time_estimate_s`` when the
  run computed estimators for the plots (uniform refinement does not need them).

Time to reach an energy error: :func:`ngcontact.studies.tables.time_to_reach`
("not reached": the finest level of the run is still above it).  Slopes:
:func:`ngcontact.rates.fitted_rate` against ndof over the last :data:`SLOPE_LEVELS` levels.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from ..rates import fitted_rate
from ..results import read_history
from .tables import fmt, md_row, time_to_reach

__all__ = ["SWEEP", "sweep_names", "sweep_argv", "write_report"]

#: per scene: uniform levels per degree, whether uniform runs compute eta, adaptive DOF and time budgets.  Every
#: scene is two membranes with mu1 = mu2: uniform and adaptive runs take --decouple (Newton on w = u1 - u2, the
#: coupled discrete solution at half the Newton system size; newton/decoupled.py)
SWEEP = {
    "lshape": dict(levels={1: 5, 2: 4, 3: 3}, estimate_uniform=True, max_ndof=200000, max_time=400),
    "test1": dict(levels={1: 8, 2: 5, 3: 4}, estimate_uniform=False, max_ndof=20000, max_time=120),
    "disk": dict(levels={1: 5, 2: 4, 3: 4}, estimate_uniform=False, max_ndof=20000, max_time=120),
    "disk_fitted": dict(levels={1: 5, 2: 4, 3: 4}, estimate_uniform=False, max_ndof=20000, max_time=120),
    "point_load": dict(levels={1: 4, 2: 3, 3: 3}, estimate_uniform=True, max_ndof=15000, max_time=100),
}
SWEEP_FLAGS = ("--decouple",)  # every entry (see SWEEP)
ORDERS = (1, 2, 3)
SWEEP_THREADS = 1  # NGSolve threads per sweep run (see main)
MODES = ("uniform", "adaptive")
TARGETS = (1e-3, 1e-4, 1e-5)
SLOPE_LEVELS = 4  # levels of the fitted slopes


def sweep_names() -> list:
    return [f"{s}-{m}-p{p}" for s in SWEEP for m in MODES for p in ORDERS]


def sweep_argv(name: str) -> list:
    """Command-line arguments of ``python -m ngcontact run`` for a sweep entry."""
    try:
        scene, mode, pp = name.split("-")
        p = int(pp[1:])
        cfg = SWEEP[scene]
        assert mode in MODES and p in ORDERS and pp[0] == "p"
    except Exception:
        raise ValueError(f"unknown sweep entry {name!r} (known: {', '.join(sweep_names())})") from None
    argv = [scene, "--order", str(p), "--no-vtk", *SWEEP_FLAGS]
    if mode == "uniform":
        argv += ["--levels", str(cfg["levels"][p])] + (["--estimate"] if cfg["estimate_uniform"] else [])
    else:
        argv += ["--adaptive", "--theta", "0.5", "--max-ndof", str(cfg["max_ndof"]),
                 "--max-time", str(cfg["max_time"])]
    return argv


# ---------------------------------------------------------------- analysis helpers
def _load(run_dir: Path):
    rows = read_history(run_dir / "history.csv")
    summary = json.loads((run_dir / "summary.json").read_text())
    return rows, summary


def _times(rows, adaptive: bool) -> np.ndarray:
    t = np.array([r["time_cum_s"] for r in rows], float)
    if not adaptive:
        est = np.array([r.get("time_estimate_s", 0.0) for r in rows], float)
        t = t - np.cumsum(np.nan_to_num(est))
    return t


def _col(rows, c):
    return np.array([r.get(c, float("nan")) for r in rows], float)


# ---------------------------------------------------------------- report
def _save(fig, png: Path) -> Path:
    """Lay out, tidy the log axes, write ``png`` and close the figure."""
    import matplotlib.pyplot as plt

    from ..plotting import tidy_log_axes

    fig.tight_layout()
    tidy_log_axes(fig)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png


def _cycle_cost(runs, scene, present, last: int = 3) -> list:
    """Markdown lines: solve and estimation time of the last ``last`` levels of every adaptive run of ``scene``
    (an adaptive cycle needs both; the ratio estimate / solve is the cost of adaptivity)."""
    out = []
    for m, p in present:
        rows = runs[f"{scene}-{m}-p{p}"][0] if m == "adaptive" else []
        for r in rows[-last:]:
            if not out:
                out = [f"Adaptive cycle cost on the last {last} levels (solve: the Newton solve; estimate: flux "
                       "reconstruction and bound):", "", "| adaptive | ndof | solve [s] | estimate [s] | estimate / solve |",
                       "|---|---|---|---|---|"]
            ts, te = r.get("time_solve_s"), r.get("time_estimate_s")
            ratio = te / ts if ts and te is not None else None
            out.append(md_row([f"P{p}", int(r["ndof"]), fmt(ts, ".2f"), fmt(te, ".2f"), fmt(ratio, ".2f")]))
    return out + [""] if out else []


def write_report(runs_dir, out_md, fig_dir) -> Path:
    """Read the sweep's run directories, write the plots and the markdown report."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..plotting import slope_label

    runs_dir, out_md, fig_dir = Path(runs_dir), Path(out_md), Path(fig_dir)
    fig_dir.mkdir(parents=True, exist_ok=True)
    runs = {}
    for name in sweep_names():
        d = runs_dir / name
        if (d / "history.csv").is_file() and (d / "summary.json").is_file():
            runs[name] = _load(d)
    missing = [n for n in sweep_names() if n not in runs]
    rel = lambda p: Path(p).relative_to(out_md.parent).as_posix()  # noqa: E731
    md = ["# Adaptive vs uniform refinement: error and estimator against ndof and run time", "",
          "Generated by `make report` from the run directories of `make sweep` (`results/sweep/runs/`); "
          "sweep definition and conventions: `ngcontact/studies/sweep.py`.", "",
          "* adaptive: Doerfler marking (theta = 0.5) on the estimator's eta_K, newest-vertex bisection, "
          "Newton-min warm-started from the previous level's (u1, u2, lam) prolongated to the new mesh; "
          "its cumulative time includes every phase (mesh, assembly, Newton, errors, estimation, marking, "
          "refinement);",
          "* uniform: T_0..T_{L-1}, nested start; the time of the estimators (computed for the plots on "
          "some scenes) is subtracted, since uniform refinement does not need them;",
          f"* both: {' '.join(f'`{f}`' for f in SWEEP_FLAGS)} (every scene is two membranes with mu1 = mu2: "
          "Newton on w = u1 - u2, the coupled discrete solution);",
          f"* rates: least-squares slope of log(quantity) against log(ndof) over the last {SLOPE_LEVELS} levels "
          "(optimal P_p: -p/2);",
          "* time to reach an error: log-log interpolation between the two levels bracketing it; "
          "'--' = not reached by the run's finest level (no extrapolation);",
          f"* every run uses {SWEEP_THREADS} NGSolve thread(s), so that times are comparable whether the sweep "
          "ran sequentially or with `make -j2 sweep`.", ""]
    if missing:
        md += [f"**Missing runs** (not in {runs_dir}): {', '.join(missing)}", ""]
    colors = {1: "C0", 2: "C1", 3: "C2"}
    rate_rows, tta_rows, ieff_rows = [], [], []
    for scene in SWEEP:
        present = [(m, p) for m in MODES for p in ORDERS if f"{scene}-{m}-p{p}" in runs]
        if not present:
            continue
        desc = runs[f"{scene}-{present[0][0]}-p{present[0][1]}"][1].get("description", "")
        has_err = any("err_energy" in runs[f"{scene}-{m}-p{p}"][0][0] for m, p in present)
        md += [f"## {scene}", "", desc, ""]
        fig, axs = plt.subplots(1, 2, figsize=(12, 4.8))
        for m, p in present:
            rows, _ = runs[f"{scene}-{m}-p{p}"]
            n, t = _col(rows, "ndof"), _times(rows, m == "adaptive")
            style = dict(color=colors[p], marker="o" if m == "adaptive" else "s",
                         mfc=colors[p] if m == "adaptive" else "none", ms=4)
            for c, ls, lab in (("err_energy", "-", "error"), ("eta", "--", r"$\eta$")):
                v = _col(rows, c)
                if np.isfinite(v).any():
                    axs[0].loglog(n, v, ls=ls, label=f"{m} P{p} {lab}", **style)
                    axs[1].loglog(t, v, ls=ls, label=f"{m} P{p} {lab}", **style)
            if m == "adaptive":  # optimal slope through the adaptive run's last point
                ref = _col(rows, "eta")
                axs[0].loglog(n, ref[-1] * (n / n[-1]) ** (-p / 2), ":", color=colors[p], lw=1.2,
                              label=slope_label(p))
        axs[0].set_xlabel("ndof")
        axs[1].set_xlabel("cumulative run time [s]")
        for ax in axs:
            ax.set_ylabel("energy error / estimator")
            ax.grid(True, which="both", alpha=0.3)
        axs[0].legend(fontsize=6.5, ncol=2)
        fig.suptitle(f"{scene}: uniform (squares) vs adaptive (dots); error solid, estimator dashed")
        png = _save(fig, fig_dir / f"{scene}_convergence.png")
        md += [f"![{scene}: error and estimator vs ndof and time]({rel(png)})", ""]

        # rates and final values
        md += ["| method | levels | final ndof | final error | final eta | slope error | slope eta | optimal | "
               "total time [s] | stop |", "|---|---|---|---|---|---|---|---|---|---|"]
        for m, p in present:
            rows, summ = runs[f"{scene}-{m}-p{p}"]
            n, err, eta = _col(rows, "ndof"), _col(rows, "err_energy"), _col(rows, "eta")
            se = fitted_rate(n, err, SLOPE_LEVELS) if np.isfinite(err).all() and len(n) >= 3 else float("nan")
            sh = fitted_rate(n, eta, SLOPE_LEVELS) if np.isfinite(eta).all() and len(n) >= 3 else float("nan")
            stop = summ.get("stop_reason", "uniform levels").split(":")[0]
            ok = "" if summ.get("converged", True) else " (Newton NOT converged)"
            md.append(md_row([f"{m} P{p}{ok}", len(rows), int(n[-1]), fmt(err[-1], ".3e", "--"),
                              fmt(eta[-1], ".3e", "--"), fmt(se, ".2f", "--"), fmt(sh, ".2f", "--"), f"{-p / 2:.2f}",
                              fmt(_times(rows, m == "adaptive")[-1], ".1f", "--"), stop]))
            rate_rows.append((scene, m, p, se, sh))
        md.append("")

        if has_err:
            # time to accuracy
            md += ["Time [s] to reach the energy error (log-log interpolation between levels):", "",
                   "| method | " + " | ".join(f"{e:.0e}" for e in TARGETS) + " |",
                   "|---|" + "---|" * len(TARGETS)]
            for m, p in present:
                rows, _ = runs[f"{scene}-{m}-p{p}"]
                err = _col(rows, "err_energy")
                tt = [time_to_reach(_times(rows, m == "adaptive"), err, e) for e in TARGETS]
                tta_rows.append((scene, m, p, tt))
                md.append(md_row([f"{m} P{p}"] + [fmt(v, ".2f", "--") for v in tt]))
            md.append("")
            # effectivity per level
            fig, ax = plt.subplots(figsize=(6, 4))
            for m, p in present:
                rows, _ = runs[f"{scene}-{m}-p{p}"]
                ie = _col(rows, "i_eff")
                if np.isfinite(ie).any():
                    ax.semilogx(_col(rows, "ndof"), ie, ("o-" if m == "adaptive" else "s--"), color=colors[p],
                                mfc=colors[p] if m == "adaptive" else "none", ms=4, label=f"{m} P{p}")
                    if m == "adaptive":
                        ieff_rows.append((scene, p, ie))
            ax.axhline(1.0, color="k", lw=0.8)
            ax.axhline(1.3, color="k", lw=0.8, ls=":")
            ax.set_xlabel("ndof")
            ax.set_ylabel(r"$I_{eff} = \eta$ / energy error")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
            ax.set_title(f"{scene}: effectivity per level")
            png = _save(fig, fig_dir / f"{scene}_ieff.png")
            if any(s == scene for s, _, _ in ieff_rows):
                md += [f"![{scene}: effectivity]({rel(png)})", ""]
                md += ["| adaptive | I_eff per level |", "|---|---|"]
                for s, p, ie in ieff_rows:
                    if s == scene:
                        md.append(f"| P{p} | " + " ".join(f"{v:.2f}" for v in ie) + " |")
                md.append("")
        md += _cycle_cost(runs, scene, present)
        # last adapted meshes
        pics = []
        for p in ORDERS:
            src = runs_dir / f"{scene}-adaptive-p{p}" / "mesh.png"
            if src.is_file():
                dst = fig_dir / f"{scene}_adaptive_p{p}_mesh.png"
                shutil.copyfile(src, dst)
                pics.append(f"![{scene} P{p} last adapted mesh]({rel(dst)})")
        if pics:
            md += ["Last adapted meshes (red: discrete contact nodes):", "", " ".join(pics), ""]

    # headline checks
    md += ["## Acceptance checks (measured in this run)", ""]
    for scene, m, p, se, sh in rate_rows:
        if scene == "lshape":
            verdict = "within 0.15" if np.isfinite(sh) and abs(sh + p / 2) <= 0.15 else "NOT within 0.15"
            md.append(f"* lshape {m} P{p}: estimator slope {sh:.2f} vs optimal {-p / 2:.2f} -> {verdict}"
                      f" (error slope {se:.2f})")
    md.append("")
    for scene in ("test1", "disk", "disk_fitted"):
        base = [tt for s, m, p, tt in tta_rows if s == scene and m == "uniform" and p == 1]
        best = [(tt[1], p) for s, m, p, tt in tta_rows if s == scene and m == "adaptive" and p >= 2
                and np.isfinite(tt[1])]
        if base and best:
            tb, (ta, pa) = base[0][1], min(best)
            if np.isfinite(tb):
                md.append(f"* {scene}, energy error 1e-4: uniform P1 {tb:.2f} s, best adaptive high order "
                          f"(P{pa}) {ta:.2f} s -> speed-up {tb / ta:.1f}x "
                          f"({'>=' if tb / ta >= 10 else '<'} 10x)")
            else:
                md.append(f"* {scene}, energy error 1e-4: uniform P1 did not reach it within the sweep; "
                          f"best adaptive high order (P{pa}) {ta:.2f} s")
    md.append("")
    for scene, p, ie in ieff_rows:
        ie = ie[np.isfinite(ie)]
        inside = np.mean((ie >= 1) & (ie <= 1.3)) * 100 if ie.size else float("nan")
        md.append(f"* I_eff {scene} adaptive P{p}: min {ie.min():.3f}, max {ie.max():.3f}; "
                  f"{inside:.0f}% of the levels in [1, 1.3]")
    md.append("")
    out_md.parent.mkdir(parents=True, exist_ok=True)
    out_md.write_text("\n".join(md) + "\n")
    return out_md


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["names"]:
        print(" ".join(sweep_names()))
        return 0
    if argv[:1] == ["run"] and len(argv) == 3:  # run NAME OUTDIR
        from ..cli import main as cli_main

        # one NGSolve thread per sweep run (run_scene reads NGCONTACT_THREADS; drivers/resources.py),
        # so that every run is timed alike whether the sweep runs sequentially or as `make -j2 sweep`
        os.environ.setdefault("NGCONTACT_THREADS", str(SWEEP_THREADS))
        return cli_main(["run", *sweep_argv(argv[1]), "-q", "--out", argv[2]])
    if argv[:1] == ["report"] and len(argv) == 4:  # report RUNS_DIR OUT_MD FIG_DIR
        print(write_report(*argv[1:]))
        return 0
    print("usage: python -m ngcontact.studies.sweep names | run NAME OUTDIR | report RUNS_DIR OUT_MD FIG_DIR",
          file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
