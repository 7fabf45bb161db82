"""The MPC flying a PX4 vehicle over MAVLink: state in, body rates and thrust out.

    result = fly("ps.mpc.npz", BridgeConfig(connection="udpin:0.0.0.0:14540", offboard=True))

``Bridge.run`` connects (pymavlink), waits for the autopilot's heartbeat, takes the thrust map
(the config's, else the autopilot's ``MPC_THR_HOVER``) and then, at every new vehicle state
(ODOMETRY, or LOCAL_POSITION_NED + ATTITUDE_QUATERNION, from the autopilot; the bridge asks
PX4 for ODOMETRY every control period), in phases:

1. **waiting**: streams hover set-points (PX4 accepts OFFBOARD only over a live stream), and
   with ``arm`` / ``offboard`` asks for them after ``stream_before_switch`` s; otherwise
   waits for the pilot's switch. Shadow mode (``dry_run``) starts flying at once and sends
   nothing at all.
2. **flying**: once the heartbeat says armed and OFFBOARD, a fresh ``MPPIController`` flies
   the reference (``reference.flight_reference``: from where OFFBOARD started) one step per
   state, each command sent as SET_ATTITUDE_TARGET (rates FRD, thrust through the map). A
   safety fault (``safety.check_state``, the MPC's own hover fallback, a non-finite command)
   switches to
3. **hover**: hover thrust, rates that level the vehicle (zero when the attitude is stale),
   for ``hover_time`` s; then the bridge **hands back** (DO_SET_MODE to position mode, or
   ``handback``) and stops sending, so PX4's offboard-loss failsafe acts even if it refuses.

The autopilot leaving OFFBOARD (its heartbeat) ends the flight at once: nothing more is sent.
The end of the reference hands back too. Every message in and out goes to the .tlog, stamped
on the autopilot's clock (its messages' own time, offset to the epoch: a lockstep simulation's
log is in simulated time). numpy, onnxruntime and pymavlink only: no torch.
"""

from __future__ import annotations

import gc
import math
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import frames
from ..config import VehicleParams
from ..control.mppi import (
    CandidateModel,
    InputLimits,
    MPPIController,
    check_members,
    yaw_of,
)
from ..control.split import SPLIT, SplitMembers
from ..evaluation.verdicts import note
from ..layout import LOAD_POS, POS, QUAT, STATE_DIM, VEL
from . import px4
from .config import BridgeConfig
from .reference import flight_reference
from .result import BridgeResult
from .safety import check_state
from .tlog import TlogWriter

mavlink = px4.mavlink
MODE_ANSWER_WAIT = 0.3  # s without waiting set-points while a mode command awaits its answer
# the user's own source of the load's position (e.g. a ROS 2 subscriber): None, or
# (position (3,) m world z up, age s)
LoadSource = Callable[[], "tuple[np.ndarray, float] | None"]


class Bridge:
    """One flight of the MPC over ``model`` (a ``CandidateModel``; ``params``: the vehicle
    constants it was made for) through a MAVLink link; see the module."""

    def __init__(
        self,
        config: BridgeConfig,
        model: CandidateModel,
        params: VehicleParams,
        *,
        load_source: LoadSource | None = None,
        clock: Callable[[], float] = time.monotonic,
        log: Callable[[str], None] | None = None,
    ) -> None:
        self.cfg = cfg = config
        self.model, self.params = model, params
        self.load_source = load_source
        self.clock = clock
        self.say = log or (lambda line: None)
        n = getattr(model, "horizon", None) or cfg.mpc.horizon  # a compiled file's: any N
        # the MPC's noise seeded by the flight's seed, as `slungload control` seeds a flight
        self.mpc_cfg = replace(cfg.mpc, horizon=n, knots=min(cfg.mpc.knots, n), seed=cfg.seed)
        self.hover_thrust = (params.mass_quad + params.mass_load) * params.gravity
        self.result = BridgeResult(end="")
        self.phase = "connecting"
        # the latest measurements: package frames, the bridge's clock, the autopilot's clock
        self.vehicle: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.vehicle_at = self.load_at = self.attitude_at = -math.inf
        self.vehicle_time = 0.0  # s, the autopilot's time of the latest state
        self.stepped_time = -math.inf  # s, the autopilot's time of the state last acted on
        self.load: np.ndarray | None = None
        self.local: tuple[np.ndarray, np.ndarray, float] | None = None  # LOCAL_POSITION_NED
        self.attitude: np.ndarray | None = None  # ATTITUDE_QUATERNION, package frames
        self.mode, self.armed = -1, False
        self.hover_param: float | None = None
        self.acks: dict[int, int] = {}
        self.asked_mode: int | None = None  # the main mode of the DO_SET_MODE awaiting its ACK
        self.quiet_until = -math.inf  # no waiting set-point before this (an answer is due)
        self.epoch: float | None = None  # s: the autopilot's time 0 on the Unix clock
        self.tlog = TlogWriter(cfg.tlog) if cfg.tlog else None

    # --- the loop -------------------------------------------------------------------------
    def run(self) -> BridgeResult:
        cfg = self.cfg
        restore = real_time(cfg.fifo_priority)
        try:
            self.conn = px4.connect(cfg.connection, system=cfg.target_system,
                                    component=cfg.component)  # fmt: skip
            try:
                self._connect()
                self.mpc = self._controller()
                # a full collection of the ~130,000 objects loaded by now takes 30-90 ms, a
                # missed period; none fell due in 15 s flights, and should a long one bring
                # one, what is alive now is left out of it
                gc.collect()
                gc.freeze()
                self.phase = "flying" if cfg.dry_run else "waiting"
                self.wait_start = self.next_tick = self.clock()
                self.next_heartbeat = self.next_request = 0.0
                while self.phase != "done":
                    self._cycle()
            finally:
                gc.unfreeze()
                if self.tlog:
                    self.tlog.close()
                self.conn.close()
        finally:
            restore()
        self.result.mpc = self.mpc.stats
        return self.result

    def _cycle(self) -> None:
        """Messages until a new state or the next tick (a period without one), then a step."""
        wait = max(self.next_tick - self.clock(), 0.0)
        msg = self.conn.recv_match(blocking=True, timeout=wait)
        while msg is not None:
            self._handle(msg)
            if self.phase == "done":
                return
            msg = self.conn.recv_match(blocking=False)
        now = self.clock()
        # a state newer than the last acted on by about a period: PX4's stream (asked for at
        # the period) or a lockstep simulator paces the steps; without one for
        # ``max_state_age`` the tick comes anyway (the state is stale then)
        fresh = self.vehicle is not None and (
            self.vehicle_time >= self.stepped_time + 0.5 * self.cfg.period
        )
        if fresh or now >= self.next_tick:
            self.next_tick = now + self.cfg.max_state_age
            if fresh:
                self.stepped_time = self.vehicle_time
            self._tick(now, fresh)

    def _tick(self, now: float, fresh: bool) -> None:
        cfg = self.cfg
        if not cfg.dry_run and now >= self.next_heartbeat:
            self.next_heartbeat = now + 1.0
            self._send(mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                mavlink.MAV_STATE_ACTIVE, 3))  # fmt: skip
        if self.phase == "waiting":
            self._wait_for_offboard(now)
        elif self.phase == "flying":
            self._fly(now, fresh)
        elif self.phase == "hover":
            self._send_hover(now)
            if now - self.hover_start >= cfg.hover_time:
                self._hand_back(f"handed back: {self.fault}")

    def _wait_for_offboard(self, now: float) -> None:
        cfg = self.cfg
        if self.mode == px4.OFFBOARD and self.armed:
            self.say("OFFBOARD and armed: the MPC flies")
            # the MPC built before the wait has only given hover commands, which change
            # nothing in it: its first step is the flight's (building one here, 30 ms,
            # would make the first period late)
            self.phase = "flying"
            self._fly(now, self.vehicle is not None)
            return
        if now - self.wait_start > cfg.wait_offboard:
            self._end("no OFFBOARD")
            return
        if self.vehicle is not None and now >= self.quiet_until:
            self._send_hover(now)  # the stream PX4 needs before it accepts OFFBOARD
        streamed = now - self.wait_start >= cfg.stream_before_switch
        if streamed and now >= self.next_request and self.vehicle is not None:
            self.next_request = now + 1.0
            if cfg.arm and not self.armed:
                self.say("asking to arm")
                self._command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
            elif cfg.offboard and self.mode != px4.OFFBOARD:
                self.say("asking for OFFBOARD")
                self._set_mode(px4.OFFBOARD, 0)
                # no hover set-point until the answer: the first after an accepted switch is
                # the MPC's (a pause well inside PX4's 2 Hz stream rule)
                self.quiet_until = now + MODE_ANSWER_WAIT

    def _fly(self, now: float, fresh: bool) -> None:
        cfg = self.cfg
        if self.vehicle is None:
            return
        state = self._state()
        if not hasattr(self, "reference"):
            if cfg.origin is not None:
                self.origin, self.yaw0 = np.array(cfg.origin[:3], float), float(cfg.origin[3])
            else:
                self.origin = state[POS].copy()
                yaw = float(yaw_of(state[QUAT]))
                self.yaw0 = yaw if math.isfinite(yaw) else 0.0
            self.reference = flight_reference(self.origin, self.yaw0, cfg.period, cfg.maneuver,
                                              cfg.seed, cfg.duration, cfg.settle,
                                              cfg.box)  # fmt: skip
            self.flight_steps = len(self.reference.yaw)
        fault = check_state(
            state, now - self.vehicle_at, now - self.load_at, self.origin, cfg
        )  # fmt: skip
        if fault is not None:
            self._start_hover(now, fault)
            return
        if not fresh:  # no new state yet: hold the stream with the last set-point
            self._send_setpoint(*self.last_setpoint)
            return
        k = self.result.steps
        hovered = self.mpc.stats.hover_steps
        command = self.mpc.step(state, self.mpc.ahead(self.reference, k))
        self.result.steps += 1
        self.result.states.append(state)
        self.result.commands.append(np.array([command.thrust, *command.rates]))
        self._send_setpoint(command.thrust, command.rates)
        self.result.latency.append(self.clock() - self.vehicle_at)
        if self.mpc.stats.hover_steps > hovered:
            self._start_hover(now, "mpc fallback")
        elif self.result.steps >= self.flight_steps:
            self._hand_back("flight complete")

    # --- safety: hover, hand back -------------------------------------------------------------
    def _start_hover(self, now: float, fault: str) -> None:
        self.result.safety.add(now, fault)
        self.say(f"safety: {fault}: hover for {self.cfg.hover_time:g} s, then hand back")
        if self.cfg.dry_run:  # shadow mode flies nothing: the event is only logged
            return
        self.fault, self.hover_start, self.phase = fault, now, "hover"
        self._send_hover(now)

    def _send_hover(self, now: float) -> None:
        """Hover thrust, and rates that level the vehicle at its heading (zero rates when the
        attitude is stale: levelling on an old attitude could tilt it)."""
        fresh = now - self.attitude_at <= self.cfg.max_state_age and self.vehicle is not None
        rotation = frames.rotation_matrix(self.vehicle[2]) if fresh else np.full((3, 3), np.nan)
        yaw = getattr(self, "yaw0", None)
        if yaw is None:
            yaw = float(yaw_of(self.vehicle[2])) if fresh else 0.0
        u = self.mpc.hover_command(rotation, yaw if math.isfinite(yaw) else 0.0)[0]
        self._send_setpoint(u[0], u[1:])

    def _hand_back(self, reason: str) -> None:
        """Ask for the hand-back mode and stop sending set-points."""
        if not self.cfg.dry_run:
            main, sub = px4.HANDBACK_MODES[self.cfg.handback]
            self._set_mode(main, sub)
            self.say(f"{reason}: asked for {self.cfg.handback} mode; set-points stopped")
        self._end(reason)

    def _end(self, reason: str) -> None:
        self.result.end, self.phase = reason, "done"

    # --- messages in ------------------------------------------------------------------------
    def _handle(self, msg) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA" or kind.startswith("UNKNOWN"):
            self.result.ignored[kind if kind == "BAD_DATA" else "UNKNOWN"] += 1
            return
        now = self.clock()
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        autopilot = source == (self.cfg.target_system, px4.AUTOPILOT_COMPONENT)
        load = source == (self.cfg.load_system, self.cfg.load_component)
        if kind == "ODOMETRY" and load:
            p = px4.odometry_position(msg)
            if p is not None:
                self.load, self.load_at = p, now
        elif autopilot:
            self._autopilot_message(kind, msg, now)
        self._log(msg)

    def _autopilot_message(self, kind: str, msg, now: float) -> None:
        if kind == "HEARTBEAT" and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID:
            self.mode = px4.main_mode(msg.custom_mode)
            self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            if self.phase in ("flying", "hover") and self.mode != px4.OFFBOARD:
                if not self.cfg.dry_run:  # the pilot (or a failsafe) took over: stop at once
                    self.say(f"the autopilot left OFFBOARD ({px4.mode_name(self.mode)})")
                    self._end("left offboard")
        elif kind == "ODOMETRY":
            pose = px4.odometry_pose(msg)
            if pose is not None:
                self.attitude_at = now  # ODOMETRY carries its own attitude
                self._new_vehicle(pose, msg.time_usec * 1e-6, now)
        elif kind == "LOCAL_POSITION_NED":
            p = frames.world_vectors([msg.x, msg.y, msg.z], "ned")
            v = frames.world_vectors([msg.vx, msg.vy, msg.vz], "ned")
            if self.attitude is not None and now - self.attitude_at <= self.cfg.max_state_age:
                self._new_vehicle((p, v, self.attitude), msg.time_boot_ms * 1e-3, now)
        elif kind == "ATTITUDE_QUATERNION":
            q = [msg.q1, msg.q2, msg.q3, msg.q4]
            self.attitude, self.attitude_at = frames.attitudes(q, "ned", "frd"), now
        elif kind == "PARAM_VALUE" and msg.param_id == px4.HOVER_PARAMETER:
            self.hover_param = float(msg.param_value)
        elif kind == "COMMAND_ACK":
            self.acks[msg.command] = msg.result
            if msg.command == mavlink.MAV_CMD_DO_SET_MODE and self.asked_mode is not None:
                # PX4 acknowledges a mode command once it has switched: fly at once, not at
                # the next heartbeat (which confirms it; one saying otherwise ends the flight)
                if msg.result == mavlink.MAV_RESULT_ACCEPTED and self.phase == "waiting":
                    self.mode, self.next_tick = self.asked_mode, now
                self.asked_mode, self.quiet_until = None, -math.inf

    def _new_vehicle(self, pose, autopilot_time: float, now: float) -> None:
        self.vehicle, self.vehicle_at, self.vehicle_time = pose, now, autopilot_time
        if self.epoch is None:
            self.epoch = time.time() - autopilot_time

    def _state(self) -> np.ndarray:
        """The state (13,) in the package's layout from the latest measurements (NaN load
        position before the first one)."""
        if self.load_source is not None:
            got = self.load_source()
            if got is not None:
                self.load, self.load_at = np.asarray(got[0], float), self.clock() - got[1]
        x = np.empty(STATE_DIM)
        p, v, q = self.vehicle
        x[POS], x[VEL], x[QUAT] = p, v, q
        x[LOAD_POS] = self.load if self.load is not None else np.nan
        return x

    # --- messages out -----------------------------------------------------------------------
    def _send_setpoint(self, thrust: float, rates) -> None:
        """SET_ATTITUDE_TARGET of ``thrust`` N and ``rates`` (3,) rad/s FLU; a non-finite value
        never reaches the wire (hover thrust, zero rates instead; counted)."""
        rates = np.asarray(rates, dtype=float)
        if not (math.isfinite(thrust) and np.isfinite(rates).all()):
            self.result.safety.add(self.clock(), "non-finite command")
            thrust, rates = self.hover_thrust, np.zeros(3)
        self.last_setpoint = (thrust, rates)
        throttle = self.thrust_map.throttle(thrust)
        ms = int(self.vehicle_time * 1e3)  # the autopilot's time of the state it answers
        msg = px4.attitude_target(ms, self.cfg.target_system, throttle, rates)
        if not self.cfg.dry_run:
            self._send(msg)
            self.result.sent += 1

    def _set_mode(self, main: int, sub: int) -> None:
        self.asked_mode = main
        flag = float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
        self._command(mavlink.MAV_CMD_DO_SET_MODE, flag, float(main), float(sub))

    def _command(self, command: int, *params: float) -> None:
        p = [*params, *[0.0] * (7 - len(params))]
        self._send(mavlink.MAVLink_command_long_message(
            self.cfg.target_system, px4.AUTOPILOT_COMPONENT, command, 0, *p))  # fmt: skip

    def _send(self, msg) -> None:
        self.conn.mav.send(msg)
        self._log(msg)

    def _log(self, msg) -> None:
        if self.tlog is not None:
            epoch = self.epoch if self.epoch is not None else time.time() - self.vehicle_time
            self.tlog.write(msg, round((epoch + self.vehicle_time) * 1e6))

    # --- start --------------------------------------------------------------------------------
    def _connect(self) -> None:
        """The autopilot's heartbeat, the thrust map and the ODOMETRY stream at the period."""
        cfg = self.cfg
        deadline = self.clock() + cfg.connect_timeout
        while self.mode < 0:
            msg = self.conn.recv_match(blocking=True, timeout=max(deadline - self.clock(), 0))
            if msg is None:
                raise TimeoutError(
                    f"no heartbeat from system {cfg.target_system} on {cfg.connection} in "
                    f"{cfg.connect_timeout:g} s"
                )
            self._handle(msg)
        if not cfg.dry_run:
            self._command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                          float(mavlink.MAVLINK_MSG_ID_ODOMETRY), cfg.period * 1e6)  # fmt: skip
        hover = px4.HOVER_PARAMETER.encode()
        self._send(mavlink.MAVLink_param_request_read_message(
            cfg.target_system, px4.AUTOPILOT_COMPONENT, hover, -1))  # fmt: skip
        if cfg.newtons_per_throttle is None and cfg.hover_throttle is None:
            while self.hover_param is None and self.clock() < deadline:
                msg = self.conn.recv_match(blocking=True, timeout=0.1)
                if msg is not None:
                    self._handle(msg)
        self.thrust_map = self._thrust_map()
        self.say(f"thrust map: {self.thrust_map.newtons_per_throttle:.3f} N per unit throttle")

    def _thrust_map(self) -> px4.ThrustMap:
        cfg = self.cfg
        if cfg.newtons_per_throttle is not None:
            return px4.ThrustMap(cfg.newtons_per_throttle)
        hover = cfg.hover_throttle if cfg.hover_throttle is not None else self.hover_param
        if hover is None:
            raise ValueError(
                f"no thrust map: give the hover throttle or the newtons per throttle (the "
                f"autopilot did not answer for {px4.HOVER_PARAMETER})"
            )
        return px4.ThrustMap.from_hover(hover, self.params)

    def _controller(self) -> MPPIController:
        """A fresh MPC (its history starts at the next state) in the vehicle's box."""
        cfg, hover = self.cfg, self.hover_thrust
        top = cfg.max_throttle * self.thrust_map.newtons_per_throttle
        limits = InputLimits(cfg.min_thrust_share * hover, top, cfg.rate_max)
        return MPPIController(self.model, limits, self.mpc_cfg, self.params)


def real_time(priority: int | None) -> Callable[[], None]:
    """Put the calling thread under the real-time FIFO scheduler at ``priority`` (None: leave
    it); returns what puts the scheduler it had back. Beside other work on the same cores the
    normal scheduler lets periods run late (docs/BENCHMARKS.md, the MPC over MAVLink)."""
    if priority is None:
        return lambda: None
    if not hasattr(os, "sched_setscheduler"):
        raise ValueError("a FIFO priority needs Linux's real-time scheduler, which this OS "
                         "lacks; leave --fifo-priority out")  # fmt: skip
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        raise ValueError(f"the OS refused the real-time FIFO scheduler at priority {priority}: "
                         "run as root or give python CAP_SYS_NICE (setcap cap_sys_nice+ep), "
                         "or leave --fifo-priority out") from None  # fmt: skip
    return lambda: os.sched_setscheduler(0, *before)


def fly(
    model: str | Path,
    config: BridgeConfig,
    *,
    load_source: LoadSource | None = None,
    threads: int = 1,
    log: Callable[[str], None] | None = None,
) -> BridgeResult:
    """Fly the MPC over an exported model (``slungload export --for-mpc``: ``.mpc.npz`` or
    ``.mpc.onnx`` and its sidecar, which gives the vehicle constants) through the bridge; see
    the module."""
    from ..deploy.backends import load_exported

    exported = load_exported(model, threads=threads)
    horizon = exported.horizon or config.mpc.horizon  # a compiled file flies the MPC's N
    warning = note((exported.meta or {}).get("preflight") or {}, str(model), horizon,
                   paired=config.with_physics, trust_window=config.pair_window)  # fmt: skip
    if warning:
        warnings.warn(warning, stacklevel=2)
    flown = exported
    if config.with_physics:  # the physics model of the file's constants beside it
        from ..control.paired import PhysicsPaired
        from ..deploy.compiled.columns import PhysicsColumns
        from ..vehicle_constants import VehicleConstants

        physics = PhysicsColumns(VehicleConstants.of(exported.params), params=exported.params)
        flown = PhysicsPaired(exported, physics, config.pair_window)
    check_members(flown, config.mpc.risk)  # before any link is opened
    if config.mpc.members == SPLIT:
        SplitMembers(flown, config.mpc.samples)  # refuses, naming why, before any link too
    return Bridge(config, flown, exported.params, load_source=load_source, log=log).run()
