"""The import command: flight logs (ROS bags, PX4 ULogs, MAVLink .tlogs, CSV) into a dataset,
checked against their own physics (``data.importing``, ``data.consistency``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import (
    add_vehicle_options,
    comma_names,
    new_command,
    vehicle_overrides,
)


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
        f"the option) (default {default.max_gap:g} s for every stream)",
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
