"""Training commands: train a network, identify the physics model's constants."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..config import ARCHITECTURES, ENSEMBLE_LEVEL, ESTIMATE_MIN_STEPS, LOSS_VARIANTS, MODEL_SIZES
from ..run_config import RunConfig
from .common import (
    add_vehicle_options,
    add_window_options,
    choices,
    given,
    new_command,
    positive_int,
    preset_help,
    resolve_params,
)

RUN = RunConfig()  # the defaults of every option that describes the run


def add_train(sub: Any) -> None:
    p = new_command(
        sub,
        "train",
        "train one model variant on a dataset",
        "Train one network (--model) with one loss variant (--variant) on a dataset's train "
        "split, validating on its val split. The run folder gets best.ckpt, last.ckpt (every "
        "epoch), run.json, run.toml (the run's description) and logs. Ctrl-C stops after the "
        "batch and saves last.ckpt; run the same command with --resume to continue.",
    )
    p.add_argument("--data", required=True, type=Path, help="dataset folder")
    p.add_argument("--out", required=True, type=Path, help="run folder to create")
    p.add_argument(
        "--config",
        type=Path,
        metavar="RUN_TOML",
        help="the run's description from a file (a run folder's run.toml, or the best "
        "configuration `slungload tune` writes) instead of the options below; --seed and "
        "--epochs still apply",
    )
    _add_model_options(p)
    p.add_argument(
        "--device",
        default="auto",
        choices=("auto", "cpu", "cuda"),
        help="default auto (GPU if any)",
    )
    p.add_argument("--devices", type=int, default=1, help="processes for DDP (default 1)")
    p.add_argument(
        "--seed", type=int, help=f"weights and batch order (default {RUN.seed}, or --config's)"
    )
    p.add_argument("--epochs", type=int, help="override the preset's maximum epochs")
    p.add_argument(
        "--ensemble",
        type=positive_int,
        metavar="K",
        help="train K members (seeds --seed ... --seed + K - 1) into OUT/member-i as one "
        "ensemble (OUT/ensemble.json), then calibrate its spread on the val split "
        "(`slungload calibrate`); a mean and an interval wherever a network is taken",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue from RUN_DIR/last.ckpt (an ensemble: its unfinished members)",
    )
    p.add_argument(
        "--fit-constants",
        action="store_true",
        help="fit the physics model's constants to the training flights first (as `identify`)",
    )
    p.add_argument(
        "--bootstrap",
        action="store_true",
        help="train on a resample of the training flights drawn with replacement from the "
        "seed (with --ensemble: members that differ by their data too)",
    )
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_window_options(p)
    add_vehicle_options(p)
    p.set_defaults(func=cmd_train, run_defaults={d: p.get_default(d) for d in RUN_OPTIONS})


def _add_model_options(p: argparse.ArgumentParser) -> None:
    """The options that describe the run's network and loss (``RUN_OPTIONS``), their defaults
    read from ``RunConfig()``."""
    p.add_argument(
        "--variant",
        default=RUN.variant,
        choices=choices("variants"),
        help=f"loss variant (default {RUN.variant}: {LOSS_VARIANTS[RUN.variant].description})",
    )
    p.add_argument(
        "--model",
        default=RUN.model.architecture,
        choices=choices("models"),
        help=f"network architecture (default {RUN.model.architecture}: "
        f"{ARCHITECTURES[RUN.model.architecture].description})",
    )
    p.add_argument(
        "--size",
        default=RUN.model.size,
        choices=choices("sizes"),
        help="network size: "
        + "; ".join(f"{n} ({s.summary()}: {s.description})" for n, s in MODEL_SIZES.items())
        + f" (default {RUN.model.size})",
    )
    p.add_argument(
        "--preset",
        default=RUN.preset,
        choices=choices("presets"),
        help=preset_help(RUN.preset),
    )
    p.add_argument(
        "--steps",
        default=RUN.loss.steps,
        choices=choices("steps"),
        help="how the fit loss weighs the horizon steps: paper (e^{-alpha n}, the default), "
        "physics-relative (each step divided by the physics model's mean-square error there, "
        "so the early steps, where physics is already good, count as much as the late ones) "
        "or mixed (the mean of the two)",
    )
    p.add_argument(
        "--load-estimate",
        default=RUN.model.load_estimate,
        choices=choices("load-estimates"),
        help="physics-step network: how it estimates the load's velocity and swing rate to "
        "start f from: difference (the last two positions, the data's estimate; default) or "
        "smoothed (quadratic fits through the last 9: less motion-capture noise)",
    )
    p.add_argument(
        "--constants",
        default=RUN.model.constants,
        choices=choices("network-constants"),
        help="physics-step network: the constants its f runs with: dataset (vehicle.json's, "
        "one set; default) or window (each window's cable length and load mass estimated in "
        "flight from its history: one network for many loads; needs --history >= "
        f"{ESTIMATE_MIN_STEPS})",
    )
    p.add_argument(
        "--constants-input",
        action="store_true",
        help="physics-step network: its correction also takes f's cable length and load mass "
        "(as ratios to the dataset's) as inputs at every step, with --constants window the "
        "window's estimate",
    )
    p.add_argument(
        "--heading-frame",
        action="store_true",
        help="the network sees each window turned about the vertical so that its last heading "
        "points along x, and its prediction is turned back: the same for every heading by "
        "construction (a network without it must learn each heading from data)",
    )


# What a --config file describes instead (its options may not be given beside it).
RUN_OPTIONS = ("variant", "model", "size", "preset", "fit_constants", "steps", "load_estimate",
               "constants", "constants_input", "heading_frame", "history", "horizon",
               "stride")  # fmt: skip


def run_from_args(args: argparse.Namespace):
    """The ``RunConfig`` of ``train``'s options, or of ``--config`` (with --seed, --epochs)."""
    from dataclasses import replace

    from ..config import LossWeights, ModelConfig, WindowConfig
    from ..run_config import RunConfig, read_toml

    if args.config is not None:
        given = [f"--{d.replace('_', '-')}" for d in RUN_OPTIONS
                 if getattr(args, d) != args.run_defaults[d]]  # fmt: skip
        if given:
            raise ValueError(f"--config {args.config} describes the run: drop {', '.join(given)}")
        run = read_toml(args.config)
        train = run.train
        if args.seed is not None:
            train = replace(train, seed=args.seed)
        if args.epochs is not None:
            train = replace(train, max_epochs=args.epochs)
        if args.bootstrap:
            train = replace(train, bootstrap=True)
        return replace(run, train=train)
    run = RunConfig.from_preset(
        args.preset,
        variant=args.variant,
        seed=RUN.seed if args.seed is None else args.seed,
        max_epochs=args.epochs,
        fit_constants=args.fit_constants,
        model=ModelConfig.sized(
            args.size,
            architecture=args.model,
            load_estimate=args.load_estimate,
            constants=args.constants,
            constants_input=args.constants_input,
            heading_frame=args.heading_frame,
        ),
        loss=LossWeights(steps=args.steps),
        window=WindowConfig(history=args.history, horizon=args.horizon, stride=args.stride),
    )
    return replace(run, train=replace(run.train, bootstrap=True)) if args.bootstrap else run


def cmd_train(args: argparse.Namespace) -> int:
    from lightning.pytorch.utilities import rank_zero_only

    from ..training.trainer import train

    run = run_from_args(args)
    if args.ensemble is not None:
        return _train_ensemble(args, run)
    result = train(args.data, run, devices=args.devices, **_train_options(args))
    if rank_zero_only.rank == 0:  # with --devices K every process runs this command
        print(result.summary())
    return 0


def _train_ensemble(args: argparse.Namespace, run: Any) -> int:
    from ..training.ensemble import train_ensemble
    from .ensemble import report_calibration

    if args.devices != 1:
        raise ValueError("--ensemble trains its members one process each: drop --devices")
    results = train_ensemble(args.data, run, members=args.ensemble, **_train_options(args))
    for i, result in enumerate(results):
        print(f"member {i}: " + ("kept (finished before)" if result is None else result.summary()))
    report_calibration(args.out, args.data, split="val", horizon=None, level=ENSEMBLE_LEVEL)
    return 0


def _train_options(args: argparse.Namespace) -> dict[str, Any]:
    """What ``train`` and ``train_ensemble`` take alike from the options."""
    return {
        "out": args.out,
        "device": args.device,
        "resume": args.resume,
        "params": resolve_params(Path(args.data), args),
        "progress": not args.quiet,
        "num_threads": args.threads,
    }


def add_identify(sub: Any) -> None:
    from ..input_lag import FIT_HORIZON  # numpy only

    p = new_command(
        sub,
        "identify",
        "fit the physics model's constants to a dataset's flights",
        "System identification: the load mass, cable length, load damping and thrust gain "
        "that make the discrete model's open-loop rollouts (--horizon steps from every "
        "training window) closest to the recorded flights, starting from vehicle.json (or the "
        "defaults listed below). The vehicle mass stays as given. `train --fit-constants` does "
        "the same before training. With --input-lag: the time constants of the commands' lags "
        "the model leaves out (thrust, roll and pitch rates, yaw rate), for the physics MPC's "
        "--input-lag (docs/control.md).",
    )
    p.add_argument("data", type=Path, help="dataset folder")
    p.add_argument(
        "--horizon",
        type=int,
        metavar="N",
        help=f"steps per rollout (default 10; with --input-lag {FIT_HORIZON}, the MPC's N)",
    )
    p.add_argument(
        "--out", type=Path, help="write the fitted constants as a vehicle.json file here"
    )
    p.add_argument(
        "--input-lag",
        action="store_true",
        help="fit the commands' lags instead, over --horizon steps (give the MPC's N, e.g. 15)",
    )
    add_vehicle_options(p)
    p.set_defaults(func=cmd_identify)


def cmd_identify(args: argparse.Namespace) -> int:
    from ..config import to_dict
    from ..fileio import write_json
    from ..training.identify import fit_input_lag, identify

    params = resolve_params(Path(args.data), args)
    horizon = given(horizon=args.horizon)  # each fit's own default otherwise
    if args.input_lag:
        if args.out is not None:
            raise ValueError("--input-lag prints the lags to fly with; it writes no --out file")
        print(fit_input_lag(args.data, params=params, **horizon).summary())
        return 0
    found = identify(args.data, params=params, **horizon)
    print(found.summary())
    if args.out is not None:
        if args.out.is_dir():
            raise IsADirectoryError(f"--out takes a file name (e.g. {args.out / 'vehicle.json'})")
        write_json(args.out, {"vehicle": to_dict(found.params), "identified": found.table})
        print(f"wrote {args.out}")
    return 0
