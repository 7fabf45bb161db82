"""Ornstein-Uhlenbeck processes sampled at the control rate: the wind and the input excitation.

One discrete process, written once: x_{k+1} = a x_k + sqrt(1 - a^2) std n_k with
a = exp(-dt / tau), started from its stationary distribution, so every sample has standard
deviation ``std`` and neighbouring samples correlate by a.
"""

from __future__ import annotations

import math

import numpy as np


def ou_process(
    std: np.ndarray, tau: float, dt: float, steps: int, rng: np.random.Generator
) -> np.ndarray:
    """(steps, d) samples of d independent stationary OU processes: std (d,) in the signal's
    units, correlation time tau s, period dt s. Draws the step noise first, then the start."""
    std = np.asarray(std, dtype=float)
    a = math.exp(-dt / tau)
    noise = rng.standard_normal((steps, std.size)) * std * math.sqrt(1.0 - a * a)
    out = np.empty((steps, std.size))
    x = rng.standard_normal(std.size) * std
    for k in range(steps):
        x = a * x + noise[k]
        out[k] = x
    return out
