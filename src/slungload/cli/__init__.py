"""Command line: parses arguments and calls the stage functions; no logic lives here.

A user error (bad path, bad file, bad option) prints one line and exits with status 2;
``--debug`` shows the traceback instead. The commands live by stage: ``data`` (simulate,
maneuvers, inspect, split, import), ``train`` (train, identify), ``ensemble`` (ensemble,
calibrate, uncertainty), ``evaluate`` (evaluate, check, reproduce, study), ``deploy`` (export,
benchmark), ``control`` and ``autopilot`` (fly, sil), each with its parser beside it;
``common`` holds what they share.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable, Sequence

from .._version import __version__
from .autopilot import add_fly, add_sil
from .control import add_control, add_record
from .data import add_inspect, add_maneuvers, add_simulate, add_split
from .deploy import add_benchmark, add_export
from .ensemble import add_calibrate, add_ensemble, add_uncertainty
from .evaluate import add_check, add_evaluate, add_reproduce
from .importing import add_import
from .study import add_study, add_tune
from .train import add_identify, add_train

USER_ERRORS = (
    ValueError,
    FileNotFoundError,
    FileExistsError,
    NotADirectoryError,
    IsADirectoryError,
    PermissionError,
    KeyError,
    TimeoutError,  # nothing answered on the link (fly)
)

# The extra that brings each optional module, by import name (pyproject.toml): a command that
# needs one an install left out says which and how to install it.
EXTRAS = {
    **dict.fromkeys(("torch", "roma", "mujoco", "lightning", "tensorboard", "matplotlib", "tqdm",
                     "onnx", "numba", "rosbags", "mcap", "pyulog", "tomli_w"), "full"),
    "onnxruntime": "onboard", "pymavlink": "onboard", "ray": "cluster", "optuna": "cluster",
}  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slungload",
        description="Learn and predict the motion of a quadrotor carrying a cable-slung load.",
    )
    parser.add_argument("--version", action="version", version=f"slungload {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    add_simulate(sub)
    add_maneuvers(sub)
    add_inspect(sub)
    add_train(sub)
    add_ensemble(sub)
    add_calibrate(sub)
    add_evaluate(sub)
    add_uncertainty(sub)
    add_check(sub)
    add_reproduce(sub)
    add_export(sub)
    add_benchmark(sub)
    add_split(sub)
    add_import(sub)
    add_identify(sub)
    add_study(sub)
    add_tune(sub)
    add_control(sub)
    add_record(sub)
    add_fly(sub)
    add_sil(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    if args.debug:
        return func(args)
    formatwarning, warnings.formatwarning = warnings.formatwarning, _one_line_warning
    try:
        return func(args)
    except USER_ERRORS as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"slungload {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:
        extra = EXTRAS.get((exc.name or "").split(".")[0])
        if extra is None:
            raise
        print(f"slungload {args.command}: error: needs {exc.name}, which this install leaves "
              f"out: pip install 'slungload[{extra}]' (from a checkout: pip install "
              f"'.[{extra}]')", file=sys.stderr)  # fmt: skip
        return 2
    except KeyboardInterrupt as exc:  # train raises a subclass carrying the signal's number
        detail = f": {exc}" if str(exc) else ""
        print(f"slungload {args.command}: interrupted{detail}", file=sys.stderr)
        return 128 + getattr(exc, "signum", 2)
    finally:
        warnings.formatwarning = formatwarning


def _one_line_warning(message, category, filename, lineno, line=None) -> str:  # noqa: ANN001
    """Warnings as one line a user can read (no source line); ``--debug`` shows Python's."""
    return f"slungload: note: {message}\n"
