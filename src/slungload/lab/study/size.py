"""How large the network must be for control: the size study (``slungload study size``).

The physics-step network does most of its work through the discrete model f, so it may not
need the paper's 239k weights, and the MPC pays for every one of them K x N times per control
step. For each named size (``config.MODEL_SIZES``) the study trains one template run (by
default ``lab.reproduce.BEYOND_PAPER[0]``: physics-step, no-physics, mixed step weighting, N = 50,
smoothed load estimate) on one dataset (for control: excited flights, docs/control.md) and
measures, per size:

- accuracy: combined RMSE at N = ``horizon`` on the **validation** flights (the split to choose
  a configuration on; ``evaluate(..., split="val")``), per seed;
- cost: one batched rollout in the MPC's shape, ``predict_candidates`` on float64 tensors (as
  ``control.mpc`` calls it) on a prediction backend (``config.PREDICTION_BACKENDS``: by
  default "compiled", what the MPC runs with ``--backend compiled``; "eager" for torch's
  operators), K = ``samples`` plans of N = ``steps`` steps from the first validation window,
  one thread, the median of ``repeats`` calls after a warm-up (``deploy.timing.time_calls``),
  with the machine's 1-min load average.

The sizes on the Pareto front (no other size both faster and, by the mean over the seeds,
more accurate) are then trained with ``front_seeds`` too, and so is any size that joins the
front once those seeds are in.

Layout of ``out``: ``runs/<RunConfig.folder()>/``, ``size.csv`` (every run), ``timing.csv``
(every size), ``size.md`` (the table) and ``size.png`` (the trade-off). Finished runs are
kept, so an interrupted study goes on where it stopped; the rollouts are timed afresh.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from ...cluster import check_reachable
from ...config import MODEL_SIZES, WindowConfig
from ...data.dataset import load_dataset
from ...deploy.compiled import with_backend
from ...deploy.timing import time_calls
from ...evaluation.evaluator import evaluate, horizon_windows
from ...evaluation.metrics import COMBINED
from ...evaluation.results import PHYSICS
from ...fileio import write_text
from ...models.base import count_parameters
from ...models.checkpoints import load_checkpoint
from ...models.prediction import NetworkModel
from ...reporting import load_average, markdown_table, mean_std, save_figure, write_csv
from ...run_config import RunConfig
from ..reproduce import BEYOND_PAPER, TrainingJob, run_training_jobs
from .config import SizeStudyConfig


@dataclass(frozen=True)
class SizeRow:
    """Validation combined RMSE at the study's horizon of one trained run (or the physics
    model: size ``"physics"``, seed None)."""

    size: str
    parameters: int
    seed: int | None
    rmse: float
    epochs: int | None = None  # trained epochs (run.json), where known


@dataclass(frozen=True)
class RolloutTiming:
    """One size's batched rollout: ``samples`` plans of ``steps`` steps, one thread."""

    size: str
    parameters: int
    median_ms: float
    p90_ms: float
    samples: int
    steps: int
    repeats: int
    load_average: float | None  # 1-min, when the timing ended
    backend: str = "eager"  # config.PREDICTION_BACKENDS


@dataclass(frozen=True)
class SizeStudy:
    """What ``study_size`` measured: every run's RMSE, every size's rollout time, the front."""

    rows: tuple[SizeRow, ...]
    timings: tuple[RolloutTiming, ...]
    front: tuple[str, ...]  # sizes on the Pareto front, fastest first
    horizon: int


def size_run(
    template: RunConfig, size: str, *, preset: str, seed: int, epochs: int | None = None
) -> RunConfig:
    """The template run with the widths of ``size`` (``MODEL_SIZES``), on a preset and seed
    (and ``epochs`` in place of the preset's, where given)."""
    run = replace(template, model=template.model.resized(size)).scheduled(preset, seed=seed)
    return run if epochs is None else replace(run, train=replace(run.train, max_epochs=epochs))


def study_size(
    *,
    data: str | Path,
    out: str | Path,
    config: SizeStudyConfig | None = None,
    template: RunConfig = BEYOND_PAPER[0],
    workers: int = 2,
    train: bool = True,
    progress: bool = True,
    cluster: str | None = None,
) -> SizeStudy:
    """Train ``template`` at every size of ``config`` (default ``SizeStudyConfig()``) for every
    seed, measure validation RMSE at its horizon and the batched rollout time, then train the
    sizes on the Pareto front for its ``front_seeds`` as well; writes the table and the figure
    into ``out``. With ``train=False`` nothing is trained: the finished runs among those named
    are evaluated and timed (to re-time on a quiet machine, or to report a study cut short).
    ``cluster``: train on a Ray cluster (``cluster.run_on_ray``) instead of ``workers`` local
    processes."""
    check_reachable(cluster)
    cfg = config or SizeStudyConfig()
    sizes, seeds, front_seeds, horizon = cfg.sizes, cfg.seeds, cfg.front_seeds, cfg.horizon
    out, data = Path(out), Path(data)

    def run_of(size: str, seed: int) -> RunConfig:
        return size_run(template, size, preset=cfg.preset, seed=seed, epochs=cfg.epochs)

    if train:
        _train(data, out, run_of, sizes, seeds, (workers, cluster), progress)
    every = tuple(dict.fromkeys((*seeds, *front_seeds)))
    finished = {s: _finished(out, run_of, s, every) for s in sizes}
    missing = [s for s, runs in finished.items() if not runs]
    if missing:
        raise FileNotFoundError(f"no finished run of the sizes {missing} under {out / 'runs'}")
    timings = tuple(
        _time_size(
            s,
            finished[s][0],
            data,
            samples=cfg.samples,
            steps=cfg.steps,
            repeats=cfg.repeats,
            backend=cfg.backend,
        )
        for s in sizes
    )
    if train:
        rows = _evaluate(data, out, run_of, {s: seeds for s in sizes}, horizon)
        more = tuple(k for k in front_seeds if k not in seeds)
        given: set[str] = set()  # the sizes trained with ``more`` seeds
        front = pareto_front(rows, timings)
        while more and not set(front) <= given:  # a size that joins the front gets them too
            given |= set(front)
            chosen_sizes = [s for s in sizes if s in given]
            _train(data, out, run_of, chosen_sizes, more, (workers, cluster), progress)
            chosen = {s: tuple(seeds) + (more if s in given else ()) for s in sizes}
            rows = _evaluate(data, out, run_of, chosen, horizon)
            front = pareto_front(rows, timings)
    else:
        # every finished run named: the front that chose who got more seeds was the training
        # run's; one re-derived from these fresh timings could name other sizes
        rows = _evaluate(data, out, run_of, {s: every for s in sizes}, horizon)
        front = pareto_front(rows, timings)
    study = SizeStudy(tuple(rows), timings, front, horizon)
    write_size_study(study, out)
    return study


def _train(data, out, run_of, sizes, seeds, engine, progress) -> None:
    """The runs of every size and seed not finished yet, seed by seed (so a study cut short
    has every size at its first seed), the sizes in the order given within a seed (the
    registry's: the largest, slowest to train, first); ``engine``: (workers, cluster)."""
    jobs = []
    for seed in seeds:
        for size in sizes:
            run = run_of(size, seed)
            run_dir = out / "runs" / run.folder()
            if not (run_dir / "run.json").is_file():
                jobs.append(TrainingJob(data, run_dir, run, (run_dir / "last.ckpt").is_file()))
    workers, cluster = engine
    run_training_jobs(jobs, workers=workers, progress=progress, cluster=cluster)


def _finished(out, run_of, size, seeds) -> list[Path]:
    """The run folders of ``size`` for ``seeds`` whose training finished (run.json)."""
    folders = [out / "runs" / run_of(size, k).folder() for k in seeds]
    return [f for f in folders if (f / "run.json").is_file()]


def _evaluate(data, out, run_of, seeds, horizon) -> list[SizeRow]:
    """Validation combined RMSE at ``horizon`` of every finished run (size -> its seeds) and
    of the physics model, in one evaluation (the same windows for all)."""
    runs = {run_of(size, seed): size for size, chosen in seeds.items() for seed in chosen}
    folders = [out / "runs" / run.folder() for run in runs]
    folders = [f for f in folders if (f / "run.json").is_file()]
    report = evaluate(folders, data=data, horizons=(horizon,), split="val", progress=False)
    size_of = {run.label(): size for run, size in runs.items()}
    info = {(m["label"], m["seed"]): m for m in report.models}
    rows = []
    for r in report.results:
        if r.label == PHYSICS:
            rows.append(SizeRow(PHYSICS, 0, None, r.metrics.rmse[COMBINED]))
            continue
        model = info[(r.label, r.seed)]
        rows.append(
            SizeRow(
                size_of[r.label],
                model["parameters"],
                r.seed,
                r.metrics.rmse[COMBINED],
                model.get("epochs"),
            )
        )
    return rows


def _time_size(
    size: str,
    run_dir: Path,
    data: Path,
    *,
    samples: int,
    steps: int,
    repeats: int,
    backend: str = "compiled",
) -> RolloutTiming:
    """The batched rollout of one trained run (any seed: the weights do not change the
    arithmetic) on ``backend`` from the first validation window of ``data``, with ``samples``
    noisy copies of its inputs as the plans."""
    loaded = load_checkpoint(run_dir)
    m = loaded.window.history
    dataset = load_dataset(data, window=WindowConfig(m, steps), params=loaded.params)
    window = horizon_windows(dataset, history=m, horizons=(steps,), split="val")[steps][0]
    x_hist = window.states[0, :m].double()  # (M, 13)
    u_past = window.inputs[0, : m - 1].double()  # (M-1, 4)
    plan = window.inputs[0, m - 1 : m - 1 + steps].double()  # (N, 4) u_k ... u_{k+N-1}
    noise = torch.randn(samples, steps, plan.shape[-1], generator=torch.Generator().manual_seed(0))
    plans = plan + 0.1 * noise.double()  # (K, N, 4)
    model = with_backend(NetworkModel(loaded.model, m), backend)
    model.predict_candidates(x_hist, u_past, plans)  # compiles the kernels before the timing
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        wall, _ = time_calls(
            lambda i: model.predict_candidates(x_hist, u_past, plans),
            repeats,
            warmup=max(5, repeats // 20),
        )
    finally:
        torch.set_num_threads(threads)
    ms = 1e3 * np.asarray(wall)
    return RolloutTiming(
        size,
        count_parameters(loaded.model),
        float(np.median(ms)),
        float(np.percentile(ms, 90)),
        samples,
        steps,
        repeats,
        load_average(),
        backend,
    )


def pareto_front(rows: Sequence[SizeRow], timings: Sequence[RolloutTiming]) -> tuple[str, ...]:
    """Sizes that no other size beats on both counts (faster rollout and lower mean RMSE over
    its seeds), fastest first."""
    mean = _means(rows)
    front, best = [], float("inf")
    for t in sorted(timings, key=lambda t: t.median_ms):
        if t.size in mean and mean[t.size][0] < best:
            front.append(t.size)
            best = mean[t.size][0]
    return tuple(front)


def _means(rows: Sequence[SizeRow]) -> dict[str, tuple[float, float, int]]:
    """size -> (mean, std, seeds) of the RMSE."""
    groups: dict[str, list[float]] = {}
    for r in rows:
        groups.setdefault(r.size, []).append(r.rmse)
    return {size: mean_std(v) for size, v in groups.items()}


def write_size_study(study: SizeStudy, out: Path) -> None:
    """size.csv (every run), timing.csv (every size), size.md (the table) and size.png."""
    write_csv(out / "size.csv", ["size", "parameters", "seed", "val_combined_rmse", "epochs"],
              [[r.size, r.parameters, r.seed, r.rmse, r.epochs] for r in study.rows])  # fmt: skip
    header = ["size", "parameters", "median_ms", "p90_ms", "samples", "steps", "repeats",
              "load_average", "backend"]  # fmt: skip
    write_csv(out / "timing.csv", header,
              [[t.size, t.parameters, t.median_ms, t.p90_ms, t.samples, t.steps, t.repeats,
                t.load_average, t.backend] for t in study.timings])  # fmt: skip
    write_text(out / "size.md", size_table(study) + "\n")
    _figure(study, out / "size.png")


def size_table(study: SizeStudy) -> str:
    """The Markdown table: one row per size (the physics model's RMSE below), largest first."""
    mean = _means(study.rows)
    seeds = sorted({r.seed for r in study.rows if r.seed is not None})
    per_seed = {(r.size, r.seed): r.rmse for r in study.rows}
    header = ["size", "widths", "parameters", *(f"seed {s}" for s in seeds), "mean ± std",
              "rollout median / p90 (ms)", "load average", "on the front"]  # fmt: skip
    rows = []
    for t in sorted(study.timings, key=lambda t: -t.parameters):
        m, s, n = mean.get(t.size, (float("nan"), 0.0, 0))
        rows.append([
            t.size, MODEL_SIZES[t.size].summary(), f"{t.parameters:,}",
            *(f"{per_seed[(t.size, k)]:.3f}" if (t.size, k) in per_seed else "-" for k in seeds),
            f"{m:.3f}" + (f" ± {s:.3f}" if n > 1 else ""), f"{t.median_ms:.1f} / {t.p90_ms:.1f}",
            "-" if t.load_average is None else f"{t.load_average:.2f}",
            "yes" if t.size in study.front else "",
        ])  # fmt: skip
    if PHYSICS in mean:
        rows.append(["physics model", "-", 0, *("" for _ in seeds), f"{mean[PHYSICS][0]:.3f}",
                     "-", "-", ""])  # fmt: skip
    t = study.timings[0]
    return (
        f"Validation combined RMSE at N = {study.horizon} against one batched rollout "
        f"(K = {t.samples}, N = {t.steps}, {t.backend} backend, one thread, median of "
        f"{t.repeats} calls)\n\n" + markdown_table(header, rows)
    )


def _figure(study: SizeStudy, path: Path) -> None:
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullLocator

    mean = _means(study.rows)
    fig = Figure(figsize=(6.4, 4.2), constrained_layout=True)
    ax = fig.add_subplot()
    timed = sorted((t for t in study.timings if t.size in mean), key=lambda t: t.median_ms)
    for i, t in enumerate(timed):
        m, s, n = mean[t.size]
        colour = "C0" if t.size in study.front else "0.5"
        ax.errorbar(t.median_ms, m, yerr=s if n > 1 else None, capsize=3, marker="o",
                    color=colour, linestyle="none")  # fmt: skip
        text = f"{t.size}\n{t.parameters:,} weights, {n} seed{'s' if n > 1 else ''}"
        ax.annotate(text, (t.median_ms, m), textcoords="offset points", fontsize=8,
                    xytext=(6, 6) if i % 2 == 0 else (6, -24))  # fmt: skip
    front = [t for t in timed if t.size in study.front]
    ax.plot([t.median_ms for t in front], [mean[t.size][0] for t in front], color="C0",
            alpha=0.5, label="Pareto front")  # fmt: skip
    if PHYSICS in mean:  # a line where it fits, else its value in the legend
        physics = mean[PHYSICS][0]
        label = f"physics model ({physics:.3f})"
        if timed and physics > 1.5 * max(mean[t.size][0] for t in timed):
            ax.plot([], [], color="0.3", linestyle=":", label=f"{label}, off the scale")
        else:
            ax.axhline(physics, color="0.3", linestyle=":", label=label)
    ax.margins(y=0.12)
    ax.set_xscale("log")
    if timed:
        t, ms = timed[0], [t.median_ms for t in timed]
        ax.set_xlabel(
            f"batched rollout, K = {t.samples}, N = {t.steps}, {t.backend}, one thread (ms, median)"
        )
        shown = [v for i, v in enumerate(ms) if i == 0 or v / ms[i - 1] > 1.2]  # no overlap
        ax.set_xticks(shown, [f"{v:.1f}" for v in shown])  # the sizes' times
        ax.xaxis.set_minor_locator(NullLocator())
        ax.set_xlim(min(ms) / 1.4, max(ms) * 2.2)
    ax.set_ylabel(f"validation combined RMSE at N = {study.horizon}")
    ax.grid(alpha=0.3)
    ax.legend()
    save_figure(fig, path)
