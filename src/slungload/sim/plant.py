"""The simulated vehicle + cable + load: MuJoCo physics plus the effects applied from Python.

``Plant.advance`` holds a (thrust, body-rate) command for one control period h: it applies the
command after the latency, scales the thrust by the flight's thrust error, and every substep
adds drag, downwash and wind forces before stepping MuJoCo.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from .aero import Aero
from .config import SimConfig
from .mjcf import CABLE, LOAD, QUAD, THRUST_ACTUATOR, build_mjcf


@dataclass(frozen=True)
class PlantParams:
    """Per-flight draws of the plant's imperfections."""

    thrust_scale: float = 1.0  # -, achieved / commanded thrust at the start of the flight
    battery_sag: float = 0.0  # 1/s, relative thrust lost per second
    thrust_offset: tuple[float, float] = (0.0, 0.0)  # m, thrust centre minus centre of mass

    @classmethod
    def draw(cls, cfg: SimConfig, rng: np.random.Generator) -> PlantParams:
        """Random imperfections for one flight (identity for effects that are off)."""
        u = rng.uniform(-1.0, 1.0)
        sag = rng.uniform(0.0, 1.0)
        off = rng.standard_normal(2) * cfg.thrust_offset_std
        eff = cfg.effects
        return cls(
            thrust_scale=1.0 + cfg.thrust_scale_spread * u if eff.thrust_error else 1.0,
            battery_sag=cfg.battery_sag * sag if eff.thrust_error else 0.0,
            thrust_offset=(float(off[0]), float(off[1])) if eff.thrust_offset else (0.0, 0.0),
        )


class VehicleState:
    """The state every plant family reads the same way from its MuJoCo data: the vehicle a free
    joint first, the load's position at ``load_qpos`` and velocity at ``load_qvel`` (three
    coordinates each, world frame)."""

    data: mujoco.MjData
    load_qpos: int
    load_qvel: int

    @property
    def p(self) -> np.ndarray:
        return self.data.qpos[0:3].copy()

    @property
    def v(self) -> np.ndarray:
        return self.data.qvel[0:3].copy()

    @property
    def q(self) -> np.ndarray:
        """Vehicle attitude, unit quaternion w-x-y-z (4,), body -> world."""
        return self.data.qpos[3:7].copy()

    @property
    def rates(self) -> np.ndarray:
        """Achieved body rates (3,), rad/s (a MuJoCo free joint's angular velocity: body axes)."""
        return self.data.qvel[3:6].copy()

    @property
    def p_load(self) -> np.ndarray:
        return self.data.qpos[self.load_qpos : self.load_qpos + 3].copy()

    @property
    def v_load(self) -> np.ndarray:
        return self.data.qvel[self.load_qvel : self.load_qvel + 3].copy()

    @property
    def rot(self) -> np.ndarray:
        """Vehicle rotation matrix (3, 3), body -> world."""
        r = np.empty(9)
        mujoco.mju_quat2Mat(r, self.data.qpos[3:7])
        return r.reshape(3, 3)

    def tilt(self) -> float:
        """Angle between body z and world z, rad."""
        return math.acos(max(-1.0, min(1.0, self.rot[2, 2])))


class Plant(VehicleState):
    """MuJoCo model and data of one flight, starting in hover with the load hanging still."""

    load_qpos, load_qvel = 7, 6  # the cube's free joint follows the vehicle's

    def __init__(self, cfg: SimConfig, params: PlantParams | None = None) -> None:
        self.cfg = cfg
        self.params = params or PlantParams()
        self.model = mujoco.MjModel.from_xml_string(
            build_mjcf(cfg, np.asarray(self.params.thrust_offset))
        )
        self.data = mujoco.MjData(self.model)
        self.aero = Aero(cfg)
        self.quad = self.model.body(QUAD).id
        self.load = self.model.body(LOAD).id
        self.cable = self.model.tendon(CABLE).id
        self.latency_steps = round(cfg.latency / cfg.timestep) if cfg.effects.latency else 0
        self.time = 0.0
        self.wind = np.zeros(3)  # m/s, the wind of the latest period (what a look-ahead holds)
        hover = cfg.total_mass * cfg.gravity
        self.command = (hover, np.zeros(3))
        self._apply(*self.command)
        if cfg.effects.thrust_lag:
            self.data.act[THRUST_ACTUATOR] = self.data.ctrl[THRUST_ACTUATOR]
        mujoco.mj_forward(self.model, self.data)

    @property
    def thrust(self) -> float:
        """Achieved thrust, N (after scale, saturation and lag)."""
        if self.cfg.effects.thrust_lag:
            return float(self.data.act[THRUST_ACTUATOR])
        return float(self.data.ctrl[THRUST_ACTUATOR])

    @property
    def cable_length(self) -> float:
        """Distance attachment -> cube top, m (the string length when taut, less when slack)."""
        return float(self.data.ten_length[self.cable])

    def set_state(self, **values: np.ndarray) -> None:
        """Overwrite p, v, q, p_load, v_load, rates (tests start swings and drops this way)."""
        slots = {
            "p": (0, 3, "qpos"), "q": (3, 7, "qpos"), "p_load": (7, 10, "qpos"),
            "v": (0, 3, "qvel"), "rates": (3, 6, "qvel"), "v_load": (6, 9, "qvel"),
        }  # fmt: skip
        for name, value in values.items():
            lo, hi, field = slots[name]
            getattr(self.data, field)[lo:hi] = value
        mujoco.mj_forward(self.model, self.data)

    # --- stepping -----------------------------------------------------------------------------
    def _apply(self, thrust_cmd: float, rates_cmd: np.ndarray) -> None:
        p = self.params
        scale = p.thrust_scale * (1.0 - p.battery_sag * self.time)
        ctrl = self.data.ctrl
        ctrl[THRUST_ACTUATOR] = min(max(thrust_cmd * scale, 0.0), self.cfg.max_thrust)
        ctrl[THRUST_ACTUATOR + 1 : THRUST_ACTUATOR + 4] = rates_cmd

    def advance(self, thrust_cmd: float, rates_cmd: np.ndarray, wind: np.ndarray) -> None:
        """Hold the command (N, rad/s body) for one control period in the given wind (3,) m/s."""
        m, d, aero = self.model, self.data, self.aero
        ideal_rates = not self.cfg.effects.rate_loop
        xfrc = d.xfrc_applied
        quad, load = self.quad, self.load
        use_aero = aero.drag or aero.downwash
        for s in range(self.cfg.substeps):
            if s == self.latency_steps:
                self.command = (thrust_cmd, np.asarray(rates_cmd, dtype=float))
                self._apply(*self.command)
            if ideal_rates:
                d.qvel[3:6] = self.command[1]
            if use_aero:
                rot = d.xmat[quad].reshape(3, 3)
                thrust = self.thrust
                wake = (
                    aero.wake_velocity(d.qpos[0:3], rot, thrust, d.qpos[7:10])
                    if aero.downwash
                    else np.zeros(3)
                )
                xfrc[quad, 0:3] = aero.vehicle_force(d.qvel[0:3], rot, thrust, wind)
                xfrc[load, 0:3] = aero.load_force(d.qvel[6:9], wind, wake)
            mujoco.mj_step(m, d)
        self.time += self.cfg.control_dt
        self.wind = wind

    def fork(self) -> Plant:
        """A twin sharing the model, with its own MuJoCo data at this plant's state: stepping it
        (``advance``) leaves this plant untouched. ``sync`` brings it back to this plant."""
        twin = copy.copy(self)
        twin.data = mujoco.MjData(self.model)
        twin.sync(self)
        return twin

    def sync(self, source: Plant) -> None:
        """Take over ``source``'s whole state (MuJoCo data, time, the command still held for
        the latency, the wind); both plants share one model (``fork``)."""
        mujoco.mj_copyData(self.data, self.model, source.data)
        self.time, self.command, self.wind = source.time, source.command, source.wind
