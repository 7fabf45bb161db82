"""An ensemble's mean against each of its members, flight by flight: the combined RMSE at N
(the sum of the four groups' RMSE) on every flight of a split, and on how many flights the
mean is below every member (issue 50's count beyond the load range).

    python examples/ensemble_per_flight.py EA --data beyond --split all --horizon 50
"""

from __future__ import annotations

import argparse

import torch

from slungload.evaluation.metrics import COMBINED, compute_metrics
from slungload.evaluation.uncertainty import ensemble_and_windows
from slungload.fileio import EVERY
from slungload.models.ensemble import spread


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ensemble", help="ensemble folder")
    parser.add_argument("--data", required=True, help="dataset folder")
    parser.add_argument("--split", default="test", choices=("test", "val", EVERY),
                        help="flights (default test; all: every flight)")  # fmt: skip
    parser.add_argument("--horizon", type=int, default=50, help="N (default 50)")
    args = parser.parse_args()
    n = args.horizon
    # the windows as `uncertainty` cuts them: the members' own constants, stride 1
    model, windows, _ = ensemble_and_windows(args.ensemble, args.data, args.split, n)
    each = model.predict_windows_members(windows)  # (E, W, N, 13)
    mean = spread(each).mean

    def rmse(pred: torch.Tensor, mask: torch.Tensor | None = None) -> float:
        """Combined RMSE of ``pred`` (W, N, 13) over the windows of ``mask`` (all: None)."""
        if mask is None:
            return compute_metrics(pred, windows).rmse[COMBINED]
        return compute_metrics(pred[mask], windows[mask]).rmse[COMBINED]

    below = flown = 0
    for i, name in enumerate(windows.names):
        mine = windows.flight == i
        if not bool(mine.any()):
            continue
        ours, theirs = rmse(mean, mine), [rmse(e, mine) for e in each]
        flown += 1
        best = ours < min(theirs)
        below += best
        cells = " ".join(f"{v:.3f}" for v in theirs)
        print(
            f"{name}: mean {ours:.3f}, members {cells}" + ("  (below every member)" if best else "")
        )
    print(f"N = {n}: the mean below every member on {below} of {flown} flights")
    print(f"pooled: mean {rmse(mean):.3f}, members " + " ".join(f"{rmse(e):.3f}" for e in each))


if __name__ == "__main__":
    main()
