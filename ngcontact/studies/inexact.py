"""Study: exact / inexact / adaptive inexact semismooth Newton on the [JSC20] disk test.

``python -m ngcontact.studies.inexact OUT [--quick]`` (``make inexact-study``: OUT = results/inexact).

Problem / discretisation: the disk test of [JSC20] (``cases/disk.py``), FEM P1
and P2 on netgen meshes of the unit disk with decreasing ``maxh`` (about 2k to
35k triangles, independent meshes as in [JSC20]), Newton-min from the cold
start X0 = [g, 0, 0] on every mesh, GMRES(100) + ILU on the reduced Newton
systems (:mod:`ngcontact.algebra.krylov`, :mod:`ngcontact.newton.linear`).

Runs (each a normal run directory under ``OUT/runs``, written by
:func:`ngcontact.results.write_run`, so history.csv / newton.csv / summary.json
carry the counters):

* P1, every mesh: ``gmres`` (||R||/||B|| <= 2e-12), ``inexact``, ``adaptive``
  (gamma_alg = gamma_lin = 0.3, nu = 10), plus the ``direct`` solve as
  reference for the energy error;
* P1, finest mesh: adaptive with (gamma_alg, gamma_lin) in {0.3, 0.03}^2;
* P2: the same three modes on the P2 meshes;
* P2 on the same meshes fitted to r = 1/sqrt 2 (``disk_fitted``): direct, inexact and adaptive.
  On the unfitted meshes f jumps inside elements and the P2 estimator overestimates the error
  (I_eff of ``disk`` P2 in results/estimators/TABLES.md; eta_disc against the error at the
  adaptive runs' accepted iterates in results/inexact/TABLES.md), so the adaptive stopping rules
  stop early; on the fitted meshes the estimator is sharp (``disk_fitted`` P2 in
  results/estimators/TABLES.md);
* P2 fitted, finest mesh: inexact and adaptive with two stronger ILU preconditioners
  (:data:`ILUS`; the ILU fill against the iteration counts and the run time), and the
  strongest one also on the unfitted finest P2 mesh;
* P1 on the ~8k mesh and P2 on the coarsest mesh: gmres, inexact and adaptive with the
  estimators evaluated after every Newton step (``log_estimators``) for the plot "estimators
  vs Newton iteration" (those evaluations are diagnostics, not part of the run time).

Outputs in OUT: ``all.csv`` (one row per run), ``TABLES.md`` (tables next to
the published [JSC20] numbers of REFERENCE.md), ``estimators_p1.png``,
``estimators_p2.png`` (eta_disc, eta_lin, eta_alg vs Newton iteration),
``gmres_vs_mesh.png`` (cumulative GMRES and Newton iterations vs number of
elements), ``estimator_log.csv`` (every adaptive evaluation: k, i, eta_*).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from .tables import fmt

__all__ = ["main", "P1_MAXH", "P2_MAXH", "PUBLISHED"]

#: maxh of the netgen disk meshes: ~2.1k, 4.2k, 8.3k, 17k, 34k triangles (results/inexact/TABLES.md)
P1_MAXH = (0.06, 0.042, 0.03, 0.021, 0.0148)
#: P2: ~2.1k, 8.3k, 27k triangles (results/inexact/TABLES.md)
P2_MAXH = (0.06, 0.03, 0.0165)
QUICK_P1, QUICK_P2 = (0.1, 0.07), (0.1,)
GAMMAS = ((0.3, 0.3), (0.03, 0.3), (0.3, 0.03), (0.03, 0.03))
#: ILU (drop_tol, fill_factor) of the study: the default (first) and the variants of the sensitivity table
ILUS = ((1e-5, 8.0), (1e-6, 10.0), (1e-6, 15.0))
#: modes run on the fitted P2 meshes (the accuracy check of the adaptive criteria with a sharp estimator)
FITTED_MODES = ("direct", "inexact", "adaptive")

#: [JSC20] disk test, REFERENCE.md ("~": read off plots)
PUBLISHED = {
    "p1_newton_8k": "15 / 46 / 14 (exact / inexact / adaptive, ~8k triangles)",
    "p1_gmres_35k": "3000 / 1660 / 670 (total GMRES at ~35k elements)",
    "p1_first_step": "220 (exact) vs 10 (adaptive): GMRES of the first Newton step",
    "p1_newton_vs_mesh": "exact ~8,12,15,19,22,25,28; adaptive ~8,11,14,18,21,23,27 (2k...35k elements, 7 meshes)",
    "p2_27k": "Newton 29 / 116 / 22, total GMRES 21000 / 7300 / 540 (~27k elements)",
    "gammas_35k": {(0.3, 0.3): "26 / 670", (0.03, 0.3): "26 / 1130", (0.3, 0.03): "27 / 680",
                   (0.03, 0.03): "27 / 1140"},
}


def _scene(maxh, fitted=False):
    """The disk test on a netgen mesh of size maxh; ``fitted``: the mesh has the circle r = 1/sqrt 2 (the
    exact contact boundary, where f and lam jump) as an internal line (``cases/disk_fitted.py``)."""
    from ..domains import UnitDisk
    from ..scenes import Scene, load_scene

    base = load_scene("disk_fitted" if fitted else "disk")
    domain = UnitDisk(maxh=maxh, interface_radius=1 / math.sqrt(2)) if fitted else UnitDisk(maxh=maxh)
    problem = replace(base.problem, domain=domain)
    return Scene(name=f"{base.name}-h{maxh:g}", path=base.path, problem=problem, description=base.description,
                 defaults={}, initial_guess=base.initial_guess)


def _run(out, order, maxh, newton, gamma_alg=0.3, gamma_lin=0.3, tag=None, fitted=False, ilu=ILUS[0]):
    from ..results import write_run
    from ..drivers import RunOptions, run_scene

    name = tag or f"p{order}{'f' if fitted else ''}-h{maxh:g}-{newton}"
    d = out / "runs" / name
    if (d / "summary.json").is_file():  # already done (re-running the study resumes)
        return d
    scene = _scene(maxh, fitted)
    opts = RunOptions(order=order, levels=1, start="cold", newton=newton, gamma_alg=gamma_alg,
                      gamma_lin=gamma_lin, nu=10, ilu_drop_tol=ilu[0], ilu_fill=ilu[1])
    t0 = time.perf_counter()
    res = run_scene(scene, opts)
    write_run(res, d, vtk=False, argv=["python -m ngcontact.studies.inexact", name])
    r = res.rows[-1]
    print(f"{name:28s} nelem {r['nelem']:6d} Newton {r['newton_its']:3d} GMRES {r.get('gmres_its', '-')!s:>6s} "
          f"err {r['err_energy']:.5e} solve {r['time_solve_s']:7.1f}s ({time.perf_counter() - t0:.1f}s)", flush=True)
    return d


def _load(d):
    from ..results import read_history

    row = read_history(d / "history.csv")[-1]
    s = json.loads((d / "summary.json").read_text())
    row.update(newton=s["options"]["newton"], order=s["options"]["order"], gamma_alg=s["options"]["gamma_alg"],
               gamma_lin=s["options"]["gamma_lin"], converged=s["converged"], run=d.name,
               ilu=(s["options"].get("ilu_drop_tol", ILUS[0][0]), s["options"].get("ilu_fill", ILUS[0][1])))
    if d.name.startswith("p2f-"):  # P2 on the fitted meshes: its own table ("order" key "2f")
        row["order"] = "2f"
    with open(d / "newton.csv") as fh:
        row["iterations"] = list(csv.DictReader(fh))
    return row


def _log_run(out, order, maxh):
    """gmres / inexact / adaptive with the estimators after every Newton step (plot data)."""
    from ..discretizations.fem import FEMDiscretization
    from ..drivers.level import LevelEstimator
    from ..newton import AdaptiveStop, KrylovSolve, NewtonOptions, semismooth_newton

    f = out / f"estimators_p{order}.json"
    if f.is_file():
        return json.loads(f.read_text())
    scene = _scene(maxh)
    disc = FEMDiscretization(scene.problem, next(scene.problem.domain.meshes(1)), order=order)
    x0, y0 = disc.initial_guess(scene.initial_guess)
    data = {"nelem": disc.mesh.ne, "maxh": maxh}
    for mode in ("gmres", "inexact", "adaptive"):
        linear = KrylovSolve(mode=mode, log_estimators=True, estimator=LevelEstimator(disc, None))
        res = semismooth_newton(disc.system, x0, y0, NewtonOptions(), linear=linear,
                                stop=AdaptiveStop() if mode == "adaptive" else None)
        data[mode] = [{"k": r.k, "eta_disc": r.eta_disc, "eta_lin": r.eta_lin, "eta_alg": r.eta_alg,
                       "gmres_cum": r.gmres_cum, "res": r.res} for r in res.history[1:]]
        data[mode + "_estimates"] = [vars(e) for e in res.estimates]
    f.write_text(json.dumps(data, indent=1))
    return data


def _plot_estimators(data, png, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True)
    for ax, mode in zip(axes, ("gmres", "inexact", "adaptive")):
        rows = data[mode]
        k = [r["k"] for r in rows]
        for key, style in (("eta_disc", "o-"), ("eta_lin", "s-"), ("eta_alg", "^-")):
            v = np.array([r[key] for r in rows], dtype=float)
            ax.semilogy(k, np.where(v > 0, v, np.nan), style, ms=4, label=key)
        ax.set_title(f"{mode} Newton ({data['nelem']} elements)")
        ax.set_xlabel("Newton iteration k")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("estimator")
    axes[0].legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def _plot_vs_mesh(rows, png):
    rows = [r for r in rows if r["ilu"] == ILUS[0]]  # the default ILU only (the ILU tables have the others)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for order, marker in ((1, "o"), (2, "s")):
        for mode, color in (("gmres", "C0"), ("inexact", "C1"), ("adaptive", "C2")):
            rr = sorted((r for r in rows if r["order"] == order and r["newton"] == mode
                         and r["gamma_alg"] == 0.3 and r["gamma_lin"] == 0.3), key=lambda r: r["nelem"])
            if not rr:
                continue
            n = [r["nelem"] for r in rr]
            axes[0].loglog(n, [r["gmres_its"] for r in rr], marker + "-", color=color, label=f"P{order} {mode}")
            axes[1].plot(n, [r["newton_its"] for r in rr], marker + "-", color=color, label=f"P{order} {mode}")
    axes[0].set_ylabel("cumulative GMRES iterations")
    axes[1].set_ylabel("Newton iterations")
    axes[1].set_xscale("log")
    for ax in axes:
        ax.set_xlabel("number of elements")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("[JSC20] disk test: Newton-min, GMRES + ILU, cold start X0 = [g, 0, 0]")
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def _ilu_tag(ilu):
    return f"ilu{ilu[0]:g}-{ilu[1]:g}"


def _complete_lu_ratio(maxh):
    """nnz(L + U) / nnz(A) of SuperLU's complete LU (same column ordering as spilu) of the first Newton
    matrix of the P2 fitted run at ``maxh``: the fill an ILU approaches as drop_tol -> 0."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from ..algebra.cfunctions import get_cfunction
    from ..discretizations.fem import FEMDiscretization

    scene = _scene(maxh, fitted=True)
    disc = FEMDiscretization(scene.problem, next(scene.problem.domain.meshes(1)), order=2)
    x, y = disc.initial_guess(scene.initial_guess)
    cf, system = get_cfunction("min"), disc.system
    g = system.gap(x)
    Ca, Cb = cf.jacobian(g, y)
    A = sp.csc_matrix(system.linearize(x, y, cf.value(g, y), Ca, Cb).A)
    lu = spla.splu(A)
    return (lu.L.nnz + lu.U.nnz) / A.nnz


def _ilu_table(rows, out):
    """The ILU sensitivity tables (P2 fitted and unfitted, finest mesh), or [] without their runs."""
    L = []
    for order, label in (("2f", "P2 fitted"), (2, "P2 unfitted")):
        sel = [r for r in rows if r["order"] == order and r["newton"] in ("inexact", "adaptive")]
        if not sel or len({r["ilu"] for r in sel}) < 2:
            continue
        ne = max(r["nelem"] for r in sel if r["ilu"] != ILUS[0])
        sel = [r for r in sel if r["nelem"] == ne]
        base = next((b for b in rows if b["order"] == order and b["nelem"] == ne and b["newton"] == "direct"), None)
        full = float("nan")
        if order == "2f":
            f = out / "complete_lu_fill.json"
            if not f.is_file():
                maxh = float(sel[0]["run"].split("-")[1][1:])  # run names p2f-h<maxh>-...
                f.write_text(json.dumps({"nelem": ne, "maxh": maxh, "ratio": _complete_lu_ratio(maxh)}))
            full = json.loads(f.read_text())
            full = full["ratio"] if full.get("nelem") == ne else float("nan")
        L += [f"## ILU sensitivity, {label}, {ne} elements", "",
              "The preconditioner's fill against the iteration counts and the run time (same runs otherwise; "
              "`--ilu-drop`, `--ilu-fill` on the CLI). fill = nnz(L+U)/nnz(A) of the ILU, mean over the Newton "
              "steps" + (f"; SuperLU's complete LU of the first Newton matrix has fill {fmt(full, '.1f')}."
                         if order == "2f" else "."), "",
              "| ILU (drop, fill bound) | fill | mode | Newton | GMRES total | GMRES accepted | GMRES 1st step "
              "| err / err(direct) | solve [s] | of which estimators [s] | of which ILU setup [s] |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
        for ilu in ILUS:
            for mode in ("inexact", "adaptive"):
                r = next((r for r in sel if r["ilu"] == ilu and r["newton"] == mode
                          and r["gamma_alg"] == 0.3 and r["gamma_lin"] == 0.3), None)
                if r is None:
                    continue
                its = r["iterations"][1:]
                acc = sum(int(it.get("gmres_accepted") or 0) for it in its)
                fills = [float(it["ilu_fill_ratio"]) for it in its if it.get("ilu_fill_ratio") not in (None, "")]
                t_ilu = sum(float(it.get("time_ilu") or 0) for it in its)
                ratio = r["err_energy"] / base["err_energy"] if base else float("nan")
                L.append(f"| ({ilu[0]:g}, {ilu[1]:g}){' default' if ilu == ILUS[0] else ''} | "
                         f"{fmt(float(np.mean(fills)) if fills else None, '.1f')} | "
                         f"{mode} | {r['newton_its']} | {int(r['gmres_its'])} | {acc} | {int(r['gmres_first_step'])} | "
                         f"{ratio:.4f} | {r['time_solve_s']:.1f} | {fmt(r.get('time_estimate_newton_s'), '.1f')} | "
                         f"{t_ilu:.1f} |")
        L.append("")
    return L


def _tables(rows, logs, out):
    ilu_lines = _ilu_table(rows, out)
    rows = [r for r in rows if r["ilu"] == ILUS[0]]  # the main tables: the default ILU
    L = ["# Inexact and adaptive inexact semismooth Newton: [JSC20] disk test", "",
         "Generated by `python -m ngcontact.studies.inexact` (`make inexact-study`) from the run directories in "
         "`runs/`. Newton-min, cold start X0 = [g, 0, 0], GMRES(100) + ILU (spilu drop 1e-5, fill 8) on the reduced "
         "SPD Newton system (`ngcontact/newton/linear.py` explains why and what ||R|| means), meshes: netgen unit disk "
         "with decreasing maxh. exact = GMRES to ||R||/||B|| <= 2e-12 (`--newton gmres`; `direct` = sparse "
         "Cholesky, same iterates), inexact = forcing ||R^{k,i}|| <= eta_k ||R^{k,0}||, eta_k = min(||Phi||/||F||, "
         "0.5), adaptive = [JSC20] criteria (gamma_alg = gamma_lin = 0.3, nu = 10) with eta_alg from the nu-step "
         "algebraic flux (`ngcontact/estimators/algebraic.py`). GMRES counts are all iterations performed "
         "(adaptive: including the nu look-ahead iterations of the last estimator evaluation of each step); "
         "`accepted` sums the indices i of the accepted iterates X^{k,i}.", ""]
    for order in (1, 2, "2f"):
        meshes = sorted({r["nelem"] for r in rows if r["order"] == order})
        if not meshes:
            continue
        title = ("P2 on meshes fitted to the contact boundary r = 1/sqrt 2 (`disk_fitted`; the P2 estimator is "
                 "sharp there: I_eff 1.03-1.19 on every level, `results/estimators/TABLES.md`)" if order == "2f" else f"P{order}")
        L += [f"## {title}: Newton / GMRES iterations, energy error, time per mesh", "",
              "| elements | ndof | mode | Newton | GMRES total | GMRES accepted | GMRES 1st step | energy error "
              "| err / err(direct) | eta_disc | eta_lin | eta_alg | solve [s] | of which estimators [s] |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for ne in meshes:
            base = next((r for r in rows if r["order"] == order and r["nelem"] == ne and r["newton"] == "direct"),
                        None)
            for mode in ("direct", "gmres", "inexact", "adaptive"):
                for r in rows:
                    if not (r["order"] == order and r["nelem"] == ne and r["newton"] == mode
                            and r["gamma_alg"] == 0.3 and r["gamma_lin"] == 0.3):
                        continue
                    acc = sum(int(it.get("gmres_accepted") or 0) for it in r["iterations"])
                    ratio = r["err_energy"] / base["err_energy"] if base else float("nan")
                    L.append(f"| {ne} | {r['ndof']} | {mode} "
                             f"{'' if r['converged'] else '(NOT converged)'} | {r['newton_its']} | "
                             f"{fmt(r.get('gmres_its'), '.0f')} | {acc if mode != 'direct' else '-'} | "
                             f"{fmt(r.get('gmres_first_step'), '.0f')} | {r['err_energy']:.6e} | "
                             f"{ratio:.4f} | {fmt(r.get('eta_disc_final'), '.3e')} | "
                             f"{fmt(r.get('eta_lin_final'), '.3e')} | {fmt(r.get('eta_alg_final'), '.3e')} | "
                             f"{r['time_solve_s']:.1f} | {fmt(r.get('time_estimate_newton_s'), '.1f')} |")
        L.append("")
        ad = [r for r in rows if r["order"] == order and r["newton"] == "adaptive" and r["gamma_alg"] == 0.3
              and r["gamma_lin"] == 0.3]
        worst = max((abs(r["err_energy"] / next(b for b in rows if b["order"] == order and b["nelem"] == r["nelem"]
                                                  and b["newton"] == "direct")["err_energy"] - 1) for r in ad),
                    default=float("nan"))
        L += [f"Adaptive vs direct energy error, {'P2 fitted' if order == '2f' else f'P{order}'}: largest "
              "relative difference over the meshes "
              f"{100 * worst:.2f} % (acceptance: <= 5 %).", ""]
    # gamma sensitivity
    for order, ne in sorted({(r["order"], r["nelem"]) for r in rows if r["newton"] == "adaptive"
                             and (r["gamma_alg"], r["gamma_lin"]) != (0.3, 0.3)}, key=lambda t: (t[0], -t[1])):
        g = [r for r in rows if r["order"] == order and r["newton"] == "adaptive"]
        L += [f"## (gamma_alg, gamma_lin) sensitivity, P{order}, {ne} elements", "",
              "| (gamma_alg, gamma_lin) | Newton | GMRES total | GMRES accepted | energy error | err / err(direct) "
              "| [JSC20] Newton / GMRES (35k) |", "|---|---|---|---|---|---|---|"]
        base = next((b for b in rows if b["order"] == order and b["nelem"] == ne and b["newton"] == "direct"), None)
        for ga, gl in GAMMAS:
            for r in g:
                if r["nelem"] == ne and r["gamma_alg"] == ga and r["gamma_lin"] == gl:
                    acc = sum(int(it.get("gmres_accepted") or 0) for it in r["iterations"])
                    ratio = r["err_energy"] / base["err_energy"] if base else float("nan")
                    L.append(f"| ({ga}, {gl}) | {r['newton_its']} | {r['gmres_its']} | {acc} | "
                             f"{r['err_energy']:.6e} | {ratio:.4f} | {PUBLISHED['gammas_35k'][(ga, gl)]} |")
        L.append("")
    L += ilu_lines
    # next to the published numbers
    L += ["## Next to the published numbers ([JSC20], REFERENCE.md)", "", "| quantity | [JSC20] | ngcontact |",
          "|---|---|---|"]

    def pick(order, target, mode, ga=0.3, gl=0.3):
        """The run of ``mode`` on the mesh (of this order) nearest to ``target`` elements."""
        meshes = sorted({r["nelem"] for r in rows if r["order"] == order})
        if not meshes:
            return None
        ne = min(meshes, key=lambda n: abs(math.log(n / target)))
        return next((r for r in rows if r["order"] == order and r["nelem"] == ne and r["newton"] == mode
                     and r["gamma_alg"] == ga and r["gamma_lin"] == gl), None)

    def note(order, target):
        meshes = sorted({r["nelem"] for r in rows if r["order"] == order})
        if not meshes:
            return ""
        ne = min(meshes, key=lambda n: abs(math.log(n / target)))
        far = max(ne / target, target / ne) > 1.5
        return f" ({ne} elements" + ("; no run near the published mesh size" if far else "") + ")"

    def triple(order, target, key):
        rr = [pick(order, target, m) for m in ("gmres", "inexact", "adaptive")]
        return " / ".join("-" if r is None else str(int(r[key])) for r in rr) + note(order, target)

    L.append(f"| P1 Newton exact / inexact / adaptive, ~8k | 15 / 46 / 14 | {triple(1, 8000, 'newton_its')} |")
    L.append(f"| P1 total GMRES exact / inexact / adaptive, ~35k | 3000 / 1660 / 670 | "
             f"{triple(1, 35000, 'gmres_its')} |")
    a, b = pick(1, 8000, "gmres"), pick(1, 8000, "adaptive")
    L.append("| P1 GMRES of the 1st Newton step, exact / adaptive | 220 / 10 | "
             + ("-" if a is None else str(int(a["gmres_first_step"]))) + " / "
             + ("-" if b is None else f"{int(b['gmres_first_step'])} (accepted iterate i = "
                f"{int(b['iterations'][1]['gmres_accepted'])})") + note(1, 8000) + " |")
    for mode, pub in (("gmres", "~8, 12, 15, 19, 22, 25, 28"), ("adaptive", "~8, 11, 14, 18, 21, 23, 27")):
        rr = sorted((r for r in rows if r["order"] == 1 and r["newton"] == mode and r["gamma_alg"] == 0.3
                     and r["gamma_lin"] == 0.3), key=lambda r: r["nelem"])
        L.append(f"| P1 Newton vs mesh, {mode} (2k...35k) | {pub} | "
                 + ", ".join(f"{r['newton_its']}" for r in rr) + " (" + ", ".join(str(r["nelem"]) for r in rr)
                 + " elements) |")
    L.append(f"| P2 Newton exact / inexact / adaptive, ~27k | 29 / 116 / 22 | {triple(2, 27000, 'newton_its')} |")
    L.append(f"| P2 total GMRES exact / inexact / adaptive, ~27k | 21000 / 7300 / 540 | "
             f"{triple(2, 27000, 'gmres_its')} |")
    L.append(f"| P2 fitted mesh, Newton exact / inexact / adaptive, ~27k | 29 / 116 / 22 | "
             f"{triple('2f', 27000, 'newton_its')} (gmres not run) |")
    L.append(f"| P2 fitted mesh, total GMRES exact / inexact / adaptive, ~27k | 21000 / 7300 / 540 | "
             f"{triple('2f', 27000, 'gmres_its')} |")
    L.append("")
    for order, data in logs.items():
        ev = data.get("adaptive_estimates", [])
        if ev:
            L += [f"Estimator evaluations of the adaptive run, P{order}, {data['nelem']} elements: {len(ev)} "
                  f"(plot: `estimators_p{order}.png`).", ""]
    expected = [f"p{o}-h{h:g}-{m}" for o, hs in ((1, P1_MAXH), (2, P2_MAXH)) for h in hs
                for m in ("direct", "gmres", "inexact", "adaptive")]
    expected += [f"p1-h{P1_MAXH[-1]:g}-adaptive-g{ga:g}-{gl:g}" for ga, gl in GAMMAS[1:]]
    expected += [f"p2f-h{h:g}-{m}" for h in P2_MAXH for m in FITTED_MODES]
    expected += [f"p2f-h{P2_MAXH[-1]:g}-{m}-{_ilu_tag(ilu)}" for ilu in ILUS[1:] for m in ("inexact", "adaptive")]
    expected += [f"p2-h{P2_MAXH[-1]:g}-{m}-{_ilu_tag(ILUS[-1])}" for m in ("inexact", "adaptive")]
    missing = [n for n in expected if not (out / "runs" / n / "summary.json").is_file()]
    if missing:
        L += ["Runs of the full study missing from `runs/` (interrupted or not run): " + ", ".join(missing) + ".", ""]
    (out / "TABLES.md").write_text("\n".join(L) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ngcontact.studies.inexact", description=__doc__.split("\n\n")[0])
    ap.add_argument("out", nargs="?", default="results/inexact")
    ap.add_argument("--quick", action="store_true", help="two coarse meshes only (smoke test)")
    ap.add_argument("--no-p2", action="store_true")
    ap.add_argument("--p1-only", action="store_true", help="P1 part only (to run P1 and P2 in two processes)")
    ap.add_argument("--p2-only", action="store_true", help="P2 part only")
    ap.add_argument("--tables-only", action="store_true",
                    help="only tables and plots from the run directories already in OUT/runs")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    p1 = QUICK_P1 if args.quick else P1_MAXH
    p2 = () if args.no_p2 else (QUICK_P2 if args.quick else P2_MAXH)
    dirs, logs = [], {}
    if args.tables_only:  # whatever runs exist (an interrupted study)
        dirs = sorted(d for d in (out / "runs").glob("*") if (d / "summary.json").is_file())
        for order in (1, 2):
            f = out / f"estimators_p{order}.json"
            if f.is_file():
                logs[order] = json.loads(f.read_text())
    else:
        # priority order: P1 on every mesh, the gamma table, the estimator logs, then P2
        if args.p2_only:
            p1 = ()
        for h in p1:
            for mode in ("direct", "gmres", "inexact", "adaptive"):
                dirs.append(_run(out, 1, h, mode))
        for ga, gl in GAMMAS[1:] if p1 else ():
            dirs.append(_run(out, 1, p1[-1], "adaptive", ga, gl, tag=f"p1-h{p1[-1]:g}-adaptive-g{ga:g}-{gl:g}"))
        if p1:
            logs[1] = _log_run(out, 1, p1[min(2, len(p1) - 1)])
        if p2 and not args.p1_only:
            logs[2] = _log_run(out, 2, p2[0])
        for h in p2 if not args.p1_only else ():
            for mode in ("direct", "gmres", "inexact", "adaptive"):
                dirs.append(_run(out, 2, h, mode))
        for h in p2 if not args.p1_only else ():
            for mode in FITTED_MODES:
                dirs.append(_run(out, 2, h, mode, fitted=True))
        for ilu in ILUS[1:] if p2 and not args.p1_only else ():
            for mode in ("inexact", "adaptive"):
                dirs.append(_run(out, 2, p2[-1], mode, fitted=True, ilu=ilu,
                                 tag=f"p2f-h{p2[-1]:g}-{mode}-{_ilu_tag(ilu)}"))
        # the strongest ILU also on the unfitted finest P2 mesh (where the adaptive error is furthest off)
        for mode in ("inexact", "adaptive") if p2 and not args.p1_only else ():
            dirs.append(_run(out, 2, p2[-1], mode, ilu=ILUS[-1], tag=f"p2-h{p2[-1]:g}-{mode}-{_ilu_tag(ILUS[-1])}"))
    rows = [_load(d) for d in dirs]
    with open(out / "all.csv", "w", newline="") as fh:
        keys = ["run", "order", "newton", "gamma_alg", "gamma_lin", "ilu", "nelem", "ndof", "newton_its", "gmres_its",
                "gmres_first_step", "gmres_max_step", "err_energy", "eta_disc_final", "eta_lin_final",
                "eta_alg_final", "n_estimates", "time_solve_s", "time_linear_s", "time_estimate_newton_s",
                "converged"]
        w = csv.writer(fh)
        w.writerow(keys)
        for r in rows:
            w.writerow([r.get(k, "") for k in keys])
    with open(out / "estimator_log.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["order", "nelem", "mode", "k", "i", "eta_disc", "eta_lin", "eta_alg", "res_alg", "stop_linear"])
        for order, data in logs.items():
            for mode in ("gmres", "inexact", "adaptive"):
                for e in data.get(mode + "_estimates", []):
                    w.writerow([order, data["nelem"], mode, e["k"], e["i"], e["eta_disc"], e["eta_lin"],
                                e["eta_alg"], e["res_alg"], int(e["stop_linear"])])
    for order, data in logs.items():
        _plot_estimators(data, out / f"estimators_p{order}.png",
                         f"[JSC20] disk, P{order}: error components along Newton-min (GMRES + ILU)")
    _plot_vs_mesh(rows, out / "gmres_vs_mesh.png")
    _tables(rows, logs, out)
    print(f"outputs: {out}/TABLES.md, all.csv, estimator_log.csv, estimators_p*.png, gmres_vs_mesh.png, runs/")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
