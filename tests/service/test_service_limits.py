"""Upload resource limits hold while parsing.

Every bomb goes to a real ``python -m canal_service`` process, and the server's peak resident
memory (VmHWM) is read before and after: a refused bomb must leave it flat, not just answer
413 eventually. The bombs are built here, with the mcap writer and zstandard.
"""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
import zstandard
from canal_testing import free_port
from mcap.writer import CompressionType, Writer
from service_helpers import demo_positions

ROOT = Path(__file__).resolve().parents[2]
MIB = 1024 * 1024
POSE_SCHEMA = json.dumps({"type": "object"}).encode()


class Server:
    """``python -m canal_service`` on loopback, with its peak RSS readable from /proc."""

    def __init__(self, data_dir: Path, *env: tuple[str, str]) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        environ = {**os.environ, "RERUN_TELEMETRY_ENABLED": "false", **dict(env)}
        self.process = subprocess.Popen(
            [sys.executable, "-m", "canal_service", "--port", str(self.port), "--data-dir",
             str(data_dir), "--no-recordings", "--no-zenoh", "--log-level", "warning"],
            env=environ)
        deadline = time.monotonic() + 30
        while True:
            try:
                httpx.get(f"{self.url}/healthz", timeout=1)
                return
            except httpx.TransportError:
                if self.process.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("service did not start") from None
                time.sleep(0.1)

    def peak_rss(self) -> int:
        """The process's high-water resident set, in bytes."""
        for line in Path(f"/proc/{self.process.pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
        raise RuntimeError("no VmHWM")

    def close(self) -> None:
        self.process.terminate()
        self.process.wait(10)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    if not Path("/proc/self/status").exists():
        pytest.skip("needs /proc to read the server's memory")
    srv = Server(tmp_path_factory.mktemp("limits"), ("CANAL_UPLOAD_MAX_POINTS", "20000"))
    with httpx.Client(base_url=srv.url, timeout=120) as http:
        assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
        # Warm every parser once, so imports and caches are in the baseline, not the bomb.
        for fmt, data in (("csv", _csv(demo_positions(0))), ("mcap", _pose_mcap(20)),
                          ("npy", _npy(demo_positions(1)))):
            r = _upload(http, fmt, data)
            assert r.status_code == 201, r.text
    yield srv
    srv.close()


def _upload(http: httpx.Client, fmt: str, data: bytes, **params: str) -> httpx.Response:
    return http.post("/skills/pour/demonstrations", params={"format": fmt, **params},
                     content=data, headers={"content-type": "application/octet-stream"})


def _refused_flat(server: Server, fmt: str, data: bytes, status: int, words: str,
                  budget: int) -> dict[str, object]:
    """Send ``data``; it must be refused with ``status`` and grow the peak RSS < ``budget``."""
    before = server.peak_rss()
    with httpx.Client(base_url=server.url, timeout=120) as http:
        n_before = http.get("/skills/pour").json()["n_demonstrations"]
        r = _upload(http, fmt, data)
        n_after = http.get("/skills/pour").json()["n_demonstrations"]
    grown = server.peak_rss() - before
    assert r.status_code == status, r.text
    error = r.json()["error"]
    assert words in error["message"], error
    assert error["field"]
    assert n_after == n_before, "a refused upload was stored"
    assert grown < budget, f"peak RSS grew by {grown / MIB:.0f} MiB on a {len(data)}-byte upload"
    return error


# ---- the bombs -------------------------------------------------------------------------------


def _csv(points: np.ndarray) -> bytes:
    buf = io.StringIO()
    buf.write("x,y,z\n")
    np.savetxt(buf, points, delimiter=",", fmt="%.6f")
    return buf.getvalue().encode()


def _npy(points: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, points)
    return buf.getvalue()


def _pose_mcap(n: int, other_topic_messages: int = 0, other_channels: int = 1,
               interleave: int = 0) -> bytes:
    """foxglove.PoseInFrame poses on /pose, and optionally a flood of empty messages (on
    ``other_channels`` channels in turn; ``interleave`` of them after each pose)."""
    buf = io.BytesIO()
    writer = Writer(buf, compression=CompressionType.ZSTD, chunk_size=4 * MIB)
    writer.start()
    schema = writer.register_schema("foxglove.PoseInFrame", "jsonschema", POSE_SCHEMA)
    pose = writer.register_channel("/pose", "json", schema)
    others = [writer.register_channel(f"/joint_noise{k}", "json", 0)
              for k in range(other_channels)]
    points = demo_positions(0, n=n)
    for i, p in enumerate(points):
        payload = {"timestamp": {"sec": i + 1, "nsec": 0}, "frame_id": "base",
                   "pose": {"position": dict(zip("xyz", p.tolist(), strict=True)),
                            "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}}}
        writer.add_message(pose, (i + 1) * 1000, json.dumps(payload).encode(), (i + 1) * 1000)
        for k in range(interleave):
            writer.add_message(others[k % other_channels], (i + 1) * 1000 + k + 1, b"",
                               (i + 1) * 1000)
    for i in range(other_topic_messages):
        writer.add_message(others[i % other_channels], i, b"", i)
    writer.finish()
    return buf.getvalue()


def _zstd_bomb(declared: int, holds: int) -> bytes:
    """An MCAP whose one chunk declares ``declared`` bytes and decompresses to ``holds``.

    The chunk holds a metadata record as long as the whole chunk: valid MCAP framing, so only
    the bytes produced can refuse it.
    """
    head = struct.pack("<BQ", 0x0C, holds - 9)
    compressor = zstandard.ZstdCompressor(level=3).compressobj(size=holds)
    parts = [compressor.compress(head)]
    zeros = bytes(4 * MIB)
    left = holds - len(head)
    while left > 0:
        parts.append(compressor.compress(zeros[:min(left, len(zeros))]))
        left -= min(left, len(zeros))
    parts.append(compressor.flush())
    compressed = b"".join(parts)
    chunk = (struct.pack("<QQQI", 0, 0, declared, 0) + struct.pack("<I", 4) + b"zstd"
             + struct.pack("<Q", len(compressed)) + compressed)
    valid = _pose_mcap(10)  # schema, channel and poses, then our chunk before the rest
    magic = b"\x89MCAP0\r\n"
    header = struct.pack("<BQ", 0x01, 8) + struct.pack("<I", 0) + struct.pack("<I", 0)
    assert valid.startswith(magic)
    return magic + header + struct.pack("<BQ", 0x06, len(chunk)) + chunk + valid[len(magic):]


def test_other_topic_flood_streams_with_flat_memory(server: Server) -> None:
    # First in the module: VmHWM only grows, so a bomb let through would hide this one.
    """2 M empty messages on another topic (they once took 24 s) are scanned in a
    stream and dropped (the pose topic is still read)."""
    data = _pose_mcap(50, other_topic_messages=300_000)
    before = server.peak_rss()
    with httpx.Client(base_url=server.url, timeout=120) as http:
        r = _upload(http, "mcap", data, topic="/pose")
    assert r.status_code == 201, r.text
    assert r.json()["n_points"] == 50
    grown = server.peak_rss() - before
    # the file itself is ~10 MB decompressed; holding its records as objects took ~10x that
    assert grown < 2 * len(data) + 24 * MIB, f"peak RSS grew by {grown / MIB:.0f} MiB"


def test_zstd_bomb_is_counted_as_produced_not_as_declared(server: Server) -> None:
    """61 KB declaring 100 bytes and holding 1.46 GB (it once took the server to 3.2 GB)."""
    bomb = _zstd_bomb(declared=100, holds=512 * MIB)
    assert len(bomb) < 200_000
    _refused_flat(server, "mcap", bomb, 413, "decompresses to more than", budget=48 * MIB)


def test_pose_topic_over_the_points_limit(server: Server) -> None:
    _refused_flat(server, "mcap", _pose_mcap(20_001), 413, "more than 20000 samples",
                  budget=48 * MIB)


def test_big_csv_is_refused_at_the_points_limit_without_amplifying(server: Server) -> None:
    """12 MB of CSV (it once cost 17.8 s of server CPU)."""
    rows = np.tile(demo_positions(0, n=1000), (1000, 1))  # 1 M rows, ~25 MB
    data = _csv(rows)
    _refused_flat(server, "csv", data, 413, "more than 20000 samples",
                  budget=2 * len(data) + 16 * MIB)


def test_npy_over_the_points_limit(server: Server) -> None:
    _refused_flat(server, "npy", _npy(np.zeros((20_001, 3))), 413, "more than 20000 samples",
                  budget=16 * MIB)


def test_json_over_the_points_limit(server: Server) -> None:
    body = json.dumps({"positions": np.zeros((20_001, 3)).tolist()}).encode()
    before = server.peak_rss()
    with httpx.Client(base_url=server.url, timeout=60) as http:
        r = http.post("/skills/pour/demonstrations", content=body,
                      headers={"content-type": "application/json"})
    assert r.status_code == 413, r.text
    assert r.json()["error"]["field"] == "positions"
    assert server.peak_rss() - before < 2 * len(body) + 16 * MIB


def test_server_time_per_upload_is_capped(tmp_path: Path) -> None:
    srv = Server(tmp_path, ("CANAL_UPLOAD_MAX_SECONDS", "0.05"))
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as http:
            assert http.post("/skills", json={"name": "pour", "dim": 3}).status_code == 201
            # two channels in turn: no run of identical records to jump over
            r = _upload(http, "mcap", _pose_mcap(50, other_topic_messages=300_000,
                                                 other_channels=2), topic="/pose")
            assert r.status_code == 413, r.text
            assert "s of server time" in r.json()["error"]["message"]
            assert http.get("/skills/pour").json()["n_demonstrations"] == 0
    finally:
        srv.close()


def test_lz4_and_uncompressed_chunks_still_read(tmp_path: Path) -> None:
    from canal_service.uploads import parse_mcap

    for compression in (CompressionType.LZ4, CompressionType.NONE):
        buf = io.BytesIO()
        writer = Writer(buf, compression=compression)
        writer.start()
        schema = writer.register_schema("foxglove.PoseInFrame", "jsonschema", POSE_SCHEMA)
        channel = writer.register_channel("/pose", "json", schema)
        for i, p in enumerate(demo_positions(0, n=30)):
            payload = {"pose": {"position": dict(zip("xyz", p.tolist(), strict=True))}}
            writer.add_message(channel, i + 1, json.dumps(payload).encode(), i + 1)
        writer.finish()
        parsed = parse_mcap(buf.getvalue(), 3, None)
        np.testing.assert_allclose(parsed.positions, demo_positions(0, n=30))


def test_tampered_chunk_crc_is_a_bad_upload() -> None:
    from canal_service.errors import BadUpload
    from canal_service.uploads import parse_mcap

    data = bytearray(_pose_mcap(30))
    crc_at = _first_chunk(bytes(data)) + 9 + 24  # opcode+length, then three u64 before it
    assert struct.unpack_from("<I", data, crc_at)[0] != 0  # the writer stored a CRC
    struct.pack_into("<I", data, crc_at, struct.unpack_from("<I", data, crc_at)[0] ^ 1)
    with pytest.raises(BadUpload, match="CRC"):
        parse_mcap(bytes(data), 3, None)


def _first_chunk(data: bytes) -> int:
    pos = 8
    while pos < len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x06:
            return pos
        pos += 9 + length
    raise AssertionError("no chunk")


def test_poses_inside_floods_are_all_read() -> None:
    """Runs of skipped messages are jumped over in numpy: the poses between them survive."""
    from canal_service.uploads import parse_mcap

    for channels in (1, 2):
        data = _pose_mcap(200, interleave=300, other_channels=channels)
        parsed = parse_mcap(data, 3, "/pose")
        np.testing.assert_allclose(parsed.positions, demo_positions(0, n=200))
        assert parsed.timestamps is not None
        np.testing.assert_allclose(parsed.timestamps, np.arange(200.0))
