"""Constraint node sets report: ``python -m ngcontact.studies.constraints OUT.md RUN_DIR...``.

Writes ``OUT.md`` (``make constraints-study``: ``results/fem/CONSTRAINTS.md``) from

* the node sets of :mod:`ngcontact.discretizations.nodesets`, computed here: the weights
  (psi_l, 1)_K / |K| of the cardinal functions per entity (vertex, edge, interior) and the
  Lebesgue constants, p = 1..6, equispaced lattice and positive set;
* the run directories written by ``python -m ngcontact run ... --constraints nodal|equispaced``
  (their ``history.csv`` and ``summary.json`` only): energy errors and rates per level, side by side
  for the two node sets, and the estimator columns of the ``--estimate`` runs;
* the acceptance checks of issue 23, evaluated on those runs.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from ..discretizations.nodesets import NODE_SETS, cardinal_weights, lattice, lebesgue_constant, reference_nodes
from ..results.files import atomic_write
from .compare import load_runs
from .tables import fmt, md_row, report_main

__all__ = ["node_set_table", "write_report", "main"]

_NAMES = {"nodal": "positive nodes (nodal)", "equispaced": "equispaced lattice", "bernstein": "Bernstein"}
_ORDER = {"equispaced": 0, "nodal": 1, "bernstein": 2}


def node_set_table(degrees=range(1, 7)) -> list:
    """Markdown lines: weights per entity (min..max) and Lebesgue constant of every node set and degree."""
    out = [md_row(["p", "node set", "vertex weights", "edge weights", "interior weights", "min weight",
                   "Lebesgue constant"]), "|" + "---|" * 7]
    for p in degrees:
        entity = (lattice(p) > 0).sum(axis=1)
        for kind in NODE_SETS:
            b = reference_nodes(p, kind)
            w = cardinal_weights(b)
            cells = []
            for e in (1, 2, 3):
                we = np.round(np.unique(np.round(w[entity == e], 12)), 4) + 0.0  # + 0.0: no -0.0 cells
                cells.append(", ".join(f"{v:.4f}" for v in we) if len(we) else "-")
            out.append(md_row([p, kind, *cells, f"{w.min():.4f}" + (" **<0**" if w.min() < -1e-12 else ""),
                               f"{lebesgue_constant(b):.2f}"]))
    return out


def _rates(rows) -> list:
    e = [r.get("err_energy") for r in rows]
    return [math.log2(a / b) if a and b else float("nan") for a, b in zip(e, e[1:])]


def _error_tables(runs, start: str) -> list:
    out = []
    plain = [r for r in runs if not r["options"].get("estimate") and r["options"]["start"] == start]
    for scene in sorted({r["scene"] for r in plain}):
        sel = sorted((r for r in plain if r["scene"] == scene),
                     key=lambda r: (r["options"]["order"], r["label"], _ORDER[r["options"].get("constraints", "nodal")]))
        nlev = max(len(r["rows"]) for r in sel)
        out += [f"### {scene}: energy error per level ({start} start)", "",
                md_row(["method", "p", "constraints", *[f"T{j}" for j in range(nlev)], "rates", "Newton its"]),
                "|" + "---|" * (nlev + 5)]
        for r in sel:
            errs = [fmt(q.get("err_energy")) for q in r["rows"]] + ["-"] * (nlev - len(r["rows"]))
            out.append(md_row([r["label"], r["options"]["order"], _NAMES[r["options"].get("constraints", "nodal")],
                               *errs, ", ".join(fmt(v, ".2f") for v in _rates(r["rows"])),
                               ", ".join(str(q["newton_its"]) for q in r["rows"])]))
        out.append("")
    return out


def _estimate_tables(runs) -> list:
    out = []
    cols = ["err_energy", "eta", "i_eff", "eta_nonc1", "eta_nonc2", "eta_nonc3", "eta_C"]
    for r in (r for r in runs if r["options"].get("estimate")):
        o = r["options"]
        out += [f"### {r['scene']}: {r['label']} P{o['order']} --estimate, {_NAMES[o.get('constraints', 'nodal')]}", "",
                md_row(["level", "ndof", *cols]), "|" + "---|" * (len(cols) + 2)]
        for q in r["rows"]:
            out.append(md_row([f"T{q['level']}", q["ndof"], *[fmt(q.get(c), ".3f" if c == "i_eff" else ".3e")
                                                               for c in cols]]))
        out.append("")
    return out


def _find(runs, scene, disc, constraints, estimate=False):
    for r in runs:
        o = r["options"]
        if (r["scene"], o["disc"], o.get("constraints", "nodal"), bool(o.get("estimate")), o["start"]) == \
                (scene, disc, constraints, estimate, "nested") and o["order"] == 4:
            return r
    return None


def acceptance(runs) -> list:
    """Markdown lines: the P4 acceptance checks of issue 23 on the nodal runs (``not run`` if absent)."""
    out = [md_row(["check", "target", "measured", "met"]), "|---|---|---|---|"]

    def line(name, target, value, ok):
        out.append(md_row([name, target, value, "yes" if ok else "**no**"]))

    fem = _find(runs, "test1", "fem", "nodal")
    if fem and len(fem["rows"]) >= 5:
        r = _rates(fem["rows"])
        line("test 1 FEM P4 rate T2->T3, T3->T4", ">= 3.8", f"{r[2]:.2f}, {r[3]:.2f}", min(r[2], r[3]) >= 3.8)
        e4 = fem["rows"][4]["err_energy"]
        line("test 1 FEM P4 error T4", "<= 3e-9", fmt(e4), e4 <= 3e-9)
    else:
        out.append(md_row(["test 1 FEM P4 to T4", "", "not run", "-"]))
    for disc in ("hho", "sipg"):
        run = _find(runs, "test1", disc, "nodal")
        if run and len(run["rows"]) >= 4:
            r = _rates(run["rows"])[2]
            line(f"test 1 {disc.upper()} P4 rate T2->T3", ">= 3.8", f"{r:.2f}", r >= 3.8)
        else:
            out.append(md_row([f"test 1 {disc.upper()} P4 to T3", "", "not run", "-"]))
    est = _find(runs, "test1", "fem", "nodal", estimate=True)
    if est and len(est["rows"]) >= 4:
        i3 = est["rows"][3]["i_eff"]
        line("test 1 FEM P4 I_eff at T3", "<= 1.2", f"{i3:.3f}", i3 <= 1.2)
    else:
        out.append(md_row(["test 1 FEM P4 --estimate to T3", "", "not run", "-"]))
    return out


def write_report(path, dirs) -> str:
    """Write the report to ``path`` (atomically) and return its text."""
    runs = load_runs(dirs)
    text = "\n".join([
        "# Contact constraints at nodes with positive weights (issue 23)", "",
        "Generated by `make constraints-study` (`python -m ngcontact.studies.constraints`): the node-set table is",
        "computed here, the other tables are read from the run directories.  `--constraints nodal` (default) puts",
        "the constraints on a node set whose Lagrange basis functions have no negative integral; `equispaced` on",
        "the lattice of [CAMWA21] (the same nodes for p = 1, 2, 3, 5); `bernstein` (FEM) on the Bernstein coefficients of",
        "the gap (u1h >= u2h everywhere) with the multiplier dual to the Bernstein basis.", "",
        "## Weights (psi_l, 1)_K / |K| of the cardinal functions and Lebesgue constants", "",
        *node_set_table(), "",
        "p = 2: the node set is forced (vertices and edge midpoints) and the vertex weight is 0: not negative, so a",
        "constant multiplier is still representable (X3 = 0 at the vertices).", "",
        "## Acceptance checks (nodal runs)", "", *acceptance(runs), "",
        "## Runs", "", *_error_tables(runs, "nested"), *_error_tables(runs, "cold"), *_estimate_tables(runs)]) + "\n"
    atomic_write(Path(path), text)
    return text


def main(argv=None) -> int:
    return report_main("constraints", "OUT.md RUN_DIR...", write_report, argv)


if __name__ == "__main__":
    sys.exit(main())
