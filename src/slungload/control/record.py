"""Training data on the states the MPC visits (``slungload control --record``).

A network trained on excited PID flights has seen swings up to about 40 deg; the MPC over it,
on a position step, swings the load past 60 deg and then predicts with a model that never saw
such a swing. Recording the MPC's own flights (sim seeds no benchmark flies) and training on
them beside the first data is one round of DAgger (Ross et al., 2011): the model learns the
states its controller leads it into. Each flight is kept until it ends or the arena stops it
(what the vehicle did up to there is valid flight), in the published schema, as ``simulate``
writes it. The new dataset is the base's flights and splits with the recorded flights added to
its train split: its validation and test flights stay the base's, so validation figures compare
across the two.
"""

from __future__ import annotations

import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

from .._version import __version__
from ..config import VEHICLE_FILE, WindowConfig, to_dict
from ..data.dataset import read_splits
from ..data.readers import flight_files
from ..data.writer import DatasetWriter
from ..deploy.compiled.batched import load_model
from ..deploy.predictor import torch_threads
from ..fileio import read_json, write_npz
from ..sim.config import SimConfig, vehicle_params
from ..workers import run_jobs
from .closed_loop import fly
from .mpc import InputLimits, MPCConfig
from .study import _knots, _mpc
from .study_config import RecordConfig


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
    nominal simulator and
    write ``out``: the dataset ``base`` (flights of the simulator's nominal vehicle) with the
    recorded flights joining its train split. Nothing is left at ``out`` if it fails."""
    base = Path(base)
    params = vehicle_params(SimConfig())
    about = base / VEHICLE_FILE
    if not about.is_file() or read_json(about).get("vehicle") != to_dict(params):
        raise ValueError(
            f"{base}: the recorded flights fly the simulator's nominal vehicle "
            f"({params.summary()}); the base must be simulated flights of that vehicle "
            f"(its {VEHICLE_FILE} says which)"
        )
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
    shortest = WindowConfig().history + WindowConfig().horizon
    writer = DatasetWriter(out)
    with writer:
        for split in splits.values():
            for name in split:
                shutil.copyfile(files[name], writer.folder / files[name].name)
        jobs = [_Job(str(model), maneuver, seed, config, writer.flight_path(name), threads)
                for maneuver, seed, name in plan]  # fmt: skip
        results = list(run_jobs(_record, jobs, workers=workers, progress=progress, start="fork",
                                desc="recording MPC flights", unit="flight"))  # fmt: skip
        kept = tuple(name for name, steps, _ in results if steps >= shortest)
        for name, steps, _ in results:
            if steps < shortest:
                writer.flight_path(name).unlink()
        made = {"base": str(base), "recorded": {"model": str(model), **asdict(config)},
                "version": __version__}  # fmt: skip
        folder = writer.finish({**splits, "train": [*splits["train"], *kept]}, params, made)
    return Recorded(
        folder,
        kept,
        tuple(name for name, _, stopped in results if stopped and name in kept),
        tuple(name for name, steps, _ in results if steps < shortest),
    )


def _record(job: _Job) -> tuple[str, int, str | None]:
    """Fly one recorded flight and write it; (name, recorded steps, why it stopped or None)."""
    cfg = job.config
    nominal = SimConfig()
    params = vehicle_params(nominal)
    with torch_threads(job.threads):
        model = load_model(job.model, params, backend=cfg.backend)
        mpc = MPCConfig(samples=cfg.samples, horizon=cfg.horizon, knots=_knots(cfg.horizon),
                        temperature=cfg.temperature, max_swing=cfg.max_swing)  # fmt: skip
        controller = _mpc(model, InputLimits.from_sim(nominal), mpc, params)(job.seed)
        log = fly(
            job.maneuver, job.seed, controller, label="record", config=nominal, steps=cfg.steps
        )
    arrays = log.published(nominal.control_dt)
    write_npz(job.path, arrays)
    return job.path.stem, len(arrays["time"]), log.stopped
