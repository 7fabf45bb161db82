"""The vehicle constants stored beside a dataset: ``vehicle.json`` read and checked.

Keys may be the ``config.VehicleParams`` fields' names or common aliases (``VEHICLE_KEY_ALIASES``);
an unknown key, one constant given twice or a value that is not a number is an error that names
the file and lists the accepted keys.
"""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path
from typing import Any

from .config import VehicleParams

VEHICLE_FILE = "vehicle.json"

# Names a user is likely to write for each vehicle constant (matched after lower-casing and
# turning '-' and ' ' into '_'); the field's own name is always accepted.
VEHICLE_KEY_ALIASES: dict[str, tuple[str, ...]] = {
    "mass_quad": (
        "mass_quadrotor", "quad_mass", "quadrotor_mass", "mass_vehicle", "vehicle_mass",
        "mass_drone", "drone_mass", "mass_uav", "uav_mass", "m_quad", "m_q", "mq",
    ),
    "mass_load": ("load_mass", "mass_payload", "payload_mass", "m_load", "m_l", "ml"),
    "cable_length": (
        "l", "length", "cable", "cable_len", "l_cable", "rope_length", "string_length",
        "tether_length", "pendulum_length",
    ),
    "load_damping": ("damping", "d", "load_angular_damping", "damping_load"),
    "dt": ("h", "sampling_time", "sample_time", "time_step", "timestep", "step", "ts"),
    "gravity": ("g", "gravity_acceleration", "grav"),
    "thrust_gain": ("k_t", "kt", "thrust_scale", "thrust_factor"),
}  # fmt: skip


def _vehicle_key(key: str) -> str:
    return key.strip().lower().replace("-", "_").replace(" ", "_")


def accepted_vehicle_keys() -> str:
    """The accepted vehicle-constant names (every field, with its aliases), for messages."""
    names = [f.name for f in fields(VehicleParams)]
    return "; ".join(
        f"{name} (or {', '.join(VEHICLE_KEY_ALIASES[name])})"
        if VEHICLE_KEY_ALIASES.get(name)
        else name
        for name in names
    )


def vehicle_from_dict(data: Any) -> VehicleParams:
    """``VehicleParams`` from a dict whose keys may be the fields' names or common aliases
    (``VEHICLE_KEY_ALIASES``: ``mass_quadrotor`` for ``mass_quad``, ``l`` for ``cable_length``,
    ...). Unknown keys, one constant given twice, or a value that is not a number are a
    ``ValueError`` that lists the accepted keys."""
    if not isinstance(data, dict):
        raise ValueError(f"expected an object of vehicle constants, got {type(data).__name__}")
    lookup = {f.name: f.name for f in fields(VehicleParams)}  # a new field needs no alias
    for name, aliases in VEHICLE_KEY_ALIASES.items():
        lookup.update({_vehicle_key(alias): name for alias in aliases})
    kwargs: dict[str, float] = {}
    given: dict[str, str] = {}
    unknown = []
    for key, value in data.items():
        name = lookup.get(_vehicle_key(str(key)))
        if name is None:
            unknown.append(key)
            continue
        if name in given:
            raise ValueError(f"{given[name]!r} and {key!r} both set {name}; keep one")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{key!r} must be a number, got {value!r}")
        given[name], kwargs[name] = key, float(value)
    if unknown:
        raise ValueError(
            f"unknown keys {sorted(map(str, unknown))}; accepted keys: {accepted_vehicle_keys()}"
        )
    return VehicleParams(**kwargs)


def read_vehicle(path: str | Path) -> VehicleParams:
    """Vehicle constants from a JSON file: at top level or under a ``"vehicle"`` key (the
    simulator and ``slungload import`` write the latter, with what made the data beside it).
    Keys may be aliases (``vehicle_from_dict``). Errors name the file."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if isinstance(data, dict) and isinstance(data.get("vehicle"), dict):
        data = data["vehicle"]
    try:
        return vehicle_from_dict(data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: bad vehicle constants ({exc})") from exc


def load_vehicle(folder: str | Path) -> VehicleParams | None:
    """Vehicle constants stored beside a dataset (``vehicle.json``), or None if absent.

    The file may hold the constants at top level or under a ``"vehicle"`` key (the simulator
    writes the latter, with its effects and seed beside them); keys may be common aliases
    (``VEHICLE_KEY_ALIASES``), and an unknown key is an error listing the accepted ones.
    """
    path = Path(folder) / VEHICLE_FILE
    if not path.is_file():
        return None
    return read_vehicle(path)


def simulated_without_excitation(folder: str | Path) -> bool:
    """Whether the dataset ``folder``'s vehicle.json says: simulated, commands never
    perturbed, no MPC flights recorded into it (a network trained there learned to predict
    from the state history, where the PID's commands are a function of it). False where it
    says otherwise or cannot say."""
    path = Path(folder) / VEHICLE_FILE
    try:
        found = json.loads(path.read_text()) if path.is_file() else None
    except (OSError, ValueError):
        return False
    if not isinstance(found, dict) or not isinstance(found.get("sim"), dict):
        return False  # real flights carry their pilot's own variation
    if found.get("recorded"):
        return False  # the MPC's own flights: their commands vary with its sampling
    excitation = found["sim"].get("excitation") or {}  # none: before excitation existed
    try:
        rates = excitation.get("rate_std", 0.0)
        stds = [excitation.get("thrust_std", 0.0), *(rates if isinstance(rates, list) else [rates])]
        return all(float(x) == 0 for x in stds)
    except (AttributeError, TypeError, ValueError):
        return False
