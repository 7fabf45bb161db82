"""A realistic simulator of the quadrotor + slung load (MuJoCo), for training data.

Deliberately *not* the paper's model: it adds drag, rotor downwash on the load, actuator lags,
thrust errors, an elastic cable that can go slack, wind and motion-capture noise, so a learned
model has something to learn beyond ``physics.py``. See ``docs/simulator.md``.
"""

from .config import Effects, SimConfig
from .dataset import SimulatedDataset, simulate_dataset, vehicle_params
from .flight import Flight, simulate_flight
from .maneuvers import MANEUVERS, Maneuver, make_maneuver

__all__ = [
    "MANEUVERS",
    "Effects",
    "Flight",
    "Maneuver",
    "SimConfig",
    "SimulatedDataset",
    "make_maneuver",
    "simulate_dataset",
    "simulate_flight",
    "vehicle_params",
]
