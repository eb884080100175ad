import os
import sys

# One OpenBLAS thread unless the user chose otherwise: the package's BLAS work is vector operations
# (norms, dot products in the Krylov and multigrid loops), where OpenBLAS threads compete with NGSolve's
# own threads and slow them down; set before numpy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from .cli import main  # noqa: E402

sys.exit(main())
