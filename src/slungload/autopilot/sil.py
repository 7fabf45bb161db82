"""Software in the loop: the package's MuJoCo simulator behind a MAVLink endpoint that answers
as PX4 does, for the subset the bridge speaks (``slungload sil``).

What it does, and the PX4 documentation each behaviour follows:

- HEARTBEAT every ``heartbeat_period`` s, autopilot ``MAV_AUTOPILOT_PX4``, base mode with
  ``MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`` (and ``SAFETY_ARMED``), PX4's custom mode (main mode
  in bits 16-23; PX4 docs "MAVLink Messaging", PX4 source ``px4_custom_mode.h``).
- COMMAND_LONG ``MAV_CMD_COMPONENT_ARM_DISARM`` and ``MAV_CMD_DO_SET_MODE``, each answered with
  COMMAND_ACK (MAVLink "Command Protocol"). The vehicle starts airborne, armed, in position
  mode (the pilot took off); disarming in flight is denied unless forced (param2 21196, PX4
  docs "Arm, Disarm, Prearm Configuration").
- OFFBOARD is accepted only while set-points stream (one within ``stream_timeout`` s, more than
  2 Hz), else temporarily rejected (PX4 docs "Offboard Mode": "The vehicle must be already be
  receiving a stream of MAVLink setpoint messages ... before arming in offboard mode or
  switching to offboard mode when flying").
- SET_ATTITUDE_TARGET with the attitude ignored: body rates FRD and normalised thrust, applied
  in OFFBOARD through the vehicle's thrust map (``hover_throttle``, PX4's ``MPC_THR_HOVER``);
  other set-points and non-finite values are ignored (counted).
- ODOMETRY of the vehicle from component 1 (pose LOCAL_NED, velocity and rates BODY_FRD, as PX4's
  ODOMETRY stream), and of the load from ``load_component`` (its motion capture), every period.
- The offboard-loss failsafe: no set-point for ``of_loss_timeout`` s (``COM_OF_LOSS_T``) in
  OFFBOARD -> position mode (``COM_OBL_RC_ACT`` = 0, the default; PX4 docs "Offboard Mode"
  and "Safety (Failsafe) Configuration": offboard loss failsafe).
- PARAM_REQUEST_READ of ``MPC_THR_HOVER`` and ``COM_OF_LOSS_T`` -> PARAM_VALUE.

Outside OFFBOARD (position, hold, land, altitude) the simulator's PID holds the point where the
mode began: one hold for all of them (no landing, no altitude-only control). Not simulated:
MAVLink's own parameter protocol beyond these two, mission items, the EKF (the vehicle's
ODOMETRY is the motion capture's, ``sim.sensors.Mocap``), RC.

Time: the simulation's (``t`` s; ODOMETRY's ``time_usec`` is ``BOOT`` + t). With ``lockstep``
the simulation advances one control period per set-point received (or after ``lockstep_wait``
wall s without one: the bridge is late or gone), else at the wall clock's pace. Every rule
above counts in simulated time. With ``start_on_offboard`` the clock stands (the plant in its
start state, the same measurement re-sent, heartbeats on the wall clock) until OFFBOARD is
first taken; with ``maneuver`` the wind is drawn over that flight as ``slungload control``
draws it for the seed: together the bridge flies the flight ``control`` flies
(``BridgeConfig.origin`` and ``settle`` give it the same reference).
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .. import frames
from ..control.mppi import yaw_of
from ..sim.controller import PIDController
from ..sim.flight import flight_setup, vehicle_draws
from ..sim.plants import plant_config
from ..sim.streams import seed_streams
from . import px4
from .config import SilConfig

mavlink = px4.mavlink
BOOT = 10.0  # s: the autopilot's uptime when the simulation starts
WIND_STEPS = 20_000  # control periods of wind drawn (10 min), repeated beyond


@dataclass
class SilLog:
    """What the endpoint saw: set-points (t s, throttle, rates FLU (3,)), modes (t, mode,
    why), the vehicle's and the load's true track (t, p (3,), p_load (3,)), ignored messages."""

    setpoints: list[tuple[float, float, np.ndarray]] = field(default_factory=list)
    modes: list[tuple[float, str, str]] = field(default_factory=list)
    track: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    ignored: Counter = field(default_factory=Counter)
    acks: list[tuple[int, int]] = field(default_factory=list)  # (command, result)
    delayed: int = 0  # telemetry messages held back by ``SilConfig.jitter``


class SilEndpoint:
    """The simulated PX4 (see the module); ``run`` in a thread or process, ``stop`` ends it."""

    def __init__(self, config: SilConfig, log: Callable[[str], None] | None = None) -> None:
        self.cfg = cfg = config
        self.say = log or (lambda line: None)
        sim = plant_config(cfg.plant)
        if not cfg.effects:
            sim = sim.with_effects(type(sim.effects).none())
        if cfg.maneuver is not None:  # the draws of `slungload control`'s flight (sim.flight)
            setup = flight_setup(cfg.maneuver, cfg.seed, sim, cfg.steps)
            self.sim, self.plant, self.wind, self.mocap = (setup.flown, setup.plant, setup.wind,
                                                           setup.mocap)  # fmt: skip
        else:  # a simulated flight's draws for this seed but the maneuver's (sim.flight)
            self.sim, self.plant, self.wind, self.mocap = vehicle_draws(
                seed_streams(cfg.seed), sim, WIND_STEPS
            )
        sim = self.sim
        self.faults = np.random.default_rng(cfg.seed + 1)  # the dropped and delayed packets
        self.delayed: list[tuple[float, object, int | None]] = []  # (wall time due, msg, comp.)
        self.h = sim.control_dt
        self.newtons_per_throttle = sim.total_mass * sim.gravity / cfg.hover_throttle
        self.pid = PIDController(sim)
        self.t, self.k = 0.0, 0
        self.mode, self.armed = px4.POSITION, True
        self.hold = self.start = self.plant.p
        self.hold_yaw = 0.0
        # the clock stands until OFFBOARD is first taken (``start_on_offboard``)
        self.paused = cfg.start_on_offboard
        self.wall_heartbeat = 0.0  # monotonic s of the next heartbeat while paused
        self.measured: tuple[np.ndarray, ...] | None = None  # the period's mocap p, v, q, p_load
        self.setpoint: tuple[float, np.ndarray] | None = None
        self.setpoint_t = -math.inf
        self.next_heartbeat = 0.0
        self.log = SilLog()
        self.stopped = threading.Event()
        # the fault spans, simulated s (a test may move them while it runs)
        self.state_gap, self.load_gap = cfg.state_gap, cfg.load_gap

    # --- the loop -----------------------------------------------------------------------------
    def run(self) -> SilLog:
        """Simulate until ``stop`` or ``duration``; returns what it saw."""
        cfg = self.cfg
        self.conn = px4.connect(cfg.connection, system=cfg.system,
                                component=px4.AUTOPILOT_COMPONENT)  # fmt: skip
        self.wall0 = time.monotonic()
        try:
            while not self.stopped.is_set() and self.t < cfg.duration:
                self._telemetry()
                if self.paused:  # telemetry and heartbeats at the wall clock's pace
                    self._receive(time.monotonic() + self.h, until_setpoint=cfg.lockstep)
                elif cfg.lockstep:
                    self._receive(time.monotonic() + cfg.lockstep_wait, until_setpoint=True)
                else:
                    self._receive(self.wall0 + (self.k + 1) * self.h, until_setpoint=False)
                self._advance()
        finally:
            self.conn.close()
        return self.log

    def stop(self) -> None:
        self.stopped.set()

    def _receive(self, deadline: float, *, until_setpoint: bool) -> None:
        paused = self.paused
        while not self.stopped.is_set():
            if paused and not self.paused:  # the flight starts: its first period, as any other
                paused = False
                lockstep = self.cfg.lockstep
                deadline = (
                    time.monotonic() + self.cfg.lockstep_wait if lockstep else self.wall0 + self.h
                )
            self._flush()
            left = deadline - time.monotonic()
            if left <= 0:
                return
            wait = 0.002 if self.delayed else 0.05  # held-back telemetry falls due meanwhile
            msg = self.conn.recv_match(blocking=True, timeout=min(left, wait))
            if msg is not None and self._handle(msg) and until_setpoint:
                return

    def _advance(self) -> None:
        """One control period: the set-point in OFFBOARD, the hold otherwise (none while the
        clock stands)."""
        if self.paused:
            return
        if self.mode == px4.OFFBOARD and self.t - self.setpoint_t > self.cfg.of_loss_timeout:
            self._set_mode(px4.POSITION, "offboard loss (COM_OF_LOSS_T)")
        if self.mode == px4.OFFBOARD and self.armed and self.setpoint is not None:
            throttle, rates = self.setpoint
            thrust = throttle * self.newtons_per_throttle
        else:
            p, v, q = self.measured[:3]
            thrust, rates = self.pid.command(self.hold, np.zeros(3), np.zeros(3), self.hold_yaw,
                                             p, v, frames.rotation_matrix(q))  # fmt: skip
        self.log.track.append((self.t, self.plant.p, self.plant.p_load))
        self.plant.advance(thrust, rates, self.wind[self.k % len(self.wind)])
        self.k += 1
        self.t = self.k * self.h

    # --- out ------------------------------------------------------------------------------------
    def _telemetry(self) -> None:
        cfg, plant = self.cfg, self.plant
        if not (self.paused and self.measured is not None):  # one measurement per period
            self.measured = self.mocap.measure(plant.p, plant.v, plant.q, plant.p_load)
        p, v, q, p_load = self.measured
        if self.paused:  # the simulated clock stands: heartbeats on the wall clock
            if time.monotonic() >= self.wall_heartbeat:
                self.wall_heartbeat = time.monotonic() + cfg.heartbeat_period
                self._heartbeat()
        elif self.t >= self.next_heartbeat:
            self.next_heartbeat = self.t + cfg.heartbeat_period
            self._heartbeat()
        usec = round((BOOT + self.t) * 1e6)
        # the load's first: a bridge that steps on the vehicle's state has the load's of the
        # same period (a real motion capture keeps no such order: the bridge takes the latest)
        if not _within(self.t, self.load_gap):
            zero = np.zeros(3)
            msg = px4.odometry_message(usec, p_load, zero, np.array([1.0, 0, 0, 0]), zero)
            self._send(msg, lossy=True, component=cfg.load_component)
        if not _within(self.t, self.state_gap):
            self._send(px4.odometry_message(usec, p, v, q, plant.rates), lossy=True)

    def _heartbeat(self) -> None:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0
        sub = {4: px4.AUTO_SUB_MODES["loiter"]}.get(self.mode, 0)
        self._send(mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base,
            px4.custom_mode(self.mode, sub), mavlink.MAV_STATE_ACTIVE, 3))  # fmt: skip

    def _send(self, msg, *, lossy: bool = False, component: int | None = None) -> None:
        if lossy and self.cfg.drop and self.faults.random() < self.cfg.drop:
            return
        if lossy and self.cfg.jitter:
            due = time.monotonic() + self.faults.uniform(0.0, self.cfg.jitter)
            self.delayed.append((due, msg, component))
            self.log.delayed += 1
            return
        self._emit(msg, component)

    def _flush(self) -> None:
        """Send the held-back telemetry that has fallen due, in the order it falls due."""
        now = time.monotonic()
        due = sorted((d for d in self.delayed if d[0] <= now), key=lambda d: d[0])
        if due:
            self.delayed = [d for d in self.delayed if d[0] > now]
            for _, msg, component in due:
                self._emit(msg, component)

    def _emit(self, msg, component: int | None) -> None:
        mav = self.conn.mav
        if component is not None:  # another component of this system (the load's mocap)
            own = mav.srcComponent
            mav.srcComponent = component
            try:
                mav.send(msg)
            finally:
                mav.srcComponent = own
        else:
            mav.send(msg)

    # --- in -------------------------------------------------------------------------------------
    def _handle(self, msg) -> bool:
        """Act on one message; True for a set-point taken."""
        kind = msg.get_type()
        if kind == "BAD_DATA" or kind.startswith("UNKNOWN"):
            self.log.ignored[kind if kind == "BAD_DATA" else "UNKNOWN"] += 1
            return False
        target = getattr(msg, "target_system", self.cfg.system)
        if target not in (0, self.cfg.system):
            return False
        if kind == "SET_ATTITUDE_TARGET":
            return self._setpoint(msg)
        if kind == "COMMAND_LONG":
            self._command(msg)
        elif kind == "PARAM_REQUEST_READ":
            self._param(msg.param_id)
        return False

    def _setpoint(self, msg) -> bool:
        got = px4.rates_and_thrust(msg)
        if got is None:
            self.log.ignored["SET_ATTITUDE_TARGET without rates and thrust"] += 1
            return False
        throttle, rates = got
        if not (math.isfinite(throttle) and np.isfinite(rates).all()):
            self.log.ignored["SET_ATTITUDE_TARGET non-finite"] += 1
            return False
        throttle = min(max(throttle, 0.0), 1.0)
        self.setpoint, self.setpoint_t = (throttle, rates), self.t
        self.log.setpoints.append((self.t, throttle, rates))
        return True

    def _command(self, msg) -> None:
        result = mavlink.MAV_RESULT_UNSUPPORTED
        if msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if msg.param1 == 1.0:
                self.armed, result = True, mavlink.MAV_RESULT_ACCEPTED
            elif msg.param2 == px4.FORCE_DISARM:
                self.armed, result = False, mavlink.MAV_RESULT_ACCEPTED
            else:  # airborne: PX4 disarms in flight only when forced
                result = mavlink.MAV_RESULT_DENIED
        elif msg.command == mavlink.MAV_CMD_DO_SET_MODE:
            result = self._mode_command(int(msg.param2), int(msg.param3))
        elif msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = mavlink.MAV_RESULT_ACCEPTED  # ODOMETRY goes out every period anyway
        self.log.acks.append((msg.command, result))
        self._send(mavlink.MAVLink_command_ack_message(
            msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))  # fmt: skip

    def _mode_command(self, main: int, sub: int) -> int:
        if main == px4.OFFBOARD:
            if self.t - self.setpoint_t > self.cfg.stream_timeout:
                return mavlink.MAV_RESULT_TEMPORARILY_REJECTED  # no set-point stream
            self._set_mode(main, "commanded")
            return mavlink.MAV_RESULT_ACCEPTED
        if main in (px4.POSITION, px4.MAIN_MODES["altitude"]) or (
            main == px4.MAIN_MODES["auto"] and sub in px4.AUTO_SUB_MODES.values()
        ):
            self._set_mode(main, "commanded")
            return mavlink.MAV_RESULT_ACCEPTED
        return mavlink.MAV_RESULT_UNSUPPORTED

    def _set_mode(self, main: int, why: str) -> None:
        if main != px4.OFFBOARD:  # hold where the mode begins
            self.hold, self.pid = self.plant.p, PIDController(self.sim)
            self.hold_yaw = float(yaw_of(self.plant.q))
        elif self.paused:  # the flight starts: the clock runs from here
            self.paused = False
            self.wall0 = time.monotonic()
            self.next_heartbeat = self.t + self.cfg.heartbeat_period
        self.mode = main
        self.log.modes.append((self.t, px4.mode_name(main), why))
        self.say(f"t = {self.t:.2f} s: {px4.mode_name(main)} ({why})")

    def _param(self, name: str) -> None:
        values = {px4.HOVER_PARAMETER: self.cfg.hover_throttle,
                  px4.OF_LOSS_PARAMETER: self.cfg.of_loss_timeout}  # fmt: skip
        if name in values:
            self._send(mavlink.MAVLink_param_value_message(
                name.encode(), float(values[name]), mavlink.MAV_PARAM_TYPE_REAL32,
                len(values), list(values).index(name)))  # fmt: skip

    def switch_mode(self, name: str) -> None:
        """The pilot's switch (tests): to a main mode by name (``px4.MAIN_MODES``)."""
        self._set_mode(px4.MAIN_MODES[name], "pilot")


def _within(t: float, span: tuple[float, float] | None) -> bool:
    return span is not None and span[0] <= t < span[1]
