"""``python -m api``: the service (see :mod:`api.server`)."""

from __future__ import annotations

from .server import main

raise SystemExit(main())
