"""Storage of results (SQLAlchemy 2.0): a SQLite file by default, PostgreSQL by URL.

Table ``tunes``: the request as validated, the plants as the library accepted them (the exact
numbers analysed, so plots can be redrawn), the result JSON. Table ``identifications``: the
options as validated, the submitted record itself (``data``: input, output, time or rate; kept
apart so that listing and reading results never loads it), the result JSON. A row is committed
before the service answers, so an ``id`` that was returned can always be read back, across
restarts.

The calls are blocking; routes run them in a thread. The service starts even when the database
is unreachable: :meth:`Store.create_schema` is then retried in the background, and every call
made before it has succeeded tries it once more first (so the first request after the database
is back is served), else raises :class:`StoreError` (503).
"""

from __future__ import annotations

import datetime as _dt
import threading
import uuid
from dataclasses import dataclass
from typing import Any

from sqlalchemy import JSON, Boolean, DateTime, Float, Integer, String, create_engine, event, func, select, text
from sqlalchemy.engine import Engine, make_url
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import DeclarativeBase, Mapped, Session, mapped_column, sessionmaker

__all__ = ["Store", "TuneRecord", "TuneSummary", "IdentificationRecord", "IdentificationSummary", "StoreError",
           "reason"]


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


class _IdentificationRow(_Base):
    __tablename__ = "identifications"

    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    created_at: Mapped[_dt.datetime] = mapped_column(DateTime(timezone=True), index=True)
    poles: Mapped[int] = mapped_column(Integer)
    zeros: Mapped[int] = mapped_column(Integer)
    cost: Mapped[float] = mapped_column(Float)
    quality: Mapped[str] = mapped_column(String(16))
    n_samples: Mapped[int] = mapped_column(Integer)
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    data: Mapped[dict[str, Any]] = mapped_column(JSON, deferred=True)
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


@dataclass(frozen=True)
class IdentificationSummary:
    id: str
    created_at: _dt.datetime
    poles: int
    zeros: int
    cost: float
    quality: str
    n_samples: int


@dataclass(frozen=True)
class IdentificationRecord:
    id: str
    created_at: _dt.datetime
    request: dict[str, Any]
    result: dict[str, Any]
    data: dict[str, Any] | None = None  # loaded only when asked for


def _now_id() -> tuple[str, _dt.datetime]:
    return uuid.uuid4().hex, _dt.datetime.now(_dt.UTC)


def reason(e: BaseException | None) -> str:
    """The driver's first line (e.g. "connection refused"), without the SQL or parameters."""
    if e is None:
        return "unknown"
    orig = getattr(e, "orig", None) or e
    line = str(orig).strip().splitlines()[0] if str(orig).strip() else type(orig).__name__
    return line[:200]


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
        self.ready = False  # the tables exist (create_schema has succeeded once)
        self._schema_lock = threading.Lock()

    def create_schema(self) -> None:
        with self._schema_lock:
            if self.ready:
                return
            try:
                _Base.metadata.create_all(self.engine)
            except SQLAlchemyError as e:
                raise StoreError("database unreachable") from e
            self.ready = True

    def require_ready(self) -> None:
        if not self.ready:
            self.create_schema()

    def dispose(self) -> None:
        self.engine.dispose()

    def ping(self) -> bool:
        if not self.ready:
            try:
                self.create_schema()
            except StoreError:
                return False
        try:
            with self.engine.connect() as c:
                c.execute(text("SELECT 1"))
            return True
        except SQLAlchemyError:
            return False

    def _insert(self, row: Any) -> None:
        self.require_ready()
        try:
            with Session(self.engine, expire_on_commit=False) as s, s.begin():
                s.add(row)
        except SQLAlchemyError as e:
            raise StoreError(f"the result could not be stored: {type(e).__name__}") from e

    def _read(self, fn: Any) -> Any:
        self.require_ready()
        try:
            with self._session() as s:
                return fn(s)
        except SQLAlchemyError as e:
            raise StoreError(f"the database could not be read: {type(e).__name__}") from e

    def _page(self, s: Session, cls: Any, cols: tuple[Any, ...], limit: int, offset: int) -> tuple[list[Any], int]:
        total = s.scalar(select(func.count()).select_from(cls)) or 0
        rows = s.execute(select(*cols).order_by(cls.created_at.desc(), cls.id).limit(limit).offset(offset)).all()
        return rows, int(total)

    # -- tunes ------------------------------------------------------------------------------------
    def add(self, *, request: dict[str, Any], plants: list[dict[str, Any]], result: dict[str, Any]) -> TuneRecord:
        rid, now = _now_id()
        row = _TuneRow(
            id=rid, created_at=now,
            structure=str(result.get("structure", "")), meets_spec=bool(result.get("meets_spec", False)),
            request=request, plants=plants, result=result,
        )
        self._insert(row)
        return TuneRecord._from_row(row)

    def get(self, tune_id: str) -> TuneRecord | None:
        def fn(s: Session) -> TuneRecord | None:
            row = s.get(_TuneRow, tune_id)
            return None if row is None else TuneRecord._from_row(row)

        return self._read(fn)

    def list(self, *, limit: int, offset: int) -> tuple[list[TuneSummary], int]:
        """Newest first; also the total number of stored results."""
        cols = (_TuneRow.id, _TuneRow.created_at, _TuneRow.structure, _TuneRow.meets_spec)

        def fn(s: Session) -> tuple[list[TuneSummary], int]:
            rows, total = self._page(s, _TuneRow, cols, limit, offset)
            return [TuneSummary(r[0], _utc(r[1]), r[2], r[3]) for r in rows], total

        return self._read(fn)

    # -- identifications --------------------------------------------------------------------------
    def add_identification(self, *, request: dict[str, Any], data: dict[str, Any],
                           result: dict[str, Any]) -> IdentificationRecord:
        rid, now = _now_id()
        model = result.get("model", {})
        cost = result.get("cost")
        row = _IdentificationRow(
            id=rid, created_at=now, poles=int(model.get("poles", 0)), zeros=int(model.get("zeros", 0)),
            cost=float(cost) if isinstance(cost, (int, float)) else float("nan"),
            quality=str(result.get("quality", "")), n_samples=int(result.get("n_samples", 0)),
            request=request, data=data, result=result,
        )
        self._insert(row)
        return IdentificationRecord(row.id, _utc(row.created_at), request, result)

    def get_identification(self, ident_id: str, *, with_data: bool = False) -> IdentificationRecord | None:
        from sqlalchemy.orm import undefer

        def fn(s: Session) -> IdentificationRecord | None:
            q = select(_IdentificationRow).where(_IdentificationRow.id == ident_id)
            if with_data:
                q = q.options(undefer(_IdentificationRow.data))
            row = s.scalars(q).first()
            if row is None:
                return None
            return IdentificationRecord(row.id, _utc(row.created_at), row.request, row.result,
                                        row.data if with_data else None)

        return self._read(fn)

    def identification_usage(self) -> tuple[int, int]:
        """How many identifications are stored, and their records' samples together."""
        R = _IdentificationRow

        def fn(s: Session) -> tuple[int, int]:
            n, samples = s.execute(select(func.count(), func.coalesce(func.sum(R.n_samples), 0))).one()
            return int(n), int(samples)

        return self._read(fn)

    def list_identifications(self, *, limit: int, offset: int) -> tuple[list[IdentificationSummary], int]:
        """Newest first; also the total number stored."""
        R = _IdentificationRow
        cols = (R.id, R.created_at, R.poles, R.zeros, R.cost, R.quality, R.n_samples)

        def fn(s: Session) -> tuple[list[IdentificationSummary], int]:
            rows, total = self._page(s, R, cols, limit, offset)
            return [IdentificationSummary(r[0], _utc(r[1]), r[2], r[3], r[4], r[5], r[6]) for r in rows], total

        return self._read(fn)
