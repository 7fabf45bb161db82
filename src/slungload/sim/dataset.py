"""Write a simulated dataset: one ``.npz`` per flight, the splits and ``vehicle.json``.

Flights run in parallel (a process pool); each flight's random streams come from
``SeedSequence(seed).spawn`` so the bytes depend on the seed only, not on the worker count.
The simulator is a data source above ``data/``: the folder is written by
``data.writer.DatasetWriter`` (the workers write into its temporary folder, renamed into place
at the end, so a crash leaves nothing half-written) and split by ``data.split.split_flights``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._version import __version__
from ..config import to_dict
from ..data.split import split_flights
from ..data.writer import DatasetWriter
from ..fileio import write_npz
from ..workers import run_jobs
from .config import SimConfig, vehicle_params
from .flight import simulate_flight
from .maneuvers import MANEUVERS


@dataclass(frozen=True)
class SimulatedDataset:
    """What ``simulate_dataset`` wrote."""

    folder: Path
    flights: tuple[str, ...]  # flight names (file stems), in generation order
    steps: tuple[int, ...]  # steps per flight
    splits: dict[str, tuple[str, ...]]  # split -> flight names
    seed: int
    elapsed: float  # s, wall-clock time of the generation

    @property
    def paths(self) -> tuple[Path, ...]:
        return tuple(self.folder / f"{name}.npz" for name in self.flights)


def flight_plan(n: int, maneuvers: Sequence[str] | None = None) -> list[tuple[str, str]]:
    """(maneuver family, flight name) for n flights: families in turn (all of ``MANEUVERS``,
    or ``maneuvers``), repetitions numbered."""
    families = list(MANEUVERS) if maneuvers is None else list(dict.fromkeys(maneuvers))
    unknown = [f for f in families if f not in MANEUVERS]
    if unknown or not families:
        raise ValueError(f"unknown maneuvers {unknown}; known: {sorted(MANEUVERS)}")
    plan = []
    for i in range(n):
        family = families[i % len(families)]
        plan.append((family, f"{family}_{i // len(families):02d}"))
    return plan


def _fly(job: tuple[str, str, np.random.SeedSequence, SimConfig, Path]) -> tuple[str, int]:
    family, name, seed, cfg, path = job
    flight = simulate_flight(family, seed=seed, config=cfg)
    write_npz(path, flight.arrays)
    return name, flight.steps


def simulate_dataset(
    out_dir: str | Path,
    *,
    flights: int = 48,
    seed: int = 0,
    config: SimConfig | None = None,
    workers: int = 2,
    progress: bool = True,
    overwrite: bool = False,
    maneuvers: Sequence[str] | None = None,
) -> SimulatedDataset:
    """Simulate ``flights`` flights into ``out_dir`` (npz per flight, splits, vehicle.json).

    Refuses a non-empty existing ``out_dir`` unless ``overwrite``. Same seed and config give
    the same bytes whatever ``workers`` is.
    """
    cfg = config or SimConfig()
    if flights < 1:
        raise ValueError(f"flights must be >= 1, got {flights}")
    writer = DatasetWriter(out_dir, overwrite=overwrite)  # flights at the top of the folder
    start = time.perf_counter()
    plan = flight_plan(flights, maneuvers)
    root = np.random.SeedSequence(seed)
    split_seed, *flight_seeds = root.spawn(flights + 1)
    with writer:
        jobs = [
            (family, name, s, cfg, writer.flight_path(name))
            for (family, name), s in zip(plan, flight_seeds, strict=True)
        ]
        # Torch-free workers: fork starts in milliseconds.
        steps = dict(
            run_jobs(
                _fly,
                jobs,
                workers=workers,
                progress=progress,
                desc="simulating flights",
                unit="flight",
                start="fork",
            )
        )
        names = [name for _, name in plan]
        lengths = [steps[n] for n in names]
        families = [family for family, _ in plan]
        splits = split_flights(names, lengths, np.random.default_rng(split_seed), families)
        out = writer.finish(splits, vehicle_params(cfg.nominal), _about(cfg, seed, flights))
    return SimulatedDataset(
        out, tuple(names), tuple(lengths), splits, seed, time.perf_counter() - start
    )


def _about(cfg: SimConfig, seed: int, flights: int) -> dict:
    """What made the data, for ``vehicle.json`` beside the constants. The load ranges are
    written only when set, so a dataset without them has the bytes it had before they existed
    (``SimConfig.from_dict`` reads their absence as none)."""
    sim = to_dict(cfg)
    if not cfg.loads.active:
        del sim["loads"]
    return {"sim": sim, "seed": seed, "flights": flights, "version": __version__}
