"""``canal serve`` runs the live bridge in processes of its own (``zenoh_processes``, default 1).

Why: the pose path is Python, and one interpreter runs one thread at a time. In the service
process it shares the GIL with uvicorn, the recorder and request handlers; a 20 ms fit or a
recording flush stalls every robot. A bridge process does poses only.

How: :class:`BridgeProcesses` starts ``python -m canal_service.bridge --supervised --shard
I/K`` for I in 0..K-1 against the service's database. It talks to them through pipes, not
through Zenoh (so it works with any Zenoh config, TLS or ACL included):

- stdin (service -> bridge): one JSON line per landed fit, ``{"fit": skill, "version": v}``;
  each bridge reloads that skill at once (shard 0 also announces it on
  ``{prefix}/{skill}/model/updated`` for bridges started elsewhere).
- stdout (bridge -> service): ``canal bridge ready ...``, then every 0.5 s one JSON line with
  the bridge's health and cumulative counts; the service adds the deltas to its own
  Prometheus metrics (``/metrics``) and reports the bridges in ``/healthz``.

With K > 1 and no config file, bridge 0 listens on the service's endpoints and bridges
1..K-1 listen on free loopback ports and connect to bridge 0; Zenoh's gossip lets a robot
that connects to bridge 0 reach the others directly. With a config file, K must be 1 (each
further bridge needs its own file: run ``python -m canal_service.bridge --shard I/K``).
"""

from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
import threading
import time
from typing import Any

import orjson

from ..core.cli import settings_options
from ..core.config import Settings
from ..service import CanalService
from .streams import add_counts

log = logging.getLogger("canal_service.bridge")

STATUS_PERIOD_S = 0.5
#: The settings a bridge process takes from its ``canal serve`` as flags (endpoints go as
#: environment variables, see ``BridgeProcesses._env``): every one ``BridgeOptions`` or the
#: bridge's service reads, so that no ``canal serve --zenoh-*`` flag is silently ignored.
PASSED_SETTINGS = ("zenoh_prefix", "log_level", "recordings_live_hz", "zenoh_queue_capacity",
                   "zenoh_coalesce_backlog", "zenoh_idle_s", "zenoh_max_streams", "zenoh_refresh_s",
                   "zenoh_lookahead", "zenoh_preload_max", "zenoh_preload_keep_s",
                   "model_cache_size")
_STALE_S = 3.0
_READY_TIMEOUT_S = 60.0


def _free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Child:
    def __init__(self, shard: int, proc: subprocess.Popen[bytes]) -> None:
        self.shard = shard
        self.proc = proc
        self.health: dict[str, Any] = {}
        self.counts: dict[str, Any] = {}
        #: what the process stored (live demonstrations, corrections), cumulative
        self.stored: dict[str, float] = {}
        self.seen = time.monotonic()
        self.ready = threading.Event()
        self.ready_line = ""
        self.stderr_tail: list[str] = []
        self.lock = threading.Lock()


class BridgeProcesses:
    """Start, watch, feed and stop the bridge processes of one service."""

    def __init__(self, settings: Settings, service: CanalService) -> None:
        self.settings = settings
        self.service = service
        self.children: list[_Child] = []
        self.state = "stopped"
        self.detail: str | None = None
        self._flushed: dict[int, dict[str, Any]] = {}
        self._stored: dict[int, dict[str, float]] = {}
        self._stopping = False

    def _argv(self, shard: int, shards: int) -> list[str]:
        s = self.settings
        argv = [sys.executable, "-m", "canal_service.bridge", "--supervised",
                "--shard", f"{shard}/{shards}", "--data-dir", str(s.data_dir),
                "--database-url", s.resolved_database_url]
        flags = {o.field: o.flag for o in settings_options(type(s))}
        for name in PASSED_SETTINGS:
            value = getattr(s, name)
            argv += [flags[name], repr(value) if isinstance(value, float) else str(value)]
        if not s.recordings_enabled:
            argv.append("--no-recordings")
        if s.zenoh_config is not None:
            return [*argv, "--zenoh-config", str(s.zenoh_config)]
        return argv

    def _env(self, shard: int, first_endpoint: str | None) -> dict[str, str]:
        """The child's endpoints as CANAL_* variables (JSON lists; an empty list stays empty)."""
        s = self.settings
        if shard == 0 or first_endpoint is None:
            listen, connect = list(s.zenoh_listen), list(s.zenoh_connect)
        else:
            listen = [f"tcp/127.0.0.1:{_free_loopback_port()}"]
            connect = [first_endpoint, *s.zenoh_connect]
        env = {"CANAL_ZENOH_LISTEN": orjson.dumps(listen).decode(),
               "CANAL_ZENOH_CONNECT": orjson.dumps(connect).decode(),
               "CANAL_ZENOH_OPEN": "true" if s.zenoh_open else "false"}
        # the token closes the bridges' live path too; in the environment, not on the
        # command line that every user of the machine can list
        env["CANAL_TOKEN"] = "" if s.token is None else s.token.get_secret_value()
        return env

    def start(self) -> bool:
        """Start the bridges and wait until each is ready; False (state "down") if one fails."""
        shards = int(self.settings.zenoh_processes)
        if self.settings.zenoh_config is not None and shards > 1:
            log.warning("zenoh_config given: starting 1 bridge process, not %d (each further "
                        "bridge needs its own config file)", shards)
            shards = 1
        first = self.settings.zenoh_listen[0] if self.settings.zenoh_listen else None
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
                   RERUN_TELEMETRY_ENABLED="false")
        for shard in range(shards):
            proc = subprocess.Popen(self._argv(shard, shards), stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    env={**env, **self._env(shard, first)})
            child = _Child(shard, proc)
            self.children.append(child)
            threading.Thread(target=self._read, args=(child,), daemon=True,
                             name=f"canal-bridge-{shard}-out").start()
            threading.Thread(target=self._read_err, args=(child,), daemon=True,
                             name=f"canal-bridge-{shard}-err").start()
            # one at a time: bridge 0 must listen before the others connect to it
            # ready = its first status line came (EOF also wakes the wait, before the exit
            # code may be known)
            if not child.ready.wait(_READY_TIMEOUT_S) or not child.health:
                try:
                    proc.wait(2.0)  # let it exit and its stderr arrive
                except subprocess.TimeoutExpired:
                    pass
                self.state = "down"
                self.detail = (f"bridge process {shard} did not start (exit "
                               f"{proc.poll()}): " + " | ".join(child.stderr_tail[-3:]))
                log.error("live bridge not started (the REST API still runs): %s", self.detail)
                self.close()
                self.state = "down"
                return False
        self.service.fit_listeners.append(self._on_fit)
        self.service.scene_listeners.append(self._on_scene)
        self.state, self.detail = "ok", None
        self.service.metrics.live_up.set(1)
        return True

    def _read(self, child: _Child) -> None:
        out = child.proc.stdout
        assert out is not None
        for raw in out:
            line = raw.decode("utf-8", "replace").strip()
            if not child.ready_line and "ready" in line:
                child.ready_line = line
                continue
            if not line.startswith("{"):
                continue
            try:
                body = orjson.loads(line)
            except orjson.JSONDecodeError:
                continue
            with child.lock:
                child.health = body.get("health", {})
                child.counts = body.get("counts", {})
                child.stored = body.get("stored", {})
                child.seen = time.monotonic()
            self._apply(child)
            child.ready.set()  # ready, and its first health is known
        child.ready.set()  # the process ended: unblock start()

    def _read_err(self, child: _Child) -> None:
        err = child.proc.stderr
        assert err is not None
        for raw in err:
            line = raw.decode("utf-8", "replace").rstrip()
            child.stderr_tail = [*child.stderr_tail[-19:], line]
            if not self._stopping:
                sys.stderr.write(f"[bridge {child.shard}] {line}\n")

    def _apply(self, child: _Child) -> None:
        """Add a bridge's new counts to the service's metrics."""
        m = self.service.metrics
        now = child.counts
        before = self._flushed.get(child.shard) or {"errors": {}}
        add_counts(m, now, before)
        for key, n in now.get("errors", {}).items():
            delta = n - before["errors"].get(key, 0)
            if delta > 0:
                m.live_errors.labels(key).inc(delta)
        self._flushed[child.shard] = {**now, "errors": dict(now.get("errors", {}))}
        m.add_stored_counts(child.stored, self._stored.get(child.shard, {}))
        self._stored[child.shard] = dict(child.stored)
        m.live_streams.set(sum(int(c.health.get("streams", 0)) for c in self.children))

    def _on_fit(self, skill: str, version: int, canal: Any) -> None:
        self._tell({"fit": skill, "version": int(version)})

    def _on_scene(self, skill: str, version: int, scene: Any) -> None:
        self._tell({"scene": skill, "version": int(version)})

    def _tell(self, notice: dict[str, Any]) -> None:
        """One JSON line to every bridge process (a fit or scene notice)."""
        line = orjson.dumps(notice) + b"\n"
        for child in self.children:
            try:
                assert child.proc.stdin is not None
                child.proc.stdin.write(line)
                child.proc.stdin.flush()
            except (OSError, ValueError):
                log.warning("bridge process %d did not take the notice %s", child.shard, notice)

    def health(self) -> dict[str, Any]:
        """State for /healthz: "ok", "behind" (a bridge is not keeping up or not reporting),
        "down" (a bridge process is gone)."""
        if self.state != "ok" or not self.children:
            return {"status": self.state, "detail": self.detail, "processes": 0}
        now = time.monotonic()
        status, detail = "ok", None
        per = []
        for c in self.children:
            with c.lock:
                h = dict(c.health)
                age = now - c.seen
            code = c.proc.poll()
            if code is not None:
                state = "down"
                status, detail = "down", f"bridge process {c.shard} exited with {code}"
            elif age > _STALE_S:
                state = "behind"
                if status == "ok":
                    status, detail = "behind", f"bridge process {c.shard} silent for {age:.1f} s"
            else:
                state = h.get("status", "ok")
                if state != "ok" and status == "ok":
                    status, detail = state, f"bridge process {c.shard} is {state}"
            per.append({"shard": c.shard, "pid": c.proc.pid, "status": state,
                        "streams": h.get("streams", 0), "coalesced": h.get("coalesced", 0),
                        "poses": int(c.counts.get("poses", 0)),
                        # drains handled: poses / drains is the worker's mean drain size
                        "drains": int(c.counts.get("drains", 0)),
                        # poses that waited for their skill's model on the loader thread
                        "parked": int(c.counts.get("parked", 0)),
                        "tracker": h.get("tracker", "compiling")})
        first = self.children[0].health
        routes: dict[str, dict[str, int]] = {}
        for c in self.children:
            with c.lock:
                shard_routes = dict(c.health.get("routes") or {})
            for skill, by_route in shard_routes.items():
                into = routes.setdefault(skill, {})
                for route, n in dict(by_route).items():
                    into[route] = into.get(route, 0) + int(n)
        return {"status": status, "detail": detail, "prefix": first.get("prefix"),
                "mode": first.get("mode"), "listen": first.get("listen", []),
                "multicast_scouting": first.get("multicast_scouting"),
                "config_file": first.get("config_file"),
                "streams": sum(int(p["streams"]) for p in per),
                "access": first.get("access", "open"), "tls": first.get("tls", False),
                "acl": first.get("acl", False), "acl_default": first.get("acl_default"),
                "coalesced": sum(int(p["coalesced"]) for p in per),
                "routes": routes, "processes": len(self.children), "bridges": per}

    def close(self) -> None:
        """Stop every bridge process (SIGTERM, then kill after 10 s)."""
        self._stopping = True
        if self._on_fit in self.service.fit_listeners:
            self.service.fit_listeners.remove(self._on_fit)
        try:
            self.service.scene_listeners.remove(self._on_scene)
        except ValueError:
            pass
        for c in self.children:
            if c.proc.poll() is None:
                c.proc.terminate()
        for c in self.children:
            try:
                c.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                c.proc.kill()
                c.proc.wait()
            for stream in (c.proc.stdin, c.proc.stdout, c.proc.stderr):
                try:
                    if stream is not None:
                        stream.close()
                except OSError:
                    pass
        if self.state == "ok":
            self.state = "stopped"
        self.service.metrics.live_up.set(0)
        self.service.metrics.live_streams.set(0)
