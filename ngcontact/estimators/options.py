"""Options of the a posteriori estimators, validated once.

:class:`EstimatorOptions` is the one place that decides the polynomial degrees of the reconstructed
fluxes: :meth:`EstimatorOptions.flux_degree` (RT degree q of sigma_h and sigma_disc) and
:meth:`EstimatorOptions.alg_flux_degree` (RT degree of the algebraic flux sigma_alg).  Every
estimator function resolves them there, from the FE degree p of the discretization.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Union

__all__ = ["EstimatorOptions", "MULTIPLIERS"]

#: names of the multipliers lam^_h of the equilibration (:mod:`.multipliers`)
MULTIPLIERS = ("contact", "fit", "shape", "p1", "dual")


@dataclass(frozen=True)
class EstimatorOptions:
    """How the estimators are computed (defaults: the guaranteed bound of :mod:`.bound`).

    Attributes
    ----------
    flux_order : int, optional
        RT degree q of the equilibrated fluxes: None (q = p) or p or p + 1 (checked against p by
        :meth:`flux_degree`).
    alg_flux_order : int, optional
        RT degree of the algebraic flux sigma_alg (:mod:`.algebraic`): None (p - 1, at least 0: it
        contains -mu grad d_h of a P_p correction d_h) or any degree >= 0.
    multiplier : {"contact", "fit", "shape", "p1", "dual"}, optional
        the multiplier lam^_h of the equilibration for p >= 2 (:func:`.flux.reconstruct_fluxes`);
        None: the smaller of two guaranteed bounds (:func:`.bound.estimate`).
    dirichlet_correction : True, "fast" or False
        correct non-polynomial Dirichlet data by the lifting w_h (:mod:`.dirichlet`); "fast" takes the
        divergence-free field rho one degree lower (cheaper, eps_w slightly larger); False assumes
        exact data (the bound is then not guaranteed for non-polynomial g).
    concentrate : bool, optional
        choose lam~ by :func:`.nonnegative.concentrated_multiplier`; None: for p >= 2 (:meth:`concentrates`).
    friedrichs : float, optional
        override of the Friedrichs constant C_F (default :func:`.terms.friedrichs_constant`).
    quad_bonus : int, optional
        extra quadrature order of the estimator integrals; None: the discretization's data bonus + 4
        (data are not polynomial).
    regularization : float, optional
        eps of the term eps (r, w) of NGSolve's ``PatchwiseSolve`` path (``batched=False``); None:
        :func:`.flux.patch_regularization`.
    batched : bool
        the batched patch solver of :mod:`.patches` (cached per discretization) instead of
        ``PatchwiseSolve``.
    res_tol : float
        :func:`.components.estimate_components`: relative PDE residual below which an iterate without
        ``r_alg`` counts as an exact linear solve.
    boundary_multiplier : bool
        p >= 2: the multiplier of the equilibration takes the residual multiplier of :mod:`.boundary`
        where contact reaches the Dirichlet boundary (False: the moments-only multipliers there, whose
        eta decays half an order slower than the error when lam > 0 on the boundary).
    closed_form : bool
        :func:`.components.estimate_components` for P1 on affine elements: the element integrals in closed
        form from per-mesh arrays (:mod:`.affine_p1`; the same values to round-off); False: by quadrature.
    shift_obstacle : bool
        obstacle problems with an obstacle psi that is not in the FE space: :func:`.bound.estimate` also evaluates
        the bound for the interpolated obstacle (:mod:`.obstacle`) and reports the smaller one.
    """

    flux_order: Optional[int] = None
    alg_flux_order: Optional[int] = None
    multiplier: Optional[str] = None
    dirichlet_correction: Union[bool, str] = True
    concentrate: Optional[bool] = None
    friedrichs: Optional[float] = None
    quad_bonus: Optional[int] = None
    regularization: Optional[float] = None
    batched: bool = True
    res_tol: float = 1e-12
    boundary_multiplier: bool = True
    closed_form: bool = True
    shift_obstacle: bool = True

    def __post_init__(self):
        def bad(name, want):
            raise ValueError(f"option {name} must be {want}, got {getattr(self, name)!r}")

        def is_int(v):
            return isinstance(v, int) and not isinstance(v, bool)

        def positive(v):
            return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0

        for name in ("flux_order", "alg_flux_order", "quad_bonus"):
            v = getattr(self, name)
            if v is not None and not (is_int(v) and v >= 0):
                bad(name, "an integer >= 0 or None")
        if self.multiplier is not None and self.multiplier not in MULTIPLIERS:
            bad("multiplier", f"one of {MULTIPLIERS} or None")
        if not any(self.dirichlet_correction is v for v in (True, False)) and self.dirichlet_correction != "fast":
            bad("dirichlet_correction", "True, False or 'fast'")
        if self.concentrate is not None and not isinstance(self.concentrate, bool):
            bad("concentrate", "True, False or None")
        for name in ("friedrichs", "regularization"):
            v = getattr(self, name)
            if v is not None and not positive(v):
                bad(name, "a finite number > 0 or None")
        for name in ("batched", "boundary_multiplier", "closed_form", "shift_obstacle"):
            if not isinstance(getattr(self, name), bool):
                bad(name, "True or False")
        if not (isinstance(self.res_tol, (int, float)) and not isinstance(self.res_tol, bool)
                and math.isfinite(self.res_tol) and self.res_tol >= 0):
            bad("res_tol", "a finite number >= 0")

    def flux_degree(self, p: int) -> int:
        """RT degree q of the equilibrated fluxes for FE degree p: p (default) or p + 1.

        >>> EstimatorOptions().flux_degree(2), EstimatorOptions(flux_order=3).flux_degree(2)
        (2, 3)
        """
        if self.flux_order is None:
            return int(p)
        if self.flux_order not in (p, p + 1):
            raise ValueError(f"option flux_order must be p = {p} or p + 1 = {p + 1} (or None), "
                             f"got {self.flux_order!r}")
        return self.flux_order

    def alg_flux_degree(self, p: int) -> int:
        """RT degree of the algebraic flux for FE degree p: max(p - 1, 0) by default.

        >>> EstimatorOptions().alg_flux_degree(1), EstimatorOptions().alg_flux_degree(3)
        (0, 2)
        """
        return max(int(p) - 1, 0) if self.alg_flux_order is None else self.alg_flux_order

    def concentrates(self, p: int) -> bool:
        """Whether lam~ is concentrated (:func:`.nonnegative.concentrated_multiplier`): default for p >= 2."""
        return p >= 2 if self.concentrate is None else self.concentrate
