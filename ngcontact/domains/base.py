"""What every domain shares: the boundary names, the :class:`Domain` interface, argument checks and
mesh measures."""
from __future__ import annotations

import gc
import importlib
import math
import numbers
import sys
from typing import Any, Iterator

import netgen.meshing as ngm
import numpy as np
import ngsolve

__all__ = ["DIRICHLET", "INTERFACE", "Domain", "check_triangular", "import_collected", "matplotlib_tri",
           "mesh_size"]

_SIDES = ("bottom", "right", "top", "left")

#: NGSolve ``dirichlet=`` regex of the outer boundary: every named boundary segment except internal
#: interfaces (std::regex, full match)
DIRICHLET = "(?!interface$).*"
INTERFACE = "interface"


def import_collected(name: str):
    """The module ``name``, imported on first use and followed by one garbage collection.  Importing matplotlib (for
    point location or plots) leaves cyclic garbage: parser exceptions whose tracebacks reach, through the frames'
    ``f_back``, the frames of the caller -- a whole run when the import happens during it -- so that everything the
    run's functions held when they returned (meshes and systems of every level, the result) would stay in memory
    until the next full collection.  The collection right after the import frees that garbage while those frames are
    still executing (nothing of the run is collected)."""
    module = sys.modules.get(name)
    if module is None:
        module = importlib.import_module(name)
        gc.collect()
    return module


def matplotlib_tri():
    """matplotlib.tri (point location in triangulations) by :func:`import_collected`."""
    return import_collected("matplotlib.tri")


def mesh_size(mesh) -> float:
    """Largest edge length (element diameter) of a triangular mesh.

    Parameters
    ----------
    mesh : ngsolve.Mesh or netgen.meshing.Mesh
        A 2D triangular mesh; curved elements are measured by their straight
        edges.

    Returns
    -------
    float
        ``max_K diam(K)``.
    """
    ngmesh = getattr(mesh, "ngmesh", mesh)
    P = ngmesh.Coordinates()[ngmesh.Elements2D().NumPy()["nodes"][:, :3] - 1]
    return float(np.sqrt(((P - np.roll(P, 1, axis=1)) ** 2).sum(axis=-1)).max())


def check_triangular(ngmesh, what: str) -> None:
    """ValueError unless ``ngmesh`` (netgen mesh) is a 2D mesh of triangles: the discretizations (Lagrange
    nodes, RT fluxes, bisection) are written for triangles.  ``what`` names the mesh in the message."""
    if ngmesh.dim != 2 or len(ngmesh.Elements3D()) > 0:
        raise ValueError(f"{what} is a {ngmesh.dim}D mesh; ngcontact solves 2D problems on triangular meshes")
    nodes = ngmesh.Elements2D().NumPy()["nodes"]
    if len(nodes) == 0:
        raise ValueError(f"{what} has no 2D elements")
    if nodes.shape[1] > 3 and (nquad := int(np.count_nonzero(nodes[:, 3]))):
        raise ValueError(f"{what} has {nquad} quadrilateral element(s) of {len(nodes)}; ngcontact needs a triangular "
                         f"mesh (netgen: GenerateMesh without quad_dominated)")
    X = np.asarray(ngmesh.Coordinates())[:, :2]
    P = X[nodes[:, :3].astype(np.int64) - 1]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    area2 = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    diam2 = np.max([np.sum(e1 ** 2, axis=1), np.sum(e2 ** 2, axis=1), np.sum((P[:, 2] - P[:, 1]) ** 2, axis=1)], axis=0)
    flat = np.flatnonzero(~(area2 > 1e-12 * diam2))  # (twice) the area relative to the squared diameter
    if len(flat):
        k = int(flat[0])
        corners = [tuple(float(c) for c in v) for v in P[k]]
        raise ValueError(f"{what} has {len(flat)} degenerate triangle(s) (zero area relative to the squared diameter, "
                         f"or repeated vertices), e.g. element {k} with vertices {corners}")


def _fail(obj, field: str, value: Any, what: str):
    raise ValueError(f"{type(obj).__name__}.{field} must be {what}, got {value!r}")


def _is_int(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _is_real(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def _check_positive(obj, name: str):
    if not (_is_real(v := getattr(obj, name)) and v > 0):
        _fail(obj, name, v, "a positive finite number")


def _check_level(level, name: str = "level") -> int:
    if not (_is_int(level) and level >= 0):
        raise ValueError(f"{name} must be a non-negative integer, got {level!r}")
    return int(level)


class Domain:
    """Base class: a domain and its sequence of nested meshes T_0, T_1, ...

    Subclasses implement ``name`` and ``_ngmeshes(start, stop)``, a generator
    of independent netgen meshes for the levels ``start, ..., stop - 1``.
    """

    curved: bool = False  #: True if the boundary is curved (call ``mesh.Curve(p)``)

    @property
    def name(self) -> str:
        """Short human-readable description."""
        raise NotImplementedError

    def _ngmeshes(self, start: int, stop: int) -> Iterator[ngm.Mesh]:
        raise NotImplementedError

    def mesh(self, level: int = 0) -> ngsolve.Mesh:
        """A fresh mesh T_level (``level`` uniform refinements of T_0)."""
        level = _check_level(level)
        return ngsolve.Mesh(next(self._ngmeshes(level, level + 1)))

    def meshes(self, levels: int, arrays: bool = False) -> Iterator[ngsolve.Mesh]:
        """Yield T_0, ..., T_{levels-1}, refining incrementally.

        The yielded meshes are independent objects: refining or curving one
        does not affect the others.  ``arrays``: the caller also accepts :class:`ArrayMesh`
        levels (structured rectangles yield them; other domains yield NGSolve meshes anyway).
        """
        for ngmesh in self._ngmeshes(0, _check_level(levels, "levels")):
            yield ngsolve.Mesh(ngmesh)

    def h(self, level: int = 0, mesh=None) -> float:
        """Mesh size of T_level: ``mesh_size`` of T_level, cached per level.  ``mesh``: T_level as the caller has
        it (an NGSolve mesh of this domain's level), measured instead of generating the level again (for a netgen
        geometry: the coarse mesh and ``level`` refinements)."""
        level, cache = _check_level(level), self.__dict__.setdefault("_h_cache", {})
        if level not in cache:
            cache[level] = mesh_size(mesh if isinstance(mesh, ngsolve.Mesh) else self.mesh(level))
        return cache[level]


