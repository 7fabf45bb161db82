"""Measure the in-flight constants estimate (``constants_estimate``) on simulated flights of
varied loads: per-window errors of the cable length and the load mass, and the load mass pooled
over each flight, clean (thrust error, thrust offset, wind and motion-capture noise off) and
with every effect on.

    python examples/measure_constants_estimate.py [--flights 14] [--seed 2] [--out /tmp/est]

Loads 0.05-0.30 kg and cables 0.5-1.0 m drawn per flight; non-overlapping windows of M = 50
steps; the nominal constants (the ranges' midpoints, vehicle.json) give dt, g and the vehicle
mass. Prints one Markdown table.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from slungload.constants_estimate import estimate_constants, pool
from slungload.data.readers import read_flight
from slungload.sim import SimConfig, simulate_dataset
from slungload.sim.config import Effects, LoadRanges
from slungload.vehicle_file import load_vehicle

WINDOW = 50
CLEAN_OFF = ("thrust_error", "thrust_offset", "wind", "mocap_noise")


def errors(folder: Path) -> dict[str, np.ndarray]:
    """Relative errors: per window (cable, mass) and per flight (pooled mass)."""
    params = load_vehicle(folder)
    cable, mass, pooled = [], [], []
    for path in sorted(folder.glob("*.npz")):
        flight = read_flight(path, params)
        truth = flight.constants
        n = len(flight.states) // WINDOW
        x = torch.from_numpy(flight.states[: n * WINDOW]).reshape(n, WINDOW, -1)
        u = torch.from_numpy(flight.inputs[: n * WINDOW]).reshape(n, WINDOW, -1)
        est = estimate_constants(x, u, params)
        cable.append(est.cable_length.numpy() / truth.cable_length - 1.0)
        mass.append(est.mass_load.numpy() / truth.mass_load - 1.0)
        pooled.append(float(pool(est, 0).mass_load) / truth.mass_load - 1.0)
    return {"cable": np.concatenate(cable), "mass": np.concatenate(mass),
            "pooled": np.asarray(pooled)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flights", type=int, default=14)
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("/tmp/est"))
    args = parser.parse_args()
    loads = LoadRanges(load_mass=(0.05, 0.30), cable_length=(0.5, 1.0))
    print(
        "| effects | flights | windows | cable per window: median / p90 / max | "
        "mass per window: median / p90 | mass pooled per flight: median / max |"
    )
    print("|---|---|---|---|---|---|")
    for name, effects in (("clean", Effects().without(*CLEAN_OFF)), ("every effect", Effects())):
        folder = args.out / name.replace(" ", "-")
        config = replace(SimConfig(), effects=effects, loads=loads)
        simulate_dataset(folder, flights=args.flights, seed=args.seed, config=config,
                         overwrite=True, progress=False)  # fmt: skip
        e = {k: np.abs(v) * 100 for k, v in errors(folder).items()}
        print(
            f"| {name} | {len(e['pooled'])} | {len(e['cable'])} | "
            f"{np.median(e['cable']):.1f} % / {np.percentile(e['cable'], 90):.2f} % / "
            f"{e['cable'].max():.1f} % | {np.median(e['mass']):.1f} % / "
            f"{np.percentile(e['mass'], 90):.0f} % | {np.median(e['pooled']):.1f} % / "
            f"{e['pooled'].max():.0f} % |"
        )


if __name__ == "__main__":
    main()
