"""Computational domains and their hierarchies of nested triangular meshes.

A domain knows nothing about finite element spaces: it produces the meshes
T_0, T_1, ... where T_j is obtained from the coarse mesh T_0 by j uniform
("red") refinements, every triangle being split into four by its edge
midpoints; on curved boundaries the new points are placed on the curve.
Every boundary segment carries a name, so ``dirichlet=DIRICHLET`` selects the
whole boundary; an internal curve named ``interface`` (mesh lines fitted to a
data discontinuity, e.g. ``UnitDisk(interface_radius=...)``) is not part of it.

Modules: :mod:`.base` (boundary names, the :class:`Domain` interface), :mod:`.boxes` (structured rectangles and
their :class:`ArrayMesh` levels), :mod:`.netgen` (netgen geometries, mesh files, given meshes).

Structured squares are built level by level with numpy and netgen's
vectorized ``AddPoints`` / ``AddElements`` (or, for callers that accept them,
yielded as :class:`ArrayMesh` levels whose NGSolve mesh is built on first use);
domains given by a netgen
geometry (or a ``.vol`` file) are refined by ``netgen.meshing.Mesh.Refine``,
which splits every triangle 1 -> 4 and projects new boundary points onto the
geometry.
"""
from __future__ import annotations

from .base import DIRICHLET, INTERFACE, Domain, check_triangular, mesh_size  # noqa: F401 (INTERFACE: by name)
from .boxes import ArrayMesh, CrissCrossSquare, StructuredSquare, _to_ngmesh  # noqa: F401 (_to_ngmesh: tests)
from .netgen import GeometryDomain, LShape, MeshDomain, MeshFileDomain, UnitDisk, as_domain

__all__ = ["DIRICHLET", "Domain", "ArrayMesh", "CrissCrossSquare", "StructuredSquare", "GeometryDomain",
           "UnitDisk", "LShape", "MeshFileDomain", "MeshDomain", "as_domain", "check_triangular", "mesh_size"]
