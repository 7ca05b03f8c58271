"""Imported once by the forkserver that forks the solver processes (never by the server itself).

One solve = one core (parallelism comes from the pool), so BLAS/OpenMP thread pools are
limited to one thread before numpy is imported; then the tuning stack (and matplotlib, for the
plot processes) is imported, so a forked solver starts warm, in milliseconds, sharing these pages
copy-on-write. The forkserver
is tied to the service's life with ``PR_SET_PDEATHSIG`` (see :mod:`api.worker`).
"""

from __future__ import annotations

import os

from .jobs import PLOT_MODULES  # cheap: the jobs import their libraries when run
from .worker import SERVICE_PID_VAR, THREAD_VARS, set_parent_death_signal, warm_up  # cheap

for _var in THREAD_VARS:  # before numpy is imported (set_parent_death_signal imports it)
    os.environ.setdefault(_var, "1")

# the forkserver ends with the service (and its solvers with it: see api.worker); if the parent changed
# between the check and prctl, the service died in between
_service = int(os.environ.get(SERVICE_PID_VAR, "0") or 0)
if _service and os.getppid() == _service and set_parent_death_signal() and os.getppid() != _service:
    os._exit(1)

warm_up()
warm_up(PLOT_MODULES)
