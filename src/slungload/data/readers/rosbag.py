"""ROS 1 (``.bag``) and ROS 2 (a rosbag2 folder, ``.mcap`` or ``.db3``) flight logs, read
with ``rosbags`` (pure Python, no ROS install; imported only when a bag is read).

Four topics make a flight (the mapping keys, defaults in ``PRESETS``):

- ``vehicle_pose``: the vehicle's motion-capture pose (``geometry_msgs/PoseStamped`` from
  vrpn / optitrack / vicon clients; also ``PoseWithCovarianceStamped``, ``TransformStamped``,
  ``nav_msgs/Odometry``, ``px4_msgs/VehicleOdometry``);
- ``load_pose``: the load's position (the same types, or ``geometry_msgs/PointStamped``);
- ``velocity``: the vehicle's velocity (``TwistStamped`` / ``TwistWithCovarianceStamped`` in the
  world frame, ``nav_msgs/Odometry`` with the twist in the body frame, or
  ``px4_msgs/VehicleOdometry``); empty: finite differences of the pose (``data.importing``);
- ``command``: the offboard command, MAVROS ``mavros_msgs/AttitudeTarget`` (``body_rate`` in
  FLU, ``thrust`` normalised) or PX4's ``px4_msgs/VehicleRatesSetpoint`` (``roll``, ``pitch``,
  ``yaw`` in FRD, ``thrust_body[2]`` normalised and negative up).

Frames: ``world`` ("enu", any z-up frame, or "ned") and ``body`` ("flu" or "frd") say how the
``geometry_msgs`` / ``nav_msgs`` topics are expressed (ROS REP 103: ENU / FLU); the MAVROS and
PX4 types carry their own conventions (MAVROS converts to ENU / FLU; PX4 is NED / FRD). Stamps:
``"header"`` (the message's header stamp, the motion-capture time; a topic whose stamps are all
zero falls back to the bag's receive time, with a note) or ``"bag"`` (receive time); PX4 types
have no ROS header and always use the receive time.

The MAVROS and PX4 message types are not in ``rosbags``' built-in typestores; bags written by
ROS carry their definitions (ROS 1, MCAP, recent sqlite3), and for bags without them the
definitions in ``MSG_DEFINITIONS`` (MAVROS 2.x, PX4 v1.14) are registered.
"""

from __future__ import annotations

import tempfile
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from ... import frames
from .logs import ROLES, LogError, RawLog, Stream, choice, merge_settings

PRESETS: dict[str, dict[str, str]] = {
    "mavros": {  # ROS 1 or 2 with MAVROS, mocap through vrpn_client_ros
        "vehicle_pose": "/vrpn_client_node/quad/pose",
        "load_pose": "/vrpn_client_node/load/pose",
        "velocity": "/mavros/local_position/velocity_local",
        "command": "/mavros/setpoint_raw/attitude",
        "world": "enu",
        "body": "flu",
        "stamps": "header",
    },
    "px4": {  # ROS 2 with PX4's uXRCE-DDS bridge, mocap through vrpn_mocap
        "vehicle_pose": "/vrpn_mocap/quad/pose",
        "load_pose": "/vrpn_mocap/load/pose",
        "velocity": "",  # finite differences of the pose (PX4's odometry is in its own frame)
        "command": "/fmu/in/vehicle_rates_setpoint",
        "world": "enu",
        "body": "flu",
        "stamps": "header",
    },
}
DEFAULT_PRESET = "mavros"

ATTITUDE_TARGET = "mavros_msgs/msg/AttitudeTarget"
RATES_SETPOINT = "px4_msgs/msg/VehicleRatesSetpoint"
PX4_ODOMETRY = "px4_msgs/msg/VehicleOdometry"
MSG_DEFINITIONS: dict[str, str] = {
    ATTITUDE_TARGET: """\
std_msgs/Header header
uint8 type_mask
uint8 IGNORE_ROLL_RATE=1
uint8 IGNORE_PITCH_RATE=2
uint8 IGNORE_YAW_RATE=4
uint8 IGNORE_THRUST=64
uint8 IGNORE_ATTITUDE=128
geometry_msgs/Quaternion orientation
geometry_msgs/Vector3 body_rate
float32 thrust
""",
    RATES_SETPOINT: """\
uint64 timestamp
float32 roll
float32 pitch
float32 yaw
float32[3] thrust_body
bool reset_integral
""",
    PX4_ODOMETRY: """\
uint64 timestamp
uint64 timestamp_sample
uint8 POSE_FRAME_UNKNOWN=0
uint8 POSE_FRAME_NED=1
uint8 POSE_FRAME_FRD=2
uint8 pose_frame
float32[3] position
float32[4] q
uint8 VELOCITY_FRAME_UNKNOWN=0
uint8 VELOCITY_FRAME_NED=1
uint8 VELOCITY_FRAME_FRD=2
uint8 VELOCITY_FRAME_BODY_FRD=3
uint8 velocity_frame
float32[3] velocity
float32[3] angular_velocity
float32[3] position_variance
float32[3] orientation_variance
float32[3] velocity_variance
uint8 reset_counter
int8 quality
""",
}

POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "geometry_msgs/msg/TransformStamped",
    "nav_msgs/msg/Odometry",
    PX4_ODOMETRY,
)
LOAD_TYPES = (*POSE_TYPES, "geometry_msgs/msg/PointStamped")
VELOCITY_TYPES = (
    "geometry_msgs/msg/TwistStamped",
    "geometry_msgs/msg/TwistWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
    PX4_ODOMETRY,
)
COMMAND_TYPES = (ATTITUDE_TARGET, RATES_SETPOINT)
TOPIC_TYPES = {  # mapping key -> accepted message types
    "vehicle_pose": POSE_TYPES,
    "load_pose": LOAD_TYPES,
    "velocity": VELOCITY_TYPES,
    "command": COMMAND_TYPES,
}
KEY_ROLES = {  # mapping key -> the roles (readers.logs.ROLES) its topic gives
    "vehicle_pose": ("position", "attitude"),
    "load_pose": ("load",),
    "velocity": ("velocity",),
    "command": ("rates", "thrust"),
}
_IGNORE_RATES = 1 | 2 | 4
_IGNORE_THRUST = 64


def bag_settings(mapping: dict[str, Any] | None, what: str) -> dict[str, Any]:
    """The preset named by ``mapping["preset"]`` (default MAVROS) updated with the mapping."""
    mapping = dict(mapping or {})
    preset = str(mapping.pop("preset", DEFAULT_PRESET)).lower()
    if preset not in PRESETS:
        raise LogError(f"{what}: unknown preset {preset!r}; known: {', '.join(PRESETS)}")
    settings = merge_settings(PRESETS[preset], mapping, what)
    for key in ("world", "body", "stamps"):
        known = {"world": frames.WORLD_FRAMES, "body": frames.BODY_FRAMES}.get(
            key, ("header", "bag")
        )
        settings[key] = choice(settings, key, known, what)
    return {"preset": preset, **settings}


def read_bag(
    path: str | Path,
    mapping: dict[str, Any] | None = None,
    *,
    progress: bool = False,
    roles: Collection[str] | None = None,
) -> RawLog:
    """The streams of one bag (ROS 1 ``.bag``; ROS 2 folder, ``.mcap`` or ``.db3``); only the
    topics that give ``roles`` (None: every role) are read, so a motion-capture bag without
    commands serves as a second log (``data.alignment``)."""
    from rosbags.highlevel import AnyReader, AnyReaderError

    path = Path(path)
    settings = bag_settings(mapping, str(path))
    wanted = set(ROLES if roles is None else roles)
    topics = {
        key: settings[key]
        for key in TOPIC_TYPES
        if settings[key] and wanted.intersection(KEY_ROLES[key])
    }
    if "load_pose" in topics and topics["load_pose"] == topics.get("vehicle_pose"):
        raise LogError(
            f"{path}: the load is mapped to the vehicle's own topic {topics['load_pose']} "
            "(mapping keys 'load_pose' and 'vehicle_pose'): |pL - p| would be 0; map "
            "load_pose to the load's motion-capture topic"
        )
    notes: list[str] = []
    with tempfile.TemporaryDirectory(prefix="slungload-mcap-") as tmp:
        source = _salvaged(path, Path(tmp), notes)
        try:
            reader = AnyReader([source], default_typestore=_fallback_typestore())
            reader.open()
        except (AnyReaderError, FileNotFoundError, OSError, KeyError, ValueError) as exc:
            raise LogError(_unreadable(path, exc)) from None
        try:
            conns = _connections(reader, topics, path)
            _register_missing(reader, {c.msgtype for cs in conns.values() for c in cs})
            samples = _collect(reader, conns, path, progress)
        finally:
            reader.close()
    kind = "ros2" if reader.is2 else "ros1"

    streams: dict[str, Stream] = {}
    for key, topic in topics.items():
        msgtype, rows = samples[key]
        stamps = _stamps(rows, settings["stamps"], topic, notes, path)
        got = _convert(key, msgtype, topic, rows, stamps, settings, path)
        streams.update({role: s for role, s in got.items() if role in wanted})
    if "velocity" in wanted and "velocity" not in topics:
        notes.append(f"{path}: no velocity topic: the velocity is a finite difference of the pose")
    return RawLog(path, kind, streams, True, settings, notes)


# --- reading ---------------------------------------------------------------------------


def _salvaged(path: Path, tmp: Path, notes: list[str]) -> Path:
    """``path``, or for an MCAP file cut short (a killed recorder) a copy of its whole records
    in ``tmp`` that reads up to the damage (``mcap_salvage``), with a note of what was lost."""
    from . import mcap_salvage

    if not (path.is_file() and path.suffix.lower() == ".mcap" and mcap_salvage.is_cut(path)):
        return path
    out = tmp / path.name
    kept = mcap_salvage.salvage(path, out)
    notes.append(kept.describe(path))
    return out


def _unreadable(path: Path, exc: Exception) -> str:
    """Why a bag cannot be read; for a ROS 1 bag without its index (a killed ``rosbag
    record``, a truncated copy) the command that repairs it."""
    text = str(exc)
    if "not indexed" in text or "index looks damaged" in text:
        return (
            f"{path}: the ROS 1 bag has no readable index (a recorder killed before closing "
            "it leaves none, and a truncated copy loses it): repair it with `rosbag reindex "
            f"{path}` (ROS 1; the original is kept as .orig.bag), then import it again "
            f"({text})"
        )
    return f"{path}: cannot be read as a ROS bag ({text})"


def _fallback_typestore():
    """ROS 2 Humble's types plus the MAVROS and PX4 messages, for bags without definitions."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, text in MSG_DEFINITIONS.items():
        store.register(get_types_from_msg(text, name))
    return store


def _register_missing(reader: Any, msgtypes: set[str]) -> None:
    missing = [t for t in msgtypes if t not in reader.typestore.fielddefs]
    if not missing:
        return
    fallback = _fallback_typestore()
    have = reader.typestore.fielddefs
    reader.typestore.register({k: v for k, v in fallback.fielddefs.items() if k not in have})


def _connections(reader: Any, topics: dict[str, str], path: Path) -> dict[str, list]:
    """Mapping key -> the bag's connections on its topic, type-checked."""
    by_topic: dict[str, list] = {}
    for conn in reader.connections:
        by_topic.setdefault(conn.topic, []).append(conn)
    out = {}
    for key, topic in topics.items():
        if topic not in by_topic:
            have = ", ".join(f"{t} ({cs[0].msgtype})" for t, cs in sorted(by_topic.items()))
            hint = (
                '; velocity = "" takes the velocity from finite differences of the pose'
                if key == "velocity"
                else ""
            )
            raise LogError(
                f"{path}: no topic {topic!r} (mapping key {key!r}); the bag has: "
                f"{have or 'none'}{hint}"
            )
        conns = by_topic[topic]
        types = sorted({c.msgtype for c in conns})
        bad = [t for t in types if t not in TOPIC_TYPES[key]]
        if bad:
            raise LogError(
                f"{path}: topic {topic} ({key}) has type {', '.join(bad)}; expected one of "
                f"{', '.join(TOPIC_TYPES[key])}"
            )
        if len(types) > 1:
            raise LogError(f"{path}: topic {topic} ({key}) has several types: {types}")
        out[key] = conns
    return out


def _collect(reader: Any, conns: dict[str, list], path: Path, progress: bool) -> dict:
    """Mapping key -> (message type, [(bag time s, message), ...]) in bag order."""
    from rosbags.highlevel import AnyReaderError
    from tqdm.auto import tqdm

    keys_of: dict[int, list[str]] = {}  # a topic may serve two keys (Odometry: pose, twist)
    for key, cs in conns.items():
        for c in cs:
            keys_of.setdefault(c.id, []).append(key)
    out: dict[str, tuple[str, list]] = {key: (cs[0].msgtype, []) for key, cs in conns.items()}
    chosen = list({c.id: c for cs in conns.values() for c in cs}.values())
    total = sum(c.msgcount for c in chosen)
    bar = tqdm(
        total=total, desc=path.name, unit="msg", disable=None if progress else True, leave=False
    )
    try:
        for conn, timestamp, raw in reader.messages(connections=chosen):
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except (AnyReaderError, KeyError, ValueError) as exc:
                raise LogError(
                    f"{path}: topic {conn.topic}: a {conn.msgtype} message cannot be decoded "
                    f"({exc})"
                ) from None
            for key in keys_of[conn.id]:
                out[key][1].append((timestamp * 1e-9, msg))
            bar.update()
    finally:
        bar.close()
    return out


def _stamps(rows: list, mode: str, topic: str, notes: list[str], path: Path) -> np.ndarray:
    """Seconds per message: header stamps, or the bag's receive time."""
    received = np.array([t for t, _ in rows], dtype=np.float64)
    if not rows or mode == "bag" or not hasattr(rows[0][1], "header"):
        return received
    header = np.array(
        [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, m in rows], dtype=np.float64
    )
    if not np.any(header):
        notes.append(f"{path}: topic {topic}: header stamps are all zero, using the bag's time")
        return received
    return header


# --- conversion to the package's frames ---------------------------------------------------


def _xyz(v: Any) -> list[float]:
    return [v.x, v.y, v.z]


def _wxyz(q: Any) -> list[float]:
    return [q.w, q.x, q.y, q.z]


def _pose(msgtype: str, msg: Any) -> tuple[list[float], list[float] | None]:
    """(position, orientation w-x-y-z or None) of one message, as expressed in it."""
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return _xyz(msg.pose.position), _wxyz(msg.pose.orientation)
    if msgtype in ("geometry_msgs/msg/PoseWithCovarianceStamped", "nav_msgs/msg/Odometry"):
        return _xyz(msg.pose.pose.position), _wxyz(msg.pose.pose.orientation)
    if msgtype == "geometry_msgs/msg/TransformStamped":
        return _xyz(msg.transform.translation), _wxyz(msg.transform.rotation)
    if msgtype == "geometry_msgs/msg/PointStamped":
        return _xyz(msg.point), None
    assert msgtype == PX4_ODOMETRY
    return list(msg.position), list(msg.q)


def _convert(
    key: str,
    msgtype: str,
    topic: str,
    rows: list,
    time: np.ndarray,
    settings: dict[str, Any],
    path: Path,
) -> dict[str, Stream]:
    """Streams (by role) of one topic in the package's frames."""
    source = f"topic {topic}"
    msgs = [m for _, m in rows]
    n = len(msgs)
    px4 = msgtype.startswith("px4_msgs/")
    world = "ned" if px4 else settings["world"]
    body = "frd" if px4 else settings["body"]
    if key in ("vehicle_pose", "load_pose"):
        poses = [_pose(msgtype, m) for m in msgs]
        pos = frames.world_vectors(np.array([p for p, _ in poses], float).reshape(n, 3), world)
        if key == "load_pose":
            return {"load": Stream(source, time, pos)}
        q = np.array([q for _, q in poses], float).reshape(n, 4)
        return {
            "position": Stream(source, time, pos),
            "attitude": Stream(source, time, frames.attitudes(q, world, body)),
        }
    if key == "velocity":
        return {"velocity": Stream(source, time, _velocity(msgtype, msgs, world, topic, path))}
    if msgtype == ATTITUDE_TARGET:
        masks = np.array([m.type_mask for m in msgs], dtype=np.int64)
        for bits, what in ((_IGNORE_RATES, "body rates"), (_IGNORE_THRUST, "thrust")):
            bad = np.flatnonzero(masks & bits)
            if len(bad):
                raise LogError(
                    f"{path}: topic {topic}: message {bad[0]} has type_mask {masks[bad[0]]}, "
                    f"which ignores the {what}; the model needs body-rate and thrust commands"
                )
        rates = np.array([_xyz(m.body_rate) for m in msgs], float).reshape(n, 3)  # FLU
        thrust = np.array([m.thrust for m in msgs], float)
    else:  # px4 VehicleRatesSetpoint: FRD rates, thrust along body z (negative up)
        rates = frames.body_vectors(
            np.array([[m.roll, m.pitch, m.yaw] for m in msgs], float).reshape(n, 3), "frd"
        )
        thrust = -np.array([m.thrust_body[2] for m in msgs], float)
    return {
        "rates": Stream(source, time, rates),
        "thrust": Stream(source, time, thrust.reshape(n, 1)),
    }


def _velocity(msgtype: str, msgs: list, world: str, topic: str, path: Path) -> np.ndarray:
    n = len(msgs)
    if msgtype == "geometry_msgs/msg/TwistStamped":
        return frames.world_vectors(
            np.array([_xyz(m.twist.linear) for m in msgs], float).reshape(n, 3), world
        )
    if msgtype == "geometry_msgs/msg/TwistWithCovarianceStamped":
        return frames.world_vectors(
            np.array([_xyz(m.twist.twist.linear) for m in msgs], float).reshape(n, 3), world
        )
    if msgtype == "nav_msgs/msg/Odometry":  # twist in the child (body) frame: R(q) v
        q = np.array([_wxyz(m.pose.pose.orientation) for m in msgs], float).reshape(n, 4)
        v = np.array([_xyz(m.twist.twist.linear) for m in msgs], float).reshape(n, 3)
        return frames.world_vectors(frames.rotate(q, v), world)
    frames_used = {int(m.velocity_frame) for m in msgs}  # PX4 VehicleOdometry
    if not frames_used <= {1, 3}:
        raise LogError(
            f"{path}: topic {topic}: velocity_frame {sorted(frames_used)}; only NED (1) and "
            "body FRD (3) velocities can be converted"
        )
    v = np.array([list(m.velocity) for m in msgs], float).reshape(n, 3)
    q = np.array([list(m.q) for m in msgs], float).reshape(n, 4)
    body = np.array([int(m.velocity_frame) == 3 for m in msgs])
    v[body] = frames.rotate(q[body], v[body])  # body FRD -> NED by the FRD -> NED attitude
    return frames.world_vectors(v, "ned")
