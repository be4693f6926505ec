"""Connect ROS 2 robots that run **rmw_zenoh** to Canal's live keys (no rclpy needed).

With rmw_zenoh, a ROS 2 topic is a Zenoh key expression of the form
``<domain_id>/<topic without leading slash>/<type name>/<type hash>``, e.g.
``0/canal/pour/arm1/pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_...``, and the
payload is the CDR message (with its encapsulation header). Canal listens on
``canal/pour/arm1/pose`` and answers a CDR ``PoseStamped`` on ``canal/pour/arm1/target``.
This adapter maps one onto the other, both ways, for every robot at once:

    ROS 2 topic /canal/<skill>/<robot>/pose    (geometry_msgs/msg/PoseStamped, published)
        -> Zenoh canal/<skill>/<robot>/pose
    Zenoh canal/<skill>/<robot>/target        (CDR PoseStamped from Canal)
        -> ROS 2 topic /canal/<skill>/<robot>/target (same type, same type hash)
    Zenoh canal/<skill>/<robot>/status        (JSON) is left on Zenoh (no ROS type for it)

The type hash of the target topic is taken from the pose topic (same message type), so a
target is only forwarded once that robot's first pose came through. Each forwarded target
carries an rmw_zenoh-style attachment (sequence number, source timestamp, a GID for this
adapter) when ``zenoh.ext.z_serialize`` is available; rmw_zenoh versions differ in what
they expect there, so check yours (``ros2 topic echo`` on the target topic) before relying
on it. With **zenoh-bridge-ros2dds** instead of rmw_zenoh, no adapter is needed: the bridge
maps ``/canal/<skill>/<robot>/pose`` to the key ``canal/<skill>/<robot>/pose`` itself (see
docs/live.md).

    python examples/ros2/rmw_zenoh_adapter.py --connect tcp/127.0.0.1:7447 [--domain 0]

The adapter is one Zenoh session; point it at the router your rmw_zenoh robots use and at
Canal (``--connect`` may be repeated).
"""

from __future__ import annotations

import argparse
import os
import signal
import threading
import time
from typing import Any

import zenoh

POSE_TYPE = "geometry_msgs::msg::dds_::PoseStamped_"


class Adapter:
    """Forward rmw_zenoh pose topics to Canal and Canal's targets back (see the module)."""

    def __init__(self, session: Any, domain: int = 0, prefix: str = "canal") -> None:
        self.session = session
        self.domain = str(domain)
        self.prefix = prefix
        self._ros_target: dict[str, str] = {}  # canal target key -> rmw_zenoh key
        self._seq = 0
        self._gid = os.urandom(16)
        self._lock = threading.Lock()
        self.forwarded_poses = 0
        self.forwarded_targets = 0
        self._subs = [
            session.declare_subscriber(f"{self.domain}/{prefix}/*/*/pose/{POSE_TYPE}/*",
                                       self._on_ros_pose),
            session.declare_subscriber(f"{prefix}/*/*/target", self._on_canal_target),
        ]

    def _on_ros_pose(self, sample: Any) -> None:
        key = str(sample.key_expr)
        # 0/canal/<skill>/<robot>/pose/<type>/<hash>
        parts = key.split("/")
        if len(parts) != 7 or parts[0] != self.domain or parts[1] != self.prefix:
            return
        _, _, skill, robot, _, type_name, type_hash = parts
        base = f"{self.prefix}/{skill}/{robot}"
        with self._lock:
            self._ros_target[base + "/target"] = (
                f"{self.domain}/{base}/target/{type_name}/{type_hash}")
        self.session.put(base + "/pose", sample.payload.to_bytes(),
                         encoding=zenoh.Encoding.APPLICATION_CDR)
        self.forwarded_poses += 1

    def _attachment(self) -> bytes | None:
        try:
            from zenoh.ext import z_serialize
        except ImportError:
            return None
        with self._lock:
            self._seq += 1
            seq = self._seq
        try:
            return bytes(z_serialize((seq, time.time_ns(), self._gid)).to_bytes())
        except Exception:
            return None

    def _on_canal_target(self, sample: Any) -> None:
        data = sample.payload.to_bytes()
        if data[:1] != b"\x00":  # only CDR answers (a JSON or binary robot is not ROS)
            return
        with self._lock:
            ros_key = self._ros_target.get(str(sample.key_expr))
        if ros_key is None:
            return
        attachment = self._attachment()
        if attachment is None:
            self.session.put(ros_key, data)
        else:
            self.session.put(ros_key, data, attachment=attachment)
        self.forwarded_targets += 1

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", action="append", default=[],
                        help="Zenoh endpoint to connect to (repeatable)")
    parser.add_argument("--config", help="a Zenoh JSON5 config file instead (TLS, auth)")
    parser.add_argument("--domain", type=int, default=0, help="ROS_DOMAIN_ID (default 0)")
    parser.add_argument("--prefix", default="canal", help="Canal's key prefix")
    args = parser.parse_args(argv)
    if args.config:
        config = zenoh.Config.from_file(args.config)
    else:
        import json

        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("connect/endpoints",
                            json.dumps(args.connect or ["tcp/127.0.0.1:7447"]))
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with zenoh.open(config) as session:
        adapter = Adapter(session, args.domain, args.prefix)
        print("rmw_zenoh adapter running; Ctrl-C to stop", flush=True)
        while not stop.wait(5.0):
            print(f"poses forwarded {adapter.forwarded_poses}, targets forwarded "
                  f"{adapter.forwarded_targets}", flush=True)
        adapter.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
