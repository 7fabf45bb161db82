"""``slungload control``: the PID, MPC + physics model and MPC + each network, flown and measured.

``compare(models, out, config)`` flies every controller on every maneuver and seed of
``config.ComparisonConfig`` (every unmodelled effect on), one MPC per prediction model and K, and
writes into ``out``: ``results.json`` (one row of ``closed_loop.flight_metrics`` per flight,
the settings and the machine), each flight's log where the control study keeps it
(``closed_loop.log_path``: ``flights/nominal/<controller>/<maneuver>_s<seed>.npz``), and the
report (``report.write_report``: ``report.md`` and the figures). The statistics are in
``results``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from datetime import date
from pathlib import Path
from typing import Any

from ...config import VehicleParams
from ...control.closed_loop import Arena, FlightLog, flight_metrics, fly, log_path, write_log
from ...control.controllers import PID, reference_maker
from ...control.mpc import InputLimits, MPCConfig, candidate_model, mpc_maker
from ...control.mppi import has_members
from ...control.paired import PhysicsPaired
from ...control.split import ALL
from ...deploy.backends import load_model
from ...deploy.predictor import torch_threads
from ...fileio import write_json
from ...models.ensemble import model_meta
from ...models.prediction import PHYSICS, PredictionModel
from ...reporting import machine
from ...sim.config import SimConfig
from ...sim.dataset import vehicle_params
from ...sim.plants import plant_config
from .config import NOMINAL, ComparisonConfig
from .report import write_report
from .results import ControlComparison


def compare(
    models: Sequence[str | Path] = (),
    out: str | Path | None = None,
    config: ComparisonConfig | None = None,
    *,
    sim: SimConfig | None = None,
    threads: int = 1,
    progress: Callable[[str], None] | None = print,
) -> ControlComparison:
    """Fly the PID, MPC + physics and MPC + each network (run folders) as ``config`` says
    (default ``ComparisonConfig()``) on the plant ``sim`` (default: the named plant
    ``config.plant``, ``sim.plants``) and write the report into ``out`` (None: nothing
    written). threads: torch threads while flying (restored after)."""
    cfg = config or ComparisonConfig()
    plant = sim or plant_config(cfg.plant)
    params = vehicle_params(plant)
    limits = InputLimits.from_sim(plant)
    predictors: list[PredictionModel] = [load_model(PHYSICS, params, backend=cfg.backend)]
    predictors += [load_model(m, backend=cfg.backend) for m in models]
    if cfg.with_physics:  # each network priced together with the physics model
        if cfg.risk is None or not models:
            raise ValueError("--with-physics prices each --model's plans under it and physics "
                             "by --risk: give both")  # fmt: skip
        physics = candidate_model(predictors[0])
        predictors[1:] = [PhysicsPaired(candidate_model(p), physics, cfg.pair_window)
                          for p in predictors[1:]]  # fmt: skip
    base = cfg.mpc
    if (cfg.risk is not None or cfg.members != ALL) and not any(map(has_members, predictors)):
        raise ValueError("--risk and --members act on an ensemble's members, and no --model is "
                         "an ensemble")  # fmt: skip
    out_dir = Path(out) if out is not None else None
    if out_dir is not None and (out_dir / "settings.json").exists():
        raise ValueError(f"{out_dir} holds a control study (settings.json), whose flights lie "
                         "where these would land; use another --out")  # fmt: skip
    # each network's training preset, for the report's smoke-run banner
    presets = {str(m): model_meta(m).get("preset") for m in models if str(m) != PHYSICS}
    plans = _plans(plant, predictors, cfg.samples, base, limits, params)
    with torch_threads(threads):
        rows, logs = _fly_all(cfg.maneuvers, cfg.seeds, plans, plant, limits, cfg.steps, out_dir,
                              progress)  # fmt: skip
    settings = _settings(models, cfg.maneuvers, cfg.seeds, cfg.samples, base, limits, cfg.steps,
                         threads)  # fmt: skip
    settings.update(backend=cfg.backend, presets=presets)
    result = ControlComparison(rows, settings, out_dir, logs)
    if out_dir is not None:
        write_json(out_dir / "results.json", {"settings": settings, "rows": rows})
        write_report(result, out_dir)
    return result


_Plan = tuple[str, int | None, Callable[[int], Any]]  # (label, K or None, seed -> controller)


def _plans(
    cfg: SimConfig,
    predictors: list[PredictionModel],
    samples: Sequence[int],
    base: MPCConfig,
    limits: InputLimits,
    params: VehicleParams,
) -> list[_Plan]:
    """The controllers to fly: the PID, then one MPC per K and prediction model (``base.risk``
    and ``base.members`` for an ensemble only, named in its label)."""
    plans: list[_Plan] = [(PID, None, reference_maker(PID, cfg))]
    for k in samples:
        for model in predictors:
            risk, members = (base.risk, base.members) if has_members(model) else (None, ALL)
            mpc_cfg = replace(base, samples=int(k), risk=risk, members=members)
            label = f"mpc-{model.name}" + ("" if risk is None else f" risk {risk:g}")
            label += "" if members == ALL else f" {members}"
            plans.append((label, int(k), mpc_maker(model, limits, mpc_cfg, params)))
    return plans


def _fly_all(
    maneuvers: Sequence[str],
    seeds: Sequence[int],
    plans: list[_Plan],
    cfg: SimConfig,
    limits: InputLimits,
    steps: int | None,
    out_dir: Path | None,
    progress: Callable[[str], None] | None,
) -> tuple[list[dict[str, Any]], list[FlightLog]]:
    """Every plan on every maneuver and seed: the metric rows (with "K" and the wall time in
    s) and the flight logs, each log saved under ``out_dir/flights`` as it lands."""
    rows, logs = [], []
    for maneuver in maneuvers:
        for seed in seeds:
            for label, k, make in plans:
                name = label if k is None else f"{label} K={k}"
                start = time.perf_counter()
                log = fly(maneuver, seed, make(seed), label=name, config=cfg, steps=steps)
                row = flight_metrics(log, limits, cfg.cable_length)
                row["K"] = k
                row["wall_s"] = time.perf_counter() - start
                rows.append(row)
                logs.append(log)
                if out_dir is not None:
                    write_log(log_path(out_dir, NOMINAL, name, maneuver, seed).with_suffix(".npz"),
                              log)  # fmt: skip
                if progress:
                    progress(_progress_line(row))
    return rows, logs


def _settings(
    models: Sequence[str | Path],
    maneuvers: Sequence[str],
    seeds: Sequence[int],
    samples: Sequence[int],
    base: MPCConfig,
    limits: InputLimits,
    steps: int | None,
    threads: int,
) -> dict[str, Any]:
    """What was flown and where (the machine when the flights ended: timings depend on its
    load), for ``results.json`` and the report."""
    return {
        "models": [str(m) for m in models],
        "maneuvers": list(maneuvers),
        "seeds": list(seeds),
        "samples": [int(k) for k in samples],
        # null where MPCConfig holds +-inf (that term off), so the file stays standard JSON
        "mpc": {
            k: None if isinstance(v, float) and math.isinf(v) else v
            for k, v in vars(base).items()
            if k != "samples"
        },  # fmt: skip
        "limits": vars(limits),
        "arena": vars(Arena()),
        "steps": steps,
        "threads": threads,
        "machine": machine(),
        "date": date.today().isoformat(),
    }


def _progress_line(row: dict[str, Any]) -> str:
    status = "ok" if row["completed"] else f"STOPPED: {row['stopped']}"
    return (
        f"{row['maneuver']} seed {row['seed']} {row['controller']}: vehicle "
        f"{row['vehicle_rmse']:.3f} m, load {row['load_rmse']:.3f} m, swing RMS "
        f"{row['swing_rms']:.1f} deg, compute median {row['compute_median']:.1f} ms ({status})"
    )
