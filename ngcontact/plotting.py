"""Plots.  Convergence plots read only the written CSV files (compute, then plot).

:func:`write_run_plots` draws every figure of a run directory; it is the ``plots`` hook of
:func:`ngcontact.results.write_run`, which itself writes data only.  matplotlib with the Agg
backend, no LaTeX.
"""
from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .results import read_history  # noqa: E402

__all__ = ["write_run_plots", "plot_run", "plot_compare", "plot_solution", "plot_eta_map", "plot_mesh", "slope_label",
           "tidy_log_axes"]


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


def _slope_line(ax, n, e, slope, label):
    """Reference line e ~ n^slope through the last point."""
    n = np.asarray(n, float)
    ref = e[-1] * (n / n[-1]) ** slope
    ax.loglog(n, ref, "k--", lw=0.8, label=label)


def write_run_plots(run_dir, result) -> list:
    """All figures of a run into ``run_dir``, which already holds its history.csv and newton.csv:
    :func:`plot_run`; with a discretization, solution.png (and mesh.png for adaptive runs); with an
    estimate, eta_map.png.  Returns the file names written."""
    run_dir = Path(run_dir)
    written = plot_run(run_dir, result.options.order)
    if result.discretization is not None:
        written.append(plot_solution(result.discretization, result.x, result.y, run_dir / "solution.png").name)
        if getattr(result.options, "adaptive", False):
            written.append(plot_mesh(result.discretization, result.x, result.y, run_dir / "mesh.png").name)
    if result.estimate is not None:
        written.append(plot_eta_map(result.estimate, run_dir / "eta_map.png").name)
    return written


def plot_run(run_dir, order: int) -> list:
    """convergence.png and error_vs_time.png (energy error and/or estimator eta) and newton.png (one
    curve per level, or per level and time step n)."""
    run_dir = Path(run_dir)
    rows = read_history(run_dir / "history.csv")
    written = []
    curves = [(c, lab) for c, lab in (("err_energy", "energy error"), ("eta", r"estimator $\eta$"))
              if rows and c in rows[0]]
    if curves:
        n = np.array([r["ndof"] for r in rows])
        t = np.array([r["time_cum_s"] for r in rows])
        for fname, xs, xlabel in (("convergence.png", n, "ndof"),
                                  ("error_vs_time.png", t, "cumulative run time [s]")):
            fig, ax = plt.subplots(figsize=(5, 4))
            for c, lab in curves:
                ax.loglog(xs, [r[c] for r in rows], "o-" if c == "err_energy" else "s--", label=f"P{order} {lab}")
            if fname == "convergence.png":
                e = np.array([r[curves[0][0]] for r in rows])
                _slope_line(ax, n, e, -order / 2, slope_label(order))
            ax.set_xlabel(xlabel)
            ax.set_ylabel("energy error / estimate")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
            fig.tight_layout()
            tidy_log_axes(fig)
            fig.savefig(run_dir / fname, dpi=120)
            plt.close(fig)
            written.append(fname)
    newton = run_dir / "newton.csv"
    if newton.exists():
        its = read_history(newton)
        fig, ax = plt.subplots(figsize=(5, 4))
        for key in sorted({(r["level"], r.get("n")) for r in its}, key=lambda key: (key[0], key[1] or 0)):
            pts = [(r["k"], r["res"]) for r in its if (r["level"], r.get("n")) == key and r["res"] > 0]
            if pts:
                k, res = zip(*pts)
                ax.semilogy(k, res, ".-", label=f"level {key[0]}" + ("" if key[1] is None else f", n = {key[1]}"))
        ax.set_xlabel("Newton iteration k")
        ax.set_ylabel(r"$\|\Phi(X^k)\| / \|F\|$")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        tidy_log_axes(fig)
        fig.savefig(run_dir / "newton.png", dpi=120)
        plt.close(fig)
        written.append("newton.png")
    return written


def plot_compare(run_dirs, out_file, title: str = "") -> Path:
    """Energy error vs ndof and vs cumulative time for several runs, side by side."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for d in map(Path, run_dirs):
        rows = read_history(d / "history.csv")
        if not rows or "err_energy" not in rows[0]:
            continue
        summary = json.loads((d / "summary.json").read_text())
        p = summary["options"]["order"]
        lab = f"{summary['options']['disc'].upper()} P{p}"
        n = np.array([r["ndof"] for r in rows])
        e = np.array([r["err_energy"] for r in rows])
        t = np.array([r["time_cum_s"] for r in rows])
        (line,) = ax1.loglog(n, e, "o-", label=lab)
        ref = e[-1] * (n / n[-1]) ** (-p / 2)
        ax1.loglog(n, ref, "--", color=line.get_color(), lw=0.8, label=slope_label(p))
        ax2.loglog(t, e, "o-", label=lab)
    ax1.set_xlabel("ndof")
    ax2.set_xlabel("cumulative run time [s]")
    for ax in (ax1, ax2):
        ax.set_ylabel("energy error")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out_file = Path(out_file)
    tidy_log_axes(fig)
    fig.savefig(out_file, dpi=120)
    plt.close(fig)
    return out_file


def plot_solution(disc, x, y, out_file) -> Path:
    """Gap u1 - u2 (or u - psi) with the discrete contact set, and lam_h, at the mesh vertices."""
    mesh = disc.mesh
    coords = np.array(mesh.ngmesh.Coordinates())[:, :2]
    tris = mesh.ngmesh.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    gfs = disc.gridfunctions(x, y)
    pts = mesh(coords[:, 0], coords[:, 1])
    gap = np.asarray(gfs["gap"](pts)).ravel()
    lam = np.asarray(gfs["lam"](pts)).ravel()
    contact = disc.contact_points(x, y)
    fig, axs = plt.subplots(1, 2, figsize=(10, 4.3))
    for ax, val, name in ((axs[0], gap, "gap"), (axs[1], lam, r"$\lambda_h$")):
        tc = ax.tripcolor(coords[:, 0], coords[:, 1], tris, val, shading="gouraud", cmap="viridis")
        fig.colorbar(tc, ax=ax)
        ax.set_aspect("equal")
        ax.set_title(name)
    axs[0].plot(contact[:, 0], contact[:, 1], "r.", ms=1.5, label="contact nodes")
    axs[0].legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    out_file = Path(out_file)
    tidy_log_axes(fig)
    fig.savefig(out_file, dpi=110)
    plt.close(fig)
    return out_file


def plot_eta_map(estimate, out_file, title: str = "") -> Path:
    """Element indicators eta_K (log colour scale) on the mesh: where the error sits."""
    from matplotlib.colors import LogNorm
    from matplotlib.tri import Triangulation

    mesh = estimate.flux.space.mesh
    pts = np.array([v.point for v in mesh.vertices])
    tris = np.array([[v.nr for v in el.vertices] for el in mesh.Elements()])
    eta = np.maximum(np.asarray(estimate.eta_K, float), 1e-300)
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    pos = eta[eta > 1e-300]
    norm = LogNorm(vmin=max(pos.min(), pos.max() * 1e-6), vmax=pos.max()) if pos.size else None
    tpc = ax.tripcolor(Triangulation(pts[:, 0], pts[:, 1], tris), facecolors=eta, norm=norm, cmap="viridis")
    fig.colorbar(tpc, ax=ax, label=r"$\eta_K$")
    ax.set_aspect("equal")
    ax.set_title(title or rf"estimator map, $\eta$ = {estimate.eta:.3e}")
    fig.tight_layout()
    tidy_log_axes(fig)
    fig.savefig(out_file, dpi=120)
    plt.close(fig)
    return Path(out_file)


def plot_mesh(disc, x, y, out_file, title: str = "") -> Path:
    """The (adapted) mesh with the discrete contact nodes: where refinement went."""
    mesh = disc.mesh
    coords = np.array(mesh.ngmesh.Coordinates())[:, :2]
    tris = mesh.ngmesh.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
    contact = disc.contact_points(x, y)
    fig, ax = plt.subplots(figsize=(5.5, 5.2))
    ax.triplot(coords[:, 0], coords[:, 1], tris, lw=0.2, color="k")
    if len(contact):
        ax.plot(contact[:, 0], contact[:, 1], "r.", ms=0.8, alpha=0.5, label="contact nodes")
        ax.legend(loc="upper right", fontsize=7)
    ax.set_aspect("equal")
    ax.set_title(title or f"P{disc.order}: {mesh.ne} triangles, ndof {disc.ndof}")
    fig.tight_layout()
    out_file = Path(out_file)
    tidy_log_axes(fig)
    fig.savefig(out_file, dpi=130)
    plt.close(fig)
    return out_file
