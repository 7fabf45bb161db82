"""A realistic simulator of the quadrotor + slung load (MuJoCo), for training data.

Deliberately *not* the paper's model: it adds drag, rotor downwash on the load, actuator lags,
thrust errors, an elastic cable that can go slack, wind and motion-capture noise, so a learned
model has something to learn beyond ``physics.py``. See ``docs/simulator.md``.
"""

from __future__ import annotations

from .._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    "config": ("Effects", "Excitation", "LoadRanges", "SimConfig"),
    "controller": ("Controller", "Measurement", "PIDController"),
    "dataset": ("SimulatedDataset", "simulate_dataset", "vehicle_params"),
    "flight": ("Flight", "flight_reference", "simulate_flight"),
    "maneuvers": ("MANEUVERS", "Maneuver", "Reference", "make_maneuver"),
}
# Resolved on first use, like the package's own API: the configs and the maneuver table are
# read by the command line's help without starting MuJoCo.
__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
