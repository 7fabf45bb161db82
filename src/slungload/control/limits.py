"""The input box the MPC's commands stay in: collective thrust and body rates. numpy only."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["InputLimits"]


@dataclass(frozen=True)
class InputLimits:
    """Box on the commands: thrust N in [thrust_min, thrust_max], |body rate| <= rate_max."""

    thrust_min: float  # N
    thrust_max: float  # N
    rate_max: float  # rad/s, each axis

    @classmethod
    def from_sim(cls, cfg) -> InputLimits:
        """The simulator's limits (a ``sim.config.SimConfig``): thrust up to ``max_thrust``,
        rates up to ``max_rate`` (the PID's own), and at least 30 % of hover thrust (the PID's
        floor on the vertical force)."""
        return cls(0.3 * cfg.total_mass * cfg.gravity, cfg.max_thrust, cfg.max_rate)

    def lower(self) -> np.ndarray:
        return np.array([self.thrust_min] + [-self.rate_max] * 3)

    def upper(self) -> np.ndarray:
        return np.array([self.thrust_max] + [self.rate_max] * 3)

    def clamp(self, u: np.ndarray) -> np.ndarray:
        """u (..., 4) clamped into the box."""
        return np.minimum(np.maximum(u, self.lower()), self.upper())

    def contains(self, u, tol: float = 1e-9) -> bool:
        """Every row of u (..., 4) finite and inside the box."""
        u = np.asarray(u, dtype=np.float64)
        if not np.isfinite(u).all():
            return False
        return bool(((u >= self.lower() - tol) & (u <= self.upper() + tol)).all())

    def at_limit(self, u: np.ndarray, rel: float = 1e-3) -> bool:
        """Whether a command (4,) sits at a bound (within ``rel`` of the range)."""
        thrust_tol = rel * (self.thrust_max - self.thrust_min)
        thrust = u[0] <= self.thrust_min + thrust_tol or u[0] >= self.thrust_max - thrust_tol
        return bool(thrust or (np.abs(u[1:]) >= self.rate_max * (1.0 - rel)).any())
