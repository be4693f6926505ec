"""The bridge's model table under its two writers: the worker installs negative entries while
the housekeeper expires them (a crash there stopped every later model refresh)."""

from __future__ import annotations

import sys
import threading

from canal_service.bridge.config import BridgeOptions
from canal_service.bridge.models import ModelEntry, ModelTable


def test_refresh_survives_negative_entries_installed_meanwhile():
    # every entry expires at once (ttl 0), so the housekeeper has work on every pass
    table = ModelTable(None, BridgeOptions(negative_ttl_s=0.0, negative_max=512))
    stop = threading.Event()
    errors: list[BaseException] = []

    def housekeeper():
        while not stop.is_set():
            try:
                table.refresh(set())
            except BaseException as exc:  # what killed the housekeeper thread
                errors.append(exc)
                return

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # hand the GIL over often: the threads interleave finely
    t = threading.Thread(target=housekeeper)
    t.start()
    try:
        for i in range(200_000):
            table.install(f"junk{i}", ModelEntry("unknown_skill", message="no such skill"))
            if errors:
                break
    finally:
        stop.set()
        t.join(10)
        sys.setswitchinterval(interval)
    assert errors == []
    assert len(table.unknown) <= 512
