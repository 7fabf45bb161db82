"""Command line: parses arguments and calls the stage functions; no logic lives here.

A user error (bad path, bad file, bad option) prints one line and exits with status 2;
``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

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
    names = ("mass_quad", "mass_load", "cable_length", "load_damping", "dt", "gravity")
    return {n: getattr(args, n) for n in names if getattr(args, n, None) is not None}


def _add_vehicle_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "vehicle constants (override the dataset's vehicle.json; default: the paper's)"
    )
    g.add_argument("--mass-quad", dest="mass_quad", type=float, metavar="KG")
    g.add_argument("--mass-load", dest="mass_load", type=float, metavar="KG")
    g.add_argument("--cable-length", dest="cable_length", type=float, metavar="M")
    g.add_argument("--load-damping", dest="load_damping", type=float, metavar="D")
    g.add_argument("--dt", type=float, metavar="S", help="sampling time h")
    g.add_argument("--gravity", type=float, metavar="M/S2")


def _add_window_options(p: argparse.ArgumentParser, horizon: int = 25) -> None:
    p.add_argument("--history", type=int, default=50, metavar="M", help="past steps (default 50)")
    p.add_argument(
        "--horizon",
        type=int,
        default=horizon,
        metavar="N",
        help=f"future steps (default {horizon})",
    )
    p.add_argument("--stride", type=int, default=1, help="steps between windows (default 1)")


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
    from .sim import Effects, SimConfig, simulate_dataset

    off = [name for name in Effects.names() if getattr(args, f"no_{name}")]
    result = simulate_dataset(
        args.out,
        flights=args.flights,
        seed=args.seed,
        config=SimConfig(effects=Effects().without(*off)),
        workers=args.workers,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    print(f"wrote {len(result.flights)} flights to {result.folder} in {result.elapsed:.1f} s")
    print(summarize(result.folder).to_table())
    return 0


def cmd_maneuvers(args: argparse.Namespace) -> int:
    from .sim import MANEUVERS

    print("\n".join(sorted(MANEUVERS)))
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

    from .config import WindowConfig
    from .training.trainer import train

    run = train(
        args.data,
        out=args.out,
        variant=args.variant,
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
        timing=not args.no_timing,
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
        timing=not args.no_timing,
        progress=not args.quiet,
    )
    stages = ", ".join(f"{k} {v:.0f} s" for k, v in result.seconds.items())
    print(f"report: {result.report_path}  ({stages})")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from .deploy.onnx import export

    result = export(args.run, args.out, format=args.format, horizon=args.horizon)
    print(result.summary())
    return 0


def cmd_benchmark(args: argparse.Namespace) -> int:
    from .deploy.benchmarks import benchmark
    from .fileio import write_text

    result = benchmark(args.run, quick=args.quick, threads=args.threads, train=not args.no_train)
    table = result.markdown()
    if args.out:
        write_text(args.out, table)
    print(table)
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
    if kind == "variants":
        from .loss import LOSS_VARIANTS as names
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

    p = sub.add_parser("simulate", help="simulate flights with MuJoCo into a dataset folder")
    p.add_argument("--out", required=True, type=Path, help="dataset folder to create")
    p.add_argument("--flights", type=int, default=48, help="number of flights (default 48)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--workers", type=int, default=2, help="parallel processes (default 2)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    effects = p.add_argument_group("unmodelled effects (all on by default; docs/simulator.md)")
    for name in _effect_names():
        effects.add_argument(
            f"--no-{name.replace('_', '-')}",
            dest=f"no_{name}",
            action="store_true",
            help=f"switch {name} off",
        )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("maneuvers", help="list the simulator's maneuvers")
    p.set_defaults(func=cmd_maneuvers)

    p = sub.add_parser("inspect", help="summarise a dataset folder")
    p.add_argument("data", type=Path, help="dataset folder (.npz flights + split lists)")
    _add_window_options(p)
    _add_vehicle_options(p)
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("train", help="train one model variant on a dataset")
    p.add_argument("--data", required=True, type=Path, help="dataset folder")
    p.add_argument("--out", required=True, type=Path, help="run folder to create")
    p.add_argument(
        "--variant",
        default="proposed",
        choices=_choices("variants"),
        help="loss variant (default proposed)",
    )
    p.add_argument(
        "--preset",
        default="default",
        choices=_choices("presets"),
        help="training schedule (default: tuned for a 2-core CPU)",
    )
    p.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    p.add_argument("--devices", type=int, default=1, help="processes for DDP (default 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--epochs", type=int, help="override the preset's maximum epochs")
    p.add_argument("--resume", action="store_true", help="continue from RUN_DIR/last.ckpt")
    p.add_argument("--threads", type=int, help="torch CPU threads")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_window_options(p)
    _add_vehicle_options(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("evaluate", help="evaluate trained runs against the physics model")
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR")
    p.add_argument("--data", type=Path, help="dataset folder (default: the runs' own)")
    p.add_argument("--out", required=True, type=Path, help="report folder")
    p.add_argument("--horizons", type=int, nargs="+", default=[25, 50], metavar="N")
    p.add_argument("--no-physics", action="store_true", help="leave out the physics predictor")
    p.add_argument("--no-timing", action="store_true", help="skip the inference-time benchmark")
    p.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("reproduce", help="the paper's experiment end to end (the main job)")
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--data", type=Path, help="dataset folder (default: simulate one)")
    p.add_argument(
        "--preset",
        default="default",
        choices=_choices("presets"),
        help="default (CPU, ~10 min a seed when idle), quick (smoke test) or paper",
    )
    p.add_argument("--seeds", default="0", help="training seeds: N, A..B or A,B (default 0)")
    p.add_argument(
        "--flights",
        type=int,
        default=48,
        help="flights to simulate when no --data is given (default 48, the paper's)",
    )
    p.add_argument("--workers", type=int, default=2, help="parallel training runs (default 2)")
    p.add_argument("--device", default="cpu", choices=("auto", "cpu", "cuda"))
    p.add_argument("--no-timing", action="store_true", help="skip the inference-time benchmark")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser("export", help="export a trained model to ONNX with a JSON sidecar")
    p.add_argument("run", type=Path, metavar="RUN_DIR", help="run folder or .ckpt")
    p.add_argument("--out", required=True, type=Path, help="model file to write (.onnx)")
    p.add_argument("--format", default="onnx", choices=("onnx",))
    p.add_argument("--horizon", type=int, help="predicted steps N (default: the run's)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("benchmark", help="latency, throughput and training speed")
    p.add_argument(
        "run",
        nargs="?",
        type=Path,
        metavar="RUN_DIR",
        help="a trained run (default: a paper-size network with random weights)",
    )
    p.add_argument("--quick", action="store_true", help="fewer repeats (about a minute)")
    p.add_argument("--threads", type=int, default=1, help="inference threads (default 1)")
    p.add_argument("--no-train", action="store_true", help="skip the training throughput")
    p.add_argument("--out", type=Path, help="also write the markdown table here")
    p.set_defaults(func=cmd_benchmark)

    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    if args.debug:
        return func(args)
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


if __name__ == "__main__":
    sys.exit(main())
