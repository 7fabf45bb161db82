"""The paper's metrics (Section IV-B), per group g of ``state.GROUPS`` (position, velocity,
quaternion, load position), with W test windows and horizon N::

    e_g[j, k] = || x_hat_g[j, k] - x_g[j, k] ||       (quaternion: || q_hat (x) q^-1 - q_id ||)
    MAE_g[k]  = mean_j e_g[j, k], with Q1 / Q3 the 25th / 75th percentiles over j
    RMSE_g    = sqrt( sum_{j,k} e_g[j, k]^2 / (W N) ),  combined = sum of the four RMSE_g

The quaternion error is the paper's: it is not sign-invariant (q and -q differ by 2); the
data are sign-continuous (``state.quat_continuous``) and both predictors continue the sign of
the last measured quaternion, so no sign ambiguity arises. Network quaternions are normalised
before the error is taken (the slack variables are ignored). Horizon step k = 1 ... N predicts
x_{M-1+k}, i.e. k dt seconds ahead.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from torch import Tensor

from ..data.windows import Windows
from ..state import GROUPS, group_errors

COMBINED = "combined"
METRIC_KEYS = (*GROUPS, COMBINED)  # columns of the RMSE table


@dataclass(frozen=True)
class Curve:
    """MAE of one group per horizon step k = 1 ... N over the test windows, with quartiles.

    Arrays (N,) in the group's unit.
    """

    mean: np.ndarray
    q1: np.ndarray  # 25th percentile over windows
    median: np.ndarray
    q3: np.ndarray  # 75th percentile over windows

    def to_dict(self) -> dict[str, list[float]]:
        return {k: getattr(self, k).tolist() for k in ("mean", "q1", "median", "q3")}


def mae_curve(error: Tensor) -> Curve:
    """error (W, N) -> MAE_k and quartiles over the W windows, each (N,)."""
    e = error.detach().cpu().double().numpy()
    if e.shape[0] == 0:
        raise ValueError("no test windows: cannot compute an MAE")
    q1, median, q3 = np.percentile(e, [25.0, 50.0, 75.0], axis=0)
    return Curve(mean=e.mean(axis=0), q1=q1, median=median, q3=q3)


def rmse(error: Tensor) -> float:
    """sqrt(sum ||e||^2 / (W N)) of an error-norm array (W, N)."""
    return float(error.double().square().mean().sqrt())


@dataclass(frozen=True)
class Metrics:
    """Errors of one predictor on one set of windows."""

    horizon: int  # N
    windows: int  # W
    rmse: dict[str, float]  # METRIC_KEYS -> RMSE (group unit); "combined" = sum of the groups
    curves: dict[str, Curve]  # group -> MAE curve

    def to_dict(self) -> dict[str, Any]:
        return {
            "horizon": self.horizon,
            "windows": self.windows,
            "rmse": dict(self.rmse),
            "mae": {g: c.to_dict() for g, c in self.curves.items()},
        }


def metrics_from_errors(errors: Mapping[str, Tensor]) -> Metrics:
    """{group: (W, N)} error norms -> RMSE per group and combined, MAE curves."""
    values = {g: rmse(errors[g]) for g in GROUPS}
    values[COMBINED] = sum(values[g] for g in GROUPS)
    first = errors[next(iter(GROUPS))]
    return Metrics(
        horizon=int(first.shape[1]),
        windows=int(first.shape[0]),
        rmse=values,
        curves={g: mae_curve(errors[g]) for g in GROUPS},
    )


def compute_metrics(pred: Tensor, windows: Windows) -> Metrics:
    """Metrics of predictions (W, N, 13) against the windows' future states."""
    return metrics_from_errors(group_errors(pred, windows.future.states))
