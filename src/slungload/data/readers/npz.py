"""The published flight files: one ``.npz`` per flight with the keys of
``fileio.FLIGHT_KEYS`` (time, p, v, attitude x-y-z-w, p_load, w_ref, T_ref), as the authors'
release and the simulator write them. See ``docs/data.md``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ...config import VehicleParams
from ...fileio import FLIGHT_KEYS, IGNORED_KEYS, OPTIONAL_KEYS, read_npz
from ...frames import quat_continuous
from ...layout import INPUT_DIM, LOAD_POS, POS, QUAT, RATES, STATE_DIM, THRUST, VEL, XYZW_TO_WXYZ
from ..flight import (
    Flight,
    FlightFormatError,
    _check_time,
    _numeric,
    _series,
    _unit_quaternions,
    recorded_constants,
)


def read(path: Path, params: VehicleParams, notes: list[str]) -> Flight:
    """One ``.npz`` flight of the published schema, validated; ignored keys go to ``notes``."""
    try:
        raw = read_npz(path)
    except ValueError as exc:  # message already names the file
        raise FlightFormatError(str(exc)) from exc
    missing = [key for key in FLIGHT_KEYS if key not in raw]
    if missing:
        raise FlightFormatError(f"{path}: missing keys {missing} (has {sorted(raw)})")
    unknown = sorted(set(raw) - set(FLIGHT_KEYS) - set(OPTIONAL_KEYS) - set(IGNORED_KEYS))
    if unknown:
        notes.append(f"{path}: ignoring unknown keys {unknown}")
    flight = from_arrays(raw, path, params)
    constants = recorded_constants(raw, params, path)  # the flight's own, where recorded
    return flight if constants is None else replace(flight, constants=constants)


def from_arrays(
    raw: dict[str, np.ndarray], path: Path, params: VehicleParams, name: str | None = None
) -> Flight:
    """Validate arrays of the published schema (every key of ``FLIGHT_KEYS``) into a ``Flight``
    (numpy only; its load state is not estimated: ``readers.load_flight`` adds it).

    The checks of ``read`` (shapes, finite values, the time step against ``params.dt``, unit
    quaternions x-y-z-w) with ``path`` in every message; other sources (``data.importing``)
    call it on what they are about to write, so an imported flight meets the same checks.
    """
    time = _numeric(raw["time"], "time", path)
    if time.ndim == 2 and 1 in time.shape:  # (T, 1) or (1, T), as MATLAB writes vectors
        time = time.reshape(-1)
    if time.ndim != 1:
        raise FlightFormatError(f"{path}: time has shape {time.shape}, expected (T,)")
    steps = len(time)
    if steps < 2:
        raise FlightFormatError(f"{path}: {steps} samples, need at least 2")
    arrays = {"time": time}
    for key, trailing in FLIGHT_KEYS.items():
        if key != "time":
            arrays[key] = _series(raw[key], key, trailing or (), steps, path)
    for key, arr in arrays.items():
        bad = np.argwhere(~np.isfinite(arr))
        if len(bad):
            value = arr[tuple(bad[0])]
            raise FlightFormatError(f"{path}: {key} holds {value} at step {bad[0][0]}")
    _check_time(time, params.dt, path)

    quat = _unit_quaternions(arrays["attitude"], path)[:, XYZW_TO_WXYZ]
    states = np.empty((steps, STATE_DIM))
    states[:, POS], states[:, VEL] = arrays["p"], arrays["v"]
    states[:, QUAT], states[:, LOAD_POS] = quat_continuous(quat), arrays["p_load"]
    inputs = np.empty((steps, INPUT_DIM))
    inputs[:, THRUST] = arrays["T_ref"]
    inputs[:, RATES] = arrays["w_ref"]
    return Flight(name or path.stem, path, time, states, inputs)
