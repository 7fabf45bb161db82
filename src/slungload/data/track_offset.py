"""The time offset and rigid frame that put one vehicle track on another (``alignment``'s
estimate): candidate offsets from the normalised cross-correlation of the two speeds, screened
by the frame fitted at each, the best refined by Gauss-Newton least squares; ``fit_rigid``
fits the frame (a yaw or any rotation, and a translation) at one offset."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .consistency import ConsistencyLimits
from .readers.logs import LogError

GRID_STEP = 0.02  # s, finest grid of the speed cross-correlation (least squares refine it)
PEAKS = 50  # highest correlation peaks screened by the frame fitted at their offset
CANDIDATES = 5  # of those, the best fits refined by least squares
PEAK_SEPARATION = 1.0  # s, correlation peaks (and refined offsets) closer than this are one
ITERATIONS = 30  # Gauss-Newton steps at most; each moves tau by one grid step at most
CONVERGED = 1e-7  # s, a Gauss-Newton step below this ends the refinement


class Tracks(NamedTuple):
    """Both vehicle tracks, cleaned: times (n,) s, positions (n, 3) m; the second's velocity."""

    t1: np.ndarray
    p1: np.ndarray
    t2: np.ndarray
    p2: np.ndarray
    v2: np.ndarray  # (n2, 3) m/s, for the derivative in the offset
    rotation: str  # "yaw" or "full"
    max_gap: float  # s, the second's samples further apart are a gap
    need: float  # s, the time both must cover at an offset


class Fit(NamedTuple):
    """The frame fitted at one offset."""

    offset: float  # s
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,) m
    residual: float  # m, RMS
    spread: float  # m, RMS
    samples: int


def estimated_offset(
    track: Tracks, t1: np.ndarray, t2: np.ndarray, tolerance: float,
    limits: ConsistencyLimits, what: str,
) -> tuple[Fit, list[Fit]]:  # fmt: skip
    """The best fit over the candidate time offsets and the other distinct ones; a
    ``LogError`` where none fits or another fits within ``tolerance`` m (the offset is
    ambiguous)."""
    step = max(GRID_STEP, median_step(t1), median_step(t2))
    # a repeated maneuver gives many equal peaks: screen them by the fit, refine the best
    screened = [fit_at(track, tau) for tau in _peaks(track, step, limits, what)]
    screened = [f for f in screened if f is not None]
    starts = [f.offset for f in sorted(screened, key=lambda f: f.residual)[:CANDIDATES]]
    fits = sorted(
        (f for f in (_refine(track, tau, step) for tau in starts) if f is not None),
        key=lambda f: f.residual,
    )
    if not fits:
        raise LogError(f"{what}: no time offset puts the vehicle tracks side by side")
    distinct: list[Fit] = []
    for f in fits:  # two peaks may converge to one offset
        if all(abs(f.offset - g.offset) > 0.5 * PEAK_SEPARATION for g in distinct):
            distinct.append(f)
    best, others = distinct[0], distinct[1:]
    rivals = [f for f in others if f.residual <= tolerance]
    if rivals:
        fit_list = "; ".join(
            f"{f.offset:.3f} s: {1000 * f.residual:.1f} mm RMS" for f in [best, *rivals]
        )
        raise LogError(
            f"{what}: the vehicle tracks fit at several time offsets ({fit_list}; tolerance "
            f"{tolerance:.3g} m): a repeated maneuver or a vehicle that hardly moves "
            "cannot tell them apart; give the offset, s added to the second log's stamps, with "
            "--time-offset SECONDS (SecondLog.time_offset)"
        )
    return best, others


def fit_rigid(a: np.ndarray, b: np.ndarray, rotation: str = "yaw") -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), c (3,)) minimising sum |a - (R b + c)|^2 over point pairs a, b (n, 3): R
    about z only ("yaw") or any proper rotation ("full": Kabsch, by the SVD of the
    cross-covariance, with the sign that excludes a reflection)."""
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    h = (b - mb).T @ (a - ma)  # (3, 3): sum of b a^T, centred
    if rotation == "yaw":
        angle = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
        cos, sin = math.cos(angle), math.sin(angle)
        r = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])
    else:
        u, _, vt = np.linalg.svd(h)
        sign = 1.0 if np.linalg.det(vt.T @ u.T) >= 0 else -1.0
        r = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    return r, ma - r @ mb


def median_step(t: np.ndarray) -> float:
    return float(np.median(np.diff(t)))


def _speed(t: np.ndarray, p: np.ndarray, h: float, max_gap: float) -> tuple[np.ndarray, ...]:
    """(speed (k,) m/s on the grid t[0] + h i, valid (k,) 0 or 1): central differences of the
    linearly interpolated positions, invalid next to a gap longer than ``max_gap``."""
    grid = t[0] + h * np.arange(int((t[-1] - t[0]) / h) + 1)
    j = np.clip(np.searchsorted(t, grid, side="right"), 1, len(t) - 1)
    ok = (t[j] - t[j - 1] <= max_gap) | (grid == t[j - 1])
    pos = np.stack([np.interp(grid, t, p[:, k]) for k in range(3)], axis=1)
    speed = np.zeros(len(grid))
    valid = np.zeros(len(grid))
    if len(grid) > 2:
        speed[1:-1] = np.linalg.norm(pos[2:] - pos[:-2], axis=1) / (2 * h)
        valid[1:-1] = ok[2:] & ok[:-2]
    return speed * valid, valid


def _peaks(track: Tracks, h: float, limits: ConsistencyLimits, what: str) -> list[float]:
    """Offsets (s) at the highest peaks of the normalised cross-correlation of the speeds on
    grids of step ``h`` (s), over the lags where the tracks share ``limits.align_overlap`` of
    the shorter one."""
    t1, t2 = track.t1, track.t2
    a, ma = _speed(t1, track.p1, h, track.max_gap)
    b, mb = _speed(t2, track.p2, h, track.max_gap)
    size = 1 << int(len(a) + len(b) - 1).bit_length()

    def xcorr(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        # sum_n x[n] y[n - k] for k = -(len(b) - 1) ... len(a) - 1, by FFT
        full = np.fft.irfft(np.fft.rfft(x, size) * np.conj(np.fft.rfft(y, size)), size)
        return full[np.arange(-(len(b) - 1), len(a)) % size]

    n = np.round(xcorr(ma, mb))
    sa, sb, sab = xcorr(a, mb), xcorr(ma, b), xcorr(a, b)
    saa, sbb = xcorr(a * a, mb), xcorr(ma, b * b)
    need = max(3.0, track.need / h)
    with np.errstate(divide="ignore", invalid="ignore"):
        va, vb = saa - sa * sa / n, sbb - sb * sb / n
        r = (sab - sa * sb / n) / np.sqrt(va * vb)
    r[~((n >= need) & (va > 1e-12 * n) & (vb > 1e-12 * n) & np.isfinite(r))] = -np.inf
    if not np.isfinite(r).any():
        raise LogError(
            f"{what}: the vehicle tracks share no stretch of {track.need:.1f} s (a share of "
            f"{limits.align_overlap:g} of the shorter one) in which the speed varies: no time "
            "offset can be estimated; check that both logs record the same flight, or give "
            "--time-offset SECONDS"
        )
    left, right = np.r_[-np.inf, r[:-1]], np.r_[r[1:], -np.inf]
    peaks = np.flatnonzero(np.isfinite(r) & (r >= left) & (r >= right))
    chosen: list[int] = []
    for k in peaks[np.argsort(-r[peaks], kind="stable")]:
        if all(abs(k - c) * h >= PEAK_SEPARATION for c in chosen):
            chosen.append(int(k))
        if len(chosen) == PEAKS:
            break
    # lag index k pairs a[i] with b[i - k + len(b) - 1]: t1 - t2 = t1[0] - t2[0] + (k - lb + 1) h
    return [float(t1[0] - t2[0] + (k - len(b) + 1) * h) for k in chosen]


def _pairs(track: Tracks, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(first's positions, second's positions and velocities at those instants minus tau),
    each (n, 3), over the first's samples inside the second's track and not in its gaps."""
    t1, p1, t2, p2, v2, _, max_gap, need = track
    if overlap(track, tau) < need - 1e-9:
        return None
    s = t1 - tau
    j = np.clip(np.searchsorted(t2, s, side="right"), 1, len(t2) - 1)
    inside = (s >= t2[0]) & (s <= t2[-1]) & ((t2[j] - t2[j - 1] <= max_gap) | (s == t2[j - 1]))
    if inside.sum() < 3:
        return None
    s = s[inside]
    b = np.stack([np.interp(s, t2, p2[:, k]) for k in range(3)], axis=1)
    v = np.stack([np.interp(s, t2, v2[:, k]) for k in range(3)], axis=1)
    return p1[inside], b, v


def overlap(track: Tracks, tau: float) -> float:
    """s, the time both tracks cover at the offset ``tau`` (s); negative: apart."""
    return float(min(track.t1[-1], track.t2[-1] + tau) - max(track.t1[0], track.t2[0] + tau))


def fit_at(track: Tracks, tau: float) -> Fit | None:
    """The frame fitted at the offset ``tau`` (s); None where the tracks share less than
    ``track.need``."""
    got = _pairs(track, tau)
    if got is None:
        return None
    a, b, _ = got
    r, c = fit_rigid(a, b, track.rotation)
    e = a - b @ r.T - c
    residual = float(np.sqrt(np.mean(np.sum(e * e, axis=1))))
    return Fit(float(tau), r, c, residual, _spread(a, track.rotation), len(a))


def _refine(track: Tracks, tau: float, step: float) -> Fit | None:
    """``_fit`` at the offset that Gauss-Newton least squares reach from ``tau``: the frame
    fitted at each step, then tau moved by -sum(e . J) / sum(J . J), e the position mismatch
    and J = R v_second its derivative in tau (each step at most ``step`` s)."""
    for _ in range(ITERATIONS):
        got = _pairs(track, tau)
        if got is None:
            return None
        a, b, v = got
        r, c = fit_rigid(a, b, track.rotation)
        e, jac = a - b @ r.T - c, v @ r.T
        den = float(np.sum(jac * jac))
        if den <= 0.0:
            break
        delta = float(np.clip(-np.sum(e * jac) / den, -step, step))
        tau += delta
        if abs(delta) < CONVERGED:
            break
    return fit_at(track, tau)


def _spread(a: np.ndarray, rotation: str) -> float:
    """RMS spread (m) of positions (n, 3) that fixes the rotation: horizontal about the mean
    for a yaw; along the second principal axis for any rotation (a straight path leaves the
    roll about it free)."""
    centred = a - a.mean(axis=0)
    if rotation == "yaw":
        return float(np.sqrt(np.mean(np.sum(centred[:, :2] ** 2, axis=1))))
    values = np.linalg.eigvalsh(centred.T @ centred / len(a))  # ascending
    return float(np.sqrt(max(values[1], 0.0)))
