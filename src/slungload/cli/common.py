"""What several commands share: the subcommand maker, name choices, seed ranges, the window
options and the vehicle-constant options."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def new_command(sub: Any, name: str, summary: str, description: str) -> argparse.ArgumentParser:
    """A subcommand with a one-line summary (in ``slungload --help``) and a description."""
    return sub.add_parser(name, help=summary, description=f"{summary[0].upper()}{summary[1:]}. "
                          f"{description}")  # fmt: skip


def choices(kind: str) -> list[str]:
    # Registries' names from modules that load neither torch nor MuJoCo: --help stays fast.
    if kind == "variants":
        from ..config import LOSS_VARIANTS as names
    elif kind == "models":
        from ..config import ARCHITECTURES as names
    elif kind == "steps":
        from ..config import STEP_WEIGHTINGS as names
    elif kind == "load-estimates":
        from ..config import LOAD_ESTIMATES as names
    else:
        from ..training.presets import PRESETS as names
    return sorted(names)


def comma_names(text: str) -> list[str]:
    """'a,b,' -> ['a', 'b']: an option's comma-separated names (empty items dropped)."""
    return [name for name in text.split(",") if name]


def comma_ints(text: str) -> list[int]:
    """'6,12' -> [6, 12]: an option's comma-separated counts (empty items dropped)."""
    return [int(k) for k in text.split(",") if k]


def seed_range(text: str) -> tuple[int, ...]:
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


def add_window_options(p: argparse.ArgumentParser, horizon: int = 25) -> None:
    g = p.add_argument_group("windows", "How the flights are cut into training windows.")
    g.add_argument(
        "--history",
        type=int,
        default=50,
        metavar="M",
        help="past steps a window holds (default 50)",
    )
    g.add_argument(
        "--horizon",
        type=int,
        default=horizon,
        metavar="N",
        help=f"future steps predicted (default {horizon})",
    )
    g.add_argument("--stride", type=int, default=1, help="steps between windows (default 1)")


def add_vehicle_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group(
        "vehicle constants of the discrete model",
        "Override the dataset's vehicle.json; without either, the paper's constants apply "
        "(mQ 1.54 kg, mL 0.21 kg, l 0.67 m, d 0.01, h 0.03 s, g 9.81 m/s^2).",
    )
    g.add_argument("--mass-quad", dest="mass_quad", type=float, metavar="KG", help="vehicle mass")
    g.add_argument("--mass-load", dest="mass_load", type=float, metavar="KG", help="load mass")
    g.add_argument("--cable-length", dest="cable_length", type=float, metavar="M", help="cable")
    g.add_argument(
        "--load-damping",
        dest="load_damping",
        type=float,
        metavar="D",
        help="load damping d per step (unitless, in [0, 1))",
    )
    g.add_argument("--dt", type=float, metavar="S", help="sampling time h, s")
    g.add_argument("--gravity", type=float, metavar="M/S2", help="gravity, m/s^2")
    g.add_argument(
        "--thrust-gain",
        dest="thrust_gain",
        type=float,
        metavar="K",
        help="achieved / commanded thrust (unitless; the paper's model: 1)",
    )


def vehicle_overrides(args: argparse.Namespace) -> dict[str, float]:
    names = (
        "mass_quad",
        "mass_load",
        "cable_length",
        "load_damping",
        "dt",
        "gravity",
        "thrust_gain",
    )
    return {n: getattr(args, n) for n in names if getattr(args, n, None) is not None}


def resolve_params(folder: Path, args: argparse.Namespace):
    """Vehicle constants for a dataset folder with the CLI's overrides applied, or None when
    there are none (the data module then reads vehicle.json or says it uses the paper's)."""
    import dataclasses

    from ..config import VehicleParams, load_vehicle

    overrides = vehicle_overrides(args)
    if not overrides:
        return None
    return dataclasses.replace(load_vehicle(folder) or VehicleParams(), **overrides)
