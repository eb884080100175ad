"""Outputs of a two-phase run: per-step CSV, profiles CSV, summary (benchmark quantities at x = 0), plots.

Compute, then plot: :func:`run_files` gives the text files of a finished run, :func:`write_plots` draws
only from what those files hold (the rows and the profiles).  The directory itself (checked, replaced
only if ours, nothing half-written) is the CLI's business.
"""
from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import asdict

import numpy as np

from .params import YEAR
from .run import ITERATE_COLUMNS, STEP_COLUMNS, TwoPhaseRun

__all__ = ["benchmark_quantities", "run_files", "write_plots", "PROFILE_COLUMNS", "DEFAULT_PROFILE_YEARS"]

PROFILE_COLUMNS = ("t_years", "x_m", "S", "P_Pa", "Pg_Pa", "chi")
#: profile times of the CLI [years] (those <= t_final are kept)
DEFAULT_PROFILE_YEARS = (2e4, 5e4, 1e5, 1.5e5, 3e5, 5e5, 5.5e5, 6e5, 6.5e5)


def _json(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def benchmark_quantities(run: TwoPhaseRun) -> dict:
    """The MoMaS comparison quantities at x = 0 (values of the cell at x = 0, centre h/2), from the step rows.

    ``gas_gone_years``: the first step time after the last step with gas at x = 0 (None if gas remains).
    """
    rows = run.rows
    t = np.array([r.t_years for r in rows])
    s0 = np.array([r.S_0 for r in rows])
    p0 = np.array([r.P_0_Pa for r in rows])
    pg0 = np.array([r.Pg_0_Pa for r in rows])
    gas = np.flatnonzero(s0 < 1.0)
    out = dict(gas_appears_years=float(t[gas[0]]) if len(gas) else None,
               P_peak_Pa=float(p0.max()), P_peak_years=float(t[p0.argmax()]),
               Pg_peak_Pa=float(pg0.max()), Pg_peak_years=float(t[pg0.argmax()]))
    out["gas_gone_years"] = (float(t[gas[-1] + 1]) if len(gas) and gas[-1] + 1 < len(t) else None)
    t_inj = run.prm.t_inject
    at = np.flatnonzero(np.isclose(t, t_inj))
    out["Sg_at_injection_end"] = float(1.0 - s0[at[0]]) if len(at) else None
    late = np.flatnonzero(t > t_inj)
    out["P_min_after_injection_Pa"] = float(p0[late].min()) if len(late) else None
    out["P_min_after_injection_years"] = float(t[late[p0[late].argmin()]]) if len(late) else None
    out["newton_total"], out["gmres_total"] = run.newton_total, run.gmres_total
    out["dt_cuts"] = int(sum(r.dt_cuts for r in rows))
    out["max_water_defect_rel"] = float(max(r.water_defect_rel for r in rows))
    out["max_h2_defect_rel"] = float(max(r.h2_defect_rel for r in rows))
    for c in ("water", "h2"):
        vals = [getattr(r, f"{c}_defect_flux") for r in rows if np.isfinite(getattr(r, f"{c}_defect_flux"))]
        out[f"max_{c}_defect_flux"] = float(max(vals)) if vals else float("nan")
    out["min_S_minus_Slr"] = float(min(r.min_S_minus_Slr for r in rows))
    out["max_S_minus_1"] = float(max(r.max_S_minus_1 for r in rows))
    out["min_chi"] = float(min(r.min_chi for r in rows))
    return out


def _csv(header, rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        w.writerow([f"{v:.10g}" if isinstance(v, float) else v for v in r])
    return buf.getvalue()


def profile_rows(run: TwoPhaseRun):
    d = run.disc
    xc = d.mesh.centre[:, 0]
    for ty in sorted(run.profiles):
        s, p, chi = d.split(run.profiles[ty])
        pg = p + d.laws.pc(s)[0]
        for k in range(len(xc)):
            yield (ty, float(xc[k]), float(s[k]), float(p[k]), float(pg[k]), float(chi[k]))


def run_files(run: TwoPhaseRun, options: dict, case: str = "h2_storage") -> dict:
    """{file name: text} of a finished run: steps.csv, profiles.csv, summary.json, and iterates.csv when the
    run logged its Newton iterates (adaptive mode)."""
    summary = dict(case=case, completed=run.completed, options=options,
                   parameters=asdict(run.prm), seconds_per_year=YEAR, steps=len(run.rows),
                   benchmark_x0=benchmark_quantities(run) if run.rows else {}, log=run.log,
                   time_s=sum(r.time_s for r in run.rows))
    text = json.dumps(summary, indent=1, default=_json)
    files = {"steps.csv": _csv(STEP_COLUMNS, (r.values() for r in run.rows)),
             "profiles.csv": _csv(PROFILE_COLUMNS, profile_rows(run)),
             "summary.json": text.replace("NaN", "null") + "\n"}
    if run.iterates:
        files["iterates.csv"] = _csv(ITERATE_COLUMNS, ([r[c] for c in ITERATE_COLUMNS] for r in run.iterates))
    return files


def write_plots(files: dict, path_of) -> list:
    """Draw the run from its files ({name: text} of :func:`run_files`); ``path_of(name)`` gives where each
    PNG goes.  Returns the names written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = list(csv.DictReader(io.StringIO(files["steps.csv"])))
    col = {k: np.array([float(r[k]) if r[k] not in ("", "nan") else np.nan for r in steps]) for k in STEP_COLUMNS}
    prof = list(csv.DictReader(io.StringIO(files["profiles.csv"])))
    written = []

    def save(fig, name):
        fig.tight_layout()
        fig.savefig(path_of(name), dpi=110)
        plt.close(fig)
        written.append(name)

    t = col["t_years"]
    fig, ax = plt.subplots(figsize=(6.4, 4))
    ax.plot(t, col["P_0_Pa"] / 1e6, label="P (liquid)")
    ax.plot(t, col["Pg_0_Pa"] / 1e6, label="P_g = P + P_c")
    ax.set(xlabel="t [years]", ylabel="pressure at x = 0 [MPa]", title="pressures at x = 0")
    ax.legend()
    save(fig, "pressure_x0.png")

    fig, ax = plt.subplots(figsize=(6.4, 4))
    ax.plot(t, col["gas_end_m"])
    ax.set(xlabel="t [years]", ylabel="end of the gas zone [m]", title="gas front")
    save(fig, "gas_front.png")

    fig, ax = plt.subplots(figsize=(6.4, 4))
    ax.plot(t, col["newton_its"], ".-", label="Newton")
    if np.nansum(col["gmres_its"]) > 0:
        ax.plot(t, col["gmres_its"], ".-", label="GMRES")
    ax.set(xlabel="t [years]", ylabel="iterations per time step", yscale="log", title="solver iterations")
    ax.legend()
    save(fig, "iterations.png")

    if np.isfinite(col["eta_sp_h"]).any():
        fig, axs = plt.subplots(1, 2, figsize=(10, 4))
        for ax, c, name in zip(axs, "wh", ("water", "hydrogen")):
            for e in ("sp", "tm", "lin", "alg"):
                v = col[f"eta_{e}_{c}"]
                if np.isfinite(v).any():
                    ax.semilogy(t, v, label=f"eta_{e}")
            ax.set(xlabel="t [years]", title=f"estimators, {name}")
            ax.legend()
        save(fig, "estimators.png")

    if prof:
        times = sorted({float(r["t_years"]) for r in prof})
        fig, axs = plt.subplots(2, 2, figsize=(10, 7))
        for ty in times:
            sel = [r for r in prof if float(r["t_years"]) == ty]
            x = np.array([float(r["x_m"]) for r in sel])
            for ax, key, scale in zip(axs.ravel(), ("S", "P_Pa", "Pg_Pa", "chi"), (1, 1e-6, 1e-6, 1)):
                ax.plot(x, np.array([float(r[key]) for r in sel]) * scale, label=f"{ty:g} y")
        for ax, lab in zip(axs.ravel(), ("S (liquid saturation)", "P [MPa]", "P_g [MPa]", "chi (dissolved H2)")):
            ax.set(xlabel="x [m]", ylabel=lab)
        axs[0, 0].legend(fontsize=7)
        save(fig, "profiles.png")
    return written
