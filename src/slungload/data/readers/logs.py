"""What every flight-log source (ROS bag, PX4 ULog, CSV) hands to the import pipeline.

A log is read into time series by role (``RawLog.streams``), each already in the package's
frames (world z up, body FLU, quaternions w-x-y-z body -> world) and stamped in seconds as the
log stamps it; ``data.importing`` cleans, resamples, validates and writes them. A source's
settings (topics, columns, frames) come from a small mapping (JSON or TOML) merged over the
source's defaults (``merge_settings``); an unknown key is an error that lists the known ones.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..flight import DatasetError

# role -> values per sample. "velocity" is optional (finite differences of the position).
ROLES: dict[str, int] = {
    "position": 3,  # vehicle position, m, world z up
    "attitude": 4,  # vehicle attitude, w-x-y-z, body (FLU) -> world (z up)
    "velocity": 3,  # vehicle velocity, m/s, world z up
    "load": 3,  # load position, m, world z up
    "rates": 3,  # commanded body rates, rad/s, FLU
    "thrust": 1,  # commanded thrust: N, or normalised (RawLog.thrust_normalized)
}
OPTIONAL_ROLES = ("velocity",)


class LogError(DatasetError):
    """A flight log that cannot be imported; the message names the file and the topic or
    column (a ``ValueError``, so the command line exits with status 2)."""


@dataclass
class Stream:
    """One role's samples as logged: ``source`` names where they came from in messages
    ("topic /vrpn_client_node/load/pose", "column p_load_x", ...)."""

    source: str
    time: np.ndarray  # (n,) s
    values: np.ndarray  # (n, ROLES[role])


@dataclass
class RawLog:
    """One log file's streams by role, in the package's frames."""

    path: Path
    format: str  # "ros1", "ros2", "ulog", "csv"
    streams: dict[str, Stream]
    thrust_normalized: bool  # thrust stream is a throttle in [0, 1], not newtons
    settings: dict[str, Any]  # the mapping used (stored in vehicle.json)
    notes: list[str] = field(default_factory=list)
    hover_throttle: float | None = None  # found in the log itself (PX4's MPC_THR_HOVER)


def load_mapping(path: str | Path) -> dict[str, Any]:
    """A mapping file: JSON (``.json``) or TOML (``.toml``, Python 3.11+), one object of
    settings. Errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such mapping file")
    text = path.read_text(encoding="utf-8")
    try:
        if path.suffix.lower() == ".toml":
            try:
                import tomllib
            except ModuleNotFoundError:  # Python 3.10
                raise LogError(f"{path}: TOML needs Python 3.11 or later; write JSON") from None
            data = tomllib.loads(text)
        else:
            data = json.loads(text)
    except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError, TOMLDecodeError
        raise LogError(f"{path}: not a valid mapping file ({exc})") from None
    if not isinstance(data, dict):
        raise LogError(f"{path}: expected an object of settings, got {type(data).__name__}")
    return data


def override(mapping: dict[str, Any] | None, given: list[str], sections: tuple[str, ...]) -> dict:
    """``mapping`` with one-key changes from the command line (``import --set``): ``KEY=VALUE``,
    or ``SECTION.KEY=VALUE`` for a mapping in sections (``sections``: "ros", "ulog", "csv");
    a VALUE with commas is a list (CSV columns: ``attitude=qx,qy,qz,qw``), an empty one turns
    the key off (``velocity=``). The keys are checked by each reader, as a file's are."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in (mapping or {}).items()}
    sectioned = any(isinstance(out.get(s), dict) for s in sections)
    for text in given:
        key, sep, value = text.partition("=")
        key = key.strip()
        if not sep or not key:
            raise LogError(
                f"--set {text!r}: expected KEY=VALUE (e.g. load=vehicle_mocap_odometry:1)"
            )
        parsed: Any = [v.strip() for v in value.split(",")] if "," in value else value.strip()
        section, dot, name = key.partition(".")
        if dot and section not in sections:
            raise LogError(f"--set {text!r}: unknown section {section!r}; sections: {sections}")
        if dot:
            if out and not sectioned:
                raise LogError(
                    f"--set {text!r}: the mapping has no sections; give --set {name}=..."
                )
            out.setdefault(section, {})[name] = parsed
            sectioned = True
        elif sectioned:
            raise LogError(
                f"--set {text!r}: the mapping is in sections ({', '.join(sections)}); name "
                f"one: --set SECTION.{key}=..."
            )
        else:
            out[key] = parsed
    return out


def merge_settings(
    defaults: dict[str, Any], given: dict[str, Any] | None, what: str
) -> dict[str, Any]:
    """``defaults`` updated with ``given``; a key not in ``defaults`` is a ``LogError`` that
    lists the known keys."""
    given = dict(given or {})
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        raise LogError(
            f"{what}: unknown mapping keys {unknown}; known keys: {', '.join(sorted(defaults))}"
        )
    return {**defaults, **given}


def choice(settings: dict[str, Any], key: str, known: tuple[str, ...], what: str) -> str:
    """A setting that must be one of ``known`` (case-insensitive)."""
    value = str(settings[key]).lower()
    if value not in known:
        raise LogError(f"{what}: mapping key {key!r} is {settings[key]!r}; expected one of {known}")
    return value
