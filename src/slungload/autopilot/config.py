"""What ``slungload fly`` does, one frozen record in SI units: the link, the thrust map, the
MPC's box, the reference, the handshake, the safety limits and the log. Every default and
every ``fly`` option's help is read from here. Light: no pymavlink, no onnxruntime."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path

from ..control.mppi import MPCConfig
from ..control.paired import TRUST_WINDOW, trust_steps
from ..sim.maneuvers import ARENA_BOX

HANDBACK = ("position", "hold", "land")  # px4.HANDBACK_MODES


def _option(default, help: str):  # noqa: A002
    """A field with its default and its ``--option`` help (``option_help``)."""
    return field(default=default, metadata={"help": help})


@dataclass(frozen=True)
class BridgeConfig:
    """The bridge between PX4 and the MPC (``bridge.Bridge``); docs/deployment.md."""

    # the link: PX4 SITL's offboard link sends to 14540, where a companion listens
    connection: str = _option(
        "udpin:0.0.0.0:14540",
        "pymavlink connection: udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, or a serial "
        "device DEVICE,BAUD",
    )
    target_system: int = _option(1, "the autopilot's MAVLink system id")
    component: int = _option(191, "this computer's MAVLink component id (191: onboard computer)")
    load_system: int = _option(1, "system id of the load's ODOMETRY (its motion capture)")
    load_component: int = _option(197, "component id of the load's ODOMETRY")
    period: float = _option(0.03, "control period, s (the model's data step)")
    # the thrust map (as `slungload import`): neither given -> the autopilot's MPC_THR_HOVER
    hover_throttle: float | None = _option(
        None,
        "throttle that holds the vehicle with its load (PX4's MPC_THR_HOVER; default: read from "
        "the autopilot)",
    )
    newtons_per_throttle: float | None = _option(
        None, "thrust per unit throttle, N, instead of the hover throttle"
    )
    # the MPC's box
    min_thrust_share: float = _option(0.3, "lowest thrust, share of hover thrust")
    max_throttle: float = _option(1.0, "highest normalised thrust")
    rate_max: float = _option(4.0, "body-rate limit, rad/s, each axis")
    mpc: MPCConfig = field(default_factory=MPCConfig)  # K, weights (N from the model file)
    with_physics: bool = _option(
        False,
        "price each plan under the model and under the physics model (the file's constants): "
        "their mean cost + --risk x their spread, each weighted by how well it predicted the "
        "steps just flown (control.paired; docs/control.md)",
    )
    trust_window: int | None = _option(
        None,
        "with --with-physics: steps just flown the model must predict at least as well as "
        f"physics to take part (0: always; default {TRUST_WINDOW}; control.paired)",
    )
    # the reference: a maneuver's offsets from where OFFBOARD starts (None: hold that point)
    maneuver: str | None = _option(
        None,
        "maneuver to fly from --origin or where OFFBOARD starts (slungload maneuvers; "
        "default: hold that point)",
    )
    seed: int = _option(0, "the maneuver's draw and the MPC's noise (as `control` seeds a flight)")
    duration: float | None = _option(
        None,
        "s of the maneuver (or of holding) after --settle, then hand back (default: the "
        "maneuver's length, or 10 s holding)",
    )
    settle: float = _option(
        0.0, "s holding the start before the maneuver (control flies the simulator's warm-up: 1 s)"
    )
    origin: tuple[float, float, float, float] | None = _option(
        None,
        "X,Y,Z,YAW: fly from this point, m in the package's world frame (z up), and heading, "
        "rad (default: where OFFBOARD started, at the vehicle's heading)",
    )
    box: tuple[float, float, float, float, float, float] | None = _option(
        None,
        "X0,Y0,Z0,X1,Y1,Z1: the flying volume, m (world frame, z up): the maneuver's positions "
        "are kept inside it (default: none; the simulator's arena: "
        + ",".join(f"{v:g}" for v in ARENA_BOX)
        + ")",
    )
    # the handshake
    arm: bool = _option(False, "arm the vehicle (else the pilot does)")
    offboard: bool = _option(
        False, "switch to OFFBOARD after streaming set-points (else wait for the pilot)"
    )
    stream_before_switch: float = _option(
        1.0, "s of set-points streamed before asking for OFFBOARD (PX4 needs a stream)"
    )
    wait_offboard: float = _option(math.inf, "s to wait for OFFBOARD before giving up")
    dry_run: bool = _option(False, "shadow mode: compute and log commands, send nothing")
    # safety
    max_state_age: float = _option(0.1, "oldest vehicle state flown on, s")
    max_load_age: float = _option(0.1, "oldest load position, s")
    max_tilt: float = _option(1.0, "attitude limit, rad from level")
    fence_radius: float = _option(5.0, "geofence: horizontal distance from the OFFBOARD start, m")
    fence_height: float = _option(3.0, "geofence: height above or below the OFFBOARD start, m")
    hover_time: float = _option(2.0, "s of hover after a safety event, then hand back")
    handback: str = _option(
        "position", "mode to hand back to: position, hold (AUTO.LOITER) or land (AUTO.LAND)"
    )
    # the OS: a loop that must answer every period, beside whatever else the computer runs
    fifo_priority: int | None = _option(
        None,
        "run the control loop under Linux's real-time FIFO scheduler at this priority, 1-99 "
        "(root or CAP_SYS_NICE; default: the normal scheduler)",
    )
    # the log
    tlog: Path | None = _option(None, "MAVLink telemetry log to write (.tlog)")
    connect_timeout: float = _option(10.0, "s to wait for the autopilot's heartbeat")

    @property
    def pair_window(self) -> int:
        """The pair's trust window in steps (``control.paired.trust_steps``; 0 without physics)."""
        return trust_steps(self.trust_window, self.with_physics)

    def __post_init__(self) -> None:
        positive = ("period", "max_state_age", "max_load_age", "max_tilt", "fence_radius",
                    "fence_height", "hover_time", "connect_timeout", "rate_max")  # fmt: skip
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.hover_throttle is not None and self.newtons_per_throttle is not None:
            raise ValueError("give the hover throttle or the newtons per throttle, not both")
        if self.hover_throttle is not None and not 0.0 < self.hover_throttle <= 1.0:
            raise ValueError(f"hover throttle must be in (0, 1], got {self.hover_throttle}")
        if self.newtons_per_throttle is not None and not self.newtons_per_throttle > 0:
            raise ValueError(f"newtons per throttle must be > 0 N, got {self.newtons_per_throttle}")
        if not 0.0 <= self.min_thrust_share < 1.0 or not 0.0 < self.max_throttle <= 1.0:
            raise ValueError("min thrust share must be in [0, 1) and max throttle in (0, 1]")
        if self.fifo_priority is not None and not 1 <= self.fifo_priority <= 99:
            raise ValueError(f"FIFO priority must be 1-99, got {self.fifo_priority}")
        if self.handback not in HANDBACK:
            raise ValueError(f"handback must be one of {HANDBACK}, got {self.handback!r}")
        if self.with_physics and self.mpc.risk is None:
            raise ValueError("with_physics prices the plans by the MPC's risk: give --risk")
        trust_steps(self.trust_window, self.with_physics)  # only with physics, >= 0
        if self.duration is not None and not self.duration > 0:
            raise ValueError(f"duration must be > 0 s, got {self.duration}")
        if not self.settle >= 0:
            raise ValueError(f"settle must be >= 0 s, got {self.settle}")
        if self.origin is not None and (
            len(self.origin) != 4 or not all(math.isfinite(float(v)) for v in self.origin)
        ):
            raise ValueError(f"origin needs four finite numbers X,Y,Z,YAW, got {self.origin}")
        if self.box is not None and (
            len(self.box) != 6
            or not all(lo < hi for lo, hi in zip(self.box[:3], self.box[3:], strict=True))
        ):
            raise ValueError(f"box needs X0,Y0,Z0,X1,Y1,Z1 with each low below its high, got "
                             f"{self.box}")  # fmt: skip


@dataclass(frozen=True)
class SilConfig:
    """The simulated PX4 behind a MAVLink endpoint (``sil.SilEndpoint``, ``slungload sil``)."""

    plant: str = _option("default", "the simulated vehicle (sim.plants)")
    seed: int = _option(
        0,
        "the flight's draws (plant imperfections, wind, sensor noise), as a simulated flight of "
        "this seed",
    )
    maneuver: str | None = _option(
        None,
        "draw the wind over this maneuver's flight of --seed as `slungload control` draws it "
        "(default: a 10-minute draw); with --start-on-offboard the flight control flies",
    )
    steps: int | None = _option(
        None, "recorded steps of that flight, as control's --steps (default: the maneuver's)"
    )
    start_on_offboard: bool = _option(
        False,
        "the simulated clock stands, the vehicle in its start state, until OFFBOARD is first "
        "taken (a flight that starts as control's does)",
    )
    effects: bool = _option(True, "the simulator's unmodelled effects on (wind, noise, lags)")
    connection: str = _option(
        "udpout:127.0.0.1:14540",
        "where the autopilot's MAVLink goes (PX4 SITL: the companion's port 14540)",
    )
    system: int = _option(1, "the autopilot's system id")
    load_component: int = _option(197, "component id of the load's ODOMETRY (its motion capture)")
    lockstep: bool = _option(True, "advance one control period per set-point (CI); else real time")
    lockstep_wait: float = _option(
        0.25, "s (wall) a lockstep period waits for a set-point before it runs without"
    )
    hover_throttle: float = _option(
        0.5, "MPC_THR_HOVER: the throttle that holds the vehicle with its load"
    )
    of_loss_timeout: float = _option(
        1.0, "COM_OF_LOSS_T: s without set-points before the offboard-loss failsafe"
    )
    stream_timeout: float = _option(
        0.5, "s: OFFBOARD is accepted only over set-points at more than 1/this Hz"
    )
    heartbeat_period: float = _option(1.0, "s between heartbeats")
    duration: float = _option(math.inf, "s of simulated time to run")
    # faults, for tests: spans (s, simulated) without the vehicle's or the load's ODOMETRY,
    # a share of telemetry messages dropped, and each one delayed by a uniform draw in [0,
    # jitter] s of wall clock (so that they may also arrive out of order)
    state_gap: tuple[float, float] | None = None
    load_gap: tuple[float, float] | None = None
    drop: float = 0.0
    jitter: float = 0.0

    def __post_init__(self) -> None:
        for name in ("lockstep_wait", "of_loss_timeout", "stream_timeout", "heartbeat_period"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 < self.hover_throttle <= 1.0:
            raise ValueError(f"hover throttle must be in (0, 1], got {self.hover_throttle}")
        if not 0.0 <= self.drop < 1.0:
            raise ValueError(f"drop must be in [0, 1), got {self.drop}")
        if not 0.0 <= self.jitter < math.inf:
            raise ValueError(f"jitter must be a finite number of s >= 0, got {self.jitter}")
        if self.steps is not None and self.steps < 1:
            raise ValueError(f"steps must be >= 1, got {self.steps}")


def option_help(config: type, name: str) -> str:
    """The help of ``config``'s field ``name`` (a ``--name`` option), with its default."""
    f = next(f for f in fields(config) if f.name == name)
    default = f.default
    if isinstance(default, bool) or default is None:
        return f.metadata["help"]
    shown = f"{default:g}" if isinstance(default, float) else str(default)
    return f"{f.metadata['help']} (default {shown})"
