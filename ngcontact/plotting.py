"""Figures.  Convergence plots read only the written files (compute, then plot).

:func:`write_run_plots` draws every figure of a run directory; it is the ``plots`` hook of
:func:`ngcontact.results.write_run`, which itself writes data only.  Figures are matplotlib
``Figure`` objects on their own Agg canvas: importing or using this module neither imports pyplot
nor changes the caller's backend (a notebook keeps its inline plots).  No LaTeX.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .results import read_history

__all__ = ["write_run_plots", "plot_run", "plot_compare", "plot_solution", "solution_figure", "plot_eta_map", "plot_mesh",
           "slope_label",
           "tidy_log_axes", "new_figure", "plotted_column", "run_label", "level_colors"]


def new_figure(**kw) -> Figure:
    """A figure drawn by its own Agg canvas (no pyplot, no global state)."""
    fig = Figure(**kw)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, out_file, dpi: int) -> Path:
    fig.tight_layout()
    tidy_log_axes(fig)
    fig.savefig(out_file, dpi=dpi)
    return Path(out_file)


def slope_label(p: int) -> str:
    """Legend of the optimal slope ndof^(-p/2), as a reduced fraction (ndof^-1 for p = 2)."""
    from fractions import Fraction

    f = Fraction(p, 2)
    return f"ndof$^{{-{f.numerator}}}$" if f.denominator == 1 else f"ndof$^{{-{f.numerator}/{f.denominator}}}$"


def tidy_log_axes(fig) -> None:
    """No labels on the minor ticks of log axes that show at least two labelled major ticks (matplotlib
    labels minor ticks on axes spanning about a decade, where they overlap); an axis with fewer keeps
    them, so that it is never left without numbers."""
    from matplotlib.ticker import NullFormatter

    for ax in fig.axes:
        for axis, scale, lim in ((ax.xaxis, ax.get_xscale(), ax.get_xlim()), (ax.yaxis, ax.get_yscale(), ax.get_ylim())):
            if scale != "log":
                continue
            lo, hi = min(lim), max(lim)
            if sum(lo <= t <= hi for t in axis.get_majorticklocs()) >= 2:
                axis.set_minor_formatter(NullFormatter())


def level_colors(n: int) -> list:
    """``n`` distinct colours ordered from the first level (dark) to the last (light), for any ``n``."""
    from matplotlib import colormaps

    return [tuple(c) for c in colormaps["viridis"](np.linspace(0.0, 0.9, max(n, 1)))][:n]


def plotted_column(rows):
    """The column that convergence plots draw: ``err_energy`` (needs an exact solution), else the estimator
    ``eta``, else None."""
    for col in ("err_energy", "eta"):
        if rows and col in rows[0] and np.isfinite([r[col] for r in rows]).any():
            return col
    return None


def run_label(summary: dict) -> str:
    """Scene and method of a run, e.g. ``test1 FEM P2`` or ``lshape FEM P3 adaptive``."""
    o = summary.get("options", {})
    label = f"{summary.get('scene', '?')} {str(o.get('disc', '?')).upper()} P{o.get('order', '?')}"
    return label + (" adaptive" if o.get("adaptive") else "")


def _summary(run_dir: Path) -> dict:
    try:
        return json.loads((run_dir / "summary.json").read_text())
    except (OSError, ValueError):
        return {}


def _slope_line(ax, n, e, slope, label, **kw):
    """Reference line e ~ n^slope through the last point."""
    n = np.asarray(n, float)
    ax.loglog(n, e[-1] * (n / n[-1]) ** slope, "--", lw=0.8, label=label, **({"color": "k"} | kw))


def write_run_plots(run_dir, result) -> list:
    """All figures of a run into ``run_dir``, which already holds its history.csv and newton.csv:
    :func:`plot_run`; with a discretization, solution.png (and mesh.png for adaptive runs); with an
    estimate, eta_map.png.  Returns the file names written."""
    run_dir = Path(run_dir)
    written = plot_run(run_dir, result.options.order)
    label = run_label(_summary(run_dir)) if (run_dir / "summary.json").is_file() else ""
    if result.discretization is not None:
        written.append(plot_solution(result.discretization, result.x, result.y, run_dir / "solution.png",
                                     title=label).name)
        if getattr(result.options, "adaptive", False):
            written.append(plot_mesh(result.discretization, result.x, result.y, run_dir / "mesh.png").name)
    if result.estimate is not None:
        written.append(plot_eta_map(result.estimate, run_dir / "eta_map.png").name)
    return written


def plot_run(run_dir, order: int) -> list:
    """convergence.png and error_vs_time.png (energy error and/or estimator eta) and newton.png (one
    curve per level, or per level and time step n, in distinct colours)."""
    run_dir = Path(run_dir)
    rows = read_history(run_dir / "history.csv")
    summary = _summary(run_dir)
    label = run_label(summary) if summary else f"P{order}"
    written = []
    curves = [(c, lab) for c, lab in (("err_energy", "energy error"), ("eta", r"estimator $\eta$"))
              if rows and c in rows[0]]
    if curves:
        n = np.array([r["ndof"] for r in rows])
        t = np.array([r["time_cum_s"] for r in rows])
        for fname, xs, xlabel in (("convergence.png", n, "ndof"),
                                  ("error_vs_time.png", t, "cumulative run time [s]")):
            fig = new_figure(figsize=(5, 4))
            ax = fig.subplots()
            for c, lab in curves:
                ax.loglog(xs, [r[c] for r in rows], "o-" if c == "err_energy" else "s--", label=f"{label} {lab}")
            if fname == "convergence.png":
                _slope_line(ax, n, np.array([r[curves[0][0]] for r in rows]), -order / 2, slope_label(order))
            ax.set_xlabel(xlabel)
            ax.set_ylabel("energy error / estimate")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8)
            _save(fig, run_dir / fname, 120)
            written.append(fname)
    newton = run_dir / "newton.csv"
    if newton.exists():
        its = read_history(newton)
        keys = sorted({(r["level"], r.get("n")) for r in its}, key=lambda key: (key[0], key[1] or 0))
        fig = new_figure(figsize=(5, 4))
        ax = fig.subplots()
        for key, color in zip(keys, level_colors(len(keys))):
            pts = [(r["k"], r["res"]) for r in its if (r["level"], r.get("n")) == key and r["res"] > 0]
            if pts:
                k, res = zip(*pts)
                ax.semilogy(k, res, ".-", color=color,
                            label=f"level {key[0]}" + ("" if key[1] is None else f", n = {key[1]}"))
        ax.set_xlabel("Newton iteration k")
        ax.set_ylabel(r"$\|\Phi(X^k)\| / \|F\|$")
        ax.set_title(f"{label}: Newton per level", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=7, ncol=1 + len(keys) // 12)
        _save(fig, run_dir / "newton.png", 120)
        written.append("newton.png")
    return written


def plot_compare(run_dirs, out_file, title: str = "") -> Path:
    """Energy error vs ndof and vs cumulative time for several runs, side by side; a run without an exact
    solution is drawn with its estimator eta (dashed, "eta" in its legend), a run with neither is skipped
    (the CLI refuses it).  Legends name scene, method and degree."""
    fig = new_figure(figsize=(10, 4))
    ax1, ax2 = fig.subplots(1, 2)
    drawn = set()
    for d in map(Path, run_dirs):
        rows = read_history(d / "history.csv")
        col = plotted_column(rows)
        if col is None:
            continue
        drawn.add(col)
        summary = _summary(d)
        p = summary.get("options", {}).get("order", 1)
        lab = run_label(summary) + (" eta" if col == "eta" else "")
        if summary.get("complete") is False:
            lab += " (incomplete)"
        n = np.array([r["ndof"] for r in rows])
        e = np.array([r[col] for r in rows])
        t = np.array([r["time_cum_s"] for r in rows])
        style = "o-" if col == "err_energy" else "s--"
        (line,) = ax1.loglog(n, e, style, label=lab)
        _slope_line(ax1, n, e, -p / 2, slope_label(p), color=line.get_color())
        ax2.loglog(t, e, style, color=line.get_color(), label=lab)
    ax1.set_xlabel("ndof")
    ax2.set_xlabel("cumulative run time [s]")
    ylabel = {frozenset({"err_energy"}): "energy error", frozenset({"eta"}): r"estimator $\eta$"}.get(
        frozenset(drawn), r"energy error / estimator $\eta$")
    for ax in (ax1, ax2):
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    return _save(fig, out_file, 120)


def _mesh_arrays(mesh):
    """Vertex coordinates (nv, 2) and triangles (ne, 3, 0-based) of a 2D mesh."""
    coords = np.array(mesh.ngmesh.Coordinates())[:, :2]
    tris = mesh.ngmesh.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    return coords, tris


def _contact_vertices(coords, contact) -> np.ndarray:
    """1.0 at the vertices that are discrete contact nodes, else 0.0 (coordinates matched to 1e-9 relative)."""
    scale = max(np.abs(coords).max(), 1.0) * 1e-9

    def keys(a):
        k = np.ascontiguousarray(np.round(np.asarray(a, float).reshape(-1, 2) / scale).astype(np.int64))
        return k.view(np.dtype((np.void, 16))).ravel()

    return np.isin(keys(coords), keys(contact)).astype(float)


#: above this many triangles the solution maps are drawn from values on a regular GRID_POINTS^2 grid
#: (matplotlib renders 1e6 triangles in minutes; the picture has fewer pixels than that)
MAX_PLOT_TRIANGLES = 250_000
GRID_POINTS = 500


def _grid_fields(mesh, coords, fields):
    """(X, Y, [values on the grid]) of CoefficientFunctions on a regular grid over the mesh's bounding box
    (NaN outside the mesh)."""
    (x0, y0), (x1, y1) = coords.min(axis=0), coords.max(axis=0)
    X, Y = np.meshgrid(np.linspace(x0, x1, GRID_POINTS), np.linspace(y0, y1, GRID_POINTS))
    pts = mesh(X.ravel(), Y.ravel())
    inside = pts["nr"] >= 0
    out = []
    for cf in fields:
        v = np.full(X.size, np.nan)
        v[inside] = np.asarray(cf(pts[inside])).ravel()
        out.append(v.reshape(X.shape))
    return X, Y, out


def plot_solution(disc, x, y, out_file, title: str = "") -> Path:
    """solution.png: :func:`solution_figure`."""
    return _save(solution_figure(disc, x, y, title), out_file, 110)


def solution_figure(disc, x, y, title: str = "") -> Figure:
    """Gap u1 - u2 (or u - psi) and lam_h at the mesh vertices, each with its title, axes and colour bar; the
    boundary of the discrete contact set drawn as a line over both, so the fields stay visible."""
    from matplotlib.lines import Line2D

    mesh = disc.mesh
    coords, tris = _mesh_arrays(mesh)
    gfs = disc.gridfunctions(x, y)
    in_contact = _contact_vertices(coords, disc.contact_points(x, y))
    gap_name = r"gap $u_{1h} - u_{2h}$" if "u1" in gfs else r"gap $u_h - \psi$"
    fig = new_figure(figsize=(10.5, 4.5))
    axs = fig.subplots(1, 2)
    on_grid = len(tris) > MAX_PLOT_TRIANGLES
    if on_grid:  # values on a regular grid; the contact indicator as a P1 function of the vertices
        from ngsolve import H1, GridFunction

        ind = GridFunction(H1(mesh, order=1))
        ind.vec.FV().NumPy()[:] = in_contact
        X, Y, (gap, lam, ind_grid) = _grid_fields(mesh, coords, (gfs["gap"], gfs["lam"], ind))
    else:
        pts = mesh(coords[:, 0], coords[:, 1])
        gap = np.asarray(gfs["gap"](pts)).ravel()
        lam = np.asarray(gfs["lam"](pts)).ravel()
    for ax, val, name in ((axs[0], gap, gap_name), (axs[1], lam, r"contact pressure $\lambda_h$")):
        if on_grid:
            tc = ax.pcolormesh(X, Y, val, shading="gouraud", cmap="viridis")
        else:
            tc = ax.tripcolor(coords[:, 0], coords[:, 1], tris, val, shading="gouraud", cmap="viridis")
        fig.colorbar(tc, ax=ax, label=name)
        ax.set_aspect("equal")
        ax.set_title(name)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    if 0 < in_contact.sum() < len(in_contact):
        for ax in axs:
            if on_grid:
                ax.contour(X, Y, ind_grid, levels=[0.5], colors="r", linewidths=0.9)
            else:
                ax.tricontour(coords[:, 0], coords[:, 1], tris, in_contact, levels=[0.5], colors="r", linewidths=0.9)
        axs[0].legend(handles=[Line2D([], [], color="r", lw=0.9, label="boundary of the contact set")],
                      loc="upper right", fontsize=7)
    elif in_contact.sum():
        axs[0].set_title(gap_name + " (contact at every vertex)")
    if title:
        fig.suptitle(f"{title}: {mesh.ne} triangles, ndof {disc.ndof}"
                     + (f" (drawn on a {GRID_POINTS}x{GRID_POINTS} grid)" if on_grid else ""), fontsize=10)
    return fig


def plot_eta_map(estimate, out_file, title: str = "") -> Path:
    """Element indicators eta_K (log colour scale) on the mesh: where the error sits."""
    from matplotlib.colors import LogNorm
    from matplotlib.tri import Triangulation

    coords, tris = _mesh_arrays(estimate.flux.space.mesh)
    eta = np.maximum(np.asarray(estimate.eta_K, float), 1e-300)
    fig = new_figure(figsize=(5.5, 4.5))
    ax = fig.subplots()
    pos = eta[eta > 1e-300]
    norm = LogNorm(vmin=max(pos.min(), pos.max() * 1e-6), vmax=pos.max()) if pos.size else None
    tpc = ax.tripcolor(Triangulation(coords[:, 0], coords[:, 1], tris), facecolors=eta, norm=norm, cmap="viridis")
    fig.colorbar(tpc, ax=ax, label=r"$\eta_K$")
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(title or rf"estimator map, $\eta$ = {estimate.eta:.3e}")
    return _save(fig, out_file, 120)


def plot_mesh(disc, x, y, out_file, title: str = "") -> Path:
    """The (adapted) mesh with the discrete contact nodes: where refinement went."""
    mesh = disc.mesh
    coords, tris = _mesh_arrays(mesh)
    contact = disc.contact_points(x, y)
    fig = new_figure(figsize=(5.5, 5.2))
    ax = fig.subplots()
    ax.triplot(coords[:, 0], coords[:, 1], tris, lw=0.2, color="k")
    if len(contact):
        ax.plot(contact[:, 0], contact[:, 1], "r.", ms=0.8, alpha=0.5, label="contact nodes")
        ax.legend(loc="upper right", fontsize=7)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(title or f"P{disc.order}: {mesh.ne} triangles, ndof {disc.ndof}")
    return _save(fig, out_file, 130)
