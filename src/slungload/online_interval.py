"""An ensemble's interval tracked in flight from its own resolved predictions.

A calibrated ensemble (``models.ensemble.Calibration``) states ``mean +- half_width``, the
half width fitted on held-out flights of the vehicle it was trained on. On a vehicle it was
not trained on (a longer cable) the members can agree on a wrong prediction: the interval is
too narrow, and the spread-based novelty flag stays silent because the spread did not grow.

In flight every prediction resolves: N steps after it was made, each of its steps has been
flown. ``OnlineInterval`` keeps one multiplier on the calibrated half width per horizon step
and state group (``layout.GROUPS``) and moves it, in log, after each resolved prediction: up
by ``rate * level`` per unit share of a group's components that fell outside, down by
``rate * (1 - level)`` per unit share inside. This is quantile tracking (Angelopoulos, Candès
and Tibshirani, "Conformal PID control", 2023), the scale form of adaptive conformal inference
(Gibbs and Candès, 2021): over a long flight each step's share of misses tends to 1 - level
whatever the plant, so the interval widens where the model is wrong and the spread is not.
``surprised``: a multiplier above ``OnlineIntervalConfig.surprise``, the model's errors that
many times what its calibration expects.

The resolution is causal and what a vehicle can do: the prediction made N steps ago, from the
state then and the inputs since applied, is compared with the N states since flown
(``normalized_errors``). numpy only (the onboard path).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .layout import GROUPS, QUAT, STATE_DIM


@dataclass(frozen=True)
class OnlineIntervalConfig:
    """The interval tracked in flight's constants: adaptive conformal.

    rate: the change of the log multiplier per resolved prediction, per unit of the share of
    its components outside the interval above 1 - level (a miss widens by rate x level, a hit
    narrows by rate x (1 - level)). surprise: the multiplier (on any step and state group)
    beyond which the model is flagged as surprised: its errors that many times what its
    calibration expects.
    """

    rate: float = 0.05
    surprise: float = 2.0

    def __post_init__(self) -> None:
        if not self.rate > 0.0:
            raise ValueError(f"OnlineIntervalConfig.rate must be > 0, got {self.rate}")
        if not self.surprise > 1.0:
            raise ValueError(f"OnlineIntervalConfig.surprise must be > 1, got {self.surprise}")


def _group_weights() -> np.ndarray:
    """(13, G): each component's share of its group (a column sums to 1)."""
    w = np.zeros((STATE_DIM, len(GROUPS)))
    for g, sl in enumerate(GROUPS.values()):
        cols = np.arange(STATE_DIM)[sl]
        w[cols, g] = 1.0 / len(cols)
    return w


def group_of_component() -> np.ndarray:
    """(13,) the ``layout.GROUPS`` index of each state component."""
    return np.argmax(_group_weights(), axis=1)


def normalized_errors(mean: np.ndarray, half_width: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """|truth - mean| / half_width, (..., N, 13) each, package layout (quaternion w-x-y-z);
    the truth's quaternion is first turned to the mean's hemisphere. 1: on the interval's
    edge."""
    truth = np.array(truth, dtype=np.float64)
    q = truth[..., QUAT]
    truth[..., QUAT] = q * np.where((q * mean[..., QUAT]).sum(-1, keepdims=True) < 0, -1.0, 1.0)
    return np.abs(truth - mean) / np.maximum(half_width, 1e-12)


class OnlineInterval:
    """Multipliers (N, G) on a calibrated interval's half width, moved by resolved errors."""

    def __init__(
        self, horizon: int, level: float, config: OnlineIntervalConfig | None = None
    ) -> None:
        if horizon < 1:
            raise ValueError(f"OnlineInterval: horizon must be >= 1, got {horizon}")
        if not 0.0 < level < 1.0:
            raise ValueError(f"OnlineInterval: level must lie in (0, 1), got {level}")
        self.config = config or OnlineIntervalConfig()
        self.level = level
        self.log_scale = np.zeros((horizon, len(GROUPS)))
        self._weights = _group_weights()
        self.resolved = 0  # predictions resolved so far

    @property
    def horizon(self) -> int:
        return self.log_scale.shape[0]

    @property
    def multiplier(self) -> np.ndarray:
        """(N, G) the factor on the calibrated half width per step and group."""
        return np.exp(self.log_scale)

    def component_multiplier(self, steps: int | None = None) -> np.ndarray:
        """(steps, 13) the multiplier per step and component (past N: step N's)."""
        rows = np.minimum(np.arange(steps or self.horizon), self.horizon - 1)
        return self.multiplier[rows][:, group_of_component()]

    @property
    def surprised(self) -> bool:
        """Some step and group's errors beyond ``config.surprise`` times the calibrated ones."""
        return bool(self.log_scale.max() > np.log(self.config.surprise))

    def outside(self, ratio: np.ndarray) -> np.ndarray:
        """ratio (n <= N, 13) = |error| / calibrated half width -> (n, G): each group's share
        of components outside the interval as it stands."""
        mult = self.component_multiplier(ratio.shape[0])
        return (ratio > mult).astype(np.float64) @ self._weights

    def update(self, ratio: np.ndarray) -> None:
        """Move the multipliers by one resolved prediction: ratio (n <= N, 13), its steps
        1..n, |error| / the calibrated half width (``normalized_errors``)."""
        ratio = np.asarray(ratio, dtype=np.float64)
        if ratio.ndim != 2 or ratio.shape[1] != STATE_DIM or not 1 <= ratio.shape[0]:
            raise ValueError(f"OnlineInterval.update: expected (n, {STATE_DIM}), got {ratio.shape}")
        n = min(ratio.shape[0], self.horizon)
        if not np.isfinite(ratio[:n]).all():
            raise ValueError("OnlineInterval.update: non-finite errors")
        miss = self.outside(ratio[:n])
        self.log_scale[:n] += self.config.rate * (miss - (1.0 - self.level))
        self.resolved += 1
