"""The ``chain`` plant family: a rotor-level vehicle carrying a cable of links.

Structurally unlike the ``tendon`` family (``plant.py``), so that a result that holds on both
is not one simulator's accident:

- **the vehicle**: four rotors in an X, each a first-order lag of its speed behind its command
  (thrust ~ speed^2, saturating at a quarter of ``max_thrust``), under an explicit body-rate PI
  loop run every substep (500 Hz) whose torques a mixer turns into rotor commands; the mixer
  assumes the rotors sit around the centre of mass, the plant puts them ``thrust_offset`` off.
  Every force and torque is applied from Python (``RotorLoop``); MuJoCo has no actuators.
- **the cable**: ``Chain.links`` straight links between point-mass beads that carry the cable's
  own mass, each link a tendon that can go slack (``cable_stretch`` off: near-rigid links), the
  load a point-mass sphere; the chain bends, so it has modes beyond the single pendulum's.
- **the air**: quadratic drag on the body, the beads and the load; no rotor drag, no downwash.

Sensors, wind, latency and thrust errors are the simulator's common ones (``PlantParams``).
``RotorLoop`` and ``chain_forces`` work on K states at once: the plant steps one, the oracle's
look-ahead (``lab.control.plant_batch``) K, with the same code.
"""

from __future__ import annotations

import copy
import math

import mujoco
import numpy as np

from ..frames import rotation_matrix
from .config import SimConfig
from .mjcf import options, vec
from .plant import PlantParams, VehicleState

QUAD = "quad"
LOAD = "load"
ROTORS = 4


def bead_masses(cfg: SimConfig) -> np.ndarray:
    """(links - 1,) kg: the cable's mass, ``cable_density`` x string length, on its beads."""
    beads = cfg.chain.links - 1
    return np.full(beads, cfg.chain.cable_density * cfg.string_length / beads)


def hanging_positions(cfg: SimConfig) -> np.ndarray:
    """(links + 1, 3) m: the attachment, each bead and the load's centre, hanging still below
    the vehicle at ``hover_z`` (links at their full length)."""
    link = cfg.string_length / cfg.chain.links
    top = cfg.hover_z - cfg.attach_below
    z = top - link * np.arange(cfg.chain.links + 1)
    z[-1] -= 0.5 * cfg.load_size  # the load's centre, below the hook on its top
    return np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)


def build_chain_mjcf(cfg: SimConfig) -> str:
    """MJCF text of the ``chain`` family hovering at ``hover_z``: the vehicle a free body, the
    beads and the load point masses on three slide joints each (their bodies at the origin, so
    their joint positions are world positions; ``ChainPlant`` sets them hanging)."""
    ch = cfg.chain
    link = cfg.string_length / ch.links
    if cfg.effects.cable_stretch:
        solref = (0.01, 0.5)  # s, rad: a soft link, a little stretch under the load
    else:
        solref = (2.0 * cfg.timestep, 1.0)  # as stiff as MuJoCo's step allows
    masses = bead_masses(cfg)

    def point(name: str, mass: float, site: str, damping: float) -> str:
        joints = "\n".join(
            f'      <joint name="{name}_{a}" type="slide" axis="{vec(np.eye(3)[i])}" '
            f'damping="{damping:.9g}"/>'
            for i, a in enumerate("xyz")
        )
        inertia = vec([max(mass * 1e-4, 1e-9)] * 3)  # a point: no rotation joint moves it
        return (f'    <body name="{name}" pos="0 0 0">\n{joints}\n'
                f'      <inertial pos="0 0 0" mass="{mass:.9g}" diaginertia="{inertia}"/>\n'
                f"      {site}\n    </body>")  # fmt: skip

    beads = "\n".join(
        point(f"bead{i}", m, f'<site name="bead{i}" pos="0 0 0"/>', ch.bead_damping)
        for i, m in enumerate(masses)
    )
    load = point(
        LOAD, cfg.load_mass, f'<site name="hook" pos="0 0 {0.5 * cfg.load_size:.9g}"/>', 0.0
    )
    sites = ["attach", *(f"bead{i}" for i in range(len(masses))), "hook"]
    tendons = "\n".join(
        f'    <spatial name="link{i}" limited="true" range="0 {link:.9g}" '
        f'solreflimit="{vec(solref)}" solimplimit="0.95 0.95 0.001">'
        f'<site site="{a}"/><site site="{b}"/></spatial>'
        for i, (a, b) in enumerate(zip(sites[:-1], sites[1:], strict=True))
    )
    return f"""<mujoco model="slungload-chain">
  {options(cfg)}
  <worldbody>
    <body name="{QUAD}" pos="0 0 {cfg.hover_z:.9g}">
      <freejoint/>
      <inertial pos="0 0 0" mass="{cfg.mass_quad:.9g}" diaginertia="{vec(cfg.inertia_quad)}"/>
      <site name="attach" pos="0 0 {-cfg.attach_below:.9g}"/>
    </body>
{beads}
{load}
  </worldbody>
  <tendon>
{tendons}
  </tendon>
</mujoco>
"""


class RotorLoop:
    """The vehicle's explicit body-rate PI loop, mixer and rotor lags, for K states at once.

    ``wrench`` takes the commanded collective thrust (K,) N and body rates (K, 3) rad/s, the
    achieved body rates (K, 3) rad/s, and returns the body-frame force and torque (K, 3) each
    that the rotors produce over the next substep; the loop's integral (K, 3) and the rotors'
    normalised speeds (K, 4) are its state (``take`` copies them from another loop).
    """

    def __init__(self, cfg: SimConfig, params: PlantParams, k: int = 1) -> None:
        ch, eff = cfg.chain, cfg.effects
        self.dt = cfg.timestep
        self.inertia = np.asarray(cfg.inertia_quad, dtype=float)
        self.kp = np.asarray(ch.rate_kp, dtype=float)
        self.ki = np.asarray(ch.rate_ki, dtype=float)
        self.bound = ch.rate_integral
        self.f_max = cfg.max_thrust / ROTORS
        self.alpha = 1.0 - math.exp(-self.dt / ch.rotor_tau) if eff.thrust_lag else 1.0
        self.ideal = not eff.rate_loop
        a = ch.arm / math.sqrt(2.0)
        xy = np.array([[a, -a], [-a, a], [a, a], [-a, -a]])  # front-right, back-left, ...
        spin = np.array([1.0, 1.0, -1.0, -1.0])  # yaw torque sign of each rotor's drag

        def allocation(pos: np.ndarray) -> np.ndarray:
            """(4, 4): rotor thrusts -> (collective N, torque x, y, z N m), body frame."""
            return np.stack([np.ones(ROTORS), pos[:, 1], -pos[:, 0], spin * ch.yaw_moment])

        self.mixer = np.linalg.inv(allocation(xy))  # what the loop believes
        self.allocation = allocation(xy - np.asarray(params.thrust_offset))  # what is
        hover = np.full(ROTORS, cfg.total_mass * cfg.gravity / ROTORS)
        self.speed = np.tile(np.sqrt(np.clip(hover / self.f_max, 0.0, 1.0)), (k, 1))
        self.integral = np.zeros((k, 3))

    def take(self, other: RotorLoop, k: int | None = None) -> None:
        """This loop's state := ``other``'s (its K rows, or its one row tiled to ``k``)."""
        if k is None:
            self.speed, self.integral = other.speed.copy(), other.integral.copy()
        else:
            self.speed = np.tile(other.speed, (k, 1))
            self.integral = np.tile(other.integral, (k, 1))

    def wrench(
        self, thrust_cmd: np.ndarray, rates_cmd: np.ndarray, rates: np.ndarray, scale: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Body force and torque (K, 3) each, N and N m (see the class); ``scale`` the
        achieved / commanded thrust of the flight's thrust error now."""
        if self.ideal:  # the rates follow their command (the plant sets them): thrust only
            force = np.zeros((len(thrust_cmd), 3))
            force[:, 2] = scale * np.clip(thrust_cmd, 0.0, ROTORS * self.f_max)
            return force, np.zeros_like(force)
        err = rates_cmd - rates
        self.integral = np.clip(self.integral + err * self.dt, -self.bound, self.bound)
        spin = self.inertia * rates
        torque = self.inertia * (self.kp * err + self.ki * self.integral) + np.cross(rates, spin)
        wanted = np.concatenate([thrust_cmd[:, None], torque], axis=1) @ self.mixer.T  # (K, 4)
        target = np.sqrt(np.clip(wanted / self.f_max, 0.0, 1.0))
        self.speed += self.alpha * (target - self.speed)
        rotor = scale * self.f_max * self.speed**2  # (K, 4) N
        out = rotor @ self.allocation.T  # (K, 4): collective, torque x, y, z
        force = np.zeros((len(rotor), 3))
        force[:, 2] = out[:, 0]
        return force, out[:, 1:]

    @property
    def thrust(self) -> np.ndarray:
        """(K,) N: the rotors' collective thrust now (before the thrust error's scale)."""
        return self.f_max * (self.speed**2).sum(axis=1)


class ChainForces:
    """Forces the ``chain`` plant applies from Python every substep, for K states at once:
    the rotors' wrench (``RotorLoop``) in the world frame, and quadratic drag on body and load
    (the beads' drag is their joints' damping, inside MuJoCo)."""

    def __init__(self, cfg: SimConfig) -> None:
        self.drag = cfg.effects.drag
        self.body_q = 0.5 * cfg.air_density * np.asarray(cfg.body_drag_area, dtype=float)
        area = math.pi * (0.5 * cfg.load_size) ** 2
        self.load_q = 0.5 * cfg.air_density * cfg.chain.load_drag_coef * area

    def vehicle(self, rot, v, wind, force_b, torque_b) -> tuple[np.ndarray, np.ndarray]:
        """World force and torque (K, 3) on the vehicle: rot (K, 3, 3) body -> world, v (K, 3)
        m/s, wind (3,) m/s, the rotors' body force and torque (K, 3)."""
        if self.drag:
            vb = np.einsum("kji,kj->ki", rot, v - wind)  # body frame
            force_b = force_b - self.body_q * np.linalg.norm(vb, axis=1, keepdims=True) * vb
        return (np.einsum("kij,kj->ki", rot, force_b), np.einsum("kij,kj->ki", rot, torque_b))

    def load(self, v_load: np.ndarray, wind: np.ndarray) -> np.ndarray:
        """Drag on the load (K, 3) N from its air-relative velocity."""
        if not self.drag:
            return np.zeros_like(v_load)
        rel = v_load - wind
        return -self.load_q * np.linalg.norm(rel, axis=1, keepdims=True) * rel


class ChainPlant(VehicleState):
    """MuJoCo model and data of one ``chain`` flight (the ``plant.Plant`` interface: the state
    of ``VehicleState``, ``advance``, ``fork``, ``sync``, ``set_state``), starting in hover with
    the chain hanging still."""

    def __init__(self, cfg: SimConfig, params: PlantParams | None = None) -> None:
        self.cfg = cfg
        self.params = params or PlantParams()
        self.model = mujoco.MjModel.from_xml_string(build_chain_mjcf(cfg))
        self.data = mujoco.MjData(self.model)
        self.quad = self.model.body(QUAD).id
        self.load = self.model.body(LOAD).id
        beads = cfg.chain.links - 1
        self.load_qpos = 7 + 3 * beads  # qpos of the load's three slide joints
        self.load_qvel = 6 + 3 * beads
        self.links = [self.model.tendon(f"link{i}").id for i in range(cfg.chain.links)]
        self.latency_steps = round(cfg.latency / cfg.timestep) if cfg.effects.latency else 0
        self.time = 0.0
        self.wind = np.zeros(3)
        hanging = hanging_positions(cfg)
        self.data.qpos[7:] = hanging[1:].reshape(-1)
        # the hover thrust that holds everything, the cable's own mass included
        hover = (cfg.total_mass + bead_masses(cfg).sum()) * cfg.gravity
        self.command = (hover, np.zeros(3))
        self.rotors = RotorLoop(cfg, self.params)
        self.rotors.speed[:] = math.sqrt(min(hover / (ROTORS * self.rotors.f_max), 1.0))
        self.forces = ChainForces(cfg)
        mujoco.mj_forward(self.model, self.data)

    @property
    def thrust(self) -> float:
        """Achieved collective thrust, N (rotor lags, saturation, thrust error)."""
        return float(self.rotors.thrust[0] * self.scale(self.time))

    @property
    def cable_length(self) -> float:
        """Length along the chain, attachment -> load top, m (its links' sum)."""
        return float(sum(self.data.ten_length[i] for i in self.links))

    def scale(self, time: float) -> float:
        """Achieved / commanded thrust at ``time`` s (the flight's thrust error)."""
        return self.params.thrust_scale * (1.0 - self.params.battery_sag * time)

    def set_state(self, **values: np.ndarray) -> None:
        """Overwrite p, v, q, rates, p_load, v_load; the beads then lie evenly on the straight
        line from the attachment to the load's hook, moving with the velocities in between
        (tests start swings and drops this way, as with ``plant.Plant``)."""
        d, lq, lv = self.data, self.load_qpos, self.load_qvel
        slots = {
            "p": (0, 3, "qpos"), "q": (3, 7, "qpos"), "p_load": (lq, lq + 3, "qpos"),
            "v": (0, 3, "qvel"), "rates": (3, 6, "qvel"), "v_load": (lv, lv + 3, "qvel"),
        }  # fmt: skip
        for name, value in values.items():
            lo, hi, field = slots[name]
            getattr(d, field)[lo:hi] = value
        top = d.qpos[0:3] + rotation_matrix(d.qpos[3:7]) @ np.array([0, 0, -self.cfg.attach_below])
        hook = d.qpos[lq : lq + 3] + np.array([0.0, 0.0, 0.5 * self.cfg.load_size])
        share = np.arange(1, self.cfg.chain.links)[:, None] / self.cfg.chain.links  # (beads, 1)
        d.qpos[7:lq] = (top + share * (hook - top)).reshape(-1)
        d.qvel[6:lv] = (d.qvel[0:3] + share * (d.qvel[lv : lv + 3] - d.qvel[0:3])).reshape(-1)
        mujoco.mj_forward(self.model, d)

    # --- stepping -----------------------------------------------------------------------------
    def advance(self, thrust_cmd: float, rates_cmd: np.ndarray, wind: np.ndarray) -> None:
        """Hold the command (N, rad/s body) for one control period in the given wind (3,) m/s."""
        m, d = self.model, self.data
        xfrc = d.xfrc_applied
        lv = self.load_qvel
        scale = self.scale(self.time)
        for s in range(self.cfg.substeps):
            if s == self.latency_steps:
                self.command = (float(thrust_cmd), np.asarray(rates_cmd, dtype=float))
            thrust, rates = self.command
            if self.rotors.ideal:
                d.qvel[3:6] = rates
            force_b, torque_b = self.rotors.wrench(
                np.array([thrust]), rates[None], d.qvel[None, 3:6], scale
            )
            rot = rotation_matrix(d.qpos[None, 3:7])
            force, torque = self.forces.vehicle(rot, d.qvel[None, 0:3], wind, force_b, torque_b)
            xfrc[self.quad, 0:3], xfrc[self.quad, 3:6] = force[0], torque[0]
            xfrc[self.load, 0:3] = self.forces.load(d.qvel[None, lv : lv + 3], wind)[0]
            mujoco.mj_step(m, d)
        self.time += self.cfg.control_dt
        self.wind = wind

    def fork(self) -> ChainPlant:
        """A twin sharing the model, with its own data and rotor state (see ``plant.Plant``)."""
        twin = copy.copy(self)
        twin.data = mujoco.MjData(self.model)
        twin.rotors = copy.copy(self.rotors)
        twin.sync(self)
        return twin

    def sync(self, source: ChainPlant) -> None:
        """Take over ``source``'s whole state (MuJoCo data, rotors, time, command, wind)."""
        mujoco.mj_copyData(self.data, self.model, source.data)
        self.rotors.take(source.rotors)
        self.time, self.command, self.wind = source.time, source.command, source.wind
