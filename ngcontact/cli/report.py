"""``ngcontact list``, ``plot``, ``table`` and the progress table of a run."""
from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["format_table", "cmd_list", "cmd_plot", "cmd_table"]


def format_table(rows, title="") -> str:
    cols = [("level", "{:>5d}"), ("ndof", "{:>8d}"), ("ndof_sc", "{:>8d}"), ("h", "{:>9.3e}"),
            ("err_energy", "{:>11.3e}"), ("rate_energy", "{:>6.2f}"), ("eta", "{:>10.3e}"), ("i_eff", "{:>6.3f}"),
            ("err_max_nodal", "{:>10.2e}"), ("newton_its", "{:>6d}"),
            ("active_nodes", "{:>7d}"), ("time_solve_s", "{:>9.2f}"), ("time_total_s", "{:>9.2f}")]
    heads = {"level": "level", "ndof": "ndof", "ndof_sc": "ndof_sc", "eta": "eta", "i_eff": "I_eff", "h": "h",
             "err_energy": "err_energy", "rate_energy": "rate", "err_max_nodal": "err_max", "newton_its": "newton",
             "active_nodes": "active", "time_solve_s": "solve[s]", "time_total_s": "total[s]"}
    cols = [(c, f) for c, f in cols if rows and c in rows[0]]
    width = [len(f.format(0 if "d" in f else 0.0)) for _, f in cols]
    lines = [title] if title else []
    lines.append(" ".join(heads[c].rjust(w) for (c, _), w in zip(cols, width)))
    for r in rows:
        cells = []
        for (c, f), w in zip(cols, width):
            v = r.get(c)
            if v is None or (isinstance(v, float) and v != v):
                cells.append("-".rjust(w))
            else:
                cells.append(f.format(v))
        lines.append(" ".join(cells))
    return "\n".join(lines)


def cmd_list(args) -> int:
    from ..scenes import list_scenes, load_scene

    for name in list_scenes():
        try:
            print(f"{name:14s} {load_scene(name).description}")
        except Exception as exc:  # a broken scene should not hide the others
            print(f"{name:14s} (cannot load: {exc})")
    return 0


def _run_dirs(dirs) -> list:
    for d in dirs:
        if not (Path(d) / "history.csv").is_file():
            raise ValueError(f"{d} is not a run directory (no history.csv)")
    return [Path(d) for d in dirs]


def cmd_plot(args) -> int:
    """The overlay figure; runs without an exact solution are drawn with their estimator eta (said on stderr),
    runs with neither are refused."""
    from ..plotting import plot_compare, plotted_column
    from ..results import read_history

    dirs = _run_dirs(args.dirs)
    for d in dirs:
        col = plotted_column(read_history(d / "history.csv"))
        if col is None:
            raise ValueError(f"{d} has no energy error (it needs an exact solution) and no estimator eta (run with "
                             f"--estimate): nothing to plot")
        if col == "eta":
            print(f"ngcontact: note: {d} has no exact solution: its curve is the estimator eta", file=sys.stderr)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    print(plot_compare(dirs, args.out, args.title))
    return 0


def cmd_table(args) -> int:
    from ..results import markdown_table

    text = markdown_table(_run_dirs(args.dirs))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text + "\n")
        print(args.out)
    else:
        print(text)
    return 0
