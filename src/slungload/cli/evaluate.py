"""Evaluation commands: evaluate runs, and reproduce the paper's experiment (the lab's)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..fileio import EVERY, HELD_OUT
from .common import (
    add_cluster_option,
    choices,
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
        choices=("test", "val", EVERY),
        help="flights to evaluate on (default test; val to choose a configuration without "
        f"looking at the test flights; {EVERY}: every flight, for a dataset the models never "
        "saw: another vehicle's or load's)",
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
    from ..deploy.timing import evaluate_runs

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


def add_check(sub: Any) -> None:
    from ..config import PreflightConfig

    cfg = PreflightConfig()
    p = new_command(
        sub,
        "check",
        "say before flying whether a network will beat the physics model in an MPC",
        "From held-out flights alone: how well each model's predicted effect of the commands "
        "follows their true effect (what an MPC's choice among plans depends on; errors every "
        "plan shares cancel), network against physics at the MPC's horizon, with a "
        "flight-bootstrap interval. 'does not pay' is a mostly reliable no; 'may pay' is "
        "necessary, not sufficient (how often each held: docs/control.md). "
        "Writes check.md, check.json and check.png to --out and the verdict to the run's "
        "preflight.json, which `slungload control` reads to warn. Give flights whose commands "
        "varied (`simulate --excite`, `record`, a pilot's): a PID's alone leave little to "
        "measure (docs/control.md).",
    )
    p.add_argument("run", type=Path, metavar="RUN_DIR", help="run folder, .ckpt or ensemble")
    p.add_argument("--data", type=Path, help="dataset folder (default: the run's own)")
    p.add_argument("--split", default=cfg.split, choices=(HELD_OUT, "test", "val", EVERY),
                   help=f"flights to judge on: {HELD_OUT} is val and test together, {EVERY} "
                   f"every flight (a vehicle the run never saw) (default {cfg.split})")  # fmt: skip
    p.add_argument("--horizon", type=positive_int, default=cfg.horizon, metavar="N",
                   help=f"the MPC's horizon, steps of 0.03 s (default {cfg.horizon})")  # fmt: skip
    p.add_argument("--pays-below", type=float, default=cfg.pays_below, metavar="R",
                   help="the network may pay when its response score's interval (the share of "
                   "the commands' effect it leaves unexplained) lies below R x physics's "
                   f"(default {cfg.pays_below:g})")  # fmt: skip
    p.add_argument("--vehicle-below", type=float, default=cfg.vehicle_below, metavar="R",
                   help="... and its vehicle score's interval below R x physics's: a network "
                   "that learned this vehicle explains its response to commands far better "
                   f"than physics (default {cfg.vehicle_below:g})")  # fmt: skip
    p.add_argument("--out", type=Path, help="report folder (default RUN_DIR/check)")
    p.set_defaults(func=cmd_check)


def cmd_check(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ..config import PreflightConfig
    from ..evaluation.preflight import check, record_verdict, write_check
    from ..evaluation.verdicts import verdicts_path

    cfg = replace(PreflightConfig(), horizon=args.horizon, split=args.split,
                  pays_below=args.pays_below, vehicle_below=args.vehicle_below)  # fmt: skip
    result = check(args.run, args.data, cfg=cfg)
    print(result.summary())
    for path in write_check(result, args.out or verdicts_path(args.run).parent / "check"):
        print(f"wrote {path}")
    print(f"wrote {record_verdict(result)}")
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
    from ..lab.reproduce import reproduce

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
