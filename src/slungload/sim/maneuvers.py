"""Reference trajectories flown by the offboard controller, registered by name.

The families mirror the paper's flights (steps, ellipses, figure eights, back and forth, roll
excitations). Each factory draws its amplitudes, periods, phases and length from the flight's
random generator and returns a ``Maneuver``: a position function of time (vectorised over a
time array) plus whether its derivatives are flown as feedforward. All flights start hovering
at the arena centre and stay inside a few metres (a motion-capture arena).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

MIN_STEPS = 197  # shortest flight, steps (the paper's range)
MAX_STEPS = 799  # longest flight, steps
ARENA_XY = 2.0  # m, |x|, |y| limit of the references
ARENA_Z = (1.0, 2.2)  # m, vehicle height limits of the references (load stays above the floor)
# the box the references stay in: lowest x, y, z, then highest, m
ARENA_BOX = (-ARENA_XY, -ARENA_XY, ARENA_Z[0], ARENA_XY, ARENA_XY, ARENA_Z[1])

PositionFn = Callable[[np.ndarray], np.ndarray]  # t (T,) s -> offset from the hover point (T, 3) m


@dataclass(frozen=True)
class Maneuver:
    """One flight's reference: offsets from the hover point as a function of time."""

    name: str
    steps: int  # recorded control steps
    offset: PositionFn  # t (T,) s -> (T, 3) m
    feedforward: bool = True  # fly the reference's velocity and acceleration as feedforward
    yaw_rate: float = 0.0  # rad/s, constant yaw rate of the reference


@dataclass(frozen=True)
class Reference:
    """Sampled reference for a flight: world-frame position, velocity, acceleration, yaw."""

    position: np.ndarray  # (T, 3) m
    velocity: np.ndarray  # (T, 3) m/s
    acceleration: np.ndarray  # (T, 3) m/s^2
    yaw: np.ndarray  # (T,) rad


def _ramp(t: np.ndarray, rise: float = 3.0) -> np.ndarray:
    """Smooth 0 -> 1 over ``rise`` seconds (C2 quintic), so every flight starts from hover."""
    s = np.clip(t / rise, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


def _steps(rng: np.random.Generator, lo: int, hi: int) -> int:
    return int(rng.integers(max(lo, MIN_STEPS), min(hi, MAX_STEPS) + 1))


def _step_sequence(rng: np.random.Generator, steps: int, dt: float, axes: int) -> Maneuver:
    """Piecewise-constant waypoints held 2.5-4 s each (no feedforward, like a setpoint step)."""
    duration = steps * dt
    times, points, t = [0.0], [np.zeros(3)], 1.0
    while t < duration:
        p = np.zeros(3)
        p[:2] = rng.uniform(-1.2, 1.2, size=2)
        if axes == 3:
            p[2] = rng.uniform(-0.4, 0.4)
        times.append(t)
        points.append(p)
        t += rng.uniform(2.5, 4.0)
    times_a, points_a = np.asarray(times), np.stack(points)

    def offset(tt: np.ndarray) -> np.ndarray:
        idx = np.searchsorted(times_a, tt, side="right") - 1
        return points_a[np.clip(idx, 0, len(points_a) - 1)]

    return Maneuver("", steps, offset, feedforward=False)


def _ellipses(
    rng: np.random.Generator, steps: int, period: tuple[float, float], xyz: bool, tilt: bool
) -> Maneuver:
    """Ellipses in the horizontal plane, optionally with a vertical oscillation or a tilt."""
    w = 2.0 * np.pi / rng.uniform(*period)
    ax, ay = rng.uniform(0.5, 1.1), rng.uniform(0.4, 1.0)
    phase = rng.uniform(0.0, 2.0 * np.pi)
    direction = rng.choice([-1.0, 1.0])
    az = rng.uniform(0.15, 0.35) if xyz else 0.0
    wz = w * rng.choice([0.5, 1.0]) if xyz else 0.0
    slope = rng.uniform(-0.3, 0.3) if tilt else 0.0  # tilted plane: z follows x

    def offset(t: np.ndarray) -> np.ndarray:
        s = _ramp(t)
        x = ax * np.cos(w * t + phase)
        y = direction * ay * np.sin(w * t + phase)
        z = az * np.sin(wz * t) + slope * x
        return s[:, None] * np.stack([x, y, z], axis=-1)

    return Maneuver("", steps, offset)


def _random_ellipses(rng: np.random.Generator, steps: int) -> Maneuver:
    """Sum of two ellipses of random axes, periods and phases in 3-D."""
    comps = []
    for period in ((3.5, 5.0), (5.0, 8.0)):
        w = 2.0 * np.pi / rng.uniform(*period)
        amp = rng.uniform(0.2, 0.7, size=3) * np.array([1.0, 1.0, 0.4])
        phases = rng.uniform(0.0, 2.0 * np.pi, size=3)
        comps.append((w, amp, phases))

    def offset(t: np.ndarray) -> np.ndarray:
        out = np.zeros((t.size, 3))
        for w, amp, ph in comps:
            out += amp * np.sin(w * t[:, None] + ph)
        return _ramp(t)[:, None] * out

    return Maneuver("", steps, offset)


def _figure_eight(rng: np.random.Generator, steps: int, xyz: bool) -> Maneuver:
    """Lemniscate laps: x = A sin(w t), y = B sin(2 w t) / 2, optionally z = C sin(2 w t)."""
    w = 2.0 * np.pi / rng.uniform(6.0, 8.0)
    ax, ay = rng.uniform(0.9, 1.5), rng.uniform(0.8, 1.4)
    az = rng.uniform(0.2, 0.4) if xyz else 0.0
    swap = rng.random() < 0.5

    def offset(t: np.ndarray) -> np.ndarray:
        x = ax * np.sin(w * t)
        y = 0.5 * ay * np.sin(2.0 * w * t)
        z = az * np.sin(2.0 * w * t + 0.5 * np.pi) - az
        xy = np.stack([y, x] if swap else [x, y], axis=-1)
        return _ramp(t)[:, None] * np.concatenate([xy, z[:, None]], axis=-1)

    return Maneuver("", steps, offset)


def _back_and_forth(
    rng: np.random.Generator, steps: int, period: tuple[float, float], amp: tuple[float, float]
) -> Maneuver:
    """Back and forth along a random horizontal line."""
    w = 2.0 * np.pi / rng.uniform(*period)
    amp = rng.uniform(*amp)
    heading = rng.uniform(0.0, np.pi)
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])

    def offset(t: np.ndarray) -> np.ndarray:
        return (_ramp(t) * amp * np.sin(w * t))[:, None] * direction

    return Maneuver("", steps, offset)


def _roll_doublets(rng: np.random.Generator, steps: int, tilt_deg: float = 25.0) -> Maneuver:
    """Lateral acceleration doublets: the vehicle rolls to ~35-45 deg and back.

    The feedforward asks for g tan(25 deg); the attitude overshoot, the position feedback and
    the load's pull add the rest (peak roll 39-46 deg over seeds 0-5). Each doublet
    accelerates +a for tau, -a for 2 tau, +a for tau (net displacement zero), then hovers
    1.5-3 s. The position is the exact double integral of the acceleration.
    """
    g = 9.81
    a = g * np.tan(np.radians(tilt_deg))
    events, t = [], 1.0
    while t < steps * 0.03:
        tau = rng.uniform(0.2, 0.26)
        sign = rng.choice([-1.0, 1.0])
        axis = np.array([0.0, 1.0, 0.0]) if rng.random() < 0.75 else np.array([1.0, 0.0, 0.0])
        events.append((t, tau, sign * a, axis))
        t += 4.0 * tau + rng.uniform(1.5, 3.0)

    def offset(tt: np.ndarray) -> np.ndarray:
        out = np.zeros((tt.size, 3))
        for t0, tau, acc, axis in events:
            # displacement of the doublet: piecewise quadratic, zero before t0 and after 4 tau
            s = np.clip(tt - t0, 0.0, 4.0 * tau)
            d = np.where(
                s < tau,
                0.5 * s * s,
                np.where(
                    s < 3.0 * tau,
                    0.5 * tau * tau + tau * (s - tau) - 0.5 * (s - tau) ** 2,
                    0.5 * tau * tau - tau * (s - 3 * tau) + 0.5 * (s - 3 * tau) ** 2,
                ),
            )
            out += (acc * d)[:, None] * axis
        return out

    return Maneuver("", steps, offset)


ManeuverFactory = Callable[[np.random.Generator], Maneuver]

MANEUVERS: dict[str, ManeuverFactory] = {
    "xy_step": lambda r: _step_sequence(r, _steps(r, 300, 600), 0.03, axes=2),
    "xyz_step": lambda r: _step_sequence(r, _steps(r, 300, 600), 0.03, axes=3),
    "slow_ellipses_xy": lambda r: _ellipses(r, _steps(r, 500, 799), (8.0, 11.0), False, False),
    "fast_ellipses_xy": lambda r: _ellipses(r, _steps(r, 300, 700), (4.0, 6.0), False, False),
    "slow_ellipses_xyz": lambda r: _ellipses(r, _steps(r, 500, 799), (8.0, 11.0), True, False),
    "fast_ellipses_xyz": lambda r: _ellipses(r, _steps(r, 300, 700), (4.0, 6.0), True, False),
    "fast_ellipses_xyz_rand": lambda r: _random_ellipses(r, _steps(r, 300, 600)),
    "fast_ellipses_xyz_v2": lambda r: _ellipses(r, _steps(r, 300, 600), (4.0, 6.0), True, True),
    "fast_8_lap_plane": lambda r: _figure_eight(r, _steps(r, 300, 700), xyz=False),
    "fast_8_lap_xyz": lambda r: _figure_eight(r, _steps(r, 300, 700), xyz=True),
    "baf_slow": lambda r: _back_and_forth(r, _steps(r, 400, 799), (7.0, 10.0), (1.0, 1.6)),
    "baf_fast": lambda r: _back_and_forth(r, _steps(r, 300, 600), (4.0, 5.5), (0.6, 1.0)),
    "baf_very_fast": lambda r: _back_and_forth(r, _steps(r, 197, 400), (2.8, 3.6), (0.3, 0.5)),
    "roll_35": lambda r: _roll_doublets(r, _steps(r, 197, 400)),
}


# What each maneuver flies (``slungload maneuvers``), in the authors' family names.
MANEUVER_DESCRIPTIONS: dict[str, str] = {
    "xy_step": "a sequence of horizontal position steps",
    "xyz_step": "a sequence of position steps in x, y and z",
    "slow_ellipses_xy": "horizontal ellipses, 8-11 s a lap",
    "fast_ellipses_xy": "horizontal ellipses, 4-6 s a lap",
    "slow_ellipses_xyz": "tilted ellipses (climbing and sinking), 8-11 s a lap",
    "fast_ellipses_xyz": "tilted ellipses, 4-6 s a lap",
    "fast_ellipses_xyz_rand": "tilted ellipses of random size and period",
    "fast_ellipses_xyz_v2": "tilted ellipses on a sloping plane, 4-6 s a lap",
    "fast_8_lap_plane": "horizontal figure eights",
    "fast_8_lap_xyz": "figure eights that climb and sink",
    "baf_slow": "back and forth along a line, 7-10 s a cycle",
    "baf_fast": "back and forth along a line, 4-5.5 s a cycle",
    "baf_very_fast": "back and forth along a line, 2.8-3.6 s a cycle (aggressive)",
    "roll_35": "roll doublets of about 25-35 degrees (aggressive)",
}


def make_maneuver(name: str, rng: np.random.Generator) -> Maneuver:
    """Draw one maneuver of the named family; unknown names list the known ones."""
    if name not in MANEUVERS:
        raise ValueError(f"unknown maneuver {name!r}; known: {sorted(MANEUVERS)}")
    m = MANEUVERS[name](rng)
    return Maneuver(name, m.steps, m.offset, m.feedforward, m.yaw_rate)


def sample_reference(
    maneuver: Maneuver,
    times: np.ndarray,
    hover: np.ndarray,
    eps: float = 1e-3,
    *,
    arena: bool = True,
) -> Reference:
    """Reference at ``times`` (T,) s: position hover + offset, derivatives by central differences.

    Times before 0 (the warm-up hover) hold the start point. Positions are clipped to the
    simulator's arena (centred on the origin) unless ``arena`` is False (a real vehicle's
    flight, offsets from wherever it starts).
    """
    t = np.maximum(times, 0.0)
    pos = hover + maneuver.offset(t)
    if arena:
        pos = np.clip(pos, ARENA_BOX[:3], ARENA_BOX[3:])
    if maneuver.feedforward:
        p_plus, p_minus = maneuver.offset(t + eps), maneuver.offset(np.maximum(t - eps, 0.0))
        vel = (p_plus - p_minus) / (2.0 * eps)
        acc = (p_plus - 2.0 * maneuver.offset(t) + p_minus) / eps**2
        vel[times < eps] = 0.0
        acc[times < eps] = 0.0
    else:
        vel = np.zeros_like(pos)
        acc = np.zeros_like(pos)
    yaw = maneuver.yaw_rate * t
    return Reference(pos, vel, acc, yaw)
