"""Restarted GMRES with an incomplete-LU preconditioner for the Newton steps.

The inexact semismooth Newton method (seed slide "Inexact semismooth Newton
method", [JSC20] Section 2.3) replaces the exact solve of A^{k-1} X^k =
B^{k-1} by i steps of an iterative solver started from X^{k,0} = X^{k-1}:

    A^{k-1} X^{k,i} = B^{k-1} - R^{k,i},        R^{k,i}: algebraic residual.

:func:`gmres` is a restarted GMRES(m) with *right* preconditioning
(A M^{-1} u = b, x = M^{-1} u): the quantity GMRES minimizes, |g_{j+1}| of the
Givens-rotated Hessenberg system, is then the norm of the true residual
b - A x of the *unpreconditioned* system, so the stopping tests of [JSC20]
(||R_alg|| / ||B||) are tested every iteration at no cost.  Every ``nu``
iterations (and at every stop) the iterate x^{i} is formed, the true residual
r^{i} = b - A x^{i} computed, and ``monitor(KrylovState)`` called; it may stop
the iteration (the adaptive criteria of [JSC20] are evaluated there).

Why an own loop rather than a library GMRES (ngsolve 6.2.2608, scipy 1.x): ``scipy.sparse.linalg.gmres`` reports only the (preconditioned)
residual *norm* to its callback, not the iterate, so the algebraic residual
vector and the a posteriori estimators of X^{k,i} cannot be evaluated every
nu steps without restarting it (which changes the Krylov space); NGSolve's
``krylovspace.GMRes`` is also a Python loop and NGSolve has no ILU
preconditioner (its preconditioners: Jacobi "local", "bddc", "multigrid",
"h1amg").  The cost is in the sparse products, the ILU triangular solves (scipy/SuperLU,
compiled) and the orthogonalization (classical Gram-Schmidt done twice, two
BLAS-2 products per iteration instead of j BLAS-1 calls of modified GS, so
the Python loop overhead stays small against the products).

Threads: on a loaded 2-core machine OpenBLAS's threaded BLAS-2 kernels slow
these small products down by a large factor; ``make inexact-study``
therefore sets OPENBLAS_NUM_THREADS=1.

The preconditioner :class:`ILU` is SuperLU's threshold ILU (``spilu``,
ILUTP) with a small fill (defaults drop_tol=1e-4, fill_factor=2): the
preconditioner of [JSC20] is "ILU", its parameters are not given.
"""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field
from typing import Callable, List, Optional

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["ILU", "KrylovState", "KrylovResult", "PreconditionerCache", "gmres", "cg", "units_scale", "UNITS_SPREAD"]


class ILU:
    """Incomplete LU factorization M ~ A (SuperLU ``spilu``); ``solve(r)`` = M^{-1} r.

    Parameters
    ----------
    A : sparse matrix
    drop_tol, fill_factor : float
        SuperLU ILUTP parameters (``scipy.sparse.linalg.spilu``).
    """

    def __init__(self, A: sp.spmatrix, drop_tol: float = 1e-4, fill_factor: float = 2.0):
        t0 = time.perf_counter()
        self.n = A.shape[0]
        self.drop_tol, self.fill_factor = drop_tol, fill_factor
        self._ilu = spla.spilu(sp.csc_matrix(A), drop_tol=drop_tol, fill_factor=fill_factor) if self.n else None
        self.nnz = (self._ilu.L.nnz + self._ilu.U.nnz) if self.n else 0
        self.time_setup = time.perf_counter() - t0

    def solve(self, r: np.ndarray) -> np.ndarray:
        return self._ilu.solve(r) if self.n else np.zeros(0)


class PreconditionerCache:
    """The preconditioners of the last ``size`` matrices, handed out again only for a bitwise identical
    matrix (same shape, sparsity and values; plus ``extra``, e.g. the kept unknowns of a truncated
    multigrid), so reuse never changes an iterate.  In a time-stepping run with Newton-min the reduced
    Newton matrix of a step's first iteration is the previous step's last one whenever the active set
    and dt did not change.  ``hits`` / ``misses`` count the look-ups."""

    def __init__(self, size: int = 2):
        self.size, self.hits, self.misses = size, 0, 0
        self._items: list = []  # (key, preconditioner), most recent last

    @staticmethod
    def _key(A, extra) -> tuple:
        A = sp.csr_matrix(A)
        h = hashlib.blake2b(digest_size=16)
        for arr in (A.indptr, A.indices, A.data) + ((np.asarray(extra),) if extra is not None else ()):
            h.update(np.ascontiguousarray(arr).tobytes())
        return A.shape, A.nnz, h.hexdigest()

    def get(self, A, build: Callable, extra=None):
        """(preconditioner, reused): the cached one for this matrix, else ``build()`` (then cached)."""
        key = self._key(A, extra)
        for k, M in self._items:
            if k == key:
                self.hits += 1
                return M, True
        self.misses += 1
        M = build()
        self._items = (self._items + [(key, M)])[-self.size:]
        return M, False


@dataclass
class KrylovState:
    """What :func:`gmres` shows its monitor every ``nu`` iterations.

    Attributes
    ----------
    i : int
        iterations done (total over restarts).
    x : ndarray
        the iterate x^{i}.
    r : ndarray
        the algebraic residual b - A x^{i} (computed, not estimated).
    res : float
        ||r|| / ||b||.
    """

    i: int
    x: np.ndarray
    r: np.ndarray
    res: float


@dataclass
class KrylovResult:
    """Outcome of :func:`gmres`.

    ``reason`` is ``"tolerance"``, ``"monitor"``, ``"maxiter"`` or ``"stagnation"`` (the computed
    residual stays above the tolerance that the GMRES estimate reached: round-off floor);
    ``res_history[j]`` is ||b - A x^{j}|| / ||b|| for j = 0..iterations
    (the GMRES residual, exact up to round-off with right preconditioning).
    """

    x: np.ndarray
    r: np.ndarray
    iterations: int
    converged: bool
    reason: str
    res: float
    res_history: List[float] = field(default_factory=list)
    time: float = 0.0


#: Krylov residuals in the units of x (Jacobi-weighted) when max / min of the matrix's diagonal exceeds this: rows
#: of very different size (two membranes with tensions far apart), where the plain 2-norm lets the stiff rows decide
UNITS_SPREAD = 1e6


def units_scale(A) -> Optional[np.ndarray]:
    """1 / diag(A) when the (positive) diagonal of A spans more than :data:`UNITS_SPREAD`, else None: the weights of
    residuals in the units of x (``D^{-1} r``) for the Krylov solves of the Newton steps."""
    d = np.asarray(A.diagonal(), dtype=float)
    if not len(d) or not np.all(d > 0.0) or d.max() <= UNITS_SPREAD * d.min():
        return None
    return 1.0 / d


def _norm2(v) -> float:
    return float(np.linalg.norm(v))


def _krylov_start(A, b, x0, M):
    """(preconditioner, x^0, scale = ||b|| (1 if b = 0), r^0 = b - A x^0, ||r^0||) of :func:`gmres` and :func:`cg`."""
    prec = (lambda v: v) if M is None else M.solve
    x = np.zeros(len(b)) if x0 is None else np.array(x0, dtype=float)
    bnorm = float(np.linalg.norm(b))
    r = b - A @ x
    return prec, x, (bnorm if bnorm > 0 else 1.0), r, float(np.linalg.norm(r))


def gmres(A, b: np.ndarray, x0: Optional[np.ndarray] = None, M=None, *, rtol: float = 1e-10,
          restart: int = 100, maxiter: int = 5000, nu: int = 10,
          monitor: Optional[Callable[[KrylovState], bool]] = None) -> KrylovResult:
    """Restarted, right-preconditioned GMRES(restart) for A x = b (module docstring).

    Parameters
    ----------
    A : sparse matrix or LinearOperator
    b : ndarray
    x0 : ndarray, optional
        initial guess (default 0): warm start X^{k,0} = X^{k-1}.
    M : object with ``solve(r)``, optional
        preconditioner M^{-1} (e.g. :class:`ILU`); identity if None.
    rtol : float
        stop when ||b - A x|| <= rtol ||b|| (0 disables the test).
    restart : int
        Krylov dimension before restarting.
    maxiter : int
        maximum total iterations.
    nu : int
        the monitor is called every ``nu`` iterations (i = nu, 2 nu, ...)
        and also at i = 0.
    monitor : callable, optional
        ``monitor(KrylovState) -> bool``; True stops the iteration.

    Returns
    -------
    KrylovResult
    """
    t0 = time.perf_counter()
    n = len(b)
    prec, x, scale, r, beta = _krylov_start(A, b, x0, M)
    hist = [beta / scale]
    i = 0

    def finish(x, r, reason):
        res = float(np.linalg.norm(r)) / scale
        return KrylovResult(x, r, i, reason == "tolerance", reason, res, hist, time.perf_counter() - t0)

    if monitor is not None and monitor(KrylovState(0, x, r, hist[0])):
        return finish(x, r, "monitor")
    if beta <= rtol * scale or n == 0 or beta == 0.0:
        return finish(x, r, "tolerance")
    m = max(1, min(restart, n))
    V = np.zeros((m + 1, n))
    Zp = np.zeros((m, n))  # M^{-1} v_j
    while True:
        H = np.zeros((m + 1, m))
        cs, sn = np.zeros(m), np.zeros(m)
        g = np.zeros(m + 1)
        g[0] = beta
        V[0] = r / beta

        def iterate(k):  # x^{i} from the first k Arnoldi vectors of this cycle
            yk = np.linalg.solve(np.triu(H[:k, :k]), g[:k])
            xk = x + yk @ Zp[:k]
            return xk, b - A @ xk

        for j in range(m):
            Zp[j] = prec(V[j])
            w = A @ Zp[j]
            # classical Gram-Schmidt, twice (CGS2: as stable as modified GS, BLAS-2 instead of j BLAS-1 calls)
            h = V[:j + 1] @ w
            w -= h @ V[:j + 1]
            h2 = V[:j + 1] @ w
            w -= h2 @ V[:j + 1]
            H[:j + 1, j] = h + h2
            h_next = float(np.linalg.norm(w))
            H[j + 1, j] = h_next
            if h_next > 0:
                V[j + 1] = w / h_next
            for l in range(j):  # previous Givens rotations
                t = cs[l] * H[l, j] + sn[l] * H[l + 1, j]
                H[l + 1, j] = -sn[l] * H[l, j] + cs[l] * H[l + 1, j]
                H[l, j] = t
            d = np.hypot(H[j, j], H[j + 1, j])
            cs[j], sn[j] = (H[j, j] / d, H[j + 1, j] / d) if d > 0 else (1.0, 0.0)
            H[j, j] = d
            H[j + 1, j] = 0.0
            g[j + 1] = -sn[j] * g[j]
            g[j] = cs[j] * g[j]
            i += 1
            hist.append(abs(g[j + 1]) / scale)
            done = abs(g[j + 1]) <= rtol * scale or h_next == 0.0
            if monitor is not None and i % nu == 0:
                xi, ri = iterate(j + 1)
                hist[-1] = float(np.linalg.norm(ri)) / scale
                if monitor(KrylovState(i, xi, ri, hist[-1])):
                    return finish(xi, ri, "monitor")
            if done or i >= maxiter:
                break
        x, r = iterate(j + 1)
        beta_old, beta = beta, float(np.linalg.norm(r))
        hist[-1] = beta / scale
        if beta <= rtol * scale or beta == 0.0:
            return finish(x, r, "tolerance")
        if i >= maxiter:
            return finish(x, r, "maxiter")
        if beta > 0.5 * beta_old and j + 1 < m:
            # the cycle ended on the *estimated* residual but the computed one stays above the
            # tolerance: the attainable accuracy (round-off) is reached
            return finish(x, r, "stagnation")


def cg(A, b: np.ndarray, x0: Optional[np.ndarray] = None, M=None, *, rtol: float = 1e-10, maxiter: int = 5000,
       nu: int = 10, monitor: Optional[Callable[[KrylovState], bool]] = None,
       weights: Optional[np.ndarray] = None) -> KrylovResult:
    """Preconditioned conjugate gradients for SPD A (SPD preconditioner ``M.solve``), with the interface of
    :func:`gmres`: ``monitor(KrylovState)`` at i = 0 and every ``nu`` iterations sees the iterate and its
    true residual and may stop the iteration; the result's residuals are true residuals.

    The recursively updated residual decides the tolerance test; at a stop it is recomputed, and if the
    true residual is still above the tolerance the iteration continues from it (residual replacement) or,
    when that does not halve it any more, stops with ``"stagnation"`` (round-off floor).  The monitor's
    true residuals do not change the iteration (no restart: CG keeps its conjugacy).  ``weights``: the residuals
    (tests, history, the monitor's) are ||weights * r|| / ||weights * b|| instead of the 2-norm (e.g. 1 / diag(A):
    row by row in the units of x); the iteration is the same.
    """
    t0 = time.perf_counter()
    prec, x, scale, r, rnorm = _krylov_start(A, b, x0, M)
    if weights is not None:
        def norm(v):
            return float(np.linalg.norm(weights * v))
        scale, rnorm = (norm(b) or 1.0), norm(r)
    else:
        norm = _norm2
    hist = [rnorm / scale]
    i = 0

    def finish(reason):
        return KrylovResult(x, r, i, reason == "tolerance", reason, hist[-1], hist, time.perf_counter() - t0)

    if monitor is not None and monitor(KrylovState(0, x, r, hist[0])):
        return finish("monitor")
    if rnorm <= rtol * scale or rnorm == 0.0:
        return finish("tolerance")
    z = prec(r)
    p, rz = z.copy(), float(r @ z)
    last_true = rnorm
    work = np.empty_like(p)  # alpha p and alpha q formed in place: no new vector per iteration
    while i < maxiter:
        q = A @ p
        pq = float(p @ q)
        if not pq > 0.0:  # A or M not SPD on this vector (or p = 0): nothing more to gain
            r = b - A @ x
            hist[-1] = norm(r) / scale
            return finish("stagnation")
        alpha = rz / pq
        x += np.multiply(p, alpha, out=work)
        r -= np.multiply(q, alpha, out=work)
        i += 1
        hist.append(norm(r) / scale)
        if monitor is not None and i % nu == 0:  # the monitor sees the true residual; CG goes on unchanged
            r_true = b - A @ x
            hist[-1] = norm(r_true) / scale
            if monitor(KrylovState(i, x, r_true, hist[-1])):
                r = r_true
                return finish("monitor")
            if hist[-1] <= rtol:
                r = r_true
                return finish("tolerance")
        elif hist[-1] <= rtol:
            r = b - A @ x  # the recursion says converged: check the true residual
            hist[-1] = norm(r) / scale
            if hist[-1] <= rtol:
                return finish("tolerance")
            if hist[-1] > 0.5 * last_true / scale:  # replacement no longer gains: round-off floor
                return finish("stagnation")
            last_true = hist[-1] * scale
            z = prec(r)  # residual replacement: restart from the true residual
            p, rz = z.copy(), float(r @ z)
            continue
        z = prec(r)
        rz_new = float(r @ z)
        p *= rz_new / rz  # p = z + beta p, in place (the same numbers)
        p += z
        rz = rz_new
    r = b - A @ x
    hist[-1] = norm(r) / scale
    return finish("tolerance" if hist[-1] <= rtol else "maxiter")
