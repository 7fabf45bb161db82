"""Where physics-informed training helps: the data-efficiency study (``slungload study data``).

Each loss variant (and architecture) is trained on nested subsets of the training flights,
6, 12, 24, ... of them, with the validation and test flights fixed, over seeds; the table and
the figure give the combined RMSE at N = 50 on the test flights against the number of training
flights, beside the physics model's (which no training changes).

Layout of ``out``: ``data/`` (simulated unless given), ``subsets/train<k>/`` (the k first
flights of a seeded order as train.txt, the same val.txt and test.txt; the listed flights
linked, not copied), ``runs/train<k>/<RunConfig.folder()>/``, ``data.csv``,
``data.md``, ``data.png``. Finished runs are kept, so an interrupted study can be re-run.
"""

from __future__ import annotations

import math
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...cluster import check_reachable
from ...config import ModelConfig
from ...data.folder import check_folder, read_splits
from ...data.split import SPLIT_FRACTIONS
from ...evaluation.evaluator import evaluate
from ...evaluation.metrics import COMBINED
from ...evaluation.results import PHYSICS
from ...fileio import write_splits, write_text
from ...reporting import markdown_table, mean_std, model_colors, save_figure, write_csv
from ...run_config import RunConfig
from ...sim import simulate_dataset
from ...vehicle_file import VEHICLE_FILE
from ..reproduce import TrainingJob, run_training_jobs
from .config import DataStudyConfig

TRAIN_SHARE = SPLIT_FRACTIONS["train"]  # of a simulated dataset's windows in training


@dataclass(frozen=True)
class StudyRow:
    """Combined RMSE at the study's horizon of one model trained on ``flights`` flights."""

    flights: int
    label: str  # "physics", or architecture/variant
    seed: int | None
    rmse: float


def study_data(
    *,
    out: str | Path,
    config: DataStudyConfig | None = None,
    data: str | Path | None = None,
    workers: int = 2,
    progress: bool = True,
    cluster: str | None = None,
) -> list[StudyRow]:
    """Train every (architecture, variant, seed) of ``config`` (default ``DataStudyConfig()``)
    on the first k training flights for each k in ``config.flights`` and evaluate at its
    horizon on the fixed test flights of ``data`` (None: a dataset simulated into
    ``out/data``); writes the table and the figure into ``out`` and returns the rows.
    ``cluster``: train on a Ray cluster (``cluster.run_on_ray``) instead of ``workers`` local
    processes."""
    check_reachable(cluster)
    cfg = config or DataStudyConfig()
    preset, horizon, sim_seed = cfg.preset, cfg.horizon, cfg.sim_seed
    sizes = sorted({int(k) for k in cfg.flights})
    out = Path(out)
    data = (
        Path(data)
        if data is not None
        else _simulated(out / "data", sizes[-1], sim_seed, workers, progress)
    )
    subsets = _nested_subsets(data, out / "subsets", sizes, sim_seed)
    runs = [
        RunConfig(variant, model=ModelConfig(architecture=arch)).scheduled(preset, seed=seed)
        for arch in cfg.architectures
        for variant in cfg.variants
        for seed in cfg.seeds
    ]
    jobs = []
    for k, folder in subsets.items():
        for run in runs:
            run_dir = _run_dir(out / "runs" / f"train{k}", run)
            if not (run_dir / "run.json").is_file():
                jobs.append(TrainingJob(folder, run_dir, run, (run_dir / "last.ckpt").is_file()))
    run_training_jobs(jobs, workers=workers, progress=progress, cluster=cluster)
    rows = []
    for k, folder in subsets.items():
        runs = sorted((out / "runs" / f"train{k}").glob("*/run.json"))
        report = evaluate(
            [r.parent for r in runs], data=folder, horizons=(horizon,), progress=False
        )
        rows += [StudyRow(k, r.label, r.seed, r.metrics.rmse[COMBINED]) for r in report.results]
    write_study(rows, out, horizon)
    return rows


def _simulated(folder: Path, largest: int, seed: int, workers: int, progress: bool) -> Path:
    """A simulated dataset with at least ``largest`` training flights (made once)."""
    if not (folder / "train.txt").is_file():
        count = max(48, math.ceil(1.15 * largest / TRAIN_SHARE))
        simulate_dataset(folder, flights=count, seed=seed, workers=workers, progress=progress)
    return folder


def _nested_subsets(data: Path, root: Path, sizes: list[int], seed: int) -> dict[int, Path]:
    """For each k a dataset folder whose train.txt holds the first k training flights of one
    seeded order (so each subset contains the smaller ones), with the same val and test."""
    data, files = check_folder(data)
    splits = read_splits(data)
    pool = list(np.random.default_rng(seed).permutation(splits["train"]))
    if len(pool) < sizes[-1]:
        raise ValueError(
            f"{data}: {len(pool)} training flights, fewer than the {sizes[-1]} asked for"
        )
    out = {}
    for k in sizes:
        folder = root / f"train{k}"
        folder.mkdir(parents=True, exist_ok=True)
        for name in [*pool[:k], *splits["val"], *splits["test"]]:  # only the listed flights
            link = folder / files[name].name
            if not link.exists():
                os.symlink(files[name].resolve(), link)
        if (data / VEHICLE_FILE).is_file():
            shutil.copyfile(data / VEHICLE_FILE, folder / VEHICLE_FILE)
        write_splits(folder, {"train": pool[:k], "val": splits["val"], "test": splits["test"]})
        out[k] = folder
    return out


def _run_dir(root: Path, run: RunConfig) -> Path:
    """Where a run of the study lives: ``root/<RunConfig.folder()>``, or the folder a study
    written before runs had one name used (``<architecture>-<variant>-s<seed>``), if it holds
    that run, so that such a study goes on where it stopped."""
    earlier = root / f"{run.model.architecture}-{run.variant}-s{run.seed}"
    return earlier if earlier.is_dir() else root / run.folder()


def write_study(rows: Sequence[StudyRow], out: Path, horizon: int) -> None:
    """data.csv (every run), data.md (mean +- std over seeds) and data.png."""
    write_csv(out / "data.csv", ["flights", "label", "seed", "combined_rmse"],
              [[r.flights, r.label, r.seed, r.rmse] for r in rows])  # fmt: skip
    table = _mean_std(rows)
    labels = list(dict.fromkeys(label for (_, label) in table))
    sizes = sorted({k for (k, _) in table})
    rows = [[k, *(_cell(table.get((k, label))) for label in labels)] for k in sizes]
    md = markdown_table(["training flights", *labels], rows)
    title = f"# Data-efficiency study: combined RMSE at N = {horizon} on the test flights"
    write_text(out / "data.md", f"{title}\n\n{md}\n")
    _figure(table, labels, sizes, out / "data.png", horizon)


def _mean_std(rows: Sequence[StudyRow]) -> dict[tuple[int, str], tuple[float, float, int]]:
    groups: dict[tuple[int, str], list[float]] = {}
    for r in rows:
        groups.setdefault((r.flights, r.label), []).append(r.rmse)
    return {key: mean_std(v) for key, v in groups.items()}


def _cell(value: tuple[float, float, int] | None) -> str:
    if value is None:
        return "-"
    mean, std, n = value
    return f"{mean:.3f}" + (f" ± {std:.3f}" if n > 1 else "")


def _figure(table, labels: list[str], sizes: list[int], path: Path, horizon: int) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.2), constrained_layout=True)
    ax = fig.add_subplot()
    colors = model_colors(labels)
    for i, label in enumerate(labels):
        ks = [k for k in sizes if (k, label) in table]
        mean = np.array([table[(k, label)][0] for k in ks])
        std = np.array([table[(k, label)][1] for k in ks])
        style = dict(linestyle=":") if label == PHYSICS else dict(marker="os^vD"[i % 5])
        style["color"] = colors[label]
        ax.errorbar(ks, mean, yerr=std, capsize=3, label=label, **style)
    ax.set_xscale("log", base=2)
    ax.set_xticks(sizes, [str(k) for k in sizes])
    ax.set_xlabel("training flights")
    ax.set_ylabel(f"combined RMSE at N = {horizon}")
    ax.grid(alpha=0.3)
    ax.legend()
    save_figure(fig, path)
