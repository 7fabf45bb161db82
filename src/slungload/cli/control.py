"""Closed-loop commands in the simulator: control (the comparison) and record (the MPC's own
flights as training data). The studies that fly (``study control``, ``study control-loads``)
are in ``study``; every default is read from ``lab.control.config``."""

from __future__ import annotations

import argparse
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..lab.control.config import ComparisonConfig, RecordConfig
from .common import (
    backends_help,
    choices,
    comma_ints,
    comma_names,
    given,
    input_lag,
    joined,
    new_command,
    plants_help,
    seed_range,
)


def add_model_option(p: argparse.ArgumentParser, what: str) -> None:
    """``--model``, repeatable: trained run folders or .ckpt files."""
    p.add_argument("--model", action="append", type=Path, default=[], metavar="RUN_DIR",
                   help=what)  # fmt: skip


def add_flight_options(
    p: argparse.ArgumentParser, cfg: Any, *, samples_many: bool, cuda: str = ""
) -> None:
    """The options every closed-loop command shares, their defaults read from ``cfg`` (a
    config of ``lab.control.config``): samples, horizon, recorded steps, backend, threads.
    ``cuda``: what the help adds about the cuda backend."""
    if samples_many:
        p.add_argument("--samples", type=comma_ints, metavar="K,K",
                       help=f"MPC samples per step; each model flies once per K (default "
                       f"{joined(cfg.samples)})")  # fmt: skip
    else:
        p.add_argument("--samples", type=int, metavar="K",
                       help=f"MPC samples per step (default {cfg.samples})")  # fmt: skip
    if hasattr(cfg, "plant"):
        p.add_argument("--plant", choices=choices("plants"),
                       help=f"the simulated vehicle ({plants_help()}; docs/simulator.md) "
                       f"(default {cfg.plant})")  # fmt: skip
    if hasattr(cfg, "cost"):
        from ..control.mppi import COSTS  # numpy only

        shown = "; ".join(f"{name}: {text}" for name, text in COSTS.items())
        p.add_argument("--cost", choices=list(COSTS),
                       help=f"the MPC's cost: {shown} (docs/control.md) "
                       f"(default {cfg.cost})")  # fmt: skip
    if hasattr(cfg, "lean"):
        from ..control.cost import LEAN_HELP, SHAPE_HELP  # numpy only

        p.add_argument("--lean", type=float, metavar="X",
                       help=f"{LEAN_HELP} (default {cfg.lean:g})")  # fmt: skip
        p.add_argument("--shape", type=float, metavar="X",
                       help=f"{SHAPE_HELP} (default {cfg.shape:g})")  # fmt: skip
    if hasattr(cfg, "risk"):
        p.add_argument("--risk", type=float, metavar="BETA",
                       help="price an ensemble's candidates (--model an ensemble folder) by "
                       "the mean of its members' costs + BETA x their standard deviation "
                       "(each member predicts each candidate: E x the compute; docs/control.md) "
                       "(default: the cost of the members' mean)")  # fmt: skip
    if hasattr(cfg, "members"):
        from ..control.split import MEMBER_USES, MEMBERS_HELP  # numpy only

        p.add_argument("--members", choices=list(MEMBER_USES),
                       help=f"{MEMBERS_HELP} (default {cfg.members})")  # fmt: skip
    if hasattr(cfg, "with_physics"):
        p.add_argument("--with-physics", action="store_true",
                       help="price each --model's plans under it and under the physics model: "
                       "their mean cost + --risk x their spread, each weighted by how "
                       "well it predicted the steps just flown (--trust-window; "
                       "docs/control.md)")  # fmt: skip
    if hasattr(cfg, "trust_window"):
        from ..control.paired import TRUST_WINDOW  # numpy only

        p.add_argument("--trust-window", type=int, metavar="H",
                       help="with --with-physics: the network takes part only while it "
                       "predicts the last H steps flown at least as well as physics (another "
                       "vehicle's network flies as physics; 0: always; docs/control.md) "
                       f"(default {TRUST_WINDOW})")  # fmt: skip
    if hasattr(cfg, "input_lag"):
        from ..input_lag import INPUT_LAG_HELP, lag_text  # numpy only

        p.add_argument("--input-lag", type=input_lag, metavar="T,R,Y",
                       help=f"{INPUT_LAG_HELP} (default {lag_text(cfg.input_lag)}: none, the "
                       "paper's model)")  # fmt: skip
    if hasattr(cfg, "horizon"):
        p.add_argument("--horizon", type=int, metavar="N",
                       help=f"MPC horizon, steps of 0.03 s (default {cfg.horizon})")  # fmt: skip
    whole = "the maneuver's whole length"
    p.add_argument("--steps", type=int,
                   help=f"cut every flight to this many recorded steps (default "
                   f"{whole if cfg.steps is None else cfg.steps})")  # fmt: skip
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument(
        "--backend",
        choices=choices("backends"),
        help=f"what the prediction models run on: {backends_help()} (equal to eager to float32 "
        f"rounding; cuda needs a CUDA build of torch{cuda}; docs/deployment.md) (default "
        f"{cfg.backend})",
    )


def add_plan_options(p: argparse.ArgumentParser, cfg: Any) -> None:
    """``--maneuvers`` and ``--seeds``, their defaults read from ``cfg``."""
    p.add_argument("--maneuvers", type=comma_names, metavar="NAME,NAME",
                   help=f"maneuvers (default {','.join(cfg.maneuvers)})")  # fmt: skip
    p.add_argument("--seeds", metavar="SEEDS",
                   help=f"sim seeds: N, A..B or A,B (default {joined(cfg.seeds)}; the default "
                   "dataset is simulated from seed 0)")  # fmt: skip


def plan_changes(args: argparse.Namespace) -> dict[str, Any]:
    """The maneuvers and seeds given, as a config's changes."""
    return given(maneuvers=args.maneuvers and tuple(args.maneuvers),
                 seeds=None if args.seeds is None else seed_range(args.seeds))  # fmt: skip


def warn_model_notes(
    models: Sequence[Path], horizon: int, *, paired: bool = False, trust_window: int = 0
) -> None:
    """What a user should know before flying each model at ``horizon`` (``mpc.model_notes``;
    ``paired``: priced with physics too, with ``trust_window``), as warnings; a model that
    cannot be read is left to the command, which says so."""
    from ..control.mpc import ModelNote, model_notes

    for model in models:
        try:
            notes = model_notes(model, horizon, paired=paired, trust_window=trust_window)
        except (OSError, ValueError):
            continue
        for note in notes:
            warnings.warn(note, ModelNote, stacklevel=1)


def add_control(sub: Any) -> None:
    cfg = ComparisonConfig()
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
        "fails in this controller. The wider experiments: `study control`, `study "
        "control-loads`.",
    )
    add_model_option(p, "a trained run folder or .ckpt (any architecture); repeat for more")
    add_plan_options(p, cfg)
    add_flight_options(p, cfg, samples_many=True)
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--quiet", action="store_true", help="no line per flight")
    p.set_defaults(func=cmd_control)


def cmd_control(args: argparse.Namespace) -> int:
    from ..lab.control.comparison import compare

    changes = plan_changes(args) | given(samples=args.samples and tuple(args.samples),
                                         horizon=args.horizon, steps=args.steps,
                                         backend=args.backend, plant=args.plant,
                                         cost=args.cost, lean=args.lean, shape=args.shape,
                                         risk=args.risk, members=args.members,
                                         input_lag=args.input_lag,
                                         with_physics=args.with_physics or None,
                                         trust_window=args.trust_window)  # fmt: skip
    config = replace(ComparisonConfig(), **changes)
    warn_model_notes(args.model, config.horizon, paired=config.with_physics,
                     trust_window=config.pair_window)  # fmt: skip
    result = compare(args.model, args.out, config, threads=args.threads,
                     progress=None if args.quiet else print)  # fmt: skip
    print(result.out / "report.md")
    return 0


def add_record(sub: Any) -> None:
    cfg = RecordConfig()
    p = new_command(
        sub,
        "record",
        "fly the MPC over a trained model in the simulator and add its flights to a dataset",
        "Fly the MPC over --model on sim seeds no benchmark flies and write a new dataset "
        "(--out): --base's flights and splits with the recorded flights added to its train "
        "split, each kept until the arena stopped it; train on it to teach the model the "
        "states its MPC leads it into (one round of DAgger; docs/control.md).",
    )
    add_model_option(p, "the trained run folder or .ckpt the MPC flies (one)")
    p.add_argument(
        "--base",
        required=True,
        type=Path,
        metavar="DATASET",
        help="the dataset the model was trained on (simulated, nominal vehicle)",
    )
    p.add_argument(
        "--flights", type=_flight_counts, metavar="NAME:COUNT,...",
        help="flights per maneuver (default " + ",".join(f"{m}:{n}" for m, n in cfg.flights)
        + ")",
    )  # fmt: skip
    p.add_argument("--first-seed", type=int, metavar="SEED",
                   help=f"the first sim seed of each maneuver's flights (default "
                   f"{cfg.first_seed}; a second round on a dataset that holds the first needs "
                   "another)")  # fmt: skip
    p.add_argument("--temperature", type=float,
                   help=f"the MPC's temperature (default {cfg.temperature:g})")  # fmt: skip
    add_flight_options(p, cfg, samples_many=False)
    p.add_argument("--workers", type=int, default=1,
                   help="flights flown at once, one process each (default 1)")  # fmt: skip
    p.add_argument("--out", required=True, type=Path, help="the new dataset's folder")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_record)


def _flight_counts(text: str) -> tuple[tuple[str, int], ...]:
    """'NAME:COUNT,NAME:COUNT' -> ((name, count), ...)."""
    try:
        pairs = [item.split(":") for item in text.split(",") if item.strip()]
        return tuple((name.strip(), int(count)) for name, count in pairs)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected NAME:COUNT,... (e.g. xy_step:30,roll_35:5), got {text!r}"
        ) from None


def cmd_record(args: argparse.Namespace) -> int:
    from ..lab.control.record import record_flights

    if len(args.model) != 1:
        raise ValueError(f"record flies one --model (the MPC's), got {len(args.model)}")
    changes = given(flights=args.flights, first_seed=args.first_seed, samples=args.samples,
                    horizon=args.horizon, steps=args.steps, backend=args.backend,
                    temperature=args.temperature, plant=args.plant)  # fmt: skip
    config = replace(RecordConfig(), **changes)
    warn_model_notes(args.model, config.horizon)
    done = record_flights(args.model[0], args.base, args.out, config, workers=args.workers,
                          threads=args.threads, progress=not args.quiet)  # fmt: skip
    print(
        f"{done.folder}: {len(done.flights)} recorded flights added to the train split "
        f"({len(done.stopped)} stopped by the arena, kept up to there; "
        f"{len(done.skipped)} too short for a training window, left out)"
    )
    return 0
