"""An ensemble's mean against physics and its members, step by step: the combined RMSE (the
sum of the four groups' RMSE) at each horizon step n alone, on a dataset's test flights.

    python examples/ensemble_per_step.py E100 --data data --horizon 100
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from slungload.config import WindowConfig
from slungload.data.dataset import load_dataset
from slungload.evaluation.evaluator import horizon_windows
from slungload.models.ensemble import load_members, spread
from slungload.models.prediction import PhysicsModel, load_prediction_model
from slungload.state import GROUPS, group_errors


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ensemble", help="ensemble folder")
    parser.add_argument("--data", required=True, help="dataset folder")
    parser.add_argument("--horizon", type=int, default=100, help="N (default 100)")
    args = parser.parse_args()
    _, members = load_members(args.ensemble)
    m, n = members[0].window.history, args.horizon
    window = WindowConfig(history=m, horizon=n, stride=1)
    dataset = load_dataset(args.data, window=window, params=members[0].params)
    windows = horizon_windows(dataset, history=m, horizons=(n,), split="test")[n]
    truth = windows.future.states.double()

    def per_step(pred: torch.Tensor) -> np.ndarray:
        errors = group_errors(pred.double(), truth)
        return sum(errors[g].square().mean(0).sqrt() for g in GROUPS).numpy()

    physics = per_step(PhysicsModel(dataset.params).predict_windows(windows))
    each = load_prediction_model(args.ensemble).predict_windows_members(windows)
    mean = per_step(spread(each).mean)
    worse = [int(i) + 1 for i in np.nonzero(mean >= physics)[0]]
    print(f"{len(windows)} windows; steps where the mean is not below physics: {worse or 'none'}")
    for step in sorted({1, 10, 25, 50, 75, 100, n} & set(range(1, n + 1))):
        p, e = physics[step - 1], mean[step - 1]
        print(f"step {step}: physics {p:.3f}, mean {e:.3f} ({e / p:.3f}x)")
    last = [per_step(e)[-1] for e in each]
    print("members at step", n, ":", " ".join(f"{v:.3f}" for v in last))


if __name__ == "__main__":
    main()
