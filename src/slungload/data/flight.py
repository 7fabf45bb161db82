"""One flight, whatever file it came from: the ``Flight`` record and the checks every reader
applies (time steps, quaternions, finite numbers). The unmeasured load state is estimated in
``load_state``. See ``docs/data.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..config import VehicleParams
from ..fileio import CONSTANT_KEYS

DT_TOLERANCE = 0.2  # each time step must be within this fraction of params.dt
QUAT_NORM_TOLERANCE = 0.1  # | |q| - 1 | allowed before renormalising


class DatasetError(ValueError):
    """A dataset folder that cannot be used (no flights, bad split lists, ...)."""


class FlightFormatError(DatasetError):
    """A flight file that does not follow the published schema; the message names the file."""


class DataWarning(UserWarning):
    """Something in a dataset was ignored or replaced by a default."""


@dataclass(frozen=True)
class Flight:
    """One validated flight, float64, in the layout of ``state.py``.

    time (T,) s; states (T, 13) = p, v, q (w-x-y-z, unit, sign-continuous), pL;
    inputs (T, 4) = commanded thrust T_ref (N), commanded body rates w_ref (rad/s);
    aux (T, 6) = estimated vL (m/s), Omega_L (rad/s), see ``estimate_load_state``; None for a
    flight read for its checks alone (``readers.load_flight(..., load_state=False)``: no torch).
    constants: the flight's own constants where its file records them (simulated varied loads,
    ``fileio.CONSTANT_KEYS``): the dataset's constants with the recorded ones in place; None
    for a flight of the dataset's constants. ``aux`` uses the dataset's constants either way.
    """

    name: str
    path: Path
    time: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    aux: np.ndarray | None = None
    constants: VehicleParams | None = None

    def __len__(self) -> int:
        return len(self.time)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last sample."""
        return float(self.time[-1] - self.time[0])

    def with_load_state(self, params: VehicleParams) -> Flight:
        """This flight with ``aux``, the causal load-state estimate with the constants
        ``params`` (``load_state.estimate_load_state``: torch, imported here, so a flight read
        for its checks alone needs none)."""
        from ..load_state import estimate_load_state

        return replace(self, aux=estimate_load_state(self.states, params))


def recorded_constants(
    raw: Mapping[str, np.ndarray], params: VehicleParams, path: Path
) -> VehicleParams | None:
    """``params`` with the constants a flight file records (``fileio.CONSTANT_KEYS``: one
    number each) in place, or None when it records none; a recorded constant that is not a
    single positive number is a ``FlightFormatError`` naming it."""
    found = {}
    for key in CONSTANT_KEYS:
        if key in raw:
            value = _numeric(np.asarray(raw[key]), key, path)
            if value.size != 1 or not np.isfinite(value).all() or not value.item() > 0:
                raise FlightFormatError(f"{path}: {key} must be one positive number, got {value}")
            found[key] = value.item()
    return replace(params, **found) if found else None


def _numeric(arr: np.ndarray, key: str, path: Path) -> np.ndarray:
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise FlightFormatError(f"{path}: {key} has dtype {arr.dtype}, expected real numbers")
    return arr.astype(np.float64)


def _series(
    arr: np.ndarray, key: str, trailing: tuple[int, ...], steps: int, path: Path
) -> np.ndarray:
    """(T, *trailing) float64; a (T,) array is accepted where trailing is (1,)."""
    arr = _numeric(arr, key, path)
    if trailing == (1,) and arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 1 + len(trailing) or arr.shape[1:] != trailing:
        expected = ("T", *trailing)
        raise FlightFormatError(f"{path}: {key} has shape {arr.shape}, expected {expected}")
    if arr.shape[0] != steps:
        raise FlightFormatError(f"{path}: {key} has {arr.shape[0]} steps but time has {steps}")
    return arr


def _check_time(time: np.ndarray, dt: float, path: Path) -> None:
    steps = np.diff(time)
    back = np.flatnonzero(steps <= 0)
    if len(back):
        i = back[0]
        raise FlightFormatError(
            f"{path}: time is not strictly increasing at index {i + 1} "
            f"(t[{i}] = {time[i]:.6g} s, t[{i + 1}] = {time[i + 1]:.6g} s)"
        )
    off = np.flatnonzero(np.abs(steps - dt) > DT_TOLERANCE * dt)
    if len(off):
        i = off[0]
        raise FlightFormatError(
            f"{path}: time step from index {i} to {i + 1} is {steps[i]:.6g} s, expected "
            f"dt = {dt} s within {DT_TOLERANCE:.0%} (vehicle.json sets dt)"
        )


def _unit_quaternions(q: np.ndarray, path: Path) -> np.ndarray:
    norms = np.linalg.norm(q, axis=-1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUAT_NORM_TOLERANCE)
    if len(bad):
        i = bad[0]
        raise FlightFormatError(
            f"{path}: attitude at step {i} has norm {norms[i]:.4g}, expected a unit quaternion"
        )
    return q / norms[:, None]
