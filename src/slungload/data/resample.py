"""One log's streams -> flights on the dataset's time grid (``slungload import``, per log).

1. checks what physics pins down in the logged streams before anything is interpolated
   (``consistency``: quaternion norms, each stream's median time step);
2. cleans each stream: samples with a NaN (a motion-capture dropout) or a zero quaternion are
   dropped, repeated stamps keep their first sample, and stamps that go back in time are an
   error; a stream left empty is an error that says whether it had messages at all;
3. turns a normalised thrust into newtons: ``T = throttle / hover_throttle * (mQ + mL) g``
   (the hover throttle holds the vehicle *with its load*; PX4's ``MPC_THR_HOVER``), or
   ``T = throttle * newtons_per_throttle`` when that slope is given;
4. keeps the time where every stream has samples, and splits it where any stream has no sample
   for longer than its max gap (``ImportOptions.gap``: its own ``max_gaps`` entry, else
   ``max_gap``; a step over it by less than ``STAMP_EPS`` is no gap) or stops with an error
   (``on_gap="error"``); pieces shorter than ``min_duration`` are dropped with a note; messages
   name the stream, its median step, the gap and the option; a dropout interpolated within a
   raised max gap (``dropout_steps`` times the stream's median step) is noted;
5. resamples each piece on a grid of step ``params.dt`` from its first instant: positions and
   velocities linearly, the attitude by slerp, the commands by holding the last set-point
   (``commands="hold"``) or linearly; without a velocity stream, v is the causal second-order
   backward difference (3 p_k - 4 p_{k-1} + p_{k-2}) / (2 h) of the resampled position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import frames
from ..config import VehicleParams
from .consistency import Check, ConsistencyError, norm_check, refusal, step_check
from .import_options import STAMP_EPS, ImportOptions
from .readers.logs import ROLES, LogError, RawLog, Stream

__all__ = ["STAMP_EPS", "LogPieces", "backward_velocity", "resample_log", "stream_steps"]
AIRBORNE = 0.5  # a ULog's last thrust above this share of hover: it ends in the air


@dataclass
class LogPieces:
    """What one log gives: pieces as (the log's stamp of the first sample, arrays in the
    published schema), notes, the thrust map used, and stream checks overridden by force."""

    pieces: list[tuple[float, dict[str, np.ndarray]]]
    notes: list[str]
    thrust_map: dict[str, float] = field(default_factory=dict)
    forced: list[str] = field(default_factory=list)
    steps: dict[str, float] = field(default_factory=dict)  # s, each stream's median step


def resample_log(raw: RawLog, params: VehicleParams, options: ImportOptions) -> LogPieces:
    """Pieces of one log as published-schema arrays at step ``params.dt``."""
    path = raw.path
    notes: list[str] = []
    missing = [r for r in ROLES if r not in raw.streams and r != "velocity"]
    if missing:
        raise LogError(f"{path}: no {', '.join(missing)} in the log")
    forced = _stream_checks(raw, options, notes)
    streams = {role: _clean(role, s, path, notes) for role, s in raw.streams.items()}
    thrust_map = _thrust_map(raw, streams, params, options, notes)
    if raw.format == "ulog":
        _ends_airborne(raw, streams["thrust"], params, notes)

    t0 = min(float(s.time[0]) for s in streams.values())
    start = max(float(s.time[0]) for s in streams.values())
    end = min(float(s.time[-1]) for s in streams.values())
    if end - start < params.dt:
        spans = "; ".join(
            f"{s.source}: {s.time[0] - t0:.3f} to {s.time[-1] - t0:.3f} s" for s in streams.values()
        )
        raise LogError(f"{path}: the streams do not overlap in time ({spans})")
    _ends_early(streams, end, options, path, notes)
    pieces, holes = _pieces(streams, start, end, options, path, t0)
    kept = [(a, b) for a, b in pieces if b - a >= max(options.min_duration, params.dt)]
    dropped = len(pieces) - len(kept)
    if len(pieces) > 1:
        notes.append(
            f"{path}: split at {len(pieces) - 1} gap(s) longer than --max-gap {options.max_gap} "
            f"s ({_worst_gaps(holes, options)}) into {len(pieces)} pieces"
        )
    _dropouts(streams, kept, params, options, path, notes)
    if dropped:
        notes.append(
            f"{path}: {dropped} piece(s) shorter than --min-duration {options.min_duration} s "
            "dropped"
        )
    if not kept:
        raise LogError(_no_piece(path, streams, holes, options))
    arrays = [(a, _resample(streams, a, b, params.dt, options)) for a, b in kept]
    steps = {role: round(step, 9) for role, step in stream_steps(streams).items()}
    return LogPieces(arrays, notes, thrust_map, forced, steps)


def _stream_checks(raw: RawLog, options: ImportOptions, notes: list[str]) -> list[str]:
    """The logged attitude's norms and every stream's median step; a failure is an error
    naming the stream, or a note (returned) under ``force``."""
    found: list[tuple[str, Check]] = []
    for role, s in raw.streams.items():
        good = np.isfinite(s.time)
        if len(s.time) > 1:
            found.append((s.source, step_check(s.time[good], options.limits)))
        if role == "attitude":
            found.append((s.source, norm_check(s.values, options.limits)))
    bad = [(source, c) for source, c in found if not c.ok]
    if not bad:
        return []
    lines = [refusal(f"{raw.path}: {source}", [c]) for source, c in bad]
    if not options.force:
        raise ConsistencyError(lines[0])
    notes += [f"forced: {line}" for line in lines]
    return lines


def _thrust_map(
    raw: RawLog,
    streams: dict[str, Stream],
    params: VehicleParams,
    options: ImportOptions,
    notes: list[str],
) -> dict[str, float]:
    """Normalised thrust -> newtons in ``streams`` (by the hover throttle or a given slope);
    the map's numbers for ``vehicle.json``."""
    path = raw.path
    if not raw.thrust_normalized:
        given = [
            f"--{k.replace('_', '-')} {getattr(options, k):g}"
            for k in ("hover_throttle", "newtons_per_throttle")
            if getattr(options, k) is not None
        ]
        if given:
            notes.append(
                f"{path}: {' and '.join(given)} not used: its thrust "
                f"({streams['thrust'].source}) is already in newtons"
            )
        return {}
    source = streams["thrust"].source
    if options.newtons_per_throttle is not None:
        scale, how = options.newtons_per_throttle, "--newtons-per-throttle"
        result = {"newtons_per_throttle": scale}
    else:
        hover = options.hover_throttle or raw.hover_throttle
        if hover is None:
            raise LogError(
                f"{path}: {source} is a normalised throttle; give the hover throttle (the "
                "throttle that holds the vehicle with its load, PX4's MPC_THR_HOVER: "
                "--hover-throttle) or the thrust per unit throttle (--newtons-per-throttle) "
                "to turn it into newtons"
            )
        if not 0.0 < hover <= 1.0:
            raise LogError(f"{path}: hover throttle {hover} is not in (0, 1]")
        scale = (params.mass_quad + params.mass_load) * params.gravity / hover
        how = "given" if options.hover_throttle else f"{path}'s MPC_THR_HOVER"
        how = f"throttle / {hover:g} ({how}) * (mQ + mL) g"
        result = {"hover_throttle": hover, "newtons_per_throttle": scale}
    thrust = streams["thrust"]
    streams["thrust"] = Stream(thrust.source, thrust.time, thrust.values * scale)
    notes.append(f"{path}: thrust = {how} = throttle * {scale:.4g} N")
    return result


def _ends_airborne(raw: RawLog, thrust: Stream, params: VehicleParams, notes: list[str]) -> None:
    """PX4 logs from arming to disarming: a ULog whose last thrust holds the vehicle up was
    cut short (a crash, a full card, a truncated copy)."""
    hover = (params.mass_quad + params.mass_load) * params.gravity
    last = float(thrust.values[-1, 0]) / hover
    if last > AIRBORNE:
        notes.append(
            f"{raw.path}: the log ends abruptly, with the vehicle in the air (last thrust "
            f"{last:.2f} x hover at t = {thrust.time[-1] - thrust.time[0]:.2f} s): the flight "
            "ends there; a truncated copy of the log?"
        )


def _ends_early(
    streams: dict[str, Stream], end: float, options: ImportOptions, path: Path, notes: list[str]
) -> None:
    """A note for a stream that stops well before the others (the flight is cut there)."""
    last = max(float(s.time[-1]) for s in streams.values())
    for role, s in streams.items():
        if float(s.time[-1]) == end and last - end > options.gap(role) + STAMP_EPS:
            notes.append(
                f"{path}: {s.source} ends {last - end:.2f} s before the log's other streams: "
                "the flight ends there"
            )


def _clean(role: str, stream: Stream, path: Path, notes: list[str]) -> Stream:
    t, v = np.asarray(stream.time, np.float64), np.asarray(stream.values, np.float64)
    good = np.isfinite(t) & np.isfinite(v).all(axis=1)
    if role == "attitude":
        norm = np.linalg.norm(np.where(np.isfinite(v), v, 0.0), axis=1)
        good &= norm > 0.5
        v = v / np.where(norm > 0, norm, 1.0)[:, None]
    if not good.all() and good.any():
        notes.append(f"{path}: {stream.source}: {int((~good).sum())} samples without a value")
    count = len(t)
    t, v = t[good], v[good]
    if len(t) == 0:
        what = "the load is never seen: " if role == "load" else ""
        why = (
            "has no message"
            if count == 0
            else f"has {count} messages but none holds a valid value (NaN"
            + (" or a zero quaternion)" if role == "attitude" else ")")
        )
        raise LogError(f"{path}: {what}{stream.source} ({role}) {why}")
    steps = np.diff(t)
    back = np.flatnonzero(steps < 0)
    if len(back):
        i = back[0] + 1
        raise LogError(
            f"{path}: {stream.source}: stamps out of order at message {i} "
            f'({t[i]:.6f} s after {t[i - 1]:.6f} s): time must not go back (stamps = "bag" '
            "uses the bag's receive time)"
        )
    repeat = np.flatnonzero(steps == 0) + 1
    if len(repeat):
        keep = np.ones(len(t), dtype=bool)
        keep[repeat] = False
        t, v = t[keep], v[keep]
        notes.append(f"{path}: {stream.source}: {len(repeat)} repeated stamps, first sample kept")
    return Stream(stream.source, t, v)


Hole = tuple[float, float, str, float]  # s from, s to, the stream's source, its max gap in s


def _pieces(
    streams: dict[str, Stream],
    start: float,
    end: float,
    options: ImportOptions,
    path: Path,
    t0: float,
) -> tuple[list[tuple[float, float]], list[Hole]]:
    """[start, end] without the gaps (longer than the stream's max gap) of any stream, and
    the gaps as (from, to, stream, its max gap)."""
    holes: list[Hole] = []
    for role, s in streams.items():
        gap = options.gap(role)
        steps = np.diff(s.time)
        for i in np.flatnonzero(steps > gap + STAMP_EPS):
            a, b = float(s.time[i]), float(s.time[i + 1])
            if b <= start or a >= end:
                continue
            if options.on_gap == "error":
                raise LogError(
                    f"{path}: {s.source}: no sample for {b - a:.3f} s from t = {a - t0:.3f} s "
                    f"(longer than {_gap_option(role, options)} s; --on-gap split cuts the "
                    "flight there instead)"
                )
            holes.append((a, b, s.source, gap))
    holes = sorted(set(holes))  # a topic that feeds two streams has its gaps twice
    pieces, cursor = [], start
    for a, b, *_ in holes:
        if a > cursor:
            pieces.append((cursor, a))
        cursor = max(cursor, b)
    if end > cursor:
        pieces.append((cursor, end))
    return pieces, holes


def _worst_gaps(holes: list[Hole], options: ImportOptions) -> str:
    """Per stream: how many gaps and the longest (and its own --max-gap, where it has one)."""
    by: dict[str, list[float]] = {}
    limit: dict[str, float] = {}
    for a, b, source, gap in holes:
        by.setdefault(source, []).append(b - a)
        limit[source] = gap
    return "; ".join(
        f"{source}: {len(g)} gap(s), the longest {max(g):.3f} s"
        + ("" if limit[source] == options.max_gap else f" (its --max-gap {limit[source]:g} s)")
        for source, g in by.items()
    )


def _gap_option(role: str, options: ImportOptions) -> str:
    """``--max-gap 0.1`` or, for a stream with its own, ``--max-gap load=0.3``."""
    gap = options.gap(role)
    return f"--max-gap {gap:g}" if gap == options.max_gap else f"--max-gap {role}={gap:g}"


def stream_steps(streams: dict[str, Stream]) -> dict[str, float]:
    """s, each stream's median time step (its rate detected: 0.1 for a 10 Hz position), by
    role."""
    return {
        role: float(np.median(np.diff(s.time))) if len(s.time) > 1 else 0.0
        for role, s in streams.items()
    }


def _dropouts(
    streams: dict[str, Stream],
    pieces: list[tuple[float, float]],
    params: VehicleParams,
    options: ImportOptions,
    path: Path,
    notes: list[str],
) -> None:
    """A note for each stream whose steps inside the kept pieces reach ``dropout_steps`` times
    its own median step and a dataset step (a dropout within its --max-gap, interpolated):
    raising --max-gap for a sparse stream does not hide another stream's dropout."""
    steps = stream_steps(streams)
    seen: set[str] = set()
    for role, s in streams.items():
        if s.source in seen or len(s.time) < 2:
            continue
        seen.add(s.source)
        limit = max(options.dropout_steps * steps[role], params.dt)
        dt = np.diff(s.time)
        inside = np.zeros(len(dt), dtype=bool)
        for a, b in pieces:
            inside |= (s.time[1:] > a) & (s.time[:-1] < b)
        long = dt[inside & (dt > limit + STAMP_EPS)]
        if len(long):
            notes.append(
                f"{path}: {s.source}: {len(long)} dropout(s) up to {long.max():.3f} s "
                f"interpolated (sampled every {steps[role]:.3g} s; within "
                f"{_gap_option(role, options)} s; --max-gap {role}=S below it splits there)"
            )


def _no_piece(
    path: Path,
    streams: dict[str, Stream],
    holes: list[Hole],
    options: ImportOptions,
) -> str:
    """Why no piece is left: the streams with gaps, each with its median step, and the
    per-stream options that would take it."""
    rates, fixes = [], []
    steps = stream_steps(streams)
    by_source: dict[str, list[str]] = {}
    for role, s in streams.items():  # a bag's pose topic gives position and attitude
        by_source.setdefault(s.source, []).append(role)
    for source, roles in by_source.items():
        if any(hole[2] == source for hole in holes):
            step = steps[roles[0]]
            rates.append(f"{source} is sampled every {step:.3f} s (median)")
            above = math.ceil(1.5 * step / 0.05) * 0.05  # a step and a half, in 0.05 s
            fixes.append(f"--max-gap {','.join(roles)}={above:g}")
    hint = ""
    if rates:
        hint = (
            f" ({'; '.join(rates)}). A slower stream imports with its own --max-gap above its "
            f"step ({' '.join(fixes)}; the other streams keep --max-gap {options.max_gap:g}); "
            "linear interpolation across a step h errs by up to h^2/8 |a|: 1.25 mm at 0.1 s "
            "and 1 m/s^2"
        )
    return (
        f"{path}: no piece of at least --min-duration {options.min_duration} s without a gap "
        f"longer than --max-gap {options.max_gap} s: "
        f"{_worst_gaps(holes, options) or 'no overlap'}{hint}; --on-gap error names the first gap"
    )


def _resample(
    streams: dict[str, Stream], a: float, b: float, dt: float, options: ImportOptions
) -> dict[str, np.ndarray]:
    # float stamps are rounded: a last step short of dt by under STAMP_EPS still counts
    n = int(np.floor((b - a + STAMP_EPS) / dt)) + 1
    grid = a + dt * np.arange(n)

    def linear(s: Stream) -> np.ndarray:
        return np.stack(
            [np.interp(grid, s.time, s.values[:, j]) for j in range(s.values.shape[1])], 1
        )

    def command(s: Stream) -> np.ndarray:
        if options.commands == "linear":
            return linear(s)
        i = np.searchsorted(s.time, grid + STAMP_EPS, side="right") - 1
        return s.values[np.clip(i, 0, len(s.time) - 1)]

    p = linear(streams["position"])
    if "velocity" in streams:
        v = linear(streams["velocity"])
    else:
        v = backward_velocity(p, dt)
    q = frames.slerp(grid, streams["attitude"].time, streams["attitude"].values)
    return {
        "time": dt * np.arange(n),
        "p": p,
        "v": v,
        "attitude": q[:, [1, 2, 3, 0]],  # w-x-y-z -> x-y-z-w, the files' order
        "p_load": linear(streams["load"]),
        "w_ref": command(streams["rates"]),
        "T_ref": command(streams["thrust"]),
    }


def backward_velocity(p: np.ndarray, dt: float) -> np.ndarray:
    """Causal velocity from positions (T, 3): (3 p_k - 4 p_{k-1} + p_{k-2}) / (2 dt) from step
    2, (p_1 - p_0) / dt at step 1, step 0 repeating step 1."""
    v = np.empty_like(p)
    if len(p) < 2:
        v[:] = 0.0
        return v
    v[1] = (p[1] - p[0]) / dt
    v[0] = v[1]
    v[2:] = (3 * p[2:] - 4 * p[1:-1] + p[:-2]) / (2 * dt)
    return v
