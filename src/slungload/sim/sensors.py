"""Motion capture as the flight controller sees it: noisy positions and attitude, and a velocity
estimated from the noisy positions by a low-passed finite difference."""

from __future__ import annotations

import math

import numpy as np

from ..frames import quat_from_rotvec, quat_multiply
from .config import SimConfig


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
        q_m = quat_multiply(q, quat_from_rotvec(self.att_std * n[6:9]))
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
