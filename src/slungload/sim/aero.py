"""Aerodynamic forces the paper's model leaves out: drag, rotor downwash on the load, wind.

Evaluated every MuJoCo substep from the current state, so it is written for 3-vectors with as
few numpy calls as possible. All vectors are world frame, z up.
"""

from __future__ import annotations

import math

import numpy as np

from .config import SimConfig
from .ou import ou_process


class Aero:
    """Forces on vehicle and load from the air; constants precomputed from a ``SimConfig``."""

    def __init__(self, cfg: SimConfig) -> None:
        eff = cfg.effects
        self.drag = eff.drag
        self.downwash = eff.downwash
        self.rho = cfg.air_density
        self.rotor_drag_per_newton = cfg.rotor_drag / (cfg.total_mass * cfg.gravity)
        self.body_q = 0.5 * cfg.air_density * np.asarray(cfg.body_drag_area, dtype=float)
        self.load_q = 0.5 * cfg.air_density * cfg.load_drag_area
        self.induced_k = 1.0 / (2.0 * cfg.air_density * cfg.rotor_area)  # v_i^2 = T * k
        self.wake_gain = cfg.downwash_gain
        self.inv_r2 = 1.0 / cfg.downwash_radius**2

    def induced_velocity(self, thrust: float) -> float:
        """Momentum-theory induced velocity at the rotor discs, m/s: sqrt(T / (2 rho A))."""
        return math.sqrt(max(thrust, 0.0) * self.induced_k)

    def wake_velocity(self, p: np.ndarray, rot: np.ndarray, thrust: float, p_load: np.ndarray):
        """Air velocity of the rotor wake at the load, (3,) m/s (zero beside or above the rotors).

        The wake flows along -body z with speed gain * v_i, decaying as a Gaussian of the load's
        distance from the rotor axis.
        """
        down = -rot[:, 2]
        rel = p_load - p
        along = rel @ down
        if along <= 0.0:
            return np.zeros(3)
        lateral2 = rel @ rel - along * along
        speed = self.wake_gain * self.induced_velocity(thrust) * math.exp(-lateral2 * self.inv_r2)
        return speed * down

    def vehicle_force(self, v: np.ndarray, rot: np.ndarray, thrust: float, wind: np.ndarray):
        """Drag on the vehicle, (3,) N: linear rotor drag (in the rotor plane, scaled by thrust)
        plus quadratic body drag per body axis, on the air-relative velocity."""
        if not self.drag:
            return np.zeros(3)
        vb = (v - wind) @ rot  # body frame
        speed = math.sqrt(vb @ vb)
        fb = -self.body_q * speed * vb
        k = self.rotor_drag_per_newton * thrust
        fb[0] -= k * vb[0]
        fb[1] -= k * vb[1]
        return rot @ fb

    def load_force(self, v_load: np.ndarray, wind: np.ndarray, wake: np.ndarray) -> np.ndarray:
        """Quadratic drag on the cube, (3,) N, from its velocity relative to wind + wake.

        With drag off and downwash on, only the wake pushes (on a load at rest in still air).
        """
        if self.drag:
            rel = v_load - wind - wake
        elif self.downwash:
            rel = -wake
        else:
            return np.zeros(3)
        return -self.load_q * math.sqrt(rel @ rel) * rel

    # --- the same forces for K states at once (``lab.control.plant_batch``); tests check them ---
    def wake_velocities(self, p, rot, thrust, p_load) -> np.ndarray:
        """``wake_velocity`` for K states: p, p_load (K, 3) m; rot (K, 3, 3); thrust (K,) N."""
        down = -rot[:, :, 2]
        rel = p_load - p
        along = np.einsum("ki,ki->k", rel, down)
        lateral2 = np.einsum("ki,ki->k", rel, rel) - along * along
        v_i = np.sqrt(np.maximum(thrust, 0.0) * self.induced_k)
        speed = self.wake_gain * v_i * np.exp(-lateral2 * self.inv_r2)
        return np.where(along[:, None] > 0.0, speed[:, None] * down, 0.0)

    def vehicle_forces(self, v, rot, thrust, wind) -> np.ndarray:
        """``vehicle_force`` for K states: v (K, 3) m/s, rot (K, 3, 3), thrust (K,) N, wind
        (3,) m/s -> (K, 3) N."""
        if not self.drag:
            return np.zeros_like(v)
        vb = np.einsum("ki,kij->kj", v - wind, rot)  # body frame
        speed = np.sqrt(np.einsum("ki,ki->k", vb, vb))
        fb = -self.body_q * speed[:, None] * vb
        fb[:, :2] -= (self.rotor_drag_per_newton * thrust)[:, None] * vb[:, :2]
        return np.einsum("kij,kj->ki", rot, fb)

    def load_forces(self, v_load, wind, wake) -> np.ndarray:
        """``load_force`` for K states: v_load, wake (K, 3) m/s, wind (3,) m/s -> (K, 3) N."""
        if self.drag:
            rel = v_load - wind - wake
        elif self.downwash:
            rel = -wake
        else:
            return np.zeros_like(v_load)
        return -self.load_q * np.sqrt(np.einsum("ki,ki->k", rel, rel))[:, None] * rel


def ou_wind(cfg: SimConfig, steps: int, rng: np.random.Generator) -> np.ndarray:
    """Ornstein-Uhlenbeck wind velocity at each control step, (steps, 3) m/s, stationary start.

    Horizontal standard deviation ``wind_std``, vertical a third of it, correlation time
    ``wind_tau``; zero when the wind effect is off (the generator is still advanced, so other
    random draws of the flight do not depend on the switch).
    """
    std = cfg.wind_std * np.array([1.0, 1.0, 1.0 / 3.0])
    wind = ou_process(std, cfg.wind_tau, cfg.control_dt, steps, rng)
    return wind if cfg.effects.wind else np.zeros_like(wind)
