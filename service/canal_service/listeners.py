"""Who hears of committed changes: the live bridge subscribes to fits and scene changes.

The service notifies after the change committed; a listener that raises is logged and does not
stop the others, nor fail the request whose data is already stored.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Generic, ParamSpec

import canal_core
from canal_core.routes import Routes

log = logging.getLogger("canal_service")

P = ParamSpec("P")


class Listeners(Generic[P]):
    """Callables told of one kind of change, in the order they subscribed. Thread-safe:
    the bridge subscribes and unsubscribes while requests notify."""

    def __init__(self, listeners: Sequence[Callable[P, None]] = (), *, what: str = "listener"
                 ) -> None:
        self._listeners: list[Callable[P, None]] = list(listeners)
        self._lock = threading.Lock()
        self._what = what

    def append(self, listener: Callable[P, None]) -> None:
        """Subscribe ``listener``."""
        with self._lock:
            self._listeners.append(listener)

    def remove(self, listener: Callable[P, None]) -> None:
        """Unsubscribe ``listener`` (ValueError when it was not subscribed, as list.remove)."""
        with self._lock:
            self._listeners.remove(listener)

    def __contains__(self, listener: object) -> bool:
        with self._lock:
            return listener in self._listeners

    def __iter__(self) -> Iterator[Callable[P, None]]:
        with self._lock:
            return iter(list(self._listeners))

    def __len__(self) -> int:
        with self._lock:
            return len(self._listeners)

    def notify(self, *args: P.args, **kwargs: P.kwargs) -> None:
        """Call every listener; one that raises is logged and does not stop the others."""
        for listener in self:
            try:
                listener(*args, **kwargs)
            except Exception:
                log.exception("%s failed", self._what)


#: ``listener(skill, version, model)``: the model is the canal, or :class:`Routes` when it
#: has several routes.
FitListener = Callable[[str, int, "canal_core.Canal | Routes | None"], None]
#: ``listener(skill, version, scene)``
SceneListener = Callable[[str, int, "canal_core.obstacles.Scene"], None]


class FitListeners(Listeners[[str, int, "canal_core.Canal | Routes | None"]]):
    """Who hears of each committed fit, as ``listener(skill, version, model)`` (the bridge),
    and of each deleted skill, as ``listener(skill, 0, None)`` (the model is read again: a
    skill that is gone is answered as unknown).

    Built by ``create_app`` and handed to both the service (which notifies) and the bridge
    (which subscribes when it starts and unsubscribes when it stops).
    """

    def __init__(self, listeners: Sequence[FitListener] = ()) -> None:
        super().__init__(listeners, what="fit listener")


class SceneListeners(Listeners[[str, int, "canal_core.obstacles.Scene"]]):
    """Who hears of each committed scene change, as ``listener(skill, version, scene)``."""

    def __init__(self, listeners: Sequence[SceneListener] = ()) -> None:
        super().__init__(listeners, what="scene listener")


__all__: Sequence[str] = ["FitListener", "FitListeners", "Listeners", "SceneListener",
                          "SceneListeners"]
