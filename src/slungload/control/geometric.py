"""A payload-aware classical baseline: geometric control of the load through the cable.

After Sreenath, Lee and Kumar, "Geometric control and differential flatness of a quadrotor UAV
with a cable-suspended load" (CDC 2013), written here from the paper's equations in this
package's frame (z up; xi = (pL - p) / l, the unit cable direction from vehicle to load). With
the cable taut, the vehicle's force F = T R e3 moves the load through

    F = (mQ + mL)(aL + g e3) - mQ l xi'',   xi . xi'' = -|xi'|^2,

so the load is steered by the cable direction, and the cable by the force across it:

1. load position loop: a = aL_ref - kx eL - kv evL - ki int eL, with the load reference the
   vehicle reference less l e3 (the load hanging still below it) and the reference's
   acceleration as feedforward;
2. A = (mQ + mL)(a + g e3) + mQ l |xi'|^2 xi; the desired cable direction xi_d = -A / |A|;
3. cable attitude loop on the sphere: e_q = xi_d x xi, e_w = xi x xi' (the cable's angular
   velocity less its desired value xi_d x xi_d', xi_d' the low-passed difference of xi_d:
   the flat outputs' higher derivatives are not fed forward); w'_d = -kq e_q - kw e_w;
4. F = (xi . A) xi + mQ l xi x w'_d (the part along the cable carries the load, the part
   across it turns the cable), flown through the PID's attitude loop
   (``PIDController.force_command``: tilt limit, thrust = F . R e3, body rates from the
   attitude error).

The cable rate xi' is the low-passed difference of the measured cable direction (time constant
``rate_tau``); the vehicle's velocity is the measured one. It meets ``sim.controller.Controller``
and knows the nominal vehicle and load (like the PID), not the flight's truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..sim.config import SimConfig
from ..sim.controller import Measurement, PIDController
from ..sim.maneuvers import Reference


@dataclass(frozen=True)
class GeometricGains:
    """Gains of the load and cable loops (x, y, z where three)."""

    kx: tuple[float, float, float] = (2.5, 2.5, 6.0)  # 1/s^2, load position
    kv: tuple[float, float, float] = (2.5, 2.5, 5.0)  # 1/s, load velocity
    ki: tuple[float, float, float] = (0.5, 0.5, 1.0)  # 1/s^3, load position integral
    kq: float = 12.0  # 1/s^2, cable direction
    kw: float = 4.0  # 1/s, cable angular velocity
    rate_tau: float = 0.05  # s, low-pass of the cable direction's difference
    feedforward_tau: float = 0.15  # s, low-pass of the desired cable direction's difference
    reference_tau: float = 0.15  # s, low-pass of the reference acceleration fed forward
    k_att: tuple[float, float, float] = (7.0, 7.0, 3.0)  # 1/s, attitude error -> rate command
    max_int_acc: float = 2.0  # m/s^2, anti-windup bound of the integral's contribution


class GeometricLoadController:
    """The controller of the module (``Controller`` contract); stateful, one per flight.

    cfg: the nominal vehicle (masses, cable length, limits); the attitude loop is the PID's,
    with ``gains.k_att`` in place of its own gains.
    """

    def __init__(self, cfg: SimConfig, gains: GeometricGains | None = None) -> None:
        self.gains = g = gains or GeometricGains()
        # The PID's force_command is the shared attitude loop, here with its own gain.
        self.attitude = PIDController(replace(cfg, k_att=g.k_att))
        self.m_quad, self.m_total = cfg.mass_quad, cfg.total_mass
        self.l, self.g, self.dt = cfg.cable_length, cfg.gravity, cfg.control_dt
        self.max_err = cfg.max_position_error
        self.kx, self.kv, self.ki = (np.asarray(a, dtype=float) for a in (g.kx, g.kv, g.ki))
        self.alpha = self.dt / (g.rate_tau + self.dt)
        self.alpha_des = self.dt / (g.feedforward_tau + self.dt)
        self.alpha_ref = self.dt / (g.reference_tau + self.dt)
        self.a_ref = np.zeros(3)  # the reference acceleration, low-passed
        self.integral = np.zeros(3)
        self.xi_prev: np.ndarray | None = None
        self.xi_rate = np.zeros(3)
        self.xi_des_prev: np.ndarray | None = None
        self.xi_des_rate = np.zeros(3)

    def __call__(
        self, measurement: Measurement, reference: Reference, k: int
    ) -> tuple[float, np.ndarray]:
        """One control step: tracks the load reference of row k (no look-ahead)."""
        m = measurement
        xi = self._cable(m)
        v_load = m.v + self.l * self.xi_rate
        e_x = m.p_load - (reference.position[k] - np.array([0.0, 0.0, self.l]))
        n = math.sqrt(e_x @ e_x)
        if n > self.max_err:
            e_x *= self.max_err / n
        e_v = v_load - reference.velocity[k]
        self.integral += e_x * self.dt
        limit = self.gains.max_int_acc / np.maximum(self.ki, 1e-9)
        np.clip(self.integral, -limit, limit, out=self.integral)
        self.a_ref += self.alpha_ref * (reference.acceleration[k] - self.a_ref)
        acc = self.a_ref - self.kx * e_x - self.kv * e_v - self.ki * self.integral
        a_vec = self.m_total * (acc + np.array([0.0, 0.0, self.g]))
        a_vec += self.m_quad * self.l * (self.xi_rate @ self.xi_rate) * xi
        xi_des = -a_vec / math.sqrt(a_vec @ a_vec)
        w_des = self._desired_rate(xi_des)
        e_q = np.cross(xi_des, xi)
        e_w = np.cross(xi, self.xi_rate) - w_des
        w_dot = -self.gains.kq * e_q - self.gains.kw * e_w
        force = (xi @ a_vec) * xi + self.m_quad * self.l * np.cross(xi, w_dot)
        return self.attitude.force_command(force, m.rotation, float(reference.yaw[k]))

    def _desired_rate(self, xi_des: np.ndarray) -> np.ndarray:
        """The desired cable's angular velocity xi_d x xi_d' (3,) rad/s, xi_d' its low-passed
        difference (the feedforward the flat outputs would give exactly)."""
        if self.xi_des_prev is not None:
            raw = (xi_des - self.xi_des_prev) / self.dt
            self.xi_des_rate += self.alpha_des * (raw - self.xi_des_rate)
        self.xi_des_prev = xi_des
        return np.cross(xi_des, self.xi_des_rate)

    def _cable(self, m: Measurement) -> np.ndarray:
        """The measured cable direction (3,), and its low-passed rate updated."""
        r = m.p_load - m.p
        xi = r / max(math.sqrt(r @ r), 1e-6)
        if self.xi_prev is not None:
            raw = (xi - self.xi_prev) / self.dt
            self.xi_rate += self.alpha * (raw - self.xi_rate)
        self.xi_prev = xi
        return xi
