"""Data commands: simulate, maneuvers, inspect, split, import."""

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
    vehicle_overrides,
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


def add_import(sub: Any) -> None:
    p = new_command(
        sub,
        "import",
        "turn flight logs (ROS bags, PX4 ULog, CSV) into a dataset folder",
        "Read motion-capture poses of vehicle and load, velocity and the offboard commands, "
        "resample them to the step dt (linear; slerp for the attitude; commands held), convert "
        "frames to z up / FLU, split at gaps, validate as .npz flights and write OUT/data/*.npz, "
        "the split lists and vehicle.json, all or nothing (docs/import.md).",
    )
    _add_import_sources(p)
    _add_import_second(p)
    _add_import_resampling(p)
    _add_import_output(p)
    add_vehicle_options(p)
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
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="one mapping key over --map's (repeat it; SECTION.KEY=VALUE for a mapping in "
        "sections ros, ulog, csv; commas make a list of columns; an empty VALUE turns a key "
        "off), e.g. --set load=vehicle_mocap_odometry:1 (ULog), --set "
        "attitude=qx,qy,qz,qw (CSV quaternion columns, in x-y-z-w order), --set T_ref=throttle "
        "--set thrust=normalized (CSV), --set load_pose=/vrpn/cube/pose (bag)",
    )


def _add_import_second(p: argparse.ArgumentParser) -> None:
    """A second log (motion capture beside a PX4 ULog) and how it is aligned to each log."""
    from dataclasses import fields

    from ..data.consistency import ConsistencyLimits  # light: no numpy
    from ..data.import_options import ROTATIONS, SecondLog

    default = {f.name: f.default for f in fields(SecondLog)}
    g = p.add_argument_group(
        "a second log",
        "streams of every flight (the load by default) from a second log, e.g. a motion-capture "
        "bag or CSV beside a PX4 ULog: its clock and world frame are fitted to each LOG on the "
        "vehicle track both hold, and the import refused when they disagree (docs/import.md)",
    )
    g.add_argument("--second", type=Path, metavar="LOG", help="the second log (any LOG format)")
    g.add_argument(
        "--second-map",
        type=Path,
        metavar="FILE",
        help="topics / columns / frames of the second log, as --map (default: --map's)",
    )
    g.add_argument(
        "--from-second",
        type=comma_names,
        metavar="ROLE,ROLE",
        help="streams taken from the second log: load, position, velocity, attitude, rates, "
        f"thrust (default {','.join(default['roles'])})",
    )
    g.add_argument(
        "--time-offset",
        type=float,
        metavar="S",
        help="seconds added to the second log's stamps to put them on LOG's clock (default: "
        "estimated from the vehicle track; the frame is fitted either way)",
    )
    g.add_argument(
        "--align",
        choices=ROTATIONS,
        help="the frames differ by a rotation about z (yaw: both z up) or any rotation (full) "
        f"(default {default['rotation']})",
    )
    g.add_argument(
        "--align-tolerance",
        type=float,
        metavar="M",
        help="largest RMS vehicle position mismatch after alignment, m (default: "
        f"{ConsistencyLimits().align_noise:g} times the noise the two tracks show, at least "
        f"{ConsistencyLimits().align_floor:g} and at most {ConsistencyLimits().align_residual:g})",
    )


def _add_import_resampling(p: argparse.ArgumentParser) -> None:
    """How the thrust becomes newtons, where flights split at gaps and how the streams are
    resampled."""
    from ..data.import_options import GAP_STREAMS, ImportOptions, groups_text  # light

    default = ImportOptions()
    thrust = p.add_mutually_exclusive_group()
    thrust.add_argument(
        "--hover-throttle",
        type=float,
        metavar="X",
        help="normalised throttle that holds vehicle + load in hover (PX4's MPC_THR_HOVER; "
        "a ULog's own by default): thrust = throttle / X * (mQ + mL) g; not used (and said so) "
        "when the thrust is logged in newtons",
    )
    thrust.add_argument(
        "--newtons-per-throttle",
        type=float,
        metavar="N",
        help="thrust in newtons per unit of normalised throttle, from a thrust-stand or a "
        "hover measurement: thrust = throttle * N (instead of --hover-throttle; unlike "
        "--thrust-gain, which scales thrust already in newtons inside the model)",
    )
    p.add_argument(
        "--max-gap",
        type=_gap,
        action="append",
        metavar="S|STREAM=S",
        help="longest time a stream may go without a sample, s; STREAM=S for one stream "
        f"(streams: {', '.join(GAP_STREAMS)}; groups: {groups_text()}; e.g. --max-gap "
        "position,velocity=0.3 for a 5 Hz EKF position beside 100 Hz motion capture; repeat "
        "the option) (default {default.max_gap:g} s for every stream)",
    )
    p.add_argument(
        "--on-gap",
        choices=("split", "error"),
        default=default.on_gap,
        help=f"split the flight at a longer gap or stop with an error (default {default.on_gap})",
    )
    p.add_argument(
        "--min-duration",
        type=float,
        default=default.min_duration,
        metavar="S",
        help=f"drop pieces shorter than this (default {default.min_duration:g} s)",
    )
    p.add_argument(
        "--commands",
        choices=("hold", "linear"),
        default=default.commands,
        help="resample set-points by holding the last one or linearly (default "
        f"{default.commands})",
    )


def _gap(text: str) -> list[tuple[str, float]]:
    """``--max-gap S`` or ``STREAM=S`` (``import_options.parse_gap``)."""
    from ..data.import_options import parse_gap

    try:
        return parse_gap(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _add_import_output(p: argparse.ArgumentParser) -> None:
    """How the flights are split into train/val/test, the vehicle constants and the run's
    output."""
    from ..data.split import WINDOW_STEPS, shares_text

    p.add_argument(
        "--split",
        choices=("seeded", "train", "blocks"),
        default="seeded",
        help=f"a seeded split by recording (the pieces of one log together) toward "
        f"{shares_text()} %% of windows (default; all in train with fewer than 3 recordings), "
        "all in train, or each recording cut in time into train, val and test blocks",
    )
    p.add_argument(
        "--block-gap",
        type=int,
        default=WINDOW_STEPS,
        metavar="STEPS",
        help="steps left out between time blocks (--split blocks), at least the M + N of the "
        f"training windows (default {WINDOW_STEPS})",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the split (default 0)")
    p.add_argument(
        "--vehicle",
        type=Path,
        metavar="FILE",
        help="vehicle constants (JSON; vehicle.json keys or aliases such as mass_quadrotor)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing folder")
    p.add_argument(
        "--force",
        action="store_true",
        help="import flights outside the physical consistency checks (noted, and recorded in "
        f"vehicle.json); the checks: {_limits_text()}",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _limits_text() -> str:
    from ..data.consistency import ConsistencyLimits  # light: no numpy

    return ConsistencyLimits().describe().replace("%", "%%")


def _gaps(given: list[list[tuple[str, float]]] | None) -> dict[str, Any]:
    """``--max-gap`` values -> ``ImportOptions`` keywords: the last plain S is ``max_gap``,
    each STREAM=S an entry of ``max_gaps``."""
    pairs = [pair for value in given or [] for pair in value]
    plain = [gap for role, gap in pairs if not role]
    out: dict[str, Any] = {"max_gaps": tuple((r, g) for r, g in pairs if r)}
    if plain:
        out["max_gap"] = plain[-1]
    return out


def cmd_import(args: argparse.Namespace) -> int:
    import dataclasses

    from ..config import VehicleParams
    from ..data.consistency import ConsistencyLimits
    from ..data.importing import ImportOptions, SecondLog, import_logs
    from ..data.readers import LOG_READERS
    from ..data.readers.logs import load_mapping, override
    from ..vehicle_file import read_vehicle

    overrides = vehicle_overrides(args)
    params = None
    if args.vehicle is not None or overrides:
        base = read_vehicle(args.vehicle) if args.vehicle is not None else VehicleParams()
        params = dataclasses.replace(base, **overrides)
    options = ImportOptions(
        hover_throttle=args.hover_throttle,
        newtons_per_throttle=args.newtons_per_throttle,
        **_gaps(args.max_gap),
        on_gap=args.on_gap,
        min_duration=args.min_duration,
        commands=args.commands,
        split=args.split,
        block_gap=args.block_gap,
        seed=args.seed,
        force=args.force,
        limits=ConsistencyLimits(
            **(
                {}
                if args.align_tolerance is None
                else {"align_residual": args.align_tolerance, "align_floor": args.align_tolerance}
            )
        ),
    )
    mapping = load_mapping(args.map) if args.map is not None else None
    if args.set:
        sections = tuple(dict.fromkeys(r.section for r in LOG_READERS.values()))
        mapping = override(mapping, args.set, sections)
    given = {"roles": args.from_second, "time_offset": args.time_offset, "rotation": args.align}
    given = {k: v for k, v in given.items() if v is not None}
    second = None
    if args.second is not None:
        own = load_mapping(args.second_map) if args.second_map is not None else None
        second = SecondLog(args.second, mapping=own, **given)
    elif given or args.second_map is not None:
        raise ValueError("--second-map, --from-second, --time-offset and --align need --second LOG")
    result = import_logs(
        args.logs,
        args.out,
        params=params,
        mapping=mapping,
        preset=args.preset,
        options=options,
        second=second,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    print(result.summary())
    return 0
