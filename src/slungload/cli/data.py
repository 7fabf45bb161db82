"""Data commands: simulate, maneuvers, inspect, split (import: ``importing``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import (
    add_vehicle_options,
    add_window_options,
    choices,
    comma_names,
    new_command,
    plants_help,
    positive_int,
    resolve_params,
    value_or_range,
)


def add_simulate(sub: Any) -> None:
    from ..sim.plants import DEFAULT_PLANT

    p = new_command(
        sub,
        "simulate",
        "simulate flights with MuJoCo into a dataset folder",
        "Fly the maneuver families (or --maneuvers) in the MuJoCo simulator, with every effect "
        "the paper's model leaves out switched on, and write a dataset folder in the authors' "
        "format: one .npz per flight, train/val/test split lists, vehicle.json.",
    )
    p.add_argument("--out", required=True, type=Path, help="dataset folder to create")
    p.add_argument(
        "--flights", type=positive_int, default=48, help="number of flights (default 48)"
    )
    p.add_argument(
        "--maneuvers",
        type=comma_names,
        metavar="NAME,NAME",
        help="fly only these families, in turn (default: all; see `slungload maneuvers`)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--plant", choices=choices("plants"), default=DEFAULT_PLANT,
                   help=f"the simulated vehicle ({plants_help()}; docs/simulator.md; the vehicle "
                   f"and load options below change it) (default {DEFAULT_PLANT})")  # fmt: skip
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
    _add_load_options(p)
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


def _add_load_options(p: argparse.ArgumentParser) -> None:
    """One option per ``sim.config.LoadRanges`` field: a value for every flight, or a range."""
    from dataclasses import fields

    from ..sim.config import LoadRanges, SimConfig

    group = p.add_argument_group(
        "vehicle and load",
        "X: one value for every flight; LO:HI: drawn per flight and recorded in its file, the "
        "midpoint in vehicle.json and for the controller (docs/simulator.md)",
    )
    for f in fields(LoadRanges):
        # Not --mass-quad: the other commands' --mass-quad ... set the model's constants
        # (config.VehicleParams), these the simulated plant.
        flag = "--vehicle-mass" if f.name == "mass_quad" else f"--{f.name.replace('_', '-')}"
        group.add_argument(
            flag,
            dest=f.name,
            type=value_or_range,
            metavar="X|LO:HI",
            help=f"{f.metadata['text']}, {f.metadata['unit']} "
            f"(default {SimConfig().value(f.name):g})",
        )


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


def _effect_names() -> tuple[str, ...]:
    from ..sim import Effects

    return Effects.names()


def cmd_simulate(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ..data.summary import summarize
    from ..sim import Effects, Excitation, simulate_dataset
    from ..sim.config import LoadRanges
    from ..sim.plants import plant_config

    off = [name for name in Effects.names() if getattr(args, f"no_{name}")]
    excitation = Excitation()
    if args.excite is not None:
        thrust, *rates = args.excite
        excitation = Excitation(thrust, tuple(rates), args.excite_tau)
    result = simulate_dataset(
        args.out,
        flights=args.flights,
        seed=args.seed,
        config=replace(
            plant_config(args.plant), effects=Effects().without(*off), excitation=excitation
        ).with_loads(**{name: getattr(args, name) for name in LoadRanges.names()}),
        workers=args.workers,
        overwrite=args.overwrite,
        progress=not args.quiet,
        maneuvers=args.maneuvers,
    )
    print(f"wrote {len(result.flights)} flights to {result.folder} in {result.elapsed:.1f} s")
    print(summarize(result.folder).to_table())
    return 0


def add_maneuvers(sub: Any) -> None:
    p = new_command(
        sub,
        "maneuvers",
        "list the simulator's maneuvers and what each flies",
        "The maneuver families of the simulator (the authors' flight names), one a line with "
        "what it flies; `simulate --maneuvers` picks some.",
    )
    p.set_defaults(func=cmd_maneuvers)


def cmd_maneuvers(args: argparse.Namespace) -> int:
    from ..sim.maneuvers import MANEUVER_DESCRIPTIONS, MANEUVERS

    width = max(map(len, MANEUVERS))
    for name in sorted(MANEUVERS):
        print(f"{name:<{width}}  {MANEUVER_DESCRIPTIONS.get(name, '')}".rstrip())
    return 0


def add_inspect(sub: Any) -> None:
    p = new_command(
        sub,
        "inspect",
        "summarise a dataset folder",
        "Flights, steps, seconds and windows per split, value ranges (speed, swing, thrust), "
        "and validation or test maneuvers that training never saw.",
    )
    p.add_argument("data", type=Path, help="dataset folder (flights + split lists)")
    add_window_options(p)
    add_vehicle_options(p)
    p.set_defaults(func=cmd_inspect)


def cmd_inspect(args: argparse.Namespace) -> int:
    from ..config import WindowConfig
    from ..data.summary import summarize

    window = WindowConfig(history=args.history, horizon=args.horizon, stride=args.stride)
    summary = summarize(args.data, window=window, params=resolve_params(Path(args.data), args))
    print(summary.to_table())
    return 0


def add_split(sub: Any) -> None:
    from ..data.split import SPLIT_FRACTIONS, WINDOW_STEPS  # light: no torch, no numpy

    p = new_command(
        sub,
        "split",
        "write the split lists of a folder of flights",
        "Write train.txt, val.txt and test.txt by recording (the pieces of one imported log "
        "stay together): name the validation and test flights, or give their shares for a "
        "seeded random draw; every other flight trains. With one or two recordings, --blocks "
        "cuts each in time instead.",
    )
    p.add_argument("data", type=Path, help="dataset folder")
    p.add_argument(
        "--val",
        type=_share_or_names,
        default=SPLIT_FRACTIONS["val"],
        metavar="SHARE|NAME,NAME",
        help="share of the flights (default %(default)s, the paper's) or their names",
    )
    p.add_argument(
        "--test",
        type=_share_or_names,
        default=SPLIT_FRACTIONS["test"],
        metavar="SHARE|NAME,NAME",
        help="share of the flights (default %(default)s, the paper's) or their names",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the random draw (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace existing split lists")
    p.add_argument(
        "--blocks",
        action="store_true",
        help="cut each recording in time into a train, a val and a test block (the paper's "
        "shares of its steps, in that order): rewrites the folder, NAME -> NAME_train, "
        "NAME_val, NAME_test",
    )
    p.add_argument(
        "--gap",
        type=int,
        default=WINDOW_STEPS,
        metavar="STEPS",
        help="steps left out between blocks, at least the M + N of the training windows "
        f"(default {WINDOW_STEPS})",
    )
    p.set_defaults(func=cmd_split)


def _share_or_names(text: str) -> float | list[str]:
    try:
        return float(text)
    except ValueError:
        return [name.strip().removesuffix(".npz") for name in text.split(",") if name.strip()]


def cmd_split(args: argparse.Namespace) -> int:
    from ..data.split import split_blocks, split_dataset

    if args.blocks:
        splits = split_blocks(args.data, gap=args.gap)
        print(", ".join(f"{s}: {', '.join(names)}" for s, names in splits.items()))
        return 0
    splits = split_dataset(
        args.data, val=args.val, test=args.test, seed=args.seed, overwrite=args.overwrite
    )
    print(", ".join(f"{s}: {len(names)} flights" for s, names in splits.items()))
    return 0
