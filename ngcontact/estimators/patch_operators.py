"""The sparse operators of :meth:`.patches.PatchSolver.solve` once every patch inverse is kept
(:func:`patch_operators`)."""
from __future__ import annotations

import numpy as np

__all__ = ["patch_operators"]


def patch_operators(solver):
    """(E_in, S_inv, G_out, R) of the :class:`.patches.PatchSolver` ``solver`` once every patch inverse is kept (else
    None; built once, kept in ``solver._patch_ops``): the map from the condensed right-hand sides g (3 ne nF3,
    hat-major) to msum (ne nF3) of its ``solve``, msum = G_out S_inv E_in g + R g, the same as the elimination of
    :mod:`.opposite_edges`, its ``_patch_loop`` and ``facet_sums``.  E (built here as CSR arrays directly: every
    (hat, element, dof at the vertex) is one patch unknown, so E has at most one entry per column) scatters the right-hand sides of the patch
    unknowns (3 ne nE) into the stacked patch unknowns (not into the fixed ones: their right-hand side is
    zero), S_inv is block diagonal with the patch inverses (m per row of a patch of m unknowns; canonical
    CSR), U picks the patch unknown of every (hat, element, dof at the vertex); with the per-pair blocks of
    the elimination (T_E, T_O: the columns at / opposite to the vertex, C = S_EO S_OO^-1, and P_E, P_O
    summing onto the facet dofs of the elements): E_in = E (T_E - C T_O),
    G_out = (P_E - P_O S_OO^-1 S_OE) U, R = P_O S_OO^-1 T_O."""
    from scipy.sparse import csc_matrix, csr_matrix

    if solver._patch_ops is not None:
        return solver._patch_ops
    keys = [(gi, c0) for gi, G in enumerate(solver.groups) for c0 in range(0, len(G["pairs"]), solver.CHUNK)]
    if not solver._keep_inverses or any(k not in solver._inv_cache for k in keys):
        return None
    ne, nE = solver.mesh.ne, solver.nE
    n_in = 3 * ne * nE
    chunks = [(gi, c0, G) for gi, G in enumerate(solver.groups) for c0 in range(0, len(G["pairs"]), solver.CHUNK)]
    sizes = [len(G["pairs"][c0:c0 + solver.CHUNK]) * G["m"] for _, c0, G in chunks]
    base, nnz = int(sum(sizes)), int(sum(n * G["m"] for n, (_, _, G) in zip(sizes, chunks)))
    itype = np.int32 if max(base, nnz, n_in) < np.iinfo(np.int32).max else np.int64
    unknown = np.full(n_in, -1, dtype=itype)  # patch unknown of (hat i, element K, dof e at the vertex)
    free = np.zeros(n_in, dtype=bool)
    data, cols = np.empty(nnz), np.empty(nnz, dtype=itype)  # S_inv, filled chunk by chunk
    indptr = np.empty(base + 1, dtype=itype)
    indptr[0] = 0
    start = at = 0
    for (gi, c0, G), size in zip(chunks, sizes):
        m, sl = G["m"], slice(c0, c0 + solver.CHUNK)
        pairs, loc = G["pairs"][sl], G["loc"][sl]                              # (np, n), (np, n, nE)
        npch = len(pairs)
        K, i = solver.pair_K[pairs], solver.pair_i[pairs]
        col = ((i[:, :, None] * ne + K[:, :, None]) * nE + np.arange(nE)).ravel()
        unknown[col] = (start + np.arange(npch)[:, None, None] * m + loc).ravel()
        free[col] = ~np.take_along_axis(G["fixed"][sl], loc.reshape(npch, -1), axis=1).ravel()
        # row j of patch p: row j of its inverse at the patch's columns
        data[at:at + size * m] = solver._inv_cache[(gi, c0)].ravel()
        cols[at:at + size * m].reshape(npch, m, m)[...] = (start + np.arange(npch)[:, None, None] * m
                                                            + np.arange(m)[None, None, :])
        indptr[start + 1:start + size + 1] = at + m * np.arange(1, size + 1)
        start, at = start + size, at + size * m
    if unknown.min() < 0:  # pragma: no cover - every (hat, element) pair lies in one patch
        raise RuntimeError("a (hat, element) pair outside the vertex patches")
    # E: column (i, K, e) -> its patch unknown, if that one is free
    E = csc_matrix((np.ones(int(free.sum())), unknown[free], np.concatenate([[0], np.cumsum(free)]).astype(itype)),
                   shape=(base, n_in)).tocsr()
    S_inv = csr_matrix((data, cols, indptr), shape=(base, base))
    U = csr_matrix((np.ones(n_in), unknown, np.arange(n_in + 1, dtype=itype)), shape=(n_in, base))
    E_in, G_out, R = solver.elim.fold(E, U)
    solver._patch_ops = (E_in, S_inv, G_out, R)
    return solver._patch_ops
