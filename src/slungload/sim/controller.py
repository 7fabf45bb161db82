"""Offboard controllers: the contract a controller meets (``Controller``) and the default PID.

Contract (``Controller``): called once per control step (period h = ``SimConfig.control_dt``)
with the step's noisy ``Measurement``, the flight's whole ``Reference`` and the step index k;
returns the thrust command T, N, and the body-rate command omega (3,), rad/s, held by the plant
for one period. Any callable with that signature qualifies (a plain function does too).

Default (``PIDController``): a geometric PID controller on the total mass mQ + mL (the load is
treated as a disturbance): the desired force F = m (a_ref + Kp e_p + Kd e_v + Ki int e_p + g e3)
gives the thrust command T = F . R e3 and the desired thrust axis F / |F|; the body-rate command
is proportional to the attitude error between the measured and the desired attitude (with the
reference yaw).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ..frames import rotvec_from_matrix
from ..layout import LOAD_POS, POS, QUAT, STATE_DIM, VEL
from .config import Excitation, SimConfig
from .maneuvers import Reference
from .ou import ou_process


@dataclass(frozen=True)
class Measurement:
    """What the flight controller measures at one control step (motion capture, world frame).

    The arrays are noisy when ``Effects.mocap_noise`` is on, and the velocity is the filtered
    estimate when ``Effects.velocity_filter`` is on (the truth otherwise); the simulator hands
    them over read-only, since the same arrays are recorded afterwards.
    """

    t: float  # s, time of the step; negative during the warm-up hover, 0 at the first record
    p: np.ndarray  # (3,) m, vehicle position
    v: np.ndarray  # (3,) m/s, vehicle velocity (estimate)
    q_wxyz: np.ndarray  # (4,) unit quaternion w-x-y-z, body -> world
    rotation: np.ndarray  # (3, 3) rotation matrix of q_wxyz, body -> world (columns: body axes)
    p_load: np.ndarray  # (3,) m, load (cube centre) position

    @property
    def state(self) -> np.ndarray:
        """(13,) float64: the measured x = (p, v, q w-x-y-z, pL) in the package's layout."""
        x = np.empty(STATE_DIM)
        x[POS], x[VEL], x[QUAT], x[LOAD_POS] = self.p, self.v, self.q_wxyz, self.p_load
        return x


@runtime_checkable
class Controller(Protocol):
    """An offboard controller: (measurement, reference, step) -> (thrust N, body rates rad/s).

    ``simulate_flight`` calls it exactly once per control step k = 0 .. K-1, in order, with the
    period h = ``SimConfig.control_dt``; K counts the warm-up hover (``SimConfig.warmup``, where
    ``measurement.t`` < 0 and the reference holds the start point) plus the recorded steps.

    measurement: the step's ``Measurement`` (t s; p m, v m/s, p_load m, (3,); q_wxyz (4,);
        rotation (3, 3) body -> world).
    reference: the *whole* flight's ``Reference``, rows 0 .. K-1 at times t + (j - k) h:
        position (K, 3) m, velocity (K, 3) m/s, acceleration (K, 3) m/s^2, yaw (K,) rad (world
        frame). Row k is this step's reference; rows k+1 .. K-1 are the look-ahead a predictive
        controller needs (it ends with the flight: hold the last row beyond it). Read-only.
    k: the step index into ``reference`` (0-based, warm-up included).

    Returns (T, omega): the collective thrust command T, N (a finite float; the plant clips the
    achieved thrust to [0, ``SimConfig.max_thrust``]), and the body-rate command omega, (3,)
    rad/s in body axes. Both are held for one period; a non-finite command makes
    ``simulate_flight`` raise ``ValueError``. A controller may keep state (the PID's integral),
    so use a fresh one per flight. Optional: ``attach(plant)``, called once with the flight's
    ``plant.Plant`` before the first step (benchmarks only: the oracle MPC predicts with it).
    """

    def __call__(
        self, measurement: Measurement, reference: Reference, k: int
    ) -> tuple[float, np.ndarray]: ...


def excitation_signal(
    excitation: Excitation, dt: float, steps: int, rng: np.random.Generator
) -> np.ndarray:
    """The perturbations (steps, 4) added to the commands (thrust N, body rates rad/s) at each
    control step of period ``dt`` s: ``Excitation``'s Ornstein-Uhlenbeck processes, started
    stationary. All zero (and ``rng`` untouched) when the excitation is off."""
    if not excitation.active:
        return np.zeros((steps, 4))
    std = np.array([excitation.thrust_std, *excitation.rate_std])
    return ou_process(std, excitation.tau, dt, steps, rng)


class PIDController:
    """The default controller (see the module): stateful (integral term), one per flight.

    Meets the ``Controller`` contract; ``command`` is the same law on plain arrays.
    """

    def __init__(self, cfg: SimConfig) -> None:
        self.mass = cfg.total_mass
        self.g = cfg.gravity
        self.dt = cfg.control_dt
        self.kp = np.asarray(cfg.kp, dtype=float)
        self.kd = np.asarray(cfg.kd, dtype=float)
        self.ki = np.asarray(cfg.ki, dtype=float)
        self.k_att = np.asarray(cfg.k_att, dtype=float)
        self.max_tilt = cfg.max_tilt
        self.max_rate = cfg.max_rate
        self.max_err = cfg.max_position_error
        self.max_thrust = cfg.max_thrust
        self.max_int_acc = 2.0  # m/s^2, anti-windup bound on the integral's contribution
        self.integral = np.zeros(3)

    def __call__(
        self, measurement: Measurement, reference: Reference, k: int
    ) -> tuple[float, np.ndarray]:
        """One control step (the ``Controller`` contract): tracks reference row k, no look-ahead."""
        return self.command(
            reference.position[k],
            reference.velocity[k],
            reference.acceleration[k],
            reference.yaw[k],
            measurement.p,
            measurement.v,
            measurement.rotation,
        )

    def command(
        self,
        p_ref: np.ndarray,
        v_ref: np.ndarray,
        a_ref: np.ndarray,
        yaw_ref: float,
        p: np.ndarray,
        v: np.ndarray,
        rot: np.ndarray,
    ) -> tuple[float, np.ndarray]:
        """References (3,) m, m/s, m/s^2 and yaw rad; measured p, v (3,), R (3, 3) body->world.

        Returns the thrust command T_ref, N, and the body-rate command w_ref (3,), rad/s.
        """
        e_p = p_ref - p
        n = math.sqrt(e_p @ e_p)
        if n > self.max_err:
            e_p *= self.max_err / n
        e_v = v_ref - v
        self.integral += e_p * self.dt
        limit = self.max_int_acc / np.maximum(self.ki, 1e-9)
        np.clip(self.integral, -limit, limit, out=self.integral)
        acc = a_ref + self.kp * e_p + self.kd * e_v + self.ki * self.integral
        force = self.mass * np.array([acc[0], acc[1], acc[2] + self.g])
        return self.force_command(force, rot, yaw_ref)

    def force_command(
        self, force: np.ndarray, rot: np.ndarray, yaw_ref: float
    ) -> tuple[float, np.ndarray]:
        """The desired force (3,) N, world frame (``force`` is changed in place), as a command:
        its vertical part at least 30 % of hover and its tilt limited (the vertical part kept,
        the horizontal one shrunk), thrust = force . R e3, and body rates proportional to the
        attitude error towards the force's direction at yaw ``yaw_ref``. The attitude loop of
        every controller built on this one (the payload-aware geometric controller too)."""
        force[2] = max(force[2], 0.3 * self.mass * self.g)
        horiz = math.hypot(force[0], force[1])
        max_h = force[2] * math.tan(self.max_tilt)
        if horiz > max_h:
            force[:2] *= max_h / horiz
        b3 = force / math.sqrt(force @ force)
        thrust = float(np.clip(force @ rot[:, 2], 0.0, self.max_thrust))
        c = np.array([math.cos(yaw_ref), math.sin(yaw_ref), 0.0])
        b2 = np.cross(b3, c)
        b2 /= math.sqrt(b2 @ b2)
        b1 = np.cross(b2, b3)
        rot_des = np.stack([b1, b2, b3], axis=1)
        err = rotvec_from_matrix(rot.T @ rot_des)  # body frame, rad
        rates = np.clip(self.k_att * err, -self.max_rate, self.max_rate)
        return thrust, rates
