"""Physical consistency of a flight: figures a wrong frame, order or unit cannot hide.

A log can be read without error and still be wrong: vehicle and load positions in different
frames, the load mapped to the vehicle's own topic, quaternion columns in w-x-y-z order, a
time column in milliseconds, a thrust in another unit. Each shows in a figure that physics
pins down; ``ConsistencyLimits`` holds the tolerances (SI units, the one home of their
defaults: the command line's help and the docs are written from it):

- the cable length |pL - p|: its median against the vehicle constants' cable length l (when
  the constants are the user's), its excess over its own median (a slack cable only
  shortens it), and not zero;
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
    cable_spread: float = 0.25  # m, 99th percentile of |pL - p| - median |pL - p|
    min_cable: float = 0.02  # m, a median |pL - p| below this: the load is the vehicle
    mean_swing: float = math.radians(60.0)  # rad, mean cable direction from straight down
    min_upright: float = 0.0  # -, mean up component of the body z axis, in [-1, 1]
    quat_norm: float = 0.1  # -, | |q| - 1 | of a logged quaternion
    thrust_low: float = 0.5  # -, median kT T / ((mQ + mL) g) at least
    thrust_high: float = 2.0  # -, and at most
    min_step: float = 1e-4  # s, median time step of a logged stream at least
    max_step: float = 0.5  # s, and at most
    # the flight's own physics, from accelerations of the positions (``accelerations``)
    thrust_axis: float = math.radians(15.0)  # rad, median angle body z to the CoM's force
    thrust_scale: float = 1.3  # -, median (mQ + mL) |a_C| / (kT T) within [1/x, x]
    cable_pull: float = math.radians(15.0)  # rad, median angle load's force to the cable
    min_force: float = 0.3  # -, specific forces below this share of g left out (free fall)
    smoothing: float = 0.3  # s, span of the local quadratic fit differentiating positions
    # a second log (data.alignment): its vehicle track against the first log's
    align_residual: float = 0.05  # m, RMS vehicle position mismatch after alignment at most
    align_noise: float = 5.0  # -, and at most this times the tracks' noise floor ...
    align_floor: float = 0.01  # m, ... or this, whichever is larger
    align_extent: float = 0.2  # m, RMS spread of the vehicle's path the frame is fitted on
    align_overlap: float = 0.5  # -, share of the shorter vehicle track both logs cover, at least
    align_duration: float = 5.0  # s, and at least this long

    def __post_init__(self) -> None:
        for f in fields(self):
            if not getattr(self, f.name) >= (-1.0 if f.name == "min_upright" else 0.0):
                raise ValueError(f"ConsistencyLimits.{f.name} is {getattr(self, f.name)}")
        if not (self.thrust_low < self.thrust_high and self.min_step < self.max_step):
            raise ValueError("ConsistencyLimits: each lower limit must be below its upper one")
        if self.thrust_scale < 1.0:
            raise ValueError(f"ConsistencyLimits.thrust_scale is {self.thrust_scale}, below 1")
        if not 0.0 < self.align_overlap <= 1.0:
            raise ValueError(
                f"ConsistencyLimits.align_overlap is {self.align_overlap}, not in (0, 1]"
            )

    def describe(self) -> str:
        """The limits in words, for the command line's help and messages."""
        return (
            f"median |pL - p| within {self.cable_length:g} m of the cable length and above "
            f"{self.min_cable:g} m, its excess over the median (99th percentile) within "
            f"{self.cable_spread:g} m; "
            f"the mean cable direction within {math.degrees(self.mean_swing):.0f} deg of "
            f"straight down; the vehicle upright on average; quaternion norms within "
            f"{self.quat_norm:g} of 1; median thrust {self.thrust_low:g} to {self.thrust_high:g} "
            f"times hover; median time step {self.min_step:g} to {self.max_step:g} s; from the "
            f"flight's accelerations (positions fitted over {self.smoothing:g} s): body z within "
            f"{math.degrees(self.thrust_axis):.0f} deg of the specific force of vehicle + load "
            f"(median), their total mass times its size within a factor {self.thrust_scale:g} "
            f"of the thrust, the load's specific force within "
            f"{math.degrees(self.cable_pull):.0f} deg of the cable; a second log's vehicle "
            f"positions within {self.align_residual:g} m (RMS) of the first's after alignment, "
            f"and within {self.align_noise:g} times the noise the tracks show (or "
            f"{self.align_floor:g} m), on a path of at least {self.align_extent:g} m (RMS spread)"
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
SPREAD = "|pL - p| above its median, 99th pct (m)"
SWING = "mean cable from straight down (deg)"
UPRIGHT = "mean up component of body z (-)"
THRUST = "median thrust / hover thrust (-)"
NORM = "quaternion | |q| - 1 |, max (-)"
STEP = "median time step (s)"
THRUST_AXIS = "body z from the CoM's specific force, median (deg)"
THRUST_SCALE = "(mQ + mL) |a_C| / (kT T), median (-)"
CABLE_PULL = "load's specific force from the cable, median (deg)"


def flight_checks(
    p: np.ndarray,
    q_wxyz: np.ndarray,
    p_load: np.ndarray,
    thrust: np.ndarray,
    params: VehicleParams,
    limits: ConsistencyLimits = ConsistencyLimits(),  # noqa: B008 (frozen)
    *,
    own_cable: bool = True,
    dt: float | None = None,
) -> tuple[Check, ...]:
    """The figures of one flight: positions (T, 3) z up, attitude (T, 4) w-x-y-z body ->
    world, load (T, 3), commanded thrust (T,) or (T, 1) in newtons, sampled every ``dt`` s
    (default ``params.dt``). ``own_cable``: the constants are the user's, so the median
    |pL - p| is held to their cable length (else only the spread around the flight's own
    median is) and their masses weigh the centre of mass (else its mass ratio is estimated
    from the flight, ``physics_checks``)."""
    import numpy as np

    r = np.asarray(p_load, float) - np.asarray(p, float)
    length = np.linalg.norm(r, axis=1)
    median = float(np.median(length))
    # one-sided: a slack cable (the load thrown up in a hard roll) shortens |pL - p|, but
    # only another frame lengthens it beyond the cable's stretch
    spread = float(np.percentile(length - median, 99))
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
    step = params.dt if dt is None else dt
    physics = physics_checks(p, q_wxyz, p_load, thrust, params, limits, dt=step,
                             masses_known=own_cable, cable=median >= limits.min_cable)  # fmt: skip
    if median < limits.min_cable:  # no cable to measure: its other figures mean nothing
        out.append(_upright(np.asarray(q_wxyz, float), limits))
        out.append(_thrust(np.asarray(thrust, float).reshape(-1), params, limits))
        return (*out, *physics)
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
    return (*out, *physics)


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


# --- the flight's own physics -------------------------------------------------------------


def accelerations(p: np.ndarray, dt: float, span: float) -> np.ndarray:
    """Accelerations (T, 3) m/s^2 of positions (T, 3) m sampled every ``dt`` s: the second
    derivative of a least-squares quadratic over ``span`` s around each sample (a
    Savitzky-Golay filter: differencing twice would turn 3 mm of motion-capture noise at
    30 ms into 8 m/s^2, this into about 0.5); NaN within half a span of either end."""
    import numpy as np

    m = max(2, round(span / (2.0 * dt)))
    k = np.arange(-m, m + 1, dtype=float)
    weights = 2.0 * np.linalg.pinv(np.stack([np.ones_like(k), k, k * k], axis=1))[2] / dt**2
    p = np.asarray(p, float)
    out = np.full(p.shape, np.nan)
    if len(p) > 2 * m:
        for j in range(p.shape[1]):
            out[m:-m, j] = np.correlate(p[:, j], weights, mode="valid")
    return out


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (n,) deg between rows of a and b (n, 3)."""
    import numpy as np

    cos = np.sum(a * b, axis=1) / np.maximum(
        np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-12
    )
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def mass_ratio(a_quad: np.ndarray, a_load: np.ndarray, b3: np.ndarray, g: float) -> float:
    """The load's share mL / (mQ + mL) that best puts the centre of mass's specific force
    (1 - mu) a_Q + mu a_L + g e3 along body z b3 (rows (n, 3); least squares on the part
    across b3), clipped to [0, 0.5]: an estimate for flights without their masses (the
    clip keeps a wrong attitude from being explained away by an absurd load)."""
    import numpy as np

    def across(v: np.ndarray) -> np.ndarray:
        return v - np.sum(v * b3, axis=1)[:, None] * b3

    base = across(a_quad + np.array([0.0, 0.0, g]))
    lever = across(a_load - a_quad)
    den = float(np.sum(lever * lever))
    mu = -float(np.sum(base * lever)) / den if den > 0 else 0.0
    return min(max(mu, 0.0), 0.5)


def physics_checks(
    p: np.ndarray,
    q_wxyz: np.ndarray,
    p_load: np.ndarray,
    thrust: np.ndarray,
    params: VehicleParams,
    limits: ConsistencyLimits = ConsistencyLimits(),  # noqa: B008 (frozen)
    *,
    dt: float,
    masses_known: bool = True,
    cable: bool = True,
) -> tuple[Check, ...]:
    """The flight against its own physics (arrays as ``flight_checks``; ``dt`` s the step).

    Vehicle and load accelerations a_Q, a_L come from the positions (``accelerations``). The
    specific force of the centre of mass, a_C = (mQ a_Q + mL a_L) / (mQ + mL) + g e3, is the
    thrust over the total mass up to drag: it lies along body z (``THRUST_AXIS``: catches a
    quaternion order or frame that still looks upright) and its size times (mQ + mL) is
    kT T (``THRUST_SCALE``: a hover throttle or thrust unit off). With ``masses_known``
    False, mL / (mQ + mL) is estimated from the flight (``mass_ratio``); the scale still uses
    the constants' total mass (a throttle mapped through the hover throttle carries it).
    The cable pulls the vehicle by mQ (a_Q + g e3) - kT T b3 = -mL (a_L + g e3): the check
    uses the load's side, the load's specific force a_L + g e3 along the cable from load to
    vehicle (``CABLE_PULL``: a load in another frame or origin), because it needs no thrust
    or masses and is measured to about g, while the vehicle's side is the small difference
    of two large forces. Samples whose force is below ``limits.min_force`` g (free fall, a
    slack cable) are left out; a flight too short for the fit gives no figures."""
    import numpy as np

    from ..frames import rotate

    g = params.gravity
    up = np.array([0.0, 0.0, g])
    a_quad = accelerations(p, dt, limits.smoothing)
    a_load = accelerations(p_load, dt, limits.smoothing)
    q = np.asarray(q_wxyz, float)
    q = q / np.maximum(np.linalg.norm(q, axis=1), 1e-12)[:, None]
    b3 = rotate(q, np.array([0.0, 0.0, 1.0]))
    kt = params.thrust_gain * np.asarray(thrust, float).reshape(-1)
    good = np.isfinite(a_quad).all(axis=1) & np.isfinite(a_load).all(axis=1)
    good &= np.isfinite(b3).all(axis=1) & np.isfinite(kt)
    if good.sum() < 3:
        return ()
    if masses_known:
        mu = params.mass_load / (params.mass_quad + params.mass_load)
    else:
        mu = mass_ratio(a_quad[good], a_load[good], b3[good], g) if cable else 0.0
    a_c = (1.0 - mu) * a_quad + mu * a_load + up
    size = np.linalg.norm(a_c, axis=1)
    seen = good & (size > limits.min_force * g)
    pushed = seen & (kt > 0)
    total = params.mass_quad + params.mass_load
    found = (
        _thrust_axis(a_c[seen], b3[seen], limits) if seen.any() else None,
        _thrust_scale(total * size[pushed] / kt[pushed], limits) if pushed.any() else None,
        _cable_pull(a_load + up, np.asarray(p, float) - np.asarray(p_load, float), good, g,
                    limits) if cable else None,
    )  # fmt: skip
    return tuple(c for c in found if c is not None)


def _thrust_axis(a_c: np.ndarray, b3: np.ndarray, limits: ConsistencyLimits) -> Check:
    """``THRUST_AXIS``: the median angle between the centre of mass's specific force (n, 3)
    and body z (n, 3), the samples with a force to measure."""
    import numpy as np

    angle = float(np.median(_angles(a_c, b3)))
    return Check(
        THRUST_AXIS, angle, f"<= {math.degrees(limits.thrust_axis):.0f}",
        angle <= math.degrees(limits.thrust_axis),
        "the attitude: quaternion components in another order (w-x-y-z read as x-y-z-w "
        "looks upright at a heading near 180 deg; CSV: the mapping key 'attitude'), its "
        "frames (mapping keys 'world', 'body'), a world -> body quaternion, or attitude "
        "and positions on different clocks or frames",
    )  # fmt: skip


def _thrust_scale(ratios: np.ndarray, limits: ConsistencyLimits) -> Check:
    """``THRUST_SCALE``: the median of the total mass x specific force / (kT T) (n,), the
    samples with a force to measure and a positive thrust."""
    import numpy as np

    scale = float(np.median(ratios))
    low, high = 1.0 / limits.thrust_scale, limits.thrust_scale
    return Check(
        THRUST_SCALE, scale, f"{low:.3g} to {high:.3g}", low <= scale <= high,
        ("a thrust above what the flight's accelerations show" if scale < low else
         "a thrust below what the flight's accelerations show")
        + ": the hover throttle (--hover-throttle: the throttle that holds vehicle and "
        "load), the thrust's unit or --newtons-per-throttle, or the masses of the "
        "vehicle constants (--vehicle, --mass-quad, --mass-load)",
    )  # fmt: skip


def _cable_pull(
    pull: np.ndarray, toward: np.ndarray, good: np.ndarray, g: float, limits: ConsistencyLimits
) -> Check | None:
    """``CABLE_PULL``: the median angle between the load's specific force (T, 3) and the
    direction load -> vehicle (T, 3), over the ``good`` samples where the cable is taut; None
    where it never is."""
    import numpy as np

    taut = good & (np.linalg.norm(pull, axis=1) > limits.min_force * g)
    if not taut.any():
        return None
    angle = float(np.median(_angles(pull[taut], toward[taut])))
    return Check(
        CABLE_PULL, angle, f"<= {math.degrees(limits.cable_pull):.0f}",
        angle <= math.degrees(limits.cable_pull),
        "the load's positions in another frame, origin or clock than the vehicle's "
        "(a second motion-capture frame, an offset origin: map both to one frame, or "
        "give the load as a second log, --second), or another body's positions",
    )  # fmt: skip
