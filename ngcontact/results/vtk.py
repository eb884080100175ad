"""VTK files of a run: the solution fields as point data, the estimator's element indicators as cell data.

NGSolve's ``VTKOutput`` writes every GridFunction as point data (values at the points of each
element's subdivision).  The indicators eta_K are one number per element, so they are added
afterwards as a ``<CellData>`` section: ``VTKOutput`` writes the cells of element 0 first, then
those of element 1, ..., the same number of cells per triangle, so each value is repeated that many
times.  A ``.pvd`` collection lists the files of all levels (ParaView's time axis = the level).
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

__all__ = ["write_solution_vtu", "add_cell_data", "read_vtu_arrays", "pvd_text"]

#: point-data fields of a run's VTK file (those the discretization provides)
POINT_FIELDS = ("u1", "u2", "u", "gap", "lam")


def write_solution_vtu(path, tmp_base, disc, x, y, estimate=None) -> Path:
    """Write ``path`` (.vtu): the fields of ``disc`` at (x, y) as point data, ``estimate.cell_data()``
    (eta_K, eta_C, eta_F_<field>, eta_R_<field>) as cell data.  ``tmp_base``: the name written first
    (NGSolve appends ``.vtu``), renamed to ``path`` when complete."""
    from ngsolve import VTKOutput

    gfs = disc.gridfunctions(x, y)
    names = [n for n in POINT_FIELDS if n in gfs]
    VTKOutput(disc.mesh, coefs=[gfs[n] for n in names], names=names, filename=str(tmp_base),
              subdivision=max(disc.order - 1, 0), legacy=False).Do()
    written = Path(f"{tmp_base}.vtu")
    if estimate is not None:
        add_cell_data(written, {n: np.array(gf.vec.FV().NumPy()) for n, gf in estimate.cell_data().items()})
    os.replace(written, path)
    return Path(path)


_HEADER_BYTES = {"UInt32": 4, "UInt64": 8}


def _appended(raw: bytes):
    """(xml head, start of the appended data, header dtype, end of the last data block) of a raw-appended .vtu."""
    marker = raw.index(b'<AppendedData encoding="raw">')
    start = raw.index(b"_", marker) + 1
    head = raw[:marker].decode()
    htype = re.search(r'header_type="(\w+)"', head)
    dtype = np.uint64 if htype and htype.group(1) == "UInt64" else np.uint32
    hb = np.dtype(dtype).itemsize
    end = 0
    for off in map(int, re.findall(r'offset="(\d+)"', head)):
        nbytes = int(np.frombuffer(raw[start + off:start + off + hb], dtype=dtype)[0])
        end = max(end, off + hb + nbytes)
    return head, start, dtype, end


def add_cell_data(vtu, arrays: dict) -> None:
    """Add one value per mesh element (``arrays``: name -> array of length ne) as cell data to a .vtu
    written by NGSolve's ``VTKOutput`` (raw appended format)."""
    vtu = Path(vtu)
    raw = vtu.read_bytes()
    head, start, dtype, end = _appended(raw)
    ncells = int(re.search(r'NumberOfCells="(\d+)"', head).group(1))
    xml, blocks, offset = [], [], end
    for name, values in arrays.items():
        values = np.asarray(values, dtype=np.float64).ravel()
        if values.size == 0 or ncells % values.size:
            raise ValueError(f"cell data {name!r}: {values.size} values for {ncells} VTK cells")
        data = np.repeat(values, ncells // values.size).tobytes()
        xml.append(f'<DataArray type="Float64" Name="{name}" NumberOfComponents="1" format="appended" '
                   f'offset="{offset}">\n</DataArray>\n')
        blocks.append(np.array([len(data)], dtype=dtype).tobytes() + data)
        offset += len(blocks[-1])
    section = "<CellData>\n" + "".join(xml) + "</CellData>\n"
    piece_end = raw.index(b"</Piece>")
    out = (raw[:piece_end] + section.encode() + raw[piece_end:start + end] + b"".join(blocks) + raw[start + end:])
    vtu.write_bytes(out)


def read_vtu_arrays(vtu) -> dict:
    """{('PointData' | 'CellData', name): array} of a raw-appended .vtu written by NGSolve (and
    :func:`add_cell_data`); also ('Cells', 'types')."""
    raw = Path(vtu).read_bytes()
    head, start, dtype, _ = _appended(raw)
    hb = np.dtype(dtype).itemsize
    types = {"Float64": np.float64, "Float32": np.float32, "Int32": np.int32, "Int64": np.int64, "UInt8": np.uint8}
    out, section = {}, None
    for m in re.finditer(r"<(PointData|CellData|Cells|Points)>|<DataArray ([^>]*)>", head):
        if m.group(1):
            section = m.group(1)
            continue
        attrs = dict(re.findall(r'(\w+)="([^"]*)"', m.group(2)))
        off = start + int(attrs["offset"])
        nbytes = int(np.frombuffer(raw[off:off + hb], dtype=dtype)[0])
        out[(section, attrs["Name"])] = np.frombuffer(raw[off + hb:off + hb + nbytes], dtype=types[attrs["type"]])
    return out


def pvd_text(entries) -> str:
    """A ParaView collection: ``entries`` = [(timestep, file name), ...]."""
    lines = ['<?xml version="1.0"?>', '<VTKFile type="Collection" version="0.1">', "<Collection>"]
    lines += [f'<DataSet timestep="{t}" file="{f}"/>' for t, f in entries]
    return "\n".join(lines + ["</Collection>", "</VTKFile>", ""])
