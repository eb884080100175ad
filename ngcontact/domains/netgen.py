"""Domains given by a netgen geometry, a mesh file or a mesh: levels by ``netgen.meshing.Mesh.Refine``."""
from __future__ import annotations

import gzip
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import netgen.meshing as ngm
import numpy as np
from netgen.geom2d import SplineGeometry

from .base import INTERFACE, Domain, _check_positive, _fail, _is_real, check_triangular

__all__ = ["GeometryDomain", "UnitDisk", "LShape", "MeshFileDomain", "MeshDomain", "as_domain"]


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
        _check_vol_file(self.path)
        mesh = ngm.Mesh(dim=2)
        try:
            mesh.Load(str(self.path))
        except Exception as err:
            raise ValueError(f"MeshFileDomain.path: cannot read {str(self.path)!r}: {err}") from err
        check_triangular(mesh, f"MeshFileDomain.path {str(self.path)!r}")
        mesh.SetGeometry(ngm.NetgenGeometry() if self.geometry is None else self.geometry)
        return mesh


def _check_vol_file(path) -> None:
    """ValueError for a netgen .vol / .vol.gz file whose points or surface elements are cut off or whose elements
    refer to points it does not have: ``netgen.meshing.Mesh.Load`` reads such files past their end (a crash of the
    process, no message).  Other files are left to netgen."""
    name = str(path)
    if not name.endswith((".vol", ".vol.gz")):
        return
    where = f"MeshFileDomain.path {name!r}"
    with (gzip.open(name, "rt") if name.endswith(".gz") else open(name)) as fh:
        lines = fh.read().splitlines()
    sections = {}
    for i, line in enumerate(lines):
        key = line.strip()
        if key == "points" or key.startswith("surfaceelements"):
            try:
                n = int(lines[i + 1].split()[0])
                rows = [lines[i + 2 + k].split() for k in range(n)]
            except (IndexError, ValueError):
                raise ValueError(f"{where}: the section '{key}' (line {i + 1}) is cut off or malformed") from None
            sections.setdefault("points" if key == "points" else "elements", []).append((i + 1, rows))
    if "points" not in sections:
        raise ValueError(f"{where}: no 'points' section (a cut-off or non-netgen .vol file)")
    npoints = len(sections["points"][0][1])
    for line_no, rows in sections.get("elements", []):
        for k, row in enumerate(rows):
            try:
                nodes = [int(v) for v in row[5:5 + int(row[4])]]
            except (IndexError, ValueError):
                raise ValueError(f"{where}: element {k} of the section at line {line_no} is malformed: "
                                 f"{' '.join(row)!r}") from None
            if len(nodes) < 3 or min(nodes) < 1 or max(nodes) > npoints:
                raise ValueError(f"{where}: element {k} of the section at line {line_no} refers to points "
                                 f"{nodes} (the file has {npoints} points)")


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
