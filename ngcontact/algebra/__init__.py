"""The algebraic layer: complementarity systems, C-functions, sparse direct and Krylov solvers.

Knows nothing of meshes, problems or drivers: :mod:`.system` (the complementarity
system ``K x - B^T D y = F``, ``C(g(x), y) = 0``, the row classes and the reduction
of its Newton step), :mod:`.reuse` (factorization reuse across Newton steps),
:mod:`.cfunctions`, :mod:`.linalg` (direct solves), :mod:`.krylov` (GMRES, ILU).
"""
