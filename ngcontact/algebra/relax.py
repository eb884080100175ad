r"""Free-boundary relaxation: projected Jacobi sweeps near the free boundary of a Newton-min iterate.

Newton-min (the primal-dual active set method) moves a wrong free boundary by about one layer of nodes per
step once it has overshot: on the two-membrane test 1 of [CAMWA21] the nested start on 2M unknowns took 8
steps on the finest level, its active sets 323,813 -> 331,557 -> 329,665 -> ... -> 329,333.  After a step
the smooth part of the error is gone and what is left sits at the free boundary: there a few sweeps of a
projected smoother of the energy J(x) = 1/2 x.K x - F.x on the constraint set {B x >= b} (the role of the
nonlinear projected Gauss-Seidel smoother in truncated nonsmooth Newton multigrid, Graeser-Kornhuber; here
damped projected Jacobi, vectorized) move the boundary where the next steps would, at the cost of sparse
products on a band of rows.

One call (:meth:`FreeBoundaryRelaxation.relax`) on (x, y):

1. the rows of the active set A = {w g(x) <= y} that touch an inactive row, and the inactive rows that touch
   an active one (the row graph is the pattern of K between the rows' first unknowns), grown by ``layers``
   layers: the band;
2. ``sweeps`` damped Jacobi sweeps x_U <- x_U + omega diag(K)_U^-1 (F - K x)_U on the unknowns U of the band
   rows, each followed by the projection of every band row onto its constraint: x_up <- max(x_up, b) for an
   obstacle row; for a two-membrane row with g < b the pair moves along (1/d_up, -1/d_lo) to g = b (the
   nearest point in the metric diag(K), so the pair's energy is minimized exactly when K has no entry between
   the two unknowns, which :class:`FreeBoundaryRelaxation` checks);
3. the band rows projected in the last sweep become active with the multiplier read off the residual,
   y = max(0, y_res), y_res = (r_up / d_up - r_lo / d_lo) / (D (1 / d_up + 1 / d_lo)), r = K x - F (the
   obstacle row: r_up / D); the other band rows inactive (y = 0).  Rows outside the band keep x and y.

The result is another point of the Newton loop (its residual and certificate are those of the new (x, y));
Newton-min's next step depends on it through the active set only.
"""
from __future__ import annotations

from typing import Tuple

import numpy as np
import scipy.sparse as sp

from .linalg import SPDSolver, pcg
from .multigrid import Multigrid
from .sparse import row_entries, submatrix

__all__ = ["FreeBoundaryRelaxation"]

#: the band's free rows are solved by CG + truncated multigrid (:class:`~.multigrid.Multigrid` on the nested
#: hierarchy the caller hands over) from this many rows on, to ||rhs - A x|| <= BAND_RTOL ||rhs||: a start of the
#: Newton loop, which converges to the same solution from any start, so the tolerance moves iteration counts only;
#: below it (or without a hierarchy, or when CG does not get there in BAND_MAXITER iterations) a sparse Cholesky
#: factorization.  At the finest ex9 level (45k free band rows of 1.05M unknowns) 5 iterations
BAND_MG_MIN, BAND_RTOL, BAND_MAXITER = 2000, 1e-10, 50


class FreeBoundaryRelaxation:
    """Projected Jacobi on a band around the free boundary of a :class:`~.system.ComplementaritySystem`
    (module docstring).  Built once per system (row graph, diagonal); ``applicable`` is False unless K is
    SPD as the system declares it (``factor_reuse``: every reduced matrix of its steps is SPD, so K is the
    Hessian of the energy; not the non-symmetric dG systems or the condensed HHO step), and where a
    constrained pair is coupled in K (the pair update would not be a minimization)."""

    def __init__(self, system):
        self.system = system
        K = system.K.tocsr()
        self.K = K
        self.d = system.diagonal()
        up, lo = system.up, system.lo
        self.two = lo >= 0
        self.lo_safe = np.where(self.two, lo, up)  # an index for every row (the lower unknown or the upper one)
        spd = bool(getattr(system, "factor_reuse", False)) and bool(len(up)) and bool(np.all(self.d > 0))
        coupled = spd and self.two.any() and np.any(np.asarray(K[up[self.two], lo[self.two]]).ravel() != 0)
        self.applicable = spd and not coupled
        if not self.applicable:
            self.G = sp.csr_matrix((len(up), len(up)))
        else:  # the graph depends on K and up only: kept with the system (its rescaled copies share K and up)
            cached = system.__dict__.get("_row_graph")
            if cached is None or cached[0] is not system.K or cached[1] is not up:
                cached = (system.K, up, _row_graph(K, up))
                system.__dict__["_row_graph"] = cached
            self.G = cached[2]

    def solve_band(self, x: np.ndarray, y: np.ndarray, layers: int, max_steps: int = 8, max_fraction: float = 1.0,
                   settle: bool = True, prolongations=()):
        """The obstacle problem on the band of ``layers`` layers around the free boundary of (x, y), the unknowns
        outside the band frozen: (x', y', rows whose class changed), or None (not applicable: a row with a lower
        unknown, K not SPD; no free boundary; the band holds more than ``max_fraction`` of the rows; the local
        active-set iteration did not settle in ``max_steps`` steps and ``settle``).

        The band's energy 1/2 x_U.K_UU x_U - c.x_U (c = F_U - K_{U,rest} x_rest) is minimized on x_U >= b by the
        primal-dual active-set iteration (Newton-min on the band) with sparse Cholesky solves of the free rows,
        from the active set of (x, y); the band rows' multipliers are read off the residual, y = (K x - F) / D
        (the obstacle row's equation), zero on the inactive rows.  Rows outside the band keep x and y.

        ``settle=False``: after ``max_steps`` solves the last one is returned even if the active set still
        changes, with y = (K x - F) / D on the rows it solved as active (negative where the iteration drops
        them) and 0 on the others, so that the active set {w g <= y} of the result is the iteration's next
        one: a Newton-min step from it is the band iteration's next step, taken on the whole system."""
        s = self.system
        if not self.applicable or self.two.any() or layers < 1:
            return None
        w = s.constraint_weight
        active = w * s.gap(x) <= y
        edge = self.boundary(active)
        if not len(edge):
            return None
        rows = self.band(edge, layers)
        if len(rows) > max_fraction * len(s.up):
            return None
        U = s.up[rows]
        order = np.argsort(U)  # the band's unknowns increasing (submatrix), rows in the same order
        rows, U = rows[order], U[order]
        KUU, c = self._frozen(U, x)
        b, D = s.b[rows], s.D[rows]
        act = active[rows].copy()
        xU = np.array(x, dtype=float)[U]
        for step in range(max_steps):
            free = ~act
            xU[act] = b[act]
            rhs = c - KUU @ np.where(act, b, 0.0)
            if free.any():
                xU[free] = self._solve_free(submatrix(KUU, free, free), rhs[free], U[free], xU[free], prolongations)
            lam = (KUU @ xU - c) / D
            new = (act & (lam > 0)) | (free & (xU < b))  # Newton-min on min(w (x - b), y): the next active set
            if np.array_equal(new, act) or step == max_steps - 1:
                break
            act = new
        if settle and not np.array_equal(new, act):
            return None
        x = np.array(x, dtype=float)
        x[U] = xU
        y = np.array(y, dtype=float)
        # y = lam on the rows solved as active (>= 0 once settled), 0 on the free ones: the active set
        # {w g <= y} of the result is the next one of the iteration, `new` (dropped: lam < 0 at g = 0; added:
        # g < 0 at y = 0)
        y[rows] = np.where(act, lam, 0.0)
        return x, y, int(np.count_nonzero(new != active[rows]))

    def _solve_free(self, A: sp.csr_matrix, rhs: np.ndarray, unknowns: np.ndarray, x0: np.ndarray, prolongations):
        """The solution of A x = rhs, A the block of K on the increasing ``unknowns`` (module constants)."""
        if prolongations and len(unknowns) >= BAND_MG_MIN:
            keep = np.zeros(self.system.n, dtype=bool)
            keep[unknowns] = True
            res = pcg(A, rhs, Multigrid(A, prolongations, keep), x0, rtol=BAND_RTOL, maxiter=BAND_MAXITER)
            if res.converged:
                return res.x
        return SPDSolver(A, self.system.solver).solve(rhs)

    def _frozen(self, U: np.ndarray, x: np.ndarray):
        """(K_UU, c = F_U - K_{U,rest} x_rest): the block of the increasing unknowns U, the rest of x frozen
        (the submatrix passes over U's rows only, not over K)."""
        KU = self.K[U]
        x_rest = np.array(x, dtype=float)
        x_rest[U] = 0.0
        return submatrix(KU, np.ones(len(U), dtype=bool), U), self.system.F[U] - KU @ x_rest

    def boundary(self, active: np.ndarray) -> np.ndarray:
        """The rows of the free boundary of ``active``: active rows next to an inactive one and inactive rows
        next to an active one."""
        G = self.G
        nb_active = G @ active.astype(np.float32)  # neighbour counts, exact in single precision
        return np.flatnonzero((active & (nb_active < np.diff(G.indptr))) | (~active & (nb_active > 0)))

    def band(self, edge: np.ndarray, layers: int) -> np.ndarray:
        """The rows ``edge`` grown by ``layers`` layers of the row graph (increasing row numbers)."""
        G = self.G
        seen = np.zeros(G.shape[0], dtype=bool)
        seen[edge] = True
        front = edge
        for _ in range(layers):
            if not len(front):
                break
            nb = G.indices[row_entries(G.indptr, front)]
            nb = nb[~seen[nb]]
            seen[nb] = True
            front = nb[np.unique(nb, return_index=True)[1]] if len(nb) > 1 else nb
        return np.flatnonzero(seen)

    def relax(self, x: np.ndarray, y: np.ndarray, *, sweeps: int, omega: float, layers: int,
              moved: int = 0, min_layers: float = 0.0) -> Tuple[np.ndarray, np.ndarray, int]:
        """(x', y', rows whose class changed) from the iterate (x, y) (module docstring); (x, y, 0) when not
        ``applicable``, when the free boundary is empty, or when the step moved it by less than ``min_layers``
        layers: ``moved`` (the rows whose class the step changed) < ``min_layers`` x its rows."""
        s = self.system
        if not self.applicable or sweeps < 1:
            return x, y, 0
        w = s.constraint_weight
        active = w * s.gap(x) <= y
        edge = self.boundary(active)
        if not len(edge) or (min_layers > 0 and moved < min_layers * len(edge)):
            return x, y, 0
        rows = self.band(edge, layers)
        two = self.two[rows]
        up, lo = s.up[rows], self.lo_safe[rows]
        in_band = np.zeros(s.n, dtype=bool)
        in_band[up] = True
        in_band[lo[two]] = True
        U = np.flatnonzero(in_band)
        # the sweeps run on the band's unknowns only: x_U with the rest of x frozen
        KUU, c = self._frozen(U, x)
        xU = np.array(x, dtype=float)[U]
        dU = self.d[U]
        pu, pl = np.searchsorted(U, up), np.searchsorted(U, lo)  # places in U; pl = pu on one-sided rows (lo_safe)
        d_up, d_lo = self.d[up], self.d[lo]
        b = s.b[rows]
        w_up = np.where(two, 1.0 / (1.0 + d_up / d_lo), 0.0)  # the pair's shift of x_up per unit of gap
        hit = np.zeros(len(rows), dtype=bool)
        for _ in range(sweeps):
            t = KUU @ xU  # xU += omega * (c - KUU xU) / dU, in place
            np.subtract(c, t, out=t)
            t *= omega
            t /= dU
            xU += t
            a = xU[pu]
            g = np.where(two, a - xU[pl], a) - b
            hit = g < 0
            # the pair moves along (1/d_up, -1/d_lo) to g = b; an obstacle row to x_up = b (the rows' upper
            # unknowns are distinct: the new values are those written)
            h = np.flatnonzero(hit)
            th = two[h]
            new_up = np.where(th, a[h] - w_up[h] * g[h], b[h])
            xU[pu[h]] = new_up
            xU[pl[h[th]]] = new_up[th] - b[h[th]]
        r = KUU @ xU - c  # residual at U, mapped to the band rows
        x = np.array(x, dtype=float)
        x[U] = xU
        y = np.array(y, dtype=float)
        r_up, r_lo = r[pu], np.where(two, r[pl], 0.0)
        inv_up, inv_lo = 1.0 / d_up, np.where(two, 1.0 / d_lo, 0.0)
        y_res = (r_up * inv_up - r_lo * inv_lo) / (s.D[rows] * (inv_up + inv_lo))
        y[rows] = np.where(hit, np.maximum(y_res, 0.0), 0.0)
        changed = int(np.count_nonzero(hit != active[rows]))
        return x, y, changed


def _row_graph(K: sp.csr_matrix, up: np.ndarray) -> sp.csr_matrix:
    """The pattern of K[up][:, up] (single-precision ones: the products count neighbours): rows l, l' are
    neighbours when their first unknowns are coupled in K.
    Where the rows' first unknowns are 0..m-1 and K has no entry from them to the others (two membranes,
    membrane 1 first; an obstacle on every unknown) it is K's leading block, read without a copy of the values."""
    m = len(up)
    end = K.indptr[m] if m <= K.shape[0] else 0
    if np.array_equal(up, np.arange(m)) and (end == 0 or K.indices[:end].max() < m):
        return sp.csr_matrix((np.ones(end, dtype=np.float32), K.indices[:end], K.indptr[:m + 1]), shape=(m, m))
    G = submatrix(K, up, up)
    return sp.csr_matrix((np.ones(G.nnz, dtype=np.float32), G.indices, G.indptr), shape=G.shape)
