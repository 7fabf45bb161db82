"""Causal least-squares slopes, numpy: the weights of the smoothed load-state estimate
(``load_state.fit_load_state`` and its compiled copy), torch-free for the onboard path.
"""

from __future__ import annotations

import numpy as np

LOAD_FIT_STEPS = 9  # history steps of the smoothed load-state estimate (``fit_load_state``)


def load_fit_coefficients(steps: int, dt: float) -> np.ndarray:
    """(steps,) weights c with sum_j c_j y_{k-steps+1+j} = the slope at sample k of the
    least-squares quadratic through the last ``steps`` samples y, spaced ``dt`` s apart: a
    causal derivative with less noise than the backward difference (which is steps = 2, a
    line) and no lag for a constant acceleration."""
    if steps < 3:
        raise ValueError(f"load_fit_coefficients: a quadratic needs >= 3 steps, got {steps}")
    t = np.arange(-steps + 1, 1, dtype=np.float64) * dt
    basis = np.stack([np.ones_like(t), t, t * t], axis=-1)  # (steps, 3)
    return np.linalg.pinv(basis)[1]  # the row giving the linear coefficient = slope at t = 0
