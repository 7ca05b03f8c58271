"""The real PostgreSQL server of this machine kind, for the tests that need it (shared helper)."""

from __future__ import annotations

import os

import pytest

PG_USERS = ("postgres", "root")
PG_HOSTPORT = "127.0.0.1:5432"

__all__ = ["PG_HOSTPORT", "pg_admin_engine", "pg_base_url", "require_pg_base_url"]


def pg_base_url() -> str | None:
    """A working ``postgresql+psycopg://`` URL to database ``test`` (trust auth), or None."""
    from sqlalchemy import create_engine, text

    for user in PG_USERS:
        url = f"postgresql+psycopg://{user}@{PG_HOSTPORT}/test"
        eng = create_engine(url, connect_args={"connect_timeout": 3})
        try:
            with eng.connect() as c:
                c.execute(text("SELECT 1"))
            return url
        except Exception:
            continue
        finally:
            eng.dispose()
    return None


def require_pg_base_url() -> str:
    """The URL; in CI (which starts the server) a missing server fails the test, elsewhere it skips."""
    url = pg_base_url()
    if url is None:
        if os.environ.get("CI"):
            pytest.fail(f"PostgreSQL is not reachable on {PG_HOSTPORT} (CI starts it)")
        pytest.skip(f"PostgreSQL is not reachable on {PG_HOSTPORT}")
    return url


def pg_admin_engine(url: str):
    """An engine for a test's own set-up and clean-up (CREATE/DROP SCHEMA): a statement that would wait on a lock
    held by a connection the test leaked fails after 30 s, naming it, instead of waiting for good."""
    from sqlalchemy import create_engine

    return create_engine(url, connect_args={"connect_timeout": 10, "options": "-c lock_timeout=30000"})
