"""Sparse-matrix kernels of the set-up: a submatrix in one pass, the absolute row sums, the entries of rows.

:func:`submatrix` is ``A[rows][:, cols]`` without the intermediate matrix of the two-step fancy index
(one boolean pass over the nonzeros; at 1e6 unknowns it takes a fraction of scipy's time and no second
copy of the rows).  The result's arrays are those of the two-step index, entry for entry (same order
inside the rows), so every later product or sweep over it rounds the same way.  :func:`abs_row_sums` is
``abs(A).sum(axis=1)`` (the infinity norm, Gershgorin bounds) without the copy of the matrix;
:func:`row_entries` the positions of some rows' entries (``A[rows].indices`` without the submatrix);
:func:`kept_entries` and :func:`place_rows` build CSR matrices from selected entries and from other matrices' rows.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["submatrix", "kept_entries", "place_rows", "abs_row_sums", "row_entries"]


def _as_index(sel, n: int, what: str) -> np.ndarray:
    """Increasing index array from a boolean mask of length n or an increasing index array."""
    sel = np.asarray(sel)
    if sel.dtype == bool:
        if len(sel) != n:
            raise ValueError(f"{what} mask has length {len(sel)}, the matrix {n}")
        return np.flatnonzero(sel)
    sel = sel.astype(np.int64, copy=False)
    if len(sel) and (sel[0] < 0 or sel[-1] >= n or np.any(np.diff(sel) <= 0)):
        raise ValueError(f"{what} must be increasing indices in 0..{n - 1}")
    return sel


def submatrix(A: sp.spmatrix, rows, cols) -> sp.csr_matrix:
    """``A[rows][:, cols]`` as a CSR matrix; ``rows``, ``cols``: boolean masks or increasing index arrays."""
    A = A.tocsr() if not sp.isspmatrix_csr(A) else A
    nr, nc = A.shape
    r, c = _as_index(rows, nr, "rows"), _as_index(cols, nc, "cols")
    itype = A.indices.dtype if max(len(c), A.nnz) < np.iinfo(np.int32).max else np.int64
    new_col = np.full(nc, -1, dtype=itype)
    new_col[c] = np.arange(len(c), dtype=itype)
    row_in = np.zeros(nr, dtype=bool)
    row_in[r] = True
    keep = np.repeat(row_in, np.diff(A.indptr))
    cj = new_col[A.indices]
    keep &= cj >= 0
    return kept_entries(A, keep, r, cj, len(c))


def kept_entries(A: sp.csr_matrix, keep: np.ndarray, rows: np.ndarray, new_col: np.ndarray,
                 ncols: int) -> sp.csr_matrix:
    """The CSR matrix of the entries ``keep`` (a mask over A's entries, none outside the increasing ``rows``) in the
    rows ``rows``, with the columns ``new_col`` (per entry).  The rows that are not selected keep no entry, so the
    result's row pointer is the running count of kept entries at the ends of the selected rows."""
    itype = np.int32 if max(A.nnz, ncols) < np.iinfo(np.int32).max else np.int64
    count = np.zeros(len(keep) + 1, dtype=itype)
    np.cumsum(keep, out=count[1:])
    indptr = np.concatenate([np.zeros(1, dtype=itype), count[A.indptr[np.asarray(rows) + 1]]])
    return sp.csr_matrix((A.data[keep], new_col[keep].astype(itype, copy=False), indptr), shape=(len(rows), ncols))


def place_rows(data: np.ndarray, indices: np.ndarray, starts: np.ndarray, M: sp.csr_matrix) -> None:
    """Write the entries of M into the arrays of another CSR matrix, those of M's row i from position starts[i] on
    (the rows' other entries are written by the caller)."""
    shift = starts.astype(np.int64) - M.indptr[:-1]  # from the entry's place in M to its place there
    pos = np.arange(M.nnz, dtype=np.int64) + np.repeat(shift, np.diff(M.indptr))
    data[pos] = M.data
    indices[pos] = M.indices


def abs_matrix(A: sp.spmatrix) -> sp.csr_matrix:
    """|A| entry by entry (CSR, the pattern of A)."""
    A = sp.csr_matrix(A)
    return sp.csr_matrix((np.abs(A.data), A.indices, A.indptr), shape=A.shape)


def abs_row_sums(A: sp.spmatrix) -> np.ndarray:
    """sum_j |a_ij| for every row i of A (zero on empty rows): segment sums of |data| over the nonempty rows."""
    A = A.tocsr() if not sp.isspmatrix_csr(A) else A
    out = np.zeros(A.shape[0])
    full = np.diff(A.indptr) > 0
    if full.any():
        out[full] = np.add.reduceat(np.abs(A.data[:A.indptr[-1]]), A.indptr[:-1][full])
    return out


def row_entries(indptr: np.ndarray, rows) -> np.ndarray:
    """Positions of the entries of ``rows`` of a CSR matrix with row pointer ``indptr``, row after row (what
    ``A[rows].indices`` reads, without building the submatrix)."""
    rows = np.asarray(rows)
    starts = indptr[rows].astype(np.int64)
    counts = indptr[rows + 1] - starts
    offsets = np.cumsum(counts) - counts  # position of each row's first entry in the result
    return np.arange(int(counts.sum()), dtype=np.int64) + np.repeat(starts - offsets, counts)
