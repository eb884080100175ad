"""What every discretization declares: the :class:`Discretization` base class, and small shared helpers.

A discretization turns problem data (:class:`~ngcontact.problems.base.Problem`)
and a mesh into an algebraic complementarity system
(:class:`~ngcontact.algebra.system.ComplementaritySystem`) and maps its
solution vectors (x, y) back to fields, errors and reports.  Callers read the
attributes and methods documented here and never probe with ``hasattr``.
"""
from __future__ import annotations

import re
from abc import ABC, abstractmethod
from typing import Optional, Tuple

import numpy as np
import scipy.sparse as sp
from ngsolve import LinearForm, TaskManager

__all__ = ["Discretization", "scipy_csr", "bit_mask", "bit_array", "assemble_load", "evaluate_at_points",
           "coordinate_only", "element_dofs", "element_edges"]


class Discretization(ABC):
    """Base class of the discretizations (FEM, HHO, dG).

    Class attributes
    ----------------
    name : str
        registry key (``fem``, ``hho``, ``sipg``, ``nipg``, ``iipg``).
    orders : tuple of int
        supported polynomial orders.
    estimable : bool
        a posteriori estimators (:mod:`ngcontact.estimators`) exist for it (FEM only).
    array_meshes : bool
        the constructor takes an :class:`~ngcontact.domains.ArrayMesh` as well (FEM: P1 builds its system from
        the arrays, the NGSolve mesh on first use of ``mesh``).

    Attributes set by the constructor
    ---------------------------------
    problem : Problem
    mesh : ngsolve.Mesh
    order : int
    nfields : int
        unknown fields (``problem.nfields``).
    system : ComplementaritySystem
        the algebraic system; its rows are the constraint rows of :attr:`constraint_points`.
    time_assembly : float
        seconds spent by the constructor.

    Sizes and timings
    -----------------
    ndof, n_interior : int
        DOFs as counted in [CAMWA21]; number of constraint rows (``system.m``).
    ndof_sc : int or None
        DOFs after static condensation (HHO), else None.
    time_condense : float or None
        seconds of static condensation and recovery in the Newton steps so far (HHO), else None.
    """

    name: str = "abstract"
    orders: Tuple[int, ...] = ()
    estimable: bool = False
    ndof_sc: Optional[int] = None
    time_condense: Optional[float] = None
    #: the constructor also takes a :class:`~ngcontact.domains.ArrayMesh` (structured rectangles) in place of the mesh
    array_meshes: bool = False

    problem: object
    mesh: object
    order: int
    nfields: int
    system: object
    time_assembly: float

    @property
    def nelem(self) -> int:
        """Number of elements of the mesh."""
        return self.mesh.ne

    @property
    @abstractmethod
    def ndof(self) -> int:
        """DOFs as counted in [CAMWA21]."""

    @property
    @abstractmethod
    def n_interior(self) -> int:
        """Number of constraint rows."""

    @property
    @abstractmethod
    def constraint_points(self) -> np.ndarray:
        """Coordinates (n_interior, 2) of the points of the constraint rows."""

    @abstractmethod
    def initial_guess(self, fields=None):
        """(x0, y0) from CoefficientFunctions per field (None: zero), y0 = 0."""

    @abstractmethod
    def prolongate(self, previous: "Discretization", x, y, cfun: str = "min"):
        """Nested iteration: (x0, y0) on this level from a coarser level's solution (x, y); ``cfun``: the
        C-function of the Newton run that starts from it (a start may be tuned to Newton-min's first step)."""

    def unknown_prolongation(self, previous: "Discretization"):
        """The sparse matrix P with x = P x_c interpolating the unknowns x_c of the coarser, nested level
        ``previous`` (the multigrid hierarchy of :mod:`ngcontact.algebra.multigrid`), or None where this
        discretization does not provide it."""
        return None

    @abstractmethod
    def errors(self, x, y) -> dict:
        """Errors against ``problem.exact`` ({} without an exact solution): at least 'err_energy'."""

    @abstractmethod
    def gridfunctions(self, x, y) -> dict:
        """Named solution fields: ``problem.field_names``, 'lam' and 'gap' (GridFunctions or CFs)."""

    def contact_points(self, x, y) -> np.ndarray:
        """Coordinates (k, 2) of the constraint points in the discrete contact set (gap <= X3)."""
        return self.constraint_points[self.system.gap(x) <= y]

    def complementarity(self, x, y) -> dict:
        """Discrete complementarity over the constraint rows: min gap, min X3, max |gap * X3|."""
        g = self.system.gap(x)
        return {"gap_min": float(g.min(initial=0.0)), "lam_min": float(y.min(initial=0.0)),
                "product_max": float(np.max(np.abs(g * y), initial=0.0))}


def scipy_csr(bf_or_mat) -> sp.csr_matrix:
    """scipy copy of an assembled NGSolve form's (or a sparse matrix's) CSR arrays."""
    mat = getattr(bf_or_mat, "mat", bf_or_mat)
    data, indices, indptr = mat.CSR()  # views: copy before the form goes away
    return sp.csr_matrix((np.array(data), np.array(indices), np.array(indptr)), shape=(mat.height, mat.width))


def bit_mask(bits) -> np.ndarray:
    """Boolean numpy copy of an NGSolve/ngcore ``BitArray`` (e.g. ``fes.FreeDofs()``).  Iterating the BitArray
    from Python takes one Python-level call per bit; here the set bits come from one projection in C++ (a vector
    of ones through ``Projector(bits, True)``)."""
    from ngsolve import Projector
    from ngsolve.la import BaseVector

    n = len(bits)
    if n == 0:
        return np.zeros(0, dtype=bool)
    ones = BaseVector(n)
    ones.FV().NumPy()[:] = 1.0
    out = ones.CreateVector()
    out.data = Projector(bits, True) * ones
    return out.FV().NumPy() != 0.0


def bit_array(mask):
    """NGSolve ``BitArray`` of a boolean numpy mask (the inverse of :func:`bit_mask`; e.g. ``definedonelements``)."""
    from ngsolve import BitArray

    return BitArray(np.asarray(mask, dtype=bool).tolist())


#: node types of a CoefficientFunction tree (its ``str``) whose value at a point depends on the coordinates
#: only: constants, x/y/z, arithmetic and elementary functions, IfPos, parameters, vectors and norms of them
_POINTWISE = re.compile(r"coordinate [xyz]$|binary operation|unary operation|scale -?[0-9.]|-?[0-9.]|ZeroC"
                        r"|\w*IfPosCoefficientFunction|\w*ParameterCoefficientFunction|\w*ConstantCoefficientFunction"
                        r"|VectorialCoefficientFunction|\w*NormCoefficientFunction")


def coordinate_only(cf) -> bool:
    """Whether the scalar CoefficientFunction ``cf`` is built from the coordinates by pointwise operations only
    (no GridFunction, normal vector, mesh size, domain-wise values...), judged from the node types of its tree;
    an unknown node type counts as not.  Such a function can be evaluated on MeshPoints of any mesh that
    contains the point."""
    text = str(cf)
    if text.strip() == "ZeroCoefficientFunction":
        return True
    nodes = re.findall(r"coef ([^,\n]*)", text)
    return bool(nodes) and all(_POINTWISE.match(n.strip()) for n in nodes)


def assemble_load(fes, integrand, compiled=None) -> np.ndarray:
    """Vector of the linear form ``integrand()`` on ``fes``; zero if NGSolve folds it to 0 (zero data).

    ``compiled``: the same integrand with compiled data (the same vector, assembled faster), assembled once
    ``integrand()`` has shown that it is not zero (a compiled zero is no longer folded away)."""
    try:
        lf = LinearForm(integrand())
        if compiled is not None:
            lf = LinearForm(compiled())
        with TaskManager():
            lf.Assemble()
    except Exception as exc:  # NGSolve folds 0 * v away: "Linearform must have TestFunction"
        if "TestFunction" not in str(exc):
            raise
        return np.zeros(fes.ndof)
    return np.array(lf.vec.FV().NumPy())


def evaluate_at_points(mesh, cf, pts: np.ndarray) -> np.ndarray:
    """Values of a scalar CoefficientFunction at points (n, 2) of ``mesh``; points outside the
    mesh (e.g. near a curved boundary) get the value 0."""
    try:
        return np.asarray(cf(mesh(pts[:, 0], pts[:, 1])), dtype=float).reshape(-1)
    except Exception:  # some point outside: one point at a time
        vals = np.zeros(len(pts))
        for i, (px, py) in enumerate(pts):
            try:
                vals[i] = cf(mesh(px, py))
            except Exception:
                vals[i] = 0.0
        return vals


def element_dofs(space) -> np.ndarray:
    """(ne, n): the dof numbers of every volume element of ``space`` in the element's local order (the same number
    n on each element), by one pass over the elements; kept on the space (the Lagrange nodes of FEM and the
    estimators' element operators read the same table of the FE space).  A space whose number of dofs or mesh size
    changed since (``Update`` after a refinement) gets its table again."""
    from ngsolve import VOL, ElementId

    ne = space.mesh.ne
    hit = getattr(space, "_ngcontact_element_dofs", None)
    if hit is not None and hit[0] == (space.ndof, ne):
        return hit[1]
    dofs = np.empty((ne, len(space.GetDofNrs(ElementId(VOL, 0))) if ne else 0), dtype=np.int64)
    for el in space.Elements(VOL):
        dofs[el.nr] = el.dofs
    dofs.flags.writeable = False  # shared by its readers
    try:
        space._ngcontact_element_dofs = ((space.ndof, ne), dofs)
    except AttributeError:  # a space type without attributes: not kept
        pass
    return dofs


def element_edges(space):
    """(ne, 3): the rank of every element's edges, in its local edge order, among the edges of the mesh that carry
    dofs (NGSolve's edge numbers; after a local refinement the parents' edges keep numbers but carry none), read off
    the element dof table of ``space`` when it is an H1 space of one order p >= 2 (the nv vertex dofs, then p - 1
    dofs per edge, edge by edge); None otherwise (P1 holds no edge dofs).  Callers check what they build from it."""
    p = int(getattr(space, "globalorder", 0))
    mesh = space.mesh
    if type(space).__name__ != "H1" or p < 2:
        return None
    n_edge_dofs = space.ndof - mesh.nv - mesh.ne * (p - 1) * (p - 2) // 2
    if n_edge_dofs < 0 or n_edge_dofs % (p - 1):
        return None
    dofs = element_dofs(space)
    if dofs.shape[1] != (p + 1) * (p + 2) // 2:
        return None
    first = dofs[:, 3:3 + 3 * (p - 1):p - 1] - mesh.nv
    edges, rest = np.divmod(first, p - 1)
    if rest.any() or (len(edges) and (edges.min() < 0 or edges.max() >= n_edge_dofs // (p - 1))):
        return None
    return edges
