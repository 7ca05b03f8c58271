"""Imported once by the forkserver that forks the solver processes (never by the server itself).

One solve = one core (parallelism comes from the pool), so BLAS/OpenMP thread pools are
limited to one thread before numpy is imported; then the tuning stack is imported, so a
forked solver starts warm, in milliseconds, sharing these pages copy-on-write.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from .worker import warm_up  # noqa: E402

warm_up()
