"""Computational domains and their hierarchies of nested triangular meshes.

A domain knows nothing about finite element spaces: it produces the meshes
T_0, T_1, ... where T_j is obtained from the coarse mesh T_0 by j uniform
("red") refinements, every triangle being split into four by its edge
midpoints; on curved boundaries the new points are placed on the curve.
Every boundary segment carries a name, so ``dirichlet=DIRICHLET`` selects the
whole boundary; an internal curve named ``interface`` (mesh lines fitted to a
data discontinuity, e.g. ``UnitDisk(interface_radius=...)``) is not part of it.

Structured squares are built level by level with numpy and netgen's
vectorized ``AddPoints`` / ``AddElements`` (or, for callers that accept them,
yielded as :class:`ArrayMesh` levels whose NGSolve mesh is built on first use);
domains given by a netgen
geometry (or a ``.vol`` file) are refined by ``netgen.meshing.Mesh.Refine``,
which splits every triangle 1 -> 4 and projects new boundary points onto the
geometry.
"""
from __future__ import annotations

import math
import numbers
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Optional

import netgen.meshing as ngm
import numpy as np
import ngsolve
from netgen.geom2d import SplineGeometry

__all__ = ["DIRICHLET", "Domain", "ArrayMesh", "CrissCrossSquare", "StructuredSquare", "GeometryDomain",
           "UnitDisk", "LShape", "MeshFileDomain", "MeshDomain", "as_domain", "check_triangular", "mesh_size"]

_SIDES = ("bottom", "right", "top", "left")

#: NGSolve ``dirichlet=`` regex of the outer boundary: every named boundary segment except internal
#: interfaces (std::regex, full match)
DIRICHLET = "(?!interface$).*"
INTERFACE = "interface"


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

    def h(self, level: int = 0) -> float:
        """Mesh size of T_level: ``mesh_size(self.mesh(level))``, cached per level."""
        level, cache = _check_level(level), self.__dict__.setdefault("_h_cache", {})
        if level not in cache:
            cache[level] = mesh_size(self.mesh(level))
        return cache[level]


# ---- structured rectangles: numpy arrays (X, T, S, tag) -> netgen mesh ----

def _red_refine(X, T, S, tag, parents: Optional[list] = None):
    """One red refinement of vertex/triangle/segment arrays (straight boundary).

    Old vertices keep their numbers, new ones (edge midpoints) follow; the
    children of triangle k are triangles 4k, ..., 4k+3, all oriented like
    their parent, the last one being the middle triangle.  ``parents``: a
    list to which the (nv_fine, 2) parent table (see ``_BoxDomain.meshes``) is appended.
    """
    nv = len(X)
    E = np.sort(T[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1).astype(np.int64)
    keys, inv = np.unique(E[:, 0] * nv + E[:, 1], return_inverse=True)
    X = np.vstack([X, 0.5 * (X[keys // nv] + X[keys % nv])])
    if parents is not None:
        old = np.arange(nv, dtype=np.int64)
        parents.append(np.concatenate([np.stack([old, old], axis=1), np.stack([keys // nv, keys % nv], axis=1)]))
    a, b, c = T.T
    ab, bc, ca = (nv + inv.reshape(-1, 3)).T
    T = np.stack([a, ab, ca, ab, b, bc, ca, bc, c, ab, bc, ca], axis=1).reshape(-1, 3)
    s = np.sort(S, axis=1).astype(np.int64)
    m = nv + np.searchsorted(keys, s[:, 0] * nv + s[:, 1])
    S = np.stack([S[:, 0], m, m, S[:, 1]], axis=1).reshape(-1, 2)
    return X, T, S, np.repeat(tag, 2)


def _grid(n: int, box):
    """Vertices of the (n+1) x (n+1) grid (index i + (n+1) j) and its boundary."""
    xmin, xmax, ymin, ymax = box
    gx, gy = np.meshgrid(np.linspace(xmin, xmax, n + 1), np.linspace(ymin, ymax, n + 1))
    X = np.column_stack([gx.ravel(), gy.ravel()])
    k, m = np.arange(n), n + 1
    # counterclockwise segments (domain on the left): bottom, right, top, left
    S = np.concatenate([np.c_[k, k + 1], np.c_[k * m + n, (k + 1) * m + n],
                        np.c_[n * m + k + 1, n * m + k], np.c_[(k + 1) * m, k * m]])
    return X, S, np.repeat(np.arange(4), n)


def _to_ngmesh(X, T, S, tag) -> ngm.Mesh:
    """Netgen 2D mesh with region "domain" and boundary regions bottom/right/top/left.

    Its topology has no face table: in 2D NGSolve numbers the element-interior dofs by element and reads the
    edges and vertices only (tests/test_setup_memory.py compares spaces, forms and refinement with and without
    it); the table (one face per triangle) is about half the time of ``ngsolve.Mesh`` at 1e6 triangles."""
    mesh = ngm.Mesh(dim=2)
    mesh.EnableTable("faces", False)
    mesh.AddPoints(np.ascontiguousarray(X, dtype=np.float64))
    dom = mesh.AddRegion("domain", dim=2)
    mesh.AddElements(dim=2, index=dom, data=np.ascontiguousarray(T, dtype=np.int32), base=0)
    for k, side in enumerate(_SIDES):
        idx = mesh.AddRegion(side, dim=1)
        seg = np.ascontiguousarray(S[tag == k], dtype=np.int32)
        mesh.AddElements(dim=1, index=idx, data=seg, base=0)
    return mesh


class _CoarseLocator:
    """Where the vertices of finer levels lie in the coarsest mesh T_0 of a hierarchy of straight-sided
    meshes: (element of T_0, NGSolve reference coordinates), for MeshPoints on T_0
    (:meth:`ArrayMesh.vertex_location`)."""

    def __init__(self, X0: np.ndarray, T0: np.ndarray, S0, tag0):
        self.mesh = ngsolve.Mesh(_to_ngmesh(X0, T0, S0, tag0))
        self.X0, self.T0 = np.asarray(X0, dtype=float), np.asarray(T0, dtype=np.int64)
        # NGSolve's reference triangle has the vertices (1,0), (0,1), (0,0): the local coordinates of p in element
        # (A, B, C) are the first two barycentric coordinates, [A - C, B - C]^-1 (p - C); per element: C, the inverse
        A, B, C = self.X0[self.T0].transpose(1, 0, 2)
        (ax, ay), (bx, by) = (A - C).T, (B - C).T
        det = ax * by - ay * bx
        self._affine = (C[:, 0].copy(), C[:, 1].copy(), by / det, -bx / det, -ay / det, ax / det)

    #: points located per batch (bounds the temporaries)
    CHUNK = 1 << 18

    def locate(self, pts: np.ndarray):
        """(elements (n,), reference coordinates (n, 2)) of the points ``pts`` (n, 2) of the domain."""
        import matplotlib.tri as mtri

        finder = mtri.Triangulation(self.X0[:, 0], self.X0[:, 1], self.T0).get_trifinder()
        n = len(pts)
        el, ref = np.empty(n, dtype=np.int32 if len(self.T0) < 2 ** 31 else np.int64), np.empty((n, 2))
        for lo in range(0, n, self.CHUNK):
            px, py = np.ascontiguousarray(pts[lo:lo + self.CHUNK, 0]), np.ascontiguousarray(pts[lo:lo + self.CHUNK, 1])
            e = np.asarray(finder(px, py))
            if len(e) and e.min() < 0:
                raise ValueError("a vertex of a finer level lies outside the coarsest mesh")
            cx, cy, i00, i01, i10, i11 = (a[e] for a in self._affine)
            rx, ry = px - cx, py - cy
            el[lo:lo + len(e)] = e
            ref[lo:lo + len(e), 0] = i00 * rx + i01 * ry
            ref[lo:lo + len(e), 1] = i10 * rx + i11 * ry
        return el, ref


class ArrayMesh:
    """One level T_j of a structured rectangle held as its arrays; the NGSolve mesh is built on first
    :meth:`build`.

    What conforming P1 needs for its algebraic system is in the arrays: the stiffness from the triangles,
    the Dirichlet vertices from the boundary segments, the nested prolongation from ``ngc_parents``; data that
    depend on the coordinates only are evaluated at the vertices on MeshPoints of the coarsest mesh T_0
    (:meth:`vertex_location`: one element switch per coarse element instead of one per vertex).  The NGSolve mesh
    (errors, GridFunctions, VTK, estimators) is built only when something asks for it; it is the mesh that
    :meth:`Domain.meshes` yields for this level (same vertices, triangles, segments and ``ngc_parents``).
    """

    def __init__(self, X, T, S, tag, parents, coarse: Optional[_CoarseLocator] = None):
        self.X, self.T, self.S, self.tag = X, T, S, tag
        self.ngc_parents = parents
        self._coarse = coarse
        self._mesh = None
        self._points = None

    @property
    def nv(self) -> int:
        return len(self.X)

    @property
    def ne(self) -> int:
        return len(self.T)

    def locator(self) -> _CoarseLocator:
        """The locator of this mesh taken as the coarsest level (T_0 of the hierarchy)."""
        if self._coarse is None:
            self._coarse = _CoarseLocator(self.X, self.T, self.S, self.tag)
        return self._coarse

    def build(self) -> ngsolve.Mesh:
        """The NGSolve mesh of this level (built once)."""
        if self._mesh is None:
            self._mesh = ngsolve.Mesh(_to_ngmesh(self.X, self.T, self.S, self.tag))
            self._mesh.ngc_parents = self.ngc_parents
        return self._mesh

    def dirichlet_vertices(self) -> np.ndarray:
        """Boolean mask of the vertices on the boundary segments whose name matches :data:`DIRICHLET`
        (what ``H1(mesh, order=1, dirichlet=DIRICHLET)`` fixes)."""
        import re

        bnd = np.zeros(self.nv, dtype=bool)
        for k, side in enumerate(_SIDES):
            if re.fullmatch(DIRICHLET, side):
                bnd[self.S[self.tag == k].ravel()] = True
        return bnd

    def vertex_location(self, where: Optional[np.ndarray] = None):
        """(T_0 as NGSolve mesh, elements, xi, eta): where the vertices (or the vertices ``where``) lie in the
        coarsest mesh T_0, for MeshPoints there (``discretizations.lagrange.meshpoints``) at which
        CoefficientFunctions of the coordinates only are evaluated (a GridFunction of this level must not be)."""
        if self._points is None:
            self._points = self.locator().locate(np.asarray(self.X, dtype=float))
        el, ref = self._points
        if where is not None:
            el, ref = el[where], ref[where]
        return self._coarse.mesh, el, ref[:, 0], ref[:, 1]


class _BoxDomain(Domain):
    """Rectangle [xmin, xmax] x [ymin, ymax] built from numpy arrays."""

    @property
    def _box(self):
        return (float(self.xmin), float(self.xmax), float(self.ymin), float(self.ymax))

    def __post_init__(self):
        if not (_is_int(self.n0) and self.n0 > 0):
            _fail(self, "n0", self.n0, "a positive integer")
        for lo, hi in (("xmin", "xmax"), ("ymin", "ymax")):
            a, b = getattr(self, lo), getattr(self, hi)
            if not _is_real(a):
                _fail(self, lo, a, "a finite number")
            if not (_is_real(b) and b > a):
                _fail(self, hi, b, f"a finite number > {lo} = {a!r}")

    @property
    def name(self) -> str:
        return (f"{self._kind} {self.n0}x{self.n0} on "
                f"[{self.xmin:g},{self.xmax:g}]x[{self.ymin:g},{self.ymax:g}]")

    def _arrays(self, level: int):
        raise NotImplementedError

    def _next(self, arrays, level: int, parents: Optional[list] = None):
        """Arrays of ``level`` given those of ``level - 1`` (``parents``: append the parent table)."""
        return self._arrays(level)

    #: ``_next`` refines the arrays of the level before (False: builds the level afresh, and the arrays of a
    #: level are not kept while it is in use)
    _next_refines = True

    def _levels(self, start, stop):
        arrays, parents = self._arrays(start), []
        for level in range(start, stop):
            if level > start:
                arrays = self._next(arrays, level, parents)
            box = [arrays, (parents.pop() if parents else None)]
            if not self._next_refines:
                arrays = None
            yield box  # the consumer empties the box: the arrays go once the mesh is built

    def _ngmeshes(self, start, stop):
        for box in self._levels(start, stop):
            ngmesh = _to_ngmesh(*box.pop(0))
            box.clear()
            yield ngmesh

    def meshes(self, levels: int, arrays: bool = False) -> Iterator[ngsolve.Mesh]:
        """Yield T_0, ..., T_{levels-1} (independent objects, see :meth:`Domain.meshes`).

        T_j (j >= 1) carries ``ngc_parents``: an (nv_j, 2) integer array, vertex v of T_j being the
        midpoint of vertices ngc_parents[v] of T_{j-1} (a repeated index: v is that coarse vertex).
        Nested P1 prolongation reads it instead of matching coordinates
        (``discretizations.fem._parent_p1_values``; it still checks the coordinates).
        ``arrays``: yield :class:`ArrayMesh` levels (their NGSolve mesh is built on first use).
        """
        coarse = None
        for box in self._levels(0, _check_level(levels, "levels")):
            (X, T, S, tag), parents = box.pop(0), box.pop()
            if not arrays:
                mesh = ngsolve.Mesh(_to_ngmesh(X, T, S, tag))
                mesh.ngc_parents = parents
                yield mesh
                continue
            if len(X) < np.iinfo(np.int32).max:  # the index type of the P1 tables and of netgen's elements
                T = T.astype(np.int32)
            level = ArrayMesh(X, T, S, tag, parents, coarse)
            coarse = coarse or level.locator()
            X = T = S = tag = None
            yield level

    def h(self, level: int = 0) -> float:
        """Nominal mesh size: side of the squares of T_level (longest side if a rectangle)."""
        level = _check_level(level)
        return max(self.xmax - self.xmin, self.ymax - self.ymin) / (self.n0 * 2 ** level)


@dataclass(frozen=True)
class CrissCrossSquare(_BoxDomain):
    """Criss-cross meshes of a rectangle, [CAMWA21] criss-cross meshes T0..Tj.

    T_0 consists of ``n0 x n0`` squares, each cut into four triangles by both
    diagonals; T_j is obtained by j red refinements (4^j * 4 n0^2 triangles;
    for ``n0 = 4`` on the unit square T_0 has 64 triangles, 41 vertices,
    104 edges and h_0 = 0.25, and T_4 has 16384 triangles).

    Parameters
    ----------
    n0 : int
        Number of squares per side of T_0.
    xmin, xmax, ymin, ymax : float
        The rectangle. Boundary names are ``bottom``, ``right``, ``top``,
        ``left``.
    """

    _kind = "criss-cross"
    n0: int = 4
    xmin: float = 0.0
    xmax: float = 1.0
    ymin: float = 0.0
    ymax: float = 1.0


    def _arrays(self, level):
        n, box = self.n0, self._box
        X, S, tag = _grid(n, box)
        hx, hy = (box[1] - box[0]) / n, (box[3] - box[2]) / n
        centers = X.reshape(n + 1, n + 1, 2)[:-1, :-1].reshape(-1, 2) + [hx / 2, hy / 2]
        i, j = np.meshgrid(np.arange(n), np.arange(n))
        a = (i + (n + 1) * j).ravel()
        b, c, d, m = a + 1, a + n + 2, a + n + 1, (n + 1) ** 2 + np.arange(n * n)
        T = np.stack([a, b, m, b, c, m, c, d, m, d, a, m], axis=1).reshape(-1, 3)
        arrays = (np.vstack([X, centers]), T, S, tag)
        for _ in range(level):
            arrays = _red_refine(*arrays)
        return arrays

    def _next(self, arrays, level, parents=None):
        return _red_refine(*arrays, parents=parents)


@dataclass(frozen=True)
class StructuredSquare(_BoxDomain):
    """Rectangle cut into ``N x N`` cells, each split by one diagonal.

    All diagonals run from (x_i, y_j) to (x_{i+1}, y_{j+1}) as in PETSc DMDA
    P1 meshes; level j has ``N = n0 * 2**j``, which is nested (red refinement
    reproduces the pattern).

    Parameters
    ----------
    n0 : int
        Cells per side of T_0.
    xmin, xmax, ymin, ymax : float
        The rectangle; boundary names ``bottom``, ``right``, ``top``, ``left``.
    """

    _kind = "structured"
    _next_refines = False
    n0: int = 16
    xmin: float = 0.0
    xmax: float = 1.0
    ymin: float = 0.0
    ymax: float = 1.0


    def _arrays(self, level):
        n = self.n0 * 2 ** level
        X, S, tag = _grid(n, self._box)
        i, j = np.meshgrid(np.arange(n), np.arange(n))
        a = (i + (n + 1) * j).ravel()
        T = np.stack([a, a + 1, a + n + 2, a, a + n + 2, a + n + 1], axis=1).reshape(-1, 3)
        return X, T, S, tag

    def _next(self, arrays, level, parents=None):
        if parents is not None:  # grid index i + (2n+1) j of T_level from the n x n grid of T_{level-1}
            n = self.n0 * 2 ** (level - 1)
            j, i = np.divmod(np.arange((2 * n + 1) ** 2, dtype=np.int64), 2 * n + 1)
            lo = (i // 2) + (n + 1) * (j // 2)  # (floor(i/2), floor(j/2)); the diagonals run (i,j)-(i+1,j+1)
            hi = ((i + 1) // 2) + (n + 1) * ((j + 1) // 2)
            parents.append(np.stack([lo, hi], axis=1))
        return self._arrays(level)


# ---- netgen geometries and mesh files: refined by netgen ----

class _NetgenDomain(Domain):
    """Levels by ``netgen.meshing.Mesh.Refine`` (1 -> 4, boundary points on the geometry)."""

    def _coarse(self) -> ngm.Mesh:
        raise NotImplementedError

    def _ngmeshes(self, start, stop):
        ngmesh = self._coarse()
        check_triangular(ngmesh, f"the coarse mesh of {self.name}")
        for level in range(stop):
            if level >= start:
                yield ngmesh if level == stop - 1 else ngmesh.Copy()
            if level < stop - 1:
                ngmesh.Refine()


@dataclass(frozen=True)
class GeometryDomain(_NetgenDomain):
    """Any 2D netgen geometry meshed with ``geometry.GenerateMesh(maxh=maxh)``.

    Parameters
    ----------
    geometry : netgen geometry
        E.g. ``netgen.geom2d.SplineGeometry``, ``CSG2d`` or
        ``netgen.occ.OCCGeometry(..., dim=2)``.
    maxh : float
        Maximal mesh size of T_0.
    label : str
        Returned by ``name``.
    curved : bool
        Whether the boundary is curved (the FE code then calls ``mesh.Curve(p)``).
    """

    geometry: Any
    maxh: float
    label: str = "geometry"
    curved: bool = True

    def __post_init__(self):
        if not callable(getattr(self.geometry, "GenerateMesh", None)):
            _fail(self, "geometry", self.geometry, "a netgen geometry with GenerateMesh")
        _check_positive(self, "maxh")
        if not isinstance(self.label, str):
            _fail(self, "label", self.label, "a string")
        if not isinstance(self.curved, bool):
            _fail(self, "curved", self.curved, "a bool")

    @property
    def name(self) -> str:
        return f"{self.label} (maxh={self.maxh:g})"

    def _coarse(self):
        return self.geometry.GenerateMesh(maxh=self.maxh)


@dataclass(frozen=True)
class UnitDisk(GeometryDomain):
    """The disk of given ``radius`` and ``center`` (boundary name ``boundary``); curved."""

    geometry: Any = field(default=None, init=False, repr=False, compare=False)
    maxh: float = 0.2
    label: str = field(default="disk", init=False, repr=False)
    curved: bool = field(default=True, init=False, repr=False)
    radius: float = 1.0
    center: tuple = (0.0, 0.0)
    interface_radius: Optional[float] = None  # mesh lines on the concentric circle of this radius

    def __post_init__(self):
        _check_positive(self, "radius")
        c = self.center
        if not (isinstance(c, (tuple, list, np.ndarray)) and len(c) == 2 and all(map(_is_real, c))):
            _fail(self, "center", c, "a pair of finite numbers")
        object.__setattr__(self, "center", (float(c[0]), float(c[1])))
        ri = self.interface_radius
        if ri is not None and not (_is_real(ri) and 0 < ri < self.radius):
            _fail(self, "interface_radius", ri, f"a number in (0, radius = {self.radius:g}) or None")
        geo = SplineGeometry()
        if ri is None:
            geo.AddCircle(self.center, self.radius, bc="boundary")
        else:  # two subdomains; the inner circle is an internal curve named INTERFACE (not Dirichlet)
            geo.AddCircle(self.center, self.radius, bc="boundary", leftdomain=2, rightdomain=0)
            geo.AddCircle(self.center, float(ri), bc=INTERFACE, leftdomain=1, rightdomain=2)
            geo.SetMaterial(1, "inner")
            geo.SetMaterial(2, "outer")
        object.__setattr__(self, "geometry", geo)
        super().__post_init__()

    @property
    def name(self) -> str:
        (cx, cy), r = self.center, self.radius
        fit = "" if self.interface_radius is None else f", mesh fitted to r={self.interface_radius:.4g}"
        return f"disk r={r:g} c=({cx:g},{cy:g}){fit} (maxh={self.maxh:g})"


@dataclass(frozen=True)
class LShape(GeometryDomain):
    """L-shaped domain (-1, 1)^2 minus [0, 1] x [-1, 0]: re-entrant corner at the origin."""

    geometry: Any = field(default=None, init=False, repr=False, compare=False)
    maxh: float = 0.25
    label: str = field(default="L-shape", init=False, repr=False)
    curved: bool = field(default=False, init=False, repr=False)

    def __post_init__(self):
        geo = SplineGeometry()
        pts = [geo.AppendPoint(*p) for p in [(-1, -1), (0, -1), (0, 0), (1, 0), (1, 1), (-1, 1)]]
        for p, q in zip(pts, pts[1:] + pts[:1]):
            geo.Append(["line", p, q], bc="boundary")
        object.__setattr__(self, "geometry", geo)
        super().__post_init__()


@dataclass(frozen=True)
class MeshFileDomain(_NetgenDomain):
    """A 2D triangular netgen mesh read from a ``.vol`` file; levels by netgen refinement.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.vol`` file.
    curved : bool
        Whether the boundary is curved.
    geometry : netgen geometry, optional
        Geometry onto which refinement projects new boundary points. By
        default new points are edge midpoints. (``Mesh.Load`` alone attaches
        netgen's *global* geometry, the last one meshed, so it is replaced.)
    """

    path: str | os.PathLike
    curved: bool = False
    geometry: Any = field(default=None, compare=False)

    def __post_init__(self):
        if not isinstance(self.path, (str, os.PathLike)):
            _fail(self, "path", self.path, "a str or os.PathLike")
        if not Path(self.path).is_file():
            raise FileNotFoundError(f"MeshFileDomain.path: no such file {str(self.path)!r}")
        if not isinstance(self.curved, bool):
            _fail(self, "curved", self.curved, "a bool")
        if self.geometry is not None and not isinstance(self.geometry, ngm.NetgenGeometry):
            _fail(self, "geometry", self.geometry, "None or a netgen geometry")

    @property
    def name(self) -> str:
        return f"mesh file {Path(self.path).name}"

    def _coarse(self):
        mesh = ngm.Mesh(dim=2)
        try:
            mesh.Load(str(self.path))
        except Exception as err:
            raise ValueError(f"MeshFileDomain.path: cannot read {str(self.path)!r}: {err}") from err
        check_triangular(mesh, f"MeshFileDomain.path {str(self.path)!r}")
        mesh.SetGeometry(ngm.NetgenGeometry() if self.geometry is None else self.geometry)
        return mesh


@dataclass(frozen=True)
class MeshDomain(_NetgenDomain):
    """A given mesh as T_0: ``ngsolve.Mesh`` or ``netgen.meshing.Mesh``, 2D triangles only (else ValueError);
    levels by netgen refinement of a copy.  Boundary segments must be named (``interface``: not Dirichlet);
    ``curved``: call ``mesh.Curve(p)`` in the FE code; ``label``: the ``name``."""

    coarse: Any
    curved: bool = False
    label: str = ""

    def __post_init__(self):
        ngmesh = getattr(self.coarse, "ngmesh", self.coarse)
        if not isinstance(ngmesh, ngm.Mesh):
            _fail(self, "coarse", self.coarse, "an ngsolve.Mesh or a netgen.meshing.Mesh")
        check_triangular(ngmesh, "MeshDomain.coarse")
        for name, typ in (("curved", bool), ("label", str)):
            if not isinstance(getattr(self, name), typ):
                _fail(self, name, getattr(self, name), f"a {typ.__name__}")
        object.__setattr__(self, "coarse", ngmesh)

    @property
    def name(self) -> str:
        return self.label or f"given mesh ({len(self.coarse.Elements2D())} triangles)"

    def _coarse(self):
        return self.coarse.Copy()


def as_domain(obj) -> Domain:
    """``obj`` as a :class:`Domain`: a domain itself, or a mesh wrapped in :class:`MeshDomain`; TypeError otherwise."""
    if isinstance(obj, Domain):
        return obj
    if isinstance(getattr(obj, "ngmesh", obj), ngm.Mesh):
        return MeshDomain(obj)
    raise TypeError(f"a domain must be an ngcontact Domain (e.g. CrissCrossSquare()) or an ngsolve.Mesh, "
                    f"got {type(obj).__name__}")
