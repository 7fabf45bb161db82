"""Physical consistency of a flight: figures a wrong frame, order or unit cannot hide.

A log can be read without error and still be wrong: vehicle and load positions in different
frames, the load mapped to the vehicle's own topic, quaternion columns in w-x-y-z order, a
time column in milliseconds, a thrust in another unit. Each shows in a figure that physics
pins down; ``ConsistencyLimits`` holds the tolerances (SI units, the one home of their
defaults: the command line's help and the docs are written from it):

- the cable length |pL - p|: its median against the vehicle constants' cable length l (when
  the constants are the user's), its spread around its own median, and not zero;
- the load below the vehicle: the mean cable direction within ``mean_swing`` of straight down;
- the vehicle upright on average (body z up), and, at import, logged quaternions of unit norm;
  a vehicle upside down that would fly upright with the quaternion read as w-x-y-z points at
  the order;
- the median thrust against hover, kT T / ((mQ + mL) g);
- at import, each logged stream's median time step, between ``min_step`` and ``max_step``.

``flight_checks`` computes the figures of one flight (``Check``, each with its likely cause);
``slungload import`` refuses a flight outside them (``ConsistencyError``, unless ``force``)
and records them in ``vehicle.json``; ``slungload inspect`` shows them for every dataset.
numpy is imported inside the functions, so the command line's help reads the limits cheaply.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

    from ..config import VehicleParams


class ConsistencyError(ValueError):
    """A flight whose figures are outside ``ConsistencyLimits``; the message names the file,
    the quantity, the value and the likely cause (a ``ValueError``: the command line exits
    with status 2; not a ``readers.logs.LogError``, whose module loads numpy)."""


@dataclass(frozen=True)
class ConsistencyLimits:
    """Tolerances of the physical checks (``flight_checks``), SI units."""

    cable_length: float = 0.15  # m, |median |pL - p| - l|, l the vehicle constants' length
    cable_spread: float = 0.25  # m, 99th percentile of ||pL - p| - median|pL - p||
    min_cable: float = 0.02  # m, a median |pL - p| below this: the load is the vehicle
    mean_swing: float = math.radians(60.0)  # rad, mean cable direction from straight down
    min_upright: float = 0.0  # -, mean up component of the body z axis, in [-1, 1]
    quat_norm: float = 0.1  # -, | |q| - 1 | of a logged quaternion
    thrust_low: float = 0.5  # -, median kT T / ((mQ + mL) g) at least
    thrust_high: float = 2.0  # -, and at most
    min_step: float = 1e-4  # s, median time step of a logged stream at least
    max_step: float = 0.5  # s, and at most
    # a second log (data.alignment): its vehicle track against the first log's
    align_residual: float = 0.05  # m, RMS vehicle position mismatch after alignment at most
    align_extent: float = 0.2  # m, RMS spread of the vehicle's path the frame is fitted on
    align_overlap: float = 0.5  # -, share of the shorter vehicle track both logs cover, at least
    align_duration: float = 5.0  # s, and at least this long

    def __post_init__(self) -> None:
        for f in fields(self):
            if not getattr(self, f.name) >= (-1.0 if f.name == "min_upright" else 0.0):
                raise ValueError(f"ConsistencyLimits.{f.name} is {getattr(self, f.name)}")
        if not (self.thrust_low < self.thrust_high and self.min_step < self.max_step):
            raise ValueError("ConsistencyLimits: each lower limit must be below its upper one")
        if not 0.0 < self.align_overlap <= 1.0:
            raise ValueError(
                f"ConsistencyLimits.align_overlap is {self.align_overlap}, not in (0, 1]"
            )

    def describe(self) -> str:
        """The limits in words, for the command line's help and messages."""
        return (
            f"median |pL - p| within {self.cable_length:g} m of the cable length and above "
            f"{self.min_cable:g} m, its spread (99th percentile) within {self.cable_spread:g} m; "
            f"the mean cable direction within {math.degrees(self.mean_swing):.0f} deg of "
            f"straight down; the vehicle upright on average; quaternion norms within "
            f"{self.quat_norm:g} of 1; median thrust {self.thrust_low:g} to {self.thrust_high:g} "
            f"times hover; median time step {self.min_step:g} to {self.max_step:g} s; a second "
            f"log's vehicle positions within {self.align_residual:g} m (RMS) of the first's "
            f"after alignment, on a path of at least {self.align_extent:g} m (RMS spread)"
        )


@dataclass(frozen=True)
class Check:
    """One figure of a flight against its limit."""

    quantity: str  # what was measured, with its unit
    value: float
    limit: str  # the limit in words: "<= 0.15"
    ok: bool
    cause: str = ""  # the likely cause, when not ok

    def text(self) -> str:
        return f"{self.quantity} = {self.value:.4g} (expected {self.limit})"


CABLE = "median |pL - p| (m)"
CABLE_OFF = "median |pL - p| - l (m)"
SPREAD = "spread of |pL - p|, 99th pct (m)"
SWING = "mean cable from straight down (deg)"
UPRIGHT = "mean up component of body z (-)"
THRUST = "median thrust / hover thrust (-)"
NORM = "quaternion | |q| - 1 |, max (-)"
STEP = "median time step (s)"


def flight_checks(
    p: np.ndarray,
    q_wxyz: np.ndarray,
    p_load: np.ndarray,
    thrust: np.ndarray,
    params: VehicleParams,
    limits: ConsistencyLimits = ConsistencyLimits(),  # noqa: B008 (frozen)
    *,
    own_cable: bool = True,
) -> tuple[Check, ...]:
    """The figures of one flight: positions (T, 3) z up, attitude (T, 4) w-x-y-z body ->
    world, load (T, 3), commanded thrust (T,) or (T, 1) in newtons. ``own_cable``: the
    constants' cable length is the user's, so the median |pL - p| is held to it (else only
    the spread around the flight's own median is)."""
    import numpy as np

    r = np.asarray(p_load, float) - np.asarray(p, float)
    length = np.linalg.norm(r, axis=1)
    median = float(np.median(length))
    spread = float(np.percentile(np.abs(length - median), 99))
    frames_cause = (
        "vehicle and load positions in different frames (axes, origin) or clocks: map both to "
        "one motion-capture frame"
    )
    out = [
        Check(
            CABLE,
            median,
            f">= {limits.min_cable:g}",
            median >= limits.min_cable,
            "the load's position is the vehicle's: the load mapped to the vehicle's own topic "
            "or columns",
        )
    ]
    if median < limits.min_cable:  # no cable to measure: its other figures mean nothing
        out.append(_upright(np.asarray(q_wxyz, float), limits))
        out.append(_thrust(np.asarray(thrust, float).reshape(-1), params, limits))
        return tuple(out)
    if own_cable:
        off = median - params.cable_length
        out.append(
            Check(
                CABLE_OFF,
                off,
                f"within +-{limits.cable_length:g} of l = {params.cable_length:g} m",
                abs(off) <= limits.cable_length,
                f"{frames_cause}; or the cable length of the vehicle constants (--cable-length)",
            )
        )
    out.append(Check(SPREAD, spread, f"<= {limits.cable_spread:g}", spread <= limits.cable_spread,
                     frames_cause))  # fmt: skip
    out.append(_swing(r, length, limits))
    out.append(_upright(np.asarray(q_wxyz, float), limits))
    out.append(_thrust(np.asarray(thrust, float).reshape(-1), params, limits))
    return tuple(out)


def _swing(r: np.ndarray, length: np.ndarray, limits: ConsistencyLimits) -> Check:
    """The mean cable direction (vehicle -> load) against straight down."""
    import numpy as np

    mean = (r / np.maximum(length, 1e-9)[:, None]).mean(axis=0)
    cos = -mean[2] / max(float(np.linalg.norm(mean)), 1e-12)
    angle = math.degrees(math.acos(max(-1.0, min(1.0, cos))))
    return Check(
        SWING,
        angle,
        f"<= {math.degrees(limits.mean_swing):.0f}",
        angle <= math.degrees(limits.mean_swing),
        "the load above or beside the vehicle: a z-down (NED) position read as z up (mapping "
        "key 'world'), or vehicle and load in different frames",
    )


def upright(q_wxyz: np.ndarray) -> np.ndarray:
    """The up component of the body z axis, R(q) e3 . e3 = 1 - 2 (qx^2 + qy^2), per sample."""
    return 1.0 - 2.0 * (q_wxyz[:, 1] ** 2 + q_wxyz[:, 2] ** 2)


def _upright(q: np.ndarray, limits: ConsistencyLimits) -> Check:
    """The vehicle upright on average. Upside down, but upright with the four numbers read as
    w-x-y-z (the predictor's refusal of w-x-y-z in the x-y-z-w slot, as a physical test), the
    cause named is the order, or an FRD body read as FLU (a 180 deg roll: in level flight the
    two look alike)."""
    import numpy as np

    q = q / np.maximum(np.linalg.norm(q, axis=1), 1e-12)[:, None]
    up = float(upright(q).mean())
    columns = q[:, [1, 2, 3, 0]]  # what the x-y-z-w columns held
    if float(upright(columns).mean()) > max(limits.min_upright, 0.5):
        cause = (
            "the quaternion order: the four numbers look like w-x-y-z in x-y-z-w columns "
            "(read as w-x-y-z the vehicle flies upright; CSV: the mapping key 'attitude' "
            "lists the columns x, y, z, w), or an FRD body read as FLU (mapping key 'body'), "
            "which looks the same in level flight"
        )
    else:
        cause = (
            "the attitude's frames (world NED or ENU, body FRD or FLU: mapping keys 'world', "
            "'body'), or a world -> body quaternion where body -> world is expected"
        )
    return Check(UPRIGHT, up, f"> {limits.min_upright:g}", up > limits.min_upright, cause)


def _thrust(thrust: np.ndarray, params: VehicleParams, limits: ConsistencyLimits) -> Check:
    import numpy as np

    hover = (params.mass_quad + params.mass_load) * params.gravity
    ratio = float(np.median(params.thrust_gain * thrust)) / hover
    ok = limits.thrust_low <= ratio <= limits.thrust_high
    if ratio < limits.thrust_low:
        cause = (
            "a thrust below hover: a normalised throttle read as newtons (CSV thrust = "
            '"normalized" with --hover-throttle), a per-motor thrust, or the masses of the '
            "vehicle constants (--vehicle, --mass-quad)"
        )
    else:
        cause = (
            "a thrust above hover: a hover throttle too low (--hover-throttle: the throttle "
            "that holds vehicle and load), a thrust in another unit, or the masses of the "
            "vehicle constants (--vehicle, --mass-quad)"
        )
    return Check(
        THRUST, ratio, f"{limits.thrust_low:g} to {limits.thrust_high:g}", ok, "" if ok else cause
    )


def norm_check(q: np.ndarray, limits: ConsistencyLimits = ConsistencyLimits()) -> Check:  # noqa: B008
    """Logged quaternions (n, 4) against unit norm (zero ones, dropouts, are left out)."""
    import numpy as np

    norm = np.linalg.norm(q, axis=1)
    norm = norm[np.isfinite(norm) & (norm > 0.5)]
    worst = float(np.abs(norm - 1.0).max()) if len(norm) else 0.0
    return Check(
        NORM,
        worst,
        f"<= {limits.quat_norm:g}",
        worst <= limits.quat_norm,
        "the columns or fields are not a unit quaternion (a scaled quaternion, Euler angles, "
        "another quantity)",
    )


def step_check(time: np.ndarray, limits: ConsistencyLimits = ConsistencyLimits()) -> Check:  # noqa: B008
    """A logged stream's median time step (s) against the limits."""
    import numpy as np

    steps = np.diff(np.asarray(time, float))
    step = float(np.median(steps)) if len(steps) else 0.0
    ok = len(steps) == 0 or limits.min_step <= step <= limits.max_step
    cause = (
        "the time unit: milliseconds or microseconds read as seconds (CSV: mapping key 'time_unit')"
        if step > limits.max_step
        else "the time unit: seconds read as a smaller unit (CSV: mapping key 'time_unit')"
    )
    return Check(STEP, step, f"{limits.min_step:g} to {limits.max_step:g}", ok, cause)


def failures(checks: tuple[Check, ...] | list[Check]) -> list[Check]:
    return [c for c in checks if not c.ok]


def refusal(where: str, failed: list[Check]) -> str:
    """One line: the file (and flight), each quantity, its value, limit and likely cause."""
    parts = [f"{c.text()}: likely {c.cause}" for c in failed]
    return f"{where}: {'; '.join(parts)}. --force (force=True) imports it anyway"


def refuse_unless_forced(
    where: str,
    checks: tuple[Check, ...] | list[Check],
    force: bool,
    forced: list[str],
    notes: list[str],
) -> None:
    """Raise ``ConsistencyError`` (``refusal`` naming ``where``) when a check fails, unless
    ``force``: then the line goes into ``forced`` and, as "forced: ...", into ``notes``."""
    bad = failures(checks)
    if not bad:
        return
    line = refusal(where, bad)
    if not force:
        raise ConsistencyError(line)
    forced.append(line)
    notes.append(f"forced: {line}")
