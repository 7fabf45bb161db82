"""The studies that fly the MPC: ``study control`` and ``study control-loads`` (the lab's
``lab.control.study`` and ``lab.control.unseen_loads``); every default is read from
``lab.control.config``."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..lab.control.config import (
    NOMINAL,
    SHIFTS,
    STUDY_KINDS,
    PlanErrorConfig,
    StudyConfig,
    UnseenLoadsConfig,
)
from .common import comma_ints, comma_names, given, joined
from .control import (
    add_flight_options,
    add_model_option,
    add_plan_options,
    plan_changes,
    warn_model_notes,
)


def add_study_control(kinds: Any) -> None:
    cfg = StudyConfig()
    s = kinds.add_parser(
        "control",
        help="where the learned model pays in the MPC: controllers, horizons, shifted plants",
        description="The PID, the payload-aware geometric controller and the MPC with the "
        "physics model, the --model and the oracle (the simulator itself) at several "
        "horizons, on every maneuver x seed, and on shifted plants; MPC settings chosen per "
        "horizon on separate tuning seeds, the physics MPC at the learned one's compute; "
        "study.md pairs every model flight by flight, measures the gap to the oracle and "
        "scores each MPC in the MPC's own cost; a second run flies only what is missing "
        "(docs/control.md).",
    )
    add_model_option(s, "the trained run folder or .ckpt of the learned MPC (one; none: no "
                     "learned MPC)")  # fmt: skip
    add_plan_options(s, cfg)
    add_flight_options(s, cfg, samples_many=False)
    s.add_argument("--controllers", type=comma_names, default=list(STUDY_KINDS),
                   metavar="NAME,NAME", help=f"kinds to fly now, e.g. the slow oracle in its own "
                   f"process (default {','.join(STUDY_KINDS)})")  # fmt: skip
    s.add_argument("--plants", type=comma_names, metavar="NAME,NAME",
                   help=f"plants to fly now, e.g. one per process (default all: {NOMINAL},"
                   + ",".join(SHIFTS).replace("%", "%%") + ")")  # fmt: skip
    s.add_argument("--horizons", type=comma_ints, metavar="N,N",
                   help=f"MPC horizons (default {joined(cfg.horizons)})")  # fmt: skip
    s.add_argument("--shift-horizons", type=comma_ints, metavar="N,N",
                   help="MPC horizons on the shifted plants, among --horizons (default the "
                   "first)")  # fmt: skip
    s.add_argument(
        "--oracle-samples",
        type=int,
        metavar="K",
        help=f"the oracle MPC's samples per step (default {cfg.oracle_samples})",
    )
    s.add_argument("--oracle-horizons", type=comma_ints, metavar="N,N",
                   help=f"the oracle MPC's horizons, among --horizons (default "
                   f"{joined(cfg.oracle_horizons)})")  # fmt: skip
    s.add_argument("--no-tune", action="store_true",
                   help="MPC settings at their defaults (smoke runs)")  # fmt: skip
    s.add_argument("--workers", type=int, default=1,
                   help="flights flown at once, one process each (default 1; the settings are "
                   "tuned first, in one process)")  # fmt: skip
    s.add_argument("--out", required=True, type=Path, help="output folder")
    s.add_argument("--quiet", action="store_true", help="no line per flight")
    s.set_defaults(func=cmd_study_control)


def cmd_study_control(args: argparse.Namespace) -> int:
    from ..lab.control.study import run_study
    from ..lab.control.study_report import write_study_report

    if len(args.model) > 1:
        n = len(args.model)
        raise ValueError(f"study control flies one --model (the learned one), got {n}")
    changes = plan_changes(args) | {"tune": not args.no_tune}
    changes |= given(horizons=args.horizons and tuple(args.horizons),
                     oracle_horizons=args.oracle_horizons and tuple(args.oracle_horizons),
                     shift_horizons=args.shift_horizons and tuple(args.shift_horizons),
                     oracle_samples=args.oracle_samples, samples=args.samples,
                     backend=args.backend, steps=args.steps, plant=args.plant,
                     cost=args.cost, lean=args.lean, shape=args.shape, risk=args.risk,
                     with_physics=args.with_physics or None, input_lag=args.input_lag,
                     trust_window=args.trust_window)  # fmt: skip
    config = replace(StudyConfig(), **changes)
    warn_model_notes(args.model, max(config.horizons), paired=config.with_physics,
                     trust_window=config.pair_window)  # fmt: skip
    learned = args.model[0] if args.model else None
    rows = run_study(learned, args.out, config, controllers=args.controllers, plants=args.plants,
                     threads=args.threads, workers=args.workers,
                     progress=None if args.quiet else print)  # fmt: skip
    print(write_study_report(rows, config, args.out, str(learned) if learned else None))
    return 0


def add_study_control_loads(kinds: Any) -> None:
    cfg = UnseenLoadsConfig()
    s = kinds.add_parser(
        "control-loads",
        help="the MPC flying loads its model never saw",
        description="A physics-step network (--model: adaptive, trained with --constants "
        "window, or with f fixed, e.g. trained on one load; or an ensemble folder of one kind) "
        "and the physics model, each with the load estimated in flight and given the true "
        "load, beside the PID, on loads the model never saw; control-loads.md in OUT; a second "
        "run flies only what is missing, and a second network flown into the same folder is "
        "compared with the first (docs/control.md).",
    )
    add_model_option(s, "the physics-step network's run folder or .ckpt, or an ensemble "
                     "folder of them (one)")  # fmt: skip
    s.add_argument("--load", action="append", type=_load, metavar="KG,M",
                   help="a load mass (kg) and cable length (m) to fly; repeat for more (default "
                   + " ".join(f"{m},{length}" for m, length in cfg.loads) + ")")  # fmt: skip
    add_plan_options(s, cfg)
    add_flight_options(s, cfg, samples_many=False,
                       cuda=", and refused here: the in-flight physics model reads its "
                       "estimate on the host")  # fmt: skip
    s.add_argument("--temperature", type=float,
                   help=f"the MPC's temperature (default {cfg.temperature:g})")  # fmt: skip
    s.add_argument("--out", required=True, type=Path, help="output folder")
    s.add_argument("--quiet", action="store_true", help="no line per flight")
    s.set_defaults(func=cmd_study_control_loads)


def _load(text: str) -> tuple[float, float]:
    """'KG,M' -> (load mass, cable length), both positive."""
    try:
        mass, length = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected KG,M (e.g. 0.2,0.8), got {text!r}") from None
    if not (mass > 0 and length > 0):
        raise argparse.ArgumentTypeError(f"load mass and cable length must be > 0, got {text!r}")
    return mass, length


def cmd_study_control_loads(args: argparse.Namespace) -> int:
    from ..lab.control.unseen_loads import fly_loads, write_loads_report

    if len(args.model) != 1:
        raise ValueError(
            f"study control-loads flies one --model (a physics-step network), got {len(args.model)}"
        )
    changes = plan_changes(args) | given(loads=args.load and tuple(args.load),
                                         samples=args.samples, horizon=args.horizon,
                                         steps=args.steps, backend=args.backend,
                                         temperature=args.temperature,
                                         risk=args.risk)  # fmt: skip
    config = replace(UnseenLoadsConfig(), **changes)
    warn_model_notes(args.model, config.horizon)
    rows = fly_loads(args.model[0], args.out, config, threads=args.threads,
                     progress=None if args.quiet else print)  # fmt: skip
    print(write_loads_report(rows, config, args.out))
    return 0


def add_study_plan_errors(kinds: Any) -> None:
    cfg = PlanErrorConfig()
    s = kinds.add_parser(
        "plan-errors",
        help="each model's errors along the plans the MPC weighs, against the plant's own",
        description="Fly the MPC over the physics model and over --model on --plant and, "
        "every few steps, fly the first candidate plans it weighs on copies of the plant: "
        "each model's load error along them, the error of their responses to the input "
        "changes, and how each model ranks them in the MPC's cost (rank correlation, regret); "
        "plan-errors.md, .csv and .png in OUT (docs/control.md).",
    )
    add_model_option(s, "the learned model's run folder or .ckpt (one; none: physics alone)")
    add_plan_options(s, cfg)
    add_flight_options(s, cfg, samples_many=False)
    s.add_argument("--candidates", type=int, metavar="C",
                   help=f"plans probed per probed step (default {cfg.candidates})")  # fmt: skip
    s.add_argument("--every", type=int, metavar="STEPS",
                   help=f"control steps between probes (default {cfg.every})")  # fmt: skip
    s.add_argument("--flying", type=comma_names, metavar="NAME,NAME",
                   help=f"whose MPC flies and is probed (default "
                   f"{','.join(cfg.flying)})")  # fmt: skip
    s.add_argument("--out", required=True, type=Path, help="output folder")
    s.add_argument("--quiet", action="store_true", help="no line per flight")
    s.set_defaults(func=cmd_study_plan_errors)


def cmd_study_plan_errors(args: argparse.Namespace) -> int:
    from ..lab.control.plan_errors import run_plan_errors

    if len(args.model) > 1:
        raise ValueError(f"study plan-errors takes one --model, got {len(args.model)}")
    learned = args.model[0] if args.model else None
    changes = plan_changes(args) | given(
        samples=args.samples, horizon=args.horizon, steps=args.steps, backend=args.backend,
        plant=args.plant, candidates=args.candidates, every=args.every,
        flying=args.flying and tuple(args.flying),
    )  # fmt: skip
    if learned is None and "flying" not in changes:
        changes["flying"] = ("physics",)
    config = replace(PlanErrorConfig(), **changes)
    print(run_plan_errors(learned, args.out, config, progress=None if args.quiet else print))
    return 0
