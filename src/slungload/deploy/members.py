"""An ensemble's members in numpy: their mean and the novelty flag (the onboard MPC's, on
either exported format; ``models.ensemble`` holds the torch originals, tests hold them equal).
numpy only."""

from __future__ import annotations

from dataclasses import asdict, is_dataclass
from statistics import NormalDist

import numpy as np

from ..layout import GROUPS, QUAT
from ..online_interval import group_of_component


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


def interval_std(std: np.ndarray, calibration: dict, shift: np.ndarray | None) -> np.ndarray:
    """``models.ensemble.Calibration.interval_std`` in numpy: the members' std (..., N, 13), or
    with the calibration's ``constants_shift`` sqrt(std^2 + shift^2), shift (..., N, 13) from
    ``deploy.compiled.physics.candidates_shift``."""
    if not calibration.get("constants_shift"):
        if shift is not None:
            raise ValueError("a constants shift given to a calibration fitted without one")
        return std
    if shift is None:
        raise ValueError(
            "this calibration widens the spread by the physics model's constants shift "
            "(calibrate --constants-shift), and no shift was given"
        )
    return np.sqrt(std * std + np.asarray(shift, np.float64) ** 2)


def members_half_width(
    members: np.ndarray, calibration: dict, shift: np.ndarray | None = None
) -> np.ndarray:
    """Members' predictions (E, ..., N, 13) -> the calibrated interval's half width (..., N,
    13): z(level) x the fitted scale per step and group x the members' std (widened by
    ``shift`` where the calibration asks: ``interval_std``); ``models.ensemble.Calibration.
    half_width`` in numpy, a test holds the two equal; past the calibration's steps, its last
    row."""
    std = interval_std(_aligned(members).std(0, ddof=1), calibration, shift)
    scale = np.asarray(calibration["scale"], np.float64)  # (N_cal, G)
    if scale.shape[1] != len(GROUPS):
        raise ValueError(f"a calibration of {scale.shape[1]} groups, not {len(GROUPS)}")
    rows = np.minimum(np.arange(std.shape[-2]), len(scale) - 1)
    z = NormalDist().inv_cdf(0.5 + calibration["level"] / 2.0)
    return z * scale[rows][:, group_of_component()] * std


def calibration_of(model: object) -> dict | None:
    """An ensemble's calibration as a dict (an exported file's already is one; the torch
    ensemble's ``Calibration`` as its fields), None where it has none."""
    calibration = getattr(model, "calibration", None)
    if is_dataclass(calibration):
        calibration = asdict(calibration)
    return calibration if isinstance(calibration, dict) else None


def members_novel(
    members: np.ndarray, calibration: dict | None, shift: np.ndarray | None = None
) -> np.ndarray:
    """Members' predictions (E, K, N, 13) -> (K,) bool: the spread (widened by ``shift``
    where the calibration asks, ``interval_std``) beyond what the calibration's windows showed
    (``models.ensemble.Calibration.novel`` in numpy, a test holds the two equal;
    ``calibration`` as a dict); all False without a calibration."""
    if calibration is None:
        return np.zeros(members.shape[1], bool)
    std = interval_std(_aligned(members).std(0, ddof=1), calibration, shift)  # (K, N, 13)
    ref = np.asarray(calibration["reference_std"], np.float64)
    ref = ref[np.minimum(np.arange(std.shape[-2]), len(ref) - 1)]
    score = (std / np.maximum(ref, 1e-12)).mean(axis=(-2, -1))
    return score > calibration["novelty_threshold"]
