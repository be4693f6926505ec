"""Lanes: a few named worker threads for one kind of request work.

Why not AnyIO's shared pool (40 threads) for uploads: an upload is a few milliseconds of
Python and small-array numpy, nearly all of it under the GIL. Eight uploads in flight on
eight pool threads do not run in parallel; they take turns on the GIL, and every hand-over
costs a futex wake-up, a cache refill and, under CPython's 5 ms switch interval, a request
that waits for the others to finish their slices (measured on 2 cores: ~1.6 ms of system
time per upload spread over the pool threads, 122-150 uploads/s; the same work on one
thread: ~216/s). A lane of one or two threads runs uploads back to back instead, and keeps
them off the shared pool, so a 10 s fit or a burst of reads neither waits behind uploads
nor makes them wait.

Each lane thread carries its name to the OS (``/proc/PID/task/TID/comm``, ``top -H``,
py-spy), so the CPU a lane costs can be read from outside the process.
"""

from __future__ import annotations

import asyncio
import ctypes
import ctypes.util
import functools
import itertools
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, ParamSpec, TypeVar

P = ParamSpec("P")
T = TypeVar("T")

_PR_SET_NAME = 15


@functools.cache
def _prctl() -> Any:
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


def name_os_thread(name: str) -> None:
    """Give the calling thread ``name`` at the OS level too (Linux; at most 15 bytes kept).

    Python 3.11 names threads for Python only; the kernel's name is what ``/proc``, ``top``
    and profilers show. Best effort: elsewhere, or if the call fails, nothing happens.
    """
    prctl = _prctl()
    if prctl is not None:
        prctl(_PR_SET_NAME, name.encode()[:15], 0, 0, 0)


class Lane:
    """A small executor with a name: ``await lane.run(fn, *args)`` runs ``fn`` on one of its
    ``workers`` threads (named ``canal-<name>-<i>``) and counts their CPU time.

    Parameters
    ----------
    name : str
        Short name, e.g. ``"upload"``; threads are ``canal-upload-0``, ``canal-upload-1``...
    workers : int
        Threads; work beyond them waits in the lane's queue (first come, first served).
    """

    def __init__(self, name: str, workers: int) -> None:
        if workers < 1:
            raise ValueError(f"expected at least 1 worker for lane {name!r}, got {workers}")
        self.name = name
        self.workers = workers
        self.thread_prefix = f"canal-{name}"
        self._numbers = itertools.count()
        self._executor: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()
        self.completed = 0
        self.cpu_s = 0.0

    def _start_thread(self) -> None:
        name = f"{self.thread_prefix}-{next(self._numbers)}"
        threading.current_thread().name = name
        name_os_thread(name)

    def _timed(self, call: Callable[[], T]) -> T:
        started = time.thread_time()
        try:
            return call()
        finally:
            spent = time.thread_time() - started
            with self._lock:
                self.completed += 1
                self.cpu_s += spent

    async def run(self, fn: Callable[P, T], *args: P.args, **kwargs: P.kwargs) -> T:
        """``fn(*args, **kwargs)`` on this lane; its exception is raised here.

        A caller that gives up (client gone) does not stop work already started: an upload
        that got as far as its insert still commits, as on any worker thread.
        """
        loop = asyncio.get_running_loop()
        call = functools.partial(fn, *args, **kwargs)
        return await loop.run_in_executor(self._threads(), self._timed, call)

    def _threads(self) -> ThreadPoolExecutor:
        # Started on first use, and again after close(): an app's lifespan may run more
        # than once (a test client entered twice), as its database reconnects after dispose.
        with self._lock:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=self.workers,
                                                    thread_name_prefix=self.thread_prefix,
                                                    initializer=self._start_thread)
            return self._executor

    def stats(self) -> dict[str, Any]:
        """Workers, calls completed and the CPU seconds they took (thread time)."""
        with self._lock:
            return {"workers": self.workers, "completed": self.completed,
                    "cpu_s": round(self.cpu_s, 6)}

    def close(self) -> None:
        """Finish what is running and queued, then stop the threads (a later :meth:`run`
        starts new ones)."""
        with self._lock:
            executor, self._executor = self._executor, None
        if executor is not None:
            executor.shutdown(wait=True)
