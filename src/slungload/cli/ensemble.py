"""Ensemble commands: name runs as one ensemble, calibrate its spread, assess its coverage.

(``train --ensemble K`` trains one; ``models.ensemble`` says what the folder holds.)
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..config import ENSEMBLE_LEVEL as LEVEL
from ..fileio import EVERY
from .common import new_command, positive_int


def _level(text: str) -> float:
    value = float(text)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"a level in (0, 1), e.g. 0.9; got {text}")
    return value


def _add_data_options(p: argparse.ArgumentParser, split: str, every: bool = False) -> None:
    """ENSEMBLE_DIR, --data, --split (with ``every``, also all: every flight) and --horizon."""
    p.add_argument("ensemble", type=Path, metavar="ENSEMBLE_DIR", help="ensemble folder")
    p.add_argument("--data", type=Path, help="dataset folder (default: the members' own)")
    p.add_argument(
        "--split", default=split, choices=("val", "test", *((EVERY,) if every else ())),
        help=f"flights (default {split}"
        + (f"; {EVERY}: every flight, for a dataset the members never saw)" if every else ")"),
    )  # fmt: skip
    p.add_argument(
        "--horizon",
        type=positive_int,
        metavar="N",
        help="predicted steps (default: the members' training horizon)",
    )


def add_ensemble(sub: Any) -> None:
    p = new_command(
        sub,
        "ensemble",
        "name trained runs as one ensemble",
        "Write ENSEMBLE_DIR/ensemble.json naming the runs (same history M and constants; "
        "e.g. seeds of one recipe trained in parallel), then calibrate its spread on their "
        "dataset's val split as `slungload calibrate` does. `train --ensemble K` does both.",
    )
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR", help="member run folders")
    p.add_argument("--out", required=True, type=Path, help="ensemble folder")
    p.add_argument("--data", type=Path, help="dataset to calibrate on (default: the runs' own)")
    p.add_argument("--no-calibrate", action="store_true", help="name the runs only")
    _add_shift_option(p)
    p.set_defaults(func=cmd_ensemble)


def cmd_ensemble(args: argparse.Namespace) -> int:
    from ..models.checkpoints import checkpoint_meta
    from ..models.ensemble import is_ensemble, write_manifest

    if is_ensemble(args.out):
        raise FileExistsError(f"{args.out} already is an ensemble folder; choose another --out")
    if args.no_calibrate and args.constants_shift:
        raise ValueError(
            "--constants-shift widens a calibration and --no-calibrate skips it: give one"
        )
    for run in args.runs:
        checkpoint_meta(run)  # a readable checkpoint, or the error that names it
    existed = args.out.exists()
    path = write_manifest(args.out, list(args.runs))
    if not args.no_calibrate:
        try:
            report_calibration(args.out, args.data, split="val", horizon=None, level=LEVEL,
                               constants_shift=args.constants_shift)  # fmt: skip
        except BaseException:  # nothing half-written: no uncalibrated ensemble left behind
            path.unlink(missing_ok=True)
            if not existed:
                args.out.rmdir()
            raise
    print(f"wrote {path} ({len(args.runs)} members)")
    return 0


def _add_shift_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--constants-shift",
        action="store_true",
        help="widen the members' spread by the physics model's move under the cable length "
        "and load mass estimated from each window's history, so the interval widens on a "
        "vehicle whose load differs from training's (members of fixed constants, M >= 17)",
    )


def report_calibration(
    ensemble: Path,
    data: Path | None,
    *,
    split: str,
    horizon: int | None,
    level: float,
    constants_shift: bool = False,
) -> None:
    """Calibrate and print what was fitted (``evaluation.uncertainty.calibrate``)."""
    from ..evaluation.uncertainty import calibrate, stats_table

    cal, stats = calibrate(ensemble, data, split=split, horizon=horizon, level=level,
                           constants_shift=constants_shift)  # fmt: skip
    spread_of = "the members' spread and the constants shift" if constants_shift else "the spread"
    print(f"calibrated the {level:.0%} interval ({spread_of}) on the {cal.fitted_on} "
          f"({cal.windows} windows)")  # fmt: skip
    print(stats_table(stats))


def add_calibrate(sub: Any) -> None:
    p = new_command(
        sub,
        "calibrate",
        "fit an ensemble's interval to held-out flights",
        "Per horizon step and state group, scale the members' spread so that the interval "
        "covers --level of the split's errors (split-conformal on |error| / std; other levels "
        "by Gaussian z), and set the novelty flag's threshold (the 99th percentile of the "
        "windows' spread relative to the median); stored in ENSEMBLE_DIR/ensemble.json.",
    )
    _add_data_options(p, "val")
    p.add_argument(
        "--level", type=_level, default=LEVEL, help=f"the interval's coverage (default {LEVEL})"
    )
    _add_shift_option(p)
    p.set_defaults(func=cmd_calibrate)


def cmd_calibrate(args: argparse.Namespace) -> int:
    report_calibration(args.ensemble, args.data, split=args.split, horizon=args.horizon,
                       level=args.level, constants_shift=args.constants_shift)  # fmt: skip
    return 0


def add_uncertainty(sub: Any) -> None:
    p = new_command(
        sub,
        "uncertainty",
        "how well a calibrated ensemble's interval covers a dataset's errors",
        "Per horizon step and state group: the members' mean's RMSE, the calibrated sigma and "
        "the share of errors inside the interval, and the share of windows flagged novel; "
        "then the same interval tracked in flight (widened where the model's resolved "
        "predictions miss it; the share of windows issued surprised). "
        "Give --data a dataset the ensemble was not trained on (another load, another "
        "vehicle) to see whether its spread says so.",
    )
    _add_data_options(p, "test", every=True)
    p.add_argument(
        "--level", type=_level, help="the interval's coverage (default: the calibration's)"
    )
    p.add_argument(
        "--carry",
        action="store_true",
        help="track the interval across the flights one after another, as one vehicle "
        "keeping its predictor between flights (default: each flight from the calibration)",
    )
    p.add_argument("--out", type=Path, help="write uncertainty.md, coverage.csv and a figure")
    p.set_defaults(func=cmd_uncertainty)


def cmd_uncertainty(args: argparse.Namespace) -> int:
    from ..evaluation.uncertainty import (
        TRACKED_FROM,
        assess,
        stats_table,
        summary_line,
        write_assessment,
    )

    stats, tracked, about = assess(
        args.ensemble,
        args.data,
        split=args.split,
        horizon=args.horizon,
        level=args.level,
        carry=args.carry,
    )
    print(f"{about}, {stats.windows} windows, {stats.level:.0%} interval:")
    print(stats_table(stats))
    print(f"as calibrated: {summary_line(stats)}")
    print(f"tracked in flight ({TRACKED_FROM[tracked.carried]}): {summary_line(tracked)}")
    if args.out is not None:
        for path in write_assessment(stats, tracked, about, args.out):
            print(f"wrote {path}")
    return 0
