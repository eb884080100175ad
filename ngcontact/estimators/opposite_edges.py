"""Element-level elimination of the facet dofs on the edge opposite to the patch vertex (:mod:`.patches`).

In the patch of vertex a, the edge of an element K opposite to a lies on the patch boundary: its facet dofs
belong to K alone there.  :class:`OppositeEdges` eliminates them per (element, local vertex) before the patch
matrices are summed and recovers them afterwards, so the patch systems of :class:`.patches.PatchSolver` hold the
2(q + 1) facet dofs per element of the edges at the vertex instead of 3(q + 1).
"""
from __future__ import annotations

import numpy as np
from ngsolve import EDGE, VOL, ElementId, NodeId

__all__ = ["OppositeEdges"]


def _opposite_vertices(mesh, F, ev, k: int, sample: int = 8):
    """opp (3,): the local vertex of a triangle opposite to its local edge j, where the facet space ``F`` numbers
    the dofs of an element in local order edge by edge (local edge j: columns j k .. j k + k - 1, the dofs of
    that edge), as checked on the first ``sample`` elements against the mesh's edges and the element vertices
    ``ev``; else None."""
    opp = None
    for K in range(min(sample, mesh.ne)):
        el = ElementId(VOL, K)
        dofs = np.asarray(F.GetDofNrs(el), dtype=np.int64)
        edges = [e.nr for e in mesh[el].edges]
        if len(dofs) != 3 * k or len(edges) != 3:
            return None
        row = []
        for j, e in enumerate(edges):
            node = NodeId(EDGE, e)
            if not np.array_equal(np.asarray(F.GetDofNrs(node), dtype=np.int64), dofs[j * k:(j + 1) * k]):
                return None
            ends = {v.nr for v in mesh[node].vertices}
            out = [i for i in range(3) if int(ev[K, i]) not in ends]
            if len(out) != 1:
                return None
            row.append(out[0])
        if opp is None:
            opp = np.array(row)
        elif not np.array_equal(opp, row):
            return None
    return opp if opp is not None and sorted(opp) == [0, 1, 2] else None


def _pair_blocks(M: np.ndarray, pair: np.ndarray, cols: np.ndarray, nr: int, nc: int):
    """Sparse matrix with the dense blocks M[p] (np, nr, ncol) at rows p nr .. p nr + nr - 1 and columns
    pair[p] nc + cols[p] (cols (np, nr, ncol): the column of every entry within the block row of pair[p])."""
    from scipy.sparse import csr_matrix

    npair = len(pair)
    rows = np.repeat(np.arange(npair * nr), M.shape[2])
    c = (pair[:, None, None] * nc + cols).ravel()
    return csr_matrix((M.ravel(), (rows, c)), shape=(npair * nr, (int(pair.max()) + 1 if npair else 0) * nc))



def _hat_major(M: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """(3, ne, ...): the per-shape blocks M (ns, 3, ...) of every element, hat-major, in one gather per hat."""
    out = np.empty((M.shape[1], len(shape)) + M.shape[2:])
    for i in range(M.shape[1]):
        np.take(M[:, i], shape, axis=0, out=out[i])
    return out


class OppositeEdges:
    """The elimination of the opposite edges for the condensed element matrices S_K of one mesh (see
    ``__init__``)."""

    def __init__(self, mesh, F, fd, ev, S_K, fixed, local_order: bool, shape=None):
        """Element-level elimination of the facet dofs of K on the edge opposite to its local vertex i.

        In the patch of vertex a the edge of K opposite to a lies on the patch boundary: its facet dofs belong to
        K alone there, so they are eliminated per (K, i) before the patch matrices are summed:
        S' = S_EE - S_EO S_OO^-1 S_OE, g' = g_E - S_EO S_OO^-1 g_O, and after the patch solve
        m_O = S_OO^-1 (g_O - S_OE m_E).  S_OO is positive definite: the only null vector of S_K, the facet
        vector of the constant 1, does not vanish on E.  A Dirichlet opposite edge has m_O = 0 (S' = S_EE).
        The patch systems keep the facet dofs of the edges at their vertex only: 2(q + 1) per element instead
        of 3(q + 1), an eighth of the LU work.  (The null mode of an interior patch is then normalized on
        those dofs; it changes the P_q part of the patch solution by a constant, not the flux.)

        ``fd``: facet dofs of K (numbering of F; in K's local order if ``local_order``, else sorted), ``fixed``:
        which of them are Dirichlet; ``S_K`` one matrix per element, or per element shape with ``shape`` (ne,)
        the shape of every element (:class:`.mixed_blocks.ElementBlocks`: the blocks are then formed and
        factorized once per shape and local vertex, where the column layout is the same for all elements).
        Sets ``E`` (ne, 3, nE) and ``O`` (ne, 3, nO), the columns of K's facet dofs at / opposite to local vertex
        i, ``fixed_O`` (ne, 3), ``S_pair`` (ne, 3, nE, nE) and the hat-major arrays of :meth:`rhs`.  Where the
        layout of the facet dofs is not the one :func:`_opposite_vertices` checks, or an opposite edge is partly
        fixed, nothing is eliminated (E: all columns, nO = 0)."""
        ne, nF3 = fd.shape
        k = nF3 // 3
        E = O = fixed_O = None
        opp = _opposite_vertices(mesh, F, ev, k) if nF3 == 3 * k and ne else None
        if opp is not None:
            if local_order:  # column c of K lies on local edge c // k
                edge = np.broadcast_to(np.arange(nF3) // k, (ne, nF3))
            else:  # columns sorted by number: their positions among K's dofs in local order
                loc = np.array([F.GetDofNrs(ElementId(VOL, e)) for e in range(ne)], dtype=np.int64)
                pos = np.argsort(loc, axis=1, kind="stable")
                edge = pos // k if np.array_equal(np.take_along_axis(loc, pos, axis=1), fd) else None
            if edge is not None:
                at = opp[edge][:, :, None] != np.arange(3)                      # (ne, nF3, 3): on an edge at i
                cols = np.argsort(~at.transpose(0, 2, 1), axis=2, kind="stable")  # (ne, 3, nF3): E first
                E, O = cols[:, :, :2 * k], cols[:, :, 2 * k:]
                fo = np.take_along_axis(np.broadcast_to(fixed[:, None, :], (ne, 3, nF3)), O, axis=2)
                fixed_O = fo.all(axis=2)
                if not np.array_equal(fixed_O, fo.any(axis=2)):
                    E = None
        if E is None:  # no elimination
            E = np.broadcast_to(np.arange(nF3), (ne, 3, nF3)).copy()
            O = np.zeros((ne, 3, 0), dtype=E.dtype)
            fixed_O = np.zeros((ne, 3), dtype=bool)
        same = bool(np.all(E == E[:1])) and bool(np.all(O == O[:1]))  # one column pattern (local order)
        if shape is not None and not same:
            S_K, shape = S_K[shape], None

        def block(R, C):  # (ne or ns, 3, len R, len C): S_K[K][R[K, i]][:, C[K, i]]
            if same:
                return np.stack([S_K[:, R[0, i][:, None], C[0, i][None, :]] for i in range(3)], axis=1)
            return np.take_along_axis(np.take_along_axis(S_K[:, None], R[:, :, :, None], axis=2), C[:, :, None, :],
                                      axis=3)

        S_EE, S_EO, S_OE, S_OO = block(E, E), block(E, O), block(O, E), block(O, O)
        nO = O.shape[2]
        if shape is None:
            S_OO[fixed_O] = np.eye(nO)
        S_OO_inv = np.linalg.inv(S_OO) if nO else S_OO
        if shape is None:
            S_OO_inv[fixed_O] = 0.0
        C = S_EO @ S_OO_inv                                                     # (ne or ns, 3, nE, nO)
        S_pair = S_EE - C @ S_OE if nO else S_EE
        # hat-major (3, ne, ...) for the right-hand sides (nf, 3, ne, nF3) of PatchSolver.solve
        if shape is not None:  # per element, gathered from the shapes' blocks in that layout; then the Dirichlet
            K, i = np.nonzero(fixed_O)  # opposite edges: m_O = 0, S' = S_EE
            fixed_EE = S_EE[shape[K], i]
            S_pair = S_pair[shape]
            S_pair[K, i] = fixed_EE
            self._Ct, self._S_OE_t, self._S_OO_inv_t = (_hat_major(M, shape) for M in (C, S_OE, S_OO_inv))
            self._Ct[i, K] = 0.0
            self._S_OO_inv_t[i, K] = 0.0
        else:
            self._Ct = C.transpose(1, 0, 2, 3).copy()
            self._S_OE_t, self._S_OO_inv_t = S_OE.transpose(1, 0, 2, 3).copy(), S_OO_inv.transpose(1, 0, 2, 3).copy()
        self.E, self.O, self.fixed_O = E, O, fixed_O
        self.ne, self.nF3, self.nE, self.nO = ne, nF3, E.shape[2], nO
        self.S_pair = S_pair
        self._Et, self._Ot = E.transpose(1, 0, 2).copy(), O.transpose(1, 0, 2).copy()
        base = (np.arange(ne) * nF3)[:, None]
        self._flat_E = [(base + E[:, i]).ravel() for i in range(3)]
        self._flat_O = [(base + O[:, i]).ravel() for i in range(3)]

    def rhs(self, g: np.ndarray):
        """(gE, gO): the right-hand sides (nf, 3, ne, nF3) split into those of the patch unknowns at the vertex,
        with the eliminated edge moved right (nf, 3, ne, nE), and those of the eliminated dofs (nf, 3, ne, nO)."""
        gE = np.take_along_axis(g, self._Et[None], axis=3)
        gO = np.take_along_axis(g, self._Ot[None], axis=3)
        if self.nO:
            gE -= np.einsum("ikeo,fiko->fike", self._Ct, gO)
        return gE, gO

    def facet_sums(self, mE: np.ndarray, gO: np.ndarray) -> np.ndarray:
        """msum (nf, ne, nF3): sum over the three vertex patches of K of the patch solutions on K's facet dofs,
        from the solutions mE (nf, 3, ne, nE) at the vertex and the eliminated right-hand sides gO (nf, 3, ne, nO)
        (:meth:`rhs`)."""
        nf = mE.shape[0]
        ne, nF3 = self.ne, self.nF3
        msum = np.zeros((nf, ne * nF3))
        nO = gO.shape[3]
        if nO:
            mO = np.einsum("ikop,fikp->fiko", self._S_OO_inv_t,
                           gO - np.einsum("ikoe,fike->fiko", self._S_OE_t, mE))
        for i in range(3):  # the columns of one local vertex are distinct: plain += is exact
            msum[:, self._flat_E[i]] += mE[:, i].reshape(nf, -1)
            if nO:
                msum[:, self._flat_O[i]] += mO[:, i].reshape(nf, -1)
        return msum.reshape(nf, ne, nF3)

    def fold(self, E, U):
        """(E_in, G_out, R): the elimination folded into the sparse operators of kept patch inverses S_inv, given E
        (stacked patch unknowns x 3 ne nE: scatter of the right-hand sides of the patch unknowns) and U
        (3 ne nE x stacked patch unknowns: the unknown of every (hat, element, dof at the vertex)); then
        msum = G_out S_inv E_in g + R g for the right-hand sides g (3 ne nF3, hat-major) of :meth:`rhs`.  With
        the per-pair blocks (T_E, T_O: the columns at / opposite to the vertex, C = S_EO S_OO^-1, and P_E, P_O
        summing onto the facet dofs of the elements): E_in = E (T_E - C T_O), G_out = (P_E - P_O S_OO^-1 S_OE) U,
        R = P_O S_OO^-1 T_O."""
        from scipy.sparse import csr_matrix

        ne, nF3, nE, nO = self.ne, self.nF3, self.nE, self.nO
        pair = np.arange(3 * ne)                                  # hat-major (i, K): i ne + K
        Kp = pair % ne
        T_E = _pair_blocks(np.ones((3 * ne, nE, 1)), pair, self._Et.reshape(3 * ne, nE, 1), nE, nF3)
        P_E = _pair_blocks(np.ones((3 * ne, nE, 1)), Kp, self._Et.reshape(3 * ne, nE, 1), nE, nF3).T
        if nO:
            T_O = _pair_blocks(np.ones((3 * ne, nO, 1)), pair, self._Ot.reshape(3 * ne, nO, 1), nO, nF3)
            P_O = _pair_blocks(np.ones((3 * ne, nO, 1)), Kp, self._Ot.reshape(3 * ne, nO, 1), nO, nF3).T
            C = self._Ct.reshape(3 * ne, nE, nO)
            Sinv = self._S_OO_inv_t.reshape(3 * ne, nO, nO)
            B = Sinv @ self._S_OE_t.reshape(3 * ne, nO, nE)

            def blk(M, rows, cols):  # the per-pair dense blocks M (3 ne, rows, cols) as a block-diagonal matrix
                return _pair_blocks(M, pair, np.broadcast_to(np.arange(cols), (3 * ne, rows, cols)), rows, cols)

            E_in = E @ (T_E - blk(C, nE, nO) @ T_O)
            G_out = (P_E - P_O @ blk(B, nO, nE)) @ U
            R = P_O @ blk(Sinv, nO, nO) @ T_O
        else:
            E_in, G_out, R = E @ T_E, P_E @ U, csr_matrix((ne * nF3, 3 * ne * nF3))
        E_in, G_out, R = (M.tocsr() for M in (E_in, G_out, R))
        for M in (E_in, G_out, R):
            M.eliminate_zeros()  # the blocks of Dirichlet opposite edges
        return E_in, G_out, R
