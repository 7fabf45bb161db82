"""Motion capture as the flight controller sees it: noisy positions and attitude, and a velocity
estimated from the noisy positions by a low-passed finite difference."""

from __future__ import annotations

import math

import numpy as np

from .config import SimConfig


def quat_mul_np(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Hamilton product of w-x-y-z quaternions, (4,) x (4,) -> (4,)."""
    w1, x1, y1, z1 = q1
    w2, x2, y2, z2 = q2
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])  # fmt: skip


def quat_from_rotvec_np(r: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) rad -> unit quaternion w-x-y-z (4,)."""
    angle = math.sqrt(r @ r)
    if angle < 1e-12:
        return np.array([1.0, 0.5 * r[0], 0.5 * r[1], 0.5 * r[2]])
    s = math.sin(0.5 * angle) / angle
    return np.array([math.cos(0.5 * angle), s * r[0], s * r[1], s * r[2]])


class Mocap:
    """Noisy motion-capture measurements and the velocity estimate, one call per control step."""

    def __init__(self, cfg: SimConfig, rng: np.random.Generator) -> None:
        self.rng = rng
        noisy = cfg.effects.mocap_noise
        self.pos_std = cfg.pos_noise if noisy else 0.0
        self.load_std = cfg.load_pos_noise if noisy else 0.0
        self.att_std = cfg.att_noise if noisy else 0.0
        self.filtered = cfg.effects.velocity_filter
        self.alpha = math.exp(-cfg.control_dt / cfg.velocity_tau)
        self.dt = cfg.control_dt
        self.last_p: np.ndarray | None = None
        self.v_est = np.zeros(3)

    def measure(
        self, p: np.ndarray, v: np.ndarray, q: np.ndarray, p_load: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """True p (3,), v (3,), q w-x-y-z (4,), pL (3,) -> measured p, v estimate, q, pL.

        The noise is drawn even when its effect is off (scaled by zero), so switching one
        effect does not change the random draws of the others.
        """
        n = self.rng.standard_normal(9)
        p_m = p + self.pos_std * n[0:3]
        pl_m = p_load + self.load_std * n[3:6]
        q_m = quat_mul_np(q, quat_from_rotvec_np(self.att_std * n[6:9]))
        if not self.filtered:
            v_est = v.copy()
        elif self.last_p is None:
            v_est = v.copy()  # the estimator has converged during the warm-up hover
        else:
            diff = (p_m - self.last_p) / self.dt
            v_est = self.alpha * self.v_est + (1.0 - self.alpha) * diff
        self.last_p = p_m
        self.v_est = v_est
        return p_m, v_est, q_m, pl_m
