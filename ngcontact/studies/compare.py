"""Comparison report of discretizations: ``python -m ngcontact.studies.compare OUT RUN_DIR...``.

Reads only the run directories written by ``python -m ngcontact run`` (their
``history.csv`` and ``summary.json``), so it can be re-run without solving
anything.  Writes into ``OUT``:

* ``all.csv``     -- every level of every run, one row each, with the run's
  scene / discretization / order / start / condensation;
* ``<test>.png``  -- energy error vs ndof and vs cumulative run time, one panel
  per polynomial degree, every method (nested start);
* ``newton_cold.png`` -- Newton iterations per level from a cold start;
* ``REPORT.md``   -- tables (finest level per method and degree, cold-start
  Newton counts next to [CAMWA21]) and the "who wins" statements, all
  computed from the runs.

"Time to reach an error": :func:`ngcontact.studies.tables.time_to_reach` on the
cumulative run time (``nan`` when the run never reaches it).
"""
from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path


from ..results import read_history
from .tables import fmt, report_main, time_to_reach

__all__ = ["load_runs", "write_report", "main"]

#: [CAMWA21] Newton-min iterations per level T0..T4 from a cold start (REFERENCE.md, approximate)
PUBLISHED_COLD = {("fem", 1): "4, 7, 11, 20, 38", ("fem", 4): "10, 20, 34, 66, 124",
                  ("hho", 1): "6, 5, 6, 11, 19", ("hho", 4): "7, 11, 19, 30, 53"}
#: [CAMWA21] energy errors T0 -> T4 (REFERENCE.md, approximate)
PUBLISHED_ERR = {("fem", 1): "8e-3 -> 5e-4", ("fem", 2): "3e-3 -> 1.4e-5", ("fem", 3): "9e-4 -> 2.3e-7",
                 ("fem", 4): "1.5e-4 -> 1.8e-7", ("hho", 1): "6e-3 -> 5.5e-4", ("hho", 2): "1e-2 -> 4.5e-5",
                 ("hho", 3): "4e-3 -> 1.4e-6", ("hho", 4): "1.3e-3 -> 2.5e-6"}


def _label(run: dict) -> str:
    o = run["options"]
    name = o["disc"].upper()
    if o["disc"] == "hho":
        name += "" if o.get("condense", True) else " noSC"
    return name


def load_runs(dirs) -> list:
    """[{dir, scene, options, label, rows, converged}] for every directory with a history.csv."""
    runs = []
    for d in map(Path, dirs):
        if not (d / "history.csv").is_file():
            print(f"compare: skipping {d} (no history.csv)", file=sys.stderr)
            continue
        s = json.loads((d / "summary.json").read_text())
        run = {"dir": str(d), "scene": s["scene"], "options": s["options"], "converged": s["converged"],
               "rows": read_history(d / "history.csv")}
        run["label"] = _label(run)
        runs.append(run)
    return runs


def _finest_table(runs, scene) -> list:
    out = ["| p | method | ndof | solved size | err_energy | rate | Newton its (per level) | assembly [s] "
           "| condense [s] | linear [s] | total [s] |", "|" + "---|" * 11]
    sel = sorted((r for r in runs if r["scene"] == scene and r["options"]["start"] == "nested"),
                 key=lambda r: (r["options"]["order"], r["label"]))
    for r in sel:
        f = r["rows"][-1]
        its = ", ".join(str(q["newton_its"]) for q in r["rows"])
        out.append("| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |".format(
            r["options"]["order"], r["label"] + ("" if r["converged"] else " (NOT converged)")
            + ("" if f["level"] == 4 else f" (T{f['level']})"), f["ndof"],
            f.get("linear_size", "-"), fmt(f.get("err_energy")), fmt(f.get("rate_energy"), ".2f"), its,
            fmt(sum(q["time_assembly_s"] for q in r["rows"]), ".2f"),
            fmt(sum(q.get("time_condense_s", 0.0) for q in r["rows"]), ".2f"),
            fmt(sum(q["time_linear_s"] for q in r["rows"]), ".2f"),
            fmt(f["time_cum_s"], ".2f")))
    return out


def _winners(runs, scene) -> list:
    """Statements computed from the data: who is most accurate per dof and fastest to an error."""
    lines = []
    sel = [r for r in runs if r["scene"] == scene and r["options"]["start"] == "nested"]
    for p in sorted({r["options"]["order"] for r in sel}):
        rp = [r for r in sel if r["options"]["order"] == p and r["converged"]]
        if not rp:
            continue
        best_err = min(rp, key=lambda r: r["rows"][-1]["err_energy"])
        f = best_err["rows"][-1]
        # error at equal dofs: compare error * ndof^(p/2) (constant of the asymptotic law) on the finest level
        const = {r["label"]: r["rows"][-1]["err_energy"] * r["rows"][-1]["ndof"] ** (p / 2) for r in rp}
        best_const = min(const, key=const.get)
        targets = [t for t in (1e-3, 1e-4, 1e-5, 1e-6) if any(q["err_energy"] <= t for r in rp for q in r["rows"])]
        line = (f"- **P{p}**: smallest finest-level error {best_err['label']} ({f['err_energy']:.2e} with "
                f"{f['ndof']} dofs); best error x ndof^(p/2) constant {best_const} "
                f"({', '.join(f'{k} {v:.2g}' for k, v in sorted(const.items(), key=lambda kv: kv[1]))})")
        if targets:
            t = targets[-1]
            times = {r["label"]: time_to_reach([q["time_cum_s"] for q in r["rows"]],
                                               [q.get("err_energy", float("nan")) for q in r["rows"]], t)
                     for r in rp}
            ok = {k: v for k, v in times.items() if math.isfinite(v)}
            if ok:
                fastest = min(ok, key=ok.get)
                others = ", ".join(f"{k} {v:.2f} s" for k, v in sorted(ok.items(), key=lambda kv: kv[1])[1:])
                never = [k for k, v in times.items() if not math.isfinite(v)]
                line += (f"; fastest to error {t:.0e}: {fastest} ({ok[fastest]:.2f} s"
                         + (f"; {others}" if others else "") + ")"
                         + (f"; not reached by {', '.join(sorted(never))}" if never else ""))
        lines.append(line + ".")
    return lines


def _cold_table(runs) -> list:
    cold = [r for r in runs if r["options"]["start"] == "cold"]
    if not cold:
        return []
    out = ["| scene | method | p | Newton its T0..T4 (ours) | [CAMWA21] | sum (ours) |", "|" + "---|" * 6]
    for r in sorted(cold, key=lambda r: (r["scene"], r["options"]["disc"], r["options"]["order"])):
        its = [q["newton_its"] for q in r["rows"]]
        pub = PUBLISHED_COLD.get((r["options"]["disc"], r["options"]["order"]), "-") if r["scene"] == "test1" else "-"
        out.append(f"| {r['scene']} | {r['label']} | {r['options']['order']} | {', '.join(map(str, its))} | {pub} "
                   f"| {sum(its)} |")
    # the paper's claim: HHO needs ~2x (test 1) / ~2.5x (test 2) fewer Newton iterations than FEM
    ratios = []
    for scene in sorted({r["scene"] for r in cold}):
        for p in (1, 2, 3, 4):
            f = [r for r in cold if r["scene"] == scene and r["options"]["disc"] == "fem" and r["options"]["order"] == p]
            h = [r for r in cold if r["scene"] == scene and r["options"]["disc"] == "hho" and r["options"]["order"] == p]
            if f and h:
                sf = sum(q["newton_its"] for q in f[0]["rows"])
                sh = sum(q["newton_its"] for q in h[0]["rows"])
                lf, lh = f[0]["rows"][-1]["newton_its"], h[0]["rows"][-1]["newton_its"]
                ratios.append(f"| {scene} | {p} | {sf / sh:.2f} | {lf / lh:.2f} |")
    if ratios:
        out += ["", "Ratio FEM / HHO of cold-start Newton iterations ([CAMWA21] claim: ~2 on test 1, ~2.5 on test 2):",
                "", "| scene | p | all levels | finest level |", "|---|---|---|---|"] + ratios
    return out


def _plots(runs, out: Path) -> list:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    markers = {"FEM": "o-", "HHO": "s-", "HHO noSC": "s:", "SIPG": "^-", "NIPG": "v--", "IIPG": "d--"}
    for scene in sorted({r["scene"] for r in runs}):
        sel = [r for r in runs if r["scene"] == scene and r["options"]["start"] == "nested"]
        orders = sorted({r["options"]["order"] for r in sel})
        if not orders:
            continue
        fig, axs = plt.subplots(2, len(orders), figsize=(4 * len(orders), 7), squeeze=False)
        for j, p in enumerate(orders):
            for r in sorted((r for r in sel if r["options"]["order"] == p), key=lambda r: r["label"]):
                e = [q["err_energy"] for q in r["rows"]]
                axs[0, j].loglog([q["ndof"] for q in r["rows"]], e, markers.get(r["label"], "x-"), ms=4,
                                 label=r["label"])
                axs[1, j].loglog([q["time_cum_s"] for q in r["rows"]], e, markers.get(r["label"], "x-"), ms=4,
                                 label=r["label"])
            axs[0, j].set_title(f"{scene}, p = {p}")
            axs[0, j].set_xlabel("ndof")
            axs[1, j].set_xlabel("cumulative run time [s]")
            for ax in axs[:, j]:
                ax.grid(True, which="both", alpha=0.3)
        axs[0, 0].set_ylabel("energy error")
        axs[1, 0].set_ylabel("energy error")
        axs[0, 0].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / f"{scene}.png", dpi=110)
        plt.close(fig)
        written.append(f"{scene}.png")
    cold = [r for r in runs if r["options"]["start"] == "cold"]
    if cold:
        scenes = sorted({r["scene"] for r in cold})
        fig, axs = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 4), squeeze=False)
        for j, scene in enumerate(scenes):
            for r in sorted((r for r in cold if r["scene"] == scene), key=lambda r: (r["label"], r["options"]["order"])):
                axs[0, j].semilogy([q["level"] for q in r["rows"]], [q["newton_its"] for q in r["rows"]],
                                   markers.get(r["label"], "x-"), label=f"{r['label']} P{r['options']['order']}")
            axs[0, j].set_title(f"{scene}: Newton-min iterations, cold start")
            axs[0, j].set_xlabel("level j (T_j)")
            axs[0, j].grid(True, which="both", alpha=0.3)
            axs[0, j].legend(fontsize=7, ncol=2)
        fig.tight_layout()
        fig.savefig(out / "newton_cold.png", dpi=110)
        plt.close(fig)
        written.append("newton_cold.png")
    return written


def write_report(out_dir, run_dirs) -> Path:
    """Write all.csv, the PNGs and REPORT.md into ``out_dir`` (see module doc)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = load_runs(run_dirs)
    if not runs:
        raise ValueError("no run directories with a history.csv given")
    keys = ["scene", "method", "order", "start"]
    cols = ["level", "ndof", "ndof_sc", "linear_size", "err_energy", "rate_energy", "err_jump", "newton_its",
            "time_assembly_s", "time_condense_s", "time_linear_s", "time_solve_s", "time_total_s", "time_cum_s"]
    tmp = out / ".all.csv.tmp"
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(keys + cols)
        for r in runs:
            for q in r["rows"]:
                w.writerow([r["scene"], r["label"], r["options"]["order"], r["options"]["start"]]
                           + ["" if (v := q.get(c)) is None or (isinstance(v, float) and v != v) else v for c in cols])
    tmp.replace(out / "all.csv")
    _plots(runs, out)
    md = ["# Discretizations compared: FEM, HHO (with / without static condensation), SIPG, NIPG",
          "",
          "Generated by `make compare` (`python -m ngcontact.studies.compare`) from the runs in `results/compare/runs/`"
          " ([CAMWA21] tests 1 and 2, criss-cross meshes T0..T4, Newton-min, tolerance 1e-10 on ||Phi||/||F||)."
          " Times are wall-clock seconds on the machine that ran the study (2 cores, shared), cumulated over"
          " the levels; 'solved size' is the largest linear system of a Newton step (reduced SPD system for FEM,"
          " face unknowns for HHO with SC, reduced full system otherwise). Nested start: every level starts from"
          " the prolongated solution of the previous one.",
          ""]
    for scene in sorted({r["scene"] for r in runs}):
        md += [f"## {scene}", "", f"![{scene}]({scene}.png)", "", "Where each method wins (computed from the runs):", ""]
        md += _winners(runs, scene) + [""]
        md += ["Finest level (T4 unless marked) per method; times summed over the levels run:", ""] + _finest_table(runs, scene) + [""]
    md += ["## Published energy errors [CAMWA21] (test 1, T0 -> T4)", "",
           "| method | p | published | ours (T0 -> T4, nested) |", "|---|---|---|---|"]
    for (disc, p), pub in sorted(PUBLISHED_ERR.items()):
        r = [r for r in runs if r["scene"] == "test1" and r["options"]["disc"] == disc and r["options"]["order"] == p
             and r["options"]["start"] == "nested" and r["options"].get("condense", True)]
        ours = f"{r[0]['rows'][0]['err_energy']:.2e} -> {r[0]['rows'][-1]['err_energy']:.2e}" if r else "-"
        md.append(f"| {disc.upper()} | {p} | {pub} | {ours} |")
    cold = _cold_table(runs)
    if cold:
        md += ["", "## Newton iterations from a cold start", "", "![cold](newton_cold.png)", ""] + cold
    tmp = out / ".REPORT.md.tmp"
    tmp.write_text("\n".join(md) + "\n")
    tmp.replace(out / "REPORT.md")
    return out / "REPORT.md"


def main(argv=None) -> int:
    return report_main("compare", "OUT_DIR RUN_DIR...", write_report, argv)


if __name__ == "__main__":
    sys.exit(main())
