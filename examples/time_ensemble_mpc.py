"""Time the MPC's candidates call of an ensemble against one of its members: K plans of N
steps on one prediction backend, one thread, the two calls interleaved; medians in ms.

    python examples/time_ensemble_mpc.py E --data data --samples 256 --horizon 15
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from slungload.config import WindowConfig
from slungload.control.mpc import candidate_model
from slungload.data.dataset import load_dataset
from slungload.deploy.backends import load_model
from slungload.models.ensemble import read_manifest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ensemble", help="ensemble folder")
    parser.add_argument("--data", required=True, help="dataset folder (a test window's history)")
    parser.add_argument("--samples", type=int, default=256, help="K (default 256)")
    parser.add_argument("--horizon", type=int, default=15, help="N (default 15)")
    parser.add_argument("--backend", default="compiled", help="default compiled")
    parser.add_argument("--calls", type=int, default=40, help="timed pairs (default 40)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    first = str(read_manifest(args.ensemble).members[0])
    one = candidate_model(load_model(first, backend=args.backend))
    every = candidate_model(load_model(args.ensemble, backend=args.backend))
    m, n, k = one.history, args.horizon, args.samples
    dataset = load_dataset(args.data, window=WindowConfig(history=m, horizon=n))
    w = dataset.splits["test"][100:101]
    x, u = w.states[0, :m].double().numpy(), w.inputs[0, : m - 1].double().numpy()
    rng = np.random.default_rng(0)
    plans = w.inputs[0, m - 1 : m - 1 + n].double().numpy() + rng.normal(0, 0.3, (k, n, 4))
    times = []
    for _ in range(args.calls + 5):
        pair = []
        for model in (one, every):
            start = time.perf_counter()
            model.predict_candidates(x, u, plans)
            pair.append(1e3 * (time.perf_counter() - start))
        times.append(pair)
    t = np.array(times[5:])
    print(f"K = {k}, N = {n}, {args.backend}, one thread: one member {np.median(t[:, 0]):.1f} ms, "
          f"the ensemble {np.median(t[:, 1]):.1f} ms ({np.median(t[:, 1] / t[:, 0]):.2f}x, "
          f"the median of {args.calls} paired ratios)")  # fmt: skip


if __name__ == "__main__":
    main()
