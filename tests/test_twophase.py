"""Two-phase water-hydrogen benchmark (ngcontact.twophase): Jacobian against finite differences,
a short coarse run through gas appearance at x = 0 with mass balance, parameter validation."""
import numpy as np
import pytest

from ngcontact.twophase import YEAR, TwoPhaseParams, run_h2
from ngcontact.twophase.fv import TwoPhaseFV, initial_state
from ngcontact.twophase.laws import VanGenuchten
from ngcontact.twophase.mesh1d import interval_mesh

#: finite-difference steps per unknown (S, P [Pa], chi)
FD_STEP = np.array([1e-7, 1.0, 1e-10])
#: typical variation of each unknown over a step: the Jacobian's columns are compared in these units
VARIATION = np.array([1e-2, 1e5, 1e-4])


def _step_and_state(gas: bool):
    prm = TwoPhaseParams()
    mesh = interval_mesh(prm.length, 8)
    disc = TwoPhaseFV(prm, mesh)
    x0 = initial_state(prm, mesh)
    system = disc.step_system(x0, 0.0, 5000 * YEAR)
    rng = np.random.default_rng(1)
    x = x0.copy()
    x[1::3] += 1e5 * rng.random(8)
    x[2::3] = 1e-4 * rng.random(8)
    if gas:  # S in the exact-law range and in the regularized chord [1 - eps, 1]
        x[0::3] = 1.0 - np.array([2e-2, 1e-2, 5e-3, 1e-3, 4e-5, 2e-5, 1e-2, 3e-3])
    return system, x


@pytest.mark.parametrize("gas", [True, False], ids=["gas-zone", "liquid-only"])
@pytest.mark.parametrize("C", [(1.0, 0.0), (0.0, 1.0), (-0.4, -0.7)], ids=["a", "b", "fb"])
def test_jacobian_matches_finite_differences(gas, C):
    """Analytic Newton matrix against differences of Phi = [R; Ca a + Cb b]: central in the gas zone,
    backward (from S = 1, the side the laws are differentiated on) in the liquid-only zone."""
    system, x = _step_and_state(gas)
    n = len(x)
    Ca, Cb = np.full(n // 3, C[0]), np.full(n // 3, C[1])
    J = system.jacobian(x, None, Ca, Cb).toarray()

    def phi(z):
        a, b = system.pair(z)
        return system.stack(system.residual(z), Ca * a + Cb * b)

    Jfd = np.empty_like(J)
    for j in range(n):
        e = np.zeros(n)
        e[j] = FD_STEP[j % 3]
        Jfd[:, j] = (phi(x + e) - phi(x - e)) / (2 * e[j]) if gas else (phi(x) - phi(x - e)) / e[j]
    col = np.tile(VARIATION, n // 3)
    rel = np.abs((J - Jfd) * col).max(axis=1) / np.abs(Jfd * col).max(axis=1)
    assert rel.max() < (1e-6 if gas else 1e-4)


def test_laws_at_full_saturation_and_regularization():
    vg = VanGenuchten(TwoPhaseParams())
    s = np.array([1.0])
    assert abs(vg.pc(s)[0][0]) < 1e-6 and vg.krl(s)[0][0] == pytest.approx(1.0) and vg.krg(s)[0][0] == 0.0
    assert np.isfinite(vg.pc(s)[1][0]) and np.isfinite(vg.krl(s)[1][0])
    # the inverse of P_c on both sides of the chord
    sat = np.array([0.9, 0.99, 1.0 - 0.6 * 5e-5])
    assert np.allclose(vg.saturation(vg.pc(sat)[0]), sat, atol=1e-12)


def test_short_run_gas_appears_at_x0_with_mass_balance():
    """100 cells, dt = 5000 years, to 3e4 years: no gas at 1e4 years, gas at x = 0 from t = 1.5e4 years
    (appearance near 1.26e4 years), mass balance of both components and the bounds on every step."""
    run = run_h2(cells=100, dt_years=5000.0, t_final_years=3e4)
    s0 = [r.S_0 for r in run.rows]
    assert [r.t_years for r in run.rows] == pytest.approx([5e3, 1e4, 1.5e4, 2e4, 2.5e4, 3e4])
    assert s0[0] == 1.0 and s0[1] == 1.0 and s0[2] < 1.0
    assert run.rows[-1].gas_end_m > 10.0
    for r in run.rows:
        assert r.water_defect_rel <= 1e-10 and r.h2_defect_rel <= 1e-10
        # the same defects relative to the mass through the boundary in the step (injected + out)
        assert not r.water_defect_flux > 1e-6 and r.h2_defect_flux <= 1e-6  # nan: no water out yet
        assert r.min_S_minus_Slr >= 0 and r.max_S_minus_1 <= 1e-14 and r.min_chi >= 0
    assert not run.log


@pytest.mark.parametrize("field, value", [("porosity", 0.0), ("n_vg", 1.0), ("mu_g", -1.0), ("eps_reg", 0.7),
                                          ("s_lr", 1.2), ("q_inject", -1.0), ("henry", float("nan")),
                                          ("chi_right", 2.0), ("chi_right", 1e-4)])
def test_parameter_errors_name_the_field(field, value):
    with pytest.raises(ValueError, match=f"parameters? [a-z_, ]*{field}"):
        TwoPhaseParams(**{field: value})


def test_run_option_errors():
    with pytest.raises(ValueError, match="option dt_years must be a finite number > 0, got -1"):
        run_h2(dt_years=-1)
    with pytest.raises(ValueError, match="option dt_years must be a finite number > 0, got inf"):
        run_h2(dt_years=float("inf"))
    with pytest.raises(ValueError, match=r"option dt_years = 0.001 gives 1e\+09 steps .* \(at most 1e\+06\)"):
        run_h2(dt_years=1e-3, t_final_years=1e6)
    with pytest.raises(ValueError, match="option cells"):
        run_h2(cells=1)
    with pytest.raises(ValueError, match="option newton"):
        run_h2(newton="lu")


def test_cli_run_writes_the_outputs(tmp_path, capsys):
    from ngcontact.cli import main

    out = tmp_path / "h2"
    assert main(["run", "h2_storage", "--test", "--t-final-years", "2e4", "--out", str(out), "-q", "--no-plots"]) == 0
    assert {"steps.csv", "profiles.csv", "summary.json"} <= {p.name for p in out.iterdir()}
    import json
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 4 and summary["benchmark_x0"]["gas_appears_years"] == 15000.0
    assert main(["run", "h2_storage", "--cells", "1", "--out", str(tmp_path / "bad")]) == 2
    assert "option --cells must be an integer >= 2, got 1" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
    assert main(["run", "h2_storage", "--newton", "multigrid", "--out", str(tmp_path / "bad")]) == 2
    assert "for the two-phase flow (the multigrid modes are for the FE discretizations), got 'multigrid'" in \
        capsys.readouterr().err


@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_gmres_modes_match_the_direct_solution(cfun):
    """Short coarse run: exact GMRES, inexact and adaptive ([CG20] stopping) against the LU run, with S <= 1
    at every accepted step and fewer GMRES iterations in the adaptive mode than in the exact one."""
    kw = dict(cells=100, dt_years=5000.0, t_final_years=3e4, cfun=cfun)
    ref = run_h2(newton="direct", **kw)
    runs = {m: run_h2(newton=m, **kw) for m in ("gmres", "inexact", "adaptive")}
    p_ref = np.array([r.Pg_0_Pa for r in ref.rows])
    for mode, run in runs.items():
        assert run.completed and not run.log, mode
        p = np.array([r.Pg_0_Pa for r in run.rows])
        assert np.abs(p - p_ref).max() / p_ref.max() < (1e-9 if mode != "adaptive" else 1e-4), mode
        # Newton-min keeps S = 1 exactly on its liquid rows; with FB, |C(a, b)| <= tol bounds 1 - S >= -tol only
        assert max(r.max_S_minus_1 for r in run.rows) <= (1e-14 if cfun == "min" else 1e-8), mode
        assert min(r.min_chi for r in run.rows) >= 0, mode
    assert runs["adaptive"].gmres_total < runs["gmres"].gmres_total
    assert all(np.isfinite([r.eta_lin_h, r.eta_alg_h, r.eta_sp_h, r.eta_tm_h]).all() for r in runs["adaptive"].rows)


def test_estimator_components_at_a_converged_step():
    """At an (exactly) converged step the linearization and algebraic components vanish next to the
    spatial and temporal ones; a perturbed iterate has a linearization component, a look-ahead an
    algebraic one."""
    from ngcontact.twophase.estimators import TwoPhaseEstimator

    run = run_h2(cells=100, dt_years=5000.0, t_final_years=2.5e4, tol=1e-9)
    disc = run.disc
    x_prev = run.profiles.get(2e4)
    run2 = run_h2(cells=100, dt_years=5000.0, t_final_years=2e4, tol=1e-9)
    system = disc.step_system(run2.x, 2e4 * YEAR, 2.5e4 * YEAR)
    est = TwoPhaseEstimator(disc, system)
    x = run.x
    zero = np.zeros_like(x)
    c = est.components(x, zero, zero)
    floor = np.maximum(c.eta_sp, c.eta_tm)
    assert np.all(c.eta_lin < 1e-4 * floor) and np.all(c.eta_alg < 1e-4 * floor)
    assert est.stop_newton(c) and est.stop_linear(c)
    dx = np.zeros_like(x)
    dx[1::3] = 1e3  # a pressure perturbation: the linearization is exact in P only through k_r upwinding
    dx[0:30:3] = -1e-3
    c2 = est.components(x - dx, zero, zero)
    assert np.any(c2.eta_lin > 1e-3 * floor)
    c3 = est.components(x, zero, dx)
    assert np.any(c3.eta_alg > 1e-3 * floor) and not est.stop_linear(c3)
    assert x_prev is None or x_prev.shape == x.shape


def test_adaptive_stop_projects_the_accepted_iterate_onto_s_le_1():
    """An iterate that meets the [CG20] criterion with S - 1 = 1e-6 in one cell is accepted (the
    violation is part of eta_lin,w) and returned with S <= 1 and the cells' hydrogen content; one that
    misses the criterion is not."""
    from types import SimpleNamespace

    from ngcontact.twophase.estimators import AdaptiveStepStop, Components, TwoPhaseEstimator

    prm = TwoPhaseParams()
    disc = TwoPhaseFV(prm, interval_mesh(prm.length, 8))
    x0 = initial_state(prm, disc.mesh)
    system = disc.step_system(x0, 0.0, 5000 * YEAR)
    est = TwoPhaseEstimator(disc, system)
    stop = AdaptiveStepStop(est)
    x = x0.copy()
    x[0::3] = [1.0, 1.0 + 1e-6, 0.99, 1.0, 1.0, 1.0, 1.0, 1.0]
    x[1::3] += 2e5
    x[2::3] = 5e-5
    one = np.ones(2)
    for lin, expected in ((1e-4 * one, "adaptive stopping criterion"), (1e-2 * one, None)):
        est.last = Components(eta_sp=one, eta_tm=0.5 * one, eta_lin=lin, eta_alg=1e-9 * one)
        rec = SimpleNamespace(res=1.0)
        stop.measure(rec, system, x, system.y0, None)
        assert stop.check(rec, 1e-8) == expected
        assert rec.eta_lin == pytest.approx(lin[0])
    xa, _ = stop.accepted(x, system.y0)
    assert xa[0::3].max() == 1.0 and xa[3] == 1.0 and xa[6] == 0.99
    assert stop.projected == pytest.approx(1e-6, rel=1e-6)
    assert np.array_equal(np.delete(xa, [3, 5]), np.delete(x, [3, 5]))  # only the violating cell changed
    a_h = disc.accumulation(disc.state(x))[0][1]
    assert np.allclose(disc.accumulation(disc.state(xa))[0][1], a_h, rtol=1e-14, atol=0)  # H2 content kept
    assert x[3] == 1.0 + 1e-6  # the loop's iterate is not modified in place


def test_adaptive_run_logs_its_newton_iterates():
    """iterates.csv of an adaptive run: one row per Newton iterate (the steps' Newton counts), the last
    one of each step with the stop reason, ratio_c = eta_lin,c / max(eta_sp,c, eta_tm,c), and S <= 1."""
    from ngcontact.twophase.outputs import run_files
    from ngcontact.twophase.run import ITERATE_COLUMNS

    run = run_h2(cells=100, dt_years=5000.0, t_final_years=3e4, cfun="fb", newton="adaptive")
    assert run.completed and not run.log and len(run.iterates) == run.newton_total
    for row in run.rows:
        its = [it for it in run.iterates if it["step"] == row.step]
        assert [it["k"] for it in its] == list(range(1, row.newton_its + 1))
        assert its[-1]["stop"] in ("adaptive stopping criterion", "converged")
        assert not any(it["stop"] for it in its[:-1])
        assert sum(it["gmres_its"] for it in its) == row.gmres_its
    it = run.iterates[-1]
    assert it["ratio_w"] == pytest.approx(it["eta_lin_w"] / max(it["eta_sp_w"], it["eta_tm_w"]))
    assert max(r.max_S_minus_1 for r in run.rows) <= 0.0
    text = run_files(run, {})["iterates.csv"]
    assert text.splitlines()[0] == ",".join(ITERATE_COLUMNS) and len(text.splitlines()) == run.newton_total + 1


def test_eta_lin_is_the_flux_error_of_the_newton_iterate():
    """diagnose.linearization_check (100 cells, the step from 4e4 y): eta_lin,c of the exact Newton-min
    iterates is their flux error against the converged step within 15 % while that error is above 1e-6 of
    the step's flux change (in 1D the linearized fluxes carry the converged step's balance)."""
    from ngcontact.twophase.diagnose import linearization_check

    check = linearization_check(t_years=4e4, cells=100, dt_years=2e4)
    change = np.array(check["step_change"])
    assert check["newton"] >= 3 and np.all(change > 0)
    tested = 0
    for row in check["rows"][1:]:
        for j, c in enumerate("wh"):
            if row[f"err_{c}"] > 1e-6 * change[j]:
                assert row[f"eta_lin_{c}"] == pytest.approx(row[f"err_{c}"], rel=0.15), (row["k"], c)
                tested += 1
    assert tested >= 6
    with pytest.raises(ValueError, match="option t_years must be >= 2 dt_years"):
        linearization_check(t_years=1e4, cells=100, dt_years=2e4)


def test_small_time_steps_inject_the_hydrogen():
    """dt = 1e-4 years on 50 cells: the injected mass per step is below 1e-8 of a cell's reference mass (the rows'
    unit); the Newton test is relative to the step's own driving residual, so the hydrogen gets in (with the
    absolute test every step passed at its start: no Newton step, no hydrogen in the domain)."""
    prm = TwoPhaseParams()
    disc = TwoPhaseFV(prm, interval_mesh(prm.length, 50))
    x0 = initial_state(prm, disc.mesh)
    run = run_h2(prm, cells=50, dt_years=1e-4, t_final_years=2e-3, estimate=False)
    gained = disc.masses(run.x)[1] - disc.masses(x0)[1]
    assert run.completed and run.newton_total >= 1
    assert gained == pytest.approx(prm.injection_rate(0.0, 2e-3 * YEAR) * 2e-3 * YEAR, rel=1e-6)


def test_gas_in_every_cell_is_certified():
    """Injection x1000: the gas reaches x = L (b = H (P + P_c) - beta_l chi = 0 in every cell).  The certificate
    measures b in the units of its two terms (relative to ||b||_inf ~ 1e-16 the converged steps failed it and the
    run gave up after six dt cuts at t ~ 2070 years)."""
    from ngcontact.twophase.run import gas_end

    prm = TwoPhaseParams(q_inject=5.57e-3)
    run = run_h2(prm, cells=20, dt_years=50, t_final_years=4000, estimate=False)
    assert run.completed and not run.log
    assert gas_end(run.disc, run.x) == pytest.approx(prm.length)


def test_defects_without_hydrogen_in_the_domain_are_finite():
    """Before any hydrogen is in the domain the H2 defect is measured against the injected mass (relative to
    max(M_H2, tiny) it read 2.5e298), and every step reports its defect relative to the mass through the boundary."""
    run = run_h2(cells=20, dt_years=1e-4, t_final_years=3e-4, estimate=False)
    for r in run.rows:
        assert r.h2_defect_rel <= 1e-6 and r.h2_defect_flux <= 1e-6


def test_step_below_the_tolerance_is_a_named_stop():
    """dt = 1e-7 years: the injection per step is ~1e-12 of a cell's reference mass, below 0.1 tol, so Newton takes
    no step; the step's mass balance (the injected hydrogen is not in the domain) stops the run with a named reason."""
    run = run_h2(cells=50, dt_years=1e-7, t_final_years=1e-6, estimate=False)
    assert not run.completed
    assert "mass balance not resolved" in run.log[-1] and "H2 defect is 1 of the hydrogen injected" in run.log[-1]


def test_certificate_names_the_pair_functions():
    """The two-phase certificate says which of its pair fails in its own terms (not 'negative multiplier')."""
    prm = TwoPhaseParams()
    disc = TwoPhaseFV(prm, interval_mesh(prm.length, 8))
    x = initial_state(prm, disc.mesh)
    system = disc.step_system(x, 0.0, 5000 * YEAR)
    bad = x.copy()
    bad[2::3] = 1.0  # dissolved mole fraction far above solubility: b < 0
    text = system.certificate(bad, system.y0, 1e-7).failure()
    assert "dissolved H2 above solubility (b < 0)" in text and "multiplier" not in text


def test_cli_names_profiles_that_no_step_reaches(tmp_path, capsys):
    """dt = 3000 years does not end a step at the default profile time 2e4 years: the CLI says which are missing
    instead of leaving them out silently."""
    from ngcontact.cli import main

    out = tmp_path / "h2"
    assert main(["run", "h2_storage", "--cells", "20", "--dt-years", "3000", "--t-final-years", "2.4e4", "--out",
                 str(out), "-q", "--no-plots"]) == 0
    err = capsys.readouterr().err
    assert "note: no profile at t = 20000 years: no step ends there with dt = 3000 years" in err
