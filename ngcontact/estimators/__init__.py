"""A posteriori error estimates by equilibrated flux reconstruction ([JSC20], seed
slides "A posteriori analysis for finite elements" to "Theorem (A posteriori
error estimate)").

* :mod:`.flux` -- patchwise equilibrated fluxes sigma_alpha_h in RT_q;
* :mod:`.estimators` -- the estimators eta_F, eta_R, eta_C, eta_nonc and the
  guaranteed total eta (:func:`estimate`);
* :mod:`.checks` -- equilibration, normal continuity, complementarity diagnostics;
* :mod:`.components` -- eta_disc, eta_lin, eta_alg of any iterate (seed Corollary), history along Newton.
"""
from .checks import complementarity_report, equilibration_defect, normal_jump, projected_source
from .components import (Components, ComponentsHistory, algebraic_residual_function, estimate_components,
                         newton_history, newton_iterates, plot_components_history)
from .estimators import Estimate, element_diameters, estimate, friedrichs_constant, nonnegative_multiplier
from .flux import FieldData, FluxReconstruction, data_rules, equilibrate, field_data, multiplier_p1, reconstruct_fluxes

__all__ = ["Estimate", "estimate", "friedrichs_constant", "element_diameters", "nonnegative_multiplier",
           "FluxReconstruction", "FieldData", "reconstruct_fluxes", "equilibrate", "multiplier_p1", "field_data",
           "data_rules",
           "equilibration_defect", "normal_jump", "complementarity_report", "projected_source",
           "Components", "ComponentsHistory", "estimate_components", "algebraic_residual_function",
           "newton_history", "newton_iterates", "plot_components_history"]
