"""The files of a run directory: columns, CSV and JSON values, reading them back, atomic writes."""
from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path

import numpy as np

__all__ = ["KEY_COLUMNS", "HISTORY_COLUMNS", "csv_text", "json_value", "read_history", "read_summary",
           "atomic_write", "TMP_MARK"]

#: the columns that identify a row: mesh level, time step index, time (the last two only in time-dependent runs)
KEY_COLUMNS = ("level", "n", "t")

HISTORY_COLUMNS = [
    *KEY_COLUMNS, "nelem", "h", "ndof", "ndof_sc", "nodes", "marked", "multiplier", "multiplier_candidates",
    "err_energy", "rate_energy", "err_max_nodal",
    "err_jump", "newton_its", "newton_converged", "res_final", "certified", "cert_penetration", "cert_negativity",
    "cert_slackness", "cert_equilibrium", "cert_tol", "newton_remedies", "newton_balanced",
    "eps_lin_final", "eps_disc_final", "active_nodes", "linear_size",
    "cg_its", "mg_levels", "mg_algebraic", "mg_builds", "mg_updates", "time_mg_setup_s",
    "gmres_its", "gmres_max_step", "gmres_first_step", "n_estimates", "time_estimate_newton_s",
    "eta_disc_final", "eta_lin_final", "eta_alg_final", "gap_min", "lam_min",
    "product_max", "time_mesh_s", "time_mark_s", "time_assembly_s", "time_prolong_s", "time_solve_s", "time_linear_s",
    "time_condense_s", "time_post_s",
    "eta", "rate_eta", "i_eff", "eta_seed", "eta_direct", "theta_contact", "eta_F", "eta_R", "eta_FR", "eta_C", "eta_nonc1",
    "eta_nonc2", "eta_nonc3", "eta_quad", "eta_bc", "eps_w", "eta_trace", "bound_proven", "eta_nonc2_seed",
    "time_estimate_s",
    "time_total_s", "time_cum_s",
]

#: part of the name of every file while it is being written (``.NAME.ngcontact-tmp``); such files are ours
TMP_MARK = ".ngcontact-tmp"


def json_value(v):
    """A history value for JSON: numbers stay numbers (NaN / inf: null)."""
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    return v


def _csv_value(v):
    """A value for a CSV cell: floats with 10 significant digits, NaN as an empty cell."""
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.10g}"
    return v


def csv_text(rows, columns=None) -> str:
    """``rows`` (dicts) as CSV text: the key columns first, then ``columns`` (default: the rows' keys in
    the order first seen); a column is written only when some row has it."""
    columns = columns or list(dict.fromkeys(k for r in rows for k in r))
    order = [*KEY_COLUMNS, *(c for c in columns if c not in KEY_COLUMNS)]
    present = [c for c in order if any(c in r for r in rows)]
    fh = io.StringIO(newline="")
    w = csv.writer(fh)
    w.writerow(present)
    for r in rows:
        w.writerow([_csv_value(r.get(c, "")) for c in present])
    return fh.getvalue()


def read_history(path) -> list:
    """Rows of a history.csv or newton.csv as dicts of ints / floats (names: str) in the file's column order
    (empty cells: nan; the time ``t``: always a float)."""
    out = []
    with open(path) as fh:
        for r in csv.DictReader(fh):
            row = {}
            for k, v in r.items():
                if v == "":
                    row[k] = float("nan")
                elif k == "t":
                    row[k] = float(v)
                else:
                    try:
                        row[k] = int(v)
                    except ValueError:
                        try:
                            row[k] = float(v)
                        except ValueError:  # a name (e.g. the multiplier candidate)
                            row[k] = v
            out.append(row)
    return out


def read_summary(run_dir) -> dict:
    """summary.json of a run directory (``complete`` defaults to True for directories written before it existed)."""
    s = json.loads((Path(run_dir) / "summary.json").read_text())
    s.setdefault("complete", True)
    s.setdefault("reason", None)
    return s


def atomic_write(path, data) -> Path:
    """Write ``data`` (str or bytes) to ``path`` through a temporary file in the same directory and a rename:
    a reader (or a kill) sees the previous or the new file, never half of it."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}{TMP_MARK}")
    with open(tmp, "wb" if isinstance(data, bytes) else "w", newline="" if isinstance(data, str) else None) as fh:
        fh.write(data)
    os.replace(tmp, path)
    return path
