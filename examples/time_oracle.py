"""Time one oracle look-ahead: K plans of N steps from a plant's state, stepped together
(``lab.control.plant_batch.PlantBatch``) against the loop over K twins it replaced
(``Plant.fork`` / ``advance``). Seconds per control step, one process, one thread.

    python examples/time_oracle.py --samples 256 --horizon 15
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from slungload.lab.control.plant_batch import PlantBatch
from slungload.sim.config import SimConfig
from slungload.sim.plant import Plant


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256, help="K (default 256)")
    parser.add_argument("--horizon", type=int, default=15, help="N (default 15)")
    parser.add_argument("--repeats", type=int, default=5, help="batched calls timed (default 5)")
    parser.add_argument("--loop", type=int, default=64, help="plans the loop flies (default 64)")
    args = parser.parse_args()
    plant = Plant(SimConfig())
    rng = np.random.default_rng(0)
    hover = [14.2, 0.0, 0.0, 0.0]
    spread = [1.0, 0.5, 0.5, 0.2]
    plans = np.tile(hover, (args.samples, args.horizon, 1)) + rng.normal(
        0.0, spread, (args.samples, args.horizon, 4)
    )
    batch = PlantBatch(plant)
    batch.advance(plans, np.zeros(3))  # warm-up
    start = time.perf_counter()
    for _ in range(args.repeats):
        batch.advance(plans, np.zeros(3))
    batched = (time.perf_counter() - start) / args.repeats
    twin = plant.fork()
    start = time.perf_counter()
    for plan in plans[: args.loop]:
        twin.sync(plant)
        for u in plan:
            twin.advance(float(u[0]), u[1:], np.zeros(3))
    loop = (time.perf_counter() - start) * args.samples / min(args.loop, args.samples)
    print(
        f"K = {args.samples}, N = {args.horizon}: batched {batched:.3f} s, loop {loop:.3f} s "
        f"per control step ({loop / batched:.1f}x)"
    )


if __name__ == "__main__":
    main()
