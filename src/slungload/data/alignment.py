"""A second log on the first log's clock and frame, from the vehicle track both hold.

The usual real set-up is a PX4 ULog for the vehicle (position, attitude, commands) and a
separate motion-capture recording (a bag, a CSV) for the load and the vehicle again. The two
never share a clock (a ULog counts from boot, a bag in Unix time) nor a world frame (both are
z up once read, but the EKF's origin and heading are not the motion capture's). From the
vehicle positions both logs hold, ``align_tracks`` estimates

- the time offset tau (s), t_first = t_second + tau: the normalised cross-correlation of the
  two speeds |v| (blind to frames) on a common grid of step ``track_offset.GRID_STEP`` or
  coarser gives candidate offsets, its highest peaks where the tracks share at least
  ``ConsistencyLimits.align_overlap`` of the shorter one; the peaks are screened by the frame
  fitted at their offset (a repeated maneuver gives many equal peaks), and the best few refined
  by Gauss-Newton least squares on the position mismatch (the frame fitted again at each
  step), to a fraction of a sample period;
- the rigid transform p_first = R p_second + c on the time-aligned positions: a rotation about
  z (``rotation="yaw"``, the default: both frames are z up, gravity fixes the vertical) or any
  rotation (``"full"``, Kabsch), and a translation;
- the residual: the RMS of |p_first - (R p_second(t - tau) + c)| over the first log's samples
  in the overlap (in m), and the RMS spread of the vehicle's path there (the rotation is only
  as good as the path is wide);
- the tracks' noise floor (``noise_floor``): what the residual of two logs of the same flight
  comes to, from each track's own sample-to-sample scatter. The residual must stay within
  ``ConsistencyLimits.align_noise`` times it (or ``align_floor``, whichever is larger, and
  ``align_residual`` at most): a true second log matches to about 1 mm, a repeat of the same
  mission to 20-50 mm, which only this relative limit tells apart.

The candidate with the smallest residual wins. Another offset that also fits within that
limit means the track cannot tell them apart (a repeated maneuver, a vehicle that
hardly moves): an error naming both, which ``time_offset`` (``--time-offset``) settles; a
given offset is used as it is, and the frame is still fitted.

``attach_second`` checks the residual and the spread against ``ConsistencyLimits``
(``ConsistencyError`` naming both files, unless ``force``) and puts the second log's streams
of the chosen roles into the first log: stamps + tau, positions R p + c, velocities R v,
attitudes q_R (x) q; body rates and thrust are the same in any world frame. They are then
cleaned and resampled like every stream (``resample``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import frames
from .consistency import Check, ConsistencyLimits, refuse_unless_forced
from .import_options import STAMP_EPS, ImportOptions, SecondLog
from .readers.logs import LogError, RawLog, Stream
from .track_offset import Fit, Tracks, estimated_offset, fit_at, median_step, overlap

RESIDUAL = "alignment residual, RMS (m)"
SPREAD = "vehicle path spread, RMS (m)"


@dataclass(frozen=True)
class Alignment:
    """A second log put on the first's clock and frame: t_first = t_second + offset,
    p_first = rotation @ p_second + translation."""

    offset: float  # s
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,) m
    residual: float  # m, RMS vehicle position mismatch over the samples below
    spread: float  # m, RMS spread of the vehicle's path there (horizontal: "yaw")
    overlap: float  # s, the time both vehicle tracks cover
    samples: int  # samples of the first log in the fit
    estimated: bool  # the offset was estimated (False: given)
    others: tuple[tuple[float, float], ...] = ()  # (offset s, residual m) of other candidates
    noise: float = 0.0  # m, the residual two noisy logs of one flight show (``noise_floor``)

    @property
    def yaw(self) -> float:
        """rad, the rotation's heading change about z."""
        return math.atan2(self.rotation[1, 0], self.rotation[0, 0])

    @property
    def tilt(self) -> float:
        """rad, the angle the rotation turns z by (0 for a rotation about z)."""
        return math.acos(max(-1.0, min(1.0, float(self.rotation[2, 2]))))

    def describe(self) -> str:
        """One line: the offset, the transform and the residual."""
        how = "estimated" if self.estimated else "given"
        tilt = f", tilt {math.degrees(self.tilt):.2f} deg" if self.tilt > 1e-9 else ""
        c = ", ".join(f"{x:.3f}" for x in self.translation)
        return (
            f"time offset {self.offset:.4f} s ({how}), rotation {math.degrees(self.yaw):.2f} "
            f"deg about z{tilt}, translation ({c}) m; vehicle positions differ by "
            f"{1000 * self.residual:.1f} mm RMS over {self.overlap:.1f} s ({self.samples} "
            "samples)"
        )

    def record(self) -> dict[str, Any]:
        """For ``vehicle.json``: units in the names."""
        return {
            "time_offset_s": self.offset,
            "time_offset_from": "estimated" if self.estimated else "given",
            "rotation": np.round(self.rotation, 12).tolist(),
            "yaw_deg": math.degrees(self.yaw),
            "tilt_deg": math.degrees(self.tilt),
            "translation_m": self.translation.tolist(),
            "residual_m": self.residual,
            "spread_m": self.spread,
            "overlap_s": self.overlap,
            "samples": self.samples,
            "noise_floor_m": self.noise,
            "other_offsets_s_residual_m": [list(o) for o in self.others],
        }


def align_tracks(
    first: Stream,
    second: Stream,
    *,
    rotation: str = "yaw",
    time_offset: float | None = None,
    limits: ConsistencyLimits = ConsistencyLimits(),  # noqa: B008 (frozen)
    max_gap: float = 0.1,
    what: str = "",
) -> Alignment:
    """The offset and transform that put the vehicle positions ``second`` (n, 3) on ``first``
    (m, 3), both in m, z up (see the module's docstring). ``time_offset`` (s): given, not
    estimated; ``max_gap`` (s): the second's samples further apart are a gap, not interpolated
    across; ``what`` names the logs in errors (``LogError``)."""
    t1, p1 = _track(first, what)
    t2, p2 = _track(second, what)
    need = _requiredoverlap(first, second, t1, t2, limits, max_gap, what)
    max_gap += STAMP_EPS  # a step over it by the stamps' rounding is no gap
    track = Tracks(t1, p1, t2, p2, np.gradient(p2, t2, axis=0), rotation, max_gap, need)
    noise = math.hypot(noise_floor(t1, p1, max_gap), noise_floor(t2, p2, max_gap))
    tolerance = residual_limit(noise, limits)
    if time_offset is not None:
        fit = fit_at(track, time_offset)
        if fit is None:
            common = overlap(track, time_offset)
            raise LogError(
                f"{what}: with the time offset {time_offset:g} s the vehicle tracks "
                + ("do not overlap" if common <= 0 else f"share only {common:.2f} s")
                + f" (the first covers {t1[0]:.3f} to {t1[-1]:.3f} s, the second "
                f"{t2[0] + time_offset:.3f} to {t2[-1] + time_offset:.3f} s on the first's "
                f"clock; at least {need:.2f} s are needed); leave --time-offset out to "
                "estimate it"
            )
        return _alignment(fit, track, estimated=False, noise=noise)
    best, others = estimated_offset(track, t1, t2, tolerance, limits, what)
    return _alignment(best, track, estimated=True, noise=noise,
                      others=[(f.offset, f.residual) for f in others])  # fmt: skip


def _requiredoverlap(
    first: Stream, second: Stream, t1: np.ndarray, t2: np.ndarray,
    limits: ConsistencyLimits, max_gap: float, what: str,
) -> float:  # fmt: skip
    """s, the overlap an alignment of the two tracks (stamps t1, t2) needs; a ``LogError``
    where the shorter is too short or either is sampled more sparsely than ``max_gap``."""
    # a short stretch fits almost anything: both must cover a good share of the shorter track
    shorter = min(t1[-1] - t1[0], t2[-1] - t2[0])
    if shorter < limits.align_duration:
        source = first.source if t1[-1] - t1[0] == shorter else second.source
        raise LogError(
            f"{what}: the vehicle track ({source}) covers {shorter:.2f} s, shorter than the "
            f"{limits.align_duration:g} s an alignment needs (ConsistencyLimits.align_duration)"
        )
    need = max(limits.align_overlap * shorter, limits.align_duration)
    sparse = [(s.source, median_step(t)) for s, t in ((first, t1), (second, t2))]
    sparse = [(source, step) for source, step in sparse if step > max_gap + STAMP_EPS]
    if sparse:
        source, step = sparse[0]
        above = math.ceil(1.5 * step / 0.05) * 0.05
        raise LogError(
            f"{what}: the vehicle track {source} has a sample every {step:.3g} s (median), "
            f"further apart than --max-gap {max_gap:g} s: every step is a gap and nothing can "
            f"be aligned; raise the position's --max-gap above its step (--max-gap "
            f"position={above:g}; ImportOptions.max_gaps)"
        )
    return need


def noise_floor(t: np.ndarray, p: np.ndarray, max_gap: float) -> float:
    """m, the RMS 3-D scatter of a position track (n, 3) at stamps t (n,) s about its smooth
    path: per axis 1.4826 MAD / sqrt 6 of the second differences (white noise of standard
    deviation s gives them 6 s^2; the median ignores the few that a manoeuvre or a dropout
    makes large), over samples whose both steps are within ``max_gap`` and alike. A sparse
    track's differences hold some of its motion: its floor errs high (a looser limit)."""
    steps = np.diff(t)
    even = (steps[1:] <= max_gap) & (steps[:-1] <= max_gap)
    even &= np.abs(steps[1:] - steps[:-1]) <= 0.25 * np.maximum(steps[1:], steps[:-1])
    d2 = (p[2:] - 2.0 * p[1:-1] + p[:-2])[even]
    if len(d2) < 10:
        return 0.0
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return float(np.sqrt(np.sum((1.4826 * mad) ** 2 / 6.0)))


def residual_limit(noise: float, limits: ConsistencyLimits) -> float:
    """m, the largest alignment residual accepted for tracks of the noise floor ``noise`` m:
    ``align_noise`` times it, at least ``align_floor``, at most ``align_residual``."""
    return min(limits.align_residual, max(limits.align_floor, limits.align_noise * noise))


def transform(role: str, stream: Stream, alignment: Alignment) -> Stream:
    """One stream of the second log on the first's clock and frame (``logs.ROLES``)."""
    r, c = alignment.rotation, alignment.translation
    v = np.asarray(stream.values, float)
    if role in ("position", "load"):
        v = v @ r.T + c
    elif role == "velocity":
        v = v @ r.T
    elif role == "attitude":  # body -> second world -> first world
        v = frames.quat_multiply(frames.quat_from_matrix(r), v)
    # "rates" (body frame) and "thrust" do not depend on the world frame
    return Stream(stream.source, np.asarray(stream.time, float) + alignment.offset, v)


def attach_second(
    first: RawLog, second: RawLog, spec: SecondLog, options: ImportOptions, notes: list[str]
) -> tuple[RawLog, dict[str, Any]]:
    """``first`` with the streams ``spec.roles`` of ``second`` on its clock and frame, and
    what to record in ``vehicle.json``. An alignment whose residual or spread is outside
    ``options.limits`` is refused (``ConsistencyError`` naming both files), or noted under
    ``options.force``."""
    missing = [r for r in dict.fromkeys(("position", *spec.roles)) if r not in second.streams]
    if missing:
        raise LogError(
            f"{second.path}: the second log gives no {', '.join(missing)} (its mapping: "
            f"{second.settings})"
        )
    alignment = align_tracks(
        first.streams["position"],
        second.streams["position"],
        rotation=spec.rotation,
        time_offset=spec.time_offset,
        limits=options.limits,
        max_gap=options.gap("position"),
        what=f"{first.path} and {second.path}",
    )
    checks = alignment_checks(alignment, options.limits)
    forced: list[str] = []
    where = f"{first.path} + {second.path} ({alignment.describe()})"
    refuse_unless_forced(where, checks, options.force, forced, notes)
    notes.append(
        f"{first.path}: {', '.join(spec.roles)} from {second.path}, {alignment.describe()}"
    )
    streams = dict(first.streams)
    start = min(float(s.time[0]) for s in first.streams.values() if len(s.time))
    end = max(float(s.time[-1]) for s in first.streams.values() if len(s.time))
    for role in spec.roles:
        moved = _within(transform(role, second.streams[role], alignment), start, end)
        streams[role] = Stream(f"{moved.source} of {second.path}", moved.time, moved.values)
    thrust = "thrust" in spec.roles  # whether it is a throttle goes with the stream
    merged = RawLog(
        first.path,
        first.format,
        streams,
        second.thrust_normalized if thrust else first.thrust_normalized,
        first.settings,
        first.notes,
        second.hover_throttle if thrust else first.hover_throttle,
    )
    record = {
        "log": str(second.path),
        "format": second.format,
        "settings": second.settings,
        "roles": list(spec.roles),
        "rotation": spec.rotation,
        "alignment": alignment.record(),
        "checks": {c.quantity: round(c.value, 6) for c in checks},
        "forced": forced,
    }
    return merged, record


def _within(stream: Stream, start: float, end: float) -> Stream:
    """The samples in [start, end] (s) and one on each side: a motion-capture recording that
    runs on before and after the first log does not end the flight early (``resample``'s note
    on streams that end before the others)."""
    t = stream.time
    a = max(int(np.searchsorted(t, start, side="left")) - 1, 0)
    b = int(np.searchsorted(t, end, side="right")) + 1
    return Stream(stream.source, t[a:b], stream.values[a:b])


def alignment_checks(alignment: Alignment, limits: ConsistencyLimits) -> tuple[Check, Check]:
    """The residual (against ``residual_limit`` of the tracks' noise floor) and the path's
    spread against their limits."""
    how = "the estimated" if alignment.estimated else "the given"
    tolerance = residual_limit(alignment.noise, limits)
    return (
        Check(
            RESIDUAL,
            alignment.residual,
            f"<= {tolerance:.3g}: {limits.align_noise:g} x the tracks' noise "
            f"{1000 * alignment.noise:.2f} mm, at least {limits.align_floor:g}, at most "
            f"{limits.align_residual:g}",
            alignment.residual <= tolerance,
            "the two logs hold different flights (a repeat of the same mission fits to "
            "centimetres, the same flight to its noise), or vehicle positions that differ by "
            "more than a rigid transform (an EKF position without motion capture, a frame "
            f"mapping such as 'world'), or {how} time offset is wrong; --align-tolerance M "
            "(ConsistencyLimits.align_residual and align_floor) accepts a mismatch up to M",
        ),
        Check(
            SPREAD,
            alignment.spread,
            f">= {limits.align_extent:g}",
            alignment.spread >= limits.align_extent,
            "a vehicle that hardly moves while both logs record: its path cannot fix the "
            "rotation between their frames; record a flight that moves",
        ),
    )


# --- the estimate -------------------------------------------------------------------------


def _track(stream: Stream, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(n,) increasing times and (n, 3) positions of a position stream, without NaN rows
    (mocap dropouts) or repeated stamps; the streams' own checks come later (``resample``)."""
    t, p = np.asarray(stream.time, float), np.asarray(stream.values, float)
    good = np.isfinite(t) & np.isfinite(p).all(axis=1)
    t, first = np.unique(t[good], return_index=True)
    if len(t) < 3:
        raise LogError(f"{what}: {stream.source} has {len(t)} valid samples, too few to align")
    return t, p[good][first]


def _alignment(
    fit: Fit,
    track: Tracks,
    *,
    estimated: bool,
    noise: float,
    others: list[tuple[float, float]] | None = None,
) -> Alignment:
    common = overlap(track, fit.offset)
    return Alignment(fit.offset, fit.rotation, fit.translation, fit.residual, fit.spread, common,
                     fit.samples, estimated, tuple(others or ()), noise)  # fmt: skip
