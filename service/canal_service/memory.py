"""Memory back to the operating system after bursts.

glibc keeps what a process freed in its heaps for reuse: after a burst of large requests
(uploads of long demonstrations, batches of reproductions) the service stayed near its peak
RSS while idle. When no request has run for ``idle_s`` seconds, :class:`MemoryReleaser`
collects garbage cycles and calls glibc's ``malloc_trim(0)``, which returns the free pages of
every heap. Fits do not need it: they run in worker processes that exit
(:mod:`canal_service.fitting`). On a libc without ``malloc_trim`` (musl, macOS) only the
garbage collection runs.
"""

from __future__ import annotations

import ctypes
import gc
import logging
import os
import threading
import time
from collections.abc import Callable

from starlette.types import ASGIApp, Receive, Scope, Send

log = logging.getLogger("canal_service")


def _malloc_trim() -> Callable[[int], int] | None:
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return None
    trim = getattr(libc, "malloc_trim", None)
    if trim is None:
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim  # type: ignore[no-any-return]


_TRIM = _malloc_trim()
#: RSS grown by this much since the last trim, while idle, calls for another.
REGROWTH_BYTES = 32 * 2**20
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def resident_bytes() -> int:
    """This process's resident set size (0 where /proc is not there)."""
    try:
        with open("/proc/self/statm", "rb") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, IndexError, ValueError):
        return 0


def release_memory(collect: bool = True) -> bool:
    """Collect garbage cycles (unless ``collect`` is False) and hand freed heap pages back to
    the OS; whether glibc's ``malloc_trim`` ran (False where the libc has none)."""
    if collect:
        gc.collect()
    if _TRIM is None:
        return False
    _TRIM(0)
    return True


class MemoryReleaser:
    """Releases memory once the service has been idle ``idle_s`` seconds after requests.

    Requests are counted by :class:`ReleaseMemoryWhenIdle`; a thread of its own looks every
    ``idle_s / 2`` seconds (never while a request runs: a trim takes milliseconds).
    """

    def __init__(self, idle_s: float) -> None:
        self.idle_s = idle_s
        self.trims = 0
        self._lock = threading.Lock()
        self._in_flight = 0
        self._dirty = False
        self._last_end = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._trimmed_at = 0

    def begin(self) -> None:
        """A request started."""
        with self._lock:
            self._in_flight += 1
            self._dirty = True

    def end(self) -> None:
        """A request ended."""
        with self._lock:
            self._in_flight -= 1
            self._last_end = time.monotonic()

    def start(self) -> None:
        """Start the watching thread (a no-op when ``idle_s`` is 0)."""
        if self.idle_s <= 0 or self._thread is not None:
            return
        self._thread = threading.Thread(target=self._run, name="canal-memory", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the watching thread."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)

    def _due(self) -> bool:
        with self._lock:
            if self._in_flight or time.monotonic() - self._last_end < self.idle_s:
                return False
            # Work that ends after the requests (the recorder writing what they queued)
            # frees memory later: grown RSS since the last trim is worth another one.
            if not self._dirty and resident_bytes() < self._trimmed_at + REGROWTH_BYTES:
                return False
            self._dirty = False
            return True

    def _run(self) -> None:
        while not self._stop.wait(self.idle_s / 2):
            if self._due():
                try:
                    release_memory()
                    self.trims += 1
                    self._trimmed_at = resident_bytes()
                except Exception:  # never take the service down for an optimisation
                    log.exception("releasing memory failed")


class ReleaseMemoryWhenIdle:
    """Pure ASGI middleware telling a :class:`MemoryReleaser` when requests start and end."""

    def __init__(self, app: ASGIApp, releaser: MemoryReleaser) -> None:
        self.app = app
        self.releaser = releaser

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        self.releaser.begin()
        try:
            await self.app(scope, receive, send)
        finally:
            self.releaser.end()
