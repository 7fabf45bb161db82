"""Evaluation commands: evaluate runs, reproduce the paper's experiment, the studies."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import (
    add_cluster_option,
    choices,
    comma_ints,
    comma_names,
    load_range,
    new_command,
    positive_int,
    preset_help,
    seed_range,
)


def add_evaluate(sub: Any) -> None:
    p = new_command(
        sub,
        "evaluate",
        "evaluate trained runs against the physics model",
        "The paper's metrics on the test flights, for every run and the physics-only "
        "predictor: MAE per horizon step with quartiles, the RMSE table beside the paper's, "
        "figures, CSVs and report.md. Runs of one variant are seeds (mean and spread).",
    )
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR", help="run folders or .ckpt")
    p.add_argument("--data", type=Path, help="dataset folder (default: the runs' own)")
    p.add_argument("--out", required=True, type=Path, help="report folder")
    p.add_argument(
        "--horizons",
        type=int,
        nargs="+",
        default=[25, 50],
        metavar="N",
        help="predicted steps to evaluate (default 25 50; h = 0.03 s a step)",
    )
    p.add_argument(
        "--split",
        default="test",
        choices=("test", "val"),
        help="flights to evaluate on (default test; val to choose a configuration without "
        "looking at the test flights)",
    )
    p.add_argument("--no-physics", action="store_true", help="leave out the physics predictor")
    _add_timing_options(p)
    p.add_argument(
        "--device", default="cpu", choices=("cpu", "cuda"), help="where to predict (default cpu)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_evaluate)


def _add_timing_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--timing",
        action="store_true",
        help="also time batch-1 inference (eager and compiled) for the report's Table II; "
        "minutes, and only meaningful on an idle machine (`slungload benchmark` is the full "
        "latency benchmark)",
    )
    p.add_argument(
        "--timing-repeats", type=int, default=100, metavar="K", help="timed calls (default 100)"
    )
    p.add_argument("--no-timing", action="store_true", help=argparse.SUPPRESS)  # the old default


def cmd_evaluate(args: argparse.Namespace) -> int:
    from ..experiment import evaluate_runs

    evaluate_runs(
        args.runs,
        data=args.data,
        out=args.out,
        horizons=tuple(args.horizons),
        include_physics=not args.no_physics,
        split=args.split,
        timing=args.timing and not args.no_timing,
        timing_repeats=args.timing_repeats,
        device=args.device,
        progress=not args.quiet,
    )
    print(args.out / "report.md")
    return 0


def add_reproduce(sub: Any) -> None:
    p = new_command(
        sub,
        "reproduce",
        "the paper's experiment end to end (the main job)",
        "Simulate the default dataset (or use --data), train the variants proposed, no-slack "
        "and no-physics of the paper's network and the physics-step network (no-physics, "
        "trained over N = 50 with the mixed step weighting and the smoothed load estimate) "
        "for every seed, two at a time, "
        "evaluate them with the physics-only predictor at N = 25 and 50, and write "
        "OUT/report/report.md. Every variant trains for its preset's epochs; a run stopped "
        "short by the time cap (a safety net) is reported and the command exits with status "
        "1: run it again to resume such runs. Finished runs are kept, so an interrupted call "
        "can be re-run.",
    )
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--data", type=Path, help="dataset folder (default: simulate one)")
    p.add_argument(
        "--preset",
        default="default",
        choices=choices("presets"),
        help=preset_help("default"),
    )
    p.add_argument(
        "--seeds",
        default="0",
        metavar="SEEDS",
        help="training seeds (weights, batches): one N, a range A..B (both included) or a "
        "list A,B,C (default 0)",
    )
    p.add_argument(
        "--flights",
        type=positive_int,
        default=48,
        help="flights to simulate when no --data is given (default 48, the paper's)",
    )
    p.add_argument("--workers", type=int, default=2, help="parallel training runs (default 2)")
    add_cluster_option(p)
    p.add_argument(
        "--device",
        default="cpu",
        choices=("auto", "cpu", "cuda"),
        help="where to train (default cpu)",
    )
    _add_timing_options(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_reproduce)


def cmd_reproduce(args: argparse.Namespace) -> int:
    from ..experiment import reproduce

    result = reproduce(
        out=args.out,
        data=args.data,
        preset=args.preset,
        seeds=seed_range(args.seeds),
        flights=args.flights,
        workers=args.workers,
        cluster=args.cluster,
        device=args.device,
        timing=args.timing and not args.no_timing,
        timing_repeats=args.timing_repeats,
        progress=not args.quiet,
    )
    stages = ", ".join(f"{k} {v:.0f} s" for k, v in result.seconds.items())
    print(f"report: {result.report_path}  ({stages})")
    for run in result.time_capped:
        print(
            f"WARNING: {run.name} was stopped by the time cap before its epoch budget; its "
            "numbers are not comparable. Run the same command again to resume it to its budget.",
            file=sys.stderr,
        )
    return 1 if result.time_capped else 0


def add_study(sub: Any) -> None:
    p = new_command(
        sub,
        "study",
        "studies beyond the paper (data: where physics-informed training helps; size: how "
        "large the network must be for control)",
        "`study data`: train each loss variant on nested subsets of the training flights "
        "(validation and test flights fixed) and plot the RMSE at N = 50 against the number "
        "of training flights. `study size`: train the physics-step network at each named size "
        "and plot its validation RMSE at N = 50 against the MPC's batched rollout time.",
    )
    kinds = p.add_subparsers(dest="study", metavar="STUDY", required=True)
    d = kinds.add_parser("data", help="RMSE against the number of training flights")
    d.add_argument("--out", required=True, type=Path, help="output folder")
    d.add_argument(
        "--flights",
        type=comma_ints,
        default=[6, 12, 24, 48],
        metavar="K,K",
        help="training-flight counts (default 6,12,24,48); the simulated dataset is sized "
        "for the largest",
    )
    d.add_argument("--data", type=Path, help="dataset folder (default: simulate one)")
    d.add_argument(
        "--variants",
        type=comma_names,
        default=["proposed", "no-slack", "no-physics"],
        metavar="V,V",
        help="loss variants (default proposed,no-slack,no-physics)",
    )
    d.add_argument(
        "--models",
        type=comma_names,
        default=["lstm-attention"],
        metavar="NAME,NAME",
        help="architectures (default lstm-attention)",
    )
    d.add_argument("--seeds", default="0", metavar="SEEDS", help="as for reproduce (default 0)")
    d.add_argument(
        "--preset", default="default", choices=choices("presets"), help="default: default"
    )
    d.add_argument("--workers", type=int, default=2, help="parallel training runs (default 2)")
    add_cluster_option(d)
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    _add_study_size(kinds)
    _add_study_loads(kinds)
    p.set_defaults(func=cmd_study)


def _add_study_size(kinds: Any) -> None:
    from ..config import MODEL_SIZES, PREDICTION_BACKENDS

    s = kinds.add_parser(
        "size",
        help="validation RMSE at N = 50 against the MPC's batched rollout time, per network size",
        description="Train reproduce's best configuration (physics-step, no-physics, mixed step "
        "weighting, N = 50, smoothed load estimate) at each named network size, evaluate it on "
        "the validation flights at N = 50, time one batched rollout in the MPC's shape "
        "(K plans of N steps, one torch thread) and train the sizes on the Pareto front with "
        "more seeds. Writes size.md, size.csv, timing.csv and size.png into OUT; finished runs "
        "are kept, so an interrupted study can be re-run.",
    )
    s.add_argument(
        "--data", required=True, type=Path, help="dataset folder (for control: excited flights)"
    )
    s.add_argument("--out", required=True, type=Path, help="output folder")
    s.add_argument(
        "--sizes",
        type=comma_names,
        default=list(MODEL_SIZES),
        metavar="NAME,NAME",
        help="network sizes: "
        + "; ".join(f"{n} ({size.summary()})" for n, size in MODEL_SIZES.items())
        + f" (default {','.join(MODEL_SIZES)})",
    )
    s.add_argument("--seeds", default="0", metavar="SEEDS", help="every size's seeds (default 0)")
    s.add_argument(
        "--front-seeds",
        default="1,2",
        metavar="SEEDS",
        help="further seeds of the sizes on the Pareto front (default 1,2; 'none': no more)",
    )
    s.add_argument(
        "--preset", default="default", choices=choices("presets"), help="default: default"
    )
    s.add_argument(
        "--epochs", type=int, help="epochs in place of the preset's (its schedule fitted to them)"
    )
    s.add_argument("--samples", type=int, default=256, metavar="K", help="plans (default 256)")
    s.add_argument("--steps", type=int, default=15, metavar="N", help="plan steps (default 15)")
    s.add_argument("--repeats", type=int, default=200, help="timed rollouts (default 200)")
    s.add_argument(
        "--backend",
        choices=list(PREDICTION_BACKENDS),
        default="compiled",
        help="what the rollouts are timed on: "
        + "; ".join(f"{k}: {v}" for k, v in PREDICTION_BACKENDS.items())
        + " (default compiled, the MPC's fast path)",
    )
    s.add_argument("--workers", type=int, default=2, help="parallel training runs (default 2)")
    add_cluster_option(s)
    s.add_argument(
        "--no-train",
        action="store_true",
        help="train nothing: evaluate and time the finished runs (re-time on a quiet machine, "
        "or report a study cut short)",
    )
    s.add_argument("--quiet", action="store_true", help="no progress bars")


def _add_study_loads(kinds: Any) -> None:
    from dataclasses import fields

    from ..study.loads_config import NETWORK_ROWS, PHYSICS_ROWS, RANGES, LoadsStudyConfig

    cfg = LoadsStudyConfig()
    s = kinds.add_parser(
        "loads",
        help="one model for many loads: unseen loads inside and beyond the training range",
        description="Simulate flights of one load, of loads drawn from a range and of loads "
        "beyond it; train the physics-step network (reproduce's best configuration) on "
        + "; ".join(
            f"{label!r}: {data} flights, f with the {c} constants"
            + (", its correction seeing them" if seeing else "")
            for label, (data, c, seeing) in NETWORK_ROWS.items()
        )  # fmt: skip
        + "; compare with physics run with "
        + ", ".join(f"the {c} constants ({label!r})" for label, c in PHYSICS_ROWS.items())
        + " on unseen loads inside the range (the test flights) and beyond it (every flight). "
        "Writes loads.md, loads.csv, flights.csv, loads.png and the evaluation reports "
        "inside/ and beyond/ into OUT; datasets and finished runs are kept, so an "
        "interrupted study can be re-run.",
    )
    s.add_argument("--out", required=True, type=Path, help="output folder")
    for f in fields(LoadsStudyConfig):
        if f.name not in RANGES:
            continue
        low, high = getattr(cfg, f.name)
        s.add_argument(
            f"--{f.name.replace('_', '-')}",
            type=load_range,
            default=(low, high),
            metavar="LO:HI",
            help=f"{f.metadata['text']}, {f.metadata['unit']} (default {low:g}:{high:g})",
        )
    s.add_argument("--flights", type=int, default=cfg.flights,
                   help=f"flights of one load and of many (default {cfg.flights})")  # fmt: skip
    s.add_argument("--beyond-flights", type=int, default=cfg.beyond_flights,
                   help=f"flights beyond the range (default {cfg.beyond_flights})")  # fmt: skip
    s.add_argument("--size", default=cfg.size, choices=choices("sizes"),
                   help=f"network size (default {cfg.size})")  # fmt: skip
    s.add_argument("--seeds", default="0", metavar="SEEDS", help="as for reproduce (default 0)")
    s.add_argument(
        "--preset", default="default", choices=choices("presets"), help="default: default"
    )
    s.add_argument(
        "--epochs", type=int, help="epochs in place of the preset's (its schedule fitted to them)"
    )
    s.add_argument("--sim-seed", type=int, default=0, help="simulation seed (default 0)")
    s.add_argument("--workers", type=int, default=2, help="parallel training runs (default 2)")
    add_cluster_option(s)
    s.add_argument("--quiet", action="store_true", help="no progress bars")


def cmd_study(args: argparse.Namespace) -> int:
    if args.study == "loads":
        from ..study import LoadsStudyConfig, study_loads

        config = LoadsStudyConfig(
            train_mass=args.train_mass, train_length=args.train_length,
            beyond_mass=args.beyond_mass, beyond_length=args.beyond_length,
            flights=args.flights, beyond_flights=args.beyond_flights, size=args.size,
        )  # fmt: skip
        study_loads(
            out=args.out, config=config, seeds=seed_range(args.seeds), preset=args.preset,
            epochs=args.epochs, sim_seed=args.sim_seed, workers=args.workers,
            cluster=args.cluster, progress=not args.quiet,
        )  # fmt: skip
        print(args.out / "loads.md")
        return 0
    if args.study == "size":
        from ..study import study_size

        study_size(
            data=args.data,
            out=args.out,
            sizes=args.sizes,
            seeds=seed_range(args.seeds),
            front_seeds=() if args.front_seeds == "none" else seed_range(args.front_seeds),
            preset=args.preset,
            samples=args.samples,
            steps=args.steps,
            repeats=args.repeats,
            backend=args.backend,
            epochs=args.epochs,
            workers=args.workers,
            cluster=args.cluster,
            train=not args.no_train,
            progress=not args.quiet,
        )
        print(args.out / "size.md")
        return 0
    from ..study import study_data

    study_data(
        out=args.out,
        flights=args.flights,
        data=args.data,
        variants=args.variants,
        architectures=args.models,
        seeds=seed_range(args.seeds),
        preset=args.preset,
        workers=args.workers,
        cluster=args.cluster,
        progress=not args.quiet,
    )
    print(args.out / "study.md")
    return 0


def add_tune(sub: Any) -> None:
    from ..tune_config import SearchSpace, TuneSettings

    space, settings = SearchSpace(), TuneSettings()
    p = new_command(
        sub,
        "tune",
        "search for the training configuration that suits a dataset (Ray Tune)",
        "A configuration search on the validation flights: Optuna's TPE proposes trials over "
        + "; ".join(
            f"{name} {'/'.join(map(str, getattr(space, name)))}"
            for name in (
                "architecture",
                "variant",
                "steps",
                "horizon",
                "load_estimate",
                "size",
                "batch_size",
            )
        )  # fmt: skip
        + f"; learning rate {space.lr[0]:g}-{space.lr[1]:g} (log-uniform), the first trial "
        "being reproduce's configuration; ASHA stops poor trials early on each epoch's "
        "validation loss; a finished trial scores combined RMSE at N = 50 on the validation "
        "flights, mean of two seeds. Writes trials.csv, tune.md, tune.png and best.toml "
        "(`slungload train --config best.toml` retrains the winner). Needs Ray (pip install "
        "'slungload[cluster]'); docs/cluster.md.",
    )
    p.add_argument("--data", required=True, type=Path, help="dataset folder")
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--trials", type=int, default=settings.trials,
                   help=f"trials (default {settings.trials})")  # fmt: skip
    p.add_argument(
        "--preset", default=settings.preset, choices=choices("presets"),
        help=f"the search budget's schedule (default {settings.preset})",
    )  # fmt: skip
    p.add_argument("--epochs", type=int, default=settings.epochs,
                   help=f"epochs per trial, the preset's schedule fitted to them (default "
                   f"{settings.epochs})")  # fmt: skip
    p.add_argument(
        "--final-preset", default=settings.final_preset, choices=choices("presets"),
        help=f"best.toml's schedule, what the winner retrains with (default "
        f"{settings.final_preset})",
    )  # fmt: skip
    p.add_argument(
        "--concurrent", type=int, default=settings.concurrent,
        help=f"trials at a time, one CPU each (default {settings.concurrent})",
    )  # fmt: skip
    p.add_argument(
        "--cluster", default="local", metavar="ADDRESS",
        help="where the trials run: local (a Ray instance on this machine; the default), auto "
        "(the cluster RAY_ADDRESS names) or ray://HOST:PORT; the dataset and OUT on storage "
        "every node sees",
    )  # fmt: skip
    p.set_defaults(func=cmd_tune)


def cmd_tune(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ..study.tune import run_tune
    from ..tune_config import TuneSettings

    settings = replace(TuneSettings(), trials=args.trials, preset=args.preset, epochs=args.epochs,
                       final_preset=args.final_preset, concurrent=args.concurrent)  # fmt: skip
    run_tune(args.data, args.out, settings, cluster=args.cluster)
    print(args.out / "tune.md")
    return 0
