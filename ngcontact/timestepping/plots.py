"""Figures of a time-dependent run (matplotlib Agg): contact area against t, the space-time contact picture,
the estimator parts against t, the iterations against t."""
from __future__ import annotations

import numpy as np

__all__ = ["write_parabolic_plots", "PLOT_FILES"]

PLOT_FILES = ("contact_area.png", "contact_spacetime.png", "estimators_t.png", "iterations_t.png")


def _col(rows, name):
    return np.array([r.get(name, np.nan) for r in rows], dtype=float)


def write_parabolic_plots(result, title: str) -> dict:
    """file name -> matplotlib Figure (the caller saves them)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result.rows
    t = _col(rows, "t")
    figs = {}
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(t, _col(rows, "contact_area"), "-", label="|contact set|")
    ax.set_xlabel("t")
    ax.set_ylabel("area of {u1h - u2h = 0}")
    ax.set_title(f"{title}: contact set")
    ax.grid(alpha=0.3)
    figs["contact_area.png"] = fig

    fig, ax = plt.subplots(figsize=(6, 4))
    if result.spacetime:
        img = np.array([f for _, f in result.spacetime]).T
        # column n covers the step (t_{n-1}, t_n]: the real time edges, also for adaptive (nonuniform) steps
        t_edges = np.concatenate([[0.0], [tn for tn, _ in result.spacetime]])
        ax.pcolormesh(t_edges, result.bins, img, cmap="Greys", vmin=0, vmax=1, shading="flat")
    ax.set_xlabel("t")
    ax.set_ylabel("position (r or x)")
    ax.set_title(f"{title}: contact (black) in space-time")
    figs["contact_spacetime.png"] = fig

    fig, ax = plt.subplots(figsize=(6, 4))
    for name, label in (("eta_sp_n", "spatial"), ("eta_tm_n", "temporal"), ("eta_C_n", "contact"),
                        ("eta_f_n", "data in t"), ("eta_lin", "linearization"), ("eta_alg", "algebraic"),
                        ("err_energy_n", "error")):
        v = _col(rows, name)
        if np.isfinite(v).any() and np.nanmax(np.abs(v)) > 0:
            ax.semilogy(t, np.where(v > 0, v, np.nan), label=label)
    ax.set_xlabel("t")
    ax.set_title(f"{title}: estimator parts per step")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    figs["estimators_t.png"] = fig

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(t, _col(rows, "newton_its"), ".-", label="Newton")
    g = _col(rows, "gmres_its")
    if np.nansum(g) > 0:
        ax.plot(t, g, ".-", label="GMRES")
    ax.set_xlabel("t")
    ax.set_ylabel("iterations per step")
    ax.set_title(f"{title}: iterations")
    ax.legend()
    ax.grid(alpha=0.3)
    figs["iterations_t.png"] = fig
    return figs
