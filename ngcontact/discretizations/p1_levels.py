"""What the P1 levels of a nested array hierarchy take from its finest level.

A nested uniform run on a structured rectangle (:class:`~ngcontact.domains.ArrayMesh` levels T_0..T_L, each
finer one carrying its parent table ``ngc_parents``) needs on every level the load vectors (f_a, psi_i) and the
data at the vertices.  Both are computed once, on T_L, and handed down:

* loads (:func:`nested_loads`): F_{j-1} = P_j^T F_j.  P1 spaces of nested meshes are nested, a coarse hat function
  being psi_a + 1/2 sum of the fine hat functions at the midpoints of the edges at a, so this is (f, psi_{j-1})
  integrated with T_L's quadrature -- the same functional, integrated more accurately than on the coarse mesh,
  for the cost of sums instead of an NGSolve mesh, a space and an assembly per level;
* data (:func:`nested_data`): injected, a coarse vertex being the fine vertex whose two parents are itself.

:func:`nested_inputs` gives both per level as keyword arguments of
:class:`~ngcontact.discretizations.fem.FEMDiscretization` (``loads=``, ``data=``); the set-up helpers the
discretization shares with them (:func:`_assemble_load`, :func:`_nodal_data`) live here.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from ngsolve import H1, CoefficientFunction, dx

from ..domains import DIRICHLET, ArrayMesh
from .base import assemble_load, coordinate_only
from .lagrange import LagrangeNodes, meshpoints

__all__ = ["nested_inputs", "nested_loads", "nested_data"]


def nested_inputs(problem, meshes, order: int = 1, constraints: str = "nodal") -> Optional[list]:
    """Per level of a nested array hierarchy ``meshes``, the keyword arguments that hand the level what is
    computed once on the finest level: ``loads`` (:func:`nested_loads`) and ``data`` (:func:`nested_data`), where
    they apply; None when neither does (another order or basis, other meshes)."""
    if not _applies(meshes, order, constraints):
        return None
    out = [{} for _ in meshes]
    for key, values in (("loads", nested_loads(problem, meshes, order, constraints)),
                        ("data", nested_data(problem, meshes, order, constraints))):
        for kw, v in zip(out, values or ()):
            kw[key] = v
    return out if any(out) else None


def nested_data(problem, meshes, order: int = 1, constraints: str = "nodal") -> Optional[list]:
    """The data at the vertices of every level (name -> values, as :func:`_nodal_data` evaluates them): the finest
    level's evaluated, each coarser level's their injection; None where P1 does not stay arrays (data not of the
    coordinates only, another order or basis) or other meshes."""
    if not (_applies(meshes, order, constraints) and all(map(coordinate_only, problem.data().values()))):
        return None
    finest = meshes[-1]
    nodes = LagrangeNodes.from_arrays(np.asarray(finest.X, dtype=float), finest.T,
                                      lambda where: meshpoints(*finest.vertex_location(where)))
    data = [None] * len(meshes)
    data[-1] = _nodal_data(problem, nodes, np.flatnonzero(finest.dirichlet_vertices()))
    for j in range(len(meshes) - 1, 0, -1):
        par = meshes[j].ngc_parents
        old = np.flatnonzero(par[:, 0] == par[:, 1])
        nc = meshes[j - 1].nv
        if len(old) != nc or np.any(np.bincount(par[old, 0], minlength=nc) != 1):
            return None
        inj = np.empty(nc, dtype=np.int64)
        inj[par[old, 0]] = old
        data[j - 1] = {name: v[inj] for name, v in data[j].items()}
    return data


def nested_loads(problem, meshes, order: int = 1, constraints: str = "nodal", quad_bonus: int = 6):
    """The load vectors of every level: list per level of ``problem.nfields`` nodal vectors, the finest level's
    assembled as its discretization assembles them (the same vectors), each coarser level's their restriction
    (module docstring); None when this does not apply (another order or basis, zero loads, other meshes)."""
    if not _applies(meshes, order, constraints) or all(map(_zero, problem.loads)):
        return None
    fes = H1(meshes[-1].build(), order=1, dirichlet=DIRICHLET)
    loads = [None] * len(meshes)
    loads[-1] = [_assemble_load(fes, f, quad_bonus) for f in problem.loads]
    for j in range(len(meshes) - 1, 0, -1):
        a, b = meshes[j].ngc_parents[:, 0], meshes[j].ngc_parents[:, 1]
        nc = meshes[j - 1].nv
        loads[j - 1] = [0.5 * (np.bincount(a, weights=F, minlength=nc) + np.bincount(b, weights=F, minlength=nc))
                        for F in loads[j]]
    return loads


def _applies(meshes, order: int, constraints: str) -> bool:
    """P1 in the Lagrange basis on ArrayMesh levels T_0..T_L, each finer one with its parent table."""
    return order == 1 and constraints != "bernstein" and bool(meshes) \
        and all(isinstance(m, ArrayMesh) for m in meshes) \
        and all(m.ngc_parents is not None and len(m.ngc_parents) == m.nv for m in meshes[1:])


def _zero(f) -> bool:
    """Whether the load ``f`` is NGSolve's zero CoefficientFunction."""
    return isinstance(f, CoefficientFunction) and str(f) == "ZeroCoefficientFunction"


def _assemble_load(fes, f, quad_bonus: int) -> np.ndarray:
    """(f, phi_i) on ``fes``, assembled with f compiled (the same vector, bitwise, faster)."""
    v = fes.TestFunction()
    return assemble_load(fes, lambda: f * v * dx(bonus_intorder=quad_bonus),
                         lambda: f.Compile() * v * dx(bonus_intorder=quad_bonus))


def _nodal_data(problem, nodes, boundary: np.ndarray) -> dict:
    """The data at the Lagrange nodes (every degree) as the FEM set-up evaluates them: Dirichlet data at the
    ``boundary`` nodes only (zero elsewhere; the only nodes where they are used and checked), the others compiled
    and in one pass over the nodes (:meth:`~ngcontact.discretizations.lagrange.LagrangeNodes.evaluate_many`: the
    same values, evaluated faster)."""
    out = {}
    data = problem.data()
    inner = [name for name in data if name not in problem.dirichlet_names]
    if inner:  # one pass over the nodes for all of them
        out.update(zip(inner, nodes.evaluate_many([data[name] for name in inner])))
    for name in problem.dirichlet_names:
        out[name] = np.zeros(nodes.ndof)
        out[name][boundary] = nodes.evaluate(data[name], boundary)
    return {name: out[name] for name in data}
