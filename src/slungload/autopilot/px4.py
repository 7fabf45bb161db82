"""PX4's MAVLink, the subset the bridge and the simulated autopilot speak, in one place.

pymavlink (the reference implementation) parses and writes the messages; this module holds
what PX4 means by them and converts to and from the package's frames (``frames``: NED -> z-up
world, FRD -> FLU body):

- **modes**: a PX4 HEARTBEAT's ``custom_mode`` packs the main mode in bits 16-23 and the
  sub mode in bits 24-31 (PX4 ``px4_custom_mode.h``); ``MAV_CMD_DO_SET_MODE`` takes
  ``MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`` in param1, the main mode in param2, the sub mode in
  param3 (PX4 docs, "MAVLink Messaging": commands);
- **state**: ODOMETRY (pose in ``MAV_FRAME_LOCAL_NED``, attitude FRD -> NED, velocity and
  rates in ``child_frame_id``: PX4 sends ``MAV_FRAME_BODY_FRD``), or LOCAL_POSITION_NED +
  ATTITUDE_QUATERNION;
- **set-point**: SET_ATTITUDE_TARGET with the attitude ignored (``type_mask`` bit 7), body
  rates FRD in rad/s and a normalised thrust in [0, 1] (PX4 docs, "Offboard Mode": "body
  rate and thrust" set-points);
- **thrust map**: newtons <-> normalised throttle, the map ``slungload import`` applies to
  logs (hover throttle, PX4's ``MPC_THR_HOVER``, or newtons per unit throttle).

MAVLink 2 and the ``common`` dialect are selected before pymavlink loads its messages
(ODOMETRY is a MAVLink 2 message).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from .. import frames
from ..config import VehicleParams

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink picks its wire protocol
from pymavlink import mavutil  # noqa: E402

DIALECT = "common"
mavutil.set_dialect(DIALECT)
mavlink = mavutil.mavlink

# PX4 main modes (px4_custom_mode.h) and the AUTO sub modes the bridge may ask for
MAIN_MODES = {"manual": 1, "altitude": 2, "position": 3, "auto": 4, "acro": 5, "offboard": 6,
              "stabilized": 7}  # fmt: skip
AUTO_SUB_MODES = {"loiter": 3, "land": 6}
OFFBOARD = MAIN_MODES["offboard"]
POSITION = MAIN_MODES["position"]
# where the bridge hands the vehicle back: name -> (main mode, sub mode)
HANDBACK_MODES = {"position": (POSITION, 0), "hold": (4, AUTO_SUB_MODES["loiter"]),
                  "land": (4, AUTO_SUB_MODES["land"])}  # fmt: skip
AUTOPILOT_COMPONENT = mavlink.MAV_COMP_ID_AUTOPILOT1
# The load's motion capture, a second ODOMETRY source: visual-inertial odometry's id, any free one
LOAD_COMPONENT = mavlink.MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY
# SET_ATTITUDE_TARGET: ignore the attitude, use the three body rates and the thrust
RATES_AND_THRUST = mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
FORCE_DISARM = 21196.0  # param2 of MAV_CMD_COMPONENT_ARM_DISARM that disarms in flight
HOVER_PARAMETER = "MPC_THR_HOVER"
OF_LOSS_PARAMETER = "COM_OF_LOSS_T"


def connect(url: str, *, system: int, component: int, timeout: float = 0.0):
    """A pymavlink connection: ``udpin:HOST:PORT`` (listen, as a companion computer does for
    PX4's offboard link), ``udpout:HOST:PORT`` (send), ``tcp:HOST:PORT``, or a serial device
    (``/dev/ttyUSB0,921600``: device and baud rate); ``udp:`` is pymavlink's ``udpin:``."""
    device, _, baud = url.partition(",")
    return mavutil.mavlink_connection(
        device, baud=int(baud or 57600), source_system=system, source_component=component,
        dialect=DIALECT, udp_timeout=timeout,
    )  # fmt: skip


def custom_mode(main: int, sub: int = 0) -> int:
    """PX4's HEARTBEAT ``custom_mode`` of a main and sub mode."""
    return (main << 16) | (sub << 24)


def main_mode(custom: int) -> int:
    """The main mode of a PX4 ``custom_mode``."""
    return (int(custom) >> 16) & 0xFF


def mode_name(main: int) -> str:
    return next((name for name, m in MAIN_MODES.items() if m == main), f"mode {main}")


@dataclass(frozen=True)
class ThrustMap:
    """Collective thrust in N <-> PX4's normalised thrust set-point in [0, 1], linear:
    ``T = throttle * newtons_per_throttle`` (``slungload import``'s map, docs/import.md)."""

    newtons_per_throttle: float  # N at full throttle

    def __post_init__(self) -> None:
        if not (math.isfinite(self.newtons_per_throttle) and self.newtons_per_throttle > 0):
            raise ValueError(f"newtons per throttle must be > 0 N, got {self.newtons_per_throttle}")

    @classmethod
    def from_hover(cls, hover_throttle: float, params: VehicleParams) -> ThrustMap:
        """The map whose ``hover_throttle`` (PX4's MPC_THR_HOVER) holds (mQ + mL) g."""
        if not 0.0 < hover_throttle <= 1.0:
            raise ValueError(f"hover throttle must be in (0, 1], got {hover_throttle}")
        return cls((params.mass_quad + params.mass_load) * params.gravity / hover_throttle)

    def throttle(self, thrust: float) -> float:
        """N -> normalised thrust, clipped to [0, 1]."""
        return min(max(thrust / self.newtons_per_throttle, 0.0), 1.0)

    def newtons(self, throttle: float) -> float:
        return throttle * self.newtons_per_throttle


# --- state: PX4's NED / FRD -> the package's frames ------------------------------------------


def odometry_pose(msg) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(p (3,) m, v (3,) m/s world z up, q w-x-y-z FLU -> z up) of an ODOMETRY message, or
    None when its frames are not ones this reads (pose in LOCAL_NED; velocity in BODY_FRD,
    as PX4 sends it, or LOCAL_NED)."""
    if msg.frame_id != mavlink.MAV_FRAME_LOCAL_NED:
        return None
    q_ned_frd = np.array(msg.q, dtype=float)
    v = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
    if msg.child_frame_id == mavlink.MAV_FRAME_BODY_FRD:
        v = frames.rotate(q_ned_frd, v)  # body FRD -> NED
    elif msg.child_frame_id != mavlink.MAV_FRAME_LOCAL_NED:
        return None
    p = frames.world_vectors([msg.x, msg.y, msg.z], "ned")
    return p, frames.world_vectors(v, "ned"), frames.attitudes(q_ned_frd, "ned", "frd")


def odometry_position(msg) -> np.ndarray | None:
    """The position (3,) m, world z up, of an ODOMETRY message in LOCAL_NED (a motion-capture
    body such as the load), else None."""
    if msg.frame_id != mavlink.MAV_FRAME_LOCAL_NED:
        return None
    return frames.world_vectors([msg.x, msg.y, msg.z], "ned")


def odometry_message(time_usec: int, p, v, q, rates):
    """ODOMETRY as PX4 sends it, from the package's p, v (3,) world z up, q (4,) w-x-y-z
    FLU -> z up and body rates (3,) FLU: pose in LOCAL_NED, velocity and rates in BODY_FRD,
    covariances unknown (NaN first, as the message defines)."""
    q_ned_frd = frames.attitudes_to(q, "ned", "frd")
    v_frd = frames.rotate(frames.quat_conjugate(q_ned_frd), frames.world_vectors(v, "ned"))
    w = frames.body_vectors(rates, "frd")
    p_ned = frames.world_vectors(p, "ned")
    unknown = [math.nan] + [0.0] * 20
    return mavlink.MAVLink_odometry_message(
        int(time_usec), mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
        *map(float, p_ned), [float(c) for c in q_ned_frd], *map(float, v_frd), *map(float, w),
        unknown, unknown, 0, mavlink.MAV_ESTIMATOR_TYPE_MOCAP, 100,
    )  # fmt: skip


# --- the set-point: body rates (FRD) and normalised thrust ------------------------------------


def attitude_target(time_boot_ms: int, system: int, throttle: float, rates_flu):
    """SET_ATTITUDE_TARGET for PX4's offboard rate control: attitude ignored, body rates
    (3,) rad/s given in FLU (sent FRD), normalised thrust in [0, 1]."""
    w = frames.body_vectors(rates_flu, "frd")
    return mavlink.MAVLink_set_attitude_target_message(
        int(time_boot_ms) & 0xFFFFFFFF, system, AUTOPILOT_COMPONENT, RATES_AND_THRUST,
        [1.0, 0.0, 0.0, 0.0], float(w[0]), float(w[1]), float(w[2]), float(throttle),
    )  # fmt: skip


def rates_and_thrust(msg) -> tuple[float, np.ndarray] | None:
    """(throttle, body rates (3,) rad/s FLU) of a SET_ATTITUDE_TARGET that commands rates and
    thrust (attitude ignored, rates and thrust not), else None."""
    ignored = msg.type_mask
    if not ignored & RATES_AND_THRUST or ignored & 0b1000111:  # rates x y z, thrust
        return None
    rates = frames.body_vectors([msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate], "frd")
    return float(msg.thrust), rates
