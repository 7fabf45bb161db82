"""The commands' lag the paper's discrete model leaves out, numpy only (the onboard path).

The paper's model turns the commanded thrust and body rates into motion at once; a vehicle's
rotors and rate loop follow them with a lag. At a short horizon a model without it believes
bang-bang rate commands act instantly, and the MPC flying it can whip the vehicle (and the load)
that the plant cannot follow (docs/control.md). ``lagged`` passes commands through first-order
lags, one time constant per channel (``LAG_CHANNELS``: thrust, roll and pitch rates, yaw rate),
so that the physics model predicts what the vehicle actually receives; ``training.identify``'s
``fit_input_lag`` fits the constants to a vehicle's flights. A network needs none: it learned
its vehicle's response from the same flights.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .layout import INPUT_DIM, RATES, THRUST

_COLUMNS = tuple(range(INPUT_DIM))
# what each of the three time constants (s) delays: the input columns it covers
LAG_CHANNELS: dict[str, tuple[int, ...]] = {
    "thrust": _COLUMNS[THRUST],
    "roll and pitch rates": _COLUMNS[RATES][:2],
    "yaw rate": _COLUMNS[RATES][2:],
}
NO_LAG = (0.0, 0.0, 0.0)  # s: the paper's model (the commands act at once)
# steps: the fit's default rollout, the MPC's default N (``control.mppi.MPCConfig.horizon``,
# above this floor; a test holds the two equal)
FIT_HORIZON = 15
# ``--input-lag``'s help, for every command that flies the MPC
INPUT_LAG_HELP = ("time constants (s) of the first-order lags the physics model (alone or "
                  "paired) is fed the plans through: " + ", ".join(LAG_CHANNELS) + " (fitted "
                  "by `slungload identify DATA --input-lag`; a network flown alone, or the "
                  "oracle, flies without: it learned its vehicle's lag; "
                  "docs/control.md)")  # fmt: skip
# time constants of warm-up: history rows the filter runs over before the plan (``warm_rows``)
WARM_TAUS = 4.0


def check_lag(lag: Sequence[float]) -> tuple[float, float, float]:
    """``lag`` as a tuple of three finite time constants >= 0 (s), or a ValueError naming it."""
    lag = tuple(float(t) for t in lag)
    if len(lag) != len(LAG_CHANNELS) or not all(math.isfinite(t) and t >= 0 for t in lag):
        names = ", ".join(LAG_CHANNELS)
        raise ValueError(f"input lag: three time constants >= 0 s ({names}), got {lag}")
    return lag  # type: ignore[return-value]


def lag_text(lag: Sequence[float]) -> str:
    """Three time constants as ``--input-lag`` takes them: (0.1, 0.1, 0.2) -> '0.1,0.1,0.2'."""
    return ",".join(f"{t:g}" for t in check_lag(lag))


def smoothing(lag: Sequence[float], dt: float) -> np.ndarray:
    """Per input column (4,): the share of the command's change a step of dt s passes on,
    1 - exp(-dt / tau) (1: no lag)."""
    alpha = np.ones(INPUT_DIM)
    for tau, cols in zip(check_lag(lag), LAG_CHANNELS.values(), strict=True):
        if tau > 0:
            alpha[list(cols)] = -math.expm1(-dt / tau)
    return alpha


def warm_rows(lag: Sequence[float], dt: float) -> int:
    """Past inputs the filter runs over before a plan so that its start forgets its guess
    (``WARM_TAUS`` of the longest time constant; 0 without lag)."""
    return math.ceil(WARM_TAUS * max(check_lag(lag)) / dt)


def lagged(u_before: np.ndarray, inputs: np.ndarray, lag: Sequence[float], dt: float) -> np.ndarray:
    """What the vehicle receives of ``inputs`` (..., N, 4) (thrust N, body rates rad/s), rows dt
    s apart, after the commands ``u_before`` (..., P, 4), P >= 1, oldest first (the filter starts
    at the oldest, taken as settled, and runs over the rest). Each column a first-order lag
    s_k = s_{k-1} + alpha (u_k - s_{k-1}) (``smoothing``); (..., N, 4) float64. No lag: the
    inputs as they are."""
    inputs = np.asarray(inputs, dtype=np.float64)
    if not any(check_lag(lag)):
        return inputs
    u_before = np.asarray(u_before, dtype=np.float64)
    if u_before.shape[-2] < 1:
        raise ValueError("lagged: needs at least one command before the inputs")
    alpha = smoothing(lag, dt)
    s = np.broadcast_to(u_before[..., 0, :], inputs[..., 0, :].shape).copy()
    for k in range(1, u_before.shape[-2]):
        s += alpha * (u_before[..., k, :] - s)
    out = np.empty_like(inputs)
    for k in range(inputs.shape[-2]):
        s += alpha * (inputs[..., k, :] - s)
        out[..., k, :] = s
    return out
