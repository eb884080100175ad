"""The stability suite: a matrix of stiff and extreme cases, each checked against one rule.

**The rule**: every run either converges with a valid exit certificate (:mod:`ngcontact.algebra.certificate`)
on every level, or stops with a named reason (a Newton failure, or data refused with a message naming the
field) -- never a finished run with a wrong answer, never NaN.  "Wrong answer" is checked where it can be:

* scaled copies of a problem (:func:`~ngcontact.problems.manufactured.scale_problem`: u times s, or the
  tensions times t with u unchanged) must reproduce the unscaled run: energy error / (s sqrt t) and
  max nodal error / s equal to the baseline's within :data:`SCALE_RTOL`;
* every other case with an exact solution must converge: the energy error of the last level at most
  :data:`DECAY` times that of the level before.

``python -m ngcontact.studies.stability [--quick] OUT.md`` runs the matrix (``make stability``:
``results/STABILITY.md``); ``--quick`` is the subset that ``tests/test_stability.py`` also runs.
"""
from __future__ import annotations

import math
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

__all__ = ["Case", "CASES", "run_case", "check_rule", "main", "SCALE_RTOL", "DECAY"]

#: relative agreement of a scaled run with its baseline (errors; the Newton tolerance is 1e-10)
SCALE_RTOL = 1e-6
#: a converging run's last energy error is at most this times the previous one (rate > 0.15 at h/2)
DECAY = 0.9


@dataclass
class Case:
    name: str
    group: str
    problem: Callable[[], object]
    options: dict
    baseline: Optional[str] = None  # name of the unscaled case this one must reproduce
    data: float = 1.0               # scale of u relative to the baseline
    tension: float = 1.0            # scale of the tensions relative to the baseline
    quick: bool = False             # part of the fast subset (tests/test_stability.py)


# ---------------------------------------------------------------- problems
def _square_mesh(kind: str):
    """A coarse user mesh of the unit square: 'distorted' (8 x 8 grid, interior vertices moved by up to
    0.3 h, fixed seed), 'anisotropic' (32 x 2 cells: aspect ratio 16), 'sliver' (4 x 4 grid whose centre
    vertex sits 1e-3 h from a diagonal: near-degenerate triangles)."""
    import netgen.meshing as ngm

    nx, ny = {"distorted": (8, 8), "anisotropic": (32, 2), "sliver": (4, 4)}[kind]
    gx, gy = np.meshgrid(np.linspace(0, 1, nx + 1), np.linspace(0, 1, ny + 1))
    X = np.column_stack([gx.ravel(), gy.ravel()])
    idx = lambda i, j: i + (nx + 1) * j  # noqa: E731
    inner = (X[:, 0] > 0) & (X[:, 0] < 1) & (X[:, 1] > 0) & (X[:, 1] < 1)
    if kind == "distorted":
        rng = np.random.default_rng(7)
        X[inner] += rng.uniform(-0.3, 0.3, size=(inner.sum(), 2)) / nx
    elif kind == "sliver":
        X[idx(2, 2)] = [0.5 + 1e-3 / 4, 0.5 - 1e-3 / 4]  # next to the diagonal of the cell below-right
    T = []
    for j in range(ny):
        for i in range(nx):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            T += [[a, b, c], [a, c, d]]
    mesh = ngm.Mesh(dim=2)
    mesh.AddPoints(np.ascontiguousarray(X))
    dom = mesh.AddRegion("domain", dim=2)
    mesh.AddElements(dim=2, index=dom, data=np.array(T, dtype=np.int32), base=0)
    bnd = mesh.AddRegion("boundary", dim=1)
    segs = []
    for i in range(nx):
        segs += [[idx(i, 0), idx(i + 1, 0)], [idx(i + 1, ny), idx(i, ny)]]
    for j in range(ny):
        segs += [[idx(nx, j), idx(nx, j + 1)], [idx(0, j + 1), idx(0, j)]]
    mesh.AddElements(dim=1, index=bnd, data=np.array(segs, dtype=np.int32), base=0)
    return mesh


def _disk(**kw):
    from ..problems.manufactured import disk_contact
    return lambda: disk_contact(**kw)


def _scaled(make, data=1.0, tension=1.0):
    from ..problems.manufactured import scale_problem
    return lambda: scale_problem(make(), data=data, tension=tension)


def _on_mesh(make, kind):
    from ..domains import MeshDomain

    def build():
        p = make()
        from dataclasses import replace
        return replace(p, domain=MeshDomain(coarse=_square_mesh(kind), label=kind))
    return build


def _no_contact():
    from ..problems import ExactSolution, TwoMembraneProblem
    from ..domains import CrissCrossSquare
    from ngsolve import exp, sin, x, y
    h = 0.05 * exp(x) * sin(y)  # harmonic: f = 0
    u1, u2 = 0.3 + h, -h  # gap 0.3 + 2 h >= 0.3 on the unit square
    return TwoMembraneProblem(domain=CrissCrossSquare(n0=4), f1=0.0, f2=0.0, g1=u1, g2=u2,
                              exact=ExactSolution(u1=u1, u2=u2, lam=0.0), name="no-contact")


def _scene_problem(name):
    def build():
        from ..scenes import load_scene
        return load_scene(name).problem
    return build


_ex9 = _scene_problem("ex9_obstacle")


def _cases() -> list:
    cases = []
    base = _disk()  # test 1 of [CAMWA21]
    off = _disk(mu1=1.0, mu2=3.0, centre=(0.42, 0.56), R=0.3, N=3, M=2, A=2.0, b=0.1, lam_r3=False)
    for cfun in ("min", "fb"):
        o = dict(order=1, levels=4, cfun=cfun)
        cases.append(Case(f"test1-p1-{cfun}", "baseline", base, o, quick=cfun == "fb"))
        for t in (1e-9, 1e-3, 1e3, 1e9):
            cases.append(Case(f"test1-p1-{cfun}-tension{t:.0e}", "tension scale (u fixed)", _scaled(base, tension=t), o,
                              baseline=f"test1-p1-{cfun}", tension=t, quick=(cfun == "fb" and t == 1e9)))
        for s in (1e-150, 1e-100, 1e-50, 1e-8, 1e8, 1e50, 1e100, 1e150):
            cases.append(Case(f"test1-p1-{cfun}-data{s:.0e}", "data scale", _scaled(base, data=s), o,
                              baseline=f"test1-p1-{cfun}", data=s, quick=(cfun == "min" and s in (1e-150, 1e-50))))
        for rho in (1e-12, 1e-6, 1e6, 1e12):
            mu1, mu2 = math.sqrt(rho), 1 / math.sqrt(rho)
            cases.append(Case(f"ratio{rho:.0e}-p1-{cfun}", "tension ratio mu1/mu2",
                              _disk(mu1=mu1, mu2=mu2, A=1000.0 * max(mu1, mu2)), dict(o, start="cold")))
        cases.append(Case(f"offcentre-p2-{cfun}", "off-centre contact, mu = (1, 3)", off, dict(order=2, levels=3, cfun=cfun),
                          quick=cfun == "fb"))
        cases.append(Case(f"offcentre-p2-{cfun}-tension1e9", "tension scale (u fixed)", _scaled(off, tension=1e9),
                          dict(order=2, levels=3, cfun=cfun), baseline=f"offcentre-p2-{cfun}", tension=1e9))
        cases.append(Case(f"no-contact-p2-{cfun}", "no contact", _no_contact, dict(order=2, levels=3, cfun=cfun)))
        for p in (2, 3):
            cases.append(Case(f"full-contact-p{p}-{cfun}", "full contact (lam > 0 on the boundary)",
                              _scene_problem("full_contact"), dict(order=p, levels=4, cfun=cfun)))
            cases.append(Case(f"obstacle-boundary-p{p}-{cfun}", "obstacle, contact set touching the boundary",
                              _scene_problem("obstacle_boundary"), dict(order=p, levels=4, cfun=cfun)))
        cases.append(Case(f"boundary-disk-p2-{cfun}", "contact touching the boundary",
                          _disk(centre=(0.2, 0.5), R=0.3, N=3, M=2, A=2.0, lam_r3=False), dict(order=2, levels=3, cfun=cfun)))
        for p in (2, 3, 4):
            cases.append(Case(f"test1-p{p}-{cfun}", "degenerate contact, P2-P4", base, dict(order=p, levels=3, cfun=cfun)))
        for kind in ("distorted", "anisotropic", "sliver"):
            cases.append(Case(f"{kind}-p1-{cfun}", "user meshes", _on_mesh(off, kind), dict(order=1, levels=3, cfun=cfun),
                              quick=(kind == "anisotropic" and cfun == "min")))
        cases.append(Case(f"ex9-p1-{cfun}", "obstacle", _ex9, dict(order=1, levels=3, cfun=cfun)))
        cases.append(Case(f"ex9-p2-{cfun}", "obstacle", _ex9, dict(order=2, levels=3, cfun=cfun)))
        cases.append(Case(f"ex9-p1-{cfun}-data1e-40-tension1e20", "obstacle, scaled",
                          _scaled(_ex9, data=1e-40, tension=1e20), dict(order=1, levels=3, cfun=cfun),
                          baseline=f"ex9-p1-{cfun}", data=1e-40, tension=1e20))
    cases.append(Case("offcentre-p1-balanced", "balanced stop", off, dict(order=1, levels=5, newton_stop="balanced"),
                      quick=True))
    cases.append(Case("anisotropic-p1-balanced", "balanced stop", _on_mesh(off, "anisotropic"),
                      dict(order=1, levels=4, newton_stop="balanced")))
    return cases


CASES = _cases()


# ---------------------------------------------------------------- running and checking
@dataclass
class Outcome:
    case: Case
    status: str                 # "converged", "stopped", "refused", "error"
    reason: str = ""
    rows: list = field(default_factory=list)
    seconds: float = 0.0


def run_case(case: Case, estimate: bool = True, newton: Optional[str] = None) -> Outcome:
    """One case through the level driver (one NGSolve thread), with the failure modes kept apart;
    ``estimate``: also the a posteriori estimate (I_eff) for P1 to P3 (not in the fast subset);
    ``newton``: the Newton linear-solve mode (RunOptions.newton) instead of the case's."""
    from ..drivers import RunOptions, run_scene
    from ..problems import ProblemDataError
    from ..scenes import Scene

    t0 = time.perf_counter()
    try:
        scene = Scene(case.name, None, case.problem())
        opts = dict(case.options)
        if estimate and not case.quick and opts.get("order", 1) <= 3 and "newton_stop" not in opts:
            opts["estimate"] = True
        if newton is not None:
            opts["newton"] = newton
        result = run_scene(scene, RunOptions.for_scene(scene, **opts), threads=1)
    except ProblemDataError as err:
        return Outcome(case, "refused", str(err), seconds=time.perf_counter() - t0)
    except Exception as err:  # an unnamed failure is a violation of the rule
        return Outcome(case, "error", f"{type(err).__name__}: {err} | {traceback.format_exc(limit=3)}",
                       seconds=time.perf_counter() - t0)
    status = "converged" if result.converged and result.complete else "stopped"
    reason = "; ".join(result.failures) or (result.stop_reason or "")
    return Outcome(case, status, reason, list(result.rows), time.perf_counter() - t0)


def check_rule(out: Outcome, baselines: dict) -> tuple:
    """(passes, verdict) of one outcome against the rule (module doc); ``baselines``: name -> Outcome."""
    case, rows = out.case, out.rows
    if out.status == "error":
        return False, "unnamed failure: " + out.reason.split(" | ")[0]
    if out.status == "refused":
        return True, "refused with a named reason"
    values = [r.get(k) for r in rows for k in ("err_energy", "err_max_nodal", "eta", "res_final") if k in r]
    if any(v is None or (isinstance(v, float) and math.isnan(v)) for v in values):
        return False, "NaN in the results"
    if out.status == "stopped":
        return bool(out.reason), "stopped with a named reason" if out.reason else "stopped without a reason"
    uncertified = [r["level"] for r in rows if not r.get("certified", 0)]
    if uncertified:
        return False, f"converged without a valid certificate on levels {uncertified}"
    if case.baseline is not None:
        base = baselines.get(case.baseline)
        if base is None or base.status != "converged":
            return False, f"baseline {case.baseline} missing or not converged"
        worst = 0.0
        for r, b in zip(rows, base.rows):
            e = r["err_energy"] / (case.data * math.sqrt(case.tension))
            m = r["err_max_nodal"] / case.data
            worst = max(worst, abs(e - b["err_energy"]) / b["err_energy"], abs(m - b["err_max_nodal"]) / b["err_max_nodal"])
        if not worst <= SCALE_RTOL:
            return False, f"WRONG ANSWER: differs from {case.baseline} by {worst:.1e} (relative)"
        return True, f"= {case.baseline} ({worst:.0e})"
    if "err_energy" in rows[-1] and len(rows) >= 2:
        e0, e1 = rows[-2]["err_energy"], rows[-1]["err_energy"]
        if e0 > 0 and not e1 <= DECAY * e0:
            return False, f"WRONG ANSWER: energy error not decreasing ({e0:.2e} -> {e1:.2e})"
        return True, "error decreasing"
    return True, "certified"


def _certificate(rows) -> str:
    worst = max((max(r.get("cert_penetration", 0.0), r.get("cert_negativity", 0.0), r.get("cert_slackness", 0.0),
                     r.get("cert_equilibrium", 0.0))
                 for r in rows), default=float("nan"))
    return f"{worst:.0e}"


def report(outcomes: list, verdicts: list, seconds: float, newton: Optional[str] = None) -> str:
    from .tables import fmt

    n_pass = sum(ok for ok, _ in verdicts)
    how = (f"`make stability-{newton}` (`python -m ngcontact.studies.stability --newton {newton}`: every case with "
           f"`--newton {newton}`, no estimates)") if newton else "`make stability` (`python -m ngcontact.studies.stability`"
    lines = ["# Stability suite" + (f": --newton {newton}" if newton else ""), "",
             f"Generated by {how}, "
             f"ngcontact/studies/stability.py) in {seconds:.0f} s.  "
             f"**{n_pass} of {len(outcomes)} cases pass the rule**: every run converges with a valid exit "
             "certificate on every level, or stops with a named reason; no finished run with a wrong answer, no NaN.", "",
             "Certificate: the largest of the relative penetration, negative multiplier, slackness and residual in "
             "the units of each field over the "
             "levels (ngcontact/algebra/certificate.py).  Check: scaled copies must reproduce their baseline "
             f"(errors within {SCALE_RTOL:g} relative after unscaling), other cases must converge (last energy "
             f"error <= {DECAY} x the previous).  Newton its: per level.  Safeguards: Newton-loop remedies taken "
             "(ngcontact/newton/safeguards.py).  I_eff = eta / err_energy per level, FEM P1 to P3 with the residual "
             "stop (equilibrated-flux estimator, guaranteed: >= 1).", "",
             "| case | group | outcome | Newton its | safeguards | certificate | err_energy (finest) | I_eff (per level) | check | rule |"
             + (" CG its (V-cycle levels; a = algebraic, 0 = factorized) |" if newton else ""),
             "|---|---|---|---|---|---|---|---|---|---|" + ("---|" if newton else "")]
    for out, (ok, verdict) in zip(outcomes, verdicts):
        rows = out.rows
        its = ",".join(str(r["newton_its"]) for r in rows) if rows else "-"
        safeg = sum(r.get("newton_remedies", 0) for r in rows) if rows else 0
        outcome = out.status if out.status == "converged" else f"{out.status}: {out.reason[:160]}"
        err = fmt(rows[-1].get("err_energy", float("nan"))) if rows else "-"
        ieff = ", ".join(f"{r['i_eff']:.2f}" for r in rows if "i_eff" in r) or "-"
        line = (f"| {out.case.name} | {out.case.group} | {outcome} | {its} | {safeg} | "
                f"{_certificate(rows) if rows else '-'} | {err} | {ieff} | {verdict} | {'pass' if ok else '**FAIL**'} |")
        if newton:
            line += " " + (", ".join(f"{r.get('cg_its', 0)} ({'a' if r.get('mg_algebraic') else r.get('mg_levels', 0)})"
                                     for r in rows) or "-") + " |"
        lines.append(line)
    return "\n".join(lines) + "\n"


def run_all(cases: list, progress=print, newton: Optional[str] = None) -> tuple:
    outcomes, by_name = [], {}
    for i, case in enumerate(cases, 1):
        out = run_case(case, estimate=newton is None, newton=newton)
        outcomes.append(out)
        by_name[case.name] = out
        progress(f"[{i}/{len(cases)}] {case.name}: {out.status} ({out.seconds:.1f} s)")
    verdicts = [check_rule(o, by_name) for o in outcomes]
    return outcomes, verdicts


def quick_cases() -> list:
    """The fast subset, with the baselines its scaled cases need."""
    chosen = [c for c in CASES if c.quick]
    names = {c.name for c in chosen}
    extra = [c for c in CASES if c.name in {q.baseline for q in chosen} - names]
    return extra + chosen


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    quick = "--quick" in argv
    args = [a for a in argv if a != "--quick"]
    newton = None
    if "--newton" in args:
        i = args.index("--newton")
        newton = args[i + 1] if i + 1 < len(args) else ""
        del args[i:i + 2]
    if len(args) != 1 or newton == "":
        print("usage: python -m ngcontact.studies.stability [--quick] [--newton MODE] OUT.md", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    outcomes, verdicts = run_all(quick_cases() if quick else CASES, progress=lambda s: print(s, flush=True),
                                 newton=newton)
    out = Path(args[0])
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".part")
    tmp.write_text(report(outcomes, verdicts, time.perf_counter() - t0, newton))
    tmp.replace(out)
    failed = [o.case.name for o, (ok, _) in zip(outcomes, verdicts) if not ok]
    print(f"{len(outcomes) - len(failed)} of {len(outcomes)} pass" + (f"; FAIL: {failed}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
