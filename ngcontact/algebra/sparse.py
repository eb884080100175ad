"""Sparse-matrix kernels of the set-up: a submatrix in one pass, and CSR assembly of element matrices.

:func:`submatrix` is ``A[rows][:, cols]`` without the intermediate matrix of the two-step fancy index
(one boolean pass over the nonzeros; at 1e6 unknowns it takes a fraction of scipy's time and no second
copy of the rows).  The result's arrays are those of the two-step index, entry for entry (same order
inside the rows), so every later product or sweep over it rounds the same way.

:func:`assemble_csr` sums element matrices into a CSR matrix in chunks of elements, so the COO
triplets of all elements never exist at once; it stores the nonzero entries only.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["submatrix", "assemble_csr"]


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
    counts = np.diff(A.indptr)
    keep = np.repeat(row_in, counts)
    cj = new_col[A.indices]
    keep &= cj >= 0
    per_row = np.zeros(nr, dtype=np.int64)  # kept entries of every row (segment sums over the nonempty rows)
    full = counts > 0
    if full.any():
        per_row[full] = np.add.reduceat(keep[:A.indptr[-1]], A.indptr[:-1][full], dtype=np.int64)
    indptr = np.concatenate([[0], np.cumsum(per_row[r])]).astype(itype)
    return sp.csr_matrix((A.data[keep], cj[keep], indptr), shape=(len(r), len(c)))


def assemble_csr(elements: np.ndarray, local, n: int, chunk: int = 1 << 17) -> sp.csr_matrix:
    """Sum of element matrices: ``elements`` (ne, k) the global numbers of each element's k unknowns,
    ``local(lo, hi)`` the element matrices of elements lo..hi-1 as a (k, k, hi - lo) array (entry (i, j) of all
    elements contiguous: filled without strided writes); an (n, n) CSR matrix in canonical form (sorted,
    summed indices) that stores the nonzero entries only: a coupling that sums to exactly zero (P1 stiffness
    across the right angles of a criss-cross or structured mesh) is not stored.

    Each chunk of elements is summed on its own (COO -> CSR), and the chunks' CSR matrices are added (a
    linear merge of sorted rows; an entry is the sum of its chunks' partial sums in chunk order): the
    triplets of all ne k^2 element entries never exist at once."""
    ne, k = elements.shape
    itype = np.int32 if n < np.iinfo(np.int32).max else np.int64
    out = None
    for lo in range(0, ne, chunk):
        hi = min(ne, lo + chunk)
        E = elements[lo:hi].astype(itype, copy=False)
        Et = np.ascontiguousarray(E.T)  # (k, m): entry (i, j, e) of the element matrices is (E[e, i], E[e, j])
        part = sp.csr_matrix((np.asarray(local(lo, hi), dtype=float).ravel(),
                              (np.repeat(Et[:, None, :], k, axis=1).ravel(),
                               np.broadcast_to(Et[None, :, :], (k, k, hi - lo)).ravel())), shape=(n, n))
        part.sum_duplicates()
        out = part if out is None else out + part
        del part
    if out is None:
        return sp.csr_matrix((n, n))
    out.eliminate_zeros()
    out.sort_indices()
    return out
