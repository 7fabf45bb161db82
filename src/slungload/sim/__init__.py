"""A realistic simulator of the quadrotor + slung load (MuJoCo), for training data.

Deliberately *not* the paper's model: it adds drag, rotor downwash on the load, actuator lags,
thrust errors, an elastic cable that can go slack, wind and motion-capture noise, so a learned
model has something to learn beyond ``physics.py``. See ``docs/simulator.md``.
"""

from .config import Effects, SimConfig
from .controller import Controller, Measurement, PIDController
from .dataset import SimulatedDataset, simulate_dataset, vehicle_params
from .flight import Flight, simulate_flight
from .maneuvers import MANEUVERS, Maneuver, Reference, make_maneuver

__all__ = [
    "MANEUVERS",
    "Controller",
    "Effects",
    "Flight",
    "Maneuver",
    "Measurement",
    "PIDController",
    "Reference",
    "SimConfig",
    "SimulatedDataset",
    "make_maneuver",
    "simulate_dataset",
    "simulate_flight",
    "vehicle_params",
]
