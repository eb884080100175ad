"""A time-dependent scene run: options from the scene and the caller, the mesh, the driver, the run directory.

Run directory (``write_parabolic_run``): ``steps.csv`` (one row per time step; columns below),
``contact_spacetime.csv`` (t and the contact fraction of the constraint points per bin of r or x),
``summary.json`` (scene, options, cumulative counts, onsets, space-time estimate and errors), the
plots of :mod:`.plots` and, with ``vtk_every`` = k, ``solution_nNNNNN.vtu`` every k-th step listed in
``solution.pvd`` (u1, u2, u1 - u2, lam; ParaView's time axis is t).

steps.csv columns: n, t, dt, newton_its, newton_converged, res_final, gmres_its, factorizations (fresh
factorizations of the direct mode), pcg_its, eta_sp_n, eta_tm_n, eta_C_n, eta_f_n (the parts of the
space-time bound, :mod:`.estimate`), eta_disc / eta_lin / eta_alg (stationary components of the step),
err_energy_n ((1/dt int_{I_n} |||u - u_htau|||^2)^{1/2}, exact solution only), active_nodes,
contact_area, gap_min, lam_min, active_<region>, time_s, newton_cum, gmres_cum.
"""
from __future__ import annotations

import json
import platform
from dataclasses import asdict, fields, replace
from pathlib import Path

from ..results.directory import OutputDir
from ..results.files import csv_text, json_value
from ..results.vtk import pvd_text
from .driver import ParabolicOptions, run_parabolic

__all__ = ["parabolic_options", "scene_mesh", "run_parabolic_scene", "write_parabolic_run", "MESH_KEYS"]

#: scene/CLI options that choose the mesh: uniform refinements of the domain's mesh, the domain's maxh
MESH_KEYS = ("level", "maxh")


def parabolic_options(scene, given: dict):
    """(ParabolicOptions, mesh options) from the scene's DEFAULTS overridden by the non-None ``given``."""
    opts = {**scene.defaults, **{k: v for k, v in given.items() if v is not None}}
    mesh_opts = {k: opts.pop(k) for k in MESH_KEYS if k in opts}
    known = {f.name for f in fields(ParabolicOptions)}
    unknown = sorted(set(opts) - known)
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for the time-dependent scene {scene.name}")
    level = mesh_opts.get("level", 0)
    if isinstance(level, bool) or not isinstance(level, int) or not 0 <= level <= 8:
        raise ValueError(f"option level must be an integer between 0 and 8, got {level!r}")
    maxh = mesh_opts.get("maxh")
    if maxh is not None and (isinstance(maxh, bool) or not isinstance(maxh, (int, float)) or not maxh > 0):
        raise ValueError(f"option maxh must be > 0, got {maxh!r}")
    return ParabolicOptions(**opts), mesh_opts


def scene_mesh(scene, mesh_opts: dict):
    """The mesh of the run: the domain (with ``maxh`` replaced if given) refined ``level`` times."""
    domain = scene.problem.domain
    if mesh_opts.get("maxh") is not None:
        domain = replace(domain, maxh=float(mesh_opts["maxh"]))
    return domain.mesh(mesh_opts.get("level", 0))


def run_parabolic_scene(scene, given: dict = None, *, progress=None, snapshot_every: int = 0):
    """Run a time-dependent scene: (ParabolicResult, ParabolicOptions, mesh options)."""
    options, mesh_opts = parabolic_options(scene, given or {})
    mesh = scene_mesh(scene, mesh_opts)
    mod = scene.module
    res = run_parabolic(scene.problem, mesh, options, progress=progress,
                        regions=getattr(mod, "REGIONS", None), space_axis=getattr(mod, "SPACE_AXIS", "r"),
                        snapshot_every=snapshot_every)
    return res, options, mesh_opts


def write_parabolic_run(out, scene, result, options, mesh_opts, *, argv=None, plots: bool = True,
                        vtk_every: int = 0) -> Path:
    """Write the run directory ``out`` (module docstring); returns its path."""
    from ..results import __version__

    d = OutputDir(out, "run", "--out")
    d.start()
    d.write("steps.csv", csv_text(result.rows))
    head = "t," + ",".join(f"b{i}" for i in range(len(result.bins) - 1))
    lines = [f"# bin edges ({getattr(scene.module, 'SPACE_AXIS', 'r')}): "
             + " ".join(f"{b:.6g}" for b in result.bins), head]
    lines += [f"{t:.10g}," + ",".join(f"{v:.4g}" for v in frac) for t, frac in result.spacetime]
    d.write("contact_spacetime.csv", "\n".join(lines) + "\n")
    opts = {k: v for k, v in asdict(options).items()}
    summary = {"scene": scene.name, "description": scene.description, "options": opts, "mesh": mesh_opts,
               "argv": argv, "ngcontact": __version__, "python": platform.python_version(),
               **result.summary, "failures": result.failures}
    d.write("summary.json", json.dumps({k: json_value(v) for k, v in summary.items()}, indent=1) + "\n")
    if vtk_every and result.snapshots:
        from ngsolve import VTKOutput

        disc, entries = result.stepper.disc, []
        for n, t, x, y in result.snapshots:
            name = f"solution_n{n:05d}.vtu"
            gfs = disc.gridfunctions(x, y)
            tmp = d.tmp_path(name[:-4])
            VTKOutput(disc.mesh, coefs=[gfs[k] for k in ("u1", "u2", "gap", "lam")], names=["u1", "u2", "gap", "lam"],
                      filename=str(tmp), subdivision=max(disc.order - 1, 0), legacy=False).Do()
            Path(f"{tmp}.vtu").replace(d.register(name))
            entries.append((t, name))
        d.write("solution.pvd", pvd_text(entries))
    if plots:
        import matplotlib.pyplot as plt

        from .plots import write_parabolic_plots

        for name, fig in write_parabolic_plots(result, scene.name).items():
            target = d.register(name)
            tmp = d.tmp_path(name)
            fig.savefig(tmp, dpi=110, format="png")
            tmp.replace(target)
            plt.close(fig)
    return d.path
