"""A realistic simulator of the quadrotor + slung load (MuJoCo), for training data.

Deliberately *not* the paper's model: it adds drag, rotor downwash on the load, actuator lags,
thrust errors, an elastic cable that can go slack, wind and motion-capture noise, so a learned
model has something to learn beyond ``physics.py``. See ``docs/simulator.md``.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS: dict[str, tuple[str, ...]] = {
    "config": ("Effects", "Excitation", "SimConfig"),
    "controller": ("Controller", "Measurement", "PIDController"),
    "dataset": ("SimulatedDataset", "simulate_dataset", "vehicle_params"),
    "flight": ("Flight", "simulate_flight"),
    "maneuvers": ("MANEUVERS", "Maneuver", "Reference", "make_maneuver"),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    # Resolved on first use, like the package's own API: the configs and the maneuver table are
    # read by the command line's help without starting MuJoCo.
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'slungload.sim' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
