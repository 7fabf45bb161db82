"""One model for many loads: the loads study (``slungload study loads``).

Three simulated datasets of the same maneuvers: ``one`` flies the nominal load (the training
range's midpoints), ``many`` a load and cable length drawn per flight from the training range
(its test flights are loads no training flight had: interpolation), ``beyond`` loads heavier
and cables longer than any in training (extrapolation; every flight is tested). The
physics-step network is trained on ``one``, on ``many``, and on ``many`` adapting f to each
window's constants estimated in flight (``ModelConfig.constants = "window"``), without and
with its correction seeing them (``ModelConfig.constants_input``), over seeds, and
compared with the physics model run with the nominal constants, with the in-flight estimate
and with each flight's true constants: combined RMSE at N = 25 and 50, MAE per step, and the
RMSE at N = 50 of each test flight against its load mass (``loads.png``), and on how many
test flights each model is better than physics with the nominal constants and than the
one-load network (``flights_better``).

Layout of ``out``: ``data/{one,many,beyond}/``, ``runs/<set>/<RunConfig.folder()>/``,
``inside/`` and ``beyond/`` (the evaluation reports), ``loads.csv``, ``flights.csv``,
``loads.md``, ``loads.png``. Datasets and finished runs are kept: an interrupted study goes
on where it stopped.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ...cluster import check_reachable
from ...config import ADAPT_PRIOR_WEIGHT, VehicleParams, WindowConfig
from ...data.dataset import Dataset, load_dataset
from ...data.folder import resolve_params
from ...data.windows import Windows, make_windows
from ...evaluation.evaluator import Candidate, evaluate_predictors
from ...evaluation.metrics import COMBINED, compute_metrics
from ...evaluation.report import write_report
from ...fileio import write_text
from ...models import load_checkpoint
from ...models.prediction import NetworkModel, PhysicsModel
from ...reporting import markdown_table, mean_std, model_colors, save_figure, write_csv
from ...run_config import RunConfig
from ...sim import SimConfig, simulate_dataset
from ..reproduce import BEYOND_PAPER, TrainingJob, run_training_jobs
from .config import (
    ESTIMATE_ROW,
    NETWORK_ROWS,
    NOMINAL_ROW,
    ONE_LOAD_ROW,
    PHYSICS_ROWS,
    SETS,
    TRUTH,
    LoadsStudyConfig,
)
from .size import size_run


@dataclass(frozen=True)
class LoadsRow:
    """Combined RMSE of one model (one seed) at one horizon on one test set."""

    test_set: str  # "inside" | "beyond"
    label: str
    seed: int | None
    horizon: int
    rmse: float


def study_loads(
    *,
    out: str | Path,
    config: LoadsStudyConfig = LoadsStudyConfig(),  # noqa: B008 (frozen)
    workers: int = 2,
    progress: bool = True,
    cluster: str | None = None,
) -> list[LoadsRow]:
    """Simulate, train and evaluate the loads study into ``out`` (see the module); returns the
    rows of ``loads.csv``. ``cluster`` trains on Ray."""
    out = Path(out)
    check_reachable(cluster)
    data = _datasets(out / "data", config, config.sim_seed, workers, progress)
    runs = {label: _runs(config, constants, seeing, config.preset, config.seeds, config.epochs)
            for label, (_, constants, seeing) in NETWORK_ROWS.items()}  # fmt: skip
    jobs = []
    for label, (source, _, _) in NETWORK_ROWS.items():
        for run in runs[label]:
            folder = out / "runs" / source / run.folder()
            if not (folder / "run.json").is_file():
                resume = (folder / "last.ckpt").is_file()
                jobs.append(TrainingJob(data[source], folder, run, resume))
    run_training_jobs(jobs, workers=workers, progress=progress, cluster=cluster)

    params, _ = resolve_params(data["many"], None)  # the nominal constants
    tested = {name: load_dataset(data[name], window=WindowConfig(), params=params)
              for name in dict.fromkeys(SETS.values())}  # fmt: skip
    prior, priors = choose_estimate_prior(tested["many"], params, config)
    rows: list[LoadsRow] = []
    per_flight: list[tuple[str, str, str, float, float]] = []
    worse: dict[tuple[str, str], tuple[int, int]] = {}
    for test_set in SETS:
        windows = _test_windows(tested, test_set, params, config.horizons)
        candidates = [
            Candidate(label, PhysicsModel(params, name=label, constants=source,
                                          **_prior(source, prior)))
            for label, source in PHYSICS_ROWS.items()
        ]  # fmt: skip
        for label, (source, _, _) in NETWORK_ROWS.items():
            for run in runs[label]:
                loaded = load_checkpoint(out / "runs" / source / run.folder())
                model = NetworkModel(loaded.model, loaded.window.history, name=label)
                candidates.append(Candidate(label, model, run.seed, loaded.model))
        report = evaluate_predictors(
            candidates, windows, params=params, training_horizon=max(config.horizons),
            dataset=str(data[SETS[test_set]]), split=test_set,
        )  # fmt: skip
        write_report(report, out / test_set)
        rows += [LoadsRow(test_set, r.label, r.seed, r.metrics.horizon, r.metrics.rmse[COMBINED])
                 for r in report.results]  # fmt: skip
        per_flight += _per_flight(candidates, windows[max(config.horizons)], test_set)
        worse.update(_steps_worse(report.curves, max(config.horizons), test_set))
    write_loads_study(rows, per_flight, worse, out, config, params, priors)
    return rows


def _prior(source: str, prior: float) -> dict[str, float]:
    """``PhysicsModel``'s keyword for the estimate's prior: only f on the estimate takes one."""
    return {"prior_weight": prior} if source == "window" else {}


def choose_estimate_prior(
    ds: Dataset, params: VehicleParams, config: LoadsStudyConfig
) -> tuple[float, dict[float, float]]:
    """The mass prior of ``config.estimate_priors`` with which physics on the in-flight estimate
    predicts the validation flights of ``ds`` (``many``) best (combined RMSE at the longest
    horizon), and each prior's RMSE. The test loads play no part in the choice."""
    horizon = max(config.horizons)
    windows = _split_windows(ds, "val", params, (horizon,))[horizon]
    scores = {}
    for weight in config.estimate_priors:
        model = PhysicsModel(params, constants="window", prior_weight=weight)
        scores[weight] = compute_metrics(model.predict_windows(windows), windows).rmse[COMBINED]
    return min(scores, key=scores.__getitem__), scores


def _datasets(
    root: Path, config: LoadsStudyConfig, seed: int, workers: int, progress: bool
) -> dict[str, Path]:
    """The three datasets (simulated once; the same maneuvers, seed and effects)."""
    mass, length = config.nominal
    plan = {
        "one": (SimConfig().with_loads(load_mass=mass, cable_length=length), config.flights),
        "many": (
            SimConfig().with_loads(load_mass=config.train_mass, cable_length=config.train_length),
            config.flights,
        ),
        "beyond": (
            SimConfig().with_loads(load_mass=config.beyond_mass, cable_length=config.beyond_length),
            config.beyond_flights,
        ),
    }
    folders = {}
    for name, (sim, flights) in plan.items():
        folder = root / name
        if not (folder / "train.txt").is_file():
            # "beyond" flies other seeds: its maneuvers' draws are not the training flights'.
            own = seed + (1 if name == "beyond" else 0)
            simulate_dataset(folder, flights=flights, seed=own, config=sim, workers=workers,
                             progress=progress, overwrite=True)  # fmt: skip
        folders[name] = folder
    return folders


def _runs(
    config: LoadsStudyConfig,
    constants: str,
    seeing: bool,
    preset: str,
    seeds: Sequence[int],
    epochs: int | None,
) -> list[RunConfig]:
    """The physics-step network of reproduce's best configuration at ``config.size``, its f
    running with ``constants`` (its correction seeing them with ``seeing``), for each seed."""
    template = BEYOND_PAPER[0]
    model = replace(template.model, constants=constants, constants_input=seeing)
    template = replace(template, model=model)
    return [size_run(template, config.size, preset=preset, seed=seed, epochs=epochs)
            for seed in seeds]  # fmt: skip


def _test_windows(
    tested: dict[str, Dataset], test_set: str, params: VehicleParams, horizons: Sequence[int]
) -> dict[int, Windows]:
    """Windows of the test flights of ``many`` (inside) or every flight of ``beyond``, for each
    horizon (``_split_windows``); ``tested``: the datasets by name."""
    split = "test" if test_set == "inside" else None
    return _split_windows(tested[SETS[test_set]], split, params, horizons)


def _split_windows(
    ds: Dataset, split: str | None, params: VehicleParams, horizons: Sequence[int]
) -> dict[int, Windows]:
    """Windows (stride 1) of the flights of ``split`` of ``ds`` (None: every flight), for each
    horizon, carrying each flight's true constants; ``ds`` read with the nominal constants
    (``params``). A split without flights is a ValueError naming the dataset."""
    names = ds.splits[split].names if split else tuple(ds.flights)
    if not names:
        raise ValueError(f"{ds.folder}: no {split} flights")
    flights = [ds.flights[n] for n in names]
    return {
        n: make_windows(flights, WindowConfig(history=ds.window.history, horizon=n), params)
        for n in horizons
    }


def _steps_worse(curves, horizon: int, test_set: str) -> dict[tuple[str, str], tuple[int, int]]:
    """(set, label) -> the horizon steps (of N = ``horizon``) at which the label's position and
    load-position MAE exceed physics with the true constants'."""
    truth = curves[TRUTH][horizon]
    return {
        (test_set, label): tuple(
            int((by_n[horizon][g].mean > truth[g].mean).sum())
            for g in ("position", "load_position")
        )
        for label, by_n in curves.items()
        if label != TRUTH and horizon in by_n
    }


def _per_flight(
    candidates: Sequence[Candidate], windows: Windows, test_set: str
) -> list[tuple[str, str, str, float, float]]:
    """(set, label, flight, its load mass kg, combined RMSE) per candidate and test flight;
    seeds of a label averaged."""
    masses = windows.vehicle().mass_load
    out: dict[tuple[str, str], list[float]] = {}
    for cand in candidates:
        pred = cand.model.predict_windows(windows)
        for i, name in enumerate(windows.names):
            mine = windows.flight == i
            if not bool(mine.any()):
                continue
            part = windows[mine]
            value = compute_metrics(pred[mine], part).rmse[COMBINED]
            out.setdefault((cand.label, name), []).append(value)
    first = {name: float(masses[windows.flight == i][0]) for i, name in enumerate(windows.names)
             if bool((windows.flight == i).any())}  # fmt: skip
    return [(test_set, label, name, first[name], mean_std(v)[0])
            for (label, name), v in out.items()]  # fmt: skip


def flights_better(
    per_flight: Sequence[tuple[str, str, str, float, float]], test_set: str, reference: str
) -> dict[str, tuple[int, int]]:
    """label -> (test flights of ``test_set`` on which its RMSE (``_per_flight``: seeds
    averaged) is below ``reference``'s, flights both were tested on); the reference itself and
    labels sharing no flight with it left out."""
    rmse = {(label, name): e for s, label, name, _, e in per_flight if s == test_set}
    mine = {name for label, name in rmse if label == reference}
    out = {}
    for label in dict.fromkeys(label for label, _ in rmse):
        shared = [n for n in mine if (label, n) in rmse]
        if label != reference and shared:
            better = sum(rmse[(label, n)] < rmse[(reference, n)] for n in shared)
            out[label] = (better, len(shared))
    return out


def write_loads_study(
    rows: Sequence[LoadsRow],
    per_flight: Sequence[tuple[str, str, str, float, float]],
    worse: dict[tuple[str, str], tuple[int, int]],
    out: Path,
    config: LoadsStudyConfig,
    params: VehicleParams,
    priors: dict[float, float] | None = None,
) -> None:
    """loads.csv (every run), flights.csv, loads.md (mean +- std over seeds, the ratios to
    physics with the true constants, the horizon steps worse than it: ``worse``; per test
    flight, how many each model predicts better than physics with the nominal constants and
    than the one-load network: ``flights_better``; the in-flight estimate's mass prior chosen,
    from ``priors``: prior -> validation RMSE) and loads.png."""
    write_csv(out / "loads.csv", ["set", "label", "seed", "horizon", "combined_rmse"],
              [[r.test_set, r.label, r.seed, r.horizon, r.rmse] for r in rows])  # fmt: skip
    header = ["set", "label", "flight", "mass_load_kg", f"combined_rmse_N{max(config.horizons)}"]
    write_csv(out / "flights.csv", header, per_flight)
    groups: dict[tuple[str, str, int], list[float]] = {}
    for r in rows:
        groups.setdefault((r.test_set, r.label, r.horizon), []).append(r.rmse)
    labels = list(dict.fromkeys(r.label for r in rows))
    parts = _loads_intro(config, params, priors)
    for test_set in SETS:
        parts += [
            "",
            f"## {test_set} the training range",
            "",
            _loads_table(test_set, labels, groups, worse, config),
        ]
        parts += _flights_better_table(test_set, labels, per_flight, config)
    parts += ["", "![RMSE against load mass](loads.png)", ""]
    write_text(out / "loads.md", "\n".join(parts))
    _figure(per_flight, config, out / "loads.png")


def _loads_intro(
    config: LoadsStudyConfig, params: VehicleParams, priors: dict[float, float] | None
) -> list[str]:
    """loads.md's title and what was trained and tested (and the estimate's prior chosen)."""
    parts = [
        "# Loads study: one model for many loads",
        "",
        f"Trained on loads of {config.train_mass[0]:g}-{config.train_mass[1]:g} kg on "
        f"{config.train_length[0]:g}-{config.train_length[1]:g} m cables (nominal "
        f"{params.mass_load:g} kg, {params.cable_length:g} m: the physics row's and the "
        f"one-load network's); tested on unseen loads inside that range and on "
        f"{config.beyond_mass[0]:g}-{config.beyond_mass[1]:g} kg, "
        f"{config.beyond_length[0]:g}-{config.beyond_length[1]:g} m beyond it. Combined RMSE "
        f"(mean ± std over seeds) and its ratio to {TRUTH!r}.",
    ]
    if priors:
        parts += [
            "",
            f"{ESTIMATE_ROW!r} runs f on each window's cable length and load mass estimated from "
            f"its history, the mass with the prior {min(priors, key=priors.__getitem__):g} "
            f"(m/s^2)^2 per equation, chosen on the validation flights of the training loads "
            f"(combined RMSE at N = {max(config.horizons)}: "
            + ", ".join(f"{w:g}: {e:.3f}" for w, e in priors.items())
            + f"). The adaptive networks' f runs on the same estimate with the prior "
            f"{ADAPT_PRIOR_WEIGHT:g}.",
        ]
    return parts


def _loads_table(
    test_set: str,
    labels: Sequence[str],
    groups: dict[tuple[str, str, int], list[float]],
    worse: dict[tuple[str, str], tuple[int, int]],
    config: LoadsStudyConfig,
) -> str:
    """One test set's table: per label and horizon the combined RMSE (mean ± std over seeds,
    ``groups``: (set, label, N) -> the seeds' RMSEs) and its ratio to ``TRUTH``'s, and the
    horizon steps worse than ``TRUTH`` (``worse``)."""
    header = ["model"]
    for n in config.horizons:
        header += [f"RMSE N = {n}", f"/ truth N = {n}"]
    header.append(f"steps worse than truth (position, load position; of {max(config.horizons)})")
    table = []
    for label in labels:
        row = [label]
        for n in config.horizons:
            values = groups.get((test_set, label, n))
            ref = groups.get((test_set, TRUTH, n))
            if not values:
                row += ["-", "-"]
                continue
            mean, std, seeds = mean_std(values)
            row.append(f"{mean:.3f}" + (f" ± {std:.3f}" if seeds > 1 else ""))
            row.append(f"{mean / mean_std(ref)[0]:.2f}" if ref else "-")
        steps = worse.get((test_set, label))
        row.append("-" if steps is None else f"{steps[0]}, {steps[1]}")
        table.append(row)
    return markdown_table(header, table)


def _flights_better_table(
    test_set: str,
    labels: Sequence[str],
    per_flight: Sequence[tuple[str, str, str, float, float]],
    config: LoadsStudyConfig,
) -> list[str]:
    """loads.md's lines (none where no label is counted) of how many test flights of
    ``test_set`` each model predicts better than physics with the nominal constants and than
    the one-load network (``flights_better``)."""
    versus = {ref: flights_better(per_flight, test_set, ref)
              for ref in (NOMINAL_ROW, ONE_LOAD_ROW)}  # fmt: skip
    counted = [label for label in labels if any(label in v for v in versus.values())]
    if not counted:
        return []
    n = max(config.horizons)
    table = [[label, *(f"{v[label][0]} of {v[label][1]}" if label in v else "-"
                       for v in versus.values())] for label in counted]  # fmt: skip
    return [
        "",
        f"Test flights on which each model's combined RMSE at N = {n} (seeds averaged) "
        "is lower than the reference's:",
        "",
        markdown_table(["model", *(f"better than {r!r}" for r in versus)], table),
    ]


def _figure(per_flight, config: LoadsStudyConfig, path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 4.4), constrained_layout=True)
    ax = fig.add_subplot()
    labels = list(dict.fromkeys(label for _, label, _, _, _ in per_flight))
    colors = model_colors(labels)
    for i, label in enumerate(labels):
        pts = sorted((m, e) for _, lab, _, m, e in per_flight if lab == label)
        if not pts:
            continue
        x, y = np.array(pts).T
        # Points, not lines: neighbouring masses are flights of different maneuvers.
        hollow = label.startswith("physics")
        ax.scatter(x, y, marker="os^vDP<>"[i % 8], s=22, label=label, color=colors[label],
                   facecolors="none" if hollow else colors[label])  # fmt: skip
    ax.axvspan(*config.train_mass, color="0.9", zorder=0, label="training range")
    ax.set_xlabel("load mass (kg)")
    ax.set_ylabel(f"combined RMSE at N = {max(config.horizons)} per test flight")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path)
