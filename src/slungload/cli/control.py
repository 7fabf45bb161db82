"""Control command: fly the PID and the MPC in the simulator."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import choices, comma_ints, comma_names, new_command, seed_range


def add_control(sub: Any) -> None:
    p = new_command(
        sub,
        "control",
        "fly the PID and a sampling MPC with the physics model and with trained networks",
        "Closed loop in the simulator with every unmodelled effect on: the simulator's PID, "
        "an MPPI controller predicting with the physics model, and the same MPC with each "
        "--model; vehicle and load tracking, swing, time at a limit, failures, fallbacks, "
        "compute per step; report.md and figures in --out (docs/control.md). Fly a "
        "physics-step network trained on flights with perturbed commands (`simulate "
        "--excite`): a network trained on the PID's flights alone ignores its inputs and "
        "fails in this controller.",
    )
    p.add_argument(
        "--model",
        action="append",
        type=Path,
        default=[],
        metavar="RUN_DIR",
        help="a trained run folder or .ckpt (any architecture; see above for which); repeat "
        "for more",
    )
    p.add_argument(
        "--maneuvers",
        type=comma_names,
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
        type=comma_ints,
        default=[32],
        metavar="K,K",
        help="MPC samples per step; each model flies once per K (default 32)",
    )
    p.add_argument("--horizon", type=int, help="MPC horizon N, steps of 0.03 s (default 15)")
    p.add_argument("--steps", type=int, help="cut every flight to this many steps (smoke runs)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument(
        "--backend",
        choices=choices("backends"),
        default="eager",
        help="what the prediction models run on: eager torch, or compiled kernels (the physics "
        "model in one compiled float64 loop, a network in float32 on compiled kernels and "
        "torch's BLAS; equal to eager to float32 rounding; docs/deployment.md) (default eager)",
    )
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--quiet", action="store_true", help="no line per flight")
    p.set_defaults(func=cmd_control)


def cmd_control(args: argparse.Namespace) -> int:
    from ..control.comparison import compare

    result = compare(
        args.model,
        args.maneuvers,
        seed_range(args.seeds),
        args.samples,
        args.out,
        horizon=args.horizon,
        steps=args.steps,
        threads=args.threads,
        backend=args.backend,
        progress=None if args.quiet else print,
    )
    print(result.out / "report.md")
    return 0
