"""``evaluate``: trained runs and the physics-only predictor on the test flights of a dataset,
at every horizon, collected into a ``Report`` (and written by ``report.write_report``).

Read top to bottom: test windows per horizon, the candidates, the example window for the
figures, ``evaluate_predictors`` (the loop), and the entry ``evaluate`` that loads runs and a
dataset. The metrics are in ``metrics.py``; every candidate is a prediction model
(``models.prediction``) run through ``predict_windows``. Batch-1
inference time is not measured here: a ``timer`` (e.g. ``deploy.timing.time_models``, which
``slungload evaluate`` passes) adds it to the report.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn
from tqdm.auto import tqdm

from ..config import VehicleParams, WindowConfig
from ..data.dataset import load_dataset
from ..data.windows import Windows
from ..models.checkpoints import LoadedModel, load_checkpoint
from ..models.ensemble import EnsembleModel, is_ensemble, load_members, spread
from ..models.prediction import NetworkModel, PhysicsModel, PredictionModel, ensemble_model
from ..reporting import device_name, versions
from ..state import GROUPS, group_errors
from .metrics import Curve, mae_curve, metrics_from_errors
from .report import write_report
from .results import PHYSICS, PHYSICS_TRUTH, Example, Report, RunResult, TimingResult, table_rows
from .uncertainty import (
    UncertaintyStats,
    member_predictions,
    shift_if_asked,
    uncertainty_stats,
)
from .windows import horizon_windows

# Batch-1 timing of the trained networks: (label, seed, network) triples, the test windows per
# horizon and the vehicle constants -> one record per network, backend and horizon.
Timer = Callable[
    [Sequence[tuple[str, "int | None", nn.Module]], Mapping[int, Windows], VehicleParams],
    Sequence[TimingResult],
]


# --- the report --------------------------------------------------------------------------


@dataclass(frozen=True)
class Candidate:
    """One prediction model to evaluate: ``label`` groups seeds of one variant in the table."""

    label: str
    model: PredictionModel
    seed: int | None = None
    network: nn.Module | None = None  # for timing; None for the physics model
    info: dict[str, Any] = field(default_factory=dict)  # run path, variant, configs


def pick_example(windows: Windows) -> tuple[int, int]:
    """A deterministic example window: the middle window of the flight with the most windows.

    Returns (index into ``windows``, flight index).
    """
    if len(windows) == 0:
        raise ValueError("no test windows to pick an example from")
    counts = torch.bincount(windows.flight)
    flight = int(torch.argmax(counts))
    idx = torch.nonzero(windows.flight == flight).flatten()
    return int(idx[len(idx) // 2]), flight


def flight_from_windows(windows: Windows, flight: int) -> np.ndarray:
    """States (T, 13) of one flight pieced together from its windows (steps they cover)."""
    idx = torch.nonzero(windows.flight == flight).flatten()
    starts = windows.start[idx]
    length = windows.window.length
    out = np.full((int(starts.max()) + length, windows.states.shape[-1]), np.nan)
    for i, s in zip(idx.tolist(), starts.tolist(), strict=True):
        out[s : s + length] = windows.states[i].double().numpy()
    return out


def evaluate_predictors(
    candidates: Sequence[Candidate],
    windows: Mapping[int, Windows],
    *,
    params: VehicleParams,
    training_horizon: int,
    dataset: str = "",
    split: str = "test",
    flights: Mapping[str, np.ndarray] | None = None,
    timer: Timer | None = None,
    device: str | torch.device = "cpu",
    progress: bool = False,
    environment: Mapping[str, Any] | None = None,
) -> Report:
    """Run every candidate on the windows of every horizon and collect a ``Report``.

    windows: N -> windows of ``split`` cut with horizon N (same flights, same M). flights: optional
    name -> states (T, 13) for the example figure (pieced from windows otherwise). timer:
    batch-1 timing of the candidates that hold a network (none without it).
    """
    history = _check_windows(candidates, windows)
    horizons = tuple(sorted(windows))
    results, pooled, predictions, spreads = _run_candidates(candidates, windows, progress)
    curves: dict[str, dict[int, dict[str, Curve]]] = {}
    for (label, n), parts in pooled.items():
        joined = {g: torch.cat([p[g] for p in parts]) for g in GROUPS}
        curves.setdefault(label, {})[n] = {g: mae_curve(joined[g]) for g in GROUPS}

    example = _example(candidates, windows[horizons[-1]], predictions, horizons[-1], flights)

    networks = [(c.label, c.seed, c.network) for c in candidates if c.network is not None]
    timings = tuple(timer(networks, windows, params)) if timer is not None and networks else ()

    test_flights = windows[horizons[0]].names
    env = {
        **versions("torch"),  # slungload's and torch's
        "threads": torch.get_num_threads(),
        "device": device_name(torch.device(device)),
        **(environment or {}),
    }
    return Report(
        dataset=dataset,
        test_flights=tuple(test_flights),
        split=split,
        params=params,
        history=history,
        training_horizon=training_horizon,
        horizons=horizons,
        labels=tuple(dict.fromkeys(c.label for c in candidates)),
        results=tuple(results),
        table=table_rows(results),
        curves=curves,
        timings=timings,
        example=example,
        models=tuple({"label": c.label, "seed": c.seed, **c.info} for c in candidates if c.network),
        environment=env,
        spreads=spreads,
    )


def _check_windows(candidates: Sequence[Candidate], windows: Mapping[int, Windows]) -> int:
    """The history M shared by the windows of every horizon, after checking there is work."""
    if not candidates:
        raise ValueError("evaluate: nothing to evaluate")
    if not windows:
        raise ValueError("evaluate: no horizon to evaluate")
    histories = {w.window.history for w in windows.values()}
    if len(histories) != 1:
        raise ValueError(f"evaluate: windows of different histories M {sorted(histories)}")
    return histories.pop()


def _run_candidates(
    candidates: Sequence[Candidate], windows: Mapping[int, Windows], progress: bool
) -> tuple[
    list[RunResult],
    dict[tuple[str, int], list[dict[str, Tensor]]],
    dict[tuple[int, int], Tensor],
    dict[str, dict[int, UncertaintyStats]],
]:
    """Every candidate at every horizon: its metrics, its error norms pooled per (label, N)
    over seeds, its predictions per (id(candidate), N), (W, N, 13), and a calibrated
    ensemble's interval statistics per label and N (``uncertainty.uncertainty_stats``)."""
    jobs = [(c, n) for n in sorted(windows) for c in candidates]
    bar = tqdm(total=len(jobs), unit="run", leave=False, disable=None if progress else True)
    results: list[RunResult] = []
    pooled: dict[tuple[str, int], list[dict[str, Tensor]]] = {}
    predictions: dict[tuple[int, int], Tensor] = {}
    spreads: dict[str, dict[int, UncertaintyStats]] = {}
    for c, n in jobs:
        bar.set_description(f"{c.label} N={n}")
        if isinstance(c.model, EnsembleModel):  # the mean, and the interval's coverage
            members, truth = member_predictions(c.model, windows[n])
            pred = spread(members).mean.to(windows[n].states.dtype)
            if c.model.calibration is not None:
                spreads.setdefault(c.label, {})[n] = uncertainty_stats(
                    members, truth, c.model.calibration, shift=shift_if_asked(c.model, windows[n])
                )
        else:
            pred = c.model.predict_windows(windows[n])
        errors = group_errors(pred, windows[n].future.states)
        results.append(RunResult(c.label, c.seed, metrics_from_errors(errors)))
        pooled.setdefault((c.label, n), []).append(errors)
        predictions[(id(c), n)] = pred
        bar.update()
    bar.close()
    return results, pooled, predictions, spreads


def _example(
    candidates: Sequence[Candidate],
    windows: Windows,
    predictions: Mapping[tuple[int, int], Tensor],
    horizon: int,
    flights: Mapping[str, np.ndarray] | None,
) -> Example:
    index, flight = pick_example(windows)
    name = windows.names[flight]
    if flights is not None and name in flights:
        flight_states = np.asarray(flights[name], dtype=np.float64)
    else:
        flight_states = flight_from_windows(windows, flight)
    preds: dict[str, np.ndarray] = {}
    for c in candidates:  # the first seed of each label
        preds.setdefault(c.label, predictions[(id(c), horizon)][index].double().numpy())
    return Example(
        flight=name,
        start=int(windows.start[index]),
        history=windows.window.history,
        flight_states=flight_states,
        window_states=windows.states[index].double().numpy(),
        predictions=preds,
    )


# --- entry ----------------------------------------------------------------------------------


def evaluate(
    runs: Sequence[str | Path],
    *,
    data: str | Path | None = None,
    out: str | Path | None = None,
    horizons: Sequence[int] = (25, 50),
    include_physics: bool = True,
    timer: Timer | None = None,
    device: str = "cpu",
    batch_size: int = 1024,
    progress: bool = True,
    split: str = "test",
) -> Report:
    """Evaluate trained runs (run folders, ``.ckpt`` files or ensemble folders: the members'
    mean, one row) on the test flights (or, with ``split="val"``, the validation flights:
    the split to choose a configuration on).

    data: dataset folder (default: the one recorded in the first run). Every run must share
    the history M and the vehicle constants. Test windows are cut with stride 1 for each
    horizon in ``horizons`` from the same test flights. Runs of one variant are seeds of one
    label (mean +- std in the table). ``include_physics`` adds the physics-only predictor
    with the dataset's constants ("physics") and, where the flights record their own (varied
    loads), with those (``PHYSICS_TRUTH``); ``timer`` adds batch-1 inference times (see
    ``Timer``). With ``out`` the report is written there (``report.write_report``).
    """
    horizons = tuple(sorted({int(n) for n in horizons}))
    if not horizons or horizons[0] < 1:
        raise ValueError(f"evaluate: horizons must be positive step counts, got {horizons}")
    ensembles = [(Path(run), *load_members(run)) for run in runs if is_ensemble(run)]
    singles = [load_checkpoint(run) for run in runs if not is_ensemble(run)]
    # every network, an ensemble's members too: what the runs must share
    loaded = singles + [lm for _, _, members in ensembles for lm in members]
    if not loaded and not include_physics:
        raise ValueError("evaluate: no run given and the physics predictor switched off")
    folder = data if data is not None else (loaded[0].meta.get("data") if loaded else None)
    if folder is None:
        raise ValueError("evaluate: no dataset folder recorded in the run; pass data=")
    history, params = _common_setup(loaded)

    window = WindowConfig(history=history, horizon=horizons[0], stride=1)
    dataset = load_dataset(folder, window=window, params=params)
    windows = horizon_windows(dataset, history=history, horizons=horizons, split=split)
    candidates = []
    if include_physics:
        candidates.append(Candidate(PHYSICS, PhysicsModel(dataset.params)))
        if windows[horizons[0]].constants is not None:  # flights of their own loads
            truth = PhysicsModel(dataset.params, name=PHYSICS_TRUTH, constants="flight")
            candidates.append(Candidate(PHYSICS_TRUTH, truth))
    training_horizon = loaded[0].window.horizon if loaded else horizons[0]
    for lm in singles:
        model = NetworkModel(lm.model, lm.window.history, batch_size=batch_size, device=device)
        seed = lm.train_config.seed
        # "+N<steps>" where the training horizon differs from the report's (the first run's)
        label = lm.run.label(with_horizon=lm.window.horizon != training_horizon)
        candidates.append(Candidate(label, model, seed, lm.model, _run_info(lm)))
    for folder, manifest, members in ensembles:
        model = ensemble_model(manifest, members, batch_size=batch_size, device=device)
        label = f"{folder.name} (mean of {len(members)})"
        candidates.append(Candidate(label, model, None, None, {"ensemble": str(folder)}))
    test = windows[horizons[0]].names
    report = evaluate_predictors(
        candidates,
        windows,
        params=dataset.params,
        training_horizon=training_horizon,
        dataset=str(dataset.folder),
        split=split,
        flights={name: dataset.flights[name].states for name in test},
        timer=timer,
        device=device,
        progress=progress,
        environment={"params_source": _params_source(loaded, dataset)},
    )
    if out is not None:
        write_report(report, out)
    return report


def _params_source(loaded: Sequence[LoadedModel], dataset: Any) -> str:
    """Where the vehicle constants came from: the runs' own (as recorded when they trained;
    the dataset is then read with them), or the dataset's for the physics predictor alone."""
    if not loaded:
        return dataset.params_source
    return f"the runs' checkpoints; {loaded[0].meta.get('params_source', 'unknown')} at training"


def _common_setup(loaded: Sequence[LoadedModel]) -> tuple[int, VehicleParams | None]:
    """History M and vehicle constants shared by all runs (defaults without runs)."""
    if not loaded:
        return WindowConfig().history, None
    histories = {lm.window.history for lm in loaded}
    if len(histories) > 1:
        names = ", ".join(f"{lm.path} (M = {lm.window.history})" for lm in loaded)
        raise ValueError(f"evaluate: runs with different histories M cannot share windows: {names}")
    params = {lm.params for lm in loaded}
    if len(params) > 1:
        names = ", ".join(str(lm.path) for lm in loaded)
        raise ValueError(f"evaluate: runs trained with different vehicle constants: {names}")
    return histories.pop(), params.pop()


def _run_info(lm: LoadedModel) -> dict[str, Any]:
    """What the report says about one run: where, what, how long, its configs."""
    info: dict[str, Any] = {
        "run": str(lm.path.parent),
        "checkpoint": str(lm.path),
        "variant": lm.variant,
        "parameters": sum(p.numel() for p in lm.model.parameters()),
        "configs": {k: v for k, v in lm.meta.items() if k != "format"},
        "architecture": lm.model_config.architecture,
    }
    if "constants" in lm.meta:  # fitted before training: name -> value, initial
        info["constants"] = lm.meta["constants"]
    summary = lm.path.parent / "run.json"
    if summary.is_file():
        try:
            run = json.loads(summary.read_text())
            info["epochs"] = run.get("epochs")
            info["stop_reason"] = run.get("stop_reason")
        except (json.JSONDecodeError, AttributeError):
            pass  # the checkpoint alone is enough; run.json only adds the epoch count
    return info
