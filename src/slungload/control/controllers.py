"""The simulator's controllers by name: the one table that ``slungload control``, the control
study and the unseen-loads flights build their controllers from.

``CONTROLLERS``: name -> ``"module:Class"`` inside this package, imported on first use (as the
log readers are), so the command line lists the names without loading torch or MuJoCo. The
reference controllers (``REFERENCE``) are built from the simulator's config alone
(``reference_maker``); the MPC is built over a prediction model (``mpc.mpc_maker``). A new
controller is a class meeting ``sim.controller.Controller`` and one line here.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..sim.config import SimConfig

PID = "pid"
GEOMETRIC = "geometric"
MPC = "mpc"
CONTROLLERS: dict[str, str] = {
    PID: "sim.controller:PIDController",  # the simulator's cascaded PID (the data's pilot)
    GEOMETRIC: "control.geometric:GeometricLoadController",  # payload-aware, through the cable
    MPC: "control.mpc:SamplingMPC",  # MPPI over a prediction model (``mpc.mpc_maker``)
}
REFERENCE = (PID, GEOMETRIC)  # built from the simulator's config alone


def controller_class(name: str) -> type:
    """The class registered as ``name``; a clear error naming the known ones otherwise."""
    if name not in CONTROLLERS:
        raise ValueError(f"unknown controller {name!r}; known: {list(CONTROLLERS)}")
    module, cls = CONTROLLERS[name].split(":")
    return getattr(importlib.import_module(f"..{module}", __package__), cls)


def reference_maker(name: str, sim: SimConfig) -> Callable[[int], Any]:
    """seed -> a fresh ``name`` controller (one of ``REFERENCE``) for the vehicle of ``sim``,
    one per flight (they keep state)."""
    if name not in REFERENCE:
        raise ValueError(f"{name!r} is not built from the simulator's config alone; "
                         f"those are {list(REFERENCE)}")  # fmt: skip
    cls = controller_class(name)
    return lambda seed: cls(sim)
