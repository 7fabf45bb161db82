"""PX4 ULog flight logs (``.ulg``), read with ``pyulog`` (imported only when a log is read).

Topics (the mapping keys, defaults in ``ULOG_DEFAULTS``; ``name`` or ``name:instance``):

- ``position`` and ``velocity``: ``vehicle_local_position`` (``x y z``, ``vx vy vz``, NED;
  samples flagged ``xy_valid`` / ``z_valid`` = 0 are dropped);
- ``attitude``: ``vehicle_attitude`` (``q[0..3]`` w-x-y-z, FRD body -> NED);
- ``rates``: ``vehicle_rates_setpoint`` (``roll pitch yaw``, FRD);
- ``thrust``: ``vehicle_thrust_setpoint`` (``xyz[2]``, normalised, negative up); when the log
  has no such topic (PX4 before 1.13), the rates set-point's ``thrust_body[2]`` or scalar
  ``thrust`` (positive up), else ``control[3]`` of ``actuator_controls_0`` (the mixer's input),
  with a note; a mapping may name any of these topics;
- ``load``: the load's position, from a logged motion-capture topic (``x y z`` or
  ``position[0..2]``, NED), e.g. ``vehicle_mocap_odometry:1`` when a second rigid body is
  streamed to PX4. PX4 logs no load by itself: without ``load`` the import stops with an
  error that lists the logged topics that carry a position (``position[0..2]``, or ``x y z``
  beside ``vx vy vz``); ``load`` naming the ``position`` topic is refused by name.

The load's position must be in the same local frame as the vehicle's: with a motion-capture
system fused by the EKF, ``vehicle_local_position`` and the mocap frame share their axes but
the EKF's origin may differ; then take the vehicle's position from its own mocap topic too
(``position = "vehicle_mocap_odometry"``). Times: each message's ``timestamp`` (microseconds
since boot). Every vector is converted NED -> z up and FRD -> FLU (``frames``). The hover
throttle of the thrust map is the log's ``MPC_THR_HOVER`` parameter unless given.
"""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from ... import frames
from .logs import ROLES, LogError, RawLog, Stream, merge_settings

ULOG_DEFAULTS: dict[str, str] = {
    "position": "vehicle_local_position",
    "velocity": "vehicle_local_position",  # "" : finite differences of the position
    "attitude": "vehicle_attitude",
    "rates": "vehicle_rates_setpoint",
    "thrust": "vehicle_thrust_setpoint",
    "load": "",  # required: the load's motion-capture topic
}
HOVER_PARAMETER = "MPC_THR_HOVER"

_POSITION_FIELDS = (("x", "y", "z"), ("position[0]", "position[1]", "position[2]"))
_VELOCITY_FIELDS = (("vx", "vy", "vz"), ("velocity[0]", "velocity[1]", "velocity[2]"))
_QUAT_FIELDS = (("q[0]", "q[1]", "q[2]", "q[3]"),)
_RATE_FIELDS = (("roll", "pitch", "yaw"),)
# thrust: the set-point's body z (FRD, negative up); PX4 before 1.13: a scalar ``thrust`` of
# the rates set-point, or only the mixer's input ``control[3]`` of ``actuator_controls_0``
# (both positive up)
_THRUST_FIELDS = (("xyz[2]",), ("thrust_body[2]",), ("thrust",), ("control[3]",))
_THRUST_UP = ("thrust", "control[3]")
ACTUATOR_CONTROLS = "actuator_controls_0"


def read_ulog(
    path: str | Path,
    mapping: dict[str, Any] | None = None,
    *,
    progress: bool = False,
    roles: Collection[str] | None = None,
) -> RawLog:
    """The streams of one ``.ulg`` file (``progress`` is unused: pyulog reads it at once);
    only ``roles`` (None: every role), so a log whose load comes from a second log needs no
    ``load`` topic."""
    from pyulog import ULog

    path = Path(path)
    try:
        log = ULog(str(path))
    except Exception as exc:  # pyulog raises bare exceptions and struct errors on bad files
        msg = f"{path}: cannot be read as a PX4 ULog ({type(exc).__name__}: {exc})"
        raise LogError(msg) from None
    topics = {f"{d.name}:{d.multi_id}": d.data for d in log.data_list}
    hover = log.initial_parameters.get(HOVER_PARAMETER)
    return ulog_streams(topics, path, mapping, hover_throttle=hover, roles=roles)


def ulog_streams(
    topics: dict[str, dict[str, np.ndarray]],
    path: Path,
    mapping: dict[str, Any] | None = None,
    *,
    hover_throttle: float | None = None,
    roles: Collection[str] | None = None,
) -> RawLog:
    """Streams from a ULog's topics as arrays: ``"name:instance"`` -> field -> (n,) values
    (``timestamp`` in microseconds), as ``pyulog`` gives them; only ``roles`` (None: every
    role). The conversion is tested on arrays; ``read_ulog`` feeds it a parsed file."""
    settings = merge_settings(ULOG_DEFAULTS, mapping, str(path))
    wanted = set(ROLES if roles is None else roles)
    notes: list[str] = []
    if "load" in wanted:
        _check_load(topics, settings, path)
    log = _Topics(topics, settings, path)
    streams = _motion_streams(log, wanted, notes)
    if "attitude" in wanted:
        name, t, q, _ = log.series("attitude", _QUAT_FIELDS, "quaternion")
        streams["attitude"] = Stream(f"topic {name}", t, frames.attitudes(q, "ned", "frd"))
    if "rates" in wanted:
        name, t, rates, _ = log.series("rates", _RATE_FIELDS, "body rate")
        streams["rates"] = Stream(f"topic {name}", t, frames.body_vectors(rates, "frd"))
    if "thrust" in wanted:
        name, t, thrust = _thrust(log, notes)
        streams["thrust"] = Stream(f"topic {name}", t, -thrust)  # body z is down in FRD
    if "load" in wanted:
        name, t, load, _ = log.series("load", _POSITION_FIELDS, "position")
        streams["load"] = Stream(f"topic {name}", t, frames.world_vectors(load, "ned"))
    return RawLog(path, "ulog", streams, True, settings, notes, hover_throttle=hover_throttle)


def _check_load(
    topics: dict[str, dict[str, np.ndarray]], settings: dict[str, Any], path: Path
) -> None:
    """The load's topic is named, and is not the vehicle's own position topic."""
    if not settings["load"]:
        own = _instance(settings["position"])
        carriers = sorted(
            name
            for name, data in topics.items()
            if _carries_position(data) and name != own and "setpoint" not in name
        )
        raise LogError(
            f"{path}: the log holds no load position: name the topic that carries it with the "
            f"mapping key 'load' (name or name:instance), or take it from a second log "
            f"(--second); topics with a position (not the vehicle's own, {own}, nor "
            f"set-points): {', '.join(carriers) or 'none'}"
        )
    if _instance(settings["load"]) == _instance(settings["position"]):
        raise LogError(
            f"{path}: the load is mapped to the vehicle's own position topic "
            f"{_instance(settings['load'])} (mapping keys 'load' and 'position'): |pL - p| "
            "would be 0; map 'load' to the load's motion-capture topic (or take the load "
            "from a second log: --second)"
        )


class _Topics:
    """A log's topics looked up by mapping key, with errors that name what the log has."""

    def __init__(
        self, topics: dict[str, dict[str, np.ndarray]], settings: dict[str, Any], path: Path
    ) -> None:
        self.topics, self.settings, self.path = topics, settings, path

    def topic(self, key: str) -> tuple[str, dict[str, np.ndarray]]:
        """The ``"name:instance"`` and fields of the topic that ``key`` maps to."""
        spec = str(self.settings[key])
        name = spec if ":" in spec else f"{spec}:0"
        if name not in self.topics:
            have = ", ".join(sorted(self.topics)) or "none"
            hint = (
                '; velocity = "" takes the velocity from finite differences of the position'
                if key == "velocity"
                else ""
            )
            raise LogError(
                f"{self.path}: no topic {spec!r} (mapping key {key!r}); the log has: {have}{hint}"
            )
        return name, self.topics[name]

    def series(self, key: str, options: tuple[tuple[str, ...], ...], what: str):
        """(topic name, (n,) times in s, (n, fields) values, all fields) of the first field
        group in ``options`` that the topic of ``key`` holds."""
        name, data = self.topic(key)
        cols = _fields(data, options)
        if cols is None:
            raise LogError(
                f"{self.path}: topic {name} ({key}) has no {what} fields "
                f"({' or '.join(' '.join(o) for o in options)}); it has: {', '.join(sorted(data))}"
            )
        t = np.asarray(data["timestamp"], np.float64) * 1e-6
        return name, t, np.stack([np.asarray(data[c], np.float64) for c in cols], axis=1), data


def _motion_streams(log: _Topics, wanted: set[str], notes: list[str]) -> dict[str, Stream]:
    """The vehicle's position and (when mapped) velocity streams, z up, without the samples
    the EKF flags invalid; those of ``wanted``."""
    path = log.path
    streams: dict[str, Stream] = {}
    if "position" not in wanted:
        return streams
    name, t, pos, data = log.series("position", _POSITION_FIELDS, "position")
    keep = _valid(data, ("xy_valid", "z_valid"))
    if len(keep) and not keep.any():
        raise LogError(
            f"{path}: topic {name} (position) has {len(keep)} samples, all flagged invalid "
            "(xy_valid or z_valid = 0: the estimator had no position); map 'position' to a "
            "motion-capture topic, e.g. vehicle_mocap_odometry:0"
        )
    if not keep.all():
        notes.append(f"{path}: topic {name}: {int((~keep).sum())} samples flagged invalid dropped")
    streams["position"] = Stream(f"topic {name}", t[keep], frames.world_vectors(pos[keep], "ned"))
    if "velocity" not in wanted:
        return streams
    if log.settings["velocity"]:
        name, t, vel, data = log.series("velocity", _VELOCITY_FIELDS, "velocity")
        keep = _valid(data, ("v_xy_valid", "v_z_valid"))
        streams["velocity"] = Stream(
            f"topic {name}", t[keep], frames.world_vectors(vel[keep], "ned")
        )
    else:
        notes.append(f"{path}: no velocity topic: the velocity is a finite difference of p")
    return streams


def _thrust(log: _Topics, notes: list[str]) -> tuple[str, np.ndarray, np.ndarray]:
    """(topic name, (n,) times in s, (n, 1) normalised thrust, FRD: negative up) from the
    topic mapped to ``thrust``; when the log has no such topic (older PX4), from the rates
    set-point's ``thrust_body[2]`` or scalar ``thrust``, else from ``control[3]`` of
    ``actuator_controls_0``, with a note."""
    path = log.path
    rates_data = log.topics.get(_instance(log.settings["rates"]), {})
    thrust_spec = str(log.settings["thrust"])
    if thrust_spec and _instance(thrust_spec) in log.topics:
        key = "thrust"
    elif _fields(rates_data, _THRUST_FIELDS) is not None:
        key = "rates"
    elif _fields(log.topics.get(f"{ACTUATOR_CONTROLS}:0", {}), _THRUST_FIELDS[3:]) is not None:
        key = ""
    elif thrust_spec:
        log.topic("thrust")  # raises: names the missing topic
        raise AssertionError  # pragma: no cover
    else:
        raise LogError(f"{path}: no thrust: set the mapping key 'thrust' to a set-point topic")
    if key:
        name, t, thrust, data = log.series(key, _THRUST_FIELDS, "thrust")
    else:  # only the mixer's input holds it
        spec = {**log.settings, "thrust": ACTUATOR_CONTROLS}
        name, t, thrust, data = _Topics(log.topics, spec, path).series(
            "thrust", _THRUST_FIELDS[3:], "thrust"
        )
    field = _fields(data, _THRUST_FIELDS)[0]  # type: ignore[index]
    if key != "thrust":
        notes.append(
            f"{path}: no topic {thrust_spec or '(thrust)'}: thrust from {field} of topic {name}"
            + (
                " (the rate controller's output to the mixer, a normalised throttle: PX4 "
                "before 1.13 logs no thrust set-point)"
                if not key
                else ""
            )
        )
    if field in _THRUST_UP:
        thrust = -thrust
    return name, t, thrust


def _instance(spec: str) -> str:
    """``name`` or ``name:instance`` -> ``name:instance``."""
    spec = str(spec)
    return spec if ":" in spec else f"{spec}:0"


def _carries_position(data: dict[str, np.ndarray]) -> bool:
    """A topic with a position: ``position[0..2]``, or ``x y z`` beside a velocity ``vx vy
    vz`` (as the local position and its set-point); accelerometers, gyroscopes,
    magnetometers and sticks also have ``x y z``, but no velocity."""
    return _fields(data, _POSITION_FIELDS[1:]) is not None or (
        _fields(data, _POSITION_FIELDS[:1]) is not None
        and _fields(data, _VELOCITY_FIELDS[:1]) is not None
    )


def _fields(data: dict[str, np.ndarray], options: tuple[tuple[str, ...], ...]):
    for cols in options:
        if all(c in data for c in cols):
            return cols
    return None


def _valid(data: dict[str, np.ndarray], flags: tuple[str, ...]) -> np.ndarray:
    n = len(data["timestamp"])
    keep = np.ones(n, dtype=bool)
    for flag in flags:
        if flag in data:
            keep &= np.asarray(data[flag]) != 0
    return keep
