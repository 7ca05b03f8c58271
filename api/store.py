"""Storage of tune results (SQLAlchemy 2.0): a SQLite file by default, PostgreSQL by URL.

One table, ``tunes``: the request as validated, the plants as the library
accepted them (the exact numbers analysed, so plots can be redrawn), the result
JSON. A row is committed before the service answers, so an ``id`` that was
returned can always be read back, across restarts.

The calls are blocking; routes run them in a thread.
"""

from __future__ import annotations

import datetime as _dt
import uuid
from dataclasses import dataclass
from typing import Any

from sqlalchemy import JSON, Boolean, DateTime, String, create_engine, event, func, select, text
from sqlalchemy.engine import Engine, make_url
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

__all__ = ["Store", "TuneRecord", "TuneSummary", "StoreError"]


class StoreError(Exception):
    """The database could not be reached or refused the operation."""


class _Base(DeclarativeBase):
    pass


class _TuneRow(_Base):
    __tablename__ = "tunes"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    created_at: Mapped[_dt.datetime] = mapped_column(DateTime(timezone=True), index=True)
    structure: Mapped[str] = mapped_column(String(32))
    meets_spec: Mapped[bool] = mapped_column(Boolean)
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    plants: Mapped[list[dict[str, Any]]] = mapped_column(JSON)
    result: Mapped[dict[str, Any]] = mapped_column(JSON)


def _utc(t: _dt.datetime) -> _dt.datetime:
    return t if t.tzinfo else t.replace(tzinfo=_dt.UTC)  # SQLite returns naive datetimes


@dataclass(frozen=True)
class TuneSummary:
    id: str
    created_at: _dt.datetime
    structure: str
    meets_spec: bool


@dataclass(frozen=True)
class TuneRecord:
    id: str
    created_at: _dt.datetime
    structure: str
    meets_spec: bool
    request: dict[str, Any]
    plants: list[dict[str, Any]]
    result: dict[str, Any]

    @classmethod
    def _from_row(cls, r: _TuneRow) -> TuneRecord:
        return cls(r.id, _utc(r.created_at), r.structure, r.meets_spec, r.request, r.plants, r.result)


def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA journal_mode=WAL")  # readers do not block the writer
    cur.execute("PRAGMA synchronous=FULL")  # a committed result survives a power cut
    cur.execute("PRAGMA busy_timeout=30000")
    cur.close()


class Store:
    """Tune results in a database given by a SQLAlchemy URL."""

    def __init__(self, url: str, *, engine_kwargs: dict[str, Any] | None = None) -> None:
        u = make_url(url)
        kwargs: dict[str, Any] = {"pool_pre_ping": True}
        if u.get_backend_name() == "sqlite":
            kwargs["connect_args"] = {"check_same_thread": False, "timeout": 30}
        elif u.get_backend_name() == "postgresql":
            kwargs["connect_args"] = {"connect_timeout": 5}
        kwargs.update(engine_kwargs or {})
        self.engine: Engine = create_engine(u, **kwargs)
        if u.get_backend_name() == "sqlite":
            event.listen(self.engine, "connect", _sqlite_pragmas)
        self._session = sessionmaker(self.engine, expire_on_commit=False)
        self.backend = u.get_backend_name()

    def create_schema(self) -> None:
        try:
            _Base.metadata.create_all(self.engine)
        except SQLAlchemyError as e:
            raise StoreError(f"cannot create the tables: {type(e).__name__}") from e

    def dispose(self) -> None:
        self.engine.dispose()

    def ping(self) -> bool:
        try:
            with self.engine.connect() as c:
                c.execute(text("SELECT 1"))
            return True
        except SQLAlchemyError:
            return False

    def add(self, *, request: dict[str, Any], plants: list[dict[str, Any]], result: dict[str, Any]) -> TuneRecord:
        row = _TuneRow(
            id=uuid.uuid4().hex, created_at=_dt.datetime.now(_dt.UTC),
            structure=str(result.get("structure", "")), meets_spec=bool(result.get("meets_spec", False)),
            request=request, plants=plants, result=result,
        )
        try:
            with Session(self.engine, expire_on_commit=False) as s, s.begin():
                s.add(row)
        except SQLAlchemyError as e:
            raise StoreError(f"the result could not be stored: {type(e).__name__}") from e
        return TuneRecord._from_row(row)

    def get(self, tune_id: str) -> TuneRecord | None:
        try:
            with self._session() as s:
                row = s.get(_TuneRow, tune_id)
                return None if row is None else TuneRecord._from_row(row)
        except SQLAlchemyError as e:
            raise StoreError(f"the database could not be read: {type(e).__name__}") from e

    def list(self, *, limit: int, offset: int) -> tuple[list[TuneSummary], int]:
        """Newest first; also the total number of stored results."""
        cols = (_TuneRow.id, _TuneRow.created_at, _TuneRow.structure, _TuneRow.meets_spec)
        try:
            with self._session() as s:
                total = s.scalar(select(func.count()).select_from(_TuneRow)) or 0
                rows = s.execute(
                    select(*cols).order_by(_TuneRow.created_at.desc(), _TuneRow.id).limit(limit).offset(offset)
                ).all()
                return [TuneSummary(r[0], _utc(r[1]), r[2], r[3]) for r in rows], int(total)
        except SQLAlchemyError as e:
            raise StoreError(f"the database could not be read: {type(e).__name__}") from e
