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
    predicted = physics_rollout(windows, constants.current(), batch_size=None)
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
    if horizon < 1:
        raise ValueError(f"horizon must be >= 1 step, got {horizon}")
    window = WindowConfig(history=2, horizon=horizon, stride=1)
    if not isinstance(data, Dataset):
        data = load_dataset(data, window=window, params=params)
    initial = params or data.params
    train, val = (_windows(data, split, window, max_windows, seed) for split in ("train", "val"))
    if len(train) == 0:
        raise ValueError(f"{data.folder}: no training window of {window.length} steps")
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
