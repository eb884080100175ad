r"""Batched vertex-patch solver for the hybridized mixed patch problems of :mod:`.flux`.

Same problems and same result as NGSolve's ``PatchwiseSolve`` (broken RT_q x P_q x facet P_q, every
right-hand side term multiplied by the hat function psi_a of the patch), computed differently:

1. the element matrices of the bilinear form: on straight triangles from reference matrices (only the RT
   mass block depends on the shape of K, :mod:`.mixed_blocks`); otherwise the form is assembled ONCE on
   the whole mesh.  Its only inter-element coupling is the facet multiplier, whose facet-facet block is
   zero, so the element matrix of K is the global matrix restricted to the dofs of K (RT and P_q dofs
   of K are element-local, the facet dofs of its edges couple only through the <tau.n, m> terms of K);
2. per element, the interior unknowns I = (RT_q(K), P_q(K)) are condensed once:
   S_K = -A_FI A_II^{-1} A_IF on the 3(q + 1) facet dofs of K (batched LU of small matrices, one per
   element shape where similar triangles share their blocks, :class:`.mixed_blocks.ElementBlocks`,
   whose ``apply`` multiplies the elements of each shape by its matrix without per-element copies);
3. the right-hand side of patch a on K is the element vector of the linear form with psi_a, i.e.
   with the barycentric coordinate of the local vertex of K that is a: three assemblies (one per
   local vertex) give all of them; they are condensed like the matrix;
4. in patch a the edge of K opposite to a lies on the patch boundary, so its facet dofs belong to K
   alone there: they are eliminated per (element, local vertex) as well (:mod:`.opposite_edges`),
   and patch a solves sum_{K in T_a} S'_K m = sum_K g'_K^a on the free facet dofs of the edges at a
   (2(q + 1) per element instead of 3(q + 1); the facet dofs of the Dirichlet boundary are not free,
   as in PatchwiseSolve), batched over patches of equal size with ``numpy.linalg.solve``; the
   eliminated dofs are recovered per element;
5. sigma = sum_a sigma^a is recovered per element at once, by linearity:
   x_I = A_II^{-1} (sum_a b_K^a - A_IF sum_a m_K^a).

Reuse across calls (every Newton iterate, every field): the element factorizations, the inverses
of the patch matrices (formed at the third call, or at the first when the caller expects many
(:meth:`PatchSolver.expect_repeats`: the estimators inside a Newton loop), kept while they fit in
:attr:`PatchSolver.CACHE_BYTES`; from then on step 4 is three sparse products -- scatter,
block-diagonal inverses, gather -- instead of the loop over groups of patches), and the parts
of the right-hand sides that are linear in a GridFunction (the flux terms psi_a mu grad u_h of
:mod:`.flux`): their three hat-weighted operators are built once (:meth:`PatchSolver.operators`:
on straight triangles applied element by element from reference matrices,
:func:`.mixed_blocks.flux_operators`, else assembled as sparse matrices), so a new u_h costs one
product instead of three assemblies with the Hessian and element-boundary terms; likewise the
FE-mass-rule sources linear in a GridFunction (``PatchData.mass`` of :mod:`.flux`), and the load part of
the sources is assembled once per load object (:meth:`PatchSolver.fixed_vectors`); the hat-weighted load and
multiplier sources (g psi_i, w)_K of the three hats come from one assembly on P_{q+1} (:meth:`PatchSolver.hat_moments`).

Cost: ``PatchwiseSolve`` (NGSolve 6.2) loops over the vertices on one thread, recomputes the
element matrices of every patch (three times per element) and inverts the full patch matrix
(~90 unknowns for q = 1, 220 for q = 2): ~30 us per vertex and field for q = 1.  Here the
factorizations are of element size, the patch systems have only the facet unknowns of the edges at
the vertex (~12 for q = 1, ~24 for q = 3), and the structure (element blocks, condensation, patch
numbering) is built once per mesh and reused for every field and every Newton iterate
(:func:`.flux.patch_solver`).
Interior patches (no Dirichlet facet) are singular: (r, m) = (1, 1) solves the homogeneous
problem, and the condensed matrix is singular to round-off whatever tiny eps (r, w) is added
(eps |omega_a| ~ 1e-15 relative), so it is treated exactly instead, in the eps -> 0 limit of
the regularized problem that ``PatchwiseSolve`` solves: the eps-term turns an incompatibility
d_a of the patch data (the w-right-hand side tested with w = 1; zero up to quadrature on
straight meshes, the vertex-rule error on curved ones) into the constant source -d_a/|omega_a|
on the patch, and this constant is added to the data explicitly; the condensed system is then
compatible and solved with S + z z^T (z the facet vector of the constant 1 on the dofs at the
vertex), whose solution satisfies S m = g and z^T m = 0 (another normalization of the null mode
than PatchwiseSolve's: the same flux, the P_q part differs by a constant).  The element blocks are
factorized with eps = 0 (the divergence of broken RT_q onto P_q(K) makes them invertible).
"""
from __future__ import annotations

import numpy as np
from ngsolve import (H1, L2, VOL, BilinearForm, CoefficientFunction, Discontinuous, ElementId, GridFunction,
                     LinearForm, TaskManager, dx)

from ..discretizations.base import bit_mask
from .mixed_blocks import ElementBlocks, ranking_classes
from .opposite_edges import OppositeEdges
from .patch_operators import patch_operators

__all__ = ["PatchSolver", "local_hats", "facet_constant_one"]


def local_hats(mesh) -> list:
    """The barycentric coordinates of every element as three ``Discontinuous(H1(order=1))`` GridFunctions (hat i:
    1 at the local vertex i of every element, 0 at the others)."""
    D1 = Discontinuous(H1(mesh, order=1))
    hats = []
    for i in range(3):
        g = GridFunction(D1)
        vals = np.zeros((mesh.ne, 3))
        vals[:, i] = 1.0
        g.vec.FV().NumPy()[:] = vals.ravel()
        hats.append(g)
    return hats


def facet_constant_one(F, fdofs=None) -> np.ndarray:
    """The coefficients of the constant 1 in the facet space F.  ``fdofs`` (ne, 3 (q + 1)): the facet dofs of every
    element in its local order, edge by edge, as FacetFESpace numbers them, q + 1 per edge, the constant first
    (checked against Set(1, dual=True) in tests/test_patches.py); None: Set(1, dual=True), a facet-mass solve."""
    if fdofs is not None:
        z = np.zeros(F.ndof)
        z[fdofs[:, ::int(F.globalorder) + 1].ravel()] = 1.0
        return z
    zf = GridFunction(F)
    zf.Set(CoefficientFunction(1.0), dual=True)
    return np.round(zf.vec.FV().NumPy(), 12)


def _scatter_add(shape, flat_index, values) -> np.ndarray:
    """Dense array of ``shape`` with values summed into the flat indices (np.add.at, by bincount)."""
    n = int(np.prod(shape))
    return np.bincount(flat_index.ravel(), weights=values.ravel(), minlength=n).reshape(shape)


def _assembled_blocks(X, bf, ne: int, nV: int, nQ: int):
    """(A_II, A_VF, facet dofs) of every element from NGSolve's assembly of ``bf`` on the whole mesh (the
    general path; :mod:`.mixed_blocks` builds them from reference matrices on straight triangles)."""
    V, Q, F = X.components
    nI = nV + nQ
    offQ, offF = V.ndof, V.ndof + Q.ndof
    form = BilinearForm(X)
    form += bf
    with TaskManager():
        form.Assemble()
    # views of the CSR arrays (no copy: ~20M entries at 1e5 dofs); ``form`` stays alive meanwhile
    data, indices, indptr = (np.asarray(a) for a in form.mat.CSR())
    # V rows (then Q rows) are consecutive, element by element, and each holds the element pattern:
    # the dofs of K (V_K, Q_K contiguous, then its facet dofs, sorted) -> reshape the CSR arrays
    lens = np.diff(indptr[:offF + 1])
    nrow = int(lens[0])
    if not np.all(lens == nrow):
        raise ValueError("unexpected sparsity pattern of the patch bilinear form")
    cols = indices[:offQ * nrow].reshape(ne, nV, nrow)
    base = (np.arange(ne) * nV)[:, None]
    expect = np.concatenate([base + np.arange(nV), offQ + (np.arange(ne) * nQ)[:, None] + np.arange(nQ)], axis=1)
    if not (np.array_equal(cols[:, :nV, :nI], np.broadcast_to(expect[:, None, :], (ne, nV, nI)))
            and np.all(np.diff(cols[:, 0, :], axis=1) > 0)):
        raise ValueError("unexpected column order of the patch bilinear form")
    dataV = data[:offQ * nrow].reshape(ne, nV, nrow)
    dataQ = data[offQ * nrow:offF * nrow].reshape(ne, nQ, nrow)[:, :, :nI]
    A_II = np.empty((ne, nI, nI))
    A_II[:, :nV, :] = dataV[:, :, :nI]
    A_II[:, nV:, :] = dataQ
    A_VF = dataV[:, :, nI:].copy()                             # A_IF = [A_VF; 0] (no Q-F coupling)
    return A_II, A_VF, cols[:, 0, nI:].copy()                  # facet dofs of K, sorted


class PatchSolver:
    """Batched solver of the patch problems of one mesh and one hybridized bilinear form.

    Parameters
    ----------
    mesh : ngsolve.Mesh
    X : ngsolve.FESpace
        the product space V x Q x F (broken RT_q, L2 order q, facet order q with the Dirichlet
        boundary), in this order.
    bf : SumOfIntegrals
        the patch bilinear form (symmetric).
    ev : ndarray (ne, 3)
        vertex numbers of every element in the local order of ``Discontinuous(H1(order=1))``.
    blocks : ElementBlocks, optional
        the element blocks (A_II, A_VF, facet dofs), e.g. from :func:`.mixed_blocks.mixed_element_blocks` (one
        per shape class of the elements); None: from the assembly of ``bf``, one per element.
    affine : AffineTriangles, optional
        the affine element maps (:mod:`.mixed_blocks`), for operators built from reference matrices.
    """

    def __init__(self, mesh, X, bf, ev, blocks=None, affine=None):
        self.mesh, self.X = mesh, X
        self.affine = affine  # .mixed_blocks.AffineTriangles of the mesh, or None
        V, Q, F = X.components
        self.Y = V * Q  # right-hand sides: the facet rows are zero
        w_ = Q.TestFunction()
        with TaskManager():
            moments = LinearForm(w_ * dx).Assemble().vec                    # (1, w_j)_K
        q1 = GridFunction(Q)
        q1.vec.data = moments
        Q.SolveM(q1.vec)  # the L2 projection of 1 onto P_q(K), i.e. 1 (element-wise inverse mass, exact when curved)
        ne = mesh.ne
        nV = len(V.GetDofNrs(ElementId(VOL, 0)))
        nQ = len(Q.GetDofNrs(ElementId(VOL, 0)))
        if V.ndof != ne * nV or Q.ndof != ne * nQ:
            raise ValueError("broken RT and L2 spaces with the same number of dofs per element expected")
        nI = nV + nQ
        offQ, offF = V.ndof, V.ndof + Q.ndof
        local_order = blocks is not None  # reference blocks: facet dofs in K's local order (else sorted)
        blocks = blocks if blocks is not None else ElementBlocks(*_assembled_blocks(X, bf, ne, nV, nQ))
        A_II, A_VF, fdofs = blocks.A_II, blocks.A_VF, blocks.fdofs
        nF3, ns = fdofs.shape[1], blocks.nshapes
        self.blocks = blocks
        z_glob = np.zeros(X.ndof)
        z_glob[offF:] = facet_constant_one(F, fdofs - offF if local_order else None)
        # per element shape (one per element without shared shapes): W = A_II^{-1} A_IF, S_K = -A_FI W.  With shapes
        # shared by elements, A_II^{-1} per shape is formed here once: W from it, and its RT rows kept for solve()
        if blocks.shape is not None:
            Ainv = np.linalg.inv(A_II)
            W, A_II_inv = Ainv[:, :, :nV] @ A_VF, np.ascontiguousarray(Ainv[:, :nV, :])  # W = A_II^{-1} [A_VF; 0]
        else:
            W, A_II_inv = np.linalg.solve(A_II, np.concatenate([A_VF, np.zeros((ns, nQ, nF3))], axis=1)), None
        S_K = -(A_VF.transpose(0, 2, 1) @ W[:, :nV, :])
        self.W_t = np.ascontiguousarray(W.transpose(0, 2, 1))                         # (ns, nF3, nI)
        self.W_V = np.ascontiguousarray(W[:, :nV, :])                                 # (ns, nV, nF3)
        self.nV, self.nQ, self.nI, self.nF3, self.offQ, self.offF = nV, nQ, nI, nF3, offQ, offF
        self.one_Q = q1.vec.FV().NumPy().reshape(ne, nQ).copy()  # coefficients of w = 1 on every K
        self.mass_Q = moments.FV().NumPy().reshape(ne, nQ).copy()  # (1, phi_j)_K
        area = (self.one_Q * self.mass_Q).sum(axis=1)

        # patches: pairs (vertex a, element K, local index i) sorted by a
        free = np.ones(X.ndof, dtype=bool)
        free[offF:] = bit_mask(F.FreeDofs())    # V and Q dofs are all free
        a_of = ev.ravel()
        order = np.argsort(a_of, kind="stable")
        self.pair_K = order // 3
        self.pair_i = order % 3
        pair_a = a_of[order]
        nv = int(mesh.nv)
        count = np.bincount(pair_a, minlength=nv)
        start = np.concatenate([[0], np.cumsum(count)])
        # the facet dofs of K at its local vertex i (E) and on the opposite edge (O, condensed per element)
        self.elim = OppositeEdges(mesh, F, fdofs - offF, ev, S_K, ~free[fdofs], local_order=local_order,
                                 shape=blocks.shape)
        fixed_O = self.elim.fixed_O[self.pair_K, self.pair_i]      # (npair,) Dirichlet opposite edge
        # patch-local numbering of the facet dofs at the vertex
        fd = np.take_along_axis(fdofs[self.pair_K], self.elim.E[self.pair_K, self.pair_i], axis=1)  # (npair, nE)
        key = pair_a[:, None].astype(np.int64) * X.ndof + fd
        uniq, inv = np.unique(key.ravel(), return_inverse=True)
        upatch = uniq // X.ndof
        ustart = np.searchsorted(upatch, np.arange(nv))
        nloc = np.bincount(upatch, minlength=nv)
        local = inv.reshape(fd.shape) - ustart[pair_a][:, None]
        self.groups = []
        sig = count.astype(np.int64) * 10000 + nloc
        for s in np.unique(sig[count > 0]):
            verts = np.flatnonzero(sig == s)
            n, m = int(count[verts[0]]), int(nloc[verts[0]])
            pairs = start[verts][:, None] + np.arange(n)[None, :]  # (np, n)
            loc = local[pairs]                                     # (np, n, nF3)
            gdof = np.zeros((len(verts), m), dtype=np.int64)
            gdof[np.arange(len(verts))[:, None, None], loc] = fd[pairs]
            fixed = ~free[gdof]                                    # Dirichlet facets: m = 0 there
            interior = ~fixed.any(axis=1) & ~fixed_O[pairs].any(axis=1)  # null mode (r, m) = (1, 1)
            self.groups.append(dict(pairs=pairs, loc=loc, fixed=fixed, interior=interior, m=m,
                                    z=z_glob[gdof] * interior[:, None], area=area[self.pair_K[pairs]].sum(axis=1)))
        self.A_II_inv = A_II_inv  # without shapes: formed with the patch inverses
        self._ops, self._fixed, self._inv_cache, self._P = {}, {}, {}, None  # _P: P_{q+1} of hat_moments
        self.ranking = ranking_classes(ev)  # of the P_q bases (.mixed_blocks.RANKINGS)
        self._patch_ops = None
        self._compat = None
        self._calls = 0
        self._inverse_from = 3  # the call of solve() that forms the inverses (expect_repeats: the first)
        nbytes = sum(len(G["pairs"]) * G["m"] ** 2 * 8 for G in self.groups)
        self.nE = self.elim.nE
        self._keep_inverses = nbytes <= self.CACHE_BYTES
        self.hats = local_hats(mesh)  # local-vertex hat functions (barycentric coordinates of K)

    #: patches per batched solve (bounded work arrays: the first touch of fresh memory costs as
    #: much as the arithmetic here)
    CHUNK = 4096
    #: memory allowed for the cached inverses of the patch matrices (else rebuilt in every call)
    CACHE_BYTES = 2 * 1024 ** 3

    def expect_repeats(self) -> None:
        """Form the inverses (patch matrices, element blocks) at the next :meth:`solve` already: the caller
        will call it many times on this mesh (the estimators of the iterates of a Newton loop), so the loop
        over the groups of patches of the first calls would only add to the cost."""
        self._inverse_from = min(self._inverse_from, self._calls + 1)

    def operators(self, key, space, form_of_hat, reference=None):
        """The operator (3 ne nI x space.ndof; ``@`` a coefficient vector) of the bilinear forms
        ``form_of_hat(hat_i)`` (trial functions of ``space``, test functions of ``self.Y``), its rows in the layout
        of the right-hand sides of :meth:`solve` (hat i, element K, local dof: V, then Q), built once per ``key``
        and kept: by ``reference(self)`` (the same operator by other means, e.g. the element-by-element
        :func:`.mixed_blocks.flux_operators`) unless it is None or returns None, else assembled (three
        assemblies, rows reordered: a sparse matrix)."""
        from scipy.sparse import csr_matrix, vstack

        if key not in self._ops:
            mat = reference(self) if reference is not None else None
            if mat is None:
                mats = []
                with TaskManager():
                    for hat in self.hats:
                        bf = BilinearForm(space, self.Y)
                        bf += form_of_hat(hat)
                        bf.Assemble()
                        data, indices, indptr = bf.mat.CSR()
                        mats.append(csr_matrix((np.array(data), np.array(indices), np.array(indptr)),
                                               shape=(bf.mat.height, bf.mat.width)))
                mat = vstack(mats, format="csr")[self._layout_rows()]
            self._ops[key] = (space, mat)  # the space is kept alive: its id in the key stays unique
        return self._ops[key][1]

    def _layout_rows(self) -> np.ndarray:
        """Rows of the three stacked Y-vectors (hat i: rows i Y.ndof + dof) in the layout of :meth:`solve`."""
        ne, nV, nQ = self.mesh.ne, self.nV, self.nQ
        K = np.arange(ne)[:, None]
        rows = np.concatenate([K * nV + np.arange(nV), self.offQ + K * nQ + np.arange(nQ)], axis=1).ravel()
        return (np.arange(3)[:, None] * self.Y.ndof + rows).ravel()

    def vertex_mass(self, bonus: int = 0) -> np.ndarray:
        """M[i, K, j] = (psi_i, w_j)_K for the local hat psi_i and the P_q basis w_j of K (kept per
        ``bonus`` quadrature order): the element vectors of a patch source psi_a g with g constant on K."""
        key = ("vertex_mass", int(bonus))
        if key not in self._ops:
            self._ops[key] = (None, self.shaped_mass(None, bonus))
        return self._ops[key][1]

    def shaped_rule_order(self, bonus: int = 0) -> int:
        """Order of the triangle rule of :meth:`shaped_mass` (exact for psi_i w_j times a P_q shape)."""
        return 2 * int(self.X.components[1].globalorder) + 1 + int(bonus)

    def shaped_mass(self, shape, bonus: int = 0) -> np.ndarray:
        """M[i, K, j] = (psi_i shape, w_j)_K (shape None: 1; not kept: the shape changes with the iterate);
        a shape with kinks (lam_h^+) is integrated by the fixed rule of :meth:`shaped_rule_order`
        (:meth:`hat_moments`), the shape 1 by the default rule + ``bonus`` of P_q, three assemblies."""
        from ngsolve import TRIG, IntegrationRule

        if shape is not None:
            rule = dx(intrules={TRIG: IntegrationRule(TRIG, self.shaped_rule_order(bonus))})
            return self.hat_moments(lambda v: shape * v * rule)
        w = self.X.components[1].TestFunction()
        M = np.empty((3, self.mesh.ne, self.nQ))
        with TaskManager():
            for i, hat in enumerate(self.hats):
                M[i] = LinearForm(hat * w * dx(bonus_intorder=int(bonus))).Assemble().vec.FV().NumPy().reshape(
                    self.mesh.ne, self.nQ)
        return M

    def hat_moments(self, source) -> np.ndarray:
        """(3, ne, nQ): (g psi_i, w_j)_K for a linear form ``source(v)`` = (g, v) (v a plain factor of its integrands,
        each with a rule fixed by its measure, not by the space): (g, v_m)_K is assembled ONCE on P_{q+1} and
        multiplied by the reference products psi_i w_j = sum_m T_jm v_m (:func:`.mixed_blocks.reference_hat_products`,
        one per ranking class of the elements): the same sums over the same points as three hat-weighted assemblies."""
        from .mixed_blocks import reference_hat_products

        q = int(self.X.components[1].globalorder)
        if self._P is None:
            self._P = L2(self.mesh, order=q + 1)
        form = LinearForm(self._P)
        form += source(self._P.TestFunction())
        with TaskManager():
            g = form.Assemble().vec.FV().NumPy().reshape(self.mesh.ne, -1)
        T = reference_hat_products(q)                                           # (6, 3, nQ, nP)
        out = np.empty((3, self.mesh.ne, self.nQ))
        for c in np.unique(self.ranking):
            sel = np.flatnonzero(self.ranking == c)
            out[:, sel] = np.einsum("ijm,km->ikj", T[c], g[sel])
        return out

    def _patch_solve(self, gi, G, sl, rhs):
        """Solutions of the patch systems of the chunk ``sl`` of group ``gi`` for ``rhs`` (np, m, nf): by the
        kept inverse (:meth:`_form_inverses`) or by ``numpy.linalg.solve`` (one or two calls per mesh, e.g.
        one estimate per mesh of an adaptive loop, do not pay for the inverses)."""
        inv = self._inv_cache.get((gi, sl.start))
        if inv is not None:
            return inv @ rhs
        return np.linalg.solve(self._patch_matrices(G, sl), rhs)

    def _form_inverses(self) -> None:
        """The inverses of all patch matrices (kept)."""
        for gi, G in enumerate(self.groups):
            for c0 in range(0, len(G["pairs"]), self.CHUNK):
                if (gi, c0) not in self._inv_cache:
                    self._inv_cache[(gi, c0)] = np.linalg.inv(self._patch_matrices(G, slice(c0, c0 + self.CHUNK)))

    def _patch_matrices(self, G, sl) -> np.ndarray:
        """The condensed matrices S_a (+ the null-mode term) of the patches ``sl`` of group G."""
        pairs, loc, m = G["pairs"][sl], G["loc"][sl], G["m"]
        npch = len(pairs)
        # flat index of every entry of every element block in its patch matrix (np, n, nE, nE); one bincount
        # sums them, element slot by element slot in each entry (the order of a loop over the slots)
        lm = loc.astype(np.int64)
        idx = lm[:, :, :, None] * m + lm[:, :, None, :]
        idx += (np.arange(npch, dtype=np.int64) * (m * m))[:, None, None, None]
        S = np.bincount(idx.ravel(), weights=self.elim.S_pair[self.pair_K[pairs], self.pair_i[pairs]].ravel(),
                        minlength=npch * m * m).reshape(npch, m, m)
        fixed = G["fixed"][sl]
        S[fixed] = 0.0
        S.transpose(0, 2, 1)[fixed] = 0.0
        ii, kk = np.nonzero(fixed)
        S[ii, kk, kk] = 1.0
        z = G["z"][sl]
        if z.any():
            z = z * np.sqrt(np.abs(np.diagonal(S, axis1=1, axis2=2)).mean(axis=1))[:, None]
            S += z[:, :, None] * z[:, None, :]
        return S

    def _layout(self, vec: np.ndarray) -> np.ndarray:
        """(ne, nI): a vector of Y = V x Q (V dofs, then Q dofs; those of K consecutive) element by element."""
        ne = self.mesh.ne
        return np.concatenate([vec[:self.offQ].reshape(ne, self.nV), vec[self.offQ:self.offF].reshape(ne, self.nQ)],
                              axis=1)

    def fixed_vectors(self, owner, source) -> np.ndarray:
        """(3, ne, nQ): :meth:`hat_moments` of ``source``, kept while ``owner`` (the data the form is built of, e.g. a
        load CoefficientFunction) is the same object; the last :attr:`FIXED_KEPT` owners are kept."""
        hit = self._fixed.get(id(owner))
        if hit is not None and hit[0] is owner:
            return hit[1]
        vecs = self.hat_moments(source)
        if len(self._fixed) >= self.FIXED_KEPT:
            self._fixed.pop(next(iter(self._fixed)))
        self._fixed[id(owner)] = (owner, vecs)  # the owner is referenced: its id stays unique
        return vecs

    #: owners of :meth:`fixed_vectors` kept (fields x a few data sets)
    FIXED_KEPT = 8

    def solve(self, lfs, linear=None, vertex=None, fixed=None) -> list:
        """Sums over the patches of the patch solutions, RT part, for several right-hand sides.

        Parameters
        ----------
        lfs : list of (callable or None)
            per field: hat (CoefficientFunction) -> SumOfIntegrals of the right-hand side on
            ``self.Y`` = V x Q (test functions of Y) with every integrand multiplied by hat.
        linear : list of (tuple, list of tuples or None), optional
            per field, further right-hand side parts ``(key, space, form_of_hat, coefficients,
            scale[, reference])``: scale * B @ coefficients with B = :meth:`operators` (key, space,
            form_of_hat[, reference]) (the three hats' parts).
        vertex : list of (list or None), optional
            per field, source terms ``(values, bonus, shape)``: patch a sees -(psi_a g_a, w) with
            g_a|_K = values[K, i] for the local vertex i of K that is a (values (ne, 3)), i.e. the
            patch-constant sources of :mod:`.flux` (exact for every degree and on curved elements,
            with :meth:`vertex_mass` of that ``bonus``), or g_a|_K = values[K, i] shape if ``shape``
            (a CoefficientFunction) is not None (:meth:`shaped_mass`).
        fixed : list of (tuple or None), optional
            per field, a further right-hand side part ``(owner, source)``, source(v) = (g, v) for a test function v
            (:meth:`hat_moments`), assembled once per owner (:meth:`fixed_vectors`; the load f).

        Returns
        -------
        list of ndarray (ne, nV)
            the V (broken RT) coefficients of sigma = sum_a sigma^a per element, one per entry of lfs.
        """
        ne, nV, nI, nF3 = self.mesh.ne, self.nV, self.nI, self.nF3
        nf = len(lfs)
        self._calls += 1
        b = np.zeros((nf, 3, ne, nI))
        linear = [None] * nf if linear is None else linear
        fixed = [None] * nf if fixed is None else fixed
        with TaskManager():
            for f, (lf_of_hat, lin, fix) in enumerate(zip(lfs, linear, fixed)):
                lins = [] if lin is None else (lin if isinstance(lin, list) else [lin])
                if fix is not None:  # P_q rows only
                    b[f, :, :, nV:] = self.fixed_vectors(*fix)
                for part in lins:  # the three hats' operators in one matrix, rows in the layout of b
                    b[f] += part[4] * (self.operators(*part[:3], *part[5:6]) @ part[3]).reshape(3, ne, nI)
                if lf_of_hat is not None:
                    for i, hat in enumerate(self.hats):
                        form = LinearForm(self.Y)
                        form += lf_of_hat(hat)
                        b[f, i] += self._layout(form.Assemble().vec.FV().NumPy())
        masses = {}  # one shaped mass per (shape, bonus) of this call: the fields share the shape of lam^
        for f, terms in enumerate(vertex or []):
            for values, bonus, shape in terms or []:
                if (id(shape), bonus) not in masses:  # the shapes are alive during the call: their ids are unique
                    masses[id(shape), bonus] = (self.vertex_mass(bonus) if shape is None
                                                else self.shaped_mass(shape, bonus))
                b[f, :, :, nV:] -= np.asarray(values, float).T[:, :, None] * masses[id(shape), bonus]
        # interior patches: the constant source making the patch data compatible (module doc)
        tested = (b[:, :, :, nV:] * self.one_Q[None, None]).sum(axis=3)   # w-rhs tested with w = 1
        P, Pt, scale = self._compatibility()
        if P.shape[0]:  # kappa of the patch of every (i, K) pair (zero outside the interior patches)
            kappa = Pt @ (scale[:, None] * (P @ tested.reshape(nf, 3 * ne).T))      # (3 ne, nf)
            b[:, :, :, nV:] += kappa.T.reshape(nf, 3, ne)[:, :, :, None] * self.mass_Q[None, None]
        # condensed right-hand sides g_K^i = -A_FI A_II^{-1} b_K^i = -W^T b_K^i
        blocks = self.blocks
        g = -blocks.apply(self.W_t, b.reshape(nf * 3, ne, nI).transpose(1, 2, 0)).transpose(2, 0, 1).reshape(
            nf, 3, ne, nF3)
        ops = patch_operators(self)
        if ops is None and self._keep_inverses and self._calls >= self._inverse_from:
            self._form_inverses()
            ops = patch_operators(self)
        if ops is not None:  # every patch inverse is kept: the whole map g -> msum as four sparse products
            E_in, S_inv, G_out, R = ops
            # one right-hand side at a time: scipy's product with several vectors is slower than as many
            # products with one (S_inv, the largest, is read once per vector either way)
            msum = np.stack([G_out @ (S_inv @ (E_in @ gf)) + R @ gf for gf in g.reshape(nf, -1)]).reshape(nf, ne, nF3)
        else:
            gE, gO = self.elim.rhs(g)  # the opposite edges eliminated per element (.opposite_edges)
            msum = self.elim.facet_sums(self._patch_loop(gE, nf), gO)
        bsum = b.sum(axis=1)                                                          # (nf, ne, nI)
        if self.A_II_inv is None and self._calls >= self._inverse_from:
            # the RT rows of A_II^{-1} per element: kept for the next calls (with shapes: formed in __init__)
            self.A_II_inv = np.ascontiguousarray(np.linalg.inv(blocks.A_II)[:, :nV, :])
        if self.A_II_inv is None:  # one block per element
            xb = np.linalg.solve(blocks.A_II, bsum.transpose(1, 2, 0))[:, :nV]          # (ne, nV, nf)
        else:
            xb = blocks.apply(self.A_II_inv, bsum.transpose(1, 2, 0))
        # x_V = A_II^{-1} sum_a b^a - W_V sum_a m^a (RT part)
        x = xb - blocks.apply(self.W_V, msum.transpose(1, 2, 0))
        return [x[:, :, f].copy() for f in range(nf)]

    def _compatibility(self):
        """(P, P^T, -1 / |T_a|): P sums over the (hat i, element K) pairs (column i ne + K) of every interior
        patch (rows); kappa_a = -sum of the tested right-hand sides of patch a / |T_a| (kept)."""
        if self._compat is None:
            from scipy.sparse import csr_matrix

            ne = self.mesh.ne
            rows, cols, scale, n = [], [], [], 0
            for G in self.groups:
                sel = G["interior"]
                if not sel.any():
                    continue
                pairs = G["pairs"][sel]                                    # (np, n)
                rows.append(np.repeat(n + np.arange(len(pairs)), pairs.shape[1]))
                cols.append((self.pair_i[pairs] * ne + self.pair_K[pairs]).ravel())
                scale.append(-1.0 / G["area"][sel])
                n += len(pairs)
            cat = (lambda a, dt: np.concatenate(a) if a else np.zeros(0, dtype=dt))
            r, c = cat(rows, np.int64), cat(cols, np.int64)
            P = csr_matrix((np.ones(len(r)), (r, c)), shape=(n, 3 * ne))
            self._compat = (P, P.T.tocsr(), cat(scale, float))
        return self._compat

    def _patch_loop(self, g, nf: int) -> np.ndarray:
        """mE (nf, 3, ne, nE): the patch solutions for the right-hand sides g (nf, 3, ne, nE) of the patch unknowns,
        on the facet dofs at the vertex of every (hat i, element K) pair, group by group and chunk by chunk."""
        mE = np.zeros(g.shape)
        for gi, G in enumerate(self.groups):
            m = G["m"]
            for c0 in range(0, len(G["pairs"]), self.CHUNK):
                sl = slice(c0, c0 + self.CHUNK)
                pairs, loc = G["pairs"][sl], G["loc"][sl]
                npch = len(pairs)
                K, i = self.pair_K[pairs], self.pair_i[pairs]                       # (np, n)
                idx = np.arange(npch)[:, None, None] * m + loc
                rhs = np.stack([_scatter_add((npch, m), idx, g[f, i, K]) for f in range(nf)], axis=2)
                rhs[G["fixed"][sl]] = 0.0
                sol = self._patch_solve(gi, G, sl, rhs)                            # (np, m, nf)
                vals = np.take_along_axis(sol[:, None, :, :], loc[:, :, :, None], axis=2)  # (np, n, nE, nf)
                mE[:, i, K] = np.moveaxis(vals, 3, 0)   # every (i, K) pair lies in one patch
        return mE
