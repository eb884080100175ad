"""Markdown tables of run directories (``ngcontact table``): errors, rates, Newton counts, times, estimators."""
from __future__ import annotations

from pathlib import Path

from .files import read_history, read_summary

__all__ = ["markdown_table", "ESTIMATE_TABLE_COLUMNS"]


def _key_cells(row) -> list:
    """The table cells of a row's keys: T<level>, then the time step and time when present."""
    return [f"T{row['level']}"] + ([str(row["n"]), f"{row['t']:.6g}"] if "n" in row else [])


def markdown_table(run_dirs) -> str:
    """One markdown table per run directory: level (time step, time), ndof, error, rate, Newton its, times."""
    out = []
    for d in map(Path, run_dirs):
        rows = read_history(d / "history.csv")
        s = read_summary(d)
        o = s["options"]
        out.append(f"### {s['scene']}: {o['disc'].upper()} P{o['order']}, Newton-{o['cfun']}, {o['start']} start"
                   + (", equispaced constraints" if o.get("constraints") == "equispaced" else "")
                   + ("" if s["converged"] else "  **(NOT converged: " + "; ".join(s["failures"]) + ")**")
                   + ("" if s["complete"] else f"  **(incomplete: {s['reason']})**"))
        has_err = bool(rows) and "err_energy" in rows[0]
        keys = ["level"] + (["n", "t"] if rows and "n" in rows[0] else [])
        head = keys + ["ndof"] + (["err_energy", "rate"] if has_err else []) + \
            ["Newton its", "solve [s]", "linear [s]", "total [s]"]
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for r in rows:
            cells = _key_cells(r) + [str(r["ndof"])]
            if has_err:
                rate = r.get("rate_energy", float("nan"))
                cells += [f"{r['err_energy']:.3e}", "-" if rate != rate else f"{rate:.2f}"]
            cells += [str(r["newton_its"]), f"{r['time_solve_s']:.2f}", f"{r['time_linear_s']:.2f}",
                      f"{r['time_total_s']:.2f}"]
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
        if rows and "eta" in rows[0]:  # --estimate: the estimator and its parts per level
            cols = [c for c in ESTIMATE_TABLE_COLUMNS if c in rows[0]]
            out.append("| " + " | ".join(keys + cols) + " |")
            out.append("|" + "---|" * (len(keys) + len(cols)))
            for r in rows:
                cells = _key_cells(r) + [_cell(r.get(c)) for c in cols]
                out.append("| " + " | ".join(cells) + " |")
            out.append("")
    return "\n".join(out)


#: estimator columns of :func:`markdown_table` (those present in the run's history)
ESTIMATE_TABLE_COLUMNS = ("err_energy", "eta", "i_eff", "rate_eta", "eta_F", "eta_R", "eta_C", "eta_nonc1",
                          "eta_nonc2", "eta_nonc3", "eta_quad", "eta_bc", "eps_w", "time_solve_s", "time_estimate_s")


def _cell(v) -> str:
    """A markdown cell: "-" for None / NaN, 3 decimals in [0.1, 100), else 4 significant digits."""
    if v is None or (isinstance(v, float) and v != v):
        return "-"
    if isinstance(v, float):
        return f"{v:.3f}" if 0.1 <= abs(v) < 100 else f"{v:.3e}"
    return str(v)
