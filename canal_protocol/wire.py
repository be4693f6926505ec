"""The live wire protocol between a robot and Canal's Zenoh bridge (stdlib + orjson only).

Robots import this module without the service: it names the key expressions and encodes and
decodes the two messages, a *pose* (robot -> Canal) and a *target* (Canal -> robot). The
codecs themselves live in :mod:`canal_protocol.codecs` (one module per format, and the one
rule that tells them apart, :func:`~canal_protocol.codecs.pose_format`); this module is
their public face.

Key expressions (defined in :mod:`canal_protocol.keys`; ``prefix`` defaults to ``canal``;
``skill`` and ``robot`` are single chunks, no ``/``, ``*``, ``$``, ``?`` or ``#``)::

    {prefix}/{skill}/{robot}/pose          robot -> Canal   put, one pose per sample
    {prefix}/{skill}/{robot}/target        Canal -> robot   put, one answer per pose
    {prefix}/{skill}/model                 queryable: latest model, JSON (= REST body of
                                           GET /skills/{skill}/models/latest?serialized=true)
    {prefix}/{skill}/{robot}/demo/start    queryable: begin capturing this stream's poses
    {prefix}/{skill}/{robot}/demo/stop     queryable: store them as a new demonstration;
                                           the reply is {"id", "n_points", "checksum"}

Encoding is chosen by the Zenoh encoding of the sample: ``application/json`` (or
``text/json``) is JSON, ``application/cdr`` is ROS 2 CDR, anything else is the binary layout
below (a default-encoded payload whose first byte is ``{`` is read as JSON, one whose first
byte is 0 as CDR). Canal answers in the encoding the pose came in.

Binary layout, version 1, little-endian, no padding. Every message starts with a 12-byte
header ``<BBBBQ``:

====== ======= ===========================================================================
offset type    field
====== ======= ===========================================================================
0      uint8   version (1)
1      uint8   kind: 1 pose, 2 target
2      uint8   flags (per kind, below)
3      uint8   dim D: number of position coordinates (2 or 3; 0 in a target without one)
4      uint64  seq: the pose's sequence number / the seq of the pose a target answers
====== ======= ===========================================================================

Pose (kind 1) after the header: ``D x float64`` position, then ``4 x float64`` orientation
quaternion (x, y, z, w) if flag 0x01, then ``float64`` timestamp in seconds if flag 0x02.
Flag 0x04 (restart) tells Canal to re-locate the robot in the canal instead of continuing
from the section reached so far (send it on the first pose of a new run; a restart pose that
jumps while the stream runs waits for poses that confirm it); other flag bits
are refused. A 3-D pose without extras is 36 bytes; a pose payload over
:data:`MAX_POSE_BYTES` is refused unread.

Target (kind 2) after the header: ``<iiddH`` = int32 model version (-1 none), int32 section
index (-1 none), float64 progress in [0, 1], float64 eta (NaN when none), uint16 status
code; then ``D x float64`` target position; then, if flag 0x08, ``uint16`` length and that
many bytes of UTF-8 message. Target flags: 0x01 inside, 0x02 done, 0x04 seq is known (set on
every answer to a pose whose header was read, errors too; not set when the header could not
be read), 0x08 has message. A 3-D target is 62 bytes.
Optional extras follow, each present when its flag is set, in this order: 0x10 ``4 x
float64`` target orientation (x, y, z, w); 0x20 ``D x float64`` feed-forward velocity;
0x40 ``uint32`` poses of this stream coalesced so far; 0x80 ``uint16`` the route the stream
follows (a model of several routes only). They sit after everything an older reader looks at,
so clients written before them keep working (they ignore the tail).

ROS 2 (CDR): a sample whose Zenoh encoding is ``application/cdr`` or whose first two bytes
are a CDR encapsulation header (``00 01`` little-endian, ``00 00`` big-endian; a binary
pose starts with ``01``) is read as a ``geometry_msgs/msg/PoseStamped``. The answer on
``.../target`` is a ``PoseStamped`` with the pose's stamp and frame_id, the target position
and orientation; statuses that PoseStamped cannot carry go to ``{prefix}/{skill}/{robot}/status``
as a JSON target (errors always, ``outside_canal``/``ok`` when the status changes). A CDR
pose has no seq: the bridge numbers each stream's CDR poses itself.

JSON pose::

    {"seq": 17, "position": [x, y, z], "orientation": [qx, qy, qz, qw]?, "t": 1.25?,
     "restart": false?}

(no other key).

JSON target::

    {"v": 1, "seq": 17, "status": "ok", "target": [x, y, z], "progress": 0.41, "eta": 0.3,
     "section": 82, "inside": true, "done": false, "model_version": 3, "message": null,
     "orientation": [qx, qy, qz, qw] | null, "coalesced": 0, "velocity": [vx, vy, vz]?}

``orientation`` is the model's orientation at the target when it learned one, else the
pose's own (null when the pose had none); ``velocity`` is there only when the model gives
one; ``coalesced`` counts this stream's poses skipped under overload so far (latest wins).

``seq`` is the pose's on every answer, errors too, and null only when the pose's ``seq``
could not be read (not JSON, not an object, no integer ``seq``); ``target``, ``eta``, ``section`` and
``model_version`` are null when there is none. JSON has no NaN: a JSON pose with NaN is
not JSON (nor is a number that overflows to infinity) and is answered ``bad_payload``.

Status keys (code, key, whether the target is usable):

==== ================= ====== ================================================================
code key               target meaning
==== ================= ====== ================================================================
0    ok                yes    inside the canal (or done)
1    outside_canal     yes    the pose is outside the canal; the target is on the boundary of
                              the section ahead, the way back in
2    detour            yes    the target goes around an obstacle of the skill's scene
3    blocked           yes    an obstacle closes the section ahead: the robot is held before it
4    in_obstacle       yes    the robot is inside an obstacle: the target backs it out
16   bad_payload       no     not a pose: garbage, truncated, wrong version/kind, missing fields
17   wrong_dimension   no     D differs from the skill's dimension
18   non_finite        no     NaN or infinity in the position, orientation or time
19   unknown_skill     no     no skill of that name
20   no_model          no     the skill has no fitted model yet
21   internal_error    no     a bug; logged by the service
22   too_many_streams  no     a new robot while the bridge process serves its most streams
                              (``zenoh_max_streams``); idle streams are forgotten
23   restart_pending   no     a restart pose that jumped while the stream runs: nothing
                              moves; the restart is made once 4 poses agree
==== ================= ====== ================================================================
"""

from __future__ import annotations

from .codecs import (
    decode_pose_as,
    decode_pose_by_encoding,
    decode_target_by_encoding,
    pose_format,
)
from .codecs.binary import (
    HEADER,
    TARGET_BODY,
    decode_pose,
    decode_target,
    encode_pose,
    encode_target,
    pack_target,
)
from .codecs.cdr import RosStamp, decode_pose_cdr, encode_pose_stamped_cdr
from .codecs.json import (
    decode_pose_json,
    decode_target_json,
    encode_pose_json,
    pack_target_json,
    target_json,
)
from .codecs.messages import (
    BINARY_ENCODING,
    CDR_ENCODING,
    FORMAT_BINARY,
    FORMAT_CDR,
    FORMAT_JSON,
    JSON_ENCODING,
    KIND_POSE,
    KIND_TARGET,
    MAX_DIM,
    MAX_POSE_BYTES,
    NO_ROUTE,
    POSE_ORIENTATION,
    POSE_RESTART,
    POSE_TIME,
    SEQ_MAX,
    STATUS_CODES,
    STATUS_KEYS,
    TARGET_COALESCED,
    TARGET_DONE,
    TARGET_INSIDE,
    TARGET_MESSAGE,
    TARGET_ORIENTATION,
    TARGET_ROUTE,
    TARGET_SEQ,
    TARGET_VELOCITY,
    USABLE,
    VERSION,
    Pose,
    Target,
    WireError,
)
from .keys import Keys, check_chunk, is_plain_chunk, keys, model_key, pose_wildcard, stream_of

__all__ = [
    "BINARY_ENCODING",
    "CDR_ENCODING",
    "FORMAT_BINARY",
    "FORMAT_CDR",
    "FORMAT_JSON",
    "HEADER",
    "JSON_ENCODING",
    "KIND_POSE",
    "KIND_TARGET",
    "MAX_DIM",
    "MAX_POSE_BYTES",
    "NO_ROUTE",
    "POSE_ORIENTATION",
    "POSE_RESTART",
    "POSE_TIME",
    "SEQ_MAX",
    "STATUS_CODES",
    "STATUS_KEYS",
    "TARGET_BODY",
    "TARGET_COALESCED",
    "TARGET_DONE",
    "TARGET_INSIDE",
    "TARGET_MESSAGE",
    "TARGET_ORIENTATION",
    "TARGET_ROUTE",
    "TARGET_SEQ",
    "TARGET_VELOCITY",
    "USABLE",
    "VERSION",
    "Keys",
    "Pose",
    "RosStamp",
    "Target",
    "WireError",
    "check_chunk",
    "decode_pose",
    "decode_pose_as",
    "decode_pose_by_encoding",
    "decode_pose_cdr",
    "decode_pose_json",
    "decode_target",
    "decode_target_by_encoding",
    "decode_target_json",
    "encode_pose",
    "encode_pose_json",
    "encode_pose_stamped_cdr",
    "encode_target",
    "is_plain_chunk",
    "keys",
    "model_key",
    "pack_target",
    "pack_target_json",
    "pose_format",
    "pose_wildcard",
    "stream_of",
    "target_json",
]
