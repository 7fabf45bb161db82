"""``slungload study control``: where the learned model pays in closed loop.

One command flies, on every maneuver x evaluation seed of a ``StudyConfig``:

- the simulator's PID and the payload-aware geometric controller (``geometric``);
- the MPC with the physics model, with the learned model and with the oracle (``oracle``: the
  simulator's own plant, the ceiling), at each horizon N of ``horizons`` (the oracle at
  ``oracle_horizons``);
- on each shifted plant of ``shifts`` (``SHIFTS``: heavier load, longer cable, stronger wind,
  slower thrust) the PID, the geometric controller and both real MPCs at ``shift_horizons``,
  every model built for the nominal vehicle.

Fair by construction: each real MPC's sampling noise, temperature and cost changes are chosen
at each horizon on the separate ``tuning_seeds`` (``tune_settings``, nominal plant), never on
the evaluation seeds; the physics model flies the largest K of ``PHYSICS_SAMPLES`` whose median
control step (sampling, prediction, cost) is within the learned model's at its K, and never
below that K (``equal_compute_samples``), per horizon. The oracle flies the learned MPC's
settings at its horizon (at its own K, ``oracle_samples``), so that the two differ only in their
model; without a learned model it flies the defaults.

Every flight lands as ``out/flights/<plant>/<controller>/<maneuver>_s<seed>.json`` (its
``closed_loop.flight_metrics`` row) and ``.npz`` (its log) as soon as it ends; a second run of
the same command flies only what is missing, so the expensive oracle can run as its own
process (``controllers``) beside the rest, once the real MPCs' settings are written.
``study_report`` turns the rows into the report.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ...config import VehicleParams
from ...control.closed_loop import FlightLog, flight_metrics, fly, log_path, read_log, write_log
from ...control.controllers import REFERENCE, reference_maker
from ...control.mpc import (
    InputLimits,
    MPCConfig,
    SamplingMPC,
    candidate_model,
    knots_for,
    mpc_maker,
)
from ...control.mppi import ReferenceAhead, has_members
from ...control.paired import PhysicsPaired
from ...deploy.backends import load_model
from ...deploy.predictor import torch_threads
from ...deploy.sidecar import sha256
from ...deploy.timing import time_calls
from ...fileio import read_json, write_json
from ...layout import LOAD_POS, POS, QUAT, STATE_DIM
from ...models.checkpoints import checkpoint_meta, checkpoint_path
from ...models.prediction import PHYSICS, PredictionModel
from ...sim.config import SimConfig, tuples_from_json
from ...sim.dataset import vehicle_params
from ...sim.plants import plant_config as named_plant
from ...workers import run_jobs
from .config import (
    NOMINAL,
    ORACLE,
    PHYSICS_SAMPLES,
    SHIFTS,
    STUDY_KINDS,
    TUNING_GRID,
    TUNING_ROUNDS,
    UNSAFE_SWING,
    StudyConfig,
    cost_changes,
    recorded_settings,
    settings_record,
)
from .oracle import PlantCandidates
from .results import mpc_label


@dataclass(frozen=True)
class Flown:
    """One controller of the study on one plant: how to build it for a flight seed."""

    plant: str  # NOMINAL or a SHIFTS name
    label: str  # the controller's name in the tables, e.g. "mpc-physics N=25"
    make: Callable[[int], Any]  # seed -> a fresh Controller


def run_study(
    learned: str | Path | None,
    out: str | Path,
    config: StudyConfig | None = None,
    *,
    controllers: Sequence[str] = STUDY_KINDS,
    plants: Sequence[str] | None = None,
    threads: int = 1,
    workers: int = 1,
    progress: Callable[[str], None] | None = print,
) -> list[dict[str, Any]]:
    """Fly what is missing of the study into ``out`` and return every row flown so far.

    learned: a trained run folder (None: no learned model, nor its equal-compute matching).
    controllers: the kinds to fly now (``STUDY_KINDS``), e.g. ("oracle",) in its own process;
    plants: the plants to fly now (NOMINAL and the config's shifts; default all), likewise.
    threads: torch threads while flying (restored after): one per process, so that processes
    flying side by side do not oversubscribe the cores, and the compute times are one core's.
    workers: flights flown at once, each in its own process (``workers.run_jobs``); the
    settings are tuned and matched first, in this process.
    """
    cfg = config or StudyConfig()
    unknown = set(controllers) - set(STUDY_KINDS)
    if unknown:
        raise ValueError(f"unknown controllers {sorted(unknown)}; known: {list(STUDY_KINDS)}")
    every = (NOMINAL, *cfg.shifts)
    plants = every if plants is None else tuple(plants)
    if set(plants) - set(every):
        raise ValueError(f"unknown plants {sorted(set(plants) - set(every))}; known: {list(every)}")
    out = Path(out)
    if (out / "results.json").exists():
        raise ValueError(f"{out} holds the flights of a `control` comparison (results.json), "
                         "which lie where the study's would land; use another --out")  # fmt: skip
    nominal = named_plant(cfg.plant)
    params = vehicle_params(nominal)
    limits = InputLimits.from_sim(nominal)
    models = _models(learned, params, cfg)
    with torch_threads(threads):
        # the oracle flies the learned MPC's settings: they are needed for it too, but an
        # oracle alone only reads them (two processes tuning at once could disagree)
        real = bool({PHYSICS, "learned"} & set(controllers))
        oracle = ORACLE in controllers and "learned" in models
        if oracle and not real and not (out / "settings.json").exists():
            raise ValueError(f"the oracle flies the learned MPC's settings, and {out} has no "
                             "settings.json yet: fly the real MPCs first (--controllers "
                             "physics,learned), or all together")  # fmt: skip
        # a folder's settings are checked whenever it has them, whatever flies now
        needed = real or oracle or (out / "settings.json").exists()
        settings = (_settings(out, cfg, models, learned, params, limits, progress)
                    if needed else {})  # fmt: skip
        if (
            ORACLE in controllers
            and "learned" not in models
            and "learned" in settings.get("mpc", {})
        ):
            raise ValueError(f"{out}'s oracle flies its learned MPC's settings: give the "
                             "learned model (--model) with the oracle")  # fmt: skip
        plans = _plan(cfg, settings, models, params, limits, nominal, controllers, plants)
        if workers <= 1:
            for flown in plans:
                plant_cfg = study_plant(cfg, flown.plant)
                for maneuver in cfg.maneuvers:
                    for seed in cfg.seeds:
                        fly_once(out, flown, maneuver, seed, plant_cfg, limits, cfg.steps, progress)
        else:
            learned_at = None if learned is None else str(learned)
            kinds = tuple(controllers)
            jobs = [_Job(str(out), learned_at, cfg, kinds, flown.plant, flown.label, maneuver,
                         seed, threads)
                    for flown in plans for maneuver in cfg.maneuvers for seed in cfg.seeds
                    if not _landed(out, flown, maneuver, seed)]  # fmt: skip
            for line in run_jobs(_fly_job, jobs, workers=workers, progress=False):
                if progress and line:
                    progress(line)
    return collect_rows(out)


@dataclass(frozen=True)
class _Job:
    """One flight of the study, as a worker process rebuilds it (it pickles)."""

    out: str
    learned: str | None
    cfg: StudyConfig
    controllers: tuple[str, ...]
    plant: str
    label: str
    maneuver: str
    seed: int
    threads: int


@lru_cache(maxsize=1)
def _worker_plans(
    out: str, learned: str | None, cfg: StudyConfig, controllers: tuple[str, ...]
) -> dict[tuple[str, str], Flown]:
    """Every (plant, label) -> ``Flown`` of the study, built once per worker process from the
    settings its parent wrote."""
    nominal = named_plant(cfg.plant)
    params = vehicle_params(nominal)
    models = _models(learned, params, cfg)
    path = Path(out) / "settings.json"
    settings = read_json(path) if path.exists() else {}
    plans = _plan(cfg, settings, models, params, InputLimits.from_sim(nominal), nominal,
                  controllers, (NOMINAL, *cfg.shifts))  # fmt: skip
    return {(f.plant, f.label): f for f in plans}


def _fly_job(job: _Job) -> str:
    """Fly one ``_Job`` in a worker; its progress line."""
    flown = _worker_plans(job.out, job.learned, job.cfg, job.controllers)[(job.plant, job.label)]
    lines: list[str] = []
    with torch_threads(job.threads):
        limits = InputLimits.from_sim(named_plant(job.cfg.plant))
        fly_once(Path(job.out), flown, job.maneuver, job.seed, study_plant(job.cfg, job.plant),
                 limits, job.cfg.steps, lines.append)  # fmt: skip
    return lines[0] if lines else ""


def _models(learned: str | Path | None, params: VehicleParams, cfg: StudyConfig) -> dict[str, Any]:
    """The physics model and, given a run folder, the learned one, on ``cfg.backend``; with
    ``cfg.with_physics`` the learned one is the network paired with the physics model."""
    models: dict[str, Any] = {PHYSICS: load_model(PHYSICS, params, backend=cfg.backend)}
    if learned is not None:
        models["learned"] = load_model(learned, backend=cfg.backend)
        if cfg.with_physics:
            models["learned"] = PhysicsPaired(candidate_model(models["learned"]),
                                              candidate_model(models[PHYSICS]),
                                              cfg.pair_window)  # fmt: skip
    return models


def study_plant(cfg: StudyConfig, plant: str) -> SimConfig:
    """The simulator's config of a study plant: NOMINAL (the study's named plant,
    ``StudyConfig.plant``) or a ``SHIFTS`` name (a shift of it)."""
    nominal = named_plant(cfg.plant)
    return nominal if plant == NOMINAL else SHIFTS[plant](nominal)


def _plan(cfg, settings, models, params, limits, nominal, controllers, plants) -> list[Flown]:
    """Every (plant, controller) to fly, plant by plant, the cheap controllers first."""
    plans: list[Flown] = []
    for plant in plants:
        plans += [Flown(plant, kind, reference_maker(kind, nominal))
                  for kind in REFERENCE if kind in controllers]  # fmt: skip
        horizons = cfg.horizons if plant == NOMINAL else cfg.shifted_horizons
        for kind in (PHYSICS, "learned"):
            if kind not in controllers or kind not in models:
                continue
            for n in horizons:
                tuned = tuples_from_json(settings["mpc"][kind][str(n)])
                mpc = cfg.mpc(**tuned, horizon=n, knots=knots_for(n),
                              samples=settings["samples"][kind][str(n)],
                              members=has_members(models[kind]))  # fmt: skip
                plans.append(Flown(plant, mpc_label(kind, n),
                                   mpc_maker(models[kind], limits, mpc, params)))  # fmt: skip
        if ORACLE in controllers and plant == NOMINAL:
            for n in cfg.oracle_horizons:
                chosen = (tuples_from_json(settings["mpc"]["learned"][str(n)])
                          if "learned" in models else {})  # fmt: skip
                mpc = cfg.mpc(**chosen, horizon=n, knots=knots_for(n), samples=cfg.oracle_samples)
                plans.append(Flown(plant, mpc_label(ORACLE, n),
                                   mpc_maker(PlantCandidates, limits, mpc, params)))  # fmt: skip
    return plans


def fly_once(out, flown: Flown, maneuver, seed, plant_cfg, limits, steps, progress) -> None:
    """Fly one flight of ``flown`` and land it under ``out`` (``closed_loop.log_path``) unless
    there."""
    if _landed(out, flown, maneuver, seed):
        return
    path = log_path(out, flown.plant, flown.label, maneuver, seed)
    start = time.perf_counter()
    log = fly(maneuver, seed, flown.make(seed), label=flown.label, config=plant_cfg, steps=steps)
    row = flight_metrics(log, limits, plant_cfg.cable_length)
    row.update(plant=flown.plant, wall_s=time.perf_counter() - start)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_log(path.with_suffix(".npz"), log)
    write_json(path.with_suffix(".json"), row)  # last: its presence means the flight is done
    if progress:
        status = "ok" if row["completed"] else f"STOPPED: {row['stopped']}"
        progress(
            f"{flown.plant} {maneuver} s{seed} {flown.label}: load {row['load_rmse']:.3f} m, "
            f"swing {row['swing_rms']:.1f} deg, {row['wall_s']:.1f} s ({status})"
        )


def _landed(out: Path, flown: Flown, maneuver: str, seed: int) -> bool:
    """Whether that flight's row is already under ``out`` (written last: the flight is done)."""
    return log_path(out, flown.plant, flown.label, maneuver, seed).with_suffix(".json").exists()


def collect_rows(out: str | Path) -> list[dict[str, Any]]:
    """Every flight row under ``out/flights``, in a stable order."""
    return [read_json(p) for p in sorted(Path(out).glob("flights/*/*/*.json"))]


def load_log(out: str | Path, row: dict[str, Any]) -> FlightLog:
    """The saved log of a row."""
    path = log_path(Path(out), row["plant"], row["controller"], row["maneuver"], row["seed"])
    return read_log(path.with_suffix(".npz"), row)


# --- settings: chosen once, written once --------------------------------------------------


def _settings(out, cfg, models, learned, params, limits, progress) -> dict[str, Any]:
    """The MPC settings and Ks of the study (``out/settings.json``): read back when there, so
    every process of one study flies the same ones; else tuned and matched now. The file names
    the learned network they were tuned for (``learned_network``): another one is refused."""
    path = Path(out) / "settings.json"
    network = learned_network(learned) if "learned" in models else None
    if path.exists():
        settings = read_json(path)
        mine, theirs = settings_record(cfg), recorded_settings(settings["config"])
        differ = [k for k in theirs if theirs[k] != mine[k]]
        if differ:
            raise ValueError(
                f"{path} was written for another study configuration ({', '.join(differ)} "
                "differ, and the MPC settings follow from them); use a new --out, or delete it "
                "to start over"
            )
        missing = sorted(set(models) - set(settings["mpc"]))
        if missing:
            raise ValueError(f"{path} holds no settings for the {', '.join(missing)} model (the "
                             "study was tuned without it); use a new --out")  # fmt: skip
        per_horizon = {str(n) for n in cfg.horizons}
        if any(set(chosen) != per_horizon for chosen in settings["mpc"].values()):
            raise ValueError(f"{path} holds one MPC setting for every horizon (written before "
                             "they were tuned per horizon); use a new --out")  # fmt: skip
        tuned_for = settings.get("learned_network")
        if network and not tuned_for:
            raise ValueError(
                f"{path} names no learned network (its settings could have been tuned for any); "
                "use a new --out"
            )
        if network and tuned_for["sha256"] != network["sha256"]:
            raise ValueError(
                f"{path} was tuned for the learned network {tuned_for['checkpoint']}, and "
                f"{network['checkpoint']} is another one (its checkpoint differs): its flights "
                "would mix two networks; use a new --out"
            )
        return settings
    tuned = {kind: {str(n): tune_settings(model, limits, params, cfg, n, progress) if cfg.tune
                    else ({}, None) for n in cfg.horizons}
             for kind, model in models.items()}  # fmt: skip
    mpc = {kind: {n: choice for n, (choice, _) in per.items()} for kind, per in tuned.items()}
    samples = {kind: {str(n): cfg.samples for n in cfg.horizons} for kind in models}
    if "learned" in models:
        for n in cfg.horizons:

            def mpc_of(kind: str, n: int = n) -> Callable[[int], SamplingMPC]:
                tuned = tuples_from_json(mpc[kind][str(n)])
                return lambda k: mpc_maker(models[kind], limits, cfg.mpc(
                    **tuned, horizon=n, knots=knots_for(n), samples=k,
                    members=has_members(models[kind])), params)(0)  # fmt: skip

            samples[PHYSICS][str(n)] = equal_compute_samples(
                mpc_of(PHYSICS), mpc_of("learned"), cfg.samples
            )
    settings = {"config": settings_record(cfg), "mpc": mpc, "samples": samples}
    if cfg.tune:  # each choice's tuning_score, so that each model's best horizon can be named
        settings["tuning_score"] = {kind: {n: list(score) for n, (_, score) in per.items()}
                                    for kind, per in tuned.items()}  # fmt: skip
    if network:
        settings["learned_network"] = network
    write_json(path, settings)
    return settings


def learned_network(learned: str | Path) -> dict[str, str | None]:
    """Which network a study's learned MPC flies: its checkpoint's path and SHA-256, and the
    preset it trained with."""
    path = checkpoint_path(learned)
    preset = checkpoint_meta(path).get("preset")
    return {"checkpoint": str(path), "sha256": sha256(path), "preset": preset}


def tune_settings(
    model: PredictionModel,
    limits: InputLimits,
    params: VehicleParams,
    cfg: StudyConfig,
    horizon: int,
    progress: Callable[[str], None] | None = None,
) -> tuple[dict[str, Any], tuple[int, int, float]]:
    """The MPC settings that fly the tuning seeds (nominal plant, N = ``horizon``, K =
    ``cfg.samples`` for every model) best by ``tuning_score`` (the fewest lost flights, then
    the fewest swinging the load past ``UNSAFE_SWING``, then the lowest mean load RMSE),
    chosen by alternating rounds: the sampling noise scale and temperature of ``TUNING_GRID``
    at the cost chosen so far (first the default cost), then the cost changes of ``cost_changes``
    at the noise chosen so far, until a round keeps the choice or ``TUNING_ROUNDS`` have run.
    Alternating, because a noise that swings the load under the default cost may fly best
    under the swing bound. A choice is flown once; the current one is kept unless another
    scores strictly better. Returns the ``MPCConfig`` fields chosen, e.g. {"temperature",
    "thrust_std", "rate_std", "max_swing"}, and their ``tuning_score``."""
    base = MPCConfig()
    noises = [{"temperature": temperature, "thrust_std": base.thrust_std * scale,
               "rate_std": tuple(r * scale for r in base.rate_std)}
              for temperature, scale in TUNING_GRID]  # fmt: skip
    costs = cost_changes(cfg.cost, cfg.lean)
    flown: dict[tuple, tuple[int, int, float]] = {}

    def score(noise: dict[str, Any], cost: dict[str, float]) -> tuple[int, int, float]:
        choice = {**noise, **cost}
        key = tuple(sorted(choice.items()))
        if key not in flown:
            flown[key] = _score(model, limits, params, cfg, horizon, choice, progress)
        return flown[key]

    noise, cost = noises[0], costs[0]
    for round_ in range(TUNING_ROUNDS):
        before = noise, cost
        pairs = [(n, cost) for n in noises] if round_ % 2 == 0 else [(noise, c) for c in costs]
        for n, c in pairs:
            if score(n, c) < score(noise, cost):
                noise, cost = n, c
        if round_ > 0 and (noise, cost) == before:
            break
    return {**noise, **cost}, score(noise, cost)


def best_horizons(settings: dict[str, Any]) -> dict[str, int]:
    """Each model's best horizon by the ``tuning_score`` of its chosen settings on the tuning
    seeds (a study's settings.json, tuned at two horizons or more); {} when it has none."""
    scores = settings.get("tuning_score", {})
    return {kind: int(min(per, key=lambda n: tuple(per[n])))
            for kind, per in scores.items() if len(per) > 1}  # fmt: skip


def _score(
    model, limits, params, cfg: StudyConfig, n: int, choice: dict[str, Any], progress
) -> tuple[int, int, float]:
    """``tuning_score`` of ``choice`` (``MPCConfig`` fields) on the tuning seeds."""
    nominal = named_plant(cfg.plant)
    mpc = cfg.mpc(**choice, horizon=n, knots=knots_for(n), samples=cfg.samples,
                  members=has_members(model))  # fmt: skip
    rows = [flight_metrics(fly(man, seed, mpc_maker(model, limits, mpc, params)(seed),
                               label="tuning", config=nominal, steps=cfg.steps),
                           limits, nominal.cable_length)
            for man in cfg.maneuvers for seed in cfg.tuning_seeds]  # fmt: skip
    score = tuning_score(rows)
    if progress:
        shown = ", ".join(f"{k} {v}" for k, v in choice.items())
        progress(f"tuning {model.name} N={n}: {shown}: {score[0]} lost, {score[1]} past "
                 f"{UNSAFE_SWING:g} deg, load RMSE {score[2]:.3f} m")  # fmt: skip
    return score


def tuning_score(rows: Sequence[dict[str, Any]]) -> tuple[int, int, float]:
    """How a choice flew its tuning flights (``flight_metrics`` rows), lower is better: flights
    lost, flights that swung the load past ``UNSAFE_SWING`` deg (a lost one counts once, as
    lost), mean load RMSE (m) of the flights flown to the end."""
    lost = sum(not r["completed"] for r in rows)
    unsafe = sum(r["completed"] and r["swing_max"] > UNSAFE_SWING for r in rows)
    done = [r["load_rmse"] for r in rows if r["completed"]]
    return lost, unsafe, float(np.mean(done)) if done else np.inf


def equal_compute_samples(
    physics: Callable[[int], SamplingMPC],
    learned: Callable[[int], SamplingMPC],
    k: int,
    repeats: int = 30,
) -> int:  # timed on the caller's torch threads (run_study: one)
    """The largest K of ``PHYSICS_SAMPLES`` whose median whole control step (sampling,
    prediction, cost, weights: ``MPPIController.step``) takes no longer than the learned
    model's at K = ``k``; at least ``k``. ``physics`` and ``learned``: K -> a fresh MPC."""
    rng = np.random.default_rng(0)
    hover = np.zeros(STATE_DIM)  # hanging still 1.5 m up, level, plus a little noise
    hover[POS], hover[QUAT], hover[LOAD_POS] = (0, 0, 1.5), (1, 0, 0, 0), (0, 0, 0.8)

    def median_s(make: Callable[[int], SamplingMPC], samples: int) -> float:
        mpc = make(samples)
        n = mpc.cfg.horizon
        ref = ReferenceAhead(np.tile(hover[POS], (n, 1)), np.zeros((n, 3)), np.zeros(n),
                             np.zeros((n, 3)))  # fmt: skip
        states = hover + 1e-3 * rng.standard_normal((repeats + 3, STATE_DIM))
        states[:, QUAT] /= np.linalg.norm(states[:, QUAT], axis=1, keepdims=True)
        wall, _ = time_calls(lambda i: mpc.core.step(states[i], ref), repeats, 3)
        return float(np.median(wall))

    budget = median_s(learned, k)
    fits = [s for s in PHYSICS_SAMPLES if s >= k and median_s(physics, s) <= budget]
    return max(fits, default=k)
