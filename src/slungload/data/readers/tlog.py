"""MAVLink telemetry logs (``.tlog``, as QGroundControl, MAVProxy and ``slungload fly`` write
them), parsed with pymavlink (imported only when a log is read).

Settings (the mapping keys, defaults in ``TLOG_DEFAULTS``): the vehicle's ``system`` and
``component`` (its autopilot), the load's ``load_system`` and ``load_component`` (its
motion capture's ODOMETRY). Streams, every vector converted NED -> z up and FRD -> FLU
(``frames``), each message stamped with the log's own time:

- ``position``, ``velocity``, ``attitude``: the vehicle's ODOMETRY (pose in LOCAL_NED,
  velocity in BODY_FRD or LOCAL_NED), else LOCAL_POSITION_NED and ATTITUDE_QUATERNION;
- ``load``: the load's ODOMETRY (LOCAL_NED);
- ``rates`` and ``thrust``: SET_ATTITUDE_TARGET to the vehicle with the attitude ignored (the
  companion's body-rate and normalised-thrust set-points, FRD);
- only while the vehicle's HEARTBEAT says OFFBOARD: outside it the set-points fly nothing,
  so each OFFBOARD span is a piece of flight (the import splits at the gaps between them).

The hover throttle of the thrust map is the log's last PARAM_VALUE of ``MPC_THR_HOVER`` (the
bridge asks the autopilot for it) unless given.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from ... import frames
from .logs import ROLES, LogError, RawLog, Stream, merge_settings

TLOG_DEFAULTS: dict[str, int] = {"system": 1, "component": 1, "load_system": 1,
                                 "load_component": 197}  # fmt: skip
OFFBOARD = 6  # PX4's main mode (bits 16-23 of the HEARTBEAT's custom mode)
_NED, _FRD = 1, 12  # MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD
_RATES_AND_THRUST = 128  # SET_ATTITUDE_TARGET: attitude ignored; rates and thrust used


def read_tlog(
    path: str | Path,
    mapping: dict[str, Any] | None = None,
    *,
    progress: bool = False,
    roles: Collection[str] | None = None,
) -> RawLog:
    """The streams of one ``.tlog`` (``progress`` unused); only ``roles`` (None: all)."""
    os.environ.setdefault("MAVLINK20", "1")  # ODOMETRY is a MAVLink 2 message
    from pymavlink import mavutil

    path = Path(path)
    settings = merge_settings(TLOG_DEFAULTS, mapping, str(path))
    try:
        ids = {k: int(v) for k, v in settings.items()}
    except ValueError as exc:
        raise LogError(f"{path}: system and component ids must be integers ({exc})") from None
    log = mavutil.mavlink_connection(str(path), dialect="common")
    rows: dict[str, list] = {k: [] for k in ("odometry", "local", "quat", "load", "sp", "mode")}
    hover = None
    vehicle = (ids["system"], ids["component"])
    load = (ids["load_system"], ids["load_component"])
    while (msg := log.recv_match(blocking=False)) is not None:
        kind, t = msg.get_type(), msg._timestamp
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "ODOMETRY" and source == load and msg.frame_id == _NED:
            rows["load"].append((t, msg.x, msg.y, msg.z))
        elif kind == "SET_ATTITUDE_TARGET" and msg.target_system == ids["system"]:
            if msg.type_mask & _RATES_AND_THRUST and not msg.type_mask & 0b1000111:
                w = (msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate)
                rows["sp"].append((t, *w, msg.thrust))
        elif source != vehicle:
            continue
        elif kind == "HEARTBEAT" and msg.type != mavutil.mavlink.MAV_TYPE_GCS:
            rows["mode"].append((t, (msg.custom_mode >> 16) & 0xFF == OFFBOARD))
        elif kind == "ODOMETRY" and msg.frame_id == _NED and msg.child_frame_id in (_NED, _FRD):
            v = np.array([msg.vx, msg.vy, msg.vz])
            if msg.child_frame_id == _FRD:
                v = frames.rotate(np.array(msg.q), v)
            rows["odometry"].append((t, msg.x, msg.y, msg.z, *v, *msg.q))
        elif kind == "LOCAL_POSITION_NED":
            rows["local"].append((t, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz))
        elif kind == "ATTITUDE_QUATERNION":
            rows["quat"].append((t, msg.q1, msg.q2, msg.q3, msg.q4))
        elif kind == "PARAM_VALUE" and msg.param_id == "MPC_THR_HOVER":
            hover = float(msg.param_value)
    log.close()
    return RawLog(path, "tlog", _streams(rows, path, roles), True, settings, hover_throttle=hover)


def _streams(rows: dict[str, list], path: Path, roles: Collection[str] | None) -> dict:
    """The streams by role from the rows of each message kind, kept while in OFFBOARD."""
    wanted = set(ROLES if roles is None else roles)
    if not rows["mode"]:
        raise LogError(f"{path}: no HEARTBEAT from the vehicle: check the mapping's system id")
    modes = np.array(rows["mode"])
    arrays = {k: _offboard(np.array(v, dtype=float) if v else np.empty((0, 2)), modes)
              for k, v in rows.items() if k != "mode"}  # fmt: skip
    if not len(arrays["sp"]):
        raise LogError(f"{path}: no SET_ATTITUDE_TARGET (rates and thrust) while in OFFBOARD")
    streams: dict[str, Stream] = {}
    odo, local, quat = arrays["odometry"], arrays["local"], arrays["quat"]
    if len(odo):
        pos, vel, att = (odo[:, 0], odo[:, 1:4]), (odo[:, 0], odo[:, 4:7]), (odo[:, 0], odo[:, 7:])
        name = "ODOMETRY"
    elif len(local) and len(quat):
        pos, vel, att = (local[:, 0], local[:, 1:4]), (local[:, 0], local[:, 4:7]), (
            quat[:, 0], quat[:, 1:])  # fmt: skip
        name = "LOCAL_POSITION_NED"
    else:
        raise LogError(f"{path}: no vehicle state (ODOMETRY, or LOCAL_POSITION_NED and "
                       "ATTITUDE_QUATERNION) from the vehicle while in OFFBOARD")  # fmt: skip
    if not len(arrays["load"]) and "load" in wanted:
        raise LogError(f"{path}: no load ODOMETRY (mapping keys load_system, load_component)")
    sp, load = arrays["sp"], arrays["load"]
    candidates = {
        "position": (name, pos[0], frames.world_vectors(pos[1], "ned")),
        "velocity": (name, vel[0], frames.world_vectors(vel[1], "ned")),
        "attitude": (name, att[0], frames.attitudes(att[1], "ned", "frd")),
        "load": ("load ODOMETRY", load[:, 0], frames.world_vectors(load[:, 1:4], "ned")),
        "rates": ("SET_ATTITUDE_TARGET", sp[:, 0], frames.body_vectors(sp[:, 1:4], "frd")),
        "thrust": ("SET_ATTITUDE_TARGET", sp[:, 0], sp[:, 4:5]),
    }
    for role in wanted:
        source, t, values = candidates[role]
        streams[role] = Stream(f"message {source}", t, values)
    return streams


def _offboard(rows: np.ndarray, modes: np.ndarray) -> np.ndarray:
    """The rows (n, 1 + k) whose time (column 0) falls after a HEARTBEAT that said OFFBOARD,
    before the next that did not; ``modes`` (m, 2): time, 1 in OFFBOARD."""
    if not len(rows):
        return rows
    last = np.searchsorted(modes[:, 0], rows[:, 0], side="right") - 1
    keep = (last >= 0) & (modes[np.maximum(last, 0), 1] > 0)
    return rows[keep]
