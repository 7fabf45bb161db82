"""Deployment commands: export to ONNX, benchmark the backends."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import choices, comma_ints, comma_names, new_command


def add_export(sub: Any) -> None:
    p = new_command(
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
    p.add_argument(
        "--format",
        default="onnx",
        choices=("onnx", "compiled"),
        help="onnx: a graph for ONNX Runtime (default); compiled (with --for-mpc): the folded "
        "weights for the compiled MPC on numpy + Numba, <run name>.mpc.npz, any N, the onboard "
        "MPC as fast as the compiled backend (docs/deployment.md)",
    )
    p.add_argument(
        "--horizon",
        type=int,
        help="predicted steps N fixed in the file (default: the run's; with --for-mpc the "
        "MPC's horizon)",
    )
    p.add_argument(
        "--for-mpc",
        action="store_true",
        help="export the MPC's candidates graph instead (encoder once, decoder batched over K "
        "candidates, package layout; <run name>-n<N>.mpc.onnx in a folder) for the onboard "
        "controller on numpy + onnxruntime (docs/deployment.md); RUN_DIR 'physics' exports the "
        "discrete model with the default vehicle constants",
    )
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    if args.for_mpc:
        from ..control.mppi import MPCConfig
        from ..deploy.candidates import export_for_mpc

        horizon = MPCConfig().horizon if args.horizon is None else args.horizon
        result = export_for_mpc(args.run, args.out, horizon=horizon, format=args.format)
        print(result.summary())
        return 0
    if args.format != "onnx":
        raise ValueError(f"export --format {args.format} writes the MPC's model: add --for-mpc")
    from ..deploy.onnx import export

    result = export(args.run, args.out, format=args.format, horizon=args.horizon)
    print(result.summary())
    return 0


def add_benchmark(sub: Any) -> None:
    p = new_command(
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
        choices=choices("models"),
        help="without RUN_DIR: a random paper-size network of this architecture (default "
        "lstm-attention)",
    )
    p.add_argument("--quick", action="store_true", help="fewer repeats (about a minute)")
    p.add_argument("--threads", type=int, default=1, help="inference threads (default 1)")
    p.add_argument("--no-train", action="store_true", help="skip the training throughput")
    p.add_argument("--out", type=Path, help="also write the markdown table here")
    mpc = p.add_argument_group(
        "MPC rollouts",
        "--mpc times the sampling controller's call instead: predict_candidates of K plans of N "
        "steps from one history, per backend (eager, compiled, cuda, onnxruntime), for the physics "
        "model and the network (without RUN_DIR: a random physics-step network), one thread, "
        "median and p99 ms",
    )
    mpc.add_argument("--mpc", action="store_true", help="time MPC-shaped rollouts")
    mpc.add_argument(
        "--samples", type=comma_ints, default=[256, 1024, 4096], metavar="K,K",
        help="candidates K (default 256,1024,4096)",
    )  # fmt: skip
    mpc.add_argument(
        "--horizons", type=comma_ints, default=[15, 50], metavar="N,N",
        help="horizons N (default 15,50)",
    )  # fmt: skip
    mpc.add_argument(
        "--backends", type=comma_names, metavar="NAME,NAME",
        help="what to time: " + ", ".join(choices("backends")) + " or onnxruntime (the "
        "exported graph) (default every one that runs here: cuda where torch sees a GPU)",
    )  # fmt: skip
    mpc.add_argument(
        "--size", choices=choices("sizes"),
        help="without RUN_DIR: a random network of this named size (default the paper's)",
    )  # fmt: skip
    p.set_defaults(func=cmd_benchmark)


def cmd_benchmark(args: argparse.Namespace) -> int:
    from ..config import ModelConfig
    from ..lab.bench.benchmarks import benchmark

    if args.mpc:
        return _benchmark_mpc(args)
    for name in ("size", "backends"):
        if getattr(args, name) is not None:
            raise ValueError(f"--{name} is for --mpc")
    config = None if args.model is None else ModelConfig(architecture=args.model)
    if config is not None and args.run is not None:
        raise ValueError("--model builds a random network; a RUN_DIR brings its own")
    result = benchmark(
        args.run, quick=args.quick, threads=args.threads, train=not args.no_train,
        model_config=config,
    )  # fmt: skip
    return _show(result.markdown(), args.out)


def _benchmark_mpc(args: argparse.Namespace) -> int:
    from ..config import ModelConfig
    from ..lab.bench.mpc import benchmark_mpc

    if args.run is not None and (args.model or args.size):
        raise ValueError("--model and --size build a random network; a RUN_DIR brings its own")
    config = ModelConfig.sized(args.size or "paper", architecture=args.model or "physics-step")
    result = benchmark_mpc(
        args.run, samples=args.samples, horizons=args.horizons, quick=args.quick,
        model_config=config, backends=args.backends,
    )  # fmt: skip
    return _show(result.markdown(), args.out)


def _show(table: str, out: Path | None) -> int:
    """Print a benchmark's Markdown, written to ``out`` as well where given."""
    from ..fileio import write_text

    if out:
        write_text(out, table)
    print(table)
    return 0
