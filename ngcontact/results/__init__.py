"""Run directories: history.csv, newton.csv, summary.json, manifest.json, figures and VTK files.

A run directory is written while the run goes (:class:`RunWriter`, the ``on_level`` hook of the
drivers): after every finished level, history.csv and newton.csv hold all finished levels and
summary.json says ``"complete": false`` with the reason (``"running or killed: ..."`` while the
run goes -- a killed run keeps exactly that -- or the interrupt / error that ended it).  When the
run ends normally, figures (a caller-supplied hook, e.g. :func:`ngcontact.plotting.write_run_plots`)
and VTK files are added and summary.json is rewritten last with ``"complete": true`` (false with a
reason when the run stopped early, e.g. at its DOF budget).  Every file is written under a temporary
name and renamed, so a file is either its previous or its new version.

manifest.json lists the files the run wrote.  Replacing a run directory removes only those (and
the fixed names of ngcontact outputs); any other file makes the replacement refuse
(:func:`check_output_dir`).  The previous run is removed when the new run has finished its first
level: a run that fails before (bad data on the coarsest mesh) leaves it untouched.  Staging
directories left by killed runs of earlier versions (``.tmp-NAME-*``, ``.old-NAME-*``) are removed
when they hold only run files, otherwise reported.

This package writes data only (figures: :mod:`ngcontact.plotting`).

Rows are keyed by ``level`` and, in time-dependent runs, by the time step ``n`` and the time
``t`` (:data:`KEY_COLUMNS`).  The key columns present come first in history.csv and newton.csv,
in that order; a stationary run has no ``n`` and ``t`` columns.

history.csv columns (one row per level, or per level and time step; a column is present
only when the run computes it -- error columns need an exact solution):

==================  ===========================================================
level               mesh level j (T_j: j uniform refinements of the coarse mesh)
n                   time-dependent runs: time step index n
t                   time-dependent runs: time t_n of the row
nelem               number of triangles
h                   mesh size (nominal for structured meshes, else max edge)
ndof                DOFs as counted in [CAMWA21]: fem (fields + 1) x interior nodes;
                    hho u1, u2 on cells and interior faces + lam on cells;
                    dg (fields + 1) x cell nodes
ndof_sc             hho: size of the statically condensed system (face unknowns)
nodes               interior Lagrange nodes per field
marked              --adaptive: elements marked on the previous level (0 on level 0)
multiplier          --adaptive, p >= 2: the multiplier candidate whose bound the estimate kept ("contact",
                    "fit", "shape"; ngcontact.estimators.bound, "Multiplier")
multiplier_candidates  --adaptive, p >= 2: candidates the level's estimate computed (2, or 1 where the
                    schedule of ngcontact.drivers.adaptive skipped the one that lost by a wide margin)
err_energy          (sum_a mu_a ||grad(u_a - u_ah)||^2)^(1/2)      [exact only]
rate_energy         log(e_{j-1}/e_j) / log(h_{j-1}/h_j)              [exact only]
err_max_nodal       max over nodes |u_a(x_l) - u_ah(x_l)|           [exact only]
err_jump            dg: jump seminorm (sum_F eta/h_F ||[u_ah - u_a]||_F^2)^(1/2) [exact]
newton_its          semismooth Newton iterations on this level
newton_converged    1 if the Newton mode's stopping criterion was met, else 0: ||Phi||/||F|| <= tol
                    (direct, gmres, inexact) or eta_lin <= gamma_lin eta_disc (adaptive), with the exit
                    certificate where the rule requires it (see certified)
res_final           final ||Phi||/||F|| (adaptive: it contains the algebraic residual of the accepted
                    GMRES iterate and can be O(1) when the estimators say the error is discretization-dominated)
certified           1 if the exit certificate holds at cert_tol (ngcontact.algebra.certificate), else 0
cert_penetration, cert_negativity, cert_slackness, cert_equilibrium
                    the certificate (ngcontact.algebra.certificate): max(-g)^+ / U, max_i (-y_i)^+ / Y_i,
                    max_i min(g_i^+ / U, y_i^+ / Y_i), and the residual of each field's constrained rows in
                    the units of that field (U the range of u; Y_i the multiplier's unit of row i, the
                    smaller of max(|y|, |F| / max D) and what moves the row's softer unknown by the range
                    of its own field; sup norms; invariant under scaling)
cert_tol            tolerance the stopping rule requires of the certificate: 1e3 tol for the residual test,
                    gamma_balance for the balanced stop, inf (recorded only) for the adaptive stop, whose
                    iterate the estimators certify
newton_remedies     safeguards the Newton loop took (cycling of Newton-min, stalled FB line search:
                    ngcontact.newton.safeguards); each is logged in the progress output
newton_balanced     --newton-stop balanced: 1 if the level stopped on eps_lin <= gamma_balance eps_disc
eps_lin_final, eps_disc_final
                    --newton-stop balanced: linearization defect and discretization proxy of
                    the last iterate (ngcontact.newton module doc)
active_nodes        nodes in the discrete contact set (gap <= X3)
linear_size         largest linear system solved in a Newton step (reduced SPD /
                    condensed face system / full system)
gmres_its           --newton gmres|inexact|adaptive: GMRES iterations, all Newton steps
                    (adaptive: including the nu look-ahead steps of sigma_alg)
cg_its              --newton multigrid|multigrid-inexact: CG iterations, all Newton steps
mg_levels           levels of the multigrid V-cycle (0: every step factorized: a small level
                    without a nested hierarchy)
mg_algebraic        1: algebraic multigrid (the mesh has no nested hierarchy), 0: geometric
mg_builds           Newton steps that built the whole hierarchy
mg_updates          Newton steps that rebuilt only its finest level (few rows changed class; the
                    other steps reused it unchanged)
time_mg_setup_s     Galerkin products and coarsest factorizations of those builds
gmres_max_step      largest number of GMRES iterations in one Newton step
gmres_first_step    GMRES iterations of the first Newton step
n_estimates         estimator evaluations inside the Newton loop (adaptive: every nu GMRES its)
time_estimate_newton_s  time of those evaluations (inside time_solve_s, not in time_linear_s)
eta_disc_final, eta_lin_final, eta_alg_final
                    error components of the last iterate ([JSC20] Corollary; adaptive
                    mode, or gmres/inexact with estimator logging)
gap_min             min over nodes of X1 - X2 (or X - psi): >= -tol at convergence
lam_min             min of X3: >= -tol at convergence
product_max         max |gap * X3|
time_mesh_s         building/refining the mesh (--adaptive: copy + bisection giving T_j)
time_mark_s         --adaptive: marking on T_{j-1} (Doerfler / maximum)
time_prolong_s      initial guess: the previous level's solution prolongated (nested start) or
                    the scene's initial guess (cold start)
time_assembly_s     spaces, Lagrange nodes, matrices, loads
time_solve_s        semismooth Newton (all iterations)
time_linear_s       reduced SPD systems (assembly + factorization + solve)
time_condense_s     hho: static condensation + cell recovery (inside time_solve_s)
time_post_s         errors and diagnostics
eta                 guaranteed estimate of |||u - u_h||| (--estimate; [JSC20] Theorem
                    plus Dirichlet-data and quadrature terms, see ngcontact.estimators)
eta_seed            the seed Theorem's total (bound of |||u - s~_h|||)
eta_direct          direct bound of |||u - u~_h||| (pays eta_nonc1 once; eta uses the
                    smaller of eta_seed + eta_nonc1 and eta_direct)
theta_contact       Theta of the direct bound (weak form tested with the
                    nonconformity correction)
eta_F, eta_R        flux / residual estimators (sum over K and alpha, squared, root)
eta_FR              (sum_a (sum_K (eta_F,K,a + eta_R,K,a)^2))^(1/2)
eta_C               contact estimator sum_K 2 (lam_h^pos, u1h - u2h)_K
eta_nonc1..3        nonconformity estimators of the seed's Theorem
eta_quad            data oscillation / quadrature term (0 for polynomial data)
eta_bc, eps_w       Dirichlet data correction |||w_h||| and its non-orthogonality
eta_trace           indicator of the Dirichlet data part g - Pi g that the correction leaves out
bound_proven        1, or 0 when eta_trace > 0.1 eta (then eta is not a proven bound; summary.json
                    "caveats" and the CLI's warning say why; ngcontact.estimators.dirichlet)
eta_obstacle        obstacle outside the FE space: |||psi - psi~||| when the bound for the interpolated
                    obstacle psi~ (+ this term) was the smaller one, else 0 (ngcontact.estimators.obstacle)
eta_nonc2_seed      seed's C_{Omega,mu} ||lam_h^neg|| (diagnostic, not in eta)
time_estimate_s     flux reconstruction + estimators
i_eff               eta / err_energy                                  [exact only]
rate_eta            log(eta_{j-1}/eta_j) / log(h_{j-1}/h_j)
                    (--adaptive: rate_energy and rate_eta use ndof^{-1/2} in place of h)
time_total_s        whole level
time_cum_s          cumulated over levels 0..j
==================  ===========================================================

newton.csv: one row per (level, time step n if any, iteration k) with the key columns, k, res, res_lin, res_c,
n_active, n_changed, step, time_linear, time_step, linear_size, linear_path (0 fresh
factorization, 1 PCG preconditioned by an earlier step's factorization, 2 PCG gave up and
the step was factorized, 3 PCG + truncated multigrid), pcg_its (see :class:`ngcontact.newton.IterationRecord`);
with --newton multigrid|multigrid-inexact also cg_cum, mg_levels, amg, cg_early, mg_rebuilt, time_mg_setup,
relaxed (rows the free-boundary relaxation reclassified; 0: the iterate is the step's), time_relax,
split (1: the two-membrane step was solved through the s/w splitting; then linear_size is the w-system's)
(:class:`ngcontact.newton.MultigridIterationRecord`); with the GMRES modes also
gmres_its, gmres_cum, gmres_accepted, gmres_stop (0 tolerance, 1 adaptive, 2 maxiter,
3 stagnation), res_alg (||R^{k,i}||/||B^{k-1}||),
eta_disc, eta_lin, eta_alg, eta, n_estimates, time_estimate, time_ilu, ilu_fill_ratio
(nnz(L+U)/nnz(A) of the step's ILU; :class:`ngcontact.newton.inexact.InexactIterationRecord`).

summary.json: ``scene``, ``scene_file``, ``problem``, ``domain``, ``description``, ``options`` (the
RunOptions), ``converged`` and ``failures`` (Newton), ``caveats`` (levels whose eta is not a proven
bound, with the reason), ``stop_reason`` (why an adaptive loop or a
budget ended the run), ``complete`` and ``reason`` (null when complete), ``final`` (the last
history row), ``versions``, ``git_revision`` (only when the package runs from its own git
checkout, else null; ``versions["ngcontact"]`` always says the version) and ``command``.
manifest.json: ``{"ngcontact": version, "kind": "run", "files": [names written]}``.
"""
from .. import __version__  # recorded in manifests and summaries; the CLI's --version
from .files import HISTORY_COLUMNS, KEY_COLUMNS, read_history, read_summary
from .directory import MANIFEST, OutputDir, check_output_dir
from .tables import ESTIMATE_TABLE_COLUMNS, markdown_table
from .writer import RunWriter, git_revision, versions, write_run

__all__ = ["write_run", "RunWriter", "check_output_dir", "OutputDir", "MANIFEST", "read_history", "read_summary",
           "markdown_table", "versions", "git_revision", "HISTORY_COLUMNS", "KEY_COLUMNS", "ESTIMATE_TABLE_COLUMNS"]
