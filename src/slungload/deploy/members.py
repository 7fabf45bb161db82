"""An ensemble's members in numpy: their mean and the novelty flag (the onboard MPC's, on
either exported format; ``models.ensemble`` holds the torch originals, tests hold them equal).
numpy only."""

from __future__ import annotations

import numpy as np

from ..layout import QUAT


def _aligned(members: np.ndarray) -> np.ndarray:
    """Members (E, ..., 13) with each quaternion turned to the first member's hemisphere."""
    q = members[..., QUAT]
    out = members.copy()
    out[..., QUAT] = q * np.where((q * q[:1]).sum(-1, keepdims=True) < 0, -1.0, 1.0)
    return out


def members_mean(members: np.ndarray) -> np.ndarray:
    """The members' mean (E, ..., 13) -> (..., 13) with a unit quaternion, each member's
    quaternion first turned to the first member's hemisphere: ``models.ensemble.spread``'s
    mean in numpy (a test holds the two equal)."""
    mean = _aligned(members).mean(0)
    norm = np.linalg.norm(mean[..., QUAT], axis=-1, keepdims=True)
    mean[..., QUAT] /= np.maximum(norm, 1e-12)
    return mean


def members_novel(members: np.ndarray, calibration: dict | None) -> np.ndarray:
    """Members' predictions (E, K, N, 13) -> (K,) bool: the spread beyond what the
    calibration's windows showed (``models.ensemble.Calibration.novel`` in numpy, a test
    holds the two equal; ``calibration`` as a dict); all False without a calibration."""
    if calibration is None:
        return np.zeros(members.shape[1], bool)
    std = _aligned(members).std(0, ddof=1)  # (K, N, 13)
    ref = np.asarray(calibration["reference_std"], np.float64)
    ref = ref[np.minimum(np.arange(std.shape[-2]), len(ref) - 1)]
    score = (std / np.maximum(ref, 1e-12)).mean(axis=(-2, -1))
    return score > calibration["novelty_threshold"]
