"""``canal serve`` writes its log lines (uvicorn's access log above all) off the event loop.

The loggers queue records; a writer thread formats and writes them with the handlers
uvicorn configured. What must hold: every line is written, in order, formatted as uvicorn
formats it (its access formatter reads the record's args), and not on the logging thread.
"""

from __future__ import annotations

import io
import logging
import threading
from collections.abc import Iterator

import pytest
from canal_service.core.serve import write_logs_off_the_loop
from uvicorn.logging import AccessFormatter


class ThreadNotingHandler(logging.StreamHandler[io.StringIO]):
    """A stream handler that also notes which thread wrote each record."""

    def __init__(self, stream: io.StringIO) -> None:
        super().__init__(stream)
        self.threads: set[str] = set()

    def emit(self, record: logging.LogRecord) -> None:
        self.threads.add(threading.current_thread().name)
        super().emit(record)


@pytest.fixture
def access_logger() -> Iterator[tuple[logging.Logger, ThreadNotingHandler]]:
    logger = logging.getLogger("canal-test.access")
    logger.propagate = False
    logger.setLevel(logging.INFO)
    handler = ThreadNotingHandler(io.StringIO())
    handler.setFormatter(AccessFormatter('%(levelprefix)s %(client_addr)s - "%(request_line)s" '
                                         "%(status_code)s", use_colors=False))
    logger.addHandler(handler)
    yield logger, handler
    for h in list(logger.handlers):
        logger.removeHandler(h)


def test_access_lines_are_written_in_order_by_a_writer_thread(
        access_logger: tuple[logging.Logger, ThreadNotingHandler]) -> None:
    logger, handler = access_logger
    listeners = write_logs_off_the_loop(["canal-test.access"])
    assert len(listeners) == 1 and handler not in logger.handlers
    try:
        for i in range(200):
            logger.info('%s - "%s %s HTTP/%s" %d', "127.0.0.1:5000", "POST",
                        f"/skills/s/demonstrations?i={i}", "1.1", 201)
    finally:
        for listener in listeners:
            listener.stop()  # writes what is queued
    lines = handler.stream.getvalue().splitlines()
    assert lines == [f'INFO:     127.0.0.1:5000 - "POST /skills/s/demonstrations?i={i} HTTP/1.1" '
                     "201 Created" for i in range(200)]
    assert threading.current_thread().name not in handler.threads


def test_a_logger_without_handlers_is_left_alone() -> None:
    logger = logging.getLogger("canal-test.silent")
    assert write_logs_off_the_loop(["canal-test.silent"]) == []
    assert logger.handlers == []
