"""``slungload control``: the PID, MPC + physics model and MPC + each network, flown and measured.

``compare(models, maneuvers, seeds, samples, out)`` flies every controller on every maneuver
and seed (every unmodelled effect on), one MPC per prediction model and K in ``samples``, and
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

from ..config import VehicleParams
from ..deploy.compiled.batched import load_model
from ..deploy.predictor import torch_threads
from ..fileio import write_json
from ..models.checkpoints import checkpoint_meta
from ..models.prediction import PHYSICS, PredictionModel
from ..reporting import machine
from ..sim.config import SimConfig
from ..sim.controller import PIDController
from ..sim.dataset import vehicle_params
from ..sim.maneuvers import MANEUVERS
from .closed_loop import Arena, FlightLog, flight_metrics, fly, log_path, write_log
from .mpc import InputLimits, MPCConfig, knots_for, mpc_maker
from .report import write_report
from .results import ControlComparison
from .study_config import DEFAULT_MANEUVERS, NOMINAL

PID = "pid"


def compare(
    models: Sequence[str | Path] = (),
    maneuvers: Sequence[str] = DEFAULT_MANEUVERS,
    seeds: Sequence[int] = (100, 101, 102),
    samples: Sequence[int] = (32,),
    out: str | Path | None = None,
    *,
    horizon: int | None = None,
    steps: int | None = None,
    config: SimConfig | None = None,
    threads: int = 1,
    backend: str = "eager",
    progress: Callable[[str], None] | None = print,
) -> ControlComparison:
    """Fly the PID, MPC + physics and MPC + each network (run folders) and write the report.

    samples: K values; each prediction model runs once per K. horizon: the MPC's N (default
    ``MPCConfig.horizon``). steps: cut every flight to this many recorded steps (smoke runs).
    threads: torch threads while flying (restored after). backend: what the prediction models
    run on (``deploy.compiled.BACKENDS``: "eager" torch, "compiled" kernels, or "cuda").
    """
    unknown = [m for m in maneuvers if m not in MANEUVERS]
    if unknown:
        raise ValueError(f"unknown maneuvers {unknown}; known: {sorted(MANEUVERS)}")
    cfg = config or SimConfig()
    params = vehicle_params(cfg)
    limits = InputLimits.from_sim(cfg)
    predictors: list[PredictionModel] = [load_model(PHYSICS, params, backend=backend)]
    predictors += [load_model(m, backend=backend) for m in models]
    base = MPCConfig() if horizon is None else MPCConfig(horizon=horizon, knots=knots_for(horizon))
    out_dir = Path(out) if out is not None else None
    if out_dir is not None and (out_dir / "settings.json").exists():
        raise ValueError(f"{out_dir} holds a control study (settings.json), whose flights lie "
                         "where these would land; use another --out")  # fmt: skip
    # each network's training preset, for the report's smoke-run banner
    presets = {str(m): checkpoint_meta(m).get("preset") for m in models if str(m) != PHYSICS}
    plans = _plans(cfg, predictors, samples, base, limits, params)
    with torch_threads(threads):
        rows, logs = _fly_all(maneuvers, seeds, plans, cfg, limits, steps, out_dir, progress)
    settings = _settings(models, maneuvers, seeds, samples, base, limits, steps, threads)
    settings.update(backend=backend, presets=presets)
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
    """The controllers to fly: the PID, then one MPC per K and prediction model."""
    plans: list[_Plan] = [(PID, None, lambda seed: PIDController(cfg))]
    for k in samples:
        for model in predictors:
            mpc_cfg = replace(base, samples=int(k))
            plans.append((f"mpc-{model.name}", int(k), mpc_maker(model, limits, mpc_cfg, params)))
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
