"""Training data on the states the MPC visits (``slungload record``).

A network trained on excited PID flights has seen swings up to about 40 deg; the MPC over it,
on a position step, swings the load past 60 deg and then predicts with a model that never saw
such a swing. Recording the MPC's own flights (sim seeds no benchmark flies) and training on
them beside the first data is one round of DAgger (Ross, Gordon and Bagnell, 2011): the model
learns the states its controller leads it into. Each flight is kept until it ends or the arena
stops it (what the vehicle did up to there is valid flight), in the published schema, as
``simulate`` writes a flight without excitation. The new dataset is the base's flights and
splits with the recorded flights added to its train split: its validation and test flights stay
the base's, so validation figures compare across the two.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

from ..._version import __version__
from ...config import WindowConfig, to_dict
from ...control.closed_loop import fly
from ...control.mpc import InputLimits, MPCConfig, knots_for, mpc_maker
from ...data.folder import read_splits
from ...data.readers import flight_files
from ...data.writer import DatasetWriter
from ...deploy.backends import load_model
from ...deploy.predictor import torch_threads
from ...fileio import read_json, write_npz
from ...models.prediction import PredictionModel
from ...sim.config import SimConfig, vehicle_params
from ...sim.plants import plant_config
from ...vehicle_file import VEHICLE_FILE, load_vehicle
from ...workers import run_jobs
from .config import RecordConfig


@dataclass(frozen=True)
class Recorded:
    """What ``record_flights`` wrote."""

    folder: Path
    flights: tuple[str, ...]  # recorded flight names, in the train split
    stopped: tuple[str, ...]  # those the arena stopped early (kept up to there)
    skipped: tuple[str, ...]  # too short for one training window (not written)


@dataclass(frozen=True)
class _Job:
    model: str
    maneuver: str
    seed: int
    config: RecordConfig
    path: Path
    threads: int


def record_flights(
    model: str | Path,
    base: str | Path,
    out: str | Path,
    config: RecordConfig = RecordConfig(),  # noqa: B008 (frozen)
    *,
    workers: int = 1,
    threads: int = 1,
    progress: bool = True,
) -> Recorded:
    """Fly the MPC over ``model`` (a run folder, or "physics") on ``config.flights`` in the
    nominal simulator and write ``out``: the dataset ``base`` (simulated flights of that
    simulator, ``_base_sim``) with the recorded flights joining its train split, in the order of
    ``config.flights``. Flights shorter than one training window (``WindowConfig().length``)
    are left out. Nothing is left at ``out`` if it fails."""
    base = Path(base)
    sim = _base_sim(base, config.plant)
    splits = read_splits(base)
    files = flight_files(base)
    plan = [(maneuver, seed, f"mpc_{maneuver}_{seed}")
            for maneuver, count in config.flights
            for seed in range(config.first_seed, config.first_seed + count)]  # fmt: skip
    taken = sorted({name for _, _, name in plan} & set(files))
    if taken:
        raise ValueError(
            f"{base} already holds flights named {taken[:3]}{' ...' if len(taken) > 3 else ''} "
            f"(recorded from sim seed {config.first_seed} on before?); record from another first "
            "seed"
        )
    writer = DatasetWriter(out)
    with writer:
        for split in splits.values():
            for name in split:
                shutil.copyfile(
                    files[name], writer.flight_path(name).with_suffix(files[name].suffix)
                )
        jobs = [_Job(str(model), maneuver, seed, config, writer.flight_path(name), threads)
                for maneuver, seed, name in plan]  # fmt: skip
        done = {name: (steps, stopped) for name, steps, stopped in run_jobs(
            _record, jobs, workers=workers, progress=progress, desc="recording MPC flights",
            unit="flight")}  # fmt: skip
        names = [name for _, _, name in plan]
        short = [n for n in names if done[n][0] < WindowConfig().length]
        for name in short:
            writer.flight_path(name).unlink()
        kept = [n for n in names if n not in short]
        made = {"sim": sim, "base": str(base.resolve()), "version": __version__,
                "recorded": {"model": str(model), **_jsonable(config)}}  # fmt: skip
        folder = writer.finish({**splits, "train": [*splits["train"], *kept]},
                               vehicle_params(plant_config(config.plant)), made)  # fmt: skip
    return Recorded(folder, tuple(kept), tuple(n for n in kept if done[n][1]), tuple(short))


def _base_sim(base: Path, plant: str) -> dict:
    """The base's simulator config (its ``vehicle.json``), checked to be the nominal simulator
    the MPC flies, excitation aside; a ValueError naming the file otherwise."""
    path = base / VEHICLE_FILE
    nominal = plant_config(plant)
    sim = read_json(path).get("sim") if path.is_file() else None
    if sim is None or load_vehicle(base) != vehicle_params(nominal):
        raise ValueError(
            f"{path}: the recorded flights fly the simulator's nominal vehicle "
            f"({vehicle_params(nominal).summary()}); the base must be flights `simulate` wrote "
            "of that vehicle (a vehicle.json with its constants and simulator config)"
        )
    if replace(SimConfig.from_dict(dict(sim)), excitation=nominal.excitation) != nominal:
        raise ValueError(
            f"{path}: the base was simulated with another simulator config (effects, noise or "
            "loads) than the nominal one the recorded flights fly"
        )
    return sim


def _jsonable(config: RecordConfig) -> dict:
    """``config`` for vehicle.json: an unbounded swing (inf) as null."""
    data = to_dict(config)
    if data["max_swing"] == float("inf"):
        data["max_swing"] = None
    return data


@lru_cache(maxsize=1)
def _model(spec: str, backend: str, plant: str) -> PredictionModel:
    """The MPC's model, loaded once per process (every flight of a recording flies the same)."""
    return load_model(spec, vehicle_params(plant_config(plant)), backend=backend)


def _record(job: _Job) -> tuple[str, int, str | None]:
    """Fly one recorded flight and write it; (name, recorded steps, why it stopped or None)."""
    cfg = job.config
    nominal = plant_config(cfg.plant)
    params = vehicle_params(nominal)
    with torch_threads(job.threads):
        model = _model(job.model, cfg.backend, cfg.plant)
        mpc = MPCConfig(samples=cfg.samples, horizon=cfg.horizon, knots=knots_for(cfg.horizon),
                        temperature=cfg.temperature, max_swing=cfg.max_swing)  # fmt: skip
        controller = mpc_maker(model, InputLimits.from_sim(nominal), mpc, params)(job.seed)
        log = fly(job.maneuver, job.seed, controller, label="record", config=nominal,
                  steps=cfg.steps)  # fmt: skip
    arrays = log.published(nominal.control_dt)
    write_npz(job.path, arrays)
    return job.path.stem, len(arrays["time"]), log.stopped
