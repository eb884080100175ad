"""Structured rectangles built level by level from numpy arrays (X, T, S, tag) -> netgen mesh, or yielded as
:class:`ArrayMesh` levels whose NGSolve mesh is built on first use."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Optional

import netgen.meshing as ngm
import numpy as np
import ngsolve

from .base import _SIDES, DIRICHLET, Domain, _check_level, _fail, _is_int, _is_real, matplotlib_tri

__all__ = ["ArrayMesh", "CrissCrossSquare", "StructuredSquare"]


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
        mtri = matplotlib_tri()
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

    def h(self, level: int = 0, mesh=None) -> float:
        """Nominal mesh size: side of the squares of T_level (longest side if a rectangle); ``mesh`` is not needed."""
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


