"""A posteriori error estimates by equilibrated flux reconstruction ([JSC20], seed slides
"A posteriori analysis for finite elements" to "Theorem (A posteriori error estimate)").

* :mod:`.view` -- what the estimators read of a discretization and an iterate (the one adapter);
* :mod:`.options` -- :class:`EstimatorOptions`, validated once (RT degrees decided there);
* :mod:`.patches` -- the batched vertex-patch solver;
* :mod:`.moments` -- hat moments of discrete functionals, the vertex device, data quadrature;
* :mod:`.multipliers` -- the multiplier lam^_h of the equilibration;
* :mod:`.boundary` -- lam^_h where contact reaches the Dirichlet boundary (residual multiplier);
* :mod:`.flux` -- patchwise equilibrated fluxes sigma_alpha_h in RT_q;
* :mod:`.dirichlet` -- correction of non-polynomial Dirichlet data (w_h, eta_bc, eps_w);
* :mod:`.nonnegative` -- the nonnegative multiplier lam~_h of the contact terms;
* :mod:`.terms` -- the individual terms eta_F, eta_R, eta_quad, eta_nonc,1..2, Theta and constants;
* :mod:`.bound` -- the guaranteed total eta (:func:`estimate`);
* :mod:`.components` -- eta_disc, eta_lin, eta_alg of any iterate (seed Corollary);
* :mod:`.affine_p1` -- the same element terms in closed form for P1 on affine elements (per-mesh arrays);
* :mod:`.algebraic` -- the algebraic flux sigma_alg of an inexact Newton step;
* :mod:`.history` -- components along Newton iterations;
* :mod:`.checks` -- equilibration, normal continuity, complementarity diagnostics.
"""
from .algebraic import algebraic_flux
from .bound import Estimate, estimate
from .checks import complementarity_report, equilibration_defect, normal_jump, projected_source
from .components import Components, algebraic_residual_function, estimate_components
from .flux import FluxReconstruction, equilibrate, reconstruct_fluxes
from .history import ComponentsHistory, newton_history, plot_components_history
from .multipliers import multiplier_p1
from .nonnegative import nonnegative_multiplier
from .options import EstimatorOptions
from .terms import element_diameters, friedrichs_constant
from .view import FieldData, expect_repeated_evaluations

__all__ = ["EstimatorOptions", "Estimate", "estimate", "friedrichs_constant", "element_diameters",
           "nonnegative_multiplier", "FluxReconstruction", "FieldData", "reconstruct_fluxes", "equilibrate",
           "multiplier_p1", "algebraic_flux",
           "equilibration_defect", "normal_jump", "complementarity_report", "projected_source",
           "Components", "ComponentsHistory", "estimate_components", "algebraic_residual_function",
           "newton_history", "plot_components_history", "expect_repeated_evaluations"]
