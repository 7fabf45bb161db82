"""Command line: parses arguments and calls the stage functions; no logic lives here.

A user error (bad path, bad file, bad option) prints one line and exits with status 2;
``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ._version import __version__

USER_ERRORS = (
    ValueError,
    FileNotFoundError,
    FileExistsError,
    NotADirectoryError,
    IsADirectoryError,
    PermissionError,
    KeyError,
)


def _vehicle_overrides(args: argparse.Namespace) -> dict[str, float]:
    names = (
        "mass_quad",
        "mass_load",
        "cable_length",
        "load_damping",
        "dt",
        "gravity",
        "thrust_gain",
    )
    return {n: getattr(args, n) for n in names if getattr(args, n, None) is not None}


def _add_vehicle_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "vehicle constants of the discrete model",
        "Override the dataset's vehicle.json; without either, the paper's constants apply "
        "(mQ 1.54 kg, mL 0.21 kg, l 0.67 m, d 0.01, h 0.03 s, g 9.81 m/s^2).",
    )
    g.add_argument("--mass-quad", dest="mass_quad", type=float, metavar="KG", help="vehicle mass")
    g.add_argument("--mass-load", dest="mass_load", type=float, metavar="KG", help="load mass")
    g.add_argument("--cable-length", dest="cable_length", type=float, metavar="M", help="cable")
    g.add_argument(
        "--load-damping",
        dest="load_damping",
        type=float,
        metavar="D",
        help="load damping d per step (unitless, in [0, 1))",
    )
    g.add_argument("--dt", type=float, metavar="S", help="sampling time h, s")
    g.add_argument("--gravity", type=float, metavar="M/S2", help="gravity, m/s^2")
    g.add_argument(
        "--thrust-gain",
        dest="thrust_gain",
        type=float,
        metavar="K",
        help="achieved / commanded thrust (unitless; the paper's model: 1)",
    )


def _add_window_options(p: argparse.ArgumentParser, horizon: int = 25) -> None:
    g = p.add_argument_group("windows", "How the flights are cut into training windows.")
    g.add_argument(
        "--history",
        type=int,
        default=50,
        metavar="M",
        help="past steps a window holds (default 50)",
    )
    g.add_argument(
        "--horizon",
        type=int,
        default=horizon,
        metavar="N",
        help=f"future steps predicted (default {horizon})",
    )
    g.add_argument("--stride", type=int, default=1, help="steps between windows (default 1)")


def _resolve_params(folder: Path, args: argparse.Namespace):
    """Vehicle constants for a dataset folder with the CLI's overrides applied, or None when
    there are none (the data module then reads vehicle.json or says it uses the paper's)."""
    import dataclasses

    from .config import VehicleParams, load_vehicle

    overrides = _vehicle_overrides(args)
    if not overrides:
        return None
    return dataclasses.replace(load_vehicle(folder) or VehicleParams(), **overrides)


# --- commands --------------------------------------------------------------------------


def cmd_simulate(args: argparse.Namespace) -> int:
    from .data.summary import summarize
    from .sim import Effects, Excitation, SimConfig, simulate_dataset

    off = [name for name in Effects.names() if getattr(args, f"no_{name}")]
    excitation = Excitation()
    if args.excite is not None:
        thrust, *rates = args.excite
        excitation = Excitation(thrust, tuple(rates), args.excite_tau)
    result = simulate_dataset(
        args.out,
        flights=args.flights,
        seed=args.seed,
        config=SimConfig(effects=Effects().without(*off), excitation=excitation),
        workers=args.workers,
        overwrite=args.overwrite,
        progress=not args.quiet,
        maneuvers=args.maneuvers,
    )
    print(f"wrote {len(result.flights)} flights to {result.folder} in {result.elapsed:.1f} s")
    print(summarize(result.folder).to_table())
    return 0


def cmd_maneuvers(args: argparse.Namespace) -> int:
    from .sim.maneuvers import MANEUVER_DESCRIPTIONS, MANEUVERS

    width = max(map(len, MANEUVERS))
    for name in sorted(MANEUVERS):
        print(f"{name:<{width}}  {MANEUVER_DESCRIPTIONS.get(name, '')}".rstrip())
    return 0


def cmd_identify(args: argparse.Namespace) -> int:
    from .config import to_dict
    from .fileio import write_json
    from .training.identify import identify

    found = identify(args.data, params=_resolve_params(Path(args.data), args), horizon=args.horizon)
    print(found.summary())
    if args.out is not None:
        if args.out.is_dir():
            raise IsADirectoryError(f"--out takes a file name (e.g. {args.out / 'vehicle.json'})")
        write_json(args.out, {"vehicle": to_dict(found.params), "identified": found.table})
        print(f"wrote {args.out}")
    return 0


def cmd_study(args: argparse.Namespace) -> int:
    from .study import study_data

    study_data(
        out=args.out,
        flights=args.flights,
        data=args.data,
        variants=args.variants,
        architectures=args.models,
        seeds=_seed_range(args.seeds),
        preset=args.preset,
        workers=args.workers,
        progress=not args.quiet,
    )
    print(args.out / "study.md")
    return 0


def cmd_split(args: argparse.Namespace) -> int:
    from .data.split import split_dataset

    splits = split_dataset(
        args.data, val=args.val, test=args.test, seed=args.seed, overwrite=args.overwrite
    )
    print(", ".join(f"{s}: {len(names)} flights" for s, names in splits.items()))
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    import dataclasses

    from .config import VehicleParams, read_vehicle
    from .data.importing import ImportOptions, import_logs
    from .data.readers.logs import load_mapping

    overrides = _vehicle_overrides(args)
    params = None
    if args.vehicle is not None or overrides:
        base = read_vehicle(args.vehicle) if args.vehicle is not None else VehicleParams()
        params = dataclasses.replace(base, **overrides)
    options = ImportOptions(
        hover_throttle=args.hover_throttle,
        max_gap=args.max_gap,
        on_gap=args.on_gap,
        min_duration=args.min_duration,
        commands=args.commands,
        split=args.split,
        seed=args.seed,
    )
    result = import_logs(
        args.logs,
        args.out,
        params=params,
        mapping=load_mapping(args.map) if args.map is not None else None,
        preset=args.preset,
        options=options,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    print(result.summary())
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    from .config import WindowConfig
    from .data.summary import summarize

    window = WindowConfig(history=args.history, horizon=args.horizon, stride=args.stride)
    summary = summarize(args.data, window=window, params=_resolve_params(Path(args.data), args))
    print(summary.to_table())
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from lightning.pytorch.utilities import rank_zero_only

    from .config import ModelConfig, WindowConfig
    from .training.trainer import train

    run = train(
        args.data,
        out=args.out,
        variant=args.variant,
        model_config=ModelConfig(architecture=args.model),
        preset=args.preset,
        device=args.device,
        devices=args.devices,
        seed=args.seed,
        max_epochs=args.epochs,
        resume=args.resume,
        window=WindowConfig(history=args.history, horizon=args.horizon, stride=args.stride),
        params=_resolve_params(Path(args.data), args),
        progress=not args.quiet,
        num_threads=args.threads,
        fit_constants=args.fit_constants,
    )
    if rank_zero_only.rank == 0:  # with --devices K every process runs this command
        print(run.summary())
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from .experiment import evaluate_runs

    evaluate_runs(
        args.runs,
        data=args.data,
        out=args.out,
        horizons=tuple(args.horizons),
        include_physics=not args.no_physics,
        timing=args.timing and not args.no_timing,
        timing_repeats=args.timing_repeats,
        device=args.device,
        progress=not args.quiet,
    )
    print(args.out / "report.md")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from .experiment import reproduce

    result = reproduce(
        out=args.out,
        data=args.data,
        preset=args.preset,
        seeds=_seed_range(args.seeds),
        flights=args.flights,
        workers=args.workers,
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


def cmd_export(args: argparse.Namespace) -> int:
    from .deploy.onnx import export

    result = export(args.run, args.out, format=args.format, horizon=args.horizon)
    print(result.summary())
    return 0


def cmd_benchmark(args: argparse.Namespace) -> int:
    from .config import ModelConfig
    from .deploy.benchmarks import benchmark
    from .fileio import write_text

    config = None if args.model is None else ModelConfig(architecture=args.model)
    if config is not None and args.run is not None:
        raise ValueError("--model builds a random network; a RUN_DIR brings its own")
    result = benchmark(
        args.run, quick=args.quick, threads=args.threads, train=not args.no_train,
        model_config=config,
    )  # fmt: skip
    table = result.markdown()
    if args.out:
        write_text(args.out, table)
    print(table)
    return 0


def cmd_control(args: argparse.Namespace) -> int:
    from .control.report import compare

    result = compare(
        args.model,
        args.maneuvers,
        _seed_range(args.seeds),
        args.samples,
        args.out,
        horizon=args.horizon,
        steps=args.steps,
        threads=args.threads,
        progress=None if args.quiet else print,
    )
    print(result.out / "report.md")
    return 0


def _seed_range(text: str) -> tuple[int, ...]:
    """'3' -> (3,); '1..3' -> (1, 2, 3); '0,4' -> (0, 4)."""
    try:
        if ".." in text:
            lo, hi = (int(t) for t in text.split(".."))
            seeds = tuple(range(lo, hi + 1))
        else:
            seeds = tuple(int(t) for t in text.split(","))
    except ValueError:
        raise ValueError(f"--seeds: expected N, A..B or A,B,..., got {text!r}") from None
    if not seeds:
        raise ValueError(f"--seeds: {text!r} names no seed")
    return seeds


# --- parser ----------------------------------------------------------------------------


def _choices(kind: str) -> list[str]:
    # Registries' names from modules that load neither torch nor MuJoCo: --help stays fast.
    if kind == "variants":
        from .config import LOSS_VARIANTS as names
    elif kind == "models":
        from .config import ARCHITECTURES as names
    else:
        from .training.presets import PRESETS as names
    return sorted(names)


def _effect_names() -> tuple[str, ...]:
    from .sim import Effects

    return Effects.names()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slungload",
        description="Learn and predict the motion of a quadrotor carrying a cable-slung load.",
    )
    parser.add_argument("--version", action="version", version=f"slungload {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    _add_simulate(sub)
    _add_maneuvers(sub)
    _add_inspect(sub)
    _add_train(sub)
    _add_evaluate(sub)
    _add_reproduce(sub)
    _add_export(sub)
    _add_benchmark(sub)
    _add_split(sub)
    _add_import(sub)
    _add_identify(sub)
    _add_study(sub)
    _add_control(sub)
    return parser


def _add_simulate(sub: Any) -> None:
    p = _command(
        sub,
        "simulate",
        "simulate flights with MuJoCo into a dataset folder",
        "Fly the maneuver families (or --maneuvers) in the MuJoCo simulator, with every effect "
        "the paper's model leaves out switched on, and write a dataset folder in the authors' "
        "format: one .npz per flight, train/val/test split lists, vehicle.json.",
    )
    p.add_argument("--out", required=True, type=Path, help="dataset folder to create")
    p.add_argument("--flights", type=int, default=48, help="number of flights (default 48)")
    p.add_argument(
        "--maneuvers",
        type=lambda text: [m for m in text.split(",") if m],
        metavar="NAME,NAME",
        help="fly only these families, in turn (default: all; see `slungload maneuvers`)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    p.add_argument(
        "--excite",
        type=_excitation,
        metavar="T,WX,WY,WZ",
        help="add smooth random perturbations to the commands, standard deviations in N and "
        "rad/s, e.g. 1,0.5,0.5,0.2 (the MPC's sampling noise): training data for a model "
        "that a controller will use (docs/control.md; default: none)",
    )
    p.add_argument(
        "--excite-tau",
        type=float,
        default=0.15,
        metavar="S",
        help="correlation time of the perturbations, s (default 0.15)",
    )
    effects = p.add_argument_group("unmodelled effects (all on by default; docs/simulator.md)")
    for name in _effect_names():
        effects.add_argument(
            f"--no-{name.replace('_', '-')}",
            dest=f"no_{name}",
            action="store_true",
            help=f"switch {name.replace('_', ' ')} off",
        )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_simulate)


def _excitation(text: str) -> tuple[float, float, float, float]:
    """``--excite T,WX,WY,WZ``: four non-negative numbers."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4 or min(values) < 0:
        raise argparse.ArgumentTypeError(
            f"expected four non-negative numbers T,WX,WY,WZ (N, rad/s), got {text!r}"
        )
    return values  # type: ignore[return-value]


def _add_maneuvers(sub: Any) -> None:
    p = _command(
        sub,
        "maneuvers",
        "list the simulator's maneuvers and what each flies",
        "The maneuver families of the simulator (the authors' flight names), one a line with "
        "what it flies; `simulate --maneuvers` picks some.",
    )
    p.set_defaults(func=cmd_maneuvers)


def _add_inspect(sub: Any) -> None:
    p = _command(
        sub,
        "inspect",
        "summarise a dataset folder",
        "Flights, steps, seconds and windows per split, value ranges (speed, swing, thrust), "
        "and validation or test maneuvers that training never saw.",
    )
    p.add_argument("data", type=Path, help="dataset folder (flights + split lists)")
    _add_window_options(p)
    _add_vehicle_options(p)
    p.set_defaults(func=cmd_inspect)


def _add_train(sub: Any) -> None:
    p = _command(
        sub,
        "train",
        "train one model variant on a dataset",
        "Train one network (--model) with one loss variant (--variant) on a dataset's train "
        "split, validating on its val split. The run folder gets best.ckpt, last.ckpt (every "
        "epoch), run.json and logs. Ctrl-C stops after the batch and saves last.ckpt; run the "
        "same command with --resume to continue.",
    )
    p.add_argument("--data", required=True, type=Path, help="dataset folder")
    p.add_argument("--out", required=True, type=Path, help="run folder to create")
    p.add_argument(
        "--variant",
        default="proposed",
        choices=_choices("variants"),
        help="loss variant (default proposed: fit + physics with slack + projection)",
    )
    p.add_argument(
        "--model",
        default="lstm-attention",
        choices=_choices("models"),
        help="network architecture (default lstm-attention, the paper's)",
    )
    p.add_argument(
        "--preset",
        default="default",
        choices=_choices("presets"),
        help="training schedule (default: 45 epochs tuned for a 2-core CPU)",
    )
    p.add_argument(
        "--device",
        default="auto",
        choices=("auto", "cpu", "cuda"),
        help="default auto (GPU if any)",
    )
    p.add_argument("--devices", type=int, default=1, help="processes for DDP (default 1)")
    p.add_argument("--seed", type=int, default=0, help="weights and batch order (default 0)")
    p.add_argument("--epochs", type=int, help="override the preset's maximum epochs")
    p.add_argument("--resume", action="store_true", help="continue from RUN_DIR/last.ckpt")
    p.add_argument(
        "--fit-constants",
        action="store_true",
        help="fit the physics model's constants to the training flights first (as `identify`)",
    )
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_window_options(p)
    _add_vehicle_options(p)
    p.set_defaults(func=cmd_train)


def _add_evaluate(sub: Any) -> None:
    p = _command(
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


def _add_reproduce(sub: Any) -> None:
    p = _command(
        sub,
        "reproduce",
        "the paper's experiment end to end (the main job)",
        "Simulate the default dataset (or use --data), train the variants proposed, no-slack "
        "and no-physics of the paper's network and the physics-step network (no-physics) for "
        "every seed, two at a time, evaluate them with the physics-only "
        "predictor at N = 25 and 50, and write OUT/report/report.md. Every variant trains for "
        "its preset's epochs; a run stopped short by the time cap (a safety net) is reported "
        "and the command exits with status 1: run it again to resume such runs. Finished runs "
        "are kept, so an interrupted call can be re-run.",
    )
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--data", type=Path, help="dataset folder (default: simulate one)")
    p.add_argument(
        "--preset",
        default="default",
        choices=_choices("presets"),
        help="default (CPU, ~10 min a seed when idle), quick (smoke test) or paper",
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
        type=int,
        default=48,
        help="flights to simulate when no --data is given (default 48, the paper's)",
    )
    p.add_argument("--workers", type=int, default=2, help="parallel training runs (default 2)")
    p.add_argument(
        "--device",
        default="cpu",
        choices=("auto", "cpu", "cuda"),
        help="where to train (default cpu)",
    )
    _add_timing_options(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_reproduce)


def _add_export(sub: Any) -> None:
    p = _command(
        sub,
        "export",
        "export a trained model to ONNX with a JSON sidecar",
        "Writes the network with its normalisation and quaternion handling (file layout in and "
        "out) for ONNX Runtime, checked against the eager network before it is kept, and a JSON "
        "sidecar (same name, .json) with the columns, units and configs. N is fixed per file: "
        "export one file per horizon.",
    )
    p.add_argument("run", type=Path, metavar="RUN_DIR", help="run folder or .ckpt")
    p.add_argument(
        "--out",
        required=True,
        type=Path,
        metavar="FILE_OR_DIR",
        help="the model file to write (FILE.onnx, plus FILE.json) in an existing folder; or an "
        "existing folder, to write <run name>-n<N>.onnx there. A missing folder is an error, "
        "not created",
    )
    p.add_argument("--format", default="onnx", choices=("onnx",), help="(default: onnx)")
    p.add_argument(
        "--horizon", type=int, help="predicted steps N fixed in the file (default: the run's)"
    )
    p.set_defaults(func=cmd_export)


def _add_benchmark(sub: Any) -> None:
    p = _command(
        sub,
        "benchmark",
        "latency, throughput and training speed",
        "Batch-1 latency (median, p90; wall clock and CPU time) of every backend (eager torch, "
        "TorchScript, ONNX Runtime, the compiled predictor), throughput at larger batches, and "
        "training speed; warns when the machine is busy.",
    )
    p.add_argument(
        "run",
        nargs="?",
        type=Path,
        metavar="RUN_DIR",
        help="a trained run (default: a paper-size network with random weights)",
    )
    p.add_argument(
        "--model",
        choices=_choices("models"),
        help="without RUN_DIR: a random paper-size network of this architecture (default "
        "lstm-attention)",
    )
    p.add_argument("--quick", action="store_true", help="fewer repeats (about a minute)")
    p.add_argument("--threads", type=int, default=1, help="inference threads (default 1)")
    p.add_argument("--no-train", action="store_true", help="skip the training throughput")
    p.add_argument("--out", type=Path, help="also write the markdown table here")
    p.set_defaults(func=cmd_benchmark)


def _add_split(sub: Any) -> None:
    p = _command(
        sub,
        "split",
        "write the split lists of a folder of flights",
        "Write train.txt, val.txt and test.txt (by flight): name the validation and test "
        "flights, or give their shares for a seeded random draw; every other flight trains.",
    )
    p.add_argument("data", type=Path, help="dataset folder")
    p.add_argument(
        "--val",
        type=_share_or_names,
        default=0.17,
        metavar="SHARE|NAME,NAME",
        help="share of the flights (default 0.17, the paper's) or their names",
    )
    p.add_argument(
        "--test",
        type=_share_or_names,
        default=0.25,
        metavar="SHARE|NAME,NAME",
        help="share of the flights (default 0.25, the paper's) or their names",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the random draw (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace existing split lists")
    p.set_defaults(func=cmd_split)


def _add_import(sub: Any) -> None:
    p = _command(
        sub,
        "import",
        "turn flight logs (ROS bags, PX4 ULog, CSV) into a dataset folder",
        "Read motion-capture poses of vehicle and load, velocity and the offboard commands, "
        "resample them to the step dt (linear; slerp for the attitude; commands held), convert "
        "frames to z up / FLU, split at gaps, validate as .npz flights and write OUT/data/*.npz, "
        "the split lists and vehicle.json, all or nothing (docs/data.md, 'Bring your own "
        "flights').",
    )
    _add_import_sources(p)
    _add_import_resampling(p)
    _add_import_output(p)
    _add_vehicle_options(p)
    p.set_defaults(func=cmd_import)


def _add_import_sources(p: argparse.ArgumentParser) -> None:
    """The logs to read, the folder to create and how the logs map to the streams."""
    p.add_argument(
        "logs",
        nargs="+",
        type=Path,
        metavar="LOG",
        help=".bag (ROS 1), rosbag2 folder / .mcap / .db3 (ROS 2), .ulg (PX4), .csv, or a "
        "folder of them",
    )
    p.add_argument("--out", required=True, type=Path, help="dataset folder to create")
    p.add_argument(
        "--map",
        type=Path,
        metavar="FILE",
        help="topics / columns / frames, JSON or TOML (default: MAVROS topics; CSV: the "
        "published keys as columns)",
    )
    p.add_argument(
        "--preset",
        choices=("mavros", "px4"),
        help="default topics of a bag: MAVROS (default) or PX4 over ROS 2",
    )


def _add_import_resampling(p: argparse.ArgumentParser) -> None:
    """How the thrust becomes newtons, where flights split at gaps and how the streams are
    resampled."""
    p.add_argument(
        "--hover-throttle",
        type=float,
        metavar="X",
        help="normalised throttle that holds vehicle + load in hover (PX4's MPC_THR_HOVER; "
        "a ULog's own by default): thrust = throttle / X * (mQ + mL) g",
    )
    p.add_argument(
        "--max-gap",
        type=float,
        default=0.1,
        metavar="S",
        help="longest time a stream may go without a sample (default 0.1 s)",
    )
    p.add_argument(
        "--on-gap",
        choices=("split", "error"),
        default="split",
        help="split the flight at a longer gap (default) or stop with an error",
    )
    p.add_argument(
        "--min-duration",
        type=float,
        default=1.0,
        metavar="S",
        help="drop pieces shorter than this (default 1 s)",
    )
    p.add_argument(
        "--commands",
        choices=("hold", "linear"),
        default="hold",
        help="resample set-points by holding the last one (default) or linearly",
    )


def _add_import_output(p: argparse.ArgumentParser) -> None:
    """How the flights are split into train/val/test, the vehicle constants and the run's
    output."""
    p.add_argument(
        "--split",
        choices=("seeded", "train"),
        default="seeded",
        help="a seeded split by flight toward 58/17/25 %% of steps (default), or all in train",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the split (default 0)")
    p.add_argument(
        "--vehicle",
        type=Path,
        metavar="FILE",
        help="vehicle constants (JSON; vehicle.json keys or aliases such as mass_quadrotor)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_identify(sub: Any) -> None:
    p = _command(
        sub,
        "identify",
        "fit the physics model's constants to a dataset's flights",
        "System identification: the load mass, cable length, load damping and thrust gain "
        "that make the discrete model's open-loop rollouts (--horizon steps from every "
        "training window) closest to the recorded flights, starting from vehicle.json (or the "
        "paper's constants). The vehicle mass stays as given. `train --fit-constants` does "
        "the same before training.",
    )
    p.add_argument("data", type=Path, help="dataset folder")
    p.add_argument(
        "--horizon", type=int, default=10, metavar="N", help="steps per rollout (default 10)"
    )
    p.add_argument(
        "--out", type=Path, help="write the fitted constants as a vehicle.json file here"
    )
    _add_vehicle_options(p)
    p.set_defaults(func=cmd_identify)


def _add_study(sub: Any) -> None:
    p = _command(
        sub,
        "study",
        "studies beyond the paper (data: where physics-informed training helps)",
        "`study data`: train each loss variant on nested subsets of the training flights "
        "(validation and test flights fixed) and plot the RMSE at N = 50 against the number "
        "of training flights.",
    )
    kinds = p.add_subparsers(dest="study", metavar="STUDY", required=True)
    d = kinds.add_parser("data", help="RMSE against the number of training flights")
    d.add_argument("--out", required=True, type=Path, help="output folder")
    d.add_argument(
        "--flights",
        type=lambda text: [int(k) for k in text.split(",") if k],
        default=[6, 12, 24, 48],
        metavar="K,K",
        help="training-flight counts (default 6,12,24,48); the simulated dataset is sized "
        "for the largest",
    )
    d.add_argument("--data", type=Path, help="dataset folder (default: simulate one)")
    d.add_argument(
        "--variants",
        type=lambda text: [v for v in text.split(",") if v],
        default=["proposed", "no-slack", "no-physics"],
        metavar="V,V",
        help="loss variants (default proposed,no-slack,no-physics)",
    )
    d.add_argument(
        "--models",
        type=lambda text: [m for m in text.split(",") if m],
        default=["lstm-attention"],
        metavar="NAME,NAME",
        help="architectures (default lstm-attention)",
    )
    d.add_argument("--seeds", default="0", metavar="SEEDS", help="as for reproduce (default 0)")
    d.add_argument(
        "--preset", default="default", choices=_choices("presets"), help="default: default"
    )
    d.add_argument("--workers", type=int, default=2, help="parallel training runs (default 2)")
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_study)


def _add_control(sub: Any) -> None:
    p = _command(
        sub,
        "control",
        "fly the PID and a sampling MPC with the physics model and with trained networks",
        "Closed loop in the simulator with every unmodelled effect on: the simulator's PID, "
        "an MPPI controller predicting with the physics model, and the same MPC with each "
        "--model; vehicle and load tracking, swing, time at a limit, failures, fallbacks, "
        "compute per step; report.md and figures in --out (docs/control.md).",
    )
    p.add_argument(
        "--model",
        action="append",
        type=Path,
        default=[],
        metavar="RUN_DIR",
        help="a trained run folder or .ckpt (any architecture); repeat for more",
    )
    p.add_argument(
        "--maneuvers",
        type=lambda text: [m for m in text.split(",") if m],
        default=["baf_very_fast", "roll_35", "fast_8_lap_xyz"],
        metavar="NAME,NAME",
        help="maneuvers (default baf_very_fast,roll_35,fast_8_lap_xyz)",
    )
    p.add_argument(
        "--seeds", default="100..102", metavar="SEEDS", help="sim seeds: N, A..B or A,B (default "
        "100..102; the default dataset is simulated from seed 0)"
    )  # fmt: skip
    p.add_argument(
        "--samples",
        type=lambda text: [int(k) for k in text.split(",") if k],
        default=[32],
        metavar="K,K",
        help="MPC samples per step; each model flies once per K (default 32)",
    )
    p.add_argument("--horizon", type=int, help="MPC horizon N, steps of 0.03 s (default 15)")
    p.add_argument("--steps", type=int, help="cut every flight to this many steps (smoke runs)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--quiet", action="store_true", help="no line per flight")
    p.set_defaults(func=cmd_control)


def _share_or_names(text: str) -> float | list[str]:
    try:
        return float(text)
    except ValueError:
        return [name.strip().removesuffix(".npz") for name in text.split(",") if name.strip()]


def _command(sub: Any, name: str, summary: str, description: str) -> argparse.ArgumentParser:
    """A subcommand with a one-line summary (in ``slungload --help``) and a description."""
    return sub.add_parser(name, help=summary, description=f"{summary[0].upper()}{summary[1:]}. "
                          f"{description}")  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    if args.debug:
        return func(args)
    formatwarning, warnings.formatwarning = warnings.formatwarning, _one_line_warning
    try:
        return func(args)
    except USER_ERRORS as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"slungload {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # train raises a subclass carrying the signal's number
        detail = f": {exc}" if str(exc) else ""
        print(f"slungload {args.command}: interrupted{detail}", file=sys.stderr)
        return 128 + getattr(exc, "signum", 2)
    finally:
        warnings.formatwarning = formatwarning


def _one_line_warning(message, category, filename, lineno, line=None) -> str:  # noqa: ANN001
    """Warnings as one line a user can read (no source line); ``--debug`` shows Python's."""
    return f"slungload: note: {message}\n"


if __name__ == "__main__":
    sys.exit(main())
