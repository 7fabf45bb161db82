"""One flight, whatever file it came from: the ``Flight`` record, the checks every reader applies
(time steps, quaternions, finite numbers), and the causal load-state estimate.

The load velocity vL and load angular velocity Omega_L are not measured; they are estimated
causally from the positions (``estimate_load_state``) so that a prediction made at step k
never uses a sample after k. See ``docs/data.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..config import VehicleParams
from ..state import (
    AUX_DIM,
    LOAD_RATE,
    LOAD_VEL,
    split_state,
)

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
    aux (T, 6) = estimated vL (m/s), Omega_L (rad/s), see ``estimate_load_state``.
    """

    name: str
    path: Path
    time: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    aux: np.ndarray

    def __len__(self) -> int:
        return len(self.time)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last sample."""
        return float(self.time[-1] - self.time[0])


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


def estimate_load_state(states: np.ndarray | Tensor, params: VehicleParams) -> np.ndarray | Tensor:
    """Causal estimate of the unmeasured load state from positions, (..., T, 13) -> (..., T, 6).

    vL_k = (pL_k - pL_{k-1}) / h. With r = pL - p and xi_k = r_k / |r_k|,
    Omega_L,k = xi_k x (r_k - r_{k-1}) / (h l): the pendulum kinematics xi_dot = Omega_L x xi
    with Omega_L perpendicular to the cable. The relative velocity is the backward difference of
    r (not vL minus the measured v) so both positions carry the same half-step lag. Only
    samples k and k-1 are used; step 0 repeats step 1's difference (a forward difference).
    Returns numpy for numpy input, torch (same dtype/device) for torch input.
    """
    x = (
        torch.from_numpy(np.asarray(states, np.float64))
        if isinstance(states, np.ndarray)
        else states
    )
    if x.shape[-2] < 2:
        raise ValueError(f"estimate_load_state: need at least 2 time steps, got {x.shape[-2]}")
    p, _, _, p_load = split_state(x)
    rel = p_load - p
    xi = rel / rel.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    aux = x.new_empty(*x.shape[:-1], AUX_DIM)
    aux[..., LOAD_VEL] = _backward_difference(p_load, params.dt)
    rel_rate = _backward_difference(rel, params.dt)
    aux[..., LOAD_RATE] = torch.linalg.cross(xi, rel_rate) / params.cable_length
    return aux.numpy() if isinstance(states, np.ndarray) else aux


LOAD_FIT_STEPS = 9  # history steps of the smoothed load-state estimate (``fit_load_state``)


def load_fit_coefficients(steps: int, dt: float) -> np.ndarray:
    """(steps,) weights c with sum_j c_j y_{k-steps+1+j} = the slope at sample k of the
    least-squares quadratic through the last ``steps`` samples y, spaced ``dt`` s apart: a
    causal derivative with less noise than the backward difference (which is steps = 2, a
    line) and no lag for a constant acceleration."""
    if steps < 3:
        raise ValueError(f"load_fit_coefficients: a quadratic needs >= 3 steps, got {steps}")
    t = np.arange(-steps + 1, 1, dtype=np.float64) * dt
    basis = np.stack([np.ones_like(t), t, t * t], axis=-1)  # (steps, 3)
    return np.linalg.pinv(basis)[1]  # the row giving the linear coefficient = slope at t = 0


def fit_load_state(states: Tensor, params: VehicleParams) -> Tensor:
    """Smoothed causal estimate of the load state at the last of K steps, (..., K, 13) ->
    (..., 6): vL and the rate of r = pL - p are the slopes of least-squares quadratics through
    the K samples (``load_fit_coefficients``), Omega_L = xi x r_dot / l with xi from the last
    sample, as ``estimate_load_state`` does with two samples. K >= 3."""
    c = torch.as_tensor(load_fit_coefficients(states.shape[-2], params.dt), dtype=states.dtype).to(
        states.device
    )
    p, _, _, p_load = split_state(states)
    rel = p_load - p
    v_load = torch.einsum("k,...kd->...d", c, p_load)
    rel_rate = torch.einsum("k,...kd->...d", c, rel)
    xi = rel[..., -1, :] / rel[..., -1, :].norm(dim=-1, keepdim=True).clamp_min(1e-9)
    rate = torch.linalg.cross(xi, rel_rate) / params.cable_length
    return torch.cat([v_load, rate], dim=-1)


def _backward_difference(y: Tensor, h: float) -> Tensor:
    """(y_k - y_{k-1}) / h along axis -2, the first step repeating the second."""
    d = (y[..., 1:, :] - y[..., :-1, :]) / h
    return torch.cat([d[..., :1, :], d], dim=-2)
