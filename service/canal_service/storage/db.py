"""Engines, sessions and migrations.

SQLite is the embedded default, tuned for one process with many threads: WAL so readers
never wait for the writer, ``busy_timeout`` so writers queue instead of failing, foreign
keys on so deletes cascade. Write transactions start with ``BEGIN IMMEDIATE``: a deferred
transaction that reads and then writes can fail with SQLITE_BUSY_SNAPSHOT under concurrent
writers, and no busy timeout saves it. PostgreSQL needs none of this.

Writers of one process queue on a lock before they ask SQLite (see :class:`Database`), and
:meth:`Database.write_one` runs the upload's single statement on SQLite without
SQLAlchemy's per-execution machinery (compiled once, on a connection of its own), and
without WAL checkpoints: a thread of their own runs those (:class:`_Checkpointer`).
"""

from __future__ import annotations

import json
import logging
import sqlite3
import threading
from collections.abc import Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager, nullcontext
from pathlib import Path
from typing import Any

import orjson
from alembic import command
from alembic.config import Config
from sqlalchemy import Connection, Engine, create_engine, event, text
from sqlalchemy.engine import Dialect, make_url
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import PoolProxiedConnection
from sqlalchemy.sql.base import Executable
from sqlalchemy.sql.compiler import SQLCompiler
from sqlalchemy.sql.dml import UpdateBase

MIGRATIONS_DIR = Path(__file__).resolve().parent.parent / "migrations"

log = logging.getLogger("canal_service")

# Arbitrary constant: replicas starting together serialise their migrations on it.
_MIGRATION_LOCK_KEY = 0x43414E414C


def json_loads(text: str | bytes) -> Any:
    """JSON columns as Python: orjson, else the stdlib for what orjson refuses (``NaN``,
    integers beyond 64 bits, which ``json.dumps`` writes).

    Why not the stdlib alone: a fitted canal is a ~100 kB column, and ``json.loads`` parses
    it in one call of 1.5-4 ms that holds the GIL throughout (measured here), which stalls
    every other thread of the process for that long: the live bridge's pose worker when a
    model loads beside it. orjson parses it about ten times faster.
    """
    try:
        return orjson.loads(text)
    except orjson.JSONDecodeError:
        return json.loads(text)


def _sqlite_engine(url: str, *, immediate: bool) -> Engine:
    engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30},
                           json_deserializer=json_loads)

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: Any, _record: Any) -> None:
        # Let SQLAlchemy emit BEGIN itself (see the SQLAlchemy SQLite transaction docs).
        dbapi_connection.isolation_level = None
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA synchronous=NORMAL")
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute("PRAGMA busy_timeout=30000")
        cursor.close()

    begin = "BEGIN IMMEDIATE" if immediate else "BEGIN"

    @event.listens_for(engine, "begin")
    def _on_begin(connection: Any) -> None:
        connection.exec_driver_sql(begin)

    return engine


class _CompiledStatement:
    """A statement compiled once for SQLite: its SQL, and how to turn named values into
    the positional parameters sqlite3 takes (with each type's own bind conversion, e.g.
    datetimes to the text SQLAlchemy stores)."""

    def __init__(self, statement: UpdateBase, dialect: Dialect) -> None:
        self.compiled: SQLCompiler = statement.compile(dialect=dialect)
        self.sql = str(self.compiled)
        self.names: tuple[str, ...] = tuple(self.compiled.positiontup or ())
        self.converters = tuple(
            self.compiled.binds[name].type.dialect_impl(dialect).bind_processor(dialect)
            for name in self.names)

    def parameters(self, values: Mapping[str, Any]) -> tuple[Any, ...]:
        # construct_params adds the values bound in the statement itself, and refuses a
        # missing one as SQLAlchemy's execute would.
        named = self.compiled.construct_params(dict(values)) or {}
        return tuple(named[name] if convert is None else convert(named[name])
                     for name, convert in zip(self.names, self.converters, strict=True))


class _Checkpointer:
    """SQLite's WAL checkpoints, run in a thread of their own (``canal-checkpoint``).

    By default the connection whose commit takes the WAL past 1,000 pages (4 MB, about 160
    uploads) copies it into the database file and syncs it, inside the request: 5-20 ms on
    a quiet disk, hundreds on a busy one, with the write lock held and every other upload
    waiting (measured: lock hold p99 69 ms, max 600 ms, 8 clients; 2.8 ms with checkpoints
    off the request path, and 133 -> 314 uploads/s). The upload writer turns automatic
    checkpoints off; this thread runs a PASSIVE checkpoint (it never blocks a writer or a
    reader) every ``interval_s`` after writes. Other connections keep SQLite's automatic
    checkpoint as a backstop.
    """

    def __init__(self, engine: Engine, interval_s: float = 0.5) -> None:
        self.engine = engine
        self.interval_s = interval_s
        self._dirty = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    def wrote(self) -> None:
        """A write committed: checkpoint soon (starts the thread on first use)."""
        self._dirty.set()
        if self._thread is None:
            with self._lock:
                if self._thread is None:
                    self._stop.clear()
                    self._thread = threading.Thread(target=self._run, name="canal-checkpoint",
                                                    daemon=True)
                    self._thread.start()

    def _run(self) -> None:
        from ..lanes import name_os_thread

        name_os_thread("canal-checkpoint")
        connection = self.engine.raw_connection()
        try:
            raw: sqlite3.Connection = connection.driver_connection  # type: ignore[assignment]
            while True:
                stopping = self._stop.wait(self.interval_s)
                if self._dirty.is_set():
                    self._dirty.clear()
                    try:
                        raw.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchall()
                    except sqlite3.Error as exc:  # busy or gone: the next round tries again
                        log.warning("WAL checkpoint failed: %s", exc)
                if stopping:
                    return
        finally:
            connection.close()

    def close(self) -> None:
        """Checkpoint what is pending and stop the thread (a later write starts it again)."""
        with self._lock:
            thread, self._thread = self._thread, None
            self._stop.set()
        if thread is not None:
            thread.join(timeout=30)


class Database:
    """The service's database: a read engine, a write engine and their sessions.

    On SQLite, writers of this process queue on a lock, handed straight to the next one,
    rather than in SQLite's busy handler, which sleeps and polls (1, 2, 5, 10 ms ... between
    tries) under ``BEGIN IMMEDIATE``; other processes on the same file still meet the busy
    timeout. PostgreSQL writers run concurrently: no lock there.
    """

    def __init__(self, url: str) -> None:
        self.url = url
        parsed = make_url(url)
        self.is_sqlite = parsed.get_backend_name() == "sqlite"
        if self.is_sqlite:
            database = parsed.database
            if database and database != ":memory:":
                Path(database).parent.mkdir(parents=True, exist_ok=True)
            self.read_engine = _sqlite_engine(url, immediate=False)
            self.write_engine = _sqlite_engine(url, immediate=True)
        else:
            self.read_engine = create_engine(url, pool_pre_ping=True,
                                             json_deserializer=json_loads)
            self.write_engine = self.read_engine
        self._read = sessionmaker(bind=self.read_engine, expire_on_commit=False)
        self._write = sessionmaker(bind=self.write_engine, expire_on_commit=False)
        # Reentrant: a write opened inside another on one thread fails as it did without
        # the lock (SQLite's busy timeout), rather than waiting for itself forever.
        self._write_lock: AbstractContextManager[object] = (
            threading.RLock() if self.is_sqlite else nullcontext())
        self._compiled: dict[UpdateBase, _CompiledStatement] = {}
        self._sqlite_writer: PoolProxiedConnection | None = None
        self._checkpointer = _Checkpointer(self.write_engine) if self.is_sqlite else None

    @contextmanager
    def read(self) -> Iterator[Session]:
        """A session for queries only; closing it ends the transaction.

        Closing, not rolling back: a rollback would expire the loaded rows the caller
        still reads after the block.
        """
        with self._read() as session:
            yield session

    @contextmanager
    def write(self) -> Iterator[Session]:
        """A session committed on success and rolled back on any error: all or nothing."""
        with self._write_lock, self._write() as session, session.begin():
            yield session

    @contextmanager
    def write_connection(self) -> Iterator[Connection]:
        """A Core connection in a write transaction, committed on success: for hot paths
        that only insert and need no ORM session."""
        with self._write_lock, self.write_engine.begin() as connection:
            yield connection

    def read_one(self, statement: Executable,
                 values: Mapping[str, Any]) -> Sequence[Any] | None:
        """The first row of a query run on a pooled connection, without an ORM session:
        for hot paths that read one row (the reproduction's model lookup)."""
        with self.read_engine.connect() as connection:
            return connection.execute(statement, values).first()

    def write_one(self, statement: UpdateBase,
                  values: Mapping[str, Any]) -> Sequence[Any] | None:
        """Run one statement in a write transaction of its own and commit it; its first
        result row (``RETURNING``), or None.

        The upload hot path. On SQLite the statement is compiled once and run on a
        connection kept for it, under the write lock: SQLAlchemy's per-execution work
        (pool checkout, events, the execution context) costs several times the insert
        itself. Errors are SQLAlchemy's (``DBAPIError`` subclasses), as on the other paths.
        """
        if not self.is_sqlite:
            with self.write_connection() as connection:
                return connection.execute(statement, values).first()
        with self._write_lock:
            compiled = self._compiled.get(statement)
            if compiled is None:
                compiled = self._compiled[statement] = _CompiledStatement(
                    statement, self.write_engine.dialect)
            if self._sqlite_writer is None:
                # From the pool: it carries the PRAGMAs of the connect hook, and
                # isolation_level None, so BEGIN and COMMIT are ours to send.
                self._sqlite_writer = self.write_engine.raw_connection()
                self._sqlite_writer.driver_connection.execute(  # type: ignore[union-attr]
                    "PRAGMA wal_autocheckpoint=0")  # the checkpointer's job, off this path
            raw: sqlite3.Connection = self._sqlite_writer.driver_connection  # type: ignore[assignment]
            try:
                raw.execute("BEGIN IMMEDIATE")
                try:
                    rows = raw.execute(compiled.sql, compiled.parameters(values)).fetchall()
                    raw.execute("COMMIT")
                finally:
                    if raw.in_transaction:  # the statement or the commit failed
                        raw.execute("ROLLBACK")
            except sqlite3.Error as exc:
                self._close_sqlite_writer()  # a fresh connection for the next write
                raise DBAPIError.instance(compiled.sql, None, exc, sqlite3.Error) from exc
        assert self._checkpointer is not None
        self._checkpointer.wrote()
        return rows[0] if rows else None

    def _close_sqlite_writer(self) -> None:
        writer, self._sqlite_writer = self._sqlite_writer, None
        if writer is not None:
            try:
                writer.invalidate()
            except Exception:  # closing a broken connection: nothing more to do
                pass

    def migrate(self) -> None:
        """Apply Alembic migrations up to head (idempotent; safe with replicas starting together).
        A PostgreSQL database must be in UTF8 (RuntimeError otherwise)."""
        if make_url(self.url).get_backend_name() == "postgresql":
            check_utf8(self.url)
        config = alembic_config(self.url)
        with self.write_engine.begin() as connection:
            if connection.dialect.name == "postgresql":
                connection.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": _MIGRATION_LOCK_KEY})
            config.attributes["connection"] = connection
            command.upgrade(config, "head")

    def ping(self) -> None:
        """Raise if the database cannot answer a trivial query."""
        with self.read_engine.connect() as connection:
            connection.execute(text("SELECT 1"))

    def dispose(self) -> None:
        """Close pooled connections."""
        if self._checkpointer is not None:
            self._checkpointer.close()
        with self._write_lock:
            if self._sqlite_writer is not None:
                self._sqlite_writer.close()
                self._sqlite_writer = None
        self.read_engine.dispose()
        if self.write_engine is not self.read_engine:
            self.write_engine.dispose()


def check_utf8(url: str) -> None:
    """RuntimeError unless the PostgreSQL database at ``url`` stores text in UTF8.

    Any other encoding fails later, on the first text it cannot hold (an emoji in a label is
    a 500 in LATIN1), or at once and obscurely (SQL_ASCII hands SQLAlchemy bytes where it
    reads the server's version). Asked on a plain driver connection, before SQLAlchemy's.
    """
    import psycopg

    conninfo = make_url(url).set(drivername="postgresql").render_as_string(hide_password=False)
    with psycopg.connect(conninfo) as connection:
        row = connection.execute("SHOW server_encoding").fetchone()
    got = row[0] if row is not None else None
    got = got.decode("ascii", "replace") if isinstance(got, bytes) else str(got)
    if got.upper() not in ("UTF8", "UTF-8"):
        raise RuntimeError(f"expected a database in UTF8 encoding, got {got}: create it with "
                           "CREATE DATABASE ... ENCODING 'UTF8' TEMPLATE template0")


def alembic_config(url: str) -> Config:
    """An Alembic config pointing at the packaged migrations, for code and for the CLI."""
    config = Config(str(MIGRATIONS_DIR / "alembic.ini"))
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    # ConfigParser interpolation would choke on '%' in URL-encoded passwords.
    config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return config
