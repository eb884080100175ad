"""What the estimators see of a discrete solution: the one adapter that reads a discretization.

The estimators work on a conforming Lagrange discretization (:class:`~ngcontact.discretizations.fem.
FEMDiscretization`): u_ah = sum_l (X_a)_l phi_l over the Lagrange nodes x_l, the multiplier
lam_h = sum_l (X3)_l Theta_l (p = 1: Theta_l = phi_l with the lumped weights D_l = (phi_l, 1);
p >= 2: the dual basis, D = 1).  Every estimator function takes

* a :class:`DiscretizationView` -- the mesh, the FE degree p, the problem data per field, the nodal
  data (the map from nodal values to the coefficients of the FE space, the interior nodes, D), the
  algebraic system (residual and nodal gap of an iterate) and a per-discretization cache; or
* a :class:`SolutionView` -- that plus one iterate (x, y) and its fields u_ah, lam_h, gap.

The public entry points take ``(disc, x, y)`` and build the views here, once per call.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from typing import Optional, Tuple

import numpy as np
from ngsolve import CoefficientFunction, GridFunction

__all__ = ["FieldData", "DiscretizationView", "SolutionView", "expect_repeated_evaluations", "REPEATED"]


@dataclass
class FieldData:
    """One membrane (or the obstacle problem's only field).

    Attributes
    ----------
    name : str
        ``"u1"``, ``"u2"`` or ``"u"``.
    mu : float
        tension mu_alpha.
    f : CoefficientFunction
        load f_alpha.
    sign : int
        s_alpha = -(-1)^alpha: div(-mu grad u) = f + s lam  (+1 for u1 / u, -1 for u2).
    u : GridFunction
        discrete solution u_alpha_h (Dirichlet lifting included).
    g : CoefficientFunction, optional
        Dirichlet data g_alpha.
    """

    name: str
    mu: float
    f: CoefficientFunction
    sign: int
    u: GridFunction
    g: Optional[CoefficientFunction] = None


_CACHE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _cache_of(disc) -> dict:
    """Per-discretization cache (mesh-dependent objects reused along Newton iterations)."""
    try:
        return _CACHE.setdefault(disc, {})
    except TypeError:  # not weak-referenceable: no cache
        return {}


#: key of the per-discretization cache marking it for repeated estimator evaluations
REPEATED = "repeated_evaluations"


def expect_repeated_evaluations(disc) -> None:
    """Mark ``disc``: its estimators will be evaluated many times (every few Krylov iterations of an adaptive
    inexact Newton loop), so the per-mesh structures that pay off only over repeated calls (the inverses of the
    patch matrices and the sparse patch step of :mod:`.patches`) are built at the first evaluation already."""
    _cache_of(disc)[REPEATED] = True


@dataclass(frozen=True, eq=False)
class DiscretizationView:
    """The data of one discretization that the estimators use (independent of the iterate).

    Attributes
    ----------
    mesh : ngsolve.Mesh
    order : int
        FE degree p.
    quad_bonus : int
        extra quadrature order of the FE load integrals.
    problem : TwoMembraneProblem or ObstacleProblem
        for its domain (Friedrichs constant) and exact solution.
    curved : bool
        curved elements (a netgen geometry with a curved boundary or interface and p >= 2).
    names, mus, loads, dirichlet, signs : tuple
        per field: name, tension mu_a, load f_a, Dirichlet data g_a, s_a (+1, -1 / +1).
    obstacle : CoefficientFunction or None
        psi of the obstacle problem (gap u - psi), None for two membranes (gap u1 - u2).
    fes : ngsolve.FESpace
        the H1 space of u_ah.
    to_coefficients : scipy.sparse matrix
        nodal values at all Lagrange nodes -> coefficients of ``fes``.
    interior : ndarray
        indices of the interior Lagrange nodes among all nodes (the unknowns of x and y).
    D : ndarray
        multiplier weights per interior node: (phi_l, 1) for p = 1, 1 for p >= 2.
    system : ComplementaritySystem
        the algebraic system (``residual``, ``gap``, ``F``, ``K``) in the layout of (x, y).
    cache : dict
        per-discretization cache of mesh-dependent objects (patch solvers, liftings, factorizations).
    """

    mesh: object
    order: int
    quad_bonus: int
    problem: object
    curved: bool
    names: Tuple[str, ...]
    mus: Tuple[float, ...]
    loads: tuple
    dirichlet: tuple
    signs: Tuple[int, ...]
    obstacle: Optional[CoefficientFunction]
    fes: object
    to_coefficients: object
    interior: np.ndarray
    D: np.ndarray
    system: object
    cache: dict = field(repr=False)
    _disc: object = field(repr=False)
    obstacle_grad: Optional[CoefficientFunction] = None  # grad of ``obstacle`` (None: its Diff in x and y)

    @classmethod
    def of(cls, disc) -> "DiscretizationView":
        """The view of a conforming Lagrange discretization (``FEMDiscretization``)."""
        problem, nf = disc.problem, disc.nfields
        names, loads, dirichlet = tuple(problem.field_names), tuple(problem.loads), tuple(problem.dirichlet)
        return cls(mesh=disc.mesh, order=disc.order, quad_bonus=disc.quad_bonus, problem=problem,
                   curved=bool(getattr(problem.domain, "curved", False)) and disc.order > 1,
                   names=names, mus=tuple(problem.mus), loads=loads, dirichlet=dirichlet,
                   signs=(+1, -1)[:nf], obstacle=problem.psi if nf == 1 else None, fes=disc.fes,
                   to_coefficients=disc.nodes.T, interior=disc.interior, D=disc.D, system=disc.system,
                   cache=_cache_of(disc), _disc=disc)

    @property
    def nfields(self) -> int:
        return len(self.names)

    @property
    def n_interior(self) -> int:
        return len(self.interior)

    def hats_at_nodes(self):
        """Psi (interior Lagrange nodes x vertices, CSR): Psi[l, a] = psi_a(x_l), psi_a the hat function of
        vertex a (vertex a = dof a of ``H1(order=1)``); cached."""
        if "hats_at_nodes" not in self.cache:
            nv = self.mesh.nv
            self.cache["hats_at_nodes"] = self._disc.nodes.V[self.interior][:, :nv].tocsr()
        return self.cache["hats_at_nodes"]

    def element_vertices(self) -> np.ndarray:
        """(ne, 3) vertex numbers of the elements, in the local order of ``Discontinuous(H1(order=1))``; cached."""
        if "ev" not in self.cache:
            self.cache["ev"] = self.mesh.ngmesh.Elements2D().NumPy()["nodes"][:, :3].astype(np.int64) - 1
        return self.cache["ev"]

    def function(self, nodal: np.ndarray, name: str = "") -> GridFunction:
        """The function of ``fes`` with the given values at all Lagrange nodes."""
        gf = GridFunction(self.fes, name=name)
        gf.vec.FV().NumPy()[:] = self.to_coefficients @ nodal
        return gf

    def interior_function(self, values: np.ndarray, name: str = "") -> GridFunction:
        """The function of ``fes`` with the given values at the interior nodes, zero on the boundary."""
        return self.function(self.extend(values), name)

    def extend(self, values: np.ndarray) -> np.ndarray:
        """Interior nodal values padded with zeros on the boundary nodes."""
        full = np.zeros(self.fes.ndof)
        full[self.interior] = values
        return full

    def dual_function(self, values: np.ndarray, name: str = "") -> GridFunction:
        """The function r_h of ``fes`` with (r_h, phi_l) = values_l at the interior nodes, r_h = 0 at the
        boundary nodes (dual basis; the Lagrange mass matrix is factorized once by the discretization)."""
        return self.function(self._disc.mass_nodal_solver().solve(self.extend(values)), name)


@dataclass(frozen=True, eq=False)
class SolutionView:
    """One iterate (x, y) on a :class:`DiscretizationView`.

    Attributes
    ----------
    disc : DiscretizationView
    x, y : ndarray
        interior nodal values [X1, X2] (or [X]) and the multiplier coefficients X3.
    gfs : dict
        ``u1``, ``u2`` (or ``u``), ``lam`` (lam_h) and ``gap`` (u1h - u2h or u_h - psi).
    fields : tuple of FieldData
    cache : dict
        quantities of this iterate computed once (e.g. the residual multiplier of :mod:`.boundary`).
    """

    disc: DiscretizationView
    x: np.ndarray
    y: np.ndarray
    gfs: dict
    fields: Tuple[FieldData, ...]
    cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, disc, x, y) -> "SolutionView":
        dv = DiscretizationView.of(disc)
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        ni, nf = dv.n_interior, dv.nfields
        if len(x) != nf * ni or len(y) != ni:
            raise ValueError(f"x must have {nf * ni} and y {ni} entries, got {len(x)} and {len(y)}")
        gfs = disc.gridfunctions(x, y)
        fields = tuple(FieldData(n, mu, f, s, gfs[n], g)
                       for n, mu, f, s, g in zip(dv.names, dv.mus, dv.loads, dv.signs, dv.dirichlet))
        return cls(disc=dv, x=x, y=y, gfs=gfs, fields=fields)

    def nodal_fields(self) -> dict:
        """Values of u_ah and lam_h at all Lagrange nodes (boundary included)."""
        return self.disc._disc.nodal_fields(self.x, self.y)

    def energy_error(self) -> Optional[float]:
        """|||u - u_h||| when the exact solution is known, else None."""
        if self.disc.problem.exact is None:
            return None
        return self.disc._disc.errors(self.x, self.y).get("err_energy")
