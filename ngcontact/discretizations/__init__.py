"""Discretizations: turn problem data + mesh into a complementarity system.

Each class takes ``(problem, mesh, order=..., solver=...)`` and provides what
:class:`~ngcontact.discretizations.base.Discretization` declares: ``system``
(:class:`~ngcontact.algebra.system.ComplementaritySystem`), ``ndof``,
``n_interior``, ``ndof_sc``, ``time_assembly``, ``time_condense``,
``estimable``, ``initial_guess``, ``prolongate``, ``gridfunctions``,
``errors``, ``complementarity``, ``contact_points``.

Registry keys are the CLI's ``--disc`` values:

* ``fem``  -- conforming P_p, p = 1..4 (:mod:`.fem`);
* ``hho``  -- hybrid high-order with static condensation (:mod:`.hho`);
* ``sipg``, ``nipg``, ``iipg`` -- interior penalty dG, theta = 1, -1, 0 (:mod:`.dg`).
"""
from .base import Discretization
from .dg import DGDiscretization
from .fem import FEMDiscretization
from .hho import HHODiscretization


def _dg_variant(variant: str):
    class _Variant(DGDiscretization):
        __doc__ = f"{variant.upper()} interior penalty dG (see :class:`DGDiscretization`)."
        name = variant

        def __init__(self, problem, mesh, order: int = 1, solver: str = "sparsecholesky", **kw):
            super().__init__(problem, mesh, order=order, solver=solver, variant=variant, **kw)

    _Variant.__name__ = _Variant.__qualname__ = f"{variant.upper()}Discretization"
    return _Variant


DISCRETIZATIONS = {
    "fem": FEMDiscretization,
    "hho": HHODiscretization,
    "sipg": _dg_variant("sipg"),
    "nipg": _dg_variant("nipg"),
    "iipg": _dg_variant("iipg"),
}

__all__ = ["DISCRETIZATIONS", "Discretization", "FEMDiscretization", "HHODiscretization", "DGDiscretization"]
