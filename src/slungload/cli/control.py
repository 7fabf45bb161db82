"""Control command: fly the PID and the MPC in the simulator."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path
from typing import Any

from ..config import PREDICTION_BACKENDS
from ..control.study_config import (
    CONTROLLERS,
    DEFAULT_MANEUVERS,
    NOMINAL,
    SHIFTS,
    RecordConfig,
    StudyConfig,
    UnseenLoadsConfig,
)
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
        metavar="NAME,NAME",
        help=f"maneuvers (default {','.join(DEFAULT_MANEUVERS)}; the study "
        f"{','.join(StudyConfig.maneuvers)})",
    )
    p.add_argument(
        "--seeds", metavar="SEEDS", help="sim seeds: N, A..B or A,B (default 100..102, the study "
        "100..104; the default dataset is simulated from seed 0)"
    )  # fmt: skip
    p.add_argument(
        "--samples",
        type=comma_ints,
        metavar="K,K",
        help=f"MPC samples per step; each model flies once per K (default 32; the study: the "
        f"learned model's K, default {StudyConfig.samples})",
    )
    p.add_argument(
        "--horizon",
        type=int,
        help="MPC horizon N, steps of 0.03 s (default 15; with --loads "
        f"{UnseenLoadsConfig.horizon})",
    )
    p.add_argument(
        "--steps",
        type=int,
        help=f"cut every flight to this many recorded steps (default: whole flights; the study "
        f"{StudyConfig.steps})",
    )
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument(
        "--backend",
        choices=choices("backends"),
        help="what the prediction models run on: "
        + "; ".join(f"{k}: {v}" for k, v in PREDICTION_BACKENDS.items())
        + " (equal to eager to float32 rounding; cuda needs a CUDA build of torch and is "
        "refused by --loads, whose in-flight physics model reads its estimate on the host; "
        f"docs/deployment.md) (default eager; the study {StudyConfig.backend})",
    )
    study = p.add_argument_group(
        "the study (--study)",
        "where the learned model pays: the PID, the payload-aware geometric controller and the "
        "MPC with the physics model, the --model (one) and the oracle (the simulator itself) "
        "at several horizons, on every maneuver x seed, and on shifted plants; MPC settings "
        "chosen per horizon on separate tuning seeds, the physics MPC at the learned one's "
        "compute; study.md pairs every model flight by flight, measures the gap to the "
        "oracle and scores each MPC in the MPC's own cost; a second run flies only what is "
        "missing (docs/control.md)",
    )
    study.add_argument("--study", action="store_true", help="fly the study instead")
    study.add_argument(
        "--controllers",
        type=comma_names,
        default=list(CONTROLLERS),
        metavar="NAME,NAME",
        help=f"kinds to fly now, e.g. the slow oracle in its own process (default "
        f"{','.join(CONTROLLERS)})",
    )
    study.add_argument(
        "--plants",
        type=lambda text: [name.strip() for name in text.split(",") if name.strip()],
        metavar="NAME,NAME",
        help=f"plants to fly now, e.g. one per process (default all: {NOMINAL},"
        + ",".join(SHIFTS).replace("%", "%%")  # argparse formats help with %
        + ")",
    )
    study.add_argument(
        "--horizons",
        type=comma_ints,
        default=list(StudyConfig.horizons),
        metavar="N,N",
        help=f"MPC horizons (default {','.join(map(str, StudyConfig.horizons))})",
    )
    study.add_argument(
        "--shift-horizons",
        type=comma_ints,
        metavar="N,N",
        help="MPC horizons on the shifted plants, among --horizons (default the first)",
    )
    study.add_argument(
        "--workers",
        type=int,
        default=1,
        help="flights flown at once, one process each (default 1; the settings are tuned "
        "first, in one process)",
    )
    study.add_argument(
        "--oracle-samples",
        type=int,
        default=StudyConfig.oracle_samples,
        metavar="K",
        help=f"the oracle MPC's samples per step (default {StudyConfig.oracle_samples})",
    )
    study.add_argument(
        "--oracle-horizons",
        type=comma_ints,
        default=list(StudyConfig.oracle_horizons),
        metavar="N,N",
        help=f"the oracle MPC's horizons, among --horizons (default "
        f"{','.join(map(str, StudyConfig.oracle_horizons))})",
    )
    study.add_argument(
        "--no-tune", action="store_true", help="MPC settings at their defaults (smoke runs)"
    )
    loads = p.add_argument_group(
        "unseen loads (--loads)",
        "the MPC flying loads its model never saw: a physics-step network (--model: adaptive, "
        "trained with --constants window, or with f fixed, e.g. trained on one load) and the "
        "physics model, each with the load estimated in flight and given the true load, beside "
        "the PID; a second run flies only what is missing, and a second network flown into the "
        "same folder is compared with the first (docs/control.md)",
    )
    loads.add_argument("--loads", action="store_true", help="fly the unseen loads instead")
    defaults = UnseenLoadsConfig()
    loads.add_argument(
        "--load",
        action="append",
        type=_load,
        metavar="KG,M",
        help="a load mass (kg) and cable length (m) to fly; repeat for more (default "
        + " ".join(f"{m},{length}" for m, length in defaults.loads)
        + f"; with --maneuvers (default the study's), --seeds (default "
        f"{','.join(map(str, defaults.seeds))}), --samples (default {defaults.samples}), "
        f"--horizon (default {defaults.horizon}), --steps and --backend)",
    )
    record = p.add_argument_group(
        "training data from the MPC's own flights (--record)",
        "fly the MPC over --model on sim seeds no benchmark flies and write a new dataset (--out):"
        " --base's flights and splits with the recorded flights added to its train split, each "
        "kept until the arena stopped it; train on it to teach the model the states its MPC "
        "leads it into (one round of DAgger; docs/control.md)",
    )
    record.add_argument("--record", action="store_true", help="record flights instead")
    record.add_argument(
        "--base", type=Path, metavar="DATASET",
        help="the dataset the model was trained on (simulated, nominal vehicle)",
    )  # fmt: skip
    rec = RecordConfig()
    record.add_argument(
        "--flights",
        type=_flight_counts,
        metavar="NAME:COUNT,...",
        help="flights per maneuver (default "
        + ",".join(f"{m}:{n}" for m, n in rec.flights)
        + f"), sim seeds from {rec.first_seed} on; with --samples (default {rec.samples}), "
        f"--horizon (default {rec.horizon}), --steps (default {rec.steps}), --backend and "
        "--workers",
    )
    record.add_argument(
        "--first-seed", type=int, default=rec.first_seed, metavar="SEED",
        help=f"the first sim seed of each maneuver's flights (default {rec.first_seed}; a "
        "second round on a dataset that holds the first needs another)",
    )  # fmt: skip
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--quiet", action="store_true", help="no line per flight")
    p.set_defaults(func=cmd_control)


def _flight_counts(text: str) -> tuple[tuple[str, int], ...]:
    """'NAME:COUNT,NAME:COUNT' -> ((name, count), ...)."""
    try:
        pairs = [item.split(":") for item in text.split(",") if item.strip()]
        return tuple((name.strip(), int(count)) for name, count in pairs)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected NAME:COUNT,... (e.g. xy_step:30,roll_35:5), got {text!r}"
        ) from None


def _load(text: str) -> tuple[float, float]:
    """'KG,M' -> (load mass, cable length), both positive."""
    try:
        mass, length = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected KG,M (e.g. 0.2,0.8), got {text!r}") from None
    if not (mass > 0 and length > 0):
        raise argparse.ArgumentTypeError(f"load mass and cable length must be > 0, got {text!r}")
    return mass, length


def cmd_control(args: argparse.Namespace) -> int:
    modes = [name for name in ("study", "loads", "record") if getattr(args, name)]
    if len(modes) > 1:
        raise ValueError(f"control: --{' and --'.join(modes)} are separate runs; give one")
    from ..control.mpc import ModelNote, MPCConfig, model_notes

    if args.study:
        longest = max(args.horizons, default=0)  # none: the study refuses it below
    else:  # the mode's default N unless given
        mode = RecordConfig if args.record else UnseenLoadsConfig if args.loads else MPCConfig
        longest = args.horizon or mode.horizon
    for model in args.model or ():
        try:
            notes = model_notes(model, longest)
        except (OSError, ValueError):
            continue  # a model that cannot be read: the mode below says so, in its words
        for note in notes:
            warnings.warn(note, ModelNote, stacklevel=1)
    if args.record:
        return _cmd_record(args)
    if args.study:
        return _cmd_study(args)
    if args.loads:
        return _cmd_loads(args)
    from ..control.comparison import compare

    result = compare(
        args.model,
        args.maneuvers or DEFAULT_MANEUVERS,
        seed_range(args.seeds or "100..102"),
        args.samples or [32],
        args.out,
        horizon=args.horizon,
        steps=args.steps,
        threads=args.threads,
        backend=args.backend or "eager",
        progress=None if args.quiet else print,
    )
    print(result.out / "report.md")
    return 0


def _given(**options: Any) -> dict[str, Any]:
    """The options the user gave (argparse leaves the others None): a config's changes. A value
    given as 0 is kept, so that the config refuses it rather than the default replacing it; a
    list given empty (``--maneuvers ,``) is refused by name."""
    for name, value in options.items():
        if isinstance(value, (list, tuple)) and not value:
            raise ValueError(f"--{name.replace('_', '-')}: give at least one value")
    return {name: value for name, value in options.items() if value is not None}


def _cmd_study(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ..control.study import run_study
    from ..control.study_report import write_study_report

    if len(args.model) > 1:
        n = len(args.model)
        raise ValueError(f"control --study flies one --model (the learned one), got {n}")
    changes = {"tune": not args.no_tune, "shift_horizons": tuple(args.shift_horizons or ()),
               "oracle_samples": args.oracle_samples}  # fmt: skip
    changes |= _given(horizons=tuple(args.horizons), oracle_horizons=tuple(args.oracle_horizons))
    changes |= _given(samples=args.samples and args.samples[0], backend=args.backend,
                      maneuvers=args.maneuvers and tuple(args.maneuvers),
                      seeds=None if args.seeds is None else seed_range(args.seeds),
                      steps=args.steps)  # fmt: skip
    config = replace(StudyConfig(), **changes)
    learned = args.model[0] if args.model else None
    rows = run_study(learned, args.out, config, controllers=args.controllers, plants=args.plants,
                     threads=args.threads, workers=args.workers,
                     progress=None if args.quiet else print)  # fmt: skip
    print(write_study_report(rows, config, args.out, str(learned) if learned else None))
    return 0


def _cmd_loads(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ..control.loads import fly_loads, write_loads_report

    if len(args.model) != 1:
        raise ValueError(
            f"control --loads flies one --model (a physics-step network), got {len(args.model)}"
        )
    changes = _given(loads=args.load and tuple(args.load),
                     maneuvers=args.maneuvers and tuple(args.maneuvers),
                     seeds=None if args.seeds is None else seed_range(args.seeds),
                     samples=args.samples and args.samples[0], horizon=args.horizon,
                     steps=args.steps, backend=args.backend)  # fmt: skip
    config = replace(UnseenLoadsConfig(), **changes)
    rows = fly_loads(args.model[0], args.out, config, threads=args.threads,
                     progress=None if args.quiet else print)  # fmt: skip
    print(write_loads_report(rows, config, args.out))
    return 0


def _cmd_record(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ..control.record import record_flights

    if len(args.model) != 1 or args.base is None:
        raise ValueError("control --record needs one --model (the MPC's) and --base (a dataset)")
    if args.maneuvers or args.seeds or (args.samples and len(args.samples) > 1):
        raise ValueError("control --record flies --flights NAME:COUNT from --first-seed at one "
                         "--samples K; --maneuvers and --seeds are the other modes'")  # fmt: skip
    changes = _given(flights=args.flights, first_seed=args.first_seed,
                     samples=args.samples and args.samples[0], horizon=args.horizon,
                     steps=args.steps, backend=args.backend)  # fmt: skip
    config = replace(RecordConfig(), **changes)
    done = record_flights(args.model[0], args.base, args.out, config, workers=args.workers,
                          threads=args.threads, progress=not args.quiet)  # fmt: skip
    print(
        f"{done.folder}: {len(done.flights)} recorded flights added to the train split "
        f"({len(done.stopped)} stopped by the arena, kept up to there; "
        f"{len(done.skipped)} too short for a training window, left out)"
    )
    return 0
