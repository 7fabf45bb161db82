"""Flight logs written by the formats' own libraries, for the import tests.

Bags are written with ``rosbags``' own writers and message types (``mavros_msgs`` is not in
rosbags' typestores: its definition is registered from ``readers.rosbag.MSG_DEFINITIONS``, as
a ROS install would carry it); a ULog by a small writer below (``write_ulog``; pyulog's own
``ULog.write_ulog`` rewrites a parsed one); CSV by hand. ``truth`` is the smooth flight they
hold.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
from flights import conical_swing

from slungload import frames
from slungload.config import VehicleParams
from slungload.data.importing import ImportOptions, import_logs
from slungload.data.readers.rosbag import ATTITUDE_TARGET, MSG_DEFINITIONS
from slungload.fileio import read_npz

PARAMS = VehicleParams()
HOVER = 0.42
T0_NS = 1_700_000_000_123_456_789  # a realistic ROS time, ns
POSE, LOAD = "/vrpn_client_node/quad/pose", "/vrpn_client_node/load/pose"
VEL, CMD = "/mavros/local_position/velocity_local", "/mavros/setpoint_raw/attitude"
THRUST_PER_THROTTLE = (PARAMS.mass_quad + PARAMS.mass_load) * PARAMS.gravity / HOVER


# --- flights to write -----------------------------------------------------------------------


def truth(t: np.ndarray) -> dict[str, np.ndarray]:
    """A smooth flight at times t: the published schema (attitude x-y-z-w), z up, FLU."""
    p = np.stack([np.sin(0.5 * t), 0.5 * np.cos(0.3 * t), 1.0 + 0.1 * t], axis=1)
    v = np.stack([0.5 * np.cos(0.5 * t), -0.15 * np.sin(0.3 * t), 0.1 + 0 * t], axis=1)
    yaw, roll = 0.2 * t, 0.1 * np.sin(t)
    q_yaw = np.stack([np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)], axis=1)
    q_roll = np.stack([np.cos(roll / 2), np.sin(roll / 2), 0 * t, 0 * t], axis=1)
    q = frames.quat_multiply(q_yaw, q_roll)  # w-x-y-z
    xi = conical_swing(t)
    return {
        "time": t,
        "p": p,
        "v": v,
        "attitude": q[:, [1, 2, 3, 0]],
        "p_load": p + PARAMS.cable_length * xi,
        "w_ref": np.stack([0.1 * np.sin(t), 0.05 * np.cos(t), 0.2 + 0 * t], axis=1),
        "T_ref": (14.2 + 0.1 * np.sin(t))[:, None],
    }


# --- ROS bags -------------------------------------------------------------------------------


def typestore(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(MSG_DEFINITIONS[ATTITUDE_TARGET], ATTITUDE_TARGET))
    return store


class Msgs:
    """Message builders of one typestore (ROS 1 headers carry a seq)."""

    def __init__(self, store, ros1: bool) -> None:
        self.store, self.ros1 = store, ros1
        self.t = store.types

    def header(self, ns: int):
        stamp = self.t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        extra = {"seq": 0} if self.ros1 else {}
        return self.t["std_msgs/msg/Header"](**extra, stamp=stamp, frame_id="world")

    def vec(self, xyz, name="geometry_msgs/msg/Vector3"):
        return self.t[name](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))

    def quat(self, xyzw):
        x, y, z, w = (float(c) for c in xyzw)
        return self.t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    def pose(self, ns, p, xyzw=(0, 0, 0, 1)):
        pose = self.t["geometry_msgs/msg/Pose"](
            position=self.vec(p, "geometry_msgs/msg/Point"), orientation=self.quat(xyzw)
        )
        return self.t["geometry_msgs/msg/PoseStamped"](header=self.header(ns), pose=pose)

    def twist(self, ns, v):
        twist = self.t["geometry_msgs/msg/Twist"](linear=self.vec(v), angular=self.vec((0, 0, 0)))
        return self.t["geometry_msgs/msg/TwistStamped"](header=self.header(ns), twist=twist)

    def command(self, ns, rates, thrust_n, mask=0):
        return self.t[ATTITUDE_TARGET](
            header=self.header(ns),
            type_mask=mask,
            orientation=self.quat((0, 0, 0, 1)),
            body_rate=self.vec(rates),
            thrust=float(thrust_n / THRUST_PER_THROTTLE),
        )


def mavros_topics(m: Msgs, arrays: dict, times: dict[str, np.ndarray] | None = None) -> dict:
    """topic -> (type, [(ns, message)]) of a flight: mocap poses, velocity, AttitudeTarget.
    ``times`` (per topic, s after T0) samples ``truth`` there instead of using ``arrays``."""
    out = {}

    def at(topic: str):
        if times is None:
            return arrays["time"], arrays
        return times[topic], truth(times[topic])

    t, a = at(POSE)
    ns = T0_NS + np.round(t * 1e9).astype(np.int64)
    out[POSE] = (
        "geometry_msgs/msg/PoseStamped",
        [(int(n), m.pose(int(n), a["p"][i], a["attitude"][i])) for i, n in enumerate(ns)],
    )
    t, a = at(LOAD)
    ns = T0_NS + np.round(t * 1e9).astype(np.int64)
    out[LOAD] = (
        "geometry_msgs/msg/PoseStamped",
        [(int(n), m.pose(int(n), a["p_load"][i])) for i, n in enumerate(ns)],
    )
    t, a = at(VEL)
    ns = T0_NS + np.round(t * 1e9).astype(np.int64)
    out[VEL] = (
        "geometry_msgs/msg/TwistStamped",
        [(int(n), m.twist(int(n), a["v"][i])) for i, n in enumerate(ns)],
    )
    t, a = at(CMD)
    ns = T0_NS + np.round(t * 1e9).astype(np.int64)
    out[CMD] = (
        ATTITUDE_TARGET,
        [(int(n), m.command(int(n), a["w_ref"][i], a["T_ref"][i, 0])) for i, n in enumerate(ns)],
    )
    return out


def write_bag(path: Path, topics: dict, store, *, ros1: bool, storage: str = "mcap") -> Path:
    """Write ``topic -> (type, [(ns, message)])`` with rosbags' own writer, in bag-time order
    (the messages' own order within a topic is kept; bag time is the header stamp)."""
    if ros1:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
    with writer:
        conns = {
            topic: writer.add_connection(topic, msgtype, typestore=store)
            for topic, (msgtype, _) in topics.items()
        }
        rows = [
            (ns, k, topic, msg)
            for topic, (_, msgs) in topics.items()
            for k, (ns, msg) in enumerate(msgs)
        ]
        for ns, _, topic, msg in sorted(rows, key=lambda r: (r[0], r[1])):
            writer.write(conns[topic], ns, serialize(msg, topics[topic][0]))
    return path


def imported(folder: Path) -> dict[str, dict[str, np.ndarray]]:
    return {p.stem: read_npz(p) for p in sorted((folder / "data").glob("*.npz"))}


def import_to_train(bag: Path, out: Path, params: VehicleParams = PARAMS):
    """``import_logs`` of one MAVROS bag into ``out`` (the test bags' hover throttle, every
    flight listed as training), no progress bar."""
    options = ImportOptions(hover_throttle=HOVER, split="train")
    return import_logs([bag], out, params=params, options=options, progress=False)


def rotation_angle(q1_xyzw: np.ndarray, q2_xyzw: np.ndarray) -> np.ndarray:
    dot = np.abs(np.sum(q1_xyzw * q2_xyzw, axis=-1))
    return 2 * np.arccos(np.clip(dot, -1.0, 1.0))


def write_ulog(path: Path, topics: dict[tuple[str, int], dict[str, np.ndarray]], params: dict):
    """A minimal ULog (header, formats, parameters, subscriptions, data) as PX4 writes it:
    ``(name, instance) -> field -> values`` with ``timestamp`` (uint64, us) and float fields
    (``name[i]`` for arrays)."""

    def message(kind: str, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0))
    out += message("B", bytes(16) + bytes(24))
    for name in sorted({n for n, _ in topics}):
        fields = next(f for (n, _), f in topics.items() if n == name)
        arrays: dict[str, int] = {}
        for key in fields:
            if key != "timestamp":
                base = key.split("[")[0]
                arrays[base] = arrays.get(base, 0) + 1
        spec = "uint64_t timestamp;" + "".join(
            f"float[{n}] {b};" if any(k.startswith(f"{b}[") for k in fields) else f"float {b};"
            for b, n in arrays.items()
        )
        out += message("F", f"{name}:{spec}".encode())
    for key, value in params.items():
        name = f"float {key}".encode()
        out += message("P", bytes([len(name)]) + name + struct.pack("<f", value))
    ids = {}
    for i, (name, instance) in enumerate(topics):
        ids[(name, instance)] = i
        out += message("A", struct.pack("<BH", instance, i) + name.encode())
    rows = []
    for key, fields in topics.items():
        order = [k for k in fields if k != "timestamp"]
        for j, stamp in enumerate(fields["timestamp"]):
            payload = struct.pack("<HQ", ids[key], int(stamp))
            payload += struct.pack(f"<{len(order)}f", *(float(fields[k][j]) for k in order))
            rows.append((int(stamp), message("D", payload)))
    for _, row in sorted(rows, key=lambda r: r[0]):
        out += row
    path.write_bytes(bytes(out))
    return path


def px4_topics(t_us: dict[str, np.ndarray], with_load: bool = True) -> dict:
    """PX4's topics (NED, FRD, normalised thrust) of the ``truth`` flight."""
    m = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])  # ENU <-> NED (its own inverse)

    def at(key):
        return truth(t_us[key] * 1e-6)

    a = at("position")
    p, v = a["p"] @ m, a["v"] @ m
    topics = {
        ("vehicle_local_position", 0): {
            "timestamp": t_us["position"],
            **{k: p[:, i] for i, k in enumerate("xyz")},
            **{f"v{k}": v[:, i] for i, k in enumerate("xyz")},
        }
    }
    a = at("attitude")
    q_flu = a["attitude"][:, [3, 0, 1, 2]]
    # inverse of frames.attitudes(., "ned", "frd"): q_ned_frd = M^-1 q B
    q_ned = frames.quat_multiply(
        frames.quat_conjugate(frames.Q_ENU_FROM_NED),
        frames.quat_multiply(q_flu, frames.Q_FLU_FROM_FRD),
    )
    topics[("vehicle_attitude", 0)] = {
        "timestamp": t_us["attitude"],
        **{f"q[{i}]": q_ned[:, i] for i in range(4)},
    }
    a = at("rates")
    w = a["w_ref"] * [1, -1, -1]
    topics[("vehicle_rates_setpoint", 0)] = {
        "timestamp": t_us["rates"],
        "roll": w[:, 0],
        "pitch": w[:, 1],
        "yaw": w[:, 2],
    }
    a = at("thrust")
    topics[("vehicle_thrust_setpoint", 0)] = {
        "timestamp": t_us["thrust"],
        "xyz[0]": 0 * a["time"],
        "xyz[1]": 0 * a["time"],
        "xyz[2]": -a["T_ref"][:, 0] / THRUST_PER_THROTTLE,
    }
    if with_load:
        a = at("load")
        pl = a["p_load"] @ m
        topics[("vehicle_mocap_odometry", 1)] = {
            "timestamp": t_us["load"],
            **{f"position[{i}]": pl[:, i] for i in range(3)},
        }
    return topics


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> Path:
    names = list(columns)
    n = max(len(c) for c in columns.values())
    lines = [",".join(names)]
    for i in range(n):
        cells = []
        for name in names:
            c = columns[name]
            cells.append("" if i >= len(c) or np.isnan(c[i]) else repr(float(c[i])))
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def default_columns(a: dict) -> dict[str, np.ndarray]:
    """The schema's arrays as the CSV reader's default columns (time, p_x ..., T_ref)."""
    columns = {"time": a["time"]}
    for key in ("p", "v", "attitude", "p_load", "w_ref"):
        axes = "xyzw" if key == "attitude" else "xyz"
        columns.update({f"{key}_{ax}": a[key][:, i] for i, ax in enumerate(axes)})
    columns["T_ref"] = a["T_ref"][:, 0]
    return columns
