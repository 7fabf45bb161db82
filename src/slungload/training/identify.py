"""Fit the discrete model's constants to flights: system identification (``slungload identify``).

The physics model's open-loop rollout from each training window's first state, driven by the
recorded inputs, is held against the recorded states over a short horizon; the fitted constants
(``models.constants.LearnedConstants``: load mass, cable length, load damping, thrust gain)
minimise the squared error summed over the state groups (m, m/s, quaternion error, m), as the
paper's RMSE weighs them. Float64, full batch, L-BFGS: four smooth parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from ..config import VehicleParams, WindowConfig
from ..data.dataset import Dataset, load_dataset
from ..data.windows import Windows, make_windows, physics_rollout
from ..input_lag import FIT_HORIZON, LAG_CHANNELS, NO_LAG, lag_text, warm_rows
from ..models.constants import FITTED, LearnedConstants
from ..state import group_errors


@dataclass(frozen=True)
class Identification:
    """What ``identify`` found: the fitted constants beside where they started, and the
    rollout error (mean over windows and steps of the summed squared group errors)."""

    params: VehicleParams  # fitted
    initial: VehicleParams
    table: dict[str, dict[str, float]]  # name -> {"value", "initial"}
    horizon: int  # steps of each rollout
    windows: int  # training windows fitted on
    train_error: tuple[float, float]  # before, after
    val_error: tuple[float, float]  # before, after (nan without validation windows)

    def summary(self) -> str:
        rows = [f"{'constant':<14} {'initial':>10} {'fitted':>10}  change"]
        for name, v in self.table.items():
            change = v["value"] / v["initial"] - 1.0
            rows.append(f"{name:<14} {v['initial']:>10.4g} {v['value']:>10.4g}  {change:+.1%}")
        (t0, t1), (v0, v1) = self.train_error, self.val_error
        rows.append(
            f"{self.horizon}-step rollout error: train {t0:.4g} -> {t1:.4g}, "
            f"val {v0:.4g} -> {v1:.4g} ({self.windows} training windows)"
        )
        return "\n".join(rows)


def rollout_error(constants: LearnedConstants, windows: Windows) -> Tensor:
    """Mean squared rollout error of the physics model with ``constants`` on ``windows``
    (history M = 1 or more: the rollout starts at x_{M-1}), summed over the state groups."""
    return _squared_error(physics_rollout(windows, constants.current(), batch_size=None), windows)


def _squared_error(predicted: Tensor, windows: Windows) -> Tensor:
    """Mean squared error of a prediction (W, N, 13) of ``windows``' futures, summed over the
    state groups (m, m/s, quaternion error, m), as the paper's RMSE weighs them."""
    errors = group_errors(predicted, windows.future.states.double())
    return sum(e.square().mean() for e in errors.values())


def identify(
    data: str | Path | Dataset,
    *,
    params: VehicleParams | None = None,
    fitted: tuple[str, ...] = FITTED,
    horizon: int = 10,
    max_windows: int = 8192,
    iterations: int = 50,
    seed: int = 0,
) -> Identification:
    """Fit ``fitted`` constants, starting from ``params`` (default: the dataset's own), to the
    training flights of a dataset folder; ``horizon`` steps per rollout, at most ``max_windows``
    windows (a seeded draw), ``iterations`` L-BFGS steps."""
    window = WindowConfig(history=2, horizon=horizon, stride=1)
    data, train, val = _fit_windows(data, params, window, max_windows, seed)
    initial = params or data.params
    constants = LearnedConstants(initial, fitted)
    before = (_value(constants, train), _value(constants, val))
    optimiser = torch.optim.LBFGS(
        constants.parameters(), lr=1.0, max_iter=iterations, line_search_fn="strong_wolfe"
    )

    def closure() -> Tensor:
        optimiser.zero_grad()
        loss = rollout_error(constants, train)
        loss.backward()
        return loss

    optimiser.step(closure)
    after = (_value(constants, train), _value(constants, val))
    return Identification(
        params=constants.params(),
        initial=initial,
        table=constants.table(),
        horizon=horizon,
        windows=len(train),
        train_error=(before[0], after[0]),
        val_error=(before[1], after[1]),
    )


def _fit_windows(
    data: str | Path | Dataset,
    params: VehicleParams | None,
    window: WindowConfig,
    count: int,
    seed: int,
) -> tuple[Dataset, Windows, Windows]:
    """The dataset (loaded with ``params`` unless given loaded) and at most ``count`` of its
    train and val windows (``_windows``); no training window is a ValueError naming why."""
    if not isinstance(data, Dataset):
        data = load_dataset(data, window=window, params=params)
    train, val = (_windows(data, split, window, count, seed) for split in ("train", "val"))
    if len(train) == 0:
        raise ValueError(f"{data.folder}: no training window of {window.length} steps")
    return data, train, val


def _windows(dataset: Dataset, split: str, window: WindowConfig, count: int, seed: int) -> Windows:
    """At most ``count`` windows (a seeded draw) of one split, cut for the rollouts."""
    flights = [dataset.flights[n] for n in dataset.splits[split].names if n in dataset.flights]
    windows = make_windows(flights, window)
    if len(windows) <= count:
        return windows
    pick = torch.randperm(len(windows), generator=torch.Generator().manual_seed(seed))[:count]
    return windows[pick.sort().values]


def _value(constants: LearnedConstants, windows: Windows) -> float:
    if len(windows) == 0:
        return float("nan")
    with torch.no_grad():
        return float(rollout_error(constants, windows))


# s: the time constants ``fit_input_lag`` tries for each channel
LAG_GRID = (0.0, 0.01, 0.02, 0.03, 0.04, 0.06, 0.08, 0.1, 0.13, 0.16, 0.2, 0.25, 0.3)


@dataclass(frozen=True)
class LagFit:
    """What ``fit_input_lag`` found: the commands' time constants (s, ``input_lag.LAG_CHANNELS``)
    and the rollout error (as ``Identification``'s) without a lag and with the fitted one."""

    lag: tuple[float, float, float]
    horizon: int
    windows: int
    train_error: tuple[float, float]  # no lag, fitted
    val_error: tuple[float, float]

    def summary(self) -> str:
        rows = [f"{name:<22} {tau:.3g} s" for name, tau in zip(LAG_CHANNELS, self.lag, strict=True)]
        (t0, t1), (v0, v1) = self.train_error, self.val_error
        rows.append(
            f"{self.horizon}-step rollout error: train {t0:.4g} -> {t1:.4g}, val {v0:.4g} -> "
            f"{v1:.4g} ({self.windows} training windows)"
        )
        rows.append(f"fly the physics model with it: --input-lag {lag_text(self.lag)}")
        return "\n".join(rows)


def fit_input_lag(
    data: str | Path | Dataset,
    *,
    params: VehicleParams | None = None,
    horizon: int = FIT_HORIZON,
    max_windows: int = 8192,
    seed: int = 0,
    grid: tuple[float, ...] = LAG_GRID,
    rounds: int = 2,
) -> LagFit:
    """The commands' lags (``input_lag.lagged``) that make the physics model's open-loop
    rollouts over ``horizon`` steps closest to the training flights: each channel's time
    constant chosen from ``grid`` in turn, ``rounds`` times over (a lag is one number a channel
    and the error is cheap; the grid keeps the fit free of the rollout's gradient through the
    filter). ``params``: the model's constants (default: the dataset's)."""
    probe = VehicleParams() if params is None else params
    warm = warm_rows((max(grid),) * len(LAG_CHANNELS), probe.dt)
    window = WindowConfig(history=warm + 2, horizon=horizon, stride=1)
    data, train, val = _fit_windows(data, params, window, max_windows, seed)
    params = params or data.params
    lag, best = NO_LAG, lagged_error(train, params, NO_LAG)
    for _ in range(rounds):
        for channel in range(len(LAG_CHANNELS)):
            for tau in grid:
                trial = tuple(tau if c == channel else t for c, t in enumerate(lag))
                error = lagged_error(train, params, trial)
                if error < best:
                    lag, best = trial, error
    return LagFit(
        lag=lag,  # type: ignore[arg-type]
        horizon=horizon,
        windows=len(train),
        train_error=(lagged_error(train, params, NO_LAG), best),
        val_error=tuple(lagged_error(val, params, t) for t in (NO_LAG, lag)),  # type: ignore[arg-type]
    )


def lagged_error(windows: Windows, params: VehicleParams, lag: tuple[float, ...]) -> float:
    """Mean squared rollout error of the physics model (summed over the state groups, as
    ``rollout_error``) on ``windows`` with the commands lagged by ``lag`` (``physics_rollout``'s
    lag; nan without windows)."""
    if len(windows) == 0:
        return float("nan")
    with torch.no_grad():
        return float(_squared_error(physics_rollout(windows, params, None, lag), windows))
