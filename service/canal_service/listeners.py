"""Who hears of committed changes: the live bridge subscribes to fits and scene changes.

The service notifies after the change committed; a listener that raises is logged and does not
stop the others, nor fail the request whose data is already stored.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator, Sequence

import canal_core
from canal_core.routes import Routes

log = logging.getLogger("canal_service")


#: ``listener(skill, version, model)``: the model is the canal, or :class:`Routes` when it
#: has several routes.
FitListener = Callable[[str, int, "canal_core.Canal | Routes"], None]


class FitListeners:
    """Who hears of each committed fit, as ``listener(skill, version, canal)`` (the bridge).

    Built by ``create_app`` and handed to both the service (which notifies) and the bridge
    (which subscribes when it starts and unsubscribes when it stops). Thread-safe.
    """

    def __init__(self, listeners: Sequence[FitListener] = ()) -> None:
        self._listeners: list[FitListener] = list(listeners)
        self._lock = threading.Lock()

    def append(self, listener: FitListener) -> None:
        """Subscribe ``listener``."""
        with self._lock:
            self._listeners.append(listener)

    def remove(self, listener: FitListener) -> None:
        """Unsubscribe ``listener`` (ValueError when it was not subscribed, as list.remove)."""
        with self._lock:
            self._listeners.remove(listener)

    def __contains__(self, listener: object) -> bool:
        with self._lock:
            return listener in self._listeners

    def __iter__(self) -> Iterator[FitListener]:
        with self._lock:
            return iter(list(self._listeners))

    def __len__(self) -> int:
        with self._lock:
            return len(self._listeners)

    def notify(self, skill: str, version: int, canal: canal_core.Canal | Routes) -> None:
        """Call every listener; one that raises is logged and does not stop the others."""
        for listener in self:
            try:
                listener(skill, version, canal)
            except Exception:
                log.exception("fit listener failed")


SceneListener = Callable[[str, int, "canal_core.obstacles.Scene"], None]


class SceneListeners:
    """Who hears of each committed scene change, as ``listener(skill, version, scene)``."""

    def __init__(self) -> None:
        self._listeners: list[SceneListener] = []
        self._lock = threading.Lock()

    def append(self, listener: SceneListener) -> None:
        with self._lock:
            self._listeners.append(listener)

    def remove(self, listener: SceneListener) -> None:
        with self._lock:
            self._listeners.remove(listener)

    def notify(self, skill: str, version: int, scene: canal_core.obstacles.Scene) -> None:
        """Call every listener; one that raises is logged and does not stop the others."""
        with self._lock:
            listeners = list(self._listeners)
        for listener in listeners:
            try:
                listener(skill, version, scene)
            except Exception:
                log.exception("scene listener failed")


__all__: Sequence[str] = ["FitListener", "FitListeners", "SceneListener", "SceneListeners"]
