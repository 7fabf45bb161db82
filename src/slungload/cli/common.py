"""What several commands share: the subcommand maker, name choices, seed ranges, the window
options and the vehicle-constant options."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

from ..config import VehicleParams


def new_command(sub: Any, name: str, summary: str, description: str) -> argparse.ArgumentParser:
    """A subcommand with a one-line summary (in ``slungload --help``) and a description."""
    return sub.add_parser(name, help=summary, description=f"{summary[0].upper()}{summary[1:]}. "
                          f"{description}")  # fmt: skip


def plants_help() -> str:
    """The named plants with what each is, for ``--plant``'s help (argparse's % escaped)."""
    from ..sim.plants import PLANTS

    return "; ".join(f"{name}: {text}" for name, (text, _) in PLANTS.items()).replace("%", "%%")


def choices(kind: str) -> list[str]:
    # Registries' names from modules that load neither torch nor MuJoCo: --help stays fast
    # (sorted; the network sizes in the registry's order, largest first).
    if kind == "variants":
        from ..config import LOSS_VARIANTS as names
    elif kind == "models":
        from ..config import ARCHITECTURES as names
    elif kind == "steps":
        from ..config import STEP_WEIGHTINGS as names
    elif kind == "load-estimates":
        from ..config import LOAD_ESTIMATES as names
    elif kind == "network-constants":
        from ..config import NETWORK_CONSTANTS

        return list(NETWORK_CONSTANTS)
    elif kind == "sizes":
        from ..config import MODEL_SIZES as names

        return list(names)
    elif kind == "plants":  # the default first, then by family
        from ..sim.plants import PLANTS as names

        return list(names)
    elif kind == "backends":  # the default first
        from ..config import PREDICTION_BACKENDS as names

        return list(names)
    else:
        from ..run_config import PRESETS as names
    return sorted(names)


def preset_help(default: str) -> str:
    """``--preset``'s help: every training preset and what it does (``run_config.PRESETS``)."""
    from ..run_config import PRESETS

    every = "; ".join(f"{name} ({preset.description})" for name, preset in PRESETS.items())
    return f"training schedule: {every} (default {default})"


def comma_names(text: str) -> list[str]:
    """'a, b,' -> ['a', 'b']: an option's comma-separated names (spaces around a name and
    empty items dropped)."""
    return [name.strip() for name in text.split(",") if name.strip()]


def backends_help() -> str:
    """Every prediction backend and what it runs (``config.PREDICTION_BACKENDS``), for help."""
    from ..config import PREDICTION_BACKENDS

    return "; ".join(f"{k}: {v}" for k, v in PREDICTION_BACKENDS.items())


def comma_ints(text: str) -> list[int]:
    """'6,12' -> [6, 12]: an option's comma-separated counts (empty items dropped)."""
    try:
        return [int(k) for k in text.split(",") if k]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected whole numbers separated by commas (e.g. 6,12), got {text!r}"
        ) from None


def input_lag(text: str) -> tuple[float, float, float]:
    """'0.1,0.1,0.2' -> (0.1, 0.1, 0.2): ``--input-lag``'s three time constants, s, >= 0."""
    from ..input_lag import check_lag  # numpy only

    try:
        return check_lag(float(t) for t in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{exc} (e.g. 0.1,0.1,0.2; given {text!r})") from None


def positive_int(text: str) -> int:
    """'48' -> 48: an option's count, at least 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return value


def value_or_range(text: str) -> float | tuple[float, float]:
    """``0.1`` (one value) or ``0.05:0.3`` (a range), positive numbers."""
    try:
        values = tuple(float(v) for v in text.split(":"))
    except ValueError:
        values = ()
    if len(values) not in (1, 2) or min(values) <= 0 or values[0] > values[-1]:
        raise argparse.ArgumentTypeError(
            f"expected a positive number or a range LO:HI with 0 < LO <= HI, got {text!r}"
        )
    return values[0] if len(values) == 1 else values  # type: ignore[return-value]


def load_range(text: str) -> tuple[float, float]:
    """``0.05:0.3``: a range LO:HI of positive numbers with LO < HI."""
    value = value_or_range(text)
    if not isinstance(value, tuple) or value[0] == value[1]:
        raise argparse.ArgumentTypeError(f"expected a range LO:HI with LO < HI, got {text!r}")
    return value


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
    """One option per field of ``config.VehicleParams`` (``--mass-quad`` for ``mass_quad``),
    its help, unit and default read from the field."""
    g = p.add_argument_group(
        "vehicle constants of the discrete model",
        "Override the vehicle.json in use; without one, these defaults apply "
        f"({VehicleParams().summary()}).",
    )
    for f in dataclasses.fields(VehicleParams):
        unit, symbol = f.metadata["unit"], f.metadata["symbol"]
        g.add_argument(
            f"--{f.name.replace('_', '-')}",
            dest=f.name,
            type=float,
            metavar=(symbol if unit == "-" else unit).upper().replace("^", ""),
            help=f"{symbol} = {f.metadata['text']}, {'unitless' if unit == '-' else unit} "
            f"(default {f.default:g})",
        )


def vehicle_overrides(args: argparse.Namespace) -> dict[str, float]:
    """The vehicle constants given on the command line, by ``VehicleParams`` field name."""
    names = (f.name for f in dataclasses.fields(VehicleParams))
    return {n: getattr(args, n) for n in names if getattr(args, n, None) is not None}


def resolve_params(folder: Path, args: argparse.Namespace):
    """Vehicle constants for a dataset folder with the CLI's overrides applied, or None when
    there are none (the data module then reads vehicle.json or says it uses the defaults)."""
    from ..vehicle_file import load_vehicle

    overrides = vehicle_overrides(args)
    if not overrides:
        return None
    return dataclasses.replace(load_vehicle(folder) or VehicleParams(), **overrides)


def add_cluster_option(p: argparse.ArgumentParser) -> None:
    """``--cluster ADDRESS``: train on a Ray cluster instead of local processes."""
    p.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="train each run as a task on a Ray cluster (needs pip install "
        "'slungload[cluster]'): auto (the cluster RAY_ADDRESS names), local (a Ray instance on "
        "this machine) or ray://HOST:PORT; the dataset, OUT and the package at the same path on "
        "every node; a re-run skips finished runs and resumes the rest (docs/cluster.md)",
    )


def given(**options: Any) -> dict[str, Any]:
    """The options the user gave (argparse leaves the others None): a config's changes. A value
    given as 0 is kept, so that the config refuses it rather than the default replacing it; a
    list given empty (``--maneuvers ,``) is refused by name."""
    for name, value in options.items():
        if isinstance(value, (list, tuple)) and not value:
            raise ValueError(f"--{name.replace('_', '-')}: give at least one value")
    return {name: value for name, value in options.items() if value is not None}


def joined(values: Any) -> str:
    """A config's numbers as a user types them: (100, 101, 102) -> '100..102', (15, 25) ->
    '15,25', 32 -> '32'."""
    if not isinstance(values, (list, tuple)):
        return str(values)
    run = len(values) > 2 and list(values) == list(range(values[0], values[0] + len(values)))
    return f"{values[0]}..{values[-1]}" if run else ",".join(map(str, values))
