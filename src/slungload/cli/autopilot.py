"""The MPC on an autopilot: ``fly`` (the bridge to PX4 over MAVLink) and ``sil`` (the simulator
behind a MAVLink endpoint that answers as PX4). Every default and help is read from
``autopilot.config``."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..autopilot.config import HANDBACK, BridgeConfig, SilConfig, option_help
from ..control.cost import LEAN_HELP, SHAPE_HELP
from ..control.mppi import COSTS, MPCConfig
from ..control.split import MEMBER_USES, MEMBERS_HELP
from ..input_lag import INPUT_LAG_HELP, lag_text
from .common import choices, given, input_lag, new_command, plants_help

FLY_OPTIONS = ("connection", "target_system", "component", "load_system", "load_component",
               "hover_throttle", "newtons_per_throttle", "min_thrust_share", "max_throttle",
               "rate_max", "maneuver", "seed", "duration", "settle", "origin", "box", "arm",
               "offboard", "with_physics", "trust_window", "stream_before_switch",
               "wait_offboard", "dry_run", "max_state_age", "max_load_age", "max_tilt",
               "fence_radius", "fence_height", "hover_time", "handback", "fifo_priority", "tlog",
               "connect_timeout")  # fmt: skip
SIL_OPTIONS = ("seed", "maneuver", "steps", "start_on_offboard", "connection", "system",
               "load_component", "lockstep_wait", "hover_throttle", "of_loss_timeout",
               "heartbeat_period", "duration")  # fmt: skip


def _floats(count: int, names: str):
    """An argparse type: ``count`` comma-separated floats, named ``names`` in the error."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) != count:
            raise argparse.ArgumentTypeError(f"expected {names} ({count} numbers), got {text!r}")
        return values

    return parse


# the options whose default is None: their type
_NONE_TYPES = {"hover_throttle": float, "newtons_per_throttle": float, "maneuver": str,
               "duration": float, "tlog": Path, "origin": _floats(4, "X,Y,Z,YAW"),
               "box": _floats(6, "X0,Y0,Z0,X1,Y1,Z1"), "steps": int,
               "fifo_priority": int, "trust_window": int}  # fmt: skip


def _add_options(p: argparse.ArgumentParser, config: type, names: tuple[str, ...]) -> None:
    """``--name`` for each field of ``config`` in ``names``: its type from its default, its
    help (with the default) from the field."""
    defaults = {f.name: f.default for f in dataclasses.fields(config)}
    for name in names:
        flag, default = "--" + name.replace("_", "-"), defaults[name]
        if isinstance(default, bool):
            p.add_argument(flag, action="store_true", help=option_help(config, name))
        elif name == "handback":
            p.add_argument(flag, choices=HANDBACK, help=option_help(config, name))
        else:
            kind = _NONE_TYPES[name] if default is None else type(default)
            p.add_argument(flag, type=kind, help=option_help(config, name))


def _changes(args: argparse.Namespace, names: tuple[str, ...]) -> dict[str, Any]:
    """The options given (a flag left off is not a change)."""
    values = {name: getattr(args, name) for name in names}
    return given(**{k: None if v is False else v for k, v in values.items()})


def add_fly(sub: Any) -> None:
    p = new_command(
        sub,
        "fly",
        "fly the MPC on a PX4 vehicle over MAVLink (or on the simulator behind `slungload sil`)",
        "Connects to the autopilot (pymavlink), reads the vehicle's state (ODOMETRY, or "
        "LOCAL_POSITION_NED + ATTITUDE_QUATERNION) and the load's (ODOMETRY of its motion "
        "capture), runs the MPC over an exported model (.mpc.npz on numpy + Numba, or .mpc.onnx "
        "on ONNX Runtime; no torch) and "
        "sends body rates and normalised thrust (SET_ATTITUDE_TARGET) every control period "
        "in OFFBOARD. It streams set-points first, switches mode only with --arm / --offboard "
        "(else waits for the pilot), stops the moment the autopilot leaves OFFBOARD, and on a "
        "stale or bad measurement, the geofence or attitude limit or the MPC's fallback hovers "
        "for --hover-time, then hands back. --tlog records the flight for `slungload import` "
        "(docs/deployment.md).",
    )
    p.add_argument("model", type=Path, help="the exported model (slungload export --for-mpc)")
    p.add_argument("--samples", type=int, help=f"MPC samples per step (default "
                   f"{MPCConfig.samples})")  # fmt: skip
    p.add_argument("--cost", choices=list(COSTS), help=f"the MPC's cost (docs/control.md) "
                   f"(default {MPCConfig.cost})")  # fmt: skip
    p.add_argument("--lean", type=float, metavar="X",
                   help=f"{LEAN_HELP} (default {MPCConfig.lean:g})")  # fmt: skip
    p.add_argument("--shape", type=float, metavar="X",
                   help=f"{SHAPE_HELP} (default {MPCConfig.shape:g})")  # fmt: skip
    p.add_argument("--risk", type=float, metavar="BETA", help="price each plan by the mean "
                   "of its members' costs + BETA x their spread: an ensemble's members, or the "
                   "model and physics with --with-physics (docs/control.md)")  # fmt: skip
    p.add_argument("--members", choices=list(MEMBER_USES),
                   help=f"{MEMBERS_HELP} (default {MPCConfig.members})")  # fmt: skip
    p.add_argument("--input-lag", type=input_lag, metavar="T,R,Y",
                   help=f"{INPUT_LAG_HELP} (default {lag_text(MPCConfig.input_lag)})")  # fmt: skip
    _add_options(p, BridgeConfig, FLY_OPTIONS)
    p.add_argument("--threads", type=int, default=1, help="ONNX Runtime threads (default 1)")
    p.set_defaults(func=cmd_fly)


def cmd_fly(args: argparse.Namespace) -> int:
    from ..autopilot.bridge import fly

    changes = _changes(args, FLY_OPTIONS)
    mpc = given(samples=args.samples, cost=args.cost, lean=args.lean, shape=args.shape,
                risk=args.risk, members=args.members, input_lag=args.input_lag)  # fmt: skip
    if mpc:
        changes["mpc"] = replace(MPCConfig(), **mpc)
    config = replace(BridgeConfig(), **changes)
    result = fly(args.model, config, threads=args.threads, log=print)
    print(result.summary())
    return 0


def add_sil(sub: Any) -> None:
    cfg = SilConfig()
    p = new_command(
        sub,
        "sil",
        "run the simulator behind a MAVLink endpoint that answers as PX4 (for `slungload fly`)",
        "Software in the loop on 127.0.0.1: the MuJoCo vehicle and load, heartbeats with PX4's "
        "modes, arming and mode commands acknowledged, OFFBOARD only over a set-point stream, "
        "body-rate set-points applied, ODOMETRY of the vehicle and of the load, the "
        "offboard-loss failsafe after COM_OF_LOSS_T. Lockstep by default (one control period "
        "per set-point); --real-time for the wall clock's pace (docs/deployment.md).",
    )
    p.add_argument("--plant", choices=choices("plants"), help=f"the simulated vehicle "
                   f"({plants_help()}) (default {cfg.plant})")  # fmt: skip
    p.add_argument("--no-effects", action="store_true",
                   help="the ideal plant: no wind, noise, lags or thrust errors")  # fmt: skip
    p.add_argument("--real-time", action="store_true", help="advance at the wall clock's pace")
    _add_options(p, SilConfig, SIL_OPTIONS)
    p.set_defaults(func=cmd_sil)


def cmd_sil(args: argparse.Namespace) -> int:
    from ..autopilot.sil import SilEndpoint

    changes = _changes(args, SIL_OPTIONS) | given(plant=args.plant)
    changes |= {"lockstep": not args.real_time, "effects": not args.no_effects}
    endpoint = SilEndpoint(replace(SilConfig(), **changes), log=print)
    x, y, z = (float(v) for v in endpoint.start)
    print(f"the vehicle starts at {x!r},{y!r},{z!r} (m, world frame, z up: fly's --origin)")
    log = endpoint.run()
    print(f"{len(log.track)} periods simulated, {len(log.setpoints)} set-points taken, "
          f"ignored: {dict(log.ignored) or 'none'}")  # fmt: skip
    return 0
