"""The parabolic study ([CMAME20] tests 6.1, 6.2; the manufactured solution; adaptive time steps) ->
``OUT/REPORT.md``.

``python -m ngcontact.studies.parabolic OUT [--size quick|full]``.  Every experiment is cached as
``OUT/runs/NAME.json`` (written when it finishes; a killed study redoes only the missing ones), and
the report is assembled from those files.  ``full`` uses the sizes of [CMAME20] (P1 on ~19k
triangles, P2 on ~4k, 300 steps); ``quick`` the sizes that fit a session on a shared 2-core machine
(the report's header states which).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path


from ..rates import fitted_rate
from ..results import git_revision
from ..results.files import atomic_write
from ..scenes import load_scene
from ..timestepping.driver import ParabolicOptions, run_parabolic
from ..timestepping.run import scene_mesh

__all__ = ["SIZES", "PROVENANCE", "run_study", "write_report", "disk_onset_radial", "read_provenance"]

SIZES = {
    "quick": dict(disk_levels=(0, 1), rings_maxh=0.05, rings_p2_maxh=0.1, table_maxh=0.1, table_p2_maxh=0.2,
                  table_T=0.1, mms_levels=(0, 1, 2, 3), mms_p2_levels=(0, 1, 2), mms_dt_level=1,
                  adapt_maxh=0.15),
    "full": dict(disk_levels=(0, 1, 2), rings_maxh=0.02, rings_p2_maxh=0.045, table_maxh=0.02, table_p2_maxh=0.045,
                 table_T=0.3, mms_levels=(0, 1, 2, 3, 4), mms_p2_levels=(0, 1, 2, 3), mms_dt_level=2,
                 adapt_maxh=0.05),
}

#: [CMAME20] test 6.2, cumulative counts (REFERENCE.md "Parabolic [CMAME20]"): variant -> (Newton, GMRES) adaptive, exact
PUBLISHED = {"min-p1": ("-", "~7000", "-", "~19000"), "fb-p1": ("~700", "~7000", "~1500", "~27000"),
             "min-p2": ("585", "8760", "912", "27085")}

#: manufactured solution, refinement in h and dt together: order p -> (dt on level 0, T); level l uses
#: dt0 / 2^(p l), so that the spatial O(h^p) and the temporal O(dt) parts of the error (and of the
#: estimate) decrease at the same rate
MMS_H = {1: (0.02, 0.1), 2: (0.01, 0.04)}
#: adaptive time steps (test 6.2): fixed steps dt, and adaptive runs from dt0 = 1e-3 with these safety factors
#: (ParabolicOptions.safety, dt_rule: ngcontact.timestepping.driver)
ADAPT_FIXED_DT = (1e-3, 2e-3, 4e-3, 8e-3, 1.6e-2)
ADAPT_SAFETY = (0.8, 0.4, 0.2, 0.1, 0.05, 0.025)  # dt_rule 'balance'
EQUI_SAFETY = (1.0, 0.4, 0.2, 0.1, 0.04, 0.02)  # dt_rule 'equidistribute'
#: test 6.1 continued to this final time (the distance to the stationary solution decays exponentially in t)
DISK_LONG_T = 1.5


def disk_onset_radial(n: int = 4000, dt: float = 1e-5):
    """Contact onset of test 6.1 from the radial problem, independent of the FEM code: before contact
    w = u1 - u2 solves w_t - w_rr - w_r / r = f1 - f2 (lam = 0), w = g on r = 1, w(0) = g; finite volumes
    on n cells of (0, 1), Crank-Nicolson with step dt.  Returns (t*, r*): the first time min w = 0
    (linear in t between the steps) and where."""
    import numpy as np
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    g, rho = 0.05, 1 / math.sqrt(2)
    c = math.sqrt(2) / (math.sqrt(2) - 1)
    h = 1.0 / n
    r = np.arange(n) * h  # unknowns at r_0 .. r_{n-1}; r_n = 1 carries w = g
    rr = np.maximum(r, h)
    f = np.where(r < rho, -4 * g, -8 * g + g * (1 + 8 * rr - 18 * rr ** 2) * c / rr)
    lo = (r[1:] - h / 2) / (r[1:] * h * h)
    up = np.concatenate([[4 / h ** 2], (r[1:-1] + h / 2) / (r[1:-1] * h * h)])  # r = 0: 4 (w_1 - w_0) / h^2
    main = np.concatenate([[-4 / h ** 2], -2 / h ** 2 * np.ones(n - 1)])
    L = sp.diags([lo, main, up], [-1, 0, 1], format="csc")
    src = f.copy()
    src[-1] += (1 - h / 2) / ((1 - h) * h * h) * g
    eye = sp.identity(n, format="csc")
    lhs, rhs = spla.splu((eye - 0.5 * dt * L).tocsc()), (eye + 0.5 * dt * L).tocsr()
    w, t = np.full(n, g), 0.0
    while True:
        w_new = lhs.solve(rhs @ w + dt * src)
        if w_new.min() <= 0:
            m0, m1 = w.min(), w_new.min()
            return float(t + dt * m0 / (m0 - m1)), float(r[np.argmin(w_new)])
        w, t = w_new, t + dt


def _run(scene, mesh, **kw):
    t0 = time.perf_counter()
    res = run_parabolic(scene.problem, mesh, ParabolicOptions(**kw), regions=getattr(scene.module, "REGIONS", None),
                        space_axis=getattr(scene.module, "SPACE_AXIS", "r"))
    s = dict(res.summary, wall_s=time.perf_counter() - t0)
    return res, s


def _energy(K, d) -> float:
    return math.sqrt(max(float(d @ (K @ d)), 0.0))


def _cached(out: Path, name: str, compute, say, revision=None):
    """The result of experiment ``name``: read from ``OUT/runs/NAME.json``, or computed and written there; a computed
    one is entered in ``OUT/runs/PROVENANCE.json`` with ``revision`` (the code it ran with) and the time it finished."""
    path = out / "runs" / f"{name}.json"
    if path.is_file():
        return json.loads(path.read_text())
    say(f"[parabolic study] {name} ...")
    val = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, json.dumps(val, indent=1, default=float) + "\n")
    prov = read_provenance(out)
    prov[name] = {"revision": revision or "unknown",
                  "finished": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    atomic_write(out / "runs" / PROVENANCE, json.dumps(prov, indent=1, sort_keys=True) + "\n")
    say(f"[parabolic study] {name} done")
    return val


#: file of ``OUT/runs`` that records, per experiment, the code revision it was computed with
PROVENANCE = "PROVENANCE.json"


def read_provenance(out) -> dict:
    """Experiment name -> {"revision", "finished"} of ``OUT/runs/PROVENANCE.json`` ({} without that file)."""
    path = Path(out) / "runs" / PROVENANCE
    return json.loads(path.read_text()) if path.is_file() else {}


def provenance_lines(out, names) -> list:
    """The report's provenance section: the revision and finishing time of every experiment of ``names`` (a cached
    result without an entry was computed before the study recorded them: its code is unknown)."""
    prov = read_provenance(out)
    revs = {prov.get(n, {}).get("revision", "not recorded") for n in names}
    if revs == {"not recorded"}:
        head = "No experiment has a recorded revision (all were cached before the study kept provenance)."
    elif len(revs) == 1:
        head = f"Every experiment was computed with revision {revs.pop()}."
    else:
        head = ("The experiments come from several code revisions (a cached result is reused until its file is "
                "deleted): compare with care.")
    L = ["## Provenance", "", head, "", "| experiment | revision | finished |", "|---|---|---|"]
    for n in sorted(names):
        e = prov.get(n)
        L.append(f"| {n} | {e['revision']} | {e['finished']} |" if e else
                 f"| {n} | not recorded (cached before the study kept provenance) | - |")
    return L + [""]


def run_study(out, size: str = "quick", say=print) -> dict:
    """Run (or read back) every experiment; returns name -> result."""
    out, z = Path(out), SIZES[size]
    revision = git_revision()  # of the code this process imported (edits made while it runs do not count)

    def cached(name, compute, say):
        return _cached(out, name, compute, say, revision)

    disk, rings, mms = (load_scene(n) for n in ("parabolic_disk", "parabolic_rings", "parabolic_manufactured"))
    R = {}
    for lev in z["disk_levels"]:
        R[f"disk-l{lev}"] = cached(f"disk-l{lev}", lambda lev=lev: _run(
            disk, scene_mesh(disk, {"level": lev}), dt=1e-3)[1], say)
        R[f"disk-l{lev}-long"] = cached(f"disk-l{lev}-long", lambda lev=lev: _run(
            disk, scene_mesh(disk, {"level": lev}), dt=1e-3, t_final=DISK_LONG_T)[1], say)
    R["disk-onset-radial"] = cached("disk-onset-radial", lambda: dict(zip(("t", "r"), disk_onset_radial())),
                                     say)
    R["rings-onset"] = cached("rings-onset", lambda: _run(
        rings, scene_mesh(rings, {"maxh": z["rings_maxh"]}), dt=1e-3)[1], say)

    def table(cfun, order, maxh, krylov="gmres"):
        mesh = scene_mesh(rings, {"maxh": maxh})
        rows, xs = {}, {}
        for mode in ("direct", "gmres", "inexact", "adaptive"):
            kw = dict(krylov=krylov) if mode != "direct" else {}
            res, s = _run(rings, mesh, dt=1e-3, t_final=z["table_T"], order=order, cfun=cfun, newton=mode, **kw)
            rows[mode], xs[mode] = s, res.x
            K = res.stepper.K
        ref = _energy(K, xs["direct"])
        for mode in rows:
            rows[mode]["rel_diff_u_T"] = _energy(K, xs[mode] - xs["direct"]) / ref
        return rows
    R["table-min-p1"] = cached("table-min-p1", lambda: table("min", 1, z["table_maxh"]), say)
    R["table-fb-p1"] = cached("table-fb-p1", lambda: table("fb", 1, z["table_maxh"]), say)
    R["table-min-p2"] = cached("table-min-p2", lambda: table("min", 2, z["table_p2_maxh"]), say)
    R["table-min-p1-cg"] = cached("table-min-p1-cg", lambda: table("min", 1, z["table_maxh"], "cg"), say)

    def mms_h(order, levels):
        dt0, T = MMS_H[order]
        return [_run(mms, scene_mesh(mms, {"level": lev}), order=order, dt=dt0 / 2 ** (order * lev), t_final=T,
                     estimate=True)[1] for lev in levels]
    R["mms-h-p1"] = cached("mms-h-p1", lambda: mms_h(1, z["mms_levels"]), say)
    R["mms-h-p2"] = cached("mms-h-p2", lambda: mms_h(2, z["mms_p2_levels"]), say)

    def mms_dt():
        mesh = scene_mesh(mms, {"level": z["mms_dt_level"]})
        out_rows, xs = [], []
        for dt in (0.1, 0.05, 0.025, 0.0125, 0.00625):
            res, s = _run(mms, mesh, order=2, dt=dt, t_final=0.4)
            xs.append(res.x)
            out_rows.append(dict(dt=dt, err=s["err_spacetime"], nelem=s["nelem"], wall_s=s["wall_s"]))
            K = res.stepper.K
        for i in range(len(xs) - 1):  # Richardson: |||u_h^dt(T) - u_h^{dt/2}(T)|||, O(dt) for backward Euler
            out_rows[i]["diff_half"] = _energy(K, xs[i] - xs[i + 1])
        return out_rows
    R["mms-dt"] = cached("mms-dt", mms_dt, say)

    def adaptive_steps(rule, safeties, mesh):
        return {f"{sf:g}": _run(rings, mesh, dt=ADAPT_FIXED_DT[0], estimate=True, adaptive_dt=True, safety=sf,
                                dt_rule=rule)[1] for sf in safeties}

    def adapt():
        mesh = scene_mesh(rings, {"maxh": z["adapt_maxh"]})
        fixed = {f"{dt:g}": _run(rings, mesh, dt=dt, estimate=True)[1] for dt in ADAPT_FIXED_DT}
        return {"fixed": fixed, "adaptive": adaptive_steps("balance", ADAPT_SAFETY, mesh)}
    R["adapt"] = cached("adapt-sweep", adapt, say)
    R["adapt-equi"] = cached("adapt-equi", lambda: adaptive_steps(
        "equidistribute", EQUI_SAFETY, scene_mesh(rings, {"maxh": z["adapt_maxh"]})), say)
    return R


def _fixed_steps_at(fixed: dict, eta: float):
    """Steps of a fixed-dt run with final estimate ``eta``: linear interpolation in (eta_st, log steps) between
    the runs of ``fixed`` (None outside their range)."""
    pts = sorted((s["eta_st"], math.log(s["steps"])) for s in fixed.values())
    for (e0, l0), (e1, l1) in zip(pts, pts[1:]):
        if e0 <= eta <= e1:
            return math.exp(l0 + (l1 - l0) * (eta - e0) / (e1 - e0)) if e1 > e0 else math.exp(l0)
    return None


def _f(v, spec=".3e"):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return format(v, spec) if isinstance(v, float) else str(v)


def write_report(out, R: dict, size: str) -> Path:
    z = SIZES[size]
    L = [f"# Parabolic two-membrane contact ([CMAME20]): study `{size}`", "",
         "Generated by `python -m ngcontact.studies.parabolic` (`make parabolic-study` for the `full` sizes). "
         "Backward Euler, FEM P_p, consistent mass matrix, Newton tolerance 1e-10 (||Phi||/||F||, each step solved for "
         "its increment X^n - X^{n-1}: F = F(t_n) - K X^{n-1}); "
         "GMRES + ILU (drop 1e-5, fill 8) for the Krylov modes; adaptive mode gamma_alg = gamma_lin = 1e-3.  "
         "Seconds (columns s) are wall times of single-threaded runs on a shared 2-core machine, several experiments "
         "at once: compare the counts, not the times, across rows; the provenance section at the end names the "
         "code revision of each experiment.", "",
         "## Test 6.1 (disk data, X0 = [g, 0, 0], dt = 1e-3; mesh fitted to r = 1/sqrt(2))", "",
         "[CMAME20] runs to T = 0.3; the rows with T = " + f"{DISK_LONG_T}" + " continue the same run so that "
         "the transient has decayed and only the spatial discretization error is left.", "",
         "| level | triangles | T | contact onset t | dist. to stationary exact at T | stationary discr. error | "
         "dist. to stationary discrete at T | Newton | factorizations |", "|---|---|---|---|---|---|---|---|---|"]
    for k in sorted(k for k in R if k.startswith("disk-l")):
        s, T = R[k], (DISK_LONG_T if k.endswith("-long") else 0.3)
        L.append(f"| {k[6:].split('-')[0]} | {s['nelem']} | {T} | {_f(s.get('onset_disk'), '.3f')} | "
                 f"{_f(s['dist_stationary_T'])} | {_f(s['err_stationary_discrete'])} | "
                 f"{_f(s['dist_stationary_discrete_T'])} | {s['newton_total']} | {s['factorizations_total']} |")
    o = R["disk-onset-radial"]
    L += ["", f"Onset of the continuous problem, from the radial equation of w = u1 - u2 before contact "
          f"(`disk_onset_radial`: finite volumes, 4000 cells, Crank-Nicolson dt = 1e-5, independent of the FEM code): "
          f"t* = {o['t']:.4f} at r = {o['r']:.3f}.  The FEM onset is the first step (dt = 1e-3) with an active node.", ""]
    s = R["rings-onset"]
    L += ["", f"## Test 6.2 (rings), P1, dt = 1e-3, maxh = {z['rings_maxh']} ({s['nelem']} triangles)", "",
          "| region | measured onset t | [CMAME20] |", "|---|---|---|",
          f"| disk r <= 1/5 | {_f(s.get('onset_disk'), '.3f')} | ~0.011 |",
          f"| ring 2/5 <= r <= 3/5 | {_f(s.get('onset_ring'), '.3f')} | ~0.060 |", "",
          f"Newton {s['newton_total']} in {s['steps']} steps, {s['factorizations_total']} factorizations, "
          f"{_f(s['wall_s'], '.0f')} s.", "",
          f"## Test 6.2: cumulative iterations over T = {z['table_T']} (dt = 1e-3)", "",
          "| variant | mesh | mode | Newton | Krylov (GMRES or CG) | rel. diff. of u(T) vs direct (energy) | converged | s | "
          "[CMAME20] Newton / GMRES |", "|---|---|---|---|---|---|---|---|---|"]
    for key, label in (("min-p1", "Newton-min P1"), ("fb-p1", "Newton-FB P1"), ("min-p2", "Newton-min P2"),
                       ("min-p1-cg", "Newton-min P1, CG + AMG")):
        pub = PUBLISHED[key.removesuffix("-cg")]
        for mode, row in R[f"table-{key}"].items():
            ref = {"adaptive": f"{pub[0]} / {pub[1]}", "gmres": f"{pub[2]} / {pub[3]} (exact)"}.get(mode, "")
            L.append(f"| {label} | {row['nelem']} tri | {mode} | {row['newton_total']} | {row['gmres_total']} | "
                     f"{_f(row['rel_diff_u_T'], '.1e')} | {row['converged']} | {_f(row['wall_s'], '.0f')} | {ref} |")
    L += ["", "`gmres` is the \"exact\" mode (||R||/||B|| <= 2e-12); the published exact runs used GMRES + ILU(0) "
          "and partly hit their iteration cap, so their counts are not comparable one to one.  The CG + AMG rows "
          "(`--krylov cg`) solve the same reduced SPD systems with CG and pyamg's Ruge-Stueben multigrid under the "
          "same stopping rules; their Krylov column counts CG iterations.", "",
          "## Manufactured solution (moving free boundary x = 0.2 + 0.5 t), space-time error "
          "(||e(T)||^2 + int |||e|||^2)^(1/2)", ""]
    L += ["Refinement in h and dt together (level l: dt = dt0 / 2^(p l)), so that the spatial and temporal parts "
          "of the error and of the estimate decrease at the same rate O(h^p); at a fixed dt the temporal data term "
          "eta_f (a Friedrichs-weighted L2 bound of f(t) - f(t_n)) stays constant and I_eff grows with the level.", ""]
    for key, p in (("mms-h-p1", 1), ("mms-h-p2", 2)):
        dt, T = MMS_H[p]
        L += [f"P{p}, dt0 = {dt}, T = {T}:", ""]
        rows = R[key]
        L += ["| level | triangles | dt | error | rate | eta_st | I_eff | eta_sp | eta_tm | "
              "eta_f | eta_C | bound proven |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for i, s in enumerate(rows):
            rate = "-" if i == 0 else _f(math.log(rows[i - 1]["err_spacetime"] / s["err_spacetime"]) / math.log(2), ".2f")
            L.append(f"| {i} | {s['nelem']} | {dt / 2 ** (p * i):.3g} | {_f(s['err_spacetime'])} | {rate} | "
                     f"{_f(s.get('eta_st'))} | "
                     f"{_f(s.get('i_eff'), '.2f')} | {_f(s.get('eta_sp'))} | {_f(s.get('eta_tm'))} | {_f(s.get('eta_f'))} | "
                     f"{_f(s.get('eta_C'))} | {s.get('bound_proven')} |")
        h = [0.5 ** i for i in range(len(rows))]
        if p > 1:
            L += ["", "bound proven = False: for p >= 2 the discrete gap may be negative between the nodes, which the "
                  "guaranteed-bound argument does not cover (ngcontact.timestepping.estimate); the numbers are the "
                  "same estimator."]
        L += ["", f"fitted rate in h (last 3 levels): {fitted_rate(h, [s['err_spacetime'] for s in rows]):.2f}", ""]
    rows = R["mms-dt"]
    L += [f"Time convergence, P2 on {rows[0]['nelem']} triangles, T = 0.4: the error against the exact solution "
          "is dominated by the spatial error, so the order in dt is measured on the difference of the solutions at T "
          "for dt and dt/2 on the same mesh (Richardson; O(dt) for backward Euler):", "",
          "| dt | error vs exact | |||u_h^dt(T) - u_h^dt/2(T)||| | ratio |", "|---|---|---|---|"]
    for i, r in enumerate(rows):
        d = r.get("diff_half")
        ratio = _f(rows[i - 1]["diff_half"] / d, ".2f") if i and d else "-"
        L.append(f"| {r['dt']} | {_f(r['err'])} | {_f(d)} | {ratio} |")
    a = R["adapt"]
    fixed = a["fixed"]
    ref = fixed[min(fixed, key=float)]  # dt = 1e-3, [CMAME20]'s step
    nelem = ref["nelem"]
    L += ["", f"## Adaptive time steps, test 6.2, P1, {nelem} triangles, T = 0.3", "",
          "Fixed steps against adaptive steps (from dt0 = 1e-3, dt in [dt0/64, 64 dt0]; rules of "
          "`ngcontact.timestepping.driver`: `balance` aims at eta_tm,n = safety x eta_sp,n, `equidistribute` (the "
          "default) at equal contributions dt_n A_n B_n of the steps to the estimate); compare the number of steps "
          "at equal final estimate eta_st.", "",
          "| run | steps | rejected | Newton | eta_st at T | eta_sp | eta_tm | s | fixed steps at this eta_st |",
          "|---|---|---|---|---|---|---|---|---|"]
    for label, runs in (("fixed dt = ", fixed), ("balance, safety = ", a["adaptive"]),
                        ("equidistribute, safety = ", R["adapt-equi"])):
        for k, s in runs.items():
            eq = "" if runs is fixed else _f(_fixed_steps_at(fixed, s["eta_st"]), ".0f")
            L.append(f"| {label}{k} | {s['steps']} | {s['rejected_steps']} | {s['newton_total']} | {_f(s['eta_st'])} | "
                     f"{_f(s['eta_sp'])} | {_f(s['eta_tm'])} | {_f(s['wall_s'], '.0f')} | {eq} |")
    L += ["", "Last column: the number of fixed steps that gives the same final estimate, interpolated linearly in "
          "(eta_st, log steps) between the fixed runs (- outside their range)."]
    L += ["", "The mesh is fixed during a run (NGSolve has no coarsening).", ""]
    L += provenance_lines(out, [f.stem for f in sorted((Path(out) / "runs").glob("*.json")) if f.name != PROVENANCE])
    path = Path(out) / "REPORT.md"
    atomic_write(path, "\n".join(L))
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ngcontact.studies.parabolic", description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--size", choices=sorted(SIZES), default="quick")
    a = ap.parse_args(argv)
    R = run_study(a.out, a.size)
    print(f"wrote {write_report(a.out, R, a.size)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
