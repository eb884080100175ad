"""Cell-centred geometry for two-point finite volumes.

The discretization (:mod:`.fv`) sees only this: cell volumes and centres, interior faces as
(left cell, right cell, transmissibility distance, area) and boundary faces as (cell, distance,
area, tag).  A 1D interval is :func:`interval_mesh`; a structured 2D mesh would be another
builder of the same :class:`CellMesh` (faces in x and y, tags per side), with no change to
:mod:`.fv`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CellMesh", "interval_mesh"]


@dataclass(frozen=True)
class CellMesh:
    """Cells and faces of a two-point flux mesh.

    Attributes
    ----------
    volume, centre : ndarray (N,), (N, dim)
    left, right : ndarray (F,) of int
        cells of each interior face; the face normal points from ``left`` to ``right``.
    dist, area : ndarray (F,)
        distance of the two cell centres [m] and face measure [m^{dim-1}].
    b_cell, b_dist, b_area : ndarray (B,)
        boundary faces: their cell, the distance from its centre to the face, the face measure
        (the outward normal points out of ``b_cell``).
    b_tag : ndarray (B,) of str
        boundary part ('left', 'right', ...).
    face_x : ndarray (F,), b_x : ndarray (B,)
        face positions (1D: the coordinate; used by the flux reconstructions and plots).
    """

    volume: np.ndarray
    centre: np.ndarray
    left: np.ndarray
    right: np.ndarray
    dist: np.ndarray
    area: np.ndarray
    b_cell: np.ndarray
    b_dist: np.ndarray
    b_area: np.ndarray
    b_tag: np.ndarray
    face_x: np.ndarray
    b_x: np.ndarray

    @property
    def ncells(self) -> int:
        return len(self.volume)

    def boundary(self, tag: str) -> np.ndarray:
        """Indices of the boundary faces tagged ``tag``."""
        return np.flatnonzero(self.b_tag == tag)


def interval_mesh(length: float, ncells: int) -> CellMesh:
    """N uniform cells on (0, L); boundary faces 'left' (x = 0) and 'right' (x = L).

    >>> m = interval_mesh(2.0, 4)
    >>> m.centre[:, 0].tolist(), m.left.tolist(), m.b_tag.tolist()
    ([0.25, 0.75, 1.25, 1.75], [0, 1, 2], ['left', 'right'])
    """
    if isinstance(ncells, bool) or not isinstance(ncells, (int, np.integer)) or ncells < 2:
        raise ValueError(f"option cells must be an integer >= 2, got {ncells!r}")
    h = length / ncells
    xf = np.linspace(0.0, length, ncells + 1)
    centre = 0.5 * (xf[:-1] + xf[1:])
    idx = np.arange(ncells - 1)
    return CellMesh(volume=np.full(ncells, h), centre=centre[:, None], left=idx, right=idx + 1,
                    dist=np.full(ncells - 1, h), area=np.ones(ncells - 1),
                    b_cell=np.array([0, ncells - 1]), b_dist=np.full(2, 0.5 * h), b_area=np.ones(2),
                    b_tag=np.array(["left", "right"]), face_x=xf[1:-1], b_x=np.array([0.0, length]))
