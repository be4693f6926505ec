"""Decoded models kept in memory, keyed so that a key names one stored row for ever."""

from __future__ import annotations

import threading
from collections import OrderedDict
from datetime import UTC, datetime

from canal_core.routes import Routes

CacheKey = tuple[int, str]


def model_cache_key(model_id: int, skill_created_at: datetime) -> CacheKey:
    """The key of a model row's decoded canal: its id with its skill's creation time (UTC).

    The id alone is not enough: SQLite gives a new row the id of a deleted last row, so a
    skill deleted, re-created and fitted again (here or in another process on the same
    file) can store its new version 1 under the id the old version 1 had. Model rows are
    deleted only with their skill, and a re-created skill has another creation time, so
    the pair names one row for ever. (The model row's own time would do too, but it is
    stored after the canal: reading it costs a walk through the canal's bytes.) Naive
    times are UTC (SQLite returns them so); aware ones are converted.
    """
    created_at = skill_created_at
    if created_at.tzinfo is not None:
        created_at = created_at.astimezone(UTC).replace(tzinfo=None)
    return model_id, created_at.isoformat()


class CanalCache:
    """Decoded models (as :class:`Routes`: one route for a single canal) by
    :func:`model_cache_key`. A model row never changes, and a key names one row for ever, so
    entries never go stale; they only age out (least recently used)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._items: OrderedDict[CacheKey, Routes] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: CacheKey) -> Routes | None:
        """The cached canal, marked recently used, or None."""
        with self._lock:
            canal = self._items.get(key)
            if canal is not None:
                self._items.move_to_end(key)
            return canal

    def put(self, key: CacheKey, canal: Routes) -> None:
        """Keep ``canal``, evicting the least recently used beyond ``size``."""
        if self.size <= 0:
            return
        with self._lock:
            self._items[key] = canal
            self._items.move_to_end(key)
            while len(self._items) > self.size:
                self._items.popitem(last=False)
