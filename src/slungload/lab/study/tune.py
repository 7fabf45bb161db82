"""``slungload tune``: a configuration search with Ray Tune on the validation split.

Every trial is one ``RunConfig`` drawn from ``SearchSpace`` (architecture, loss variant, step
weighting, training horizon, load estimate, learning rate, network size, batch size) on a
search budget (``TuneSettings.preset`` with ``epochs``). Optuna's TPE (through Ray Tune's
``OptunaSearch``) proposes the trials, the first one being reproduce's hand-chosen
configuration (``lab.reproduce.BEYOND_PAPER``), so the search can only match or beat it; ASHA
stops poor trials early on the validation loss each epoch reports (``train(on_epoch=...)``).
A trial that runs to the end trains the same configuration with the second seed and reports
the objective: combined RMSE at N = 50 on the validation flights, mean of the seeds. The
test flights are never looked at.

Writes into ``out``: ``trials.csv`` (every trial: its choices, epochs, validation loss and
objective), ``tune.md`` (the table, best first), ``tune.png`` (objective per trial and the best
so far) and ``best.toml``: the best configuration on the final budget
(``TuneSettings.final_preset``), which ``slungload train --config best.toml`` retrains. Trial
runs live in ``out/trials/<trial>/s<seed>``; Ray Tune's own state in ``out/ray``.

Ray (``pip install 'slungload[cluster]'``) runs the trials locally (``cluster="local"``) or on a
cluster (``cluster.connect``); on this project's machines start it only in a private network
namespace (docs/cluster.md).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ...cluster import connect, require_ray
from ...config import LossWeights, ModelConfig, WindowConfig
from ...data.dataset import load_dataset
from ...data.windows import Windows
from ...evaluation.evaluator import evaluate, horizon_windows
from ...evaluation.metrics import COMBINED, compute_metrics
from ...fileio import write_text
from ...models.prediction import NetworkModel
from ...reporting import markdown_table, save_figure, write_csv
from ...run_config import RunConfig
from ...training.trainer import train
from ..reproduce import BEYOND_PAPER
from .config import SearchSpace, TuneSettings

OBJECTIVE = "objective"  # combined RMSE at N = 50 on val, mean of the seeds
# ASHA's signal: each epoch's combined RMSE at the objective's horizon on a fixed subset of the
# validation windows, the same for every trial (the training loss or the validation RMSE at a
# trial's own horizon would compare loss variants or horizons, not configurations).
VAL_LOSS = "val_rmse"
EPOCH_WINDOWS = 512  # validation windows each epoch's figure is measured on
STARTED = "started"  # when a trial started, Unix s: its reports carry it


def choice_run(
    choice: dict[str, Any], preset: str, seed: int, epochs: int | None, history: int = 50
) -> RunConfig:
    """The ``RunConfig`` of one trial's choices (M = ``history``). The load estimate is the
    physics-step network's starting point of f; an architecture without a physics step trains
    with the default whatever was drawn (``trained_choice`` records that)."""
    choice = trained_choice(choice)
    run = RunConfig.from_preset(
        preset,
        variant=choice["variant"],
        seed=seed,
        max_epochs=epochs,
        model=ModelConfig.sized(
            choice["size"],
            architecture=choice["architecture"],
            load_estimate=choice["load_estimate"],
        ),
        loss=LossWeights(steps=choice["steps"]),
        window=WindowConfig(history=history, horizon=int(choice["horizon"])),
    )
    return replace(
        run, train=replace(run.train, lr=float(choice["lr"]), batch_size=int(choice["batch_size"]))
    )


def trained_choice(choice: dict[str, Any]) -> dict[str, Any]:
    """The choices a trial really trains: the load estimate only where f starts from it."""
    if choice["architecture"] == "physics-step":
        return dict(choice)
    return {**choice, "load_estimate": ModelConfig().load_estimate}


def hand_chosen(preset: str) -> dict[str, Any]:
    """Reproduce's configuration (``BEYOND_PAPER``) as a trial's choices, on ``preset``'s
    learning rate and batch size."""
    run = BEYOND_PAPER[0].scheduled(preset, seed=0)
    return {
        "architecture": run.model.architecture,
        "variant": run.variant,
        "steps": run.loss.steps,
        "horizon": run.window.horizon,
        "load_estimate": run.model.load_estimate,
        "size": run.model.size,
        "batch_size": run.train.batch_size,
        "lr": run.train.lr,
    }


def within(choice: dict[str, Any], space: SearchSpace) -> bool:
    """Whether ``space`` allows every value of ``choice``."""
    low, high = space.lr
    return low <= choice["lr"] <= high and all(
        choice[name] in getattr(space, name) for name in choice if name != "lr"
    )


def _trial(choice: dict[str, Any], data: str, out: str, settings: TuneSettings) -> None:
    """One trial (a Ray Tune function trainable): seed one reporting every epoch, then the
    other seeds and the objective."""
    from ray import tune

    folder = Path(out) / "trials" / tune.get_context().get_trial_id()
    windows = _epoch_windows(data, settings)
    # Every report carries the objective (the searcher reads it each time): +inf until the
    # trial's end, so a trial ASHA stops counts as the worst for TPE.
    # "started" (Unix s) orders the trials for the figure: Ray's trial ids are random.
    runs, last = [], {VAL_LOSS: math.nan, "epoch": 0, OBJECTIVE: math.inf, STARTED: time.time()}
    for i, seed in enumerate(settings.seeds):
        run = choice_run(choice, settings.preset, seed, settings.epochs, settings.history)

        def report(epoch: int, metrics: dict[str, float], net: Any) -> None:
            pred = NetworkModel(net, settings.history).predict_windows(windows)
            rmse = compute_metrics(pred, windows).rmse[COMBINED]
            last.update({VAL_LOSS: rmse, "epoch": epoch + 1})
            tune.report(dict(last))

        train(data, run, out=folder / f"s{seed}", progress=False, num_threads=1,
              on_epoch=report if i == 0 else None)  # fmt: skip
        runs.append(folder / f"s{seed}")
    report_ = evaluate(runs, data=data, horizons=(settings.horizon,), include_physics=False,
                       progress=False, split="val")  # fmt: skip
    rmse = float(np.mean([r.metrics.rmse[COMBINED] for r in report_.results]))
    tune.report({**last, OBJECTIVE: rmse})


def _epoch_windows(data: str, settings: TuneSettings) -> Windows:
    """A fixed subset (``EPOCH_WINDOWS``, evenly spaced) of the validation windows at the
    objective's horizon."""
    dataset = load_dataset(data, window=WindowConfig(settings.history, settings.horizon))
    every = horizon_windows(dataset, history=settings.history, horizons=(settings.horizon,),
                            split="val")[settings.horizon]  # fmt: skip
    pick = np.linspace(0, len(every) - 1, min(EPOCH_WINDOWS, len(every))).round().astype(int)
    return every[torch.from_numpy(np.unique(pick))]


def run_tune(
    data: str | Path,
    out: str | Path,
    settings: TuneSettings | None = None,
    space: SearchSpace | None = None,
    *,
    cluster: str = "local",
) -> list[dict[str, Any]]:
    """Search (see the module); returns the trials' rows, best first."""
    ray = require_ray()
    try:
        import optuna  # noqa: F401  (OptunaSearch imports it only when built)
        from ray import tune
        from ray.tune.logger import CSVLoggerCallback, JsonLoggerCallback
        from ray.tune.schedulers import ASHAScheduler
        from ray.tune.search import ConcurrencyLimiter
        from ray.tune.search.optuna import OptunaSearch
    except ImportError as exc:  # Ray without its tune extra, or no Optuna
        raise ValueError(
            f"slungload tune needs Ray Tune and Optuna ({exc}): pip install 'slungload[cluster]'"
        ) from exc

    settings, space = settings or TuneSettings(), space or SearchSpace()
    max_epochs = settings.epochs or RunConfig.from_preset(settings.preset).train.max_epochs
    if max_epochs <= settings.grace_epochs:  # as TuneSettings refuses for a given --epochs
        raise ValueError(f"preset {settings.preset!r} trains {max_epochs} epochs, no more than "
                         f"ASHA's grace period of {settings.grace_epochs}: give --epochs "
                         f"{settings.grace_epochs + 1} or more")  # fmt: skip
    data, out = Path(data).resolve(), Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    params = {name: tune.choice(list(getattr(space, name))) for name in
              ("architecture", "variant", "steps", "horizon", "load_estimate", "size",
               "batch_size")}  # fmt: skip
    params["lr"] = tune.loguniform(*space.lr)
    first = hand_chosen(settings.preset)
    start = [first] if within(first, space) else None  # a narrower space may exclude it
    searcher = ConcurrencyLimiter(
        OptunaSearch(
            metric=OBJECTIVE, mode="min", points_to_evaluate=start, seed=settings.search_seed
        ),  # fmt: skip
        max_concurrent=settings.concurrent,
    )
    # max_t one past the last epoch: ASHA stops a trial that reaches max_t, and a trial must
    # still train its other seeds after its last reported epoch.
    scheduler = ASHAScheduler(metric=VAL_LOSS, mode="min", time_attr="epoch",
                              max_t=max_epochs + 1, grace_period=settings.grace_epochs)  # fmt: skip
    # Ray Tune's default loggers include TensorBoard's, which prints "NaN or Inf found in input
    # tensor" for every trial ASHA stops (its objective is +inf): keep the CSV and JSON ones.
    os.environ.setdefault("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", "1")
    started = connect(cluster)
    try:
        trainable = tune.with_resources(
            tune.with_parameters(_trial, data=str(data), out=str(out), settings=settings),
            {"cpu": 1},
        )
        tuner = tune.Tuner(
            trainable,
            param_space=params,
            tune_config=tune.TuneConfig(
                num_samples=settings.trials, search_alg=searcher, scheduler=scheduler
            ),  # fmt: skip
            run_config=tune.RunConfig(
                name="tune",
                storage_path=str(out / "ray"),
                verbose=0,
                callbacks=[CSVLoggerCallback(), JsonLoggerCallback()],
            ),
        )
        grid = tuner.fit()
    finally:
        if started:
            ray.shutdown()
    rows = _in_start_order([_row(result) for result in grid])
    rows.sort(key=lambda r: (not math.isfinite(r[OBJECTIVE]), r[OBJECTIVE], -r["epochs"]))
    write_tune(rows, first if start else None, settings, out)
    return rows


def _row(result: Any) -> dict[str, Any]:
    """One trial's choices, epochs trained, last validation loss and objective (+inf if
    stopped early)."""
    history = result.metrics_dataframe
    epochs = history["epoch"].max() if "epoch" in history else 0
    loss = result.metrics.get(VAL_LOSS, math.nan)
    objective = result.metrics.get(OBJECTIVE, math.inf)
    return {
        "trial": result.metrics.get("trial_id", "?"),
        STARTED: result.metrics.get(STARTED, math.inf),
        **trained_choice(result.config),
        "epochs": int(epochs) if epochs == epochs else 0,  # NaN: no epoch reported
        VAL_LOSS: float(loss),
        OBJECTIVE: float(objective) if objective is not None else math.inf,
    }


def _in_start_order(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows in the order their trials started, each with its number there ("order", from
    1) in place of its start time."""
    ordered = sorted(rows, key=lambda r: r[STARTED])
    return [{"trial": r["trial"], "order": n, **{k: v for k, v in r.items() if k not in
             ("trial", STARTED)}} for n, r in enumerate(ordered, 1)]  # fmt: skip


def write_tune(
    rows: Sequence[dict[str, Any]],
    first: dict[str, Any] | None,
    settings: TuneSettings,
    out: Path,
) -> Path:
    """trials.csv, tune.md, tune.png and best.toml (see the module); returns tune.md."""
    keys = list(rows[0]) if rows else []
    write_csv(out / "trials.csv", keys, [[r.get(k, "") for k in keys] for r in rows])
    finished = [r for r in rows if math.isfinite(r[OBJECTIVE])]
    lines = [
        "# Configuration search",
        "",
        f"{len(rows)} trials ({len(finished)} ran to the end, {len(rows) - len(finished)} "
        f"stopped early by ASHA); search budget: preset {settings.preset!r}, "
        f"{settings.epochs or 'all its'} epochs; objective: combined RMSE at N = "
        f"{settings.horizon} on the validation flights, mean of seeds "
        f"{', '.join(map(str, settings.seeds))}. "
        + (
            "The first trial is reproduce's configuration: "
            + ", ".join(f"{k} {v}" for k, v in first.items())
            + "."
            if first
            else "Reproduce's configuration is outside this search space."
        ),
        "",
        markdown_table(keys, [[_cell(r[k]) for k in keys] for r in rows]),
        "",
        "![objective per trial](tune.png)",
    ]
    if finished:
        best = choice_run(finished[0], settings.final_preset, settings.seeds[0], None,
                          settings.history)  # fmt: skip
        best.write_toml(out / "best.toml")
        lines += ["", f"Best: trial {finished[0]['trial']}, objective "
                  f"{finished[0][OBJECTIVE]:.4f}; `best.toml` (preset "
                  f"{settings.final_preset!r}): `slungload train --config best.toml`."]  # fmt: skip
    write_text(out / "tune.md", "\n".join(lines) + "\n")
    _plot(rows, out / "tune.png")
    return out / "tune.md"


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return "-" if not math.isfinite(value) else f"{value:.4g}"
    return str(value)


def _plot(rows: Sequence[dict[str, Any]], path: Path) -> Path:
    """Left: the objective of each finished trial in the order the trials started, and the
    best so far. Right: ASHA's view, each trial's last reported validation RMSE against the
    epoch it reached (finished trials filled), so stopped trials show too."""
    ordered = sorted(rows, key=lambda r: r["order"])
    order, values = [r["order"] for r in ordered], [r[OBJECTIVE] for r in ordered]
    fig = Figure(figsize=(9.0, 3.4))
    ax, asha = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    done = [(n, v) for n, v in zip(order, values, strict=True) if math.isfinite(v)]
    ax.plot([n for n, _ in done], [v for _, v in done], "o", label="finished trial")
    best, running = math.inf, []
    for v in values:
        best = min(best, v) if math.isfinite(v) else best
        running.append(best)
    ax.step(order, running, where="post", label="best so far")
    ax.set_xlabel("trial (start order)")
    ax.set_ylabel("objective: val combined RMSE, N = 50")
    ax.legend(fontsize=8)
    for finished, style in ((True, {}), (False, {"facecolors": "none"})):
        part = [r for r in ordered if math.isfinite(r[OBJECTIVE]) == finished]
        asha.scatter([r["epochs"] for r in part], [r[VAL_LOSS] for r in part],
                     edgecolors="C0", color="C0", s=24,
                     label="ran to the end" if finished else "stopped early", **style)  # fmt: skip
    asha.set_xlabel("epochs reached")
    asha.set_ylabel("last epoch's val RMSE (ASHA's metric)")
    asha.legend(fontsize=8)
    for a in (ax, asha):
        a.grid(alpha=0.3)
        a.xaxis.set_major_locator(MaxNLocator(integer=True))  # trials and epochs are counts
    fig.tight_layout()
    return save_figure(fig, path)
