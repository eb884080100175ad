"""Run directories: writing and reading history.csv, newton.csv, summary.json and the VTK files.

This module writes data only.  Figures are drawn by a caller-supplied hook (``write_run(...,
plots=ngcontact.plotting.write_run_plots)``) into the same staging directory, so that plots
and data appear together: everything is written into a temporary sibling directory that
replaces the target only once complete, and a failed run never leaves partial outputs that look
finished.

Rows are keyed by ``level`` and, in time-dependent runs, by the time step ``n`` and the time
``t`` (:data:`KEY_COLUMNS`).  The key columns present come first in history.csv and newton.csv,
in that order; a stationary run has no ``n`` and ``t`` columns.

history.csv columns (one row per level, or per level and time step; a column is present
only when the run computes it -- error columns need an exact solution):

==================  ===========================================================
level               mesh level j (T_j: j uniform refinements of the coarse mesh)
n                   time-dependent runs: time step index n
t                   time-dependent runs: time t_n of the row
nelem               number of triangles
h                   mesh size (nominal for structured meshes, else max edge)
ndof                DOFs as counted in [CAMWA21]: fem (fields + 1) x interior nodes;
                    hho u1, u2 on cells and interior faces + lam on cells;
                    dg (fields + 1) x cell nodes
ndof_sc             hho: size of the statically condensed system (face unknowns)
nodes               interior Lagrange nodes per field
marked              --adaptive: elements marked on the previous level (0 on level 0)
err_energy          (sum_a mu_a ||grad(u_a - u_ah)||^2)^(1/2)      [exact only]
rate_energy         log(e_{j-1}/e_j) / log(h_{j-1}/h_j)              [exact only]
err_max_nodal       max over nodes |u_a(x_l) - u_ah(x_l)|           [exact only]
err_jump            dg: jump seminorm (sum_F eta/h_F ||[u_ah - u_a]||_F^2)^(1/2) [exact]
newton_its          semismooth Newton iterations on this level
newton_converged    1 if the Newton mode's stopping criterion was met, else 0: ||Phi||/||F|| <= tol
                    (direct, gmres, inexact) or eta_lin <= gamma_lin eta_disc (adaptive)
res_final           final ||Phi||/||F|| (adaptive: it contains the algebraic residual of the accepted
                    GMRES iterate and can be O(1) when the estimators say the error is discretization-dominated)
newton_balanced     --newton-stop balanced: 1 if the level stopped on eps_lin <= gamma_balance eps_disc
eps_lin_final, eps_disc_final
                    --newton-stop balanced: linearization defect and discretization proxy of
                    the last iterate (ngcontact.newton module doc)
active_nodes        nodes in the discrete contact set (gap <= X3)
linear_size         largest linear system solved in a Newton step (reduced SPD /
                    condensed face system / full system)
gmres_its           --newton gmres|inexact|adaptive: GMRES iterations, all Newton steps
                    (adaptive: including the nu look-ahead steps of sigma_alg)
gmres_max_step      largest number of GMRES iterations in one Newton step
gmres_first_step    GMRES iterations of the first Newton step
n_estimates         estimator evaluations inside the Newton loop (adaptive: every nu GMRES its)
time_estimate_newton_s  time of those evaluations (inside time_solve_s, not in time_linear_s)
eta_disc_final, eta_lin_final, eta_alg_final
                    error components of the last iterate ([JSC20] Corollary; adaptive
                    mode, or gmres/inexact with estimator logging)
gap_min             min over nodes of X1 - X2 (or X - psi): >= -tol at convergence
lam_min             min of X3: >= -tol at convergence
product_max         max |gap * X3|
time_mesh_s         building/refining the mesh (--adaptive: copy + bisection giving T_j)
time_mark_s         --adaptive: marking on T_{j-1} (Doerfler / maximum)
time_prolong_s      initial guess: the previous level's solution prolongated (nested start) or
                    the scene's initial guess (cold start)
time_assembly_s     spaces, Lagrange nodes, matrices, loads
time_solve_s        semismooth Newton (all iterations)
time_linear_s       reduced SPD systems (assembly + factorization + solve)
time_condense_s     hho: static condensation + cell recovery (inside time_solve_s)
time_post_s         errors and diagnostics
eta                 guaranteed estimate of |||u - u_h||| (--estimate; [JSC20] Theorem
                    plus Dirichlet-data and quadrature terms, see ngcontact.estimators)
eta_seed            the seed Theorem's total (bound of |||u - s~_h|||)
eta_direct          direct bound of |||u - u~_h||| (pays eta_nonc1 once; eta uses the
                    smaller of eta_seed + eta_nonc1 and eta_direct)
theta_contact       Theta of the direct bound (weak form tested with the
                    nonconformity correction)
eta_F, eta_R        flux / residual estimators (sum over K and alpha, squared, root)
eta_FR              (sum_a (sum_K (eta_F,K,a + eta_R,K,a)^2))^(1/2)
eta_C               contact estimator sum_K 2 (lam_h^pos, u1h - u2h)_K
eta_nonc1..3        nonconformity estimators of the seed's Theorem
eta_quad            data oscillation / quadrature term (0 for polynomial data)
eta_bc, eps_w       Dirichlet data correction |||w_h||| and its non-orthogonality
eta_nonc2_seed      seed's C_{Omega,mu} ||lam_h^neg|| (diagnostic, not in eta)
time_estimate_s     flux reconstruction + estimators
i_eff               eta / err_energy                                  [exact only]
rate_eta            log(eta_{j-1}/eta_j) / log(h_{j-1}/h_j)
                    (--adaptive: rate_energy and rate_eta use ndof^{-1/2} in place of h)
time_total_s        whole level
time_cum_s          cumulated over levels 0..j
==================  ===========================================================

newton.csv: one row per (level, time step n if any, iteration k) with the key columns, k, res, res_lin, res_c,
n_active, n_changed, step, time_linear, time_step, linear_size, linear_path (0 fresh
factorization, 1 PCG preconditioned by an earlier step's factorization, 2 PCG gave up and
the step was factorized), pcg_its (see :class:`ngcontact.newton.IterationRecord`); with --newton other than direct also
gmres_its, gmres_cum, gmres_accepted, gmres_stop (0 tolerance, 1 adaptive, 2 maxiter,
3 stagnation), res_alg (||R^{k,i}||/||B^{k-1}||),
eta_disc, eta_lin, eta_alg, eta, n_estimates, time_estimate, time_ilu, ilu_fill_ratio
(nnz(L+U)/nnz(A) of the step's ILU; :class:`ngcontact.newton.inexact.InexactIterationRecord`).
"""
from __future__ import annotations

import csv
import json
import math
import os
import platform
import shutil
import subprocess
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np

__all__ = ["write_run", "check_output_dir", "read_history", "markdown_table", "versions", "git_revision",
           "HISTORY_COLUMNS", "KEY_COLUMNS"]

#: the columns that identify a row: mesh level, time step index, time (the last two only in time-dependent runs)
KEY_COLUMNS = ("level", "n", "t")

HISTORY_COLUMNS = [
    *KEY_COLUMNS, "nelem", "h", "ndof", "ndof_sc", "nodes", "marked", "err_energy", "rate_energy", "err_max_nodal",
    "err_jump", "newton_its", "newton_converged", "res_final", "newton_balanced",
    "eps_lin_final", "eps_disc_final", "active_nodes", "linear_size",
    "gmres_its", "gmres_max_step", "gmres_first_step", "n_estimates", "time_estimate_newton_s",
    "eta_disc_final", "eta_lin_final", "eta_alg_final", "gap_min", "lam_min",
    "product_max", "time_mesh_s", "time_mark_s", "time_assembly_s", "time_prolong_s", "time_solve_s", "time_linear_s",
    "time_condense_s", "time_post_s",
    "eta", "rate_eta", "i_eff", "eta_seed", "eta_direct", "theta_contact", "eta_F", "eta_R", "eta_FR", "eta_C", "eta_nonc1",
    "eta_nonc2", "eta_nonc3", "eta_quad", "eta_bc", "eps_w", "eta_nonc2_seed", "time_estimate_s",
    "time_total_s", "time_cum_s",
]


def _json_value(v):
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


def _write_csv(path: Path, rows, columns=None):
    """``rows`` (dicts) as CSV: the key columns first, then ``columns`` (default: the rows' keys in
    the order first seen); a column is written only when some row has it."""
    columns = columns or list(dict.fromkeys(k for r in rows for k in r))
    order = [*KEY_COLUMNS, *(c for c in columns if c not in KEY_COLUMNS)]
    present = [c for c in order if any(c in r for r in rows)]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(present)
        for r in rows:
            w.writerow([_csv_value(r.get(c, "")) for c in present])


def read_history(path) -> list:
    """Rows of a history.csv or newton.csv as dicts of ints / floats in the file's column order
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
                        row[k] = float(v)
            out.append(row)
    return out


def git_revision() -> str:
    try:
        here = Path(__file__).resolve().parent
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True,
                             text=True, timeout=5)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, timeout=5)
        if rev.returncode:
            return "unknown"
        return rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except Exception:
        return "unknown"


def versions() -> dict:
    import matplotlib
    import numpy
    import scipy
    import ngsolve

    from . import __version__

    return {"ngcontact": __version__, "ngsolve": ngsolve.__version__, "numpy": numpy.__version__,
            "scipy": scipy.__version__, "matplotlib": matplotlib.__version__,
            "python": platform.python_version()}


#: what a run directory holds (write_run); anything else in it is the user's and blocks its replacement
RUN_FILE_SUFFIXES = (".csv", ".json", ".png", ".vtu", ".pvd", ".vtk")


def check_output_dir(out_dir, field: str = "out") -> Path:
    """Check, before any work, that a run directory can be written at ``out_dir``; returns it absolute.

    A run directory replaces ``out_dir`` as a whole, so ``out_dir`` must be absent, empty, or a
    previous run directory (it has a ``summary.json``): any other existing directory is refused
    rather than deleted.  Its nearest existing ancestor must be a writable directory.  Errors
    (ValueError) name ``field`` and the path.
    """
    if out_dir is None or str(out_dir).strip() == "":
        raise ValueError(f"{field} must be a directory path, got {str(out_dir)!r}")
    given = str(out_dir)
    out = Path(os.path.abspath(os.path.expanduser(given)))
    if out.parent == out:
        raise ValueError(f"{field} {given!r} is a file-system root, not a run directory")
    cwd = Path.cwd().resolve()
    if os.path.islink(out) and not out.exists():
        raise ValueError(f"{field} {given!r} is a broken symbolic link")
    if out.exists() and (out.resolve() == cwd or out.resolve() in cwd.parents):
        raise ValueError(f"{field} {given!r} is the working directory or contains it (a run directory is replaced "
                         f"as a whole): choose a subdirectory, e.g. {field} out/run")
    if out.exists():
        if not out.is_dir():
            raise ValueError(f"{field} {given!r} exists and is not a directory")
        entries = list(out.iterdir())
        if entries and not (out / "summary.json").is_file():
            raise ValueError(f"{field} {given!r} is a non-empty directory that is not an ngcontact run directory "
                             f"(no summary.json); refusing to replace it: choose a new or empty directory")
        foreign = [e.name for e in entries if e.is_dir() or e.suffix not in RUN_FILE_SUFFIXES]
        if foreign:
            raise ValueError(f"{field} {given!r} is a run directory that also holds {foreign[0]!r}"
                             f"{f' (and {len(foreign) - 1} more)' if len(foreign) > 1 else ''}, which replacing "
                             f"it would delete: move it away or choose another directory")
    anc = out.parent
    while not anc.exists():
        anc = anc.parent
    if not anc.is_dir():
        raise ValueError(f"{field} {given!r} cannot be created: {anc} is not a directory")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise ValueError(f"{field} {given!r} cannot be created: {anc} is not writable")
    try:  # the staging directory of write_run is created there: try it (access() says yes to root anywhere)
        os.rmdir(tempfile.mkdtemp(prefix=".ngcontact-probe-", dir=out.parent if out.parent.exists() else anc))
    except OSError as exc:
        raise ValueError(f"{field} {given!r} cannot be created: {exc.strerror} ({anc})") from None
    return out


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_run(result, out_dir, vtk: bool = True, plots=None, argv=None) -> Path:
    """Write all outputs of a :class:`~ngcontact.drivers.RunResult` atomically into ``out_dir``.

    Parameters
    ----------
    result : RunResult
        ``rows`` (history.csv), ``iterations`` (newton.csv), ``scene``, ``options`` (a dataclass),
        ``converged``, ``failures``, optional ``stop_reason``; ``discretization``, ``x``, ``y`` and
        ``estimate`` (each may be None) for the VTK files.
    out_dir : path
        must pass :func:`check_output_dir` (absent, empty or a previous run directory, which is replaced).
    vtk : bool
        write solution.vtu (needs ``result.discretization``).
    plots : callable or None
        ``plots(directory, result)`` draws the figures into the staging directory after the CSV and
        JSON files are written there, e.g. :func:`ngcontact.plotting.write_run_plots`; None or False: no
        figures.
    argv : list of str or None
        the command line, recorded in summary.json.

    The files are written into a hidden sibling directory that is renamed into place once complete; on
    any exception (of ``plots`` too; through the CLI, on Ctrl-C or SIGTERM) it is removed."""
    if plots and not callable(plots):
        raise TypeError(f"plots must be None or a callable (directory, result), got {plots!r}; "
                        "figures are drawn by e.g. ngcontact.plotting.write_run_plots")
    out_dir = check_output_dir(out_dir, "out_dir")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{out_dir.name}-", dir=out_dir.parent))
    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it 0700; a run directory follows the umask
    old = None
    try:
        _write_csv(tmp / "history.csv", result.rows, HISTORY_COLUMNS)
        _write_csv(tmp / "newton.csv", result.iterations)
        summary = {
            "scene": result.scene.name,
            "scene_file": _display_path(result.scene.path),
            "problem": type(result.scene.problem).__name__,
            "domain": result.scene.problem.domain.name,
            "description": result.scene.description,
            "options": asdict(result.options),
            "converged": result.converged,
            "failures": result.failures,
            **({"stop_reason": result.stop_reason} if getattr(result, "stop_reason", None) else {}),
            "final": {k: _json_value(v) for k, v in result.rows[-1].items()} if result.rows else {},
            "versions": versions(),
            "git_revision": git_revision(),
            "command": " ".join(argv) if argv else None,
        }
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        if plots:
            plots(tmp, result)
        if vtk and result.discretization is not None:
            _write_vtk(result, tmp / "solution")
        if os.path.lexists(out_dir):
            old = out_dir.with_name(f".old-{out_dir.name}-{os.getpid()}")
            out_dir.rename(old)
        tmp.rename(out_dir)
        if old is not None:
            if old.is_symlink():
                old.unlink()
            else:
                shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and os.path.lexists(old) and not os.path.lexists(out_dir):
            old.rename(out_dir)  # interrupted between the two renames: the previous run comes back
        raise
    return out_dir


def _display_path(path) -> str:
    """``path`` relative to the working directory when it lies below it (no absolute paths of the
    machine that ran it in committed summaries), else as given."""
    if path is None:
        return None
    p = Path(path)
    try:
        return str(p.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def _write_vtk(result, basename: Path):
    from ngsolve import VTKOutput

    disc = result.discretization
    gfs = disc.gridfunctions(result.x, result.y)
    names = [n for n in ("u1", "u2", "u", "gap", "lam") if n in gfs]
    coefs = [gfs[n] for n in names]
    if result.estimate is not None:  # eta_K maps as (piecewise constant) cell data
        for n, gf in result.estimate.cell_data().items():
            names.append(n)
            coefs.append(gf)
    VTKOutput(disc.mesh, coefs=coefs, names=names, filename=str(basename),
              subdivision=max(disc.order - 1, 0), legacy=False).Do()


def _key_cells(row) -> list:
    """The table cells of a row's keys: T<level>, then the time step and time when present."""
    return [f"T{row['level']}"] + ([str(row["n"]), f"{row['t']:.6g}"] if "n" in row else [])


def markdown_table(run_dirs) -> str:
    """One markdown table per run directory: level (time step, time), ndof, error, rate, Newton its, times."""
    out = []
    for d in map(Path, run_dirs):
        rows = read_history(d / "history.csv")
        s = json.loads((d / "summary.json").read_text())
        o = s["options"]
        out.append(f"### {s['scene']}: {o['disc'].upper()} P{o['order']}, Newton-{o['cfun']}, {o['start']} start"
                   + ("" if s["converged"] else "  **(NOT converged: " + "; ".join(s["failures"]) + ")**"))
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
